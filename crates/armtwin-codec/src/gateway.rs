//! armtwin's own gateway messages (joints and measured poses, JSON or Zenoh-serialized) as
//! [`Decoder`]s, and such a message into the pipeline in one call, as `validate` and the
//! benchmarks take it.
//!
//! The decoder is chosen per message ([`Codec`]): armtwin's JSON ([`json`]), or Zenoh's own
//! serialization with one of armtwin's schemas ([`zser`]), as the sample's encoding says. The
//! encoding's name is read here; comparing Zenoh `Encoding` values is the transport's side.
//! Must not know the network, the filesystem or the clock.

use armtwin_core::pipeline::{self, MeasuredStream, Pipeline, Robot, Sink, Untracked};
use armtwin_core::sample::MeasuredSample;
use serde::Deserialize;

use crate::decoded::{Arrival, Decoded, Decoder, Refused};
use crate::json::{self, DecodedJoints, Undecodable, WireError};
use crate::zser;

/// How a source's payloads are encoded (`[[sources]] codec`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SourceCodec {
    /// armtwin's own messages, read as on armtwin's keys: JSON, or Zenoh's serialization when
    /// the sample's encoding says so.
    Json,
    /// Zenoh's serialization with the schema of the source's stream, whatever the encoding.
    ZenohSerialized,
    /// ROS 2 CDR: `sensor_msgs/msg/JointState` joints, `geometry_msgs/msg/PoseStamped` poses.
    Ros2,
}

impl SourceCodec {
    /// The configuration's name.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Json => "json",
            Self::ZenohSerialized => "zenoh-serialized",
            Self::Ros2 => "ros2",
        }
    }
}

/// How a gateway message's payload is decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Codec {
    /// armtwin's JSON messages ([`json`]).
    Json,
    /// Zenoh's own serialization ([`zser`]) with the schema the encoding names; `None` for a
    /// schema armtwin does not read (or none), which is rejected.
    ZenohSerialized(Option<zser::Schema>),
}

/// A Zenoh encoding's name for its serialization without a schema.
const ZENOH_SERIALIZED: &str = "zenoh/serialized";

impl Codec {
    /// The codec of a sample's encoding, by the encoding's text (`zenoh/serialized;<schema>`):
    /// `zenoh/serialized` (with its schema) is Zenoh's serialization; any other encoding, the
    /// default `zenoh/bytes` included, is JSON, so a gateway that sets none keeps working.
    #[must_use]
    pub fn from_encoding_name(encoding: &str) -> Self {
        if encoding == ZENOH_SERIALIZED {
            return Self::ZenohSerialized(None);
        }
        match encoding
            .strip_prefix(ZENOH_SERIALIZED)
            .and_then(|rest| rest.strip_prefix(';'))
        {
            Some(schema) => Self::ZenohSerialized(zser::Schema::from_name(schema)),
            None => Self::Json,
        }
    }

    /// The stamp a message of this codec offers without being decoded.
    #[must_use]
    pub fn stamp_hint(self, payload: &[u8]) -> Option<f64> {
        match self {
            Self::Json => json::stamp_hint(payload),
            Self::ZenohSerialized(_) => zser::stamp_hint(payload),
        }
    }

    /// A joint message of this codec, for an arm with `joint_count` joints.
    pub fn read_joints(
        self,
        payload: &[u8],
        joint_count: usize,
    ) -> Result<DecodedJoints, Undecodable> {
        match self {
            Self::Json => json::read_joints(payload, joint_count),
            Self::ZenohSerialized(Some(zser::Schema::Joints)) => {
                zser::read_joints(payload, joint_count)
            }
            Self::ZenohSerialized(Some(zser::Schema::JointsState)) => {
                zser::read_joints_with_state(payload, joint_count)
            }
            Self::ZenohSerialized(_) => Err(self.wrong_schema(payload, zser::Schema::Joints)),
        }
    }

    /// A measured-pose message of this codec.
    pub fn read_measured(self, payload: &[u8]) -> Result<MeasuredSample, Undecodable> {
        match self {
            Self::Json => json::read_measured(payload),
            Self::ZenohSerialized(Some(zser::Schema::Pose)) => zser::read_measured(payload),
            Self::ZenohSerialized(_) => Err(self.wrong_schema(payload, zser::Schema::Pose)),
        }
    }

    /// The error of a `zenoh/serialized` message on a key that takes `expected`.
    fn wrong_schema(self, payload: &[u8], expected: zser::Schema) -> Undecodable {
        Refused {
            error: WireError::Schema {
                expected: expected.as_str(),
            },
            stamp_s: self.stamp_hint(payload),
        }
    }
}

/// A gateway's joint messages (`<prefix>/joints/<robot>`), decoded against the robot's joint
/// count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Joints(pub Codec);

impl Decoder for Joints {
    type Message = DecodedJoints;
    type Error = WireError;

    fn read(&self, robot: &Robot, payload: &[u8]) -> Result<DecodedJoints, Undecodable> {
        self.0.read_joints(payload, robot.joint_count())
    }

    fn stamp_hint(&self, payload: &[u8]) -> Option<f64> {
        self.0.stamp_hint(payload)
    }
}

/// A gateway's measured poses (`<prefix>/measured/<robot>`, or a sensor's key).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pose(pub Codec);

impl Decoder for Pose {
    type Message = MeasuredSample;
    type Error = WireError;

    fn read(&self, _robot: &Robot, payload: &[u8]) -> Result<MeasuredSample, Undecodable> {
        self.0.read_measured(payload)
    }

    fn stamp_hint(&self, payload: &[u8]) -> Option<f64> {
        self.0.stamp_hint(payload)
    }
}

/// A joint message (optionally with an embedded measured pose) of `robot`, arrived on `key`.
pub fn joint_message(
    pipeline: &mut Pipeline,
    robot: &Robot,
    key: &str,
    codec: Codec,
    payload: &[u8],
    fallback_s: impl FnOnce() -> f64,
    sink: &mut impl Sink,
) {
    let message = Decoded::decode(&Joints(codec), robot, payload, fallback_s);
    message.step(pipeline.track(robot, sink), Arrival::on(key), sink);
}

/// A measured-pose message of `robot` from `stream`, arrived on `key`.
#[allow(
    clippy::too_many_arguments,
    reason = "what `Decoded::decode` and `step` take, in one call"
)]
pub fn measured_message(
    pipeline: &mut Pipeline,
    robot: &Robot,
    key: &str,
    stream: MeasuredStream,
    codec: Codec,
    payload: &[u8],
    fallback_s: impl FnOnce() -> f64,
    sink: &mut impl Sink,
) {
    let message = Decoded::decode(&Pose(codec), robot, payload, fallback_s);
    message.step(pipeline.track(robot, sink), Arrival { key, stream }, sink);
}

/// A message of a robot that may not be tracked (`robot` is the id its key names), for the
/// reason `why`: one rejection event at the best stamp `decoder` finds in it.
#[allow(
    clippy::too_many_arguments,
    reason = "one input: who, why, where, how, and its bytes"
)]
pub fn untracked_robot(
    robot: &str,
    why: Untracked,
    key: &str,
    decoder: &impl Decoder,
    payload: &[u8],
    fallback_s: impl FnOnce() -> f64,
    sink: &mut impl Sink,
) {
    let stamp_s = decoder.stamp_hint(payload).unwrap_or_else(fallback_s);
    pipeline::reject_untracked(robot, key, stamp_s, why, sink);
}
