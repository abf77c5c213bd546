//! A gateway message's bytes into the pipeline: the one path from payload to twin that the live
//! service and offline validation share, so a recording validated offline and the same recording
//! replayed into the service cannot disagree.
//!
//! Two steps, so a caller that shares the pipeline can decode without holding it: decoding
//! ([`JointMessage::decode`], [`MeasuredMessage::decode`]) needs only the robot's immutable
//! settings; stepping the pipeline with the result ([`JointMessage::step`],
//! [`MeasuredMessage::step`]) is the only part that touches the twin. [`joint_message`] and
//! [`measured_message`] do both.
//!
//! A message that does not decode becomes one rejection (an event and a count) at the best stamp
//! it offers; an invalid embedded `measured` part is rejected on its own while the joints it came
//! with still yield their pose. Must not know the network or the filesystem: callers pass the key
//! a message arrived on and how to get the stamp to use when the message carries none (the
//! transport's or the arrival time, read only then; or the recording's). Nothing is logged here:
//! the sink reports each rejection once.

use crate::codec::wire::{self, DecodedJoints, WireError};
use crate::pipeline::{self, MeasuredStream, Pipeline, Robot, Sink};
use crate::sample::MeasuredSample;

/// A joint message decoded against its robot's joint count, with the stamp it goes in at.
#[derive(Debug, Clone, PartialEq)]
pub struct JointMessage {
    stamp_s: f64,
    decoded: Result<DecodedJoints, WireError>,
}

impl JointMessage {
    /// Decodes `payload` for `robot`; `fallback_s` gives the stamp of a message without one.
    #[must_use]
    pub fn decode(robot: &Robot, payload: &[u8], fallback_s: impl FnOnce() -> f64) -> Self {
        // One pass: a refused message comes back with the best stamp it offers.
        match wire::read_joints(payload, robot.settings().model.joint_count()) {
            Ok(decoded) => Self {
                stamp_s: decoded.sample.stamp_s.unwrap_or_else(fallback_s),
                decoded: Ok(decoded),
            },
            Err(refused) => Self {
                stamp_s: refused.stamp_s.unwrap_or_else(fallback_s),
                decoded: Err(refused.error),
            },
        }
    }

    /// Steps `pipeline` with the message, which arrived on `key`.
    pub fn step(&self, pipeline: &mut Pipeline, robot: &Robot, key: &str, sink: &mut impl Sink) {
        match &self.decoded {
            Ok(decoded) => {
                if let Some(error) = &decoded.measured_error {
                    reject(pipeline, robot, key, self.stamp_s, error, sink);
                }
                pipeline.joints(robot, key, self.stamp_s, &decoded.sample, sink);
            }
            Err(error) => reject(pipeline, robot, key, self.stamp_s, error, sink),
        }
    }
}

/// A measured-pose message decoded, with the stamp it goes in at.
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredMessage {
    stamp_s: f64,
    decoded: Result<MeasuredSample, WireError>,
}

impl MeasuredMessage {
    /// Decodes `payload`; `fallback_s` gives the stamp of a message without one.
    #[must_use]
    pub fn decode(payload: &[u8], fallback_s: impl FnOnce() -> f64) -> Self {
        match wire::read_measured(payload) {
            Ok(measured) => Self {
                stamp_s: measured.stamp_s.unwrap_or_else(fallback_s),
                decoded: Ok(measured),
            },
            Err(refused) => Self {
                stamp_s: refused.stamp_s.unwrap_or_else(fallback_s),
                decoded: Err(refused.error),
            },
        }
    }

    /// Steps `pipeline` with the message of `robot`'s `stream`, which arrived on `key`.
    pub fn step(
        &self,
        pipeline: &mut Pipeline,
        robot: &Robot,
        key: &str,
        stream: MeasuredStream,
        sink: &mut impl Sink,
    ) {
        match &self.decoded {
            Ok(measured) => {
                pipeline.measured(robot, key, stream, self.stamp_s, &measured.pose, sink);
            }
            Err(error) => reject(pipeline, robot, key, self.stamp_s, error, sink),
        }
    }
}

/// A joint message (optionally with an embedded measured pose) of `robot`, arrived on `key`.
pub fn joint_message(
    pipeline: &mut Pipeline,
    robot: &Robot,
    key: &str,
    payload: &[u8],
    fallback_s: impl FnOnce() -> f64,
    sink: &mut impl Sink,
) {
    JointMessage::decode(robot, payload, fallback_s).step(pipeline, robot, key, sink);
}

/// A measured-pose message of `robot` from `stream`, arrived on `key`.
pub fn measured_message(
    pipeline: &mut Pipeline,
    robot: &Robot,
    key: &str,
    stream: MeasuredStream,
    payload: &[u8],
    fallback_s: impl FnOnce() -> f64,
    sink: &mut impl Sink,
) {
    MeasuredMessage::decode(payload, fallback_s).step(pipeline, robot, key, stream, sink);
}

/// A message of a robot that may not be tracked (`robot` is the id its key names): one
/// rejection event at the best stamp it offers.
pub fn unknown_robot(
    robot: &str,
    key: &str,
    payload: &[u8],
    fallback_s: impl FnOnce() -> f64,
    sink: &mut impl Sink,
) {
    let stamp_s = wire::stamp_hint(payload).unwrap_or_else(fallback_s);
    pipeline::reject_unknown_robot(robot, key, stamp_s, sink);
}

/// One rejection (event and count) for a message, or part of one, that did not decode.
fn reject(
    pipeline: &mut Pipeline,
    robot: &Robot,
    key: &str,
    stamp_s: f64,
    error: &WireError,
    sink: &mut impl Sink,
) {
    pipeline.reject(robot, key, stamp_s, error.cause(), error, sink);
}
