//! Sinks any mode can use as they are: [`Discard`] drops every result, [`Record`] keeps every
//! result, owned and in order.
//!
//! Owns no receiver of its own: the service publishes, validation writes a report, each with its
//! own sink. Must not format anything a receiver would want formatted differently: a recorded
//! event keeps its sentence only because [`Event`] borrows what it says.

use super::{Event, EventDetail, EventKind, MetricsReadout, Robot, RobotIndex, Sink};
use crate::kinematics::{OutputFrame, PoseReadout};
use crate::metrics::Deviation;

/// A sink that drops every result: for measuring the pipeline alone (benchmarks, tests).
#[derive(Debug, Clone, Copy, Default)]
pub struct Discard;

impl Sink for Discard {
    fn pose(&mut self, _: &Robot, _: f64, _: u64, _: OutputFrame, _: &PoseReadout) {}
}

/// A sink that keeps every result in the order it came: for comparing two runs, or asserting on
/// what a twin gave (tests, a caller that looks at results only after a run).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Record {
    /// Every result, oldest first.
    pub results: Vec<Recorded>,
}

/// One result a [`Record`] kept.
#[derive(Debug, Clone, PartialEq)]
pub enum Recorded {
    /// [`Sink::tracking`]: the robot tracked from then on.
    Tracking(RobotIndex),
    /// [`Sink::pose`].
    Pose(RecordedPose),
    /// [`Sink::deviation`].
    Deviation(RecordedDeviation),
    /// [`Sink::event`].
    Event(RecordedEvent),
    /// [`Sink::metrics`] (the readout names its robot; boxed, as it outweighs the rest).
    Metrics(Box<MetricsReadout>),
}

/// A twin pose as a [`Record`] keeps it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordedPose {
    /// Its robot.
    pub robot: RobotIndex,
    /// Source time (s).
    pub stamp_s: f64,
    /// The pose's sequence number.
    pub seq: u64,
    /// The frame it is given in.
    pub frame: OutputFrame,
    /// The pose.
    pub pose: PoseReadout,
}

/// A deviation as a [`Record`] keeps it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordedDeviation {
    /// Its robot.
    pub robot: RobotIndex,
    /// Source time (s) of the measured pose.
    pub stamp_s: f64,
    /// The measured pose, in the output frame.
    pub measured: PoseReadout,
    /// Twin minus measured.
    pub deviation: Deviation,
}

/// An [`Event`] as a [`Record`] keeps it: owned, with its sentence written.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedEvent {
    /// Robot id.
    pub robot: String,
    /// The robot's index; `None` for a robot that is neither configured nor defaulted.
    pub index: Option<RobotIndex>,
    /// Source time (s).
    pub stamp_s: f64,
    /// What it reports.
    pub kind: EventKind,
    /// The key of the input concerned, if any.
    pub key: Option<String>,
    /// Its structured details.
    pub detail: EventDetail,
    /// Its sentence ([`Event`]'s `Display`).
    pub sentence: String,
}

impl Record {
    /// The robots tracked, in order.
    pub fn tracked(&self) -> impl Iterator<Item = RobotIndex> + '_ {
        self.results.iter().filter_map(|result| match result {
            Recorded::Tracking(robot) => Some(*robot),
            _ => None,
        })
    }

    /// The twin poses, in order.
    pub fn poses(&self) -> impl Iterator<Item = &RecordedPose> {
        self.results.iter().filter_map(|result| match result {
            Recorded::Pose(pose) => Some(pose),
            _ => None,
        })
    }

    /// The deviations, in order.
    pub fn deviations(&self) -> impl Iterator<Item = &RecordedDeviation> {
        self.results.iter().filter_map(|result| match result {
            Recorded::Deviation(deviation) => Some(deviation),
            _ => None,
        })
    }

    /// The events, in order.
    pub fn events(&self) -> impl Iterator<Item = &RecordedEvent> {
        self.results.iter().filter_map(|result| match result {
            Recorded::Event(event) => Some(event),
            _ => None,
        })
    }

    /// The metrics snapshots, in order.
    pub fn metrics(&self) -> impl Iterator<Item = &MetricsReadout> {
        self.results.iter().filter_map(|result| match result {
            Recorded::Metrics(readout) => Some(&**readout),
            _ => None,
        })
    }
}

impl Sink for Record {
    fn pose(
        &mut self,
        robot: &Robot,
        stamp_s: f64,
        seq: u64,
        frame: OutputFrame,
        pose: &PoseReadout,
    ) {
        self.results.push(Recorded::Pose(RecordedPose {
            robot: robot.index(),
            stamp_s,
            seq,
            frame,
            pose: *pose,
        }));
    }

    fn tracking(&mut self, robot: &Robot) {
        self.results.push(Recorded::Tracking(robot.index()));
    }

    fn deviation(
        &mut self,
        robot: &Robot,
        stamp_s: f64,
        measured: &PoseReadout,
        deviation: &Deviation,
    ) {
        self.results.push(Recorded::Deviation(RecordedDeviation {
            robot: robot.index(),
            stamp_s,
            measured: *measured,
            deviation: *deviation,
        }));
    }

    fn event(&mut self, event: &Event<'_>) {
        self.results.push(Recorded::Event(RecordedEvent {
            robot: event.robot.to_owned(),
            index: event.index,
            stamp_s: event.stamp_s,
            kind: event.kind,
            key: event.key.map(str::to_owned),
            detail: event.detail,
            sentence: event.to_string(),
        }));
    }

    fn metrics(&mut self, _robot: &Robot, readout: &MetricsReadout) {
        self.results
            .push(Recorded::Metrics(Box::new(readout.clone())));
    }
}
