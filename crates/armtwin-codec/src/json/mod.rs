//! armtwin's JSON messages: decoding gateway input, encoding twin outputs. (The same gateway
//! messages in Zenoh's serialization are [`crate::zser`]'s, with this module's [`WireError`].)
//!
//! Owns the JSON field sets on both sides of armtwin and every check on what gateways send:
//! size, encoding, field names, types, finiteness, joint count, angle unit and the orientation
//! forms of a measured pose. Must not know about the network: it turns bytes into
//! [`JointSample`] / [`MeasuredSample`], and the core's results into message structs and bytes.
//!
//! Input (gateway → armtwin), one JSON object per message:
//! - joints: `{"t": 12.5, "q": [q1, …, qn]}` or flat `{"time": 12.5, "q1": …, "qn": …}`, optional
//!   `"seq"` (non-negative integer), `"unit"` of the joint angles (`"rad"`, the default, or
//!   `"deg"`) and `"measured"` (a measured pose object whose own stamp is ignored);
//! - measured pose: `"t"` or `"time"`, `"x"`, `"y"`, `"z"` (m) and exactly one orientation form:
//!   quaternion `qx, qy, qz, qw`; `roll, pitch, yaw` (rad, `R = Rz(yaw) · Ry(pitch) · Rx(roll)`);
//!   or a UR rotation vector `rx, ry, rz` (rad).
//!
//! Unknown fields are skipped unparsed (forward compatibility). An optional field (`t`, `time`,
//! `seq`, `unit`, `measured`) holding `null` counts as absent, as serialisers write `None`.
//!
//! Output (armtwin → dashboards): [`PoseMessage`], [`DeviationMessage`], [`EventMessage`],
//! [`MetricsMessage`] and [`StateMessage`], serialised by [`to_json_bytes`] (numbers in shortest
//! round-trip form; a non-finite number would become `null`, `serde_json`'s rule), and the live
//! self-calibration's [`EstimateMessage`].
//!
//! Files by concern: `decode` (the entry points and the general decoder's checks) over `slots`
//! (its one pass of `serde_json`'s parser into fixed slots), with `fast` (the usual shapes, held
//! equal to it by the tests), both building `joints` (a decoded joint message and how it steps
//! its twin); `state` (the `state` object's own decoder, on a parsed value) and
//! `pose` (a measured pose's orientation forms, shared with the binary codecs); `encode` (the
//! fixed-layout writer), `messages` (the output messages), `effort` (the effort outputs) and
//! `history` (the per-second history answer).

use armtwin_core::pipeline::RejectCause;
use thiserror::Error;

use crate::decoded::{CodecError, Refused};

mod decode;
mod effort;
mod encode;
mod fast;
mod history;
mod joints;
mod messages;
mod pose;
mod slots;
mod state;

pub use decode::{decode_joints, decode_measured, read_joints, read_measured, stamp_hint};
pub use effort::{
    effort_readout_bytes, effort_readout_json, effort_summary_json, payload_message_bytes,
    payload_readout_json,
};
pub use encode::to_json_bytes;
pub use history::{HistoryMessage, HistoryRows, HistorySpans, SecondJson};
pub use joints::DecodedJoints;
pub use messages::{
    AlarmsJson, DeviationMessage, ErrorsJson, EstimateMessage, EventMessage, MetricsMessage,
    ParameterJson, PoseMessage, StampedJointsJson, StampedPoseJson, StateMessage, StatsJson,
    StatsSetJson, WindowJson, deviation_json_bytes, joint_state_json, not_identifiable,
    paired_json_bytes, parameters_json, pose_json_bytes,
};
pub(crate) use pose::pose_from_quaternion;

/// Largest accepted payload (bytes); larger ones are rejected before parsing.
pub const MAX_PAYLOAD_BYTES: usize = 64 * 1024;

/// Why a gateway message was rejected (JSON, or zenoh-ext serialized: [`super::zser`]).
#[derive(Debug, Clone, PartialEq, Error)]
pub enum WireError {
    /// The payload exceeds [`MAX_PAYLOAD_BYTES`].
    #[error("payload of {bytes} bytes exceeds the limit of {limit} bytes")]
    TooLarge {
        /// Payload size.
        bytes: usize,
        /// The limit.
        limit: usize,
    },
    /// The payload is not UTF-8 text.
    #[error("payload is not UTF-8 (invalid byte at offset {valid_up_to})")]
    NotUtf8 {
        /// Length of the valid prefix.
        valid_up_to: usize,
    },
    /// The payload is not a JSON document.
    #[error("payload is not JSON: {detail}")]
    NotJson {
        /// The parser's message, with line and column.
        detail: String,
    },
    /// The payload is JSON but not an object.
    #[error("payload is {got}, expected a JSON object")]
    NotObject {
        /// What it is instead (`an array`, `a number`, …).
        got: &'static str,
    },
    /// A required field is absent.
    #[error("field '{field}': missing")]
    MissingField {
        /// The field's name (nested fields as `measured.qw`).
        field: String,
    },
    /// A field holds the wrong JSON type (numbers in strings are not coerced).
    #[error("field '{field}': expected {expected}, got {got}")]
    WrongType {
        /// The field's name (array elements as `q[2]`, 0-based).
        field: String,
        /// What the field must hold (`a number`, `an array`, …).
        expected: &'static str,
        /// What it holds (`a string`, `the number -1`, …).
        got: String,
    },
    /// A number does not fit a finite `f64` (`1e400`), or a value computed from it overflows.
    #[error("field '{field}': not a finite number (out of the range of f64)")]
    NonFinite {
        /// The field's name.
        field: String,
    },
    /// The message carries a number of joint angles other than the arm's.
    #[error("field '{field}': expected {expected} joint angles, got {got}")]
    JointCount {
        /// `q` for the array form, `q1..qN` for the flat form.
        field: String,
        /// The arm's joint count.
        expected: usize,
        /// Angles in the message.
        got: usize,
    },
    /// Two fields that mean the same thing are both present.
    #[error("fields '{first}' and '{second}' are both present; send only one")]
    AmbiguousFields {
        /// One of them.
        first: String,
        /// The other.
        second: String,
    },
    /// A field appears twice in one object.
    #[error("field '{field}': appears more than once")]
    DuplicateField {
        /// The field's name.
        field: String,
    },
    /// The angle unit is neither `rad` nor `deg`.
    #[error("field 'unit': expected \"rad\" or \"deg\", got {got:?}")]
    Unit {
        /// The unit sent.
        got: String,
    },
    /// A measured pose has no orientation, or more than one form of it.
    #[error("{}", orientation_forms_message(.found))]
    OrientationForms {
        /// The first field of each form present (empty: none).
        found: Vec<String>,
    },
    /// A quaternion's norm is zero, not finite, or more than 5 % away from 1.
    #[error("fields '{fields}': quaternion norm {norm} is not within 5 % of 1")]
    QuaternionNorm {
        /// The quaternion's fields (`qx..qw`, or `measured.qx..qw`).
        fields: String,
        /// Its norm.
        norm: f64,
    },
    /// A binary message ends inside a field.
    #[error("field '{field}': needs {needed} bytes at offset {offset}, the payload has {bytes}")]
    Truncated {
        /// The field (`q[3]`, the length of `measured`).
        field: String,
        /// Bytes the field needs.
        needed: usize,
        /// Where it starts.
        offset: usize,
        /// Payload size.
        bytes: usize,
    },
    /// A binary message goes on after its last field.
    #[error("{extra} bytes after the last field (the message ends at offset {end})")]
    TrailingBytes {
        /// Bytes left over.
        extra: usize,
        /// Where the last field ends.
        end: usize,
    },
    /// A binary sequence length is not a LEB128 number of at most 64 bits.
    #[error(
        "field '{field}': the length at offset {offset} is not a LEB128 number of at most 64 bits"
    )]
    MalformedLength {
        /// The sequence.
        field: String,
        /// Where its length starts.
        offset: usize,
    },
    /// A binary sequence holds a number of values its schema does not allow.
    #[error("field '{field}': expected {expected} values, got {got}")]
    SequenceLength {
        /// The sequence.
        field: String,
        /// What the schema allows (`7`, `0 or 7`).
        expected: &'static str,
        /// The length the message gives (not allocated: the values need not be there).
        got: u64,
    },
    /// The joint state beside the angles is not what its fields allow (a value of the wrong
    /// type or count, a negative payload mass).
    #[error("joint state field '{field}': {detail}")]
    JointState {
        /// The field (`state.temperature_c`, `payload[0]`).
        field: String,
        /// What is wrong with it.
        detail: String,
    },
    /// A `zenoh/serialized` message without the schema its key expects.
    #[error(
        "encoding zenoh/serialized without the schema '{expected}' this key takes: tag the sample with it"
    )]
    Schema {
        /// The schema the key takes.
        expected: &'static str,
    },
}

impl WireError {
    /// The rejection cause of the error's class: the core's for a non-finite number and a joint
    /// count, else the class's own name.
    #[must_use]
    pub fn cause(&self) -> RejectCause {
        match self {
            Self::TooLarge { .. } => RejectCause::Decode("too_large"),
            Self::NotUtf8 { .. } => RejectCause::Decode("not_utf8"),
            Self::NotJson { .. } => RejectCause::Decode("not_json"),
            Self::NotObject { .. } => RejectCause::Decode("not_object"),
            Self::MissingField { .. } => RejectCause::Decode("missing_field"),
            Self::WrongType { .. } => RejectCause::Decode("wrong_type"),
            Self::NonFinite { .. } => RejectCause::NonFinite,
            Self::JointCount { .. } => RejectCause::JointCount,
            Self::AmbiguousFields { .. } => RejectCause::Decode("ambiguous_fields"),
            Self::DuplicateField { .. } => RejectCause::Decode("duplicate_field"),
            Self::Unit { .. } => RejectCause::Decode("unit"),
            Self::OrientationForms { .. } => RejectCause::Decode("orientation_forms"),
            Self::QuaternionNorm { .. } => RejectCause::Decode("quaternion_norm"),
            Self::Truncated { .. } => RejectCause::Decode("truncated"),
            Self::TrailingBytes { .. } => RejectCause::Decode("trailing_bytes"),
            Self::MalformedLength { .. } => RejectCause::Decode("malformed_length"),
            Self::SequenceLength { .. } => RejectCause::Decode("sequence_length"),
            Self::JointState { .. } => RejectCause::Decode("joint_state"),
            Self::Schema { .. } => RejectCause::Decode("schema"),
        }
    }

    /// A stable `snake_case` name of the error class, for event messages and counters
    /// ([`RejectCause::as_str`] of [`cause`](Self::cause)).
    #[must_use]
    pub fn kind(&self) -> &'static str {
        self.cause().as_str()
    }
}

impl CodecError for WireError {
    fn reject_cause(&self) -> RejectCause {
        WireError::cause(self)
    }
}

fn orientation_forms_message(found: &[String]) -> String {
    const FORMS: &str = "qx, qy, qz, qw or roll, pitch, yaw or rx, ry, rz";
    if found.is_empty() {
        format!("no orientation fields: send exactly one of {FORMS}")
    } else {
        let fields = found
            .iter()
            .map(|field| format!("'{field}'"))
            .collect::<Vec<_>>()
            .join(", ");
        format!(
            "orientation given in {} forms (fields {fields}): send exactly one of {FORMS}",
            found.len()
        )
    }
}

/// A gateway message (JSON or Zenoh-serialized) that did not decode: why, and the stamp it
/// offers, so that its rejection is reported at the message's own time (`t` or, without a `t`
/// field, `time`, when the payload is a JSON object and that field holds a number; a binary
/// message's leading `t` when it is finite).
pub type Undecodable = Refused<WireError>;

/// The two decoding paths apart, for the test that holds them equal on every message the fast
/// one takes: not an interface.
#[doc(hidden)]
pub mod paths {
    pub use super::decode::{general_joints, general_measured};
    pub use super::fast::{joints as fast_joints, measured as fast_measured};
    pub use super::slots::joint_index;
}
