//! The service's [`Sink`]: one robot's results encoded and published through the [`Outlet`], its
//! event budget applied, the totals the dashboard reads counted, the rule that decides when a
//! robot streams enough for route caches (asked of the control thread), and, with `[service]
//! outputs = "paired"`, the rule that decides when a twin pose goes out with its deviation or
//! alone.
//!
//! Must not take any lock but the untracked robots' event bucket: it runs under the robot's cell.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

use tracing::{debug, info, warn};
use zenoh::bytes::ZBytes;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Publisher;

use super::events::EventBucket;
use super::history_log::HistoryLog;
use super::publish::{Outlet, RobotPublishers};
use super::recording::{Recorder, RobotRecording};
use super::requests::Requests;
use crate::config::{EventBudget, OutputEncoding, OutputShape};
use armtwin_codec::{PoseFields, cdr, json, zser};
use armtwin_core::dynamics::monitor::EffortReadout;
use armtwin_core::kinematics::{OutputFrame, PoseReadout};
use armtwin_core::metrics::Deviation;
use armtwin_core::pipeline::{Event, EventDetail, EventKind, MetricsReadout, Robot, Sink};
use armtwin_core::sample::JointSample;
use armtwin_mesh::keys::Stream;
use armtwin_mesh::ros2;
use armtwin_view::RobotCounts;

/// Events kept per robot for the dashboard's robot page.
const RECENT_EVENTS: usize = 10;

/// Twin poses a robot publishes on plain keys within [`ROUTE_CACHE_WINDOW_S`] of source time
/// before the control thread is asked to declare the publishers (and input keys) that cache its
/// routes: a rate, not a count, so a robot that sends now and then never gets them. Zenoh
/// computes the route of a put on an undeclared key anew every time; a declaration is paid once,
/// costs in proportion to the keys beside it and holds memory for as long as the robot is
/// tracked. A robot that streams repays it; one under the rate spends less CPU on its plain keys
/// than the declarations' memory and their cost to every later declaration are worth (the
/// figures: crates/armtwin-bench/README.md, "The service next to a plain Zenoh echo").
const ROUTE_CACHE_POSES: u32 = 64;

/// The span of source time (s) [`ROUTE_CACHE_POSES`] poses must fall in.
const ROUTE_CACHE_WINDOW_S: f64 = 10.0;

/// What every robot's sink shares, and where sinks are made: the outlet results go out
/// through, the control thread's requests, the event budget (with the one bucket of the
/// robots that may not be tracked) and the flight recorder.
pub(super) struct Sinks {
    outlet: Outlet,
    requests: Requests,
    event_budget: EventBudget,
    recorder: Recorder,
    /// Where the robots' histories keep the seconds of closed minutes.
    history_log: HistoryLog,
    /// Shared by the robots that may not be tracked, so a flood of made-up ids cannot grow the
    /// buckets. A leaf lock: held for a bucket's arithmetic only, never across a `put`.
    untracked_bucket: Mutex<EventBucket>,
}

impl Sinks {
    /// Sinks that publish through `outlet`, ask the control thread through `requests`, keep
    /// each robot's events within `event_budget` and its recent streams in `recorder`.
    pub(super) fn new(
        outlet: Outlet,
        requests: Requests,
        event_budget: EventBudget,
        recorder: Recorder,
    ) -> Self {
        Self {
            outlet,
            requests,
            event_budget,
            recorder,
            history_log: HistoryLog::none(),
            untracked_bucket: Mutex::new(EventBucket::full(event_budget, Instant::now())),
        }
    }

    /// The same sinks, the histories keeping the seconds of closed minutes in `history_log`.
    pub(super) fn with_history_log(mut self, history_log: HistoryLog) -> Self {
        self.history_log = history_log;
        self
    }

    /// Where the robots' histories keep the seconds of closed minutes.
    pub(super) fn history_log(&self) -> &HistoryLog {
        &self.history_log
    }

    /// The outlet every sink publishes through.
    pub(super) fn outlet(&self) -> &Outlet {
        &self.outlet
    }

    /// The flight recorder.
    pub(super) fn recorder(&self) -> &Recorder {
        &self.recorder
    }

    /// The sink of one robot, for one call into its twin, with `robot`, the robot's output
    /// state, borrowed from its locked cell.
    pub(super) fn of<'a>(&'a self, robot: &'a mut RobotOutputState) -> ZenohSink<'a> {
        ZenohSink {
            sinks: self,
            robot: Some(robot),
        }
    }

    /// The sink of the rejection of a robot that may not be tracked.
    pub(super) fn untracked(&self) -> ZenohSink<'_> {
        ZenohSink {
            sinks: self,
            robot: None,
        }
    }
}

/// A robot's output state: its publishers, event bucket, twin pose for ROS tools and totals.
#[derive(Default)]
pub(super) struct RobotOutputState {
    /// Once the control thread has declared them.
    declared: Option<RobotPublishers>,
    /// The robot's liveliness token, once the control thread has declared it.
    token: Option<LivelinessToken>,
    /// From tracking on.
    event_bucket: Option<EventBucket>,
    /// From tracking on: the twin pose for ROS tools.
    ros2_pose: Option<Ros2PoseState>,
    /// What the dashboard and `/metrics` read beyond the twin's own state.
    counts: RobotCounts,
    /// Whether the robot streams fast enough for route caches.
    route_demand: RouteDemand,
    /// From tracking on, if the robot records: its recent streams.
    recording: Option<RobotRecording>,
    /// With `[service] outputs = "paired"`, from its first twin pose: the newest one.
    paired: Option<Box<PairedPose>>,
}

impl RobotOutputState {
    /// What the dashboard and `/metrics` read beyond the twin's own state.
    pub(super) fn counts(&self) -> &RobotCounts {
        &self.counts
    }

    /// The same, to change.
    pub(super) fn counts_mut(&mut self) -> &mut RobotCounts {
        &mut self.counts
    }

    /// The robot's metrics publisher, once the control thread has declared it.
    pub(super) fn metrics_publisher(&self) -> Option<Arc<Publisher<'static>>> {
        self.declared.as_ref().and_then(RobotPublishers::metrics)
    }

    /// Gives the robot the publishers the control thread declared for it.
    pub(super) fn set_publishers(&mut self, publishers: RobotPublishers) {
        self.declared = Some(publishers);
    }

    /// Gives the robot's publishers their metrics publisher (declared after them).
    pub(super) fn set_metrics_publisher(&mut self, publisher: Publisher<'static>) {
        if let Some(declared) = self.declared.as_mut() {
            declared.set_metrics(publisher);
        }
    }

    /// Gives the robot the liveliness token the control thread declared for it.
    pub(super) fn set_token(&mut self, token: LivelinessToken) {
        self.token = Some(token);
    }

    /// The robot's recent streams, if it records.
    pub(super) fn recording_mut(&mut self) -> Option<&mut RobotRecording> {
        self.recording.as_mut()
    }

    /// The robot's publishers and token, taken out to be undeclared.
    pub(super) fn take_declared(&mut self) -> (Option<RobotPublishers>, Option<LivelinessToken>) {
        (self.declared.take(), self.token.take())
    }
}

/// A robot's twin poses in its current span of source time, until they make it worth its route
/// caches ([`ROUTE_CACHE_POSES`] within [`ROUTE_CACHE_WINDOW_S`]).
#[derive(Default)]
struct RouteDemand {
    /// Source time (s) the current span began.
    since_s: f64,
    /// Poses since then.
    poses: u32,
    /// The caches were asked for.
    asked: bool,
}

impl RouteDemand {
    /// Counts a pose stamped `stamp_s`: `true` once, when the robot has reached the rate.
    fn pose(&mut self, stamp_s: f64) -> bool {
        if self.asked {
            return false;
        }
        // A span that has run out (or a clock that went back) starts again here.
        if !(self.since_s..self.since_s + ROUTE_CACHE_WINDOW_S).contains(&stamp_s) {
            self.since_s = stamp_s;
            self.poses = 0;
        }
        self.poses += 1;
        self.asked = self.poses >= ROUTE_CACHE_POSES;
        self.asked
    }
}

/// Where a robot's newest twin pose is on the paired stream.
#[derive(Clone, Copy, PartialEq, Eq)]
enum PairedState {
    /// Not published yet: it waits for the deviation paired at its stamp.
    Held,
    /// Published without a deviation.
    Alone,
    /// Published with a deviation.
    Paired,
}

/// A robot's newest twin pose, kept for the paired stream (`[service] outputs = "paired"`): a
/// pose waits within the call into the twin that made it, where a joint sample's own measured
/// pose (or one that came first and waited for its stamp) pairs; a robot whose measured poses
/// come after their joint samples has its poses wait for them, up to its next joint sample or the
/// control thread's next turn without input. A deviation at its stamp that comes after it went
/// out alone sends it again, with the deviation, and the robot's poses wait from then on.
struct PairedPose {
    /// Its robot, for a pose that goes out when the sink that held it is gone.
    robot: Arc<str>,
    stamp_s: f64,
    seq: u64,
    frame: OutputFrame,
    fields: PoseFields,
    state: PairedState,
    /// The robot's measured poses pair after the call that made their twin pose.
    pairs_later: bool,
}

impl PairedPose {
    /// Its message, with `deviation` (paired at its stamp) if any.
    fn payload(&self, encoding: OutputEncoding, deviation: Option<&Deviation>) -> ZBytes {
        match (encoding, deviation) {
            (OutputEncoding::Json, _) => json::paired_json_bytes(
                &self.robot,
                self.stamp_s,
                self.seq,
                self.frame.as_str(),
                &self.fields,
                deviation,
            )
            .into(),
            (OutputEncoding::ZenohSerialized, Some(deviation)) => {
                zser::paired_bytes(self.stamp_s, self.seq, &self.fields, deviation).into()
            }
            (OutputEncoding::ZenohSerialized, None) => {
                zser::paired_pose_bytes(self.stamp_s, self.seq, &self.fields).into()
            }
        }
    }
}

/// A robot's twin pose output for ROS tools, as the sink publishes it.
struct Ros2PoseState {
    /// Its key, for the poses sent before the publisher is declared.
    key: String,
    /// `<tf_prefix>base` or `<tf_prefix>base_link`: the robot's output frame.
    frame_id: String,
    /// `Some` for `rmw_zenoh`: the publisher gid of the attachment.
    gid: Option<[u8; 16]>,
    /// The attachment's next sequence number (from 1, as `rmw_zenoh` counts).
    next_seq: i64,
}

/// Publishes one robot's results on Zenoh: made for one call into the twin ([`Sinks::of`]), from
/// what every sink shares and the robot's own [`RobotOutputState`] (borrowed from the robot's
/// locked cell), or without one for inputs of robots that may not be tracked.
pub(super) struct ZenohSink<'a> {
    sinks: &'a Sinks,
    robot: Option<&'a mut RobotOutputState>,
}

impl ZenohSink<'_> {
    /// Publishes the robot's held twin pose, if it holds one, without a deviation. `always`:
    /// also for a robot whose measured poses pair after their call, which then stops waiting for
    /// them (its measured poses did not come).
    pub(super) fn release_paired_pose(&mut self, always: bool) {
        let Some(state) = self.robot.as_deref_mut() else {
            return;
        };
        let Some(pose) = state.paired.as_deref_mut() else {
            return;
        };
        if pose.state != PairedState::Held || (pose.pairs_later && !always) {
            return;
        }
        pose.state = PairedState::Alone;
        pose.pairs_later = false;
        let payload = pose.payload(self.sinks.outlet.encoding(), None);
        let declared = state.declared.as_ref();
        self.sinks
            .outlet
            .publish(declared, &pose.robot, Stream::Paired, payload);
    }

    /// Keeps `robot`'s twin pose for the paired stream, until its deviation comes or the call
    /// ends; the one before it goes out alone first if its deviation never came.
    fn hold_paired_pose(
        &mut self,
        robot: &Robot,
        stamp_s: f64,
        seq: u64,
        frame: OutputFrame,
        fields: PoseFields,
    ) {
        self.release_paired_pose(true);
        let Some(state) = self.robot.as_deref_mut() else {
            // Only a tracked robot has twin poses: nothing to keep them for otherwise.
            return;
        };
        match state.paired.as_deref_mut() {
            Some(pose) => {
                pose.stamp_s = stamp_s;
                pose.seq = seq;
                pose.frame = frame;
                pose.fields = fields;
                pose.state = PairedState::Held;
            }
            None => {
                state.paired = Some(Box::new(PairedPose {
                    robot: Arc::clone(robot.shared_id()),
                    stamp_s,
                    seq,
                    frame,
                    fields,
                    state: PairedState::Held,
                    pairs_later: false,
                }));
            }
        }
    }

    /// Publishes `deviation`, paired at `stamp_s`, with the robot's twin pose of that stamp; or
    /// on the deviation stream when the robot's newest pose has another stamp (a measured pose
    /// paired by interpolation, or after a newer joint sample).
    fn put_paired_deviation(&mut self, robot: &Robot, stamp_s: f64, deviation: &Deviation) {
        let encoding = self.sinks.outlet.encoding();
        let paired = self
            .robot
            .as_deref_mut()
            .and_then(|state| state.paired.as_deref_mut())
            .filter(|pose| pose.stamp_s.to_bits() == stamp_s.to_bits())
            .map(|pose| {
                if pose.state == PairedState::Alone {
                    pose.pairs_later = true;
                }
                pose.state = PairedState::Paired;
                pose.payload(encoding, Some(deviation))
            });
        if let Some(payload) = paired {
            self.put(robot.id(), Stream::Paired, payload);
        } else {
            let payload = deviation_payload(encoding, robot, stamp_s, deviation);
            self.put(robot.id(), Stream::Deviation, payload);
        }
    }

    /// Publishes `payload` on `robot`'s `stream` ([`Outlet::publish`]).
    fn put(&self, robot: &str, stream: Stream, payload: impl Into<ZBytes>) {
        let declared = self
            .robot
            .as_deref()
            .and_then(|state| state.declared.as_ref());
        self.sinks.outlet.publish(declared, robot, stream, payload);
    }

    /// `robot`'s twin computes with `model` from now on: its incident files draw it. When the
    /// joints are of another count, its pending incident is written now, with what it holds,
    /// and its recording starts afresh.
    pub(super) fn model_replaced(
        &mut self,
        robot: &Robot,
        model: &Arc<armtwin_core::model::RobotModel>,
    ) {
        let Some(state) = self.robot.as_deref_mut() else {
            return;
        };
        let Some(recording) = state.recording.as_mut() else {
            return;
        };
        if recording.follow_model(model) {
            return;
        }
        if let Some(incident) = recording.cut(robot.id()) {
            self.sinks.recorder.send(incident);
        }
        state.recording = self.sinks.recorder.start_with(robot, model);
    }

    /// Publishes an event about `robot`'s controller (`kind` `controller`: what a gateway read
    /// of it, not a sample).
    pub(super) fn controller_event(
        &mut self,
        robot: &str,
        reason: &str,
        detail: &serde_json::Value,
    ) {
        self.mesh_event(robot, "controller", reason, detail);
    }

    /// Publishes an event of `kind` about what the mesh said of `robot` besides its samples (its
    /// controller, its description): always, as alarms are, kept among the recent events and
    /// logged at warn. `t` is the arrival time: such messages carry no stamp of the robot's.
    pub(super) fn mesh_event(
        &mut self,
        robot: &str,
        kind: &'static str,
        reason: &str,
        detail: &serde_json::Value,
    ) {
        let message = serde_json::json!({
            "robot": robot,
            "t": SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0.0, |since| since.as_secs_f64()),
            "kind": kind,
            "reason": reason,
            "detail": detail,
        });
        let payload = json::to_json_bytes(&message);
        if let Some(state) = self.robot.as_deref_mut() {
            let recent = &mut state.counts.recent_events;
            if recent.len() == RECENT_EVENTS {
                recent.pop_front();
            }
            recent.push_back(Arc::from(payload.as_slice()));
        }
        self.put(robot, Stream::Events, payload);
        warn!(robot, kind, reason, "event");
    }

    /// Prepares `robot`'s twin pose output for ROS tools, if it has one.
    fn track_ros2_pose(&mut self, robot: &Robot) {
        let outlet = &self.sinks.outlet;
        let Some(output) = outlet.ros2_pose_of(robot.id()) else {
            return;
        };
        if output.namespace.is_none()
            && let Err(e) = ros2::relative_ros_name(robot.id(), true)
        {
            warn!(robot = robot.id(), error = %e, "the robot id is its twin pose's ROS namespace, but not a ROS name: ROS nodes cannot subscribe to it (set ros2_pose.namespace)");
        }
        let state = Ros2PoseState {
            key: output.key(robot.id()),
            frame_id: cdr::frame_id(&output.tf_prefix, robot.settings().model.frame()),
            gid: output
                .attaches()
                .then(|| outlet.ros2_publisher_gid(robot.id())),
            next_seq: 1,
        };
        if let Some(robot_state) = self.robot.as_deref_mut() {
            robot_state.ros2_pose = Some(state);
        }
    }

    /// Publishes the twin pose as a CDR `PoseStamped` (with `rmw_zenoh`'s attachment for that
    /// scheme), if `robot` has the output.
    fn put_ros2_pose(&mut self, robot: &Robot, stamp_s: f64, pose: &PoseReadout) {
        let Some(robot_state) = self.robot.as_deref_mut() else {
            return;
        };
        let Some(state) = &mut robot_state.ros2_pose else {
            return;
        };
        let payload = cdr::encode_pose_stamped(stamp_s, &state.frame_id, pose);
        let attachment = state.gid.map(|gid| {
            let seq = state.next_seq;
            state.next_seq += 1;
            ros2::encode_attachment(seq, unix_now_ns(), &gid)
        });
        self.sinks.outlet.publish_ros2_pose(
            robot_state.declared.as_ref(),
            robot.id(),
            &state.key,
            payload,
            attachment,
        );
    }
}

impl Sink for ZenohSink<'_> {
    fn tracking(&mut self, robot: &Robot) {
        if let Some(state) = self.robot.as_deref_mut() {
            state.event_bucket = Some(EventBucket::full(self.sinks.event_budget, Instant::now()));
            state.recording = self.sinks.recorder.start(robot);
        }
        self.track_ros2_pose(robot);
        self.sinks.requests.track(robot);
    }

    fn pose(
        &mut self,
        robot: &Robot,
        stamp_s: f64,
        seq: u64,
        frame: OutputFrame,
        pose: &PoseReadout,
    ) {
        let fields = PoseFields::from(pose);
        match self.sinks.outlet.shape() {
            OutputShape::Separate => {
                let payload = pose_payload(
                    self.sinks.outlet.encoding(),
                    robot,
                    (stamp_s, seq),
                    frame,
                    &fields,
                );
                self.put(robot.id(), Stream::Pose, payload);
            }
            OutputShape::Paired => self.hold_paired_pose(robot, stamp_s, seq, frame, fields),
        }
        if let Some(state) = self.robot.as_deref_mut() {
            state.counts.poses += 1;
            if state.route_demand.pose(stamp_s) {
                self.sinks.requests.cache_routes(robot);
            }
        }
        self.put_ros2_pose(robot, stamp_s, pose);
    }

    fn joints(&mut self, robot: &Robot, stamp_s: f64, sample: &JointSample, twin: &PoseReadout) {
        let recording = self
            .robot
            .as_deref_mut()
            .and_then(|state| state.recording.as_mut());
        if let Some(incident) =
            recording.and_then(|recording| recording.joints(robot.id(), stamp_s, sample, twin))
        {
            self.sinks.recorder.send(incident);
        }
    }

    fn deviation(
        &mut self,
        robot: &Robot,
        stamp_s: f64,
        measured: &PoseReadout,
        deviation: &Deviation,
    ) {
        if let Some(recording) = self
            .robot
            .as_deref_mut()
            .and_then(|state| state.recording.as_mut())
        {
            recording.measured(stamp_s, measured, deviation);
        }
        match self.sinks.outlet.shape() {
            OutputShape::Separate => {
                let payload =
                    deviation_payload(self.sinks.outlet.encoding(), robot, stamp_s, deviation);
                self.put(robot.id(), Stream::Deviation, payload);
            }
            OutputShape::Paired => self.put_paired_deviation(robot, stamp_s, deviation),
        }
    }

    /// Publishes the event unless its robot's rate limit keeps it back, and logs it once (at
    /// warn for rejections and alarms); a kept-back event is only counted, and formats nothing.
    fn event(&mut self, event: &Event<'_>) {
        let always = matches!(
            event.kind,
            EventKind::Alarm | EventKind::Recovered | EventKind::Restart | EventKind::Epoch
        );
        // An event names its robot's index only when it has a twin, whose entry this sink holds.
        let mut robot_state = self.robot.as_deref_mut().filter(|_| event.index.is_some());
        if let (Some(state), Some(kind)) = (&mut robot_state, self.sinks.recorder.trigger_of(event))
            && let Some(recording) = state.recording.as_mut()
        {
            let config = self.sinks.recorder.config();
            let text =
                String::from_utf8_lossy(&json::to_json_bytes(&json::EventMessage::new(event)))
                    .into_owned();
            recording.trigger(kind, event.stamp_s, text, (config.pre_s, config.post_s));
        }
        if let (Some(state), EventDetail::Rejected { cause }) = (&mut robot_state, &event.detail) {
            let by_cause = &mut state.counts.rejected_by_cause;
            match by_cause.iter_mut().find(|(counted, _)| counted == cause) {
                Some((_, count)) => *count += 1,
                None => by_cause.push((*cause, 1)),
            }
        }
        let now = Instant::now();
        let budget = self.sinks.event_budget;
        let tracked = robot_state
            .as_mut()
            .and_then(|state| state.event_bucket.as_mut());
        let passed = match tracked {
            Some(bucket) => bucket.pass(budget, now, always),
            None => self
                .sinks
                .untracked_bucket
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .pass(budget, now, always),
        };
        let suppressed = match passed {
            Ok(suppressed) => suppressed,
            Err(suppressed) => {
                if suppressed == 1 {
                    warn!(robot = %event.robot, per_s = budget.per_s, burst = budget.burst, "event rate limit reached: further events are counted, not published");
                }
                return;
            }
        };
        let mut message = json::EventMessage::new(event);
        message.suppressed = suppressed;
        let cause = match event.detail {
            EventDetail::Rejected { cause } => Some(cause.as_str()),
            EventDetail::Unpaired { cause, .. } => Some(cause),
            _ => None,
        };
        let payload = json::to_json_bytes(&message);
        if let Some(state) = robot_state {
            let recent = &mut state.counts.recent_events;
            if recent.len() == RECENT_EVENTS {
                recent.pop_front();
            }
            recent.push_back(Arc::from(payload.as_slice()));
        }
        self.put(event.robot, Stream::Events, payload);
        let (robot, kind, key) = (event.robot, event.kind.as_str(), event.key);
        let reason = message.reason.as_str();
        match event.kind {
            EventKind::Rejected | EventKind::Alarm => {
                warn!(robot, kind, cause, key, reason, "event");
            }
            EventKind::Recovered | EventKind::Restart | EventKind::Epoch => {
                info!(robot, kind, cause, key, reason, "event");
            }
            EventKind::Gap | EventKind::Unpaired => {
                debug!(robot, kind, cause, key, reason, "event");
            }
        }
    }

    fn effort(&mut self, robot: &Robot, readout: &EffortReadout) {
        if let Some(recording) = self
            .robot
            .as_deref_mut()
            .and_then(|state| state.recording.as_mut())
        {
            recording.effort(readout);
        }
        self.put(
            robot.id(),
            Stream::Effort,
            json::effort_readout_bytes(robot.id(), readout),
        );
    }

    fn metrics(&mut self, robot: &Robot, readout: &MetricsReadout) {
        // A reset, a new epoch or the end: a pose waiting for its deviation goes out first.
        self.release_paired_pose(true);
        let message = json::MetricsMessage::new(readout);
        self.put(robot.id(), Stream::Metrics, message.to_json_bytes());
    }
}

/// A sink lives for one call into the twin: a twin pose that call left waiting goes out as it
/// ends, unless the robot's measured poses pair after their call.
impl Drop for ZenohSink<'_> {
    fn drop(&mut self) {
        self.release_paired_pose(false);
    }
}

/// The message of a twin pose on the pose stream.
fn pose_payload(
    encoding: OutputEncoding,
    robot: &Robot,
    (stamp_s, seq): (f64, u64),
    frame: OutputFrame,
    fields: &PoseFields,
) -> ZBytes {
    match encoding {
        OutputEncoding::Json => {
            json::pose_json_bytes(robot.id(), stamp_s, seq, frame.as_str(), fields).into()
        }
        OutputEncoding::ZenohSerialized => zser::twin_pose_bytes(stamp_s, seq, fields).into(),
    }
}

/// The message of `deviation`, paired at `stamp_s`, on the deviation stream.
fn deviation_payload(
    encoding: OutputEncoding,
    robot: &Robot,
    stamp_s: f64,
    deviation: &Deviation,
) -> ZBytes {
    match encoding {
        OutputEncoding::Json => json::deviation_json_bytes(robot.id(), stamp_s, deviation).into(),
        OutputEncoding::ZenohSerialized => zser::deviation_bytes(stamp_s, deviation).into(),
    }
}

fn unix_now_ns() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
}

#[cfg(test)]
mod tests {
    use super::{ROUTE_CACHE_POSES, ROUTE_CACHE_WINDOW_S, RouteDemand};

    /// Poses stamped `period_s` apart from `start_s`: the index of the one that asks for route
    /// caches, if any does within `poses`.
    fn asks_at(demand: &mut RouteDemand, start_s: f64, period_s: f64, poses: u32) -> Option<u32> {
        (0..poses).find(|&pose| demand.pose(start_s + f64::from(pose) * period_s))
    }

    #[test]
    fn a_streaming_robot_asks_for_route_caches_once_at_the_rate() {
        let mut demand = RouteDemand::default();
        assert_eq!(
            asks_at(&mut demand, 1.7e9, 0.01, 1000),
            Some(ROUTE_CACHE_POSES - 1)
        );
        assert_eq!(asks_at(&mut demand, 1.7e9 + 10.0, 0.01, 1000), None);
    }

    #[test]
    fn a_robot_under_the_rate_never_asks_however_long_it_sends() {
        let period_s = ROUTE_CACHE_WINDOW_S / f64::from(ROUTE_CACHE_POSES) * 1.05;
        let mut demand = RouteDemand::default();
        assert_eq!(asks_at(&mut demand, 0.0, period_s, 10_000), None);
        // Then it speeds up: it asks within one span.
        let start_s = 10_000.0 * period_s;
        let asked = asks_at(&mut demand, start_s, 0.01, 1000).expect("asks once it streams");
        assert!(asked < 2 * ROUTE_CACHE_POSES, "{asked}");
    }

    #[test]
    fn a_clock_that_goes_back_starts_the_span_again() {
        let mut demand = RouteDemand::default();
        assert_eq!(
            asks_at(&mut demand, 100.0, 0.01, ROUTE_CACHE_POSES - 1),
            None
        );
        assert_eq!(
            asks_at(&mut demand, 50.0, 0.01, 1000),
            Some(ROUTE_CACHE_POSES - 1)
        );
    }
}
