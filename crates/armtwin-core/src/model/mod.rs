//! Robot descriptions: the built-in catalog, custom arms, how a user names either
//! ([`ModelRef`]), factory calibration and tool, and the [`RobotModel`] that joins them into one
//! compiled chain.
//!
//! Owns what a robot *is*; [`crate::kinematics`] owns how a pose is computed from it. Files are
//! parsed from text handed in by the caller: nothing here opens a file.

pub mod calibration;
pub mod catalog;
pub mod custom;
pub mod inertia;
mod reference;
pub mod ur_inertia;
pub mod urdf;

use nalgebra::IsometryMatrix3;
use thiserror::Error;

use crate::kinematics::{
    Chain, DhConvention, DhParameters, KinematicsError, OutputFrame, Pose, TcpOffset,
};
pub use calibration::{Calibration, CalibrationError, CalibrationForm, MountingDeltas};
use inertia::ArmInertials;
pub use reference::ModelRef;

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

/// A nominal arm: a DH table with the limits of each joint, and its links' inertial parameters
/// where known.
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
    /// Link masses, centres of mass and inertias in the link frames (DH frames of `convention`,
    /// or the joint frames of `joint_origins`), and rotor inertias, for [`crate::dynamics`];
    /// `None` when not published or not given.
    pub inertials: Option<ArmInertials>,
    /// An arm described by its joints' origins (a URDF's chain) rather than a DH table, which is
    /// then empty.
    pub joint_origins: Option<JointOrigins>,
}

impl ArmDescription {
    /// Its moving joints: its DH table's rows, or its joint origins'.
    #[must_use]
    pub fn joint_count(&self) -> usize {
        self.joint_origins
            .as_ref()
            .map_or(self.dh.len(), |origins| origins.parent_from_joint.len())
    }
}

/// A chain of joints that turn about their own frame's z, at fixed origins: a URDF's revolute
/// chain with each axis turned onto z.
#[derive(Debug, Clone, PartialEq)]
pub struct JointOrigins {
    /// Per joint: the previous joint's frame (or the base) to this joint's frame.
    pub parent_from_joint: Vec<IsometryMatrix3<f64>>,
    /// The last joint's frame to the flange (the chain's tip link).
    pub last_from_flange: IsometryMatrix3<f64>,
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
    /// A URDF that is not readable, or whose chain the twin cannot take.
    #[error("{source_name}: {reason}")]
    Urdf {
        /// The URDF file.
        source_name: String,
        /// What is wrong.
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
        let flange_chain = match (&arm.joint_origins, &calibration) {
            (Some(origins), None) => {
                Chain::from_origins(&origins.parent_from_joint, origins.last_from_flange)
            }
            (Some(_), Some(calibration)) => {
                return Err(ModelError::CalibrationMismatch {
                    source_name: calibration.source_name.clone(),
                    reason: format!(
                        "'{}' is described by joint origins (a URDF), and a calibration file applies to a DH table: put the robot's calibrated origins in its URDF",
                        arm.name
                    ),
                });
            }
            (None, None) => Chain::from_dh(arm.convention, &arm.dh),
            (None, Some(calibration)) => calibration.chain_for(&arm)?,
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

    /// The same arm in the same output frame with `deltas` to its nominal table (a
    /// `calibration.conf` `[mounting]` section, named `source_name`) and `tool`: an identified,
    /// applied or restored calibration of this robot. Its own calibration, if any, is replaced.
    pub fn with_deltas(
        &self,
        deltas: MountingDeltas,
        tool: TcpOffset,
        source_name: &str,
    ) -> Result<Self, ModelError> {
        Self::new(
            self.arm.clone(),
            Some(Calibration {
                source_name: source_name.to_owned(),
                form: CalibrationForm::MountingDeltas(deltas),
            }),
            tool,
            self.frame,
        )
    }

    /// The same arm, calibration and output frame with another `tool`: the TCP a controller
    /// reports (`tcp_offset`) in place of the configured one.
    pub fn with_tool(&self, tool: TcpOffset) -> Result<Self, ModelError> {
        Self::new(self.arm.clone(), self.calibration.clone(), tool, self.frame)
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
    /// [`Self::check_joints`]: position in metres, the rotation's columns the TCP's axes in the
    /// output frame (`frame_from_base · base_from_flange · flange_from_tcp`).
    /// [`Pose::readout`](crate::kinematics::Pose::readout) gives the quaternion in wire order
    /// `[x, y, z, w]` with `w ≥ 0`, and roll, pitch, yaw with `R = Rz(yaw) · Ry(pitch) · Rx(roll)`.
    ///
    /// A `ur10e` with a 0.2 m tool along the flange's z axis, turned a quarter turn about it, in
    /// ROS `base_link` (`base` turned π about z), at `q = 0`: the tool's z axis is `base_link` +y,
    /// so the TCP sits 0.2 m further along y than the flange, at
    /// `(−(a₂ + a₃), d₄ + d₆ + 0.2, d₁ − d₅)`:
    ///
    /// ```
    /// use approx::assert_abs_diff_eq;
    /// use armtwin_core::kinematics::{OutputFrame, TcpOffset};
    /// use armtwin_core::model::{RobotModel, catalog};
    /// use nalgebra::{Matrix3, Vector3};
    /// use std::f64::consts::FRAC_PI_2;
    ///
    /// // As on the UR pendant: x, y, z (m), then a rotation vector (rad).
    /// let tool = TcpOffset::from_ur_pose([0.0, 0.0, 0.2, 0.0, 0.0, FRAC_PI_2]).ok_or("finite")?;
    /// let model = RobotModel::new(catalog::arm("ur10e")?, None, tool, OutputFrame::BaseLink)?;
    /// let pose = model.pose(&[0.0; 6])?;
    /// // d₁ = 0.1807, a₂ = −0.6127, a₃ = −0.57155, d₄ = 0.17415, d₅ = 0.11985, d₆ = 0.11655 (m)
    /// let position_m = Vector3::new(1.18425, 0.4907, 0.06085);
    /// assert_abs_diff_eq!(pose.position_m, position_m, epsilon = 1e-12);
    /// // Columns: the TCP's x, y, z axes in base_link.
    /// let axes = Matrix3::new(0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0);
    /// assert_abs_diff_eq!(pose.rotation, axes, epsilon = 1e-15);
    ///
    /// // A third of a turn about (−1, −1, −1)/√3; of q and −q, the one with w ≥ 0.
    /// let readout = pose.readout();
    /// for (got, expected) in readout.quaternion_xyzw.iter().zip([-0.5, -0.5, -0.5, 0.5]) {
    ///     assert_abs_diff_eq!(*got, expected, epsilon = 1e-15);
    /// }
    /// // Pitch −π/2 is gimbal lock: yaw is then 0 and roll carries the rotation.
    /// assert_abs_diff_eq!(readout.rpy.roll_rad, -FRAC_PI_2, epsilon = 1e-12);
    /// assert_abs_diff_eq!(readout.rpy.pitch_rad, -FRAC_PI_2, epsilon = 1e-12);
    /// assert_abs_diff_eq!(readout.rpy.yaw_rad, 0.0, epsilon = 1e-12);
    ///
    /// // Outside the controller's ±2π on joint 3: an error that names the joint.
    /// let error = model.pose(&[0.0, 0.0, 7.0, 0.0, 0.0, 0.0]).unwrap_err();
    /// assert!(error.to_string().contains("q3"), "{error}");
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn pose(&self, q_rad: &[f64]) -> Result<Pose, KinematicsError> {
        self.check_joints(q_rad)?;
        Ok(self.chain.pose_unchecked(q_rad))
    }

    /// The compiled chain (output frame and tool included).
    #[must_use]
    pub fn chain(&self) -> &Chain {
        &self.chain
    }

    /// How far `other`'s poses are from this model's, at zero and at [`PROBE_CONFIGURATIONS`]
    /// spread configurations (within ±1.2 rad of zero): the largest position difference (m)
    /// and rotation-matrix entry difference. `None` when their joint counts differ.
    #[must_use]
    pub fn pose_difference(&self, other: &Self) -> Option<PoseDifference> {
        let n = self.joint_count();
        if other.joint_count() != n {
            return None;
        }
        let mut worst = PoseDifference {
            position_m: 0.0,
            rotation: 0.0,
        };
        let mut q_rad = vec![0.0; n];
        for probe in 0..=PROBE_CONFIGURATIONS {
            for (k, q) in q_rad.iter_mut().enumerate() {
                // Incommensurate frequencies: no two joints move together across the probes.
                #[allow(clippy::cast_precision_loss, reason = "small counts")]
                let phase = (probe * (k + 1)) as f64;
                *q = 1.2 * (0.9 * phase + 0.37 * k as f64).sin() * f64::from(u8::from(probe > 0));
            }
            let a = self.chain.pose_unchecked(&q_rad);
            let b = other.chain.pose_unchecked(&q_rad);
            worst.position_m = worst.position_m.max((a.position_m - b.position_m).amax());
            worst.rotation = worst.rotation.max((a.rotation - b.rotation).amax());
        }
        Some(worst)
    }
}

/// Configurations besides zero at which [`RobotModel::pose_difference`] compares two models.
pub const PROBE_CONFIGURATIONS: usize = 16;

/// The largest difference between two models' poses ([`RobotModel::pose_difference`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseDifference {
    /// Position (m), the largest coordinate difference.
    pub position_m: f64,
    /// The largest rotation-matrix entry difference.
    pub rotation: f64,
}

impl PoseDifference {
    /// Whether both are within `tolerance` (m, and per entry).
    #[must_use]
    pub fn within(&self, tolerance: f64) -> bool {
        self.position_m <= tolerance && self.rotation <= tolerance
    }
}
