//! What of a robot's twin outlives the process ([`TwinRecord`]), and why a record is refused.
//!
//! Owns the record's plain data. Must not choose a file format (the caller serializes it) nor
//! build a twin from it: [`Twin::restored`](super::Twin::restored) does, beside the twin's own
//! fields.

use super::Alarms;
use crate::kinematics::TcpOffset;
use crate::metrics::CumulativeParts;
use crate::model::MountingDeltas;

/// What of a robot's twin outlives the process: the cumulative metrics and counters of its
/// epoch, the pose `seq` to go on from, the last gateway `seq` (so that samples lost while the
/// service was down show as a `gap`) and its alarms. Plain data: the caller chooses the file
/// format. The window, alignment and last values start afresh on restore.
#[derive(Debug, Clone, PartialEq)]
pub struct TwinRecord {
    /// Robot id.
    pub robot: String,
    /// The name of the arm its model describes (a record of another arm is foreign).
    pub arm: String,
    /// The metrics epoch.
    pub epoch: u64,
    /// Measured poses paired with the twin.
    pub paired: u64,
    /// Measured poses that could not be paired.
    pub unpaired: u64,
    /// Inputs rejected.
    pub rejected: u64,
    /// The `seq` of the next twin pose.
    pub next_pose_seq: u64,
    /// The last gateway `seq` accepted.
    pub last_gateway_seq: Option<u64>,
    /// Cumulative statistics.
    pub cumulative: CumulativeParts,
    /// Which alarms are active.
    pub alarms_active: Alarms,
    /// The model in use, when an applied calibration replaced the configured one: the epoch's
    /// deviations are of that model, so the restored twin goes on with it.
    pub applied: Option<AppliedModel>,
}

/// What an applied calibration changed in a robot's configured model.
#[derive(Debug, Clone, PartialEq)]
pub struct AppliedModel {
    /// The `calibration.conf` deltas to the arm's nominal table.
    pub deltas: MountingDeltas,
    /// The tool.
    pub tool: TcpOffset,
}

/// The calibration source name of a model rebuilt from a [`TwinRecord`].
pub(super) const APPLIED_SOURCE_NAME: &str = "applied calibration (restored)";

/// Why a [`TwinRecord`] was not restored.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RestoreError {
    /// The robot already has a twin (restoring is for a pipeline that has had no input).
    #[error("robot '{robot}' is already tracked")]
    AlreadyTracked {
        /// The robot.
        robot: String,
    },
    /// The record is of another arm than the robot's model.
    #[error(
        "robot '{robot}': the record is of arm '{recorded}', the robot's model is '{configured}'"
    )]
    Arm {
        /// The robot.
        robot: String,
        /// The record's arm.
        recorded: String,
        /// The robot's model's arm.
        configured: String,
    },
    /// The statistics cannot be the sums of any samples.
    #[error("robot '{robot}': the cumulative statistics are not valid sums")]
    Statistics {
        /// The robot.
        robot: String,
    },
    /// The applied calibration does not make a model of the robot's arm.
    #[error("robot '{robot}': the applied calibration does not fit its arm: {problem}")]
    Applied {
        /// The robot.
        robot: String,
        /// Why.
        problem: String,
    },
}
