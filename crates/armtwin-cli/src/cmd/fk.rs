//! `armtwin fk`: the TCP pose of one joint configuration as JSON, or of every row of a joint CSV
//! as a pose CSV on stdout.
//!
//! Owns parsing the angles and writing the answer; must not compute the pose (the model does).

use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read, Write};
use std::path::Path;

use anyhow::{Context, Result, bail};
use armtwin_codec::PoseFields;
use armtwin_codec::joint_csv::{JointCsvReader, PoseCsvWriter};
use armtwin_core::kinematics::Pose;
use armtwin_core::model::urdf::{JointKind, UrdfRobot};
use armtwin_core::model::{ModelRef, RobotModel};
use serde::Serialize;

use crate::flags::FkArgs;

#[derive(Serialize)]
struct FkOutput {
    #[serde(flatten)]
    pose: PoseFields,
    #[serde(skip_serializing_if = "Option::is_none")]
    matrix: Option<[[f64; 4]; 4]>,
}

fn to_radians(q: &mut [f64], degrees: bool) {
    if degrees {
        for angle in q {
            *angle = angle.to_radians();
        }
    }
}

pub(super) fn run(args: &FkArgs) -> Result<()> {
    if let ModelRef::Urdf(path) = ModelRef::parse(&args.robot.model) {
        return run_urdf(args, path);
    }
    let model = args.robot.load()?;
    if let Some(path) = &args.csv {
        return run_csv(&model, path, args.deg);
    }
    if args.joints.is_empty() {
        bail!(
            "give {} joint angles (or --csv FILE); e.g. armtwin fk --model {} 0 -1.57 0 -1.57 0 0",
            model.joint_count(),
            model.arm().name
        );
    }
    let mut q = args.joints.clone();
    to_radians(&mut q, args.deg);
    let pose = model.pose(&q)?;
    print_pose(&pose, args.matrix)
}

/// The tip link's pose in the base link's frame, from a URDF; joint values base to tip (rad, or m
/// for prismatic joints). The calibration, TCP and frame flags are for DH models.
fn run_urdf(args: &FkArgs, path: &Path) -> Result<()> {
    if args.robot.calibration.is_some() || args.robot.tcp.is_some() || args.csv.is_some() {
        bail!("--calibration, --tcp and --csv are not taken with a URDF --model");
    }
    let text = super::read_text(path)?;
    let chain = UrdfRobot::parse(&text)
        .and_then(|robot| {
            robot.chain(
                args.robot.links.base_link.as_deref(),
                args.robot.links.tip_link.as_deref(),
            )
        })
        .with_context(|| path.display().to_string())?;
    if args.joints.len() != chain.joint_count() {
        let names: Vec<_> = chain.joints.iter().map(|j| j.name.as_str()).collect();
        bail!(
            "{}: the chain from '{}' to '{}' has {} moving joints ({}); got {} values",
            path.display(),
            chain.base_link,
            chain.tip_link,
            chain.joint_count(),
            names.join(", "),
            args.joints.len()
        );
    }
    let mut q = args.joints.clone();
    for (value, joint) in q.iter_mut().zip(&chain.joints) {
        if args.deg && joint.kind != JointKind::Prismatic {
            *value = value.to_radians();
        }
    }
    let pose = chain.pose(&q).with_context(|| path.display().to_string())?;
    print_pose(&pose, args.matrix)
}

/// One pose as a JSON line on stdout, with its 4×4 matrix if asked.
fn print_pose(pose: &Pose, matrix: bool) -> Result<()> {
    let output = FkOutput {
        pose: PoseFields::from(&pose.readout()),
        matrix: matrix.then(|| pose.homogeneous_rows()),
    };
    let stdout = io::stdout();
    let mut out = stdout.lock();
    serde_json::to_writer(&mut out, &output)?;
    writeln!(out)?;
    Ok(())
}

fn run_csv(model: &RobotModel, path: &Path, degrees: bool) -> Result<()> {
    let (input, name): (Box<dyn Read>, String) = if path == Path::new("-") {
        (Box::new(io::stdin().lock()), "stdin".to_owned())
    } else {
        let file = File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
        (Box::new(BufReader::new(file)), path.display().to_string())
    };
    let rows = JointCsvReader::new(input, model.joint_count()).with_context(|| name.clone())?;
    let mut writer = PoseCsvWriter::new(BufWriter::new(io::stdout().lock()))?;
    for row in rows {
        let mut row = row.with_context(|| name.clone())?;
        to_radians(&mut row.q, degrees);
        let pose = model
            .pose(&row.q)
            .with_context(|| format!("{name}: line {}", row.line))?;
        writer.write(row.time_s, &PoseFields::from(&pose.readout()))?;
    }
    writer.finish()?;
    Ok(())
}
