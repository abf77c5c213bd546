//! The built-in catalog of Universal Robots arms: nominal standard-DH parameters and joint limits.
//!
//! DH values are Universal Robots' published ones ("DH parameters for calculations of kinematics
//! and dynamics", also `config/<model>/default_kinematics.yaml` in UR's ROS 2 description), not
//! the rounded table of the `UR10e` FMU report. Every UR arm shares one structure,
//! `α = [π/2, 0, 0, π/2, −π/2, 0]`, `a₁ = a₄ = a₅ = a₆ = 0`, `d₂ = d₃ = 0`, `θ = 0`, so an entry
//! holds only `d₁, a₂, a₃, d₄, d₅, d₆`.
//!
//! Link inertial parameters, where published, are in [`super::ur_inertia`].
//!
//! Joint limits are the controller's: ±360° on every joint, except the tool joint (wrist 3) of
//! the `UR3` and `UR3e`, which turns without limit. (ROS descriptions halve the elbow to ±180° for
//! motion planning; the controller reports the full range, so a twin must accept it.)

use std::f64::consts::{FRAC_PI_2, TAU};

use super::{ArmDescription, JointLimits, ModelError};
use crate::kinematics::{DhConvention, DhParameters};

/// One catalog entry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UrEntry {
    /// Catalog name, as given to `--model`.
    pub name: &'static str,
    /// Human-readable name and generation.
    pub title: &'static str,
    /// `[d1, a2, a3, d4, d5, d6]` (m).
    pub d1_a2_a3_d4_d5_d6_m: [f64; 6],
    /// Whether wrist 3 turns without limit.
    pub wrist_3_unlimited: bool,
}

/// The catalog, in the order `armtwin models` lists it.
pub const UNIVERSAL_ROBOTS: [UrEntry; 9] = [
    UrEntry {
        name: "ur3",
        title: "UR3 (CB3)",
        d1_a2_a3_d4_d5_d6_m: [0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819],
        wrist_3_unlimited: true,
    },
    UrEntry {
        name: "ur5",
        title: "UR5 (CB3)",
        d1_a2_a3_d4_d5_d6_m: [0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823],
        wrist_3_unlimited: false,
    },
    UrEntry {
        name: "ur10",
        title: "UR10 (CB3)",
        d1_a2_a3_d4_d5_d6_m: [0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922],
        wrist_3_unlimited: false,
    },
    UrEntry {
        name: "ur3e",
        title: "UR3e (e-Series)",
        d1_a2_a3_d4_d5_d6_m: [0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921],
        wrist_3_unlimited: true,
    },
    UrEntry {
        name: "ur5e",
        title: "UR5e (e-Series)",
        d1_a2_a3_d4_d5_d6_m: [0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996],
        wrist_3_unlimited: false,
    },
    UrEntry {
        name: "ur10e",
        title: "UR10e (e-Series)",
        d1_a2_a3_d4_d5_d6_m: [0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655],
        wrist_3_unlimited: false,
    },
    UrEntry {
        name: "ur16e",
        title: "UR16e (e-Series)",
        d1_a2_a3_d4_d5_d6_m: [0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655],
        wrist_3_unlimited: false,
    },
    UrEntry {
        name: "ur20",
        title: "UR20",
        d1_a2_a3_d4_d5_d6_m: [0.2363, -0.862, -0.7287, 0.201, 0.1593, 0.1543],
        wrist_3_unlimited: false,
    },
    UrEntry {
        name: "ur30",
        title: "UR30",
        d1_a2_a3_d4_d5_d6_m: [0.2363, -0.637, -0.5037, 0.201, 0.1593, 0.1543],
        wrist_3_unlimited: false,
    },
];

/// Joint names of every UR arm, base to flange (ROS names).
pub const UR_JOINT_NAMES: [&str; 6] = [
    "shoulder_pan",
    "shoulder_lift",
    "elbow",
    "wrist_1",
    "wrist_2",
    "wrist_3",
];

impl UrEntry {
    /// The entry as a standard-DH arm description.
    #[must_use]
    pub fn arm(&self) -> ArmDescription {
        let [d1, a2, a3, d4, d5, d6] = self.d1_a2_a3_d4_d5_d6_m;
        let row = |a_m: f64, alpha_rad: f64, d_m: f64| DhParameters {
            a_m,
            alpha_rad,
            d_m,
            theta_offset_rad: 0.0,
        };
        let full_turns = JointLimits {
            min_rad: Some(-TAU),
            max_rad: Some(TAU),
        };
        let mut joint_limits = vec![full_turns; 6];
        if self.wrist_3_unlimited {
            joint_limits[5] = JointLimits::UNLIMITED;
        }
        ArmDescription {
            name: self.name.to_owned(),
            convention: DhConvention::Standard,
            dh: vec![
                row(0.0, FRAC_PI_2, d1),
                row(a2, 0.0, 0.0),
                row(a3, 0.0, 0.0),
                row(0.0, FRAC_PI_2, d4),
                row(0.0, -FRAC_PI_2, d5),
                row(0.0, 0.0, d6),
            ],
            joint_limits,
            inertials: super::ur_inertia::inertials(self.name),
            joint_origins: None,
        }
    }
}

/// The catalog arm called `name` (case-insensitive).
pub fn arm(name: &str) -> Result<ArmDescription, ModelError> {
    UNIVERSAL_ROBOTS
        .iter()
        .find(|entry| entry.name.eq_ignore_ascii_case(name))
        .map(UrEntry::arm)
        .ok_or_else(|| ModelError::UnknownModel {
            name: name.to_owned(),
            known: UNIVERSAL_ROBOTS
                .iter()
                .map(|entry| entry.name)
                .collect::<Vec<_>>()
                .join(", "),
        })
}
