//! The one seam between the twin core and whoever takes its results: the [`Sink`] trait.
//!
//! Owns the list of result kinds a twin gives. Must not know any receiver (the service's Zenoh
//! publishers, validation's report, a benchmark): they implement the trait elsewhere. Only
//! [`Sink::pose`] is required; every other result is defaulted to nothing, so a new kind of
//! result edits this trait and the sinks that want it, not every sink.

use super::{Event, MetricsReadout, Robot};
use crate::dynamics::monitor::EffortReadout;
use crate::kinematics::{OutputFrame, PoseReadout};
use crate::metrics::Deviation;
use crate::sample::JointSample;

/// Where the pipeline's results go. Every result names its robot by [`Robot`] (or, for events,
/// [`Event::index`]), whose [`RobotIndex`](super::RobotIndex) lets a sink keep per-robot state
/// in a `Vec`.
///
/// Only [`pose`](Sink::pose), the result of every valid joint sample, must be written; the rest
/// do nothing unless a sink overrides them:
///
/// ```
/// use armtwin_core::kinematics::{OutputFrame, PoseReadout};
/// use armtwin_core::pipeline::{Robot, Sink};
///
/// /// Counts twin poses and ignores everything else.
/// struct PoseCount(u64);
///
/// impl Sink for PoseCount {
///     fn pose(&mut self, _: &Robot, _: f64, _: u64, _: OutputFrame, _: &PoseReadout) {
///         self.0 += 1;
///     }
/// }
/// ```
pub trait Sink {
    /// The twin pose of a valid joint sample.
    fn pose(
        &mut self,
        robot: &Robot,
        stamp_s: f64,
        seq: u64,
        frame: OutputFrame,
        pose: &PoseReadout,
    );

    /// A valid joint sample as it came in, with its twin pose (right after [`Sink::pose`]): for
    /// a sink that keeps the inputs themselves (the service's flight recorder).
    fn joints(&mut self, robot: &Robot, stamp_s: f64, sample: &JointSample, twin: &PoseReadout) {
        let _ = (robot, stamp_s, sample, twin);
    }

    /// A robot is tracked from now on (declare its outputs, its liveliness token).
    fn tracking(&mut self, robot: &Robot) {
        let _ = robot;
    }

    /// Twin minus measured, for a paired measured pose (given in the output frame).
    fn deviation(
        &mut self,
        robot: &Robot,
        stamp_s: f64,
        measured: &PoseReadout,
        deviation: &Deviation,
    ) {
        let _ = (robot, stamp_s, measured, deviation);
    }

    /// An event (its sentence, if the sink wants one, is its `Display`).
    fn event(&mut self, event: &Event<'_>) {
        let _ = event;
    }

    /// The effort of a joint sample of a robot whose effort is watched.
    fn effort(&mut self, robot: &Robot, readout: &EffortReadout) {
        let _ = (robot, readout);
    }

    /// A metrics readout of `robot`.
    fn metrics(&mut self, robot: &Robot, readout: &MetricsReadout) {
        let _ = (robot, readout);
    }
}
