//! The pure core between "a decoded sample" and "a pose plus updated metrics", shared by every
//! mode: the Zenoh service, offline validation and replay all feed it the same way.
//!
//! Owns, per robot: the model, the joint/measured alignment, pose sequence numbers, deviation
//! statistics (cumulative and windowed), alarms, counters and the last values for the state
//! view. Results go to a [`Sink`]; the pipeline never awaits, never touches the network or the
//! filesystem, and never panics on input.
//!
//! A robot's id is resolved once per input: a [`RobotDirectory`] turns it into a [`Robot`]
//! handle (index, id, settings), and every per-sample method takes that handle. Twins live in a
//! `Vec` by [`RobotIndex`], each carrying its own [`Robot`], and sinks get the same index, so
//! nothing on the way from input to outputs hashes the id again. The directory never changes an
//! entry, so a caller may decode against a robot's settings before it locks the pipeline.
//!
//! Events ([`Event`]) carry numbers, causes and borrowed errors; their sentence is written only
//! by their `Display`, so an event a sink drops costs no formatting.
//!
//! Stamp rules (per robot, source time): joint stamps must increase strictly, and so must
//! measured stamps; a sample that goes back or repeats a stamp is rejected (`out_of_order`,
//! `duplicate_stamp`), because a twin cannot tell which of two readings at one instant is true.
//! A gateway `seq` that skips numbers raises a `gap` event (samples lost upstream); one that goes
//! back or repeats rejects the sample.
//!
//! Layout: this file holds the settings, the result types and [`Pipeline`] (the twins of many
//! robots, offline); `twin` the one stepping path ([`Twin`]), with `effort` its effort monitor's
//! glue; `alarm` the alarm thresholds and hold timers ([`Alarms`]); `record` what outlives the
//! process ([`TwinRecord`]) and a twin restored from it; `sink` the [`Sink`] trait and [`sinks`]
//! the ready-made ones; `directory` the robot ids; `event` the events.

mod alarm;
mod directory;
mod effort;
mod event;
mod record;
mod sink;
pub mod sinks;
mod twin;

use std::error::Error;
use std::sync::Arc;

use nalgebra::IsometryMatrix3;

pub use self::alarm::{AlarmChange, AlarmConfig, AlarmStates, Alarms};
pub use self::directory::{Robot, RobotDirectory, RobotGroup, RobotIndex, Untracked};
pub use self::event::{Event, EventDetail, EventKind, Reason, RejectCause};
pub use self::record::{AppliedModel, RestoreError, TwinRecord};
pub use self::sink::Sink;
pub use self::sinks::Discard;
pub use self::twin::Twin;
use crate::align::AlignConfig;
use crate::dynamics::monitor::{EffortConfig, EffortSummary};
use crate::kinematics::PoseReadout;
use crate::metrics::{DEFAULT_HISTORY_S, DEFAULT_WINDOW_SLICES, StatsSet};
use crate::model::RobotModel;
use crate::sample::{JointSample, JointState};
use crate::self_calibration::{PairReservoir, ReservoirConfig};

/// Another stream of measured poses for a robot (motion capture, a laser tracker, another
/// gateway), with the fixed transform from the sensor's frame to the robot's base frame.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorStream {
    /// The Zenoh key expression it arrives on.
    pub key_expr: String,
    /// `base_from_sensor`.
    pub base_from_sensor: IsometryMatrix3<f64>,
}

/// Everything configured for one robot.
#[derive(Debug, Clone)]
pub struct RobotSettings {
    /// Model, calibration, tool and output frame (shared between robots using the default).
    pub model: Arc<RobotModel>,
    /// Alarm thresholds.
    pub alarm: AlarmConfig,
    /// Extra measured-pose streams.
    pub sensors: Vec<SensorStream>,
    /// Keep a reservoir of the robot's pairs for self-calibration ([`crate::self_calibration`]).
    pub self_calibration: Option<ReservoirConfig>,
    /// Watch the robot's effort ([`crate::dynamics::monitor`]): its arm must have inertial
    /// parameters and five to seven joints.
    pub effort: Option<EffortConfig>,
}

/// Settings shared by every robot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PipelineConfig {
    /// Length of the metrics window (s of source time).
    pub window_s: f64,
    /// Time slices the metrics window is kept in ([`crate::metrics::SlicedWindow`]): its edge
    /// moves in steps of `window_s / window_slices`, and a robot's window holds this many slices
    /// whatever the rate.
    pub window_slices: usize,
    /// Seconds of per-second window history a robot keeps ([`crate::metrics::History`]); 0
    /// keeps none.
    pub history_s: usize,
    /// Time alignment limits.
    pub align: AlignConfig,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            window_s: 10.0,
            window_slices: DEFAULT_WINDOW_SLICES,
            history_s: DEFAULT_HISTORY_S,
            align: AlignConfig::default(),
        }
    }
}

/// Which stream a measured pose came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeasuredStream {
    /// `…/measured/<robot>` or the `measured` part of a joint message: the robot's base frame.
    Robot,
    /// The robot's configured sensor stream with this index.
    Sensor(usize),
}

/// A robot's metrics at one instant.
#[derive(Debug, Clone, PartialEq)]
pub struct MetricsReadout {
    /// Robot id.
    pub robot: String,
    /// Newest source time (s) seen for the robot.
    pub stamp_s: f64,
    /// Measured poses paired with the twin.
    pub paired: u64,
    /// Measured poses that could not be paired.
    pub unpaired: u64,
    /// Inputs rejected.
    pub rejected: u64,
    /// Since start or the last reset.
    pub cumulative: StatsSet,
    /// Over the last `window_s` seconds of source time.
    pub window: StatsSet,
    /// The window's length (s).
    pub window_s: f64,
    /// The metrics epoch: 0 from the start, one more each time the robot's model was replaced
    /// ([`Pipeline::replace_model`]); the counters and statistics cover this epoch only.
    pub epoch: u64,
    /// Its effort, when watched (boxed: most robots have none).
    pub effort: Option<Box<EffortSummary>>,
}

/// Why a robot's model was not replaced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ReplaceModelError {
    /// The robot has no twin yet.
    #[error("the robot is not tracked")]
    NotTracked,
    /// The model has another number of joints.
    #[error("the model has {got} joints, the robot {expected}")]
    JointCount {
        /// The robot's.
        expected: usize,
        /// The model's.
        got: usize,
    },
}

/// A robot's last values, for the state view.
#[derive(Debug, Clone)]
pub struct RobotState<'a> {
    /// Robot id.
    pub robot: &'a str,
    /// Its current model (model, calibration, tool, frame): the configured one, or the one that
    /// replaced it.
    pub model: &'a RobotModel,
    /// Last valid joint sample: stamp (s) and angles (rad).
    pub last_joints: Option<(f64, &'a [f64])>,
    /// The latest of each part of the joint state reported beside the angles (velocities,
    /// currents, temperatures, modes, payload), with the stamp of the last sample that had any.
    pub last_state: Option<(f64, &'a JointState)>,
    /// Last twin pose: stamp (s) and pose.
    pub last_twin_pose: Option<(f64, &'a PoseReadout)>,
    /// Last measured pose (in the output frame): stamp (s) and pose.
    pub last_measured: Option<(f64, &'a PoseReadout)>,
    /// Current metrics.
    pub metrics: MetricsReadout,
    /// Which alarms are active.
    pub alarms_active: Alarms,
}

/// The multi-robot twin core: one twin per robot that has had input, by [`RobotIndex`].
pub struct Pipeline {
    config: PipelineConfig,
    /// `None` until the robot's first input. Boxed: a configured robot that never sends costs a
    /// pointer, not a twin.
    twins: Vec<Option<Box<Twin>>>,
}

/// Rejects an input of a robot that may not be tracked (neither configured nor covered by a
/// default, or the fleet is full): one event (there is no twin to count it).
pub fn reject_untracked(
    robot: &str,
    key: &str,
    stamp_s: f64,
    why: Untracked,
    sink: &mut impl Sink,
) {
    let (cause, reason) = match why {
        Untracked::Unknown => (RejectCause::UnknownRobot, Reason::UnknownRobot),
        Untracked::Full { max_robots } => {
            (RejectCause::FleetFull, Reason::FleetFull { max_robots })
        }
        Untracked::GroupFull {
            max_robots,
            prefix_len,
        } => (
            RejectCause::FleetFull,
            Reason::GroupFull {
                max_robots,
                prefix_len,
            },
        ),
    };
    sink.event(&Event {
        robot,
        index: None,
        stamp_s,
        kind: EventKind::Rejected,
        key: Some(key),
        detail: EventDetail::Rejected { cause },
        reason,
    });
}

impl Pipeline {
    /// A pipeline with no robot tracked yet.
    #[must_use]
    pub fn new(config: PipelineConfig) -> Self {
        Self {
            config,
            twins: Vec::new(),
        }
    }

    /// The robots tracked so far, in index order.
    pub fn tracked(&self) -> impl Iterator<Item = &Robot> {
        self.twins.iter().flatten().map(|twin| twin.robot())
    }

    fn twin(&self, robot: RobotIndex) -> Option<&Twin> {
        self.twins.get(robot.get())?.as_deref()
    }

    fn twin_mut(&mut self, robot: RobotIndex) -> Option<&mut Twin> {
        self.twins.get_mut(robot.get())?.as_deref_mut()
    }

    /// `robot`'s twin, tracking it first (and telling the sink) if this is its first input: for
    /// a caller that steps the twin itself.
    pub fn track(&mut self, robot: &Robot, sink: &mut impl Sink) -> &mut Twin {
        let index = robot.index().get();
        if self.twins.len() <= index {
            self.twins.resize_with(index + 1, || None);
        }
        let slot = &mut self.twins[index];
        if let Some(twin) = slot {
            twin
        } else {
            sink.tracking(robot);
            slot.insert(Box::new(Twin::new(robot.clone(), &self.config)))
        }
    }

    /// Rejects an input of `robot` that could not be decoded (or was refused before reaching
    /// the pipeline): one event, one count; `error` says why.
    pub fn reject(
        &mut self,
        robot: &Robot,
        key: &str,
        stamp_s: f64,
        cause: RejectCause,
        error: &dyn Error,
        sink: &mut impl Sink,
    ) {
        self.track(robot, sink)
            .reject(key, stamp_s, cause, error, sink);
    }

    /// A decoded joint sample of `robot`, stamped `stamp_s` (the message's own stamp, else the
    /// transport's). Valid ones yield exactly one twin pose; an embedded measured pose pairs
    /// with it exactly. Source time moves on only once the input is accepted.
    pub fn joints(
        &mut self,
        robot: &Robot,
        key: &str,
        stamp_s: f64,
        sample: &JointSample,
        sink: &mut impl Sink,
    ) {
        self.track(robot, sink).joints(key, stamp_s, sample, sink);
    }

    /// A decoded measured pose of `robot` from `stream`, stamped `stamp_s`.
    pub fn measured(
        &mut self,
        robot: &Robot,
        key: &str,
        stream: MeasuredStream,
        stamp_s: f64,
        pose: &PoseReadout,
        sink: &mut impl Sink,
    ) {
        self.track(robot, sink)
            .measured(key, stream, stamp_s, pose, sink);
    }

    /// Robots with new results since their last metrics (the periodic publication while data
    /// flows sends theirs, with [`take_due_metrics`](Self::take_due_metrics)).
    #[must_use]
    pub fn robots_with_due_metrics(&self) -> Vec<RobotIndex> {
        self.twins
            .iter()
            .flatten()
            .filter(|twin| twin.is_due())
            .map(|twin| twin.robot().index())
            .collect()
    }

    /// `robot`'s metrics if it has new results since its last ones, which they then count as
    /// sent: for a caller that sends them itself (the service, outside its lock).
    pub fn take_due_metrics(&mut self, robot: RobotIndex) -> Option<MetricsReadout> {
        self.twin_mut(robot)?.take_due_metrics()
    }

    /// Resets `robot`'s statistics and counters; returns (and sends) the final metrics before
    /// the reset.
    pub fn reset(&mut self, robot: RobotIndex, sink: &mut impl Sink) -> Option<MetricsReadout> {
        Some(self.twin_mut(robot)?.reset(sink))
    }

    /// The model `robot`'s FK runs, if it is tracked.
    #[must_use]
    pub fn model(&self, robot: RobotIndex) -> Option<&Arc<RobotModel>> {
        self.twin(robot).map(Twin::model)
    }

    /// `robot`'s self-calibration reservoir, if it is tracked and keeps one.
    #[must_use]
    pub fn reservoir(&self, robot: RobotIndex) -> Option<&PairReservoir> {
        self.twin(robot)?.reservoir()
    }

    /// Replaces `robot`'s model (an applied calibration) and starts a new metrics epoch: the
    /// old epoch's final metrics are sent and returned, counters and statistics start afresh
    /// (deviations of two models must not mix), and an `epoch` event says why. A model of
    /// another joint count (a robot's own description) starts alignment afresh, unless the
    /// robot's effort monitor or self-calibration rides on its joints: refused then.
    pub fn replace_model(
        &mut self,
        robot: RobotIndex,
        model: Arc<RobotModel>,
        sink: &mut impl Sink,
    ) -> Result<MetricsReadout, ReplaceModelError> {
        self.twin_mut(robot)
            .ok_or(ReplaceModelError::NotTracked)?
            .replace_model(model, sink)
    }

    /// The state view of `robot`, if it is tracked.
    #[must_use]
    pub fn state(&self, robot: RobotIndex) -> Option<RobotState<'_>> {
        self.twin(robot).map(Twin::state)
    }

    /// What of every tracked robot's twin outlives the process, in index order.
    #[must_use]
    pub fn records(&self) -> Vec<TwinRecord> {
        self.twins
            .iter()
            .flatten()
            .map(|twin| twin.record())
            .collect()
    }

    /// Tracks `robot` (telling the sink) with its twin continued from `record`: counters,
    /// cumulative statistics, pose `seq`, gateway `seq` and alarms as recorded. Nothing is
    /// changed when the record is refused.
    pub fn restore(
        &mut self,
        robot: &Robot,
        record: &TwinRecord,
        sink: &mut impl Sink,
    ) -> Result<(), RestoreError> {
        if self.twin(robot.index()).is_some() {
            return Err(RestoreError::AlreadyTracked {
                robot: robot.id().to_owned(),
            });
        }
        let twin = Twin::restored(robot.clone(), &self.config, record)?;
        let index = robot.index().get();
        if self.twins.len() <= index {
            self.twins.resize_with(index + 1, || None);
        }
        sink.tracking(robot);
        self.twins[index] = Some(Box::new(twin));
        Ok(())
    }

    /// End of input: waiting measured poses become unpaired, and every robot's final metrics go
    /// out.
    pub fn finish(&mut self, sink: &mut impl Sink) {
        for twin in self.twins.iter_mut().flatten() {
            twin.finish(sink);
        }
    }
}
