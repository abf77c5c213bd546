//! `armtwin models`: the built-in robot models, as a table or as JSON.
//!
//! Owns the listing's layout; must not hold model data (the catalog does).

use std::io::{self, Write};

use anyhow::Result;
use armtwin_core::model::catalog;
use armtwin_core::model::urdf::ModelFrames;
use serde::Serialize;

use crate::flags::{ChainLinks, ModelsArgs, RobotArgs};

#[derive(Serialize)]
struct ModelListing {
    name: &'static str,
    title: &'static str,
    convention: &'static str,
    joints: Vec<JointListing>,
}

#[derive(Serialize)]
struct JointListing {
    name: &'static str,
    a_m: f64,
    alpha_rad: f64,
    d_m: f64,
    theta_offset_rad: f64,
    min_rad: Option<f64>,
    max_rad: Option<f64>,
}

/// `--urdf MODEL`: the model's URDF on stdout.
fn write_urdf(args: &ModelsArgs, model: &str) -> Result<()> {
    let robot = RobotArgs {
        model: model.to_owned(),
        links: ChainLinks::default(),
        calibration: args.calibration.clone(),
        tcp: args.tcp,
        frame: args.frame,
    }
    .load()?;
    io::stdout()
        .lock()
        .write_all(ModelFrames::of(&robot).urdf(&robot).as_bytes())?;
    Ok(())
}

pub(super) fn run(args: &ModelsArgs) -> Result<()> {
    if let Some(model) = &args.urdf {
        return write_urdf(args, model);
    }
    let listings: Vec<ModelListing> = catalog::UNIVERSAL_ROBOTS
        .iter()
        .map(|entry| {
            let arm = entry.arm();
            ModelListing {
                name: entry.name,
                title: entry.title,
                convention: arm.convention.as_str(),
                joints: arm
                    .dh
                    .iter()
                    .zip(&arm.joint_limits)
                    .zip(catalog::UR_JOINT_NAMES)
                    .map(|((row, limits), name)| JointListing {
                        name,
                        a_m: row.a_m,
                        alpha_rad: row.alpha_rad,
                        d_m: row.d_m,
                        theta_offset_rad: row.theta_offset_rad,
                        min_rad: limits.min_rad,
                        max_rad: limits.max_rad,
                    })
                    .collect(),
            }
        })
        .collect();
    let stdout = io::stdout();
    let mut out = stdout.lock();
    if args.json {
        serde_json::to_writer_pretty(&mut out, &listings)?;
        writeln!(out)?;
        return Ok(());
    }
    writeln!(
        out,
        "Universal Robots, standard DH (alpha = [pi/2, 0, 0, pi/2, -pi/2, 0]), metres:"
    )?;
    writeln!(
        out,
        "{:<7} {:<17} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}  wrist 3",
        "model", "", "d1", "a2", "a3", "d4", "d5", "d6"
    )?;
    for entry in &catalog::UNIVERSAL_ROBOTS {
        let [d1, a2, a3, d4, d5, d6] = entry.d1_a2_a3_d4_d5_d6_m;
        writeln!(
            out,
            "{:<7} {:<17} {d1:>9} {a2:>9} {a3:>9} {d4:>9} {d5:>9} {d6:>9}  {}",
            entry.name,
            entry.title,
            if entry.wrist_3_unlimited {
                "unlimited"
            } else {
                "±360°"
            }
        )?;
    }
    writeln!(
        out,
        "Every other joint: ±360°. `armtwin models --json` for full tables."
    )?;
    Ok(())
}
