//! One robot's [`Twin`]: everything the core keeps for a robot, stepped by that robot's inputs
//! alone, and the stepping itself (validation, stamp order, alignment, pairing, statistics,
//! alarms, events).
//!
//! Owns the one stepping path every mode runs: the service steps a robot's twin under that
//! robot's lock, [`Pipeline`](super::Pipeline) steps it offline; neither adds logic of its own.
//! Must not decode bytes, await, or touch the network, the filesystem or a clock: results go to
//! a [`Sink`], time comes in as source stamps.
//!
//! Two parts of the twin live beside it: `effort` (its effort monitor, stepped with each joint
//! sample) and `record` (what of it outlives the process, and a twin restored from that). The
//! fields they use are `pub(super)`; the rest of the pipeline reaches a twin by its methods.

use std::error::Error;
use std::ops::RangeInclusive;
use std::sync::Arc;

use nalgebra::{IsometryMatrix3, Matrix3, Rotation3, Vector3};

use super::alarm::AlarmStates;
use super::{
    Event, EventDetail, EventKind, MeasuredStream, MetricsReadout, PipelineConfig, Reason,
    RejectCause, ReplaceModelError, Robot, RobotState, Sink,
};
use crate::align::{self, Aligner, Bracket, Pending, UnpairedReason};
use crate::dynamics::monitor::EffortMonitor;
use crate::kinematics::{KinematicsError, OutputFrame, PoseReadout, TcpOffset};
use crate::metrics::{
    CumulativeStats, Deviation, History, HistoryRow, MINUTE_S, SECONDS_TIER_S, SecondsArchive,
    WindowWithHistory,
};
use crate::model::{ModelError, RobotModel};
use crate::orientation;
use crate::sample::{JointSample, JointState};
use crate::self_calibration::PairReservoir;

/// Largest deviation (m or rad) taken as a comparison (no arm reaches 100 m); beyond it a measured
/// pose is refused as not belonging to the robot, which also keeps the statistics finite and
/// exact.
const MAX_DEVIATION: f64 = 100.0;

/// Why a joint sample was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Refusal {
    /// Its joints are invalid (count, finiteness, limits).
    Joints,
    /// Its stamp does not follow the previous sample's.
    Order,
}

/// A measured pose waiting in the aligner.
#[derive(Debug, Clone)]
struct Waiting {
    pose: PoseReadout,
    key: String,
}

/// A robot's deviation statistics.
pub(super) struct DeviationStats {
    pub(super) cumulative: CumulativeStats,
    /// The window, and the history of its seconds.
    pub(super) window: WindowWithHistory,
}

/// One robot's twin: everything the pipeline keeps for it, stepped by that robot's inputs alone.
///
/// A [`Pipeline`] keeps one per tracked robot; a caller that keeps each robot's twin under a
/// lock of its own (the service, so that robots on different links never wait on each other)
/// steps a `Twin` directly. Both run the same code: a pipeline's per-robot methods only find
/// the twin and delegate. Unlike the pipeline, a twin does not announce itself: whoever
/// creates one calls [`Sink::tracking`].
pub struct Twin {
    /// Its index, id and settings (shared with the directory).
    pub(super) robot: Robot,
    /// The model its FK runs: the configured one until [`Twin::replace_model`].
    pub(super) model: Arc<RobotModel>,
    /// Pairs kept for self-calibration, when the robot's settings ask for it.
    reservoir: Option<Box<PairReservoir>>,
    pub(super) epoch: u64,
    aligner: Aligner<Waiting>,
    /// Created by the first paired measurement (the window's slices are most of a twin's
    /// memory): a robot that only streams joints never needs them.
    pub(super) stats: Option<Box<DeviationStats>>,
    /// The metrics window's length (s) and slices, and the seconds of its history.
    pub(super) window_s: f64,
    pub(super) window_slices: usize,
    pub(super) history_s: usize,
    /// Where its history will keep the seconds of closed minutes, until its statistics are made
    /// (in memory when none is given).
    seconds_archive: Option<Box<dyn SecondsArchive>>,
    pub(super) paired: u64,
    pub(super) unpaired: u64,
    pub(super) rejected: u64,
    pub(super) next_pose_seq: u64,
    pub(super) last_gateway_seq: Option<u64>,
    last_joint_s: Option<f64>,
    last_joints: Vec<f64>,
    /// The latest of each part of the joint state sources sent beside the angles, and the stamp
    /// of the last joint sample that brought any.
    last_state: Option<(f64, JointState)>,
    last_pose: Option<(f64, PoseReadout)>,
    /// The metrics epoch whose model computed `last_pose`.
    last_pose_epoch: u64,
    /// Last accepted measured stamp per stream: index 0 the robot's own (controller) stream,
    /// `i + 1` sensor `i`.
    last_measured_s: Vec<Option<f64>>,
    last_measured: Option<(f64, PoseReadout)>,
    newest_s: f64,
    pub(super) alarms: AlarmStates,
    /// Its effort monitor, when the robot's settings ask for one.
    /// Its monitor boxes its arm's state itself: a robot without one pays for the `Option` only.
    pub(super) effort: Option<EffortMonitor>,
    /// New results since the last periodic metrics.
    pub(super) dirty: bool,
    scratch_q: Vec<f64>,
}

impl Twin {
    /// The twin of `robot` before any input, with its configured model. Tells no sink: the
    /// caller announces the robot ([`Sink::tracking`]).
    #[must_use]
    pub fn new(robot: Robot, config: &PipelineConfig) -> Self {
        let joint_count = robot.settings().model.joint_count();
        Self {
            model: Arc::clone(&robot.settings().model),
            reservoir: robot
                .settings()
                .self_calibration
                .map(|config| Box::new(PairReservoir::new(config))),
            epoch: 0,
            aligner: Aligner::new(config.align),
            stats: None,
            window_s: config.window_s,
            window_slices: config.window_slices,
            history_s: config.history_s,
            seconds_archive: None,
            paired: 0,
            unpaired: 0,
            rejected: 0,
            next_pose_seq: 0,
            last_gateway_seq: None,
            last_joint_s: None,
            last_joints: Vec::with_capacity(joint_count),
            last_state: None,
            last_pose: None,
            last_pose_epoch: 0,
            last_measured_s: Vec::new(),
            last_measured: None,
            newest_s: f64::NEG_INFINITY,
            alarms: AlarmStates::default(),
            effort: effort_monitor(&robot, config),
            dirty: false,
            scratch_q: Vec::with_capacity(joint_count),
            robot,
        }
    }

    /// Its robot.
    #[must_use]
    pub fn robot(&self) -> &Robot {
        &self.robot
    }

    /// Rejects an input that could not be decoded (or was refused before reaching the twin):
    /// one event, one count; `error` says why.
    pub fn reject(
        &mut self,
        key: &str,
        stamp_s: f64,
        cause: RejectCause,
        error: &dyn Error,
        sink: &mut impl Sink,
    ) {
        self.count_rejection(key, stamp_s, cause, Reason::Error(error), sink);
    }

    /// A decoded joint sample, stamped `stamp_s` ([`Pipeline::joints`]).
    pub fn joints(&mut self, key: &str, stamp_s: f64, sample: &JointSample, sink: &mut impl Sink) {
        self.dirty = true;
        match self.accept_joints(key, stamp_s, sample, sink) {
            Ok(pose) => {
                // Older waiting poses first, so statistics and alarms see stamps in order.
                self.pair_ready(sink);
                if let Some(measured) = &sample.measured {
                    let measured = self.to_output_frame(measured, MeasuredStream::Robot);
                    if self.accept_measured_stamp(key, MeasuredStream::Robot, stamp_s, sink)
                        && self.pair(key, stamp_s, &pose, measured, sink)
                        && let Some(reservoir) = &mut self.reservoir
                    {
                        reservoir.offer(stamp_s, &sample.q_rad, &measured);
                    }
                }
            }
            Err(Refusal::Order) => {
                // Resent or out of order: its measured part shares the stamp and is not counted
                // a second time.
            }
            Err(Refusal::Joints) => {
                // The joints were refused; a measured pose that came with them is still valid
                // input and goes through the aligner like any other.
                if let Some(measured) = &sample.measured {
                    let measured = self.to_output_frame(measured, MeasuredStream::Robot);
                    self.measured_in_frame(key, MeasuredStream::Robot, stamp_s, measured, sink);
                }
            }
        }
    }

    /// A decoded measured pose from `stream`, stamped `stamp_s`.
    pub fn measured(
        &mut self,
        key: &str,
        stream: MeasuredStream,
        stamp_s: f64,
        pose: &PoseReadout,
        sink: &mut impl Sink,
    ) {
        self.dirty = true;
        let pose = self.to_output_frame(pose, stream);
        self.measured_in_frame(key, stream, stamp_s, pose, sink);
    }

    /// Whether it has new results since its last metrics.
    #[must_use]
    pub fn is_due(&self) -> bool {
        self.dirty
    }

    /// Its metrics if it has new results since its last ones, which they then count as sent
    /// ([`Pipeline::take_due_metrics`]).
    pub fn take_due_metrics(&mut self) -> Option<MetricsReadout> {
        if !self.dirty {
            return None;
        }
        self.dirty = false;
        Some(self.metrics_readout())
    }

    /// Resets its statistics and counters; returns (and sends) the final metrics before the
    /// reset.
    pub fn reset(&mut self, sink: &mut impl Sink) -> MetricsReadout {
        let last = self.metrics_readout();
        self.restart_statistics();
        sink.metrics(&self.robot, &last);
        last
    }

    /// The model its FK runs.
    #[must_use]
    pub fn model(&self) -> &Arc<RobotModel> {
        &self.model
    }

    /// Its self-calibration reservoir, if it keeps one.
    #[must_use]
    pub fn reservoir(&self) -> Option<&PairReservoir> {
        self.reservoir.as_deref()
    }

    /// Replaces its model and starts a new metrics epoch ([`Pipeline::replace_model`]).
    pub fn replace_model(
        &mut self,
        model: Arc<RobotModel>,
        sink: &mut impl Sink,
    ) -> Result<MetricsReadout, ReplaceModelError> {
        let source = model
            .calibration()
            .map_or("the nominal model", |c| c.source_name.as_str())
            .to_owned();
        self.replace(model, Reason::ModelReplaced { source: &source }, sink)
    }

    /// Replaces its model's tool by `tool`, given by `source` (`the controller`), and starts a
    /// new metrics epoch: deviations from two TCPs never mix. Nothing changes, and `None` comes
    /// back, when the model already has that tool.
    pub fn replace_tool(
        &mut self,
        tool: TcpOffset,
        source: &str,
        sink: &mut impl Sink,
    ) -> Result<Option<MetricsReadout>, ModelError> {
        if *self.model.tool() == tool {
            return Ok(None);
        }
        let model = Arc::new(self.model.with_tool(tool)?);
        let reason = Reason::ToolReplaced {
            source,
            tool: tool.to_ur_pose(),
        };
        // The same arm: its joint count cannot differ.
        Ok(self.replace(model, reason, sink).ok())
    }

    fn replace(
        &mut self,
        model: Arc<RobotModel>,
        reason: Reason<'_>,
        sink: &mut impl Sink,
    ) -> Result<MetricsReadout, ReplaceModelError> {
        let expected = self.model.joint_count();
        let new_count = model.joint_count() != expected;
        // The effort monitor and the self-calibration are built for the arm's joints.
        if new_count && (self.effort.is_some() || self.reservoir.is_some()) {
            return Err(ReplaceModelError::JointCount {
                expected,
                got: model.joint_count(),
            });
        }
        if new_count {
            // The joints kept for alignment are of the other count: measured poses waiting
            // for them end unpaired, in the epoch they came in.
            self.restart_alignment(sink);
            self.last_joint_s = None;
            self.last_joints.clear();
            self.last_state = None;
        }
        let last = self.metrics_readout();
        sink.metrics(&self.robot, &last);
        self.restart_statistics();
        self.robot.set_joint_count(model.joint_count());
        self.model = model;
        self.epoch += 1;
        self.dirty = true;
        let detail = EventDetail::Epoch { epoch: self.epoch };
        let event = self.event(last.stamp_s, EventKind::Epoch, None, detail, reason);
        sink.event(&event);
        Ok(last)
    }

    /// Its state view.
    #[must_use]
    pub fn state(&self) -> RobotState<'_> {
        RobotState {
            robot: self.robot.id(),
            model: &self.model,
            last_joints: self
                .last_joint_s
                .map(|stamp_s| (stamp_s, self.last_joints.as_slice())),
            last_state: self.last_state.as_ref().map(|(s, state)| (*s, state)),
            last_twin_pose: self.last_pose.as_ref().map(|(s, p)| (*s, p)),
            last_measured: self.last_measured.as_ref().map(|(s, p)| (*s, p)),
            metrics: self.metrics_readout(),
            alarms_active: self.alarms.active(),
        }
    }

    /// Its newest source time (s): the newest stamp of its accepted samples; `None` before any.
    #[must_use]
    pub fn newest_s(&self) -> Option<f64> {
        self.newest_s.is_finite().then_some(self.newest_s)
    }

    /// The same twin, its history keeping the seconds of closed minutes in `archive` (which
    /// must keep [`crate::metrics::History::archive_minutes`] of them) instead of in memory.
    #[must_use]
    pub fn with_seconds_archive(mut self, archive: Box<dyn SecondsArchive>) -> Self {
        match &mut self.stats {
            // Restored: its history holds no second yet.
            Some(stats) => stats.window.set_archive(archive),
            None => self.seconds_archive = Some(archive),
        }
        self
    }

    /// The seconds of history it keeps ([`PipelineConfig::history_s`]).
    #[must_use]
    pub fn history_s(&self) -> usize {
        self.history_s
    }

    /// Its history and the second still open (that of its window's newest slice), once it has
    /// both.
    fn history_and_open_second(&self) -> Option<(&History, i64)> {
        let window = &self.stats.as_ref()?.window;
        Some((window.history()?, window.open_second()?))
    }

    /// The completed seconds of its window's history within `seconds` (source time), oldest
    /// first: those before the second its window's newest slice lies in. Empty when no history
    /// is kept or before the first pair.
    #[must_use]
    pub fn history(&self, seconds: RangeInclusive<i64>) -> Vec<HistoryRow> {
        let Some((history, open)) = self.history_and_open_second() else {
            return Vec::new();
        };
        let last = (*seconds.end()).min(open.saturating_sub(1));
        history.rows(*seconds.start()..=last).collect()
    }

    /// The completed minutes of its window's history starting within `seconds` (source time),
    /// oldest first: those that end by the second its window's newest slice lies in. Empty when
    /// no history is kept or before the first pair.
    #[must_use]
    pub fn history_minutes(&self, seconds: RangeInclusive<i64>) -> Vec<HistoryRow> {
        let Some((history, open)) = self.history_and_open_second() else {
            return Vec::new();
        };
        let last = (*seconds.end()).min(open.saturating_sub(MINUTE_S));
        history.minute_rows(*seconds.start()..=last).collect()
    }

    /// The seconds its history keeps one by one (the newest; the rest by the minute).
    #[must_use]
    pub fn history_exact_s(&self) -> usize {
        self.history_s.min(SECONDS_TIER_S)
    }

    /// End of input: waiting measured poses become unpaired, and its final metrics go out.
    pub fn finish(&mut self, sink: &mut impl Sink) {
        for (pending, reason) in self.aligner.finish() {
            self.unpaired_event(&pending, reason, sink);
        }
        self.dirty = false;
        sink.metrics(&self.robot, &self.metrics_readout());
    }

    /// An event of this robot.
    pub(super) fn event<'a>(
        &'a self,
        stamp_s: f64,
        kind: EventKind,
        key: Option<&'a str>,
        detail: EventDetail,
        reason: Reason<'a>,
    ) -> Event<'a> {
        Event {
            robot: self.robot.id(),
            index: Some(self.robot.index()),
            stamp_s,
            kind,
            key,
            detail,
            reason,
        }
    }

    /// Counters and statistics start afresh (a reset, a new epoch). Alarms stay as they are:
    /// clearing one silently would leave dashboards waiting for a `recovered` that never comes.
    fn restart_statistics(&mut self) {
        if let Some(stats) = &mut self.stats {
            stats.cumulative.reset();
            stats.window.reset_window();
        }
        if let Some(monitor) = &mut self.effort {
            monitor.reset_statistics();
        }
        self.paired = 0;
        self.unpaired = 0;
        self.rejected = 0;
    }

    /// One rejection: an event and a count.
    fn count_rejection(
        &mut self,
        key: &str,
        stamp_s: f64,
        cause: RejectCause,
        reason: Reason<'_>,
        sink: &mut impl Sink,
    ) {
        self.rejected += 1;
        self.dirty = true;
        let detail = EventDetail::Rejected { cause };
        sink.event(&self.event(stamp_s, EventKind::Rejected, Some(key), detail, reason));
    }

    /// Validates and evaluates a joint sample: its twin pose is sent and returned.
    fn accept_joints(
        &mut self,
        key: &str,
        stamp_s: f64,
        sample: &JointSample,
        sink: &mut impl Sink,
    ) -> Result<PoseReadout, Refusal> {
        if let Err(error) = self.model.check_joints(&sample.q_rad) {
            let cause = match error {
                KinematicsError::JointCount { .. } => RejectCause::JointCount,
                KinematicsError::NonFinite { .. } => RejectCause::NonFinite,
                KinematicsError::OutOfLimits { .. } => RejectCause::JointLimits,
            };
            self.count_rejection(key, stamp_s, cause, Reason::Error(&error), sink);
            return Err(Refusal::Joints);
        }
        self.restart_if_clock_went_back(key, "joint", stamp_s, self.last_joint_s, sink);
        if let Some((cause, reason)) = stamp_problem("joint", stamp_s, self.last_joint_s) {
            self.count_rejection(key, stamp_s, cause, reason, sink);
            return Err(Refusal::Order);
        }
        if let Some(seq) = sample.seq {
            if let Some(last) = self.last_gateway_seq {
                if seq <= last {
                    // The stamp moved on (an older or equal one was refused above), so this is
                    // not a resend but a gateway that counts afresh: refusing it would lock the
                    // robot out until the new count passes the old one.
                    let detail = EventDetail::SeqRestart {
                        from_seq: last,
                        to_seq: seq,
                    };
                    let event = self.event(
                        stamp_s,
                        EventKind::Restart,
                        Some(key),
                        detail,
                        Reason::SeqRestart,
                    );
                    sink.event(&event);
                } else if seq != last + 1 {
                    let detail = EventDetail::SeqGap {
                        expected: last + 1,
                        got: seq,
                    };
                    let event =
                        self.event(stamp_s, EventKind::Gap, Some(key), detail, Reason::SeqGap);
                    sink.event(&event);
                }
            }
            self.last_gateway_seq = Some(seq);
        }
        let max_gap_s = self.aligner.config().max_gap_s;
        if let Some(last_s) = self.last_joint_s
            && stamp_s - last_s > max_gap_s
        {
            let gap_s = stamp_s - last_s;
            let detail = EventDetail::StampGap { gap_s };
            let reason = Reason::StampGap { max_gap_s };
            sink.event(&self.event(stamp_s, EventKind::Gap, Some(key), detail, reason));
        }
        self.advance_time(stamp_s);
        let pose = self.model.chain().pose_unchecked(&sample.q_rad).readout();
        let seq = self.next_pose_seq;
        self.next_pose_seq += 1;
        sink.pose(&self.robot, stamp_s, seq, self.model.frame(), &pose);
        sink.joints(&self.robot, stamp_s, sample, &pose);
        self.aligner.push_joints(stamp_s, &sample.q_rad);
        self.last_joint_s = Some(stamp_s);
        self.last_joints.clear();
        self.last_joints.extend_from_slice(&sample.q_rad);
        if let Some(state) = sample.state.as_ref().filter(|state| !state.is_empty()) {
            match &mut self.last_state {
                Some((last_s, last)) => {
                    *last_s = stamp_s;
                    last.update_from(state);
                }
                None => self.last_state = Some((stamp_s, JointState::clone(state))),
            }
        }
        self.last_pose = Some((stamp_s, pose));
        self.last_pose_epoch = self.epoch;
        self.step_effort(key, stamp_s, sample, sink);
        Ok(pose)
    }

    /// Measured poses waiting in the aligner end unpaired, and alignment starts afresh.
    fn restart_alignment(&mut self, sink: &mut impl Sink) {
        let config = *self.aligner.config();
        for (pending, reason) in self.aligner.finish() {
            self.unpaired_event(&pending, reason, sink);
        }
        self.aligner = Aligner::new(config);
    }

    /// Measured stamps must increase strictly; rejects (and returns false) otherwise.
    /// A stamp more than `restart_s` behind its stream's last one means the gateway restarted
    /// its clock: waiting measured poses end unpaired, and alignment, stamp order and the metrics
    /// window start afresh (cumulative metrics and counters continue), with a `restart` event.
    fn restart_if_clock_went_back(
        &mut self,
        key: &str,
        stream: &'static str,
        stamp_s: f64,
        last_s: Option<f64>,
        sink: &mut impl Sink,
    ) {
        let config = *self.aligner.config();
        let Some(last_s) = last_s.filter(|last_s| stamp_s < last_s - config.restart_s) else {
            return;
        };
        self.restart_alignment(sink);
        if let Some(stats) = &mut self.stats {
            stats.window.restart();
        }
        if let Some(monitor) = &mut self.effort {
            monitor.restart_clock();
        }
        self.last_joint_s = None;
        self.last_measured_s.clear();
        self.alarms.stop_hold_timers();
        self.last_gateway_seq = None;
        self.newest_s = stamp_s;
        let detail = EventDetail::Restart {
            from_s: last_s,
            to_s: stamp_s,
        };
        let reason = Reason::Restart {
            stream,
            restart_s: config.restart_s,
        };
        sink.event(&self.event(stamp_s, EventKind::Restart, Some(key), detail, reason));
    }

    /// Measured stamps must increase strictly within each stream; rejects (and returns false)
    /// otherwise.
    fn accept_measured_stamp(
        &mut self,
        key: &str,
        stream: MeasuredStream,
        stamp_s: f64,
        sink: &mut impl Sink,
    ) -> bool {
        let slot = match stream {
            MeasuredStream::Robot => 0,
            MeasuredStream::Sensor(index) => index + 1,
        };
        let last_s = self.last_measured_s.get(slot).copied().flatten();
        self.restart_if_clock_went_back(key, "measured", stamp_s, last_s, sink);
        let last_s = self.last_measured_s.get(slot).copied().flatten();
        if let Some((cause, reason)) = stamp_problem("measured", stamp_s, last_s) {
            self.count_rejection(key, stamp_s, cause, reason, sink);
            return false;
        }
        if self.last_measured_s.len() <= slot {
            // Exact: most robots have one stream, and a `Vec` would otherwise start at four.
            self.last_measured_s
                .reserve_exact(slot + 1 - self.last_measured_s.len());
            self.last_measured_s.resize(slot + 1, None);
        }
        self.last_measured_s[slot] = Some(stamp_s);
        self.advance_time(stamp_s);
        true
    }

    /// Source time moved on to `stamp_s` (an accepted sample): the metrics' time and window
    /// follow, so a window whose pairs stopped empties as time goes on.
    fn advance_time(&mut self, stamp_s: f64) {
        if stamp_s > self.newest_s {
            self.newest_s = stamp_s;
            if let Some(stats) = &mut self.stats {
                stats.window.advance_to(stamp_s);
            }
        }
    }

    /// A measured pose already in the output frame.
    fn measured_in_frame(
        &mut self,
        key: &str,
        stream: MeasuredStream,
        stamp_s: f64,
        pose: PoseReadout,
        sink: &mut impl Sink,
    ) {
        if !self.accept_measured_stamp(key, stream, stamp_s, sink) {
            return;
        }
        self.resolve(key, stamp_s, pose, sink);
    }

    /// Pairs a measured pose through the aligner, or queues it, or reports it unpaired.
    fn resolve(&mut self, key: &str, stamp_s: f64, pose: PoseReadout, sink: &mut impl Sink) {
        // The joint angles at the measured stamp go to `scratch_q`, where the pair's
        // self-calibration sample is taken from.
        match self.aligner.bracket(stamp_s) {
            Bracket::Exact(q_rad) => {
                self.scratch_q.clear();
                self.scratch_q.extend_from_slice(q_rad);
            }
            Bracket::Between { q0, q1, fraction } => {
                align::interpolate(q0, q1, fraction, &mut self.scratch_q);
            }
            Bracket::Later => {
                let waiting = Waiting {
                    pose,
                    key: key.to_owned(),
                };
                for (pending, reason) in self.aligner.wait(stamp_s, waiting) {
                    self.unpaired_event(&pending, reason, sink);
                }
                return;
            }
            Bracket::Unpaired(reason) => {
                let pending = Pending {
                    stamp_s,
                    item: Waiting {
                        pose,
                        key: key.to_owned(),
                    },
                };
                self.unpaired_event(&pending, reason, sink);
                return;
            }
        }
        // The newest joint sample's pose when the measured stamp is its own (the common case: a
        // joint message, then its measured pose), else recomputed rather than kept for every
        // sample of history: the same pure function of the same angles, so the same pose.
        let twin_pose = match self.last_pose {
            Some((joint_s, pose))
                if joint_s.to_bits() == stamp_s.to_bits() && self.last_pose_epoch == self.epoch =>
            {
                pose
            }
            _ => self.model.chain().pose_unchecked(&self.scratch_q).readout(),
        };
        if self.pair(key, stamp_s, &twin_pose, pose, sink)
            && let Some(reservoir) = &mut self.reservoir
        {
            reservoir.offer(stamp_s, &self.scratch_q, &pose);
        }
    }

    /// Pairs the measured poses that the newest joint sample now brackets.
    fn pair_ready(&mut self, sink: &mut impl Sink) {
        for pending in self.aligner.take_ready() {
            let Pending { stamp_s, item } = pending;
            self.resolve(&item.key, stamp_s, item.pose, sink);
        }
    }

    fn unpaired_event(
        &mut self,
        pending: &Pending<Waiting>,
        reason: UnpairedReason,
        sink: &mut impl Sink,
    ) {
        self.unpaired += 1;
        self.dirty = true;
        let detail = EventDetail::Unpaired {
            cause: reason.kind(),
            measured_s: pending.stamp_s,
        };
        let reason = Reason::Unpaired {
            reason,
            align: *self.aligner.config(),
        };
        let key = Some(pending.item.key.as_str());
        sink.event(&self.event(pending.stamp_s, EventKind::Unpaired, key, detail, reason));
    }

    /// Compares a measured pose with the twin's at its stamp; false if it was refused as too
    /// far from the twin to be this robot's.
    fn pair(
        &mut self,
        key: &str,
        stamp_s: f64,
        twin_pose: &PoseReadout,
        measured: PoseReadout,
        sink: &mut impl Sink,
    ) -> bool {
        let deviation = Deviation::between(twin_pose, &measured);
        let magnitudes = deviation.magnitudes();
        if !magnitudes
            .iter()
            .all(|v| v.is_finite() && *v <= MAX_DEVIATION)
        {
            let reason = Reason::OutOfRange {
                position_m: measured.position_m,
                distance_m: deviation.position_m,
            };
            self.count_rejection(key, stamp_s, RejectCause::OutOfRange, reason, sink);
            return false;
        }
        sink.deviation(&self.robot, stamp_s, &measured, &deviation);
        let stats = self.stats.get_or_insert_with(|| {
            let mut window = WindowWithHistory::with_archive(
                self.window_s,
                self.window_slices,
                self.history_s,
                self.seconds_archive.take(),
            );
            // As if it had followed source time all along.
            window.advance_to(self.newest_s);
            Box::new(DeviationStats {
                cumulative: CumulativeStats::new(),
                window,
            })
        });
        stats.cumulative.add(&magnitudes);
        stats.window.add(stamp_s, &magnitudes);
        self.paired += 1;
        self.last_measured = Some((stamp_s, measured));
        let alarm = self.robot.settings().alarm;
        let changes = self.alarms.update(&alarm, stamp_s, &deviation);
        for change in changes.into_iter().flatten() {
            let kind = if change.active {
                EventKind::Alarm
            } else {
                EventKind::Recovered
            };
            let detail = EventDetail::Alarm {
                metric: change.metric.as_str(),
                value: change.value,
                threshold: change.threshold,
            };
            let reason = Reason::Alarm {
                unit: change.unit,
                hold_s: alarm.hold_s,
            };
            sink.event(&self.event(stamp_s, kind, None, detail, reason));
        }
        true
    }

    /// A measured pose from `stream` in the model's output frame.
    fn to_output_frame(&self, pose: &PoseReadout, stream: MeasuredStream) -> PoseReadout {
        let frame = self.model.frame();
        let sensor = match stream {
            MeasuredStream::Robot => None,
            MeasuredStream::Sensor(index) => self
                .robot
                .settings()
                .sensors
                .get(index)
                .map(|sensor| sensor.base_from_sensor),
        };
        if sensor.is_none() && frame == OutputFrame::Base {
            return *pose;
        }
        let frame_from_measured =
            frame.frame_from_base() * sensor.unwrap_or_else(IsometryMatrix3::identity);
        transform(&frame_from_measured, pose)
    }

    fn metrics_readout(&self) -> MetricsReadout {
        MetricsReadout {
            robot: self.robot.id().to_owned(),
            stamp_s: if self.newest_s.is_finite() {
                self.newest_s
            } else {
                0.0
            },
            paired: self.paired,
            unpaired: self.unpaired,
            rejected: self.rejected,
            cumulative: self
                .stats
                .as_ref()
                .map(|stats| stats.cumulative.readout())
                .unwrap_or_default(),
            window: self
                .stats
                .as_ref()
                .map(|stats| stats.window.readout())
                .unwrap_or_default(),
            window_s: self.window_s,
            epoch: self.epoch,
            effort: self.effort().map(Box::new),
        }
    }
}

/// Why `stamp_s` cannot follow `last_s` in a `stream` (stamps must be finite and increase
/// strictly), as a rejection cause and what its sentence says.
fn stamp_problem(
    stream: &'static str,
    stamp_s: f64,
    last_s: Option<f64>,
) -> Option<(RejectCause, Reason<'static>)> {
    if !stamp_s.is_finite() {
        return Some((RejectCause::NonFinite, Reason::StampNotFinite { stream }));
    }
    let last_s = last_s.filter(|last_s| stamp_s <= *last_s)?;
    let cause = if stamp_s < last_s {
        RejectCause::OutOfOrder
    } else {
        RejectCause::DuplicateStamp
    };
    Some((cause, Reason::StampOrder { stream, last_s }))
}

/// `target_from_source · pose`.
fn transform(target_from_source: &IsometryMatrix3<f64>, pose: &PoseReadout) -> PoseReadout {
    let position = target_from_source * nalgebra::Point3::from(Vector3::from(pose.position_m));
    let rotation: Matrix3<f64> = target_from_source.rotation.matrix()
        * orientation::matrix_from_quaternion(&pose.quaternion());
    let quaternion =
        orientation::quaternion_from_matrix(Rotation3::from_matrix_unchecked(rotation).matrix());
    PoseReadout::from_position_quaternion(position.coords.into(), &quaternion)
}

/// The effort monitor `robot`'s settings ask for. The configuration checked the arm when it was
/// loaded; an arm that still cannot be watched (a model replaced by one of another size) is
/// watched by none.
fn effort_monitor(robot: &Robot, config: &PipelineConfig) -> Option<EffortMonitor> {
    let effort = robot.settings().effort.as_ref()?;
    EffortMonitor::new(robot.settings().model.arm(), effort, config.window_s).ok()
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use super::*;
    use crate::kinematics::TcpOffset;
    use crate::model::MountingDeltas;
    use crate::pipeline::sinks::{Discard, Record};
    use crate::pipeline::{
        AlarmConfig, AppliedModel, Pipeline, RestoreError, RobotDirectory, RobotSettings,
    };
    use crate::sample::JointAngles;

    /// One input of a test run, given to a pipeline or to a twin alone.
    enum Input {
        Joints(f64, JointSample),
        Measured(f64, PoseReadout),
        Undecodable(f64),
        DueMetrics,
    }

    /// Joints, some with a measured pose 2 mm off (paired, alarming), repeated stamps, measured
    /// poses that wait for the next joints, decoding failures and periodic metrics: every path
    /// a twin takes.
    fn mixed_inputs(model: &RobotModel) -> Vec<Input> {
        let q_rad = vec![0.1, -1.0, 1.0, -1.0, 1.0, 0.5];
        let mut off = model.pose(&q_rad).expect("valid").readout();
        off.position_m[1] += 0.002;
        let mut inputs = Vec::new();
        for i in 0..40_u32 {
            let stamp_s = f64::from(i) * 0.01;
            let joints = JointSample {
                stamp_s: None,
                seq: Some(u64::from(i)),
                q_rad: JointAngles::from_slice(&q_rad),
                measured: (i % 3 == 0).then_some(off),
                state: None,
            };
            if i % 7 == 0 {
                inputs.push(Input::Joints(stamp_s, joints.clone()));
            }
            inputs.push(Input::Joints(stamp_s, joints));
            if i % 5 == 0 {
                inputs.push(Input::Measured(stamp_s + 0.005, off));
            }
            if i % 11 == 0 {
                inputs.push(Input::Undecodable(stamp_s));
            }
            if i % 10 == 9 {
                inputs.push(Input::DueMetrics);
            }
        }
        inputs
    }

    /// A nominal UR10e and robot `r1` of a directory that gives it `alarm`.
    fn ur10e_robot(alarm: AlarmConfig) -> (Arc<RobotModel>, Robot) {
        let model = Arc::new(RobotModel::nominal("ur10e").expect("catalog"));
        let settings = RobotSettings {
            model: Arc::clone(&model),
            alarm,
            sensors: Vec::new(),
            self_calibration: None,
            effort: None,
        };
        let mut robots = RobotDirectory::new(Some(settings), HashMap::new());
        let r1 = robots.admit("r1").expect("default settings").clone();
        (model, r1)
    }

    #[test]
    fn a_twin_stepped_alone_gives_what_the_pipeline_gives() {
        let (model, r1) = ur10e_robot(AlarmConfig {
            position_m: Some(0.001),
            angle_rad: None,
            hold_s: 0.0,
        });
        let config = PipelineConfig::default();
        let error = std::fmt::Error;
        let stream = MeasuredStream::Robot;

        let mut pipeline = Pipeline::new(config);
        let mut through_pipeline = Record::default();
        let sink = &mut through_pipeline;
        for input in mixed_inputs(&model) {
            match input {
                Input::Joints(stamp_s, joints) => pipeline.joints(&r1, "j", stamp_s, &joints, sink),
                Input::Measured(stamp_s, pose) => {
                    pipeline.measured(&r1, "m", stream, stamp_s, &pose, sink);
                }
                Input::Undecodable(stamp_s) => {
                    pipeline.reject(&r1, "j", stamp_s, RejectCause::NonFinite, &error, sink);
                }
                Input::DueMetrics => {
                    for index in pipeline.robots_with_due_metrics() {
                        let readout = pipeline.take_due_metrics(index).expect("due");
                        sink.metrics(&r1, &readout);
                    }
                }
            }
        }
        let records = pipeline.records();
        pipeline.finish(sink);

        let mut alone = Record::default();
        let sink = &mut alone;
        sink.tracking(&r1);
        let mut twin = Twin::new(r1.clone(), &config);
        for input in mixed_inputs(&model) {
            match input {
                Input::Joints(stamp_s, joints) => twin.joints("j", stamp_s, &joints, sink),
                Input::Measured(stamp_s, pose) => twin.measured("m", stream, stamp_s, &pose, sink),
                Input::Undecodable(stamp_s) => {
                    twin.reject("j", stamp_s, RejectCause::NonFinite, &error, sink);
                }
                Input::DueMetrics => {
                    if let Some(readout) = twin.take_due_metrics() {
                        sink.metrics(&r1, &readout);
                    }
                }
            }
        }
        let record = twin.record();
        twin.finish(sink);

        assert_eq!(
            alone.poses().count(),
            40,
            "the repeated stamps are rejected"
        );
        assert!(
            alone.deviations().count() > 0
                && alone.metrics().count() >= 5
                && alone.events().count() > 0
        );
        assert_eq!(alone, through_pipeline);
        assert_eq!(records, vec![record]);
    }

    #[test]
    fn the_history_answers_completed_seconds_until_the_clock_goes_back() {
        let (model, r1) = ur10e_robot(AlarmConfig::default());
        let mut twin = Twin::new(r1, &PipelineConfig::default());
        let q_rad = vec![0.1, -1.0, 1.0, -1.0, 1.0, 0.5];
        let mut off = model.pose(&q_rad).expect("valid").readout();
        off.position_m[1] += 0.002;
        let sample = |measured| JointSample {
            stamp_s: None,
            seq: None,
            q_rad: JointAngles::from_slice(&q_rad),
            measured,
            state: None,
        };
        // 100 pairs a second from 10 s to 12.49 s: second 12 is still open.
        for i in 0..250_u32 {
            let stamp_s = 10.0 + f64::from(i) * 0.01;
            twin.joints("j", stamp_s, &sample(Some(off)), &mut Discard);
        }
        let rows = twin.history(i64::MIN..=i64::MAX);
        let seconds: Vec<(i64, u64)> = rows.iter().map(|row| (row.second, row.totals.n)).collect();
        assert_eq!(seconds, [(10, 100), (11, 100)]);
        assert!((rows[0].stats()[0].mae - 0.002).abs() < 1e-9, "{rows:?}");
        assert_eq!(twin.history(11..=20).len(), 1);
        assert_eq!(twin.history_s(), 3600);
        // A joint sample alone moves the time on and completes second 12.
        twin.joints("j", 13.0, &sample(None), &mut Discard);
        assert_eq!(twin.history(12..=12)[0].totals.n, 50);
        // The clock goes back by more than `restart_s`: the seconds of the old clock go.
        twin.joints("j", 1.0, &sample(None), &mut Discard);
        assert!(twin.history(i64::MIN..=i64::MAX).is_empty());
        assert_eq!(twin.newest_s(), Some(1.0));
    }

    #[test]
    fn a_restored_twin_is_due_and_refuses_another_arm() {
        let (model, r1) = ur10e_robot(AlarmConfig::default());
        let config = PipelineConfig::default();
        let mut pipeline = Pipeline::new(config);
        for input in mixed_inputs(&model) {
            if let Input::Joints(stamp_s, joints) = input {
                pipeline.joints(&r1, "j", stamp_s, &joints, &mut Discard);
            }
        }
        let record = pipeline.records().remove(0);
        let restored = Twin::restored(r1.clone(), &config, &record).expect("same arm");
        assert!(restored.is_due(), "as a pipeline's restored twin");
        assert_eq!(restored.record(), record);
        let mut foreign = record;
        foreign.arm = "ur5e".to_owned();
        assert!(matches!(
            Twin::restored(r1, &config, &foreign),
            Err(RestoreError::Arm { .. })
        ));
    }

    #[test]
    fn statistics_start_with_the_first_pair_and_follow_source_time() {
        let (model, r1) = ur10e_robot(AlarmConfig::default());
        let mut pipeline = Pipeline::new(PipelineConfig::default());
        let q_rad = vec![0.1, -1.0, 1.0, -1.0, 1.0, 0.5];
        let joints = JointSample {
            stamp_s: None,
            seq: None,
            q_rad: JointAngles::from_slice(&q_rad),
            measured: None,
            state: None,
        };
        let stats =
            |pipeline: &Pipeline| pipeline.twin(r1.index()).expect("tracked").stats.is_some();
        let metrics = |pipeline: &Pipeline| pipeline.state(r1.index()).expect("tracked").metrics;
        for i in 0..5 {
            pipeline.joints(&r1, "j", f64::from(i), &joints, &mut Discard);
        }
        assert!(!stats(&pipeline), "joints alone need none");
        let readout = metrics(&pipeline);
        assert_eq!((readout.window.n, readout.window_s), (0, 10.0));

        let measured = model.pose(&q_rad).expect("valid").readout();
        pipeline.measured(
            &r1,
            "m",
            MeasuredStream::Robot,
            4.0,
            &measured,
            &mut Discard,
        );
        assert!(stats(&pipeline));
        let readout = metrics(&pipeline);
        assert_eq!((readout.cumulative.n, readout.window.n), (1, 1));
        // The window created at t = 4 s knows source time: 10 s later its pair has left.
        pipeline.joints(&r1, "j", 14.0, &joints, &mut Discard);
        let readout = metrics(&pipeline);
        assert_eq!((readout.cumulative.n, readout.window.n), (1, 0));
    }

    #[test]
    fn a_restored_twin_continues_its_metrics_seq_and_alarms() {
        let (model, r1) = ur10e_robot(AlarmConfig {
            position_m: Some(0.001),
            angle_rad: None,
            hold_s: 0.0,
        });
        let q_rad = vec![0.1, -1.0, 1.0, -1.0, 1.0, 0.5];
        let mut off = model.pose(&q_rad).expect("valid").readout();
        off.position_m[0] += 0.01;
        let mut first = Pipeline::new(PipelineConfig::default());
        for i in 0..20_u32 {
            let joints = JointSample {
                stamp_s: None,
                seq: Some(u64::from(i)),
                q_rad: JointAngles::from_slice(&q_rad),
                measured: Some(off),
                state: None,
            };
            first.joints(&r1, "j", f64::from(i) * 0.01, &joints, &mut Discard);
        }
        let before = first.state(r1.index()).expect("tracked");
        assert!(
            before.alarms_active.position,
            "1 cm off arms the 1 mm alarm"
        );
        let records = first.records();
        assert_eq!(records.len(), 1);
        assert_eq!(
            (records[0].next_pose_seq, records[0].last_gateway_seq),
            (20, Some(19))
        );
        let minutes: Vec<(i64, u64)> = records[0]
            .history_minutes
            .iter()
            .map(|row| (row.second, row.totals.n))
            .collect();
        assert_eq!(minutes, [(0, 20)], "the open minute is kept too");

        let mut second = Pipeline::new(PipelineConfig::default());
        second
            .restore(&r1, &records[0], &mut Discard)
            .expect("same arm");
        let after = second.state(r1.index()).expect("restored");
        assert_eq!(after.metrics.cumulative, before.metrics.cumulative);
        assert_eq!(after.metrics.paired, 20);
        assert_eq!(after.alarms_active, before.alarms_active);
        assert_eq!(after.metrics.window.n, 0, "the window starts afresh");
        assert_eq!(second.records(), records, "bit for bit");
        assert!(matches!(
            second.restore(&r1, &records[0], &mut Discard),
            Err(RestoreError::AlreadyTracked { .. })
        ));

        let mut foreign = records[0].clone();
        foreign.arm = "ur5e".to_owned();
        let mut third = Pipeline::new(PipelineConfig::default());
        assert!(matches!(
            third.restore(&r1, &foreign, &mut Discard),
            Err(RestoreError::Arm { .. })
        ));
        let mut damaged = records[0].clone();
        damaged.cumulative.sums_of_squares[0] = [-1.0, 0.0];
        assert!(matches!(
            third.restore(&r1, &damaged, &mut Discard),
            Err(RestoreError::Statistics { .. })
        ));
        let mut damaged = records[0].clone();
        damaged.history_minutes[0].second = 7;
        assert!(matches!(
            third.restore(&r1, &damaged, &mut Discard),
            Err(RestoreError::History { .. })
        ));
        assert_eq!(
            third.tracked().count(),
            0,
            "a refused record tracks nothing"
        );
        // The restored minute is answered once a later minute's sample completes it.
        let joints = JointSample {
            stamp_s: None,
            seq: Some(20),
            q_rad: JointAngles::from_slice(&q_rad),
            measured: None,
            state: None,
        };
        second.joints(&r1, "j", 61.0, &joints, &mut Discard);
        let twin = second.twin(r1.index()).expect("restored");
        let answered: Vec<(i64, u64)> = twin
            .history_minutes(i64::MIN..=i64::MAX)
            .iter()
            .map(|row| (row.second, row.totals.n))
            .collect();
        assert_eq!(answered, [(0, 20)]);
    }

    #[test]
    fn a_restored_twin_goes_on_with_its_applied_calibration() {
        let nominal = Arc::new(RobotModel::nominal("ur10e").expect("catalog"));
        let mut robots = RobotDirectory::new(
            Some(RobotSettings {
                model: Arc::clone(&nominal),
                alarm: AlarmConfig::default(),
                sensors: Vec::new(),
                self_calibration: None,
                effort: None,
            }),
            HashMap::new(),
        );
        let r1 = robots.admit("r1").expect("default settings").clone();
        let mut deltas = MountingDeltas::ZERO;
        deltas.delta_theta_rad[1] = 2e-3;
        deltas.delta_a_m[2] = 4e-4;
        let tool = TcpOffset {
            position_m: [0.0, 0.0, 0.1],
            rotation_vector_rad: [0.0, 0.0, 0.3],
        };
        let calibrated = Arc::new(nominal.with_deltas(deltas, tool, "estimate").expect("fits"));
        let q_rad = [0.1, -1.0, 1.0, -1.0, 1.0, 0.5];
        let mut first = Pipeline::new(PipelineConfig::default());
        let joints = || JointSample {
            stamp_s: None,
            seq: None,
            q_rad: JointAngles::from_slice(&q_rad),
            measured: None,
            state: None,
        };
        first.joints(&r1, "j", 0.0, &joints(), &mut Discard);
        assert_eq!(first.records()[0].applied, None, "the configured model");
        first
            .replace_model(r1.index(), Arc::clone(&calibrated), &mut Discard)
            .expect("same joints");
        let records = first.records();
        assert_eq!(
            records[0].applied,
            Some(AppliedModel { deltas, tool }),
            "the applied model's deltas and tool"
        );

        let mut second = Pipeline::new(PipelineConfig::default());
        second
            .restore(&r1, &records[0], &mut Discard)
            .expect("fits the arm");
        let restored = second.model(r1.index()).expect("restored");
        let pose = |model: &RobotModel| model.pose(&q_rad).expect("valid").readout();
        assert_eq!(
            pose(restored),
            pose(&calibrated),
            "the same FK, bit for bit"
        );
        assert_ne!(pose(restored), pose(&nominal));
        assert_eq!(second.records(), records);
        second.joints(&r1, "j", 0.01, &joints(), &mut Discard);
        assert_eq!(second.state(r1.index()).expect("tracked").metrics.epoch, 1);
    }
}
