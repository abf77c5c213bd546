//! `armtwin validate`: a recording run offline through exactly the code the live service runs.
//!
//! Each entry becomes the bytes a gateway would publish ([`recording::payload`]: a row's joint
//! message, a malformed line's raw text), which go through [`ingest::joint_message`] into a
//! [`Pipeline`] configured like the service's. What comes out is collected per row, so the
//! report can name the line of every rejection and plot every pair. This module owns the run and
//! its result; [`report`] writes the files and [`svg`] draws the plots; [`dynamics`] compares a
//! UR RTDE recording's joint torques with the model (`--dynamics`). It does no I/O itself.

pub mod dynamics;
pub mod report;
pub mod svg;

use std::collections::HashMap;

use armtwin_codec::gateway::Joints;
use armtwin_codec::recording::{self, Format, Recording};
use armtwin_core::kinematics::{OutputFrame, PoseReadout};
use armtwin_core::metrics::{Deviation, StatsSet};
use armtwin_core::pipeline::{
    Event, EventDetail, EventKind, MetricsReadout, Pipeline, PipelineConfig, Robot, RobotDirectory,
    RobotSettings, Sink, Untracked,
};
use armtwin_mesh::ingest::{self, Codec};
use armtwin_mesh::keys::{KeySpace, Stream};

/// One recording row's outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct RowOutcome {
    /// 1-based line in the file.
    pub line: u64,
    /// Source time given to the row (s).
    pub stamp_s: f64,
    /// The twin pose, if the row's joints were valid.
    pub twin: Option<PoseReadout>,
    /// The measured pose (output frame) and twin-minus-measured, if the row was paired.
    pub paired: Option<(PoseReadout, Deviation)>,
    /// Causes of the rejections this row raised (empty when it was accepted whole).
    pub rejected: Vec<&'static str>,
}

/// One rejected input, with where it came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rejection {
    /// 1-based line in the file.
    pub line: u64,
    /// Stable cause name, as on the service's events key.
    pub cause: &'static str,
    /// A sentence for people.
    pub reason: String,
}

/// Counts of the non-rejection events the pipeline raised.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EventCounts {
    /// Deviations that stayed above a configured alarm threshold.
    pub alarms: u64,
    /// Alarms that recovered.
    pub recoveries: u64,
    /// Gaps in joint stamps or gateway sequence numbers.
    pub gaps: u64,
    /// Measured poses that could not be paired.
    pub unpaired: u64,
    /// Clock restarts.
    pub restarts: u64,
}

/// The result of validating one recording.
#[derive(Debug, Clone)]
pub struct Validation {
    /// The layout recognised.
    pub format: Format,
    /// Whether the recording carries measured poses.
    pub has_pose: bool,
    /// The output frame of every pose.
    pub frame: OutputFrame,
    /// One entry per data line (rows and malformed lines), in file order.
    pub rows: Vec<RowOutcome>,
    /// Every rejection, in file order.
    pub rejections: Vec<Rejection>,
    /// Lines that did not split into the header's columns (also among `rejections`).
    pub malformed_lines: Vec<u64>,
    /// Other events.
    pub events: EventCounts,
    /// Final metrics, exactly as the service publishes them at the end of a stream.
    pub metrics: MetricsReadout,
}

impl Validation {
    /// Rows whose joints yielded a twin pose.
    #[must_use]
    pub fn poses(&self) -> usize {
        self.rows.iter().filter(|r| r.twin.is_some()).count()
    }
}

/// Collects the pipeline's results per row.
struct Collector {
    frame: OutputFrame,
    /// Index of the row being fed.
    current: usize,
    rows: Vec<RowOutcome>,
    /// Row index of each source time given, to place results that arrive later (a measured pose
    /// that waited for joints).
    row_of_stamp: HashMap<u64, usize>,
    rejections: Vec<Rejection>,
    events: EventCounts,
    metrics: Option<MetricsReadout>,
}

impl Collector {
    fn row_at(&mut self, stamp_s: f64) -> &mut RowOutcome {
        let index = self
            .row_of_stamp
            .get(&stamp_s.to_bits())
            .copied()
            .unwrap_or(self.current);
        &mut self.rows[index]
    }
}

impl Sink for Collector {
    fn pose(
        &mut self,
        _robot: &Robot,
        stamp_s: f64,
        _seq: u64,
        frame: OutputFrame,
        pose: &PoseReadout,
    ) {
        self.frame = frame;
        self.row_at(stamp_s).twin = Some(*pose);
    }

    fn deviation(
        &mut self,
        _robot: &Robot,
        stamp_s: f64,
        measured: &PoseReadout,
        deviation: &Deviation,
    ) {
        self.row_at(stamp_s).paired = Some((*measured, *deviation));
    }

    fn event(&mut self, event: &Event<'_>) {
        match (event.kind, event.detail) {
            (EventKind::Rejected, EventDetail::Rejected { cause }) => {
                // A rejection always concerns the input being fed.
                let row = &mut self.rows[self.current];
                row.rejected.push(cause.as_str());
                let line = row.line;
                self.rejections.push(Rejection {
                    line,
                    cause: cause.as_str(),
                    reason: event.to_string(),
                });
            }
            (EventKind::Alarm, _) => self.events.alarms += 1,
            (EventKind::Recovered, _) => self.events.recoveries += 1,
            (EventKind::Gap, _) => self.events.gaps += 1,
            (EventKind::Unpaired, _) => self.events.unpaired += 1,
            (EventKind::Restart, _) => self.events.restarts += 1,
            // Validation never replaces its model.
            (EventKind::Rejected | EventKind::Epoch, _) => {}
        }
    }

    fn metrics(&mut self, _robot: &Robot, readout: &MetricsReadout) {
        self.metrics = Some(readout.clone());
    }
}

/// The robot id a validation runs as (it appears in the report's metrics).
pub const ROBOT_ID: &str = "recording";

/// Runs `recording`, whose entries have source times `times_s`, through a pipeline with
/// `config` and `settings`, calling `progress` with the number of entries done.
///
/// # Panics
/// If `times_s` is shorter than the recording's entries (use
/// [`armtwin_codec::recording::source_times`]).
#[must_use]
pub fn validate(
    recording: &Recording,
    times_s: &[f64],
    config: PipelineConfig,
    settings: RobotSettings,
    mut progress: impl FnMut(usize),
) -> Validation {
    assert!(
        times_s.len() >= recording.entries.len(),
        "a source time per entry"
    );
    let frame = settings.model.frame();
    let robot = RobotDirectory::new(None, HashMap::from([(ROBOT_ID.to_owned(), settings)]))
        .find(ROBOT_ID)
        .cloned();
    let mut pipeline = Pipeline::new(config);
    let mut collector = Collector {
        frame,
        current: 0,
        rows: Vec::with_capacity(recording.entries.len()),
        row_of_stamp: HashMap::with_capacity(recording.entries.len()),
        rejections: Vec::new(),
        events: EventCounts::default(),
        metrics: None,
    };
    // The key a live sample of the robot would come on, named in the rejections as the service
    // names them.
    let key = KeySpace::default().key(Stream::Joints, ROBOT_ID);
    let mut malformed_lines = Vec::new();
    for (index, (entry, &stamp_s)) in recording.entries.iter().zip(times_s).enumerate() {
        let line = match entry {
            Ok(row) => row.line,
            Err(malformed) => malformed.line,
        };
        collector.current = collector.rows.len();
        collector.rows.push(RowOutcome {
            line,
            stamp_s,
            twin: None,
            paired: None,
            rejected: Vec::new(),
        });
        collector
            .row_of_stamp
            .entry(stamp_s.to_bits())
            .or_insert(collector.current);
        if let Err(malformed) = entry {
            malformed_lines.push(malformed.line);
        }
        let rejections_before = collector.rejections.len();
        let payload = recording::payload(entry, stamp_s);
        match &robot {
            Some(robot) => {
                ingest::joint_message(
                    &mut pipeline,
                    robot,
                    &key,
                    Codec::Json,
                    &payload,
                    || stamp_s,
                    &mut collector,
                );
            }
            None => ingest::untracked_robot(
                ROBOT_ID,
                Untracked::Unknown,
                &key,
                &Joints(Codec::Json),
                &payload,
                || stamp_s,
                &mut collector,
            ),
        }
        if let Err(malformed) = entry {
            // The service sees only the message; the file also knows why the line is bad.
            for rejection in &mut collector.rejections[rejections_before..] {
                rejection.reason = format!(
                    "malformed line ({}); as a message: {}",
                    malformed.problem, rejection.reason
                );
            }
        }
        progress(index + 1);
    }
    pipeline.finish(&mut collector);
    // A recording without data lines never tracks the robot: its metrics are all zero.
    let metrics = collector.metrics.take().unwrap_or_else(|| MetricsReadout {
        robot: ROBOT_ID.to_owned(),
        stamp_s: 0.0,
        paired: 0,
        unpaired: 0,
        rejected: 0,
        cumulative: StatsSet::default(),
        window: StatsSet::default(),
        window_s: config.window_s,
        epoch: 0,
        effort: None,
    });
    Validation {
        format: recording.format,
        has_pose: recording.has_pose,
        frame: collector.frame,
        rows: collector.rows,
        rejections: collector.rejections,
        malformed_lines,
        events: collector.events,
        metrics,
    }
}
