//! A decoded joint message ([`DecodedJoints`]) and what it does to the twin: what the general
//! reader (`decode`) and its fast path (`fast`) both return.
//!
//! Must not read bytes: the readers beside it do.

use armtwin_core::pipeline::{Sink, Twin};
use armtwin_core::sample::JointSample;

use super::WireError;
use crate::decoded::{Arrival, Message, reject};

/// A decoded joint message: the joint sample, and the error of its `measured` part when that
/// part was invalid (the joint sample stays valid: a bad pose reading must not cost the twin its
/// joint sample).
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedJoints {
    /// The joint sample (its `measured` is `None` when the part was invalid).
    pub sample: JointSample,
    /// Why the embedded `measured` part was refused, if it was.
    pub measured_error: Option<WireError>,
    /// Why the joint state beside the angles was refused, if it was (the sample then has none).
    pub state_error: Option<WireError>,
}

/// A gateway's joint message: an invalid embedded measured part is rejected on its own, and the
/// joints it came with still yield their pose.
impl Message for DecodedJoints {
    fn stamp_s(&self) -> Option<f64> {
        self.sample.stamp_s
    }

    fn step(&self, twin: &mut Twin, arrival: Arrival<'_>, stamp_s: f64, sink: &mut impl Sink) {
        for error in [&self.measured_error, &self.state_error]
            .into_iter()
            .flatten()
        {
            reject(twin, arrival.key, stamp_s, error, sink);
        }
        twin.joints(arrival.key, stamp_s, &self.sample, sink);
    }
}
