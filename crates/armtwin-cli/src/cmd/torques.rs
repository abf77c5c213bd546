//! `armtwin torques`: the inverse-dynamics torques of one state as JSON, for a catalog arm with
//! published inertias or any URDF chain, so a model can be checked against a user's own tools.
//!
//! Owns reading the arguments and writing the answer; the dynamics are the core's.

use std::io::{self, Write};

use anyhow::{Context, Result, bail};
use armtwin_core::dynamics::ArmDynamics;
use armtwin_core::model::urdf::{UrdfDynamics, UrdfRobot};
use armtwin_core::model::{ModelRef, catalog};
use serde::Serialize;

use crate::flags::TorquesArgs;

#[derive(Serialize)]
struct TorquesOutput<'a> {
    /// Per joint, base to tip: N·m, or N for a prismatic joint.
    torque: &'a [f64],
    /// The joints' names (URDF) or numbers.
    joints: Vec<String>,
    /// Gravity's magnitude along the base's −z (m/s²).
    gravity_m_s2: f64,
}

/// `values`, or zeros when none were given; an error when the count is wrong.
fn values_or_zeros(values: &[f64], count: usize, flag: &str) -> Result<Vec<f64>> {
    match values.len() {
        0 => Ok(vec![0.0; count]),
        n if n == count => Ok(values.to_vec()),
        n => bail!("--{flag} has {n} values; the model has {count} joints"),
    }
}

pub(super) fn run(args: &TorquesArgs) -> Result<()> {
    let (torque, joints, gravity_m_s2) = match ModelRef::parse(&args.model) {
        ModelRef::Urdf(path) => {
            let text = super::read_text(path)?;
            let context = || path.display().to_string();
            let robot = UrdfRobot::parse(&text).with_context(context)?;
            let chain = robot
                .chain(
                    args.links.base_link.as_deref(),
                    args.links.tip_link.as_deref(),
                )
                .with_context(context)?;
            let dynamics = UrdfDynamics::new(&robot, &chain).with_context(context)?;
            let count = dynamics.joint_count();
            if args.q.len() != count {
                bail!(
                    "{}: the chain from '{}' to '{}' has {count} moving joints; --q has {} values",
                    path.display(),
                    chain.base_link,
                    chain.tip_link,
                    args.q.len()
                );
            }
            let qd = values_or_zeros(&args.qd, count, "qd")?;
            let qdd = values_or_zeros(&args.qdd, count, "qdd")?;
            let torque = dynamics
                .inverse_dynamics(&args.q, &qd, &qdd)
                .with_context(context)?;
            let names = chain.joints.iter().map(|j| j.name.clone()).collect();
            (
                torque,
                names,
                armtwin_core::model::urdf::STANDARD_GRAVITY_M_S2,
            )
        }
        ModelRef::Catalog(name) => {
            args.links.only_for(&ModelRef::Catalog(name))?;
            let arm = catalog::arm(name)?;
            let dynamics = ArmDynamics::<6>::from_arm(&arm)
                .with_context(|| format!("model '{name}' has no published inertias"))?;
            let state = |values: &[f64], flag: &str| -> Result<[f64; 6]> {
                let values = values_or_zeros(values, 6, flag)?;
                Ok(values.try_into().unwrap_or([0.0; 6]))
            };
            let (q, qd, qdd) = (
                state(&args.q, "q")?,
                state(&args.qd, "qd")?,
                state(&args.qdd, "qdd")?,
            );
            let torque = dynamics.inverse_dynamics_nm(&q, &qd, &qdd).to_vec();
            let gravity = dynamics.gravity_base_m_s2();
            let magnitude = gravity.iter().map(|g| g * g).sum::<f64>().sqrt();
            (torque, (1..=6).map(|k| k.to_string()).collect(), magnitude)
        }
        ModelRef::CustomArm(path) => bail!(
            "{}: a custom arm's TOML has no inertias; give its URDF for its dynamics",
            path.display()
        ),
    };
    let output = TorquesOutput {
        torque: &torque,
        joints,
        gravity_m_s2,
    };
    let stdout = io::stdout();
    let mut out = stdout.lock();
    serde_json::to_writer(&mut out, &output)?;
    writeln!(out)?;
    Ok(())
}
