//! Robot descriptions: the built-in catalog, custom arms, factory calibration and tool, and the
//! [`RobotModel`] that joins them into one compiled chain.
//!
//! Owns what a robot *is*; [`crate::kinematics`] owns how a pose is computed from it. Files are
//! parsed from text handed in by the caller: nothing here opens a file.

pub mod calibration;
pub mod catalog;
pub mod custom;

use thiserror::Error;

use crate::kinematics::{
    Chain, DhConvention, DhParameters, KinematicsError, OutputFrame, Pose, TcpOffset,
};
pub use calibration::{Calibration, CalibrationError, CalibrationForm};

/// Position limits of one revolute joint (rad); `None` on a side means unlimited.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLimits {
    /// Lowest allowed angle (rad).
    pub min_rad: Option<f64>,
    /// Highest allowed angle (rad).
    pub max_rad: Option<f64>,
}

impl JointLimits {
    /// No limit on either side.
    pub const UNLIMITED: Self = Self {
        min_rad: None,
        max_rad: None,
    };

    /// Whether `angle_rad` lies within the limits (inclusive).
    #[must_use]
    pub fn contains(&self, angle_rad: f64) -> bool {
        self.min_rad.is_none_or(|min| angle_rad >= min)
            && self.max_rad.is_none_or(|max| angle_rad <= max)
    }
}

/// A nominal arm: a DH table with the limits of each joint.
#[derive(Debug, Clone, PartialEq)]
pub struct ArmDescription {
    /// Model name (`ur10e`, or a custom arm's own name).
    pub name: String,
    /// Convention of `dh`.
    pub convention: DhConvention,
    /// One row per revolute joint, base to flange.
    pub dh: Vec<DhParameters>,
    /// One entry per joint.
    pub joint_limits: Vec<JointLimits>,
}

/// Why a robot model cannot be built.
#[derive(Debug, Error)]
pub enum ModelError {
    /// The model name is not in the catalog.
    #[error("unknown model '{name}'; the catalog has: {known}")]
    UnknownModel {
        /// The name asked for.
        name: String,
        /// The catalog's names, comma-separated.
        known: String,
    },
    /// A calibration file could not be read.
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
    /// A calibration does not fit the arm it is applied to.
    #[error("{source_name}: {reason}")]
    CalibrationMismatch {
        /// The calibration file.
        source_name: String,
        /// What does not fit.
        reason: String,
    },
    /// A custom arm file is invalid.
    #[error("{source_name}: {reason}")]
    CustomArm {
        /// The arm file.
        source_name: String,
        /// What is wrong, with the field where known.
        reason: String,
    },
}

/// The error for joint `index` (0-based) whose `value` failed [`RobotModel::check_joints`]; kept
/// out of the per-sample path.
#[cold]
fn joint_error(index: usize, value: f64, limits: &JointLimits) -> KinematicsError {
    if value.is_finite() {
        KinematicsError::OutOfLimits {
            joint: index + 1,
            value_rad: value,
            min_rad: limits.min_rad.unwrap_or(f64::NEG_INFINITY),
            max_rad: limits.max_rad.unwrap_or(f64::INFINITY),
        }
    } else {
        KinematicsError::NonFinite {
            joint: index + 1,
            value,
        }
    }
}

/// Everything forward kinematics needs for one robot: its arm, its own calibration, its tool and
/// the frame poses are reported in, compiled once into a [`Chain`].
#[derive(Debug, Clone)]
pub struct RobotModel {
    arm: ArmDescription,
    calibration: Option<Calibration>,
    tool: TcpOffset,
    frame: OutputFrame,
    chain: Chain,
}

impl RobotModel {
    /// Builds the model; fails when the calibration does not fit the arm.
    pub fn new(
        arm: ArmDescription,
        calibration: Option<Calibration>,
        tool: TcpOffset,
        frame: OutputFrame,
    ) -> Result<Self, ModelError> {
        let flange_chain = match &calibration {
            None => Chain::from_dh(arm.convention, &arm.dh),
            Some(calibration) => calibration.chain_for(&arm)?,
        };
        let chain = flange_chain.with_frame_and_tool(frame, &tool);
        Ok(Self {
            arm,
            calibration,
            tool,
            frame,
            chain,
        })
    }

    /// A catalog model with no calibration, no tool, in the `base` frame.
    pub fn nominal(name: &str) -> Result<Self, ModelError> {
        Self::new(
            catalog::arm(name)?,
            None,
            TcpOffset::FLANGE,
            OutputFrame::Base,
        )
    }

    /// The nominal arm.
    #[must_use]
    pub fn arm(&self) -> &ArmDescription {
        &self.arm
    }

    /// The factory calibration, if one was given.
    #[must_use]
    pub fn calibration(&self) -> Option<&Calibration> {
        self.calibration.as_ref()
    }

    /// The tool offset.
    #[must_use]
    pub fn tool(&self) -> &TcpOffset {
        &self.tool
    }

    /// The frame poses are expressed in.
    #[must_use]
    pub fn frame(&self) -> OutputFrame {
        self.frame
    }

    /// Number of joints.
    #[must_use]
    pub fn joint_count(&self) -> usize {
        self.chain.joint_count()
    }

    /// Checks count, finiteness and joint limits of `q_rad`.
    pub fn check_joints(&self, q_rad: &[f64]) -> Result<(), KinematicsError> {
        if q_rad.len() != self.joint_count() {
            return Err(KinematicsError::JointCount {
                expected: self.joint_count(),
                got: q_rad.len(),
            });
        }
        for (index, (&value, limits)) in q_rad.iter().zip(&self.arm.joint_limits).enumerate() {
            if !(value.is_finite() && limits.contains(value)) {
                return Err(joint_error(index, value, limits));
            }
        }
        Ok(())
    }

    /// The TCP pose in the model's output frame for joint angles `q_rad` (rad), after
    /// [`Self::check_joints`].
    pub fn pose(&self, q_rad: &[f64]) -> Result<Pose, KinematicsError> {
        self.check_joints(q_rad)?;
        Ok(self.chain.pose_unchecked(q_rad))
    }

    /// The compiled chain (output frame and tool included).
    #[must_use]
    pub fn chain(&self) -> &Chain {
        &self.chain
    }
}
