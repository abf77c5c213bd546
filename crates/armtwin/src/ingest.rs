//! A gateway message's bytes into the pipeline: the one path from payload to twin that the live
//! service and offline validation share, so a recording validated offline and the same recording
//! replayed into the service cannot disagree.
//!
//! A message that does not decode becomes one rejection (an event and a count) at the best stamp
//! it offers; an invalid embedded `measured` part is rejected on its own while the joints it came
//! with still yield their pose. Must not know the network or the filesystem: callers pass the key
//! a message arrived on and how to get the stamp to use when the message carries none (the
//! transport's or the arrival time, read only then; or the recording's).

use tracing::debug;

use crate::codec::wire::{self, WireError};
use crate::pipeline::{MeasuredStream, Pipeline, Sink};

/// A joint message (optionally with an embedded measured pose) of `robot`, arrived on `key`.
pub fn joint_message(
    pipeline: &mut Pipeline,
    robot: &str,
    key: &str,
    payload: &[u8],
    fallback_s: impl FnOnce() -> f64,
    sink: &mut impl Sink,
) {
    let Some(settings) = pipeline.settings_for(robot) else {
        let stamp_s = wire::stamp_hint(payload).unwrap_or_else(fallback_s);
        pipeline.reject_unknown_robot(robot, key, stamp_s, sink);
        return;
    };
    match wire::read_joints(payload, settings.model.joint_count()) {
        Ok(decoded) => {
            let stamp_s = decoded.sample.stamp_s.unwrap_or_else(fallback_s);
            if let Some(error) = decoded.measured_error {
                reject(pipeline, robot, key, stamp_s, &error, sink);
            }
            pipeline.joints(robot, key, stamp_s, &decoded.sample, sink);
        }
        Err(refused) => {
            let stamp_s = refused.stamp_s.unwrap_or_else(fallback_s);
            reject(pipeline, robot, key, stamp_s, &refused.error, sink);
        }
    }
}

/// A measured-pose message of `robot` from `stream`, arrived on `key`.
pub fn measured_message(
    pipeline: &mut Pipeline,
    robot: &str,
    key: &str,
    stream: MeasuredStream,
    payload: &[u8],
    fallback_s: impl FnOnce() -> f64,
    sink: &mut impl Sink,
) {
    if pipeline.settings_for(robot).is_none() {
        let stamp_s = wire::stamp_hint(payload).unwrap_or_else(fallback_s);
        pipeline.reject_unknown_robot(robot, key, stamp_s, sink);
        return;
    }
    match wire::read_measured(payload) {
        Ok(measured) => {
            let stamp_s = measured.stamp_s.unwrap_or_else(fallback_s);
            pipeline.measured(robot, key, stream, stamp_s, &measured.pose, sink);
        }
        Err(refused) => {
            let stamp_s = refused.stamp_s.unwrap_or_else(fallback_s);
            reject(pipeline, robot, key, stamp_s, &refused.error, sink);
        }
    }
}

/// One rejection (event and count) for a message, or part of one, that did not decode.
fn reject(
    pipeline: &mut Pipeline,
    robot: &str,
    key: &str,
    stamp_s: f64,
    error: &WireError,
    sink: &mut impl Sink,
) {
    debug!(%robot, %key, %error, "input rejected");
    pipeline.reject(robot, key, stamp_s, error.kind(), error.to_string(), sink);
}
