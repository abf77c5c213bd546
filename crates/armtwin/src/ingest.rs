//! A gateway message's bytes into the pipeline: the one path from payload to twin that the live
//! service and offline validation share, so a recording validated offline and the same recording
//! replayed into the service cannot disagree.
//!
//! Two steps, so a caller that shares the pipeline can decode without holding it: decoding
//! ([`JointMessage::decode`], [`MeasuredMessage::decode`]) needs only the robot's immutable
//! settings; stepping the robot's [`Twin`] with the result ([`JointMessage::step`],
//! [`MeasuredMessage::step`]) is the only part that touches it: offline the twin comes from the
//! [`Pipeline`] ([`Pipeline::track`]), in the service from the robot's own locked entry.
//! [`joint_message`] and [`measured_message`] do both. ROS 2 messages of a `codec = "ros2"` source take the same two
//! steps ([`Ros2JointMessage`], [`Ros2PoseMessage`]) into the same pipeline calls.
//!
//! The decoder is chosen per message ([`Codec`]): armtwin's JSON, or Zenoh's own serialization
//! with one of armtwin's schemas ([`zser`]), as the sample's encoding says (a Zenoh `Encoding`
//! is a value: reading one needs no session).
//!
//! A message that does not decode becomes one rejection (an event and a count) at the best stamp
//! it offers; an invalid embedded `measured` part is rejected on its own while the joints it came
//! with still yield their pose. Must not know the network or the filesystem: callers pass the key
//! a message arrived on and how to get the stamp to use when the message carries none (the
//! transport's or the arrival time, read only then; or the recording's). Nothing is logged here:
//! the sink reports each rejection once.

use std::borrow::Cow;
use std::sync::LazyLock;

use serde::Deserialize;
use zenoh::bytes::Encoding;

use crate::codec::cdr::{self, CdrError, JointNames};
use crate::codec::wire::{self, DecodedJoints, Undecodable, WireError};
use crate::codec::zser;
use crate::pipeline::{self, MeasuredStream, Pipeline, RejectCause, Robot, Sink, Twin};
use crate::ros2::AttachmentError;
use crate::sample::{JointSample, MeasuredSample};

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

/// How a message's payload is decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Codec {
    /// armtwin's JSON messages ([`wire`]).
    Json,
    /// Zenoh's own serialization ([`zser`]) with the schema the encoding names; `None` for a
    /// schema armtwin does not read (or none), which is rejected.
    ZenohSerialized(Option<zser::Schema>),
}

/// `zenoh/serialized;armtwin/joints/v1`, built once: comparing with it needs no allocation.
static JOINTS_ENCODING: LazyLock<Encoding> =
    LazyLock::new(|| Encoding::ZENOH_SERIALIZED.with_schema(zser::JOINTS_SCHEMA));
/// `zenoh/serialized;armtwin/pose/v1`.
static POSE_ENCODING: LazyLock<Encoding> =
    LazyLock::new(|| Encoding::ZENOH_SERIALIZED.with_schema(zser::POSE_SCHEMA));

impl Codec {
    /// The codec of a sample's encoding: `zenoh/serialized` (with its schema) is Zenoh's
    /// serialization; any other encoding, the default `zenoh/bytes` included, is JSON, so a
    /// gateway that sets none keeps working.
    #[must_use]
    pub fn from_encoding(encoding: &Encoding) -> Self {
        if *encoding == *JOINTS_ENCODING {
            return Self::ZenohSerialized(Some(zser::Schema::Joints));
        }
        if *encoding == *POSE_ENCODING {
            return Self::ZenohSerialized(Some(zser::Schema::Pose));
        }
        if *encoding == Encoding::ZENOH_SERIALIZED {
            return Self::ZenohSerialized(None);
        }
        // Allocates only for an encoding with a schema, which JSON gateways rarely set.
        let text = Cow::<str>::from(encoding);
        match text.strip_prefix("zenoh/serialized;") {
            Some(schema) => Self::ZenohSerialized(zser::Schema::from_name(schema)),
            None => Self::Json,
        }
    }

    /// The stamp a message of this codec offers without being decoded.
    fn stamp_hint(self, payload: &[u8]) -> Option<f64> {
        match self {
            Self::Json => wire::stamp_hint(payload),
            Self::ZenohSerialized(_) => zser::stamp_hint(payload),
        }
    }

    /// The error of a `zenoh/serialized` message on a key that takes `expected`.
    fn wrong_schema(self, payload: &[u8], expected: zser::Schema) -> Undecodable {
        Undecodable {
            error: WireError::Schema {
                expected: expected.as_str(),
            },
            stamp_s: self.stamp_hint(payload),
        }
    }
}

/// A joint message decoded against its robot's joint count, with the stamp it goes in at.
#[derive(Debug, Clone, PartialEq)]
pub struct JointMessage {
    stamp_s: f64,
    decoded: Result<DecodedJoints, WireError>,
}

impl JointMessage {
    /// Decodes `payload` with `codec` for `robot`; `fallback_s` gives the stamp of a message
    /// without one.
    #[must_use]
    pub fn decode(
        robot: &Robot,
        codec: Codec,
        payload: &[u8],
        fallback_s: impl FnOnce() -> f64,
    ) -> Self {
        let joint_count = robot.settings().model.joint_count();
        // One pass: a refused message comes back with the best stamp it offers.
        let read = match codec {
            Codec::Json => wire::read_joints(payload, joint_count),
            Codec::ZenohSerialized(Some(zser::Schema::Joints)) => {
                zser::read_joints(payload, joint_count)
            }
            Codec::ZenohSerialized(_) => Err(codec.wrong_schema(payload, zser::Schema::Joints)),
        };
        match read {
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

    /// Steps the robot's `twin` with the message, which arrived on `key`.
    pub fn step(&self, twin: &mut Twin, key: &str, sink: &mut impl Sink) {
        match &self.decoded {
            Ok(decoded) => {
                if let Some(error) = &decoded.measured_error {
                    reject(twin, key, self.stamp_s, error, sink);
                }
                twin.joints(key, self.stamp_s, &decoded.sample, sink);
            }
            Err(error) => reject(twin, key, self.stamp_s, error, sink),
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
    /// Decodes `payload` with `codec`; `fallback_s` gives the stamp of a message without one.
    #[must_use]
    pub fn decode(codec: Codec, payload: &[u8], fallback_s: impl FnOnce() -> f64) -> Self {
        let read = match codec {
            Codec::Json => wire::read_measured(payload),
            Codec::ZenohSerialized(Some(zser::Schema::Pose)) => zser::read_measured(payload),
            Codec::ZenohSerialized(_) => Err(codec.wrong_schema(payload, zser::Schema::Pose)),
        };
        match read {
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

    /// Steps the robot's `twin` with the message of its `stream`, which arrived on `key`.
    pub fn step(&self, twin: &mut Twin, key: &str, stream: MeasuredStream, sink: &mut impl Sink) {
        match &self.decoded {
            Ok(measured) => {
                twin.measured(key, stream, self.stamp_s, &measured.pose, sink);
            }
            Err(error) => reject(twin, key, self.stamp_s, error, sink),
        }
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
    let message = JointMessage::decode(robot, codec, payload, fallback_s);
    message.step(pipeline.track(robot, sink), key, sink);
}

/// A measured-pose message of `robot` from `stream`, arrived on `key`.
#[allow(
    clippy::too_many_arguments,
    reason = "what `MeasuredMessage::decode` and `step` take, in one call"
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
    let message = MeasuredMessage::decode(codec, payload, fallback_s);
    message.step(pipeline.track(robot, sink), key, stream, sink);
}

/// A message of a robot that may not be tracked (`robot` is the id its key names): one
/// rejection event at the best stamp it offers.
pub fn unknown_robot(
    robot: &str,
    key: &str,
    codec: Codec,
    payload: &[u8],
    fallback_s: impl FnOnce() -> f64,
    sink: &mut impl Sink,
) {
    let stamp_s = codec.stamp_hint(payload).unwrap_or_else(fallback_s);
    pipeline::reject_unknown_robot(robot, key, stamp_s, sink);
}

/// One rejection (event and count) for a message, or part of one, that did not decode.
fn reject(twin: &mut Twin, key: &str, stamp_s: f64, error: &WireError, sink: &mut impl Sink) {
    twin.reject(key, stamp_s, error.cause(), error, sink);
}

/// A ROS 2 `sensor_msgs/msg/JointState` decoded for its robot (joints matched by name), with the
/// stamp it goes in at: `header.stamp`, else the caller's fallback.
#[derive(Debug, Clone, PartialEq)]
pub struct Ros2JointMessage {
    stamp_s: f64,
    decoded: Result<JointSample, CdrError>,
}

impl Ros2JointMessage {
    /// Decodes `payload` for the arm whose `JointState` names are `joint_names`.
    #[must_use]
    pub fn decode(
        payload: &[u8],
        joint_names: &JointNames,
        fallback_s: impl FnOnce() -> f64,
    ) -> Self {
        let decoded = cdr::decode_joint_state(payload, joint_names);
        Self {
            stamp_s: cdr_stamp_s(&decoded, |s| s.stamp_s, payload, fallback_s),
            decoded,
        }
    }

    /// The stamp the message goes in at (s).
    #[must_use]
    pub fn stamp_s(&self) -> f64 {
        self.stamp_s
    }

    /// Gives the sample the gateway sequence number `seq` (the `rmw_zenoh` attachment's).
    pub fn set_seq(&mut self, seq: u64) {
        if let Ok(sample) = &mut self.decoded {
            sample.seq = Some(seq);
        }
    }

    /// Steps the robot's `twin` with the message, which arrived on `key`.
    pub fn step(&self, twin: &mut Twin, key: &str, sink: &mut impl Sink) {
        match &self.decoded {
            Ok(sample) => twin.joints(key, self.stamp_s, sample, sink),
            Err(error) => twin.reject(key, self.stamp_s, error.cause(), error, sink),
        }
    }
}

/// The stamp a CDR message goes in at: its `header.stamp`, or for a refused one what its header
/// still offers, else `fallback_s`.
fn cdr_stamp_s<T>(
    decoded: &Result<T, CdrError>,
    stamp_of: impl FnOnce(&T) -> Option<f64>,
    payload: &[u8],
    fallback_s: impl FnOnce() -> f64,
) -> f64 {
    match decoded {
        Ok(sample) => stamp_of(sample),
        Err(_) => cdr::stamp_hint(payload),
    }
    .unwrap_or_else(fallback_s)
}

/// A ROS 2 `geometry_msgs/msg/PoseStamped` decoded, its frame checked, with the stamp it goes in
/// at: `header.stamp`, else the caller's fallback.
#[derive(Debug, Clone, PartialEq)]
pub struct Ros2PoseMessage {
    stamp_s: f64,
    decoded: Result<MeasuredSample, CdrError>,
}

impl Ros2PoseMessage {
    /// Decodes `payload`, a pose in `expected_frame` (the robot's `<tf_prefix>base`).
    #[must_use]
    pub fn decode(payload: &[u8], expected_frame: &str, fallback_s: impl FnOnce() -> f64) -> Self {
        let decoded = cdr::decode_pose_stamped_in(payload, expected_frame).map(|pose| pose.sample);
        Self {
            stamp_s: cdr_stamp_s(&decoded, |s| s.stamp_s, payload, fallback_s),
            decoded,
        }
    }

    /// The stamp the message goes in at (s).
    #[must_use]
    pub fn stamp_s(&self) -> f64 {
        self.stamp_s
    }

    /// Steps the robot's `twin` with the pose of its `stream`, which arrived on `key`.
    pub fn step(&self, twin: &mut Twin, key: &str, stream: MeasuredStream, sink: &mut impl Sink) {
        match &self.decoded {
            Ok(measured) => {
                twin.measured(key, stream, self.stamp_s, &measured.pose, sink);
            }
            Err(error) => twin.reject(key, self.stamp_s, error.cause(), error, sink),
        }
    }
}

/// One rejection (event and count) for an `rmw_zenoh` attachment that does not parse; the
/// sample it came with is stepped on its own, without a sequence number.
pub fn reject_attachment(
    twin: &mut Twin,
    key: &str,
    stamp_s: f64,
    error: &AttachmentError,
    sink: &mut impl Sink,
) {
    twin.reject(key, stamp_s, RejectCause::Attachment, error, sink);
}
