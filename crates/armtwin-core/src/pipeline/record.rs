//! What of a robot's twin outlives the process ([`TwinRecord`]), why a record is refused, and
//! the twin's side of it: [`Twin::record`] writes a record, [`Twin::restored`] builds a twin
//! from one.
//!
//! Owns the record's plain data and its mapping to and from a twin. Must not choose a file
//! format: the caller serializes the record.

use std::sync::Arc;

use super::alarm::AlarmStates;
use super::twin::{DeviationStats, Twin};
use super::{Alarms, PipelineConfig, Robot};
use crate::kinematics::TcpOffset;
use crate::metrics::{CumulativeParts, CumulativeStats, HistoryRow, WindowWithHistory};
use crate::model::{CalibrationForm, MountingDeltas};

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
    /// The minutes of its history holding pairs, oldest first ([`crate::metrics::History::minute_rows`]); the
    /// seconds are not kept.
    pub history_minutes: Vec<HistoryRow>,
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
const APPLIED_SOURCE_NAME: &str = "applied calibration (restored)";

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
    /// The history's minutes cannot be those of any pairs.
    #[error("robot '{robot}': the history is not valid: {problem}")]
    History {
        /// The robot.
        robot: String,
        /// Why.
        problem: crate::metrics::MinutesError,
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

impl Twin {
    /// The twin of `robot` continued from `record`: counters, cumulative statistics, pose
    /// `seq`, gateway `seq` and alarms as recorded, with new results due (its metrics go out
    /// at the next periodic publication). Tells no sink ([`Twin::new`]).
    pub fn restored(
        robot: Robot,
        config: &PipelineConfig,
        record: &TwinRecord,
    ) -> Result<Self, RestoreError> {
        let configured = &robot.settings().model.arm().name;
        if *configured != record.arm {
            return Err(RestoreError::Arm {
                robot: robot.id().to_owned(),
                recorded: record.arm.clone(),
                configured: configured.clone(),
            });
        }
        let cumulative = CumulativeStats::from_parts(&record.cumulative).ok_or_else(|| {
            RestoreError::Statistics {
                robot: robot.id().to_owned(),
            }
        })?;
        let applied = match &record.applied {
            None => None,
            Some(applied) => {
                let model = robot
                    .settings()
                    .model
                    .with_deltas(applied.deltas, applied.tool, APPLIED_SOURCE_NAME)
                    .map_err(|e| RestoreError::Applied {
                        robot: robot.id().to_owned(),
                        problem: e.to_string(),
                    })?;
                Some(Arc::new(model))
            }
        };
        let mut twin = Self::new(robot, config);
        if let Some(model) = applied {
            twin.model = model;
        }
        twin.epoch = record.epoch;
        twin.paired = record.paired;
        twin.unpaired = record.unpaired;
        twin.rejected = record.rejected;
        twin.next_pose_seq = record.next_pose_seq;
        twin.last_gateway_seq = record.last_gateway_seq;
        if record.cumulative.n > 0 {
            let mut window =
                WindowWithHistory::new(twin.window_s, twin.window_slices, twin.history_s);
            window
                .restore_history_minutes(&record.history_minutes)
                .map_err(|problem| RestoreError::History {
                    robot: twin.robot.id().to_owned(),
                    problem,
                })?;
            twin.stats = Some(Box::new(DeviationStats { cumulative, window }));
        }
        twin.alarms = AlarmStates::restored(record.alarms_active);
        twin.dirty = true;
        Ok(twin)
    }
    /// What of it outlives the process.
    #[must_use]
    pub fn record(&self) -> TwinRecord {
        TwinRecord {
            robot: self.robot.id().to_owned(),
            arm: self.model.arm().name.clone(),
            epoch: self.epoch,
            paired: self.paired,
            unpaired: self.unpaired,
            rejected: self.rejected,
            next_pose_seq: self.next_pose_seq,
            last_gateway_seq: self.last_gateway_seq,
            cumulative: self.stats.as_ref().map_or_else(
                || CumulativeStats::new().to_parts(),
                |stats| stats.cumulative.to_parts(),
            ),
            alarms_active: self.alarms.active(),
            applied: self.applied_model(),
            history_minutes: self
                .stats
                .as_ref()
                .map(|stats| stats.window.history_minutes_record())
                .unwrap_or_default(),
        }
    }
    /// What an applied calibration changed in its configured model, if one was applied.
    fn applied_model(&self) -> Option<AppliedModel> {
        if Arc::ptr_eq(&self.model, &self.robot.settings().model) {
            return None;
        }
        let deltas = match self
            .model
            .calibration()
            .map(|calibration| &calibration.form)
        {
            Some(CalibrationForm::MountingDeltas(deltas)) => *deltas,
            // Applied models are identified as deltas: any other form is the configured one.
            Some(_) => return None,
            None => MountingDeltas::ZERO,
        };
        Some(AppliedModel {
            deltas,
            tool: *self.model.tool(),
        })
    }
}
