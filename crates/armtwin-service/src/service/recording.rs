//! The flight recorder in the service: each recording robot's rings (fed by its sink under the
//! robot's lock), the incidents its events and the operator's queries set off, and the moment
//! an incident's `post_s` has passed and it goes to the writer thread.
//!
//! Must not write a file or wait: the rings' closed blocks go to their log's own thread, and an
//! incident is copied out of the rings (its blocks read back from the log, once per incident)
//! and handed over ([`IncidentSender::send`] never blocks); the writer thread does the rest.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};

use tracing::warn;
use zenoh::bytes::Encoding;
use zenoh::qos::CongestionControl;
use zenoh::{Session, Wait};

use crate::config::RecorderConfig;
use armtwin_core::dynamics::monitor::EffortReadout;
use armtwin_core::kinematics::PoseReadout;
use armtwin_core::metrics::Deviation;
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::{Event, EventDetail, EventKind, Robot};
use armtwin_core::sample::JointSample;
use armtwin_mesh::keys::{KeySpace, Stream};
use armtwin_recorder::incident::{EFFORT_STRIDE, MEASURED_STRIDE, fill_effort, fill_measured};
use armtwin_recorder::ros2_messages::{LOG_INFO, LOG_WARN};
use armtwin_recorder::{
    Incident, IncidentSender, JointRecord, LogLine, Outcome, RecordRing, Spool, StoreCounters,
    Trigger, store,
};
use armtwin_view::RecorderTotals;

/// Wall time past an incident's `post_s` after which it is written with what it has: a robot
/// that stopped streaming still leaves its file.
const STALLED_GRACE: Duration = Duration::from_secs(2);

/// Triggers folded into one incident; more are counted in its last line.
const MAX_LOG_LINES: usize = 32;

/// Incidents a robot may set off back to back; after them, one per `post_s` of wall time (one
/// per second at least), so that a robot whose stamps jump (a gap incident each sample) takes
/// the writer thread and the disk at that pace, and the other robots' incidents still go out.
/// Triggers held back are counted in the robot's next incident. Operators' requests are not
/// held back.
const INCIDENT_BURST: f64 = 4.0;

/// What every robot's recorder shares: the settings, the fleet's log of closed blocks and the
/// writer thread.
pub(super) struct Recorder {
    config: RecorderConfig,
    spool: Arc<Spool>,
    sender: Option<IncidentSender>,
    writer: Mutex<Option<JoinHandle<()>>>,
}

impl Recorder {
    /// The recorder of `config`, its files written by the thread behind `sender` (none: the
    /// rings run, nothing is written).
    pub(super) fn new(
        config: RecorderConfig,
        writer: Option<(IncidentSender, JoinHandle<()>)>,
    ) -> Self {
        let (sender, handle) = writer.unzip();
        Self {
            // Beside the files it writes: on the disk the operator chose for recordings.
            spool: Spool::in_dir(&config.store.dir, config.fleet_bytes as u64),
            config,
            sender,
            writer: Mutex::new(handle),
        }
    }

    /// The settings.
    pub(super) fn config(&self) -> &RecorderConfig {
        &self.config
    }

    /// `robot`'s recording, if it records.
    pub(super) fn start(&self, robot: &Robot) -> Option<RobotRecording> {
        self.start_with(robot, &robot.settings().model)
    }

    /// The same, of `robot` computing with `model`.
    pub(super) fn start_with(
        &self,
        robot: &Robot,
        model: &Arc<RobotModel>,
    ) -> Option<RobotRecording> {
        if !self.config.records(robot.id()) {
            return None;
        }
        let joint_record = JointRecord {
            joint_count: model.joint_count(),
        };
        let span_s = self.config.span_s();
        let robot_bytes = self.config.robot_bytes;
        // The joints take half: a measured pose and an effort record come at most once a
        // joint sample, and only for some robots.
        let ring = |stride: usize, quarters: usize| {
            RecordRing::new(
                stride,
                span_s,
                robot_bytes / 4 * quarters,
                Arc::clone(&self.spool),
            )
        };
        Some(RobotRecording {
            joints: ring(joint_record.stride(), 2),
            measured: ring(MEASURED_STRIDE, 1),
            efforts: ring(EFFORT_STRIDE, 1),
            scratch: vec![
                0.0;
                joint_record
                    .stride()
                    .max(MEASURED_STRIDE)
                    .max(EFFORT_STRIDE)
            ],
            joint_record,
            model: Arc::clone(model),
            draw: self.config.draw_robot,
            pending: None,
            incident_tokens: INCIDENT_BURST,
            refilled: Instant::now(),
            held_back: 0,
        })
    }

    /// Hands `incident` to the writer thread.
    pub(super) fn send(&self, incident: Incident) {
        if let Some(sender) = &self.sender {
            sender.send(incident);
        }
    }

    /// The trigger word of `event`, if it sets an incident off.
    pub(super) fn trigger_of(&self, event: &Event<'_>) -> Option<&'static str> {
        match (event.kind, &event.detail) {
            (EventKind::Alarm, EventDetail::Collision { .. }) => Some("collision"),
            (EventKind::Alarm, EventDetail::Payload { .. }) => Some("payload"),
            (EventKind::Alarm, _) => Some("alarm"),
            (EventKind::Restart, _) => Some("restart"),
            (EventKind::Gap, EventDetail::StampGap { gap_s }) if *gap_s > self.config.gap_s => {
                Some("gap")
            }
            _ => None,
        }
    }

    /// Files written, their bytes, failures and the rings' memory.
    pub(super) fn totals(&self) -> RecorderTotals {
        let counters = self.sender.as_ref().map(IncidentSender::counters);
        let count = |read: fn(&StoreCounters) -> &AtomicU64| {
            counters.map_or(0, |counters| read(counters).load(Ordering::Relaxed))
        };
        RecorderTotals {
            files: count(|c| &c.files),
            bytes: count(|c| &c.bytes),
            failures: count(|c| &c.failures) + count(|c| &c.dropped),
            ring_bytes: self.spool.used_bytes(),
        }
    }

    /// Lets the writer thread write what it was handed, then waits for it (at shutdown, after
    /// every twin was finished).
    pub(super) fn finish(&self) {
        if let Some(sender) = &self.sender {
            sender.stop();
        }
        let handle = self
            .writer
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take();
        if let Some(handle) = handle
            && handle.join().is_err()
        {
            warn!("the recorder's writer thread panicked");
        }
    }
}

/// An incident waiting for its `post_s` to pass.
struct Pending {
    trigger: Trigger,
    from_s: f64,
    until_s: f64,
    /// Written with what it has by then, should the robot stop streaming.
    deadline: Instant,
    log: Vec<LogLine>,
    folded: usize,
}

/// One robot's rings and its pending incident.
pub(super) struct RobotRecording {
    joint_record: JointRecord,
    joints: RecordRing,
    measured: RecordRing,
    efforts: RecordRing,
    /// One record, built before it is pushed.
    scratch: Vec<f64>,
    /// The robot's model when it started: the file's names, and what it draws.
    model: Arc<RobotModel>,
    /// `[recorder] draw_robot`.
    draw: bool,
    pending: Option<Pending>,
    /// Incidents the robot may set off now ([`INCIDENT_BURST`] at most), as of `refilled`.
    incident_tokens: f64,
    refilled: Instant,
    /// Triggers held back since the robot's last incident.
    held_back: usize,
}

/// What an operator's record request started.
pub(super) struct Requested {
    pub(super) from_s: f64,
    pub(super) until_s: f64,
    pub(super) path: std::path::PathBuf,
}

impl RobotRecording {
    /// Keeps a valid joint sample and its twin pose; the incident it is the first sample past,
    /// if any.
    pub(super) fn joints(
        &mut self,
        robot: &str,
        stamp_s: f64,
        sample: &JointSample,
        twin: &PoseReadout,
    ) -> Option<Incident> {
        if sample.q_rad.len() == self.joint_record.joint_count {
            let record = &mut self.scratch[..self.joint_record.stride()];
            self.joint_record.fill(record, stamp_s, sample, twin);
            self.joints.push(record);
        }
        // Past `until_s`, not at it: a sample stamped `until_s` has its measured pose paired
        // after this call.
        match &self.pending {
            Some(pending) if stamp_s > pending.until_s => self.cut(robot),
            _ => None,
        }
    }

    /// The robot computes with `model` from now on: files draw it, every sample they hold (an
    /// incident across a change draws the earlier samples with it too). Whether the rings go
    /// on: not when its joints are of another count (nothing changes then: the recording must
    /// cut its pending incident and start afresh).
    pub(super) fn follow_model(&mut self, model: &Arc<RobotModel>) -> bool {
        let same_count = model.joint_count() == self.joint_record.joint_count;
        if same_count {
            self.model = Arc::clone(model);
        }
        same_count
    }

    /// Keeps a paired measured pose and its deviation.
    pub(super) fn measured(&mut self, stamp_s: f64, measured: &PoseReadout, deviation: &Deviation) {
        let record = &mut self.scratch[..MEASURED_STRIDE];
        fill_measured(record, stamp_s, measured, deviation);
        self.measured.push(record);
    }

    /// Keeps an effort readout.
    pub(super) fn effort(&mut self, readout: &EffortReadout) {
        let record = &mut self.scratch[..EFFORT_STRIDE];
        fill_effort(record, readout);
        self.efforts.push(record);
    }

    /// Sets an incident off at `stamp_s` (or folds this trigger into the pending one, whose
    /// file it then also explains); `None` when the robot has set off its share of incidents
    /// lately ([`INCIDENT_BURST`]) and the trigger is held back.
    pub(super) fn trigger(
        &mut self,
        kind: &'static str,
        stamp_s: f64,
        text: String,
        (pre_s, post_s): (f64, f64),
    ) -> Option<&Trigger> {
        if self.pending.is_none() && kind != "operator" && !self.take_incident_token(post_s) {
            self.held_back += 1;
            return None;
        }
        let level = if kind == "operator" {
            LOG_INFO
        } else {
            LOG_WARN
        };
        let line = LogLine {
            stamp_s,
            level,
            text: text.clone(),
        };
        let pending = self.pending.get_or_insert_with(|| Pending {
            trigger: Trigger {
                kind,
                stamp_s,
                at: SystemTime::now(),
                event_json: text,
            },
            from_s: stamp_s - pre_s,
            until_s: stamp_s + post_s,
            deadline: Instant::now() + Duration::from_secs_f64(post_s) + STALLED_GRACE,
            log: Vec::new(),
            folded: 0,
        });
        if self.held_back > 0 {
            pending.log.push(LogLine {
                stamp_s,
                level: LOG_WARN,
                text: format!(
                    "{} triggers since this robot's last incident were held back: after {} \
                     incidents back to back, a robot sets off one per post_s",
                    self.held_back, INCIDENT_BURST
                ),
            });
            self.held_back = 0;
        }
        if pending.log.len() < MAX_LOG_LINES {
            pending.log.push(line);
        } else {
            pending.folded += 1;
        }
        Some(&pending.trigger)
    }

    /// Takes one of the robot's incident tokens, refilled at one per `post_s` (one per second
    /// at least) of wall time; `false` when none is left.
    fn take_incident_token(&mut self, post_s: f64) -> bool {
        let now = Instant::now();
        let period_s = post_s.max(1.0);
        let refill = now.duration_since(self.refilled).as_secs_f64() / period_s;
        self.incident_tokens = (self.incident_tokens + refill).min(INCIDENT_BURST);
        self.refilled = now;
        if self.incident_tokens < 1.0 {
            return false;
        }
        self.incident_tokens -= 1.0;
        true
    }

    /// An operator's request for the `pre_s` before the robot's newest sample and the `post_s`
    /// after; `None` before the robot's first sample.
    pub(super) fn request(&mut self, robot: &str, span: (f64, f64)) -> Option<Requested> {
        let stamp_s = self.joints.newest_s()?;
        let text = serde_json::json!({
            "robot": robot,
            "t": stamp_s,
            "kind": "record",
            "reason": "an operator asked for a recording",
            "detail": {"pre_s": span.0, "post_s": span.1},
        })
        .to_string();
        let trigger = self.trigger("operator", stamp_s, text, span)?.clone();
        let pending = self.pending.as_ref()?;
        Some(Requested {
            from_s: pending.from_s,
            until_s: pending.until_s,
            path: store::file_name(&Incident {
                robot: robot.to_owned(),
                trigger,
                ..self.empty_incident(robot)
            }),
        })
    }

    /// The pending incident, if its robot stopped streaming before its `post_s` passed.
    pub(super) fn cut_stalled(&mut self, robot: &str, now: Instant) -> Option<Incident> {
        match &self.pending {
            Some(pending) if now >= pending.deadline => self.cut(robot),
            _ => None,
        }
    }

    /// The pending incident with what the rings hold of its span, now.
    pub(super) fn cut(&mut self, robot: &str) -> Option<Incident> {
        let pending = self.pending.take()?;
        let mut incident = self.empty_incident(robot);
        self.joints
            .copy_range(pending.from_s, pending.until_s, &mut incident.joints);
        self.measured
            .copy_range(pending.from_s, pending.until_s, &mut incident.measured);
        self.efforts
            .copy_range(pending.from_s, pending.until_s, &mut incident.efforts);
        incident.log = pending.log;
        if pending.folded > 0 {
            incident.log.push(LogLine {
                stamp_s: pending.until_s,
                level: LOG_WARN,
                text: format!("{} more triggers in this incident", pending.folded),
            });
        }
        incident.trigger = pending.trigger;
        incident.from_s = pending.from_s;
        incident.until_s = pending.until_s;
        Some(incident)
    }

    fn empty_incident(&self, robot: &str) -> Incident {
        Incident {
            robot: robot.to_owned(),
            model: self.model.arm().name.clone(),
            calibration_source: self
                .model
                .calibration()
                .map_or_else(|| "nominal".to_owned(), |c| c.source_name.clone()),
            frame_id: self.model.frame().as_str().to_owned(),
            trigger: Trigger {
                kind: "",
                stamp_s: 0.0,
                at: SystemTime::now(),
                event_json: String::new(),
            },
            from_s: 0.0,
            until_s: 0.0,
            joint_record: self.joint_record,
            joints: Vec::new(),
            measured: Vec::new(),
            efforts: Vec::new(),
            log: Vec::new(),
            drawn: self.draw.then(|| Arc::clone(&self.model)),
        }
    }
}

/// The recorder of `config`, its writer thread started (without it, should the thread not
/// start, the rings run and nothing is written); each file's outcome goes out as an event of
/// its robot on `session`.
pub(super) fn start(config: &RecorderConfig, session: Session, keys: KeySpace) -> Recorder {
    let writer = store::spawn(config.store.clone(), move |outcome| {
        announce(&session, &keys, outcome);
    });
    let writer = match writer {
        Ok(writer) => Some(writer),
        Err(e) => {
            warn!(error = %e, "cannot start the recorder's writer thread: no incident file will be written");
            None
        }
    };
    Recorder::new(config.clone(), writer)
}

/// An outcome as an event on `<prefix>/events/<robot>`: `recorded` with the file's path, size
/// and span, or `record_failed` with why.
fn announce(session: &Session, keys: &KeySpace, outcome: &Outcome) {
    let (robot, body) = match outcome {
        Outcome::Recorded {
            robot,
            trigger,
            path,
            bytes,
            from_s,
            until_s,
            messages,
            write_s,
        } => (
            robot,
            serde_json::json!({
                "robot": robot,
                "t": until_s,
                "kind": "recorded",
                "reason": format!("{trigger}: {} written ({bytes} bytes)", path.display()),
                "detail": {
                    "trigger": trigger,
                    "path": path,
                    "bytes": bytes,
                    "from_s": from_s,
                    "until_s": until_s,
                    "messages": messages,
                    "write_s": write_s,
                },
            }),
        ),
        Outcome::Failed {
            robot,
            trigger,
            path,
            error,
        } => (
            robot,
            serde_json::json!({
                "robot": robot,
                "kind": "record_failed",
                "reason": format!("{trigger}: {} not written: {error}", path.display()),
                "detail": {"trigger": trigger, "path": path, "error": error},
            }),
        ),
    };
    let put = session
        .put(keys.key(Stream::Events, robot), body.to_string())
        .encoding(Encoding::APPLICATION_JSON)
        .congestion_control(CongestionControl::Block)
        .wait();
    if let Err(e) = put {
        warn!(robot, error = %e, "cannot publish the recorder's event");
    }
}
