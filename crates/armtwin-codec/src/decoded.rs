//! One decoded message, whatever its codec, and the one way it steps its robot's twin: the path
//! from payload to twin that the live service and offline validation share, so a recording
//! validated offline and the same recording replayed into the service cannot disagree.
//!
//! Two steps, so a caller that shares the pipeline can decode without holding it:
//! [`Decoded::decode`] needs only the robot's immutable settings and a [`Decoder`];
//! [`Decoded::step`] is the only part that touches the robot's [`Twin`] (offline from
//! [`Pipeline::track`](armtwin_core::pipeline::Pipeline::track), in the service from the robot's
//! own locked entry).
//!
//! A codec plugs in with a [`Decoder`] (bytes to a message, and the stamp a payload offers), a
//! [`Message`] (what the decoded value does to the twin) and an error that is a [`CodecError`]
//! (its rejection cause). A new input (an RTDE gateway's joint angles, velocities and currents;
//! a joint-state extension) adds those three in its own module or crate; neither this module
//! nor the core changes.
//!
//! A message that does not decode becomes one rejection (an event and a count) at the best
//! stamp it offers: its own, else what the refused payload still offers, else the caller's
//! fallback (the transport's or the arrival time, read only then; or the recording's). Nothing
//! is logged here: the sink reports each rejection once. Must not know the network, the
//! filesystem or the clock.

use std::error::Error;

use armtwin_core::pipeline::{MeasuredStream, RejectCause, Robot, Sink, Twin};
use armtwin_core::sample::{JointSample, MeasuredSample};

/// An error a codec refuses a payload with: its rejection cause, for the event's
/// `detail.cause` and the counts by cause. A class the core also has (a non-finite number, a
/// wrong joint count) is the core's variant; any other is [`RejectCause::Decode`] with a name
/// from [`DECODE_CAUSES`].
pub trait CodecError: Error + 'static {
    /// The rejection cause of the error's class.
    fn reject_cause(&self) -> RejectCause;
}

/// Every class name the codecs of this crate refuse a payload for beyond the core's own causes:
/// the fixed set [`RejectCause::Decode`] takes from them. A count by cause therefore holds at
/// most these and the core's causes.
pub const DECODE_CAUSES: [&str; 24] = [
    "too_large",
    "not_utf8",
    "not_json",
    "not_object",
    "missing_field",
    "wrong_type",
    "ambiguous_fields",
    "duplicate_field",
    "unit",
    "orientation_forms",
    "quaternion_norm",
    "truncated",
    "trailing_bytes",
    "malformed_length",
    "sequence_length",
    "schema",
    "cdr_header",
    "cdr_truncated",
    "cdr_malformed",
    "missing_joint",
    "duplicate_joint",
    "frame_id",
    "attachment",
    "joint_state",
];

/// A payload a decoder refused: why, and the stamp it still offers, so that its rejection is
/// reported at the message's own time.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{error}")]
pub struct Refused<E> {
    /// Why the message was refused.
    pub error: E,
    /// The stamp the payload offers (s), when its framing gets that far; `None` otherwise.
    pub stamp_s: Option<f64>,
}

/// Where a message came in: the key, and the robot's measured stream a pose belongs to.
#[derive(Debug, Clone, Copy)]
pub struct Arrival<'a> {
    /// The key the message arrived on (named by its events).
    pub key: &'a str,
    /// For a measured pose, the robot's own stream or one of its sensors'; joint messages
    /// ignore it.
    pub stream: MeasuredStream,
}

impl<'a> Arrival<'a> {
    /// A message of the robot's own streams, arrived on `key`.
    #[must_use]
    pub fn on(key: &'a str) -> Self {
        Self {
            key,
            stream: MeasuredStream::Robot,
        }
    }
}

/// What a decoded message does to its robot's twin.
pub trait Message {
    /// The message's own stamp (s), if it carries one.
    fn stamp_s(&self) -> Option<f64>;

    /// Steps `twin` with the message, which goes in at `stamp_s`.
    fn step(&self, twin: &mut Twin, arrival: Arrival<'_>, stamp_s: f64, sink: &mut impl Sink);
}

/// Reads one kind of message for a robot.
pub trait Decoder {
    /// What a payload decodes to.
    type Message: Message;
    /// Why a payload is refused.
    type Error: CodecError;

    /// Decodes `payload` for `robot` in one pass: the message, or why not with the stamp the
    /// payload still offers.
    fn read(&self, robot: &Robot, payload: &[u8]) -> Result<Self::Message, Refused<Self::Error>>;

    /// The stamp a payload offers without being decoded: a message of a robot that may not be
    /// tracked is rejected at its own time.
    fn stamp_hint(&self, payload: &[u8]) -> Option<f64>;
}

/// A message decoded for its robot, with the stamp it goes in at.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded<T, E> {
    stamp_s: f64,
    decoded: Result<T, E>,
}

impl<T: Message, E: CodecError> Decoded<T, E> {
    /// Decodes `payload` with `decoder` for `robot`; `fallback_s` gives the stamp of a message
    /// that offers none (called only then).
    #[must_use]
    pub fn decode<D: Decoder<Message = T, Error = E>>(
        decoder: &D,
        robot: &Robot,
        payload: &[u8],
        fallback_s: impl FnOnce() -> f64,
    ) -> Self {
        match decoder.read(robot, payload) {
            Ok(message) => Self {
                stamp_s: message.stamp_s().unwrap_or_else(fallback_s),
                decoded: Ok(message),
            },
            Err(refused) => Self {
                stamp_s: refused.stamp_s.unwrap_or_else(fallback_s),
                decoded: Err(refused.error),
            },
        }
    }

    /// The stamp the message goes in at (s).
    #[must_use]
    pub fn stamp_s(&self) -> f64 {
        self.stamp_s
    }

    /// The decoded message, if it decoded: for what the transport adds before it is stepped
    /// (the `rmw_zenoh` attachment's sequence number).
    pub fn message_mut(&mut self) -> Option<&mut T> {
        self.decoded.as_mut().ok()
    }

    /// Steps the robot's `twin` with the message, or rejects it (one event, one count).
    pub fn step(&self, twin: &mut Twin, arrival: Arrival<'_>, sink: &mut impl Sink) {
        match &self.decoded {
            Ok(message) => message.step(twin, arrival, self.stamp_s, sink),
            Err(error) => reject(twin, arrival.key, self.stamp_s, error, sink),
        }
    }
}

/// One rejection (event and count) for a message, or part of one (an embedded measured pose,
/// an `rmw_zenoh` attachment), that did not decode.
pub fn reject(
    twin: &mut Twin,
    key: &str,
    stamp_s: f64,
    error: &impl CodecError,
    sink: &mut impl Sink,
) {
    twin.reject(key, stamp_s, error.reject_cause(), error, sink);
}

/// A joint sample without an embedded measured pose (ROS 2 `JointState`).
impl Message for JointSample {
    fn stamp_s(&self) -> Option<f64> {
        self.stamp_s
    }

    fn step(&self, twin: &mut Twin, arrival: Arrival<'_>, stamp_s: f64, sink: &mut impl Sink) {
        twin.joints(arrival.key, stamp_s, self, sink);
    }
}

/// A measured pose of the arrival's stream.
impl Message for MeasuredSample {
    fn stamp_s(&self) -> Option<f64> {
        self.stamp_s
    }

    fn step(&self, twin: &mut Twin, arrival: Arrival<'_>, stamp_s: f64, sink: &mut impl Sink) {
        twin.measured(arrival.key, arrival.stream, stamp_s, &self.pose, sink);
    }
}
