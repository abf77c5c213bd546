//! The service's wire messages (JSON): decoding gateway input, encoding twin outputs.
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
//! round-trip form; a non-finite number would become `null`, `serde_json`'s rule).

use std::borrow::Cow;
use std::collections::BTreeSet;
use std::fmt::{self, Write as _};

use nalgebra::{UnitQuaternion, Vector3};
use serde::Serialize;
use serde::de::{self, DeserializeSeed, Deserializer, IgnoredAny, MapAccess, SeqAccess, Visitor};
use serde_json::{Number, Value, json};
use thiserror::Error;

use super::PoseFields;
use super::flat_json::FlatObject;
use crate::kinematics::PoseReadout;
use crate::metrics::{Deviation, METRIC_NAMES, Stats, StatsSet};
use crate::orientation::{self, Rpy};
use crate::pipeline::{Alarms, Event, EventDetail, MetricsSnapshot, RejectCause, RobotState};
use crate::sample::{JointSample, MeasuredSample};

/// Largest accepted payload (bytes); larger ones are rejected before parsing.
pub const MAX_PAYLOAD_BYTES: usize = 64 * 1024;

/// How far a quaternion's norm may be from 1 before it is rejected rather than normalised
/// (gateways round their components; a larger error means a wrong field, not rounding).
const QUATERNION_NORM_TOLERANCE: f64 = 0.05;

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
    /// The rejection cause of the error's class.
    #[must_use]
    pub fn cause(&self) -> RejectCause {
        match self {
            Self::TooLarge { .. } => RejectCause::TooLarge,
            Self::NotUtf8 { .. } => RejectCause::NotUtf8,
            Self::NotJson { .. } => RejectCause::NotJson,
            Self::NotObject { .. } => RejectCause::NotObject,
            Self::MissingField { .. } => RejectCause::MissingField,
            Self::WrongType { .. } => RejectCause::WrongType,
            Self::NonFinite { .. } => RejectCause::NonFinite,
            Self::JointCount { .. } => RejectCause::JointCount,
            Self::AmbiguousFields { .. } => RejectCause::AmbiguousFields,
            Self::DuplicateField { .. } => RejectCause::DuplicateField,
            Self::Unit { .. } => RejectCause::Unit,
            Self::OrientationForms { .. } => RejectCause::OrientationForms,
            Self::QuaternionNorm { .. } => RejectCause::QuaternionNorm,
            Self::Truncated { .. } => RejectCause::Truncated,
            Self::TrailingBytes { .. } => RejectCause::TrailingBytes,
            Self::MalformedLength { .. } => RejectCause::MalformedLength,
            Self::SequenceLength { .. } => RejectCause::SequenceLength,
            Self::Schema { .. } => RejectCause::Schema,
        }
    }

    /// A stable `snake_case` name of the error class, for event messages and counters
    /// ([`RejectCause::as_str`] of [`cause`](Self::cause)).
    #[must_use]
    pub fn kind(&self) -> &'static str {
        self.cause().as_str()
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

// ---------------------------------------------------------------------------------------------
// Decoding
// ---------------------------------------------------------------------------------------------

/// A decoded joint message: the joint sample, and the error of its `measured` part when that
/// part was invalid (the joint sample stays valid: a bad pose reading must not cost the twin its
/// joint sample).
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedJoints {
    /// The joint sample (its `measured` is `None` when the part was invalid).
    pub sample: JointSample,
    /// Why the embedded `measured` part was refused, if it was.
    pub measured_error: Option<WireError>,
}

/// A gateway message that did not decode: why, and the stamp it offers, so that its rejection
/// is reported at the message's own time.
#[derive(Debug, Clone, PartialEq, Error)]
#[error("{error}")]
pub struct Undecodable {
    /// Why the message was refused.
    pub error: WireError,
    /// The message's `t` or, without a `t` field, its `time`, when the payload is a JSON object
    /// and that field holds a number; `None` otherwise (also for a `t` holding `null`).
    pub stamp_s: Option<f64>,
}

/// The stamp (`t` or `time`) of a message, if it has a usable one, read without knowing what
/// kind of message it is (a message of an unknown robot is rejected at its own time).
#[must_use]
pub fn stamp_hint(payload: &[u8]) -> Option<f64> {
    match read_message(payload, Schema::Stamp) {
        Ok(slots) => slots.stamp_hint(),
        Err(undecodable) => undecodable.stamp_s,
    }
}

/// Decodes a joint message for an arm with `joint_count` joints.
///
/// Angles come back in radians whatever `unit` said; a `measured` object gets the joint
/// message's stamp. An invalid `measured` part is reported in
/// [`DecodedJoints::measured_error`], not as the message's error.
///
/// ```
/// use armtwin::codec::wire::decode_joints;
/// let sample = decode_joints(br#"{"time": 2.5, "unit": "deg", "q1": 90, "q2": -45}"#, 2)?.sample;
/// assert_eq!(sample.stamp_s, Some(2.5));
/// assert!((sample.q_rad[0] - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
/// let error = decode_joints(br#"{"q": [0, "1.2"]}"#, 2).unwrap_err();
/// assert_eq!(error.kind(), "wrong_type");
/// assert_eq!(error.to_string(), "field 'q[1]': expected a number, got the string \"1.2\"");
/// # Ok::<(), armtwin::codec::wire::WireError>(())
/// ```
pub fn decode_joints(payload: &[u8], joint_count: usize) -> Result<DecodedJoints, WireError> {
    read_joints(payload, joint_count).map_err(|undecodable| undecodable.error)
}

/// [`decode_joints`], and for a refused message the stamp it offers, from the same pass.
///
/// ```
/// use armtwin::codec::wire::read_joints;
/// let refused = read_joints(br#"{"t": 3.5, "q": [0, 0, 0]}"#, 2).unwrap_err();
/// assert_eq!(refused.error.kind(), "joint_count");
/// assert_eq!(refused.stamp_s, Some(3.5));
/// assert_eq!(read_joints(b"{\"t\": 3.5,", 2).unwrap_err().stamp_s, None);
/// ```
pub fn read_joints(payload: &[u8], joint_count: usize) -> Result<DecodedJoints, Undecodable> {
    match fast::joints(payload, joint_count) {
        Some(decoded) => Ok(decoded),
        None => general_joints(payload, joint_count),
    }
}

/// [`read_joints`] for any message, naming what is wrong with an invalid one.
fn general_joints(payload: &[u8], joint_count: usize) -> Result<DecodedJoints, Undecodable> {
    let slots = read_message(payload, Schema::Joints { joint_count })?;
    let stamp_s = slots.stamp_hint();
    slots
        .into_joints(joint_count)
        .map_err(|error| Undecodable { error, stamp_s })
}

/// Decodes a measured-pose message: position (m) and exactly one orientation form, the
/// quaternion normalised (within 5 % of unit norm) and canonicalised to `qw ≥ 0`.
pub fn decode_measured(payload: &[u8]) -> Result<MeasuredSample, WireError> {
    read_measured(payload).map_err(|undecodable| undecodable.error)
}

/// [`decode_measured`], and for a refused message the stamp it offers, from the same pass.
pub fn read_measured(payload: &[u8]) -> Result<MeasuredSample, Undecodable> {
    match fast::measured(payload) {
        Some(measured) => Ok(measured),
        None => general_measured(payload),
    }
}

/// [`read_measured`] for any message, naming what is wrong with an invalid one.
fn general_measured(payload: &[u8]) -> Result<MeasuredSample, Undecodable> {
    let slots = read_message(payload, Schema::Measured)?;
    let stamp_s = slots.stamp_hint();
    slots
        .into_measured()
        .map_err(|error| Undecodable { error, stamp_s })
}

/// The `n` in a flat joint field `qn` (`q1`, `q2`, …; no sign, no leading zero).
fn joint_index(key: &str) -> Option<usize> {
    let digits = key.strip_prefix('q')?;
    if digits.is_empty() || digits.starts_with('0') || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

/// The fields of a measured pose: position, then the orientation forms in
/// [`OrientationForm::ALL`] order, each in wire order.
const POSE_KEYS: [&str; 13] = [
    "x", "y", "z", "qx", "qy", "qz", "qw", "roll", "pitch", "yaw", "rx", "ry", "rz",
];

/// The orientation forms a measured pose may carry.
#[derive(Debug, Clone, Copy)]
enum OrientationForm {
    /// `qx, qy, qz, qw`.
    Quaternion,
    /// `roll, pitch, yaw` (rad), `R = Rz(yaw) · Ry(pitch) · Rx(roll)`.
    RollPitchYaw,
    /// UR rotation vector `rx, ry, rz` (rad).
    RotationVector,
}

impl OrientationForm {
    const ALL: [Self; 3] = [Self::Quaternion, Self::RollPitchYaw, Self::RotationVector];

    /// Where the form's fields are in [`POSE_KEYS`], in wire order.
    fn slots(self) -> std::ops::Range<usize> {
        match self {
            Self::Quaternion => 3..7,
            Self::RollPitchYaw => 7..10,
            Self::RotationVector => 10..13,
        }
    }

    /// The form's fields, in wire order.
    fn keys(self) -> &'static [&'static str] {
        &POSE_KEYS[self.slots()]
    }

    /// The first of the form's fields present in `pose`, as an index into [`POSE_KEYS`].
    fn first_present(self, pose: &PoseSlots) -> Option<usize> {
        self.slots().find(|&index| pose[index].is_some())
    }
}

/// Position and exactly one orientation form, from a measured pose object.
fn pose_readout(pose: &PoseSlots, prefix: &str) -> Result<PoseReadout, WireError> {
    let required = |index: usize| {
        let field = || format!("{prefix}{}", POSE_KEYS[index]);
        match &pose[index] {
            Some(got) => number(got, field),
            None => Err(WireError::MissingField { field: field() }),
        }
    };
    let position_m = [required(0)?, required(1)?, required(2)?];
    let present = || {
        OrientationForm::ALL
            .into_iter()
            .filter_map(|form| form.first_present(pose).map(|index| (form, index)))
    };
    let mut forms = present();
    let (Some((form, _)), None) = (forms.next(), forms.next()) else {
        return Err(WireError::OrientationForms {
            found: present()
                .map(|(_, index)| format!("{prefix}{}", POSE_KEYS[index]))
                .collect(),
        });
    };
    let mut values = [0.0; 4];
    for (value, index) in values.iter_mut().zip(form.slots()) {
        *value = required(index)?;
    }
    pose_of(prefix, position_m, form, values)
}

/// The pose of a position (m) and the values of one orientation form (in the form's wire order;
/// unused trailing values ignored).
fn pose_of(
    prefix: &str,
    position_m: [f64; 3],
    form: OrientationForm,
    values: [f64; 4],
) -> Result<PoseReadout, WireError> {
    let orientation = match form {
        OrientationForm::Quaternion => quaternion(prefix, values)?,
        OrientationForm::RollPitchYaw => {
            let [roll_rad, pitch_rad, yaw_rad, _] = values;
            orientation::quaternion_from_matrix(&orientation::matrix_from_rpy(Rpy {
                roll_rad,
                pitch_rad,
                yaw_rad,
            }))
        }
        OrientationForm::RotationVector => {
            let [rx, ry, rz, _] = values;
            rotation_vector(prefix, [rx, ry, rz])?
        }
    };
    Ok(PoseReadout::from_position_quaternion(
        position_m,
        &orientation,
    ))
}

/// A measured pose of a position (m) and a quaternion in wire order `[x, y, z, w]`, with this
/// decoder's checks (norm within 5 % of 1, then normalised and canonicalised to `qw ≥ 0`): for
/// the binary codecs that carry the same pose.
pub(crate) fn pose_from_quaternion(
    position_m: [f64; 3],
    xyzw: [f64; 4],
) -> Result<PoseReadout, WireError> {
    pose_of("", position_m, OrientationForm::Quaternion, xyzw)
}

/// A quaternion in wire order `[x, y, z, w]`, normalised if its norm is within 5 % of 1.
fn quaternion(prefix: &str, xyzw: [f64; 4]) -> Result<UnitQuaternion<f64>, WireError> {
    let norm = xyzw.iter().map(|c| c * c).sum::<f64>().sqrt();
    let error = || WireError::QuaternionNorm {
        fields: format!("{prefix}qx..qw"),
        norm,
    };
    // Also false for an infinite norm (components beyond ~1e154) and for zero.
    if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE || !norm.is_finite() {
        return Err(error());
    }
    orientation::quaternion_from_xyzw(xyzw).ok_or_else(error)
}

/// A UR rotation vector `[rx, ry, rz]` (rad); rejected if its angle overflows.
fn rotation_vector(prefix: &str, rxyz: [f64; 3]) -> Result<UnitQuaternion<f64>, WireError> {
    let q = orientation::quaternion_from_rotation_vector(&Vector3::from(rxyz));
    if q.coords.iter().all(|c| c.is_finite()) {
        return Ok(q);
    }
    // Only a norm beyond ~1e154 overflows; blame the largest component.
    let largest = (0..3)
        .max_by(|&a, &b| rxyz[a].abs().total_cmp(&rxyz[b].abs()))
        .unwrap_or(0);
    Err(WireError::NonFinite {
        field: format!(
            "{prefix}{}",
            OrientationForm::RotationVector.keys()[largest]
        ),
    })
}

// ---------------------------------------------------------------------------------------------
// The JSON layer: one pass of serde_json's parser over the payload into fixed slots. Fields a
// message does not use are skipped unparsed (their numbers never converted, so they may hold
// anything, even `1e400`); kept fields record what they held, and the checks on the slots name
// the problem afterwards.
// ---------------------------------------------------------------------------------------------

/// Which fields of a message's top level are kept.
#[derive(Debug, Clone, Copy)]
enum Schema {
    /// A joint message: stamp, `seq`, `unit`, `q` or `q1..qN`, and a `measured` pose.
    Joints {
        /// The arm's joint count: how many angles are kept.
        joint_count: usize,
    },
    /// A measured-pose message: stamp and pose fields.
    Measured,
    /// Only the stamp.
    Stamp,
}

/// A top-level field of a message.
#[derive(Debug, Clone, Copy)]
enum MessageKey {
    T,
    Time,
    Seq,
    Unit,
    Q,
    /// `q<n>`.
    Joint(usize),
    Measured,
    /// A pose field of a measured-pose message, as an index into [`POSE_KEYS`].
    Pose(usize),
    /// A field the message does not use.
    Other,
}

impl MessageKey {
    fn of(schema: Schema, key: &str) -> Self {
        match (schema, key) {
            (_, "t") => Self::T,
            (_, "time") => Self::Time,
            (Schema::Joints { .. }, "seq") => Self::Seq,
            (Schema::Joints { .. }, "unit") => Self::Unit,
            (Schema::Joints { .. }, "q") => Self::Q,
            (Schema::Joints { .. }, "measured") => Self::Measured,
            (Schema::Joints { .. }, other) => joint_index(other).map_or(Self::Other, Self::Joint),
            (Schema::Measured, other) => pose_key(other).map_or(Self::Other, Self::Pose),
            (Schema::Stamp, _) => Self::Other,
        }
    }
}

fn pose_key(key: &str) -> Option<usize> {
    POSE_KEYS.iter().position(|pose_key| *pose_key == key)
}

/// A JSON number as the parser gave it.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Num {
    Unsigned(u64),
    Signed(i64),
    Float(f64),
}

impl Num {
    fn to_f64(self) -> f64 {
        match self {
            Self::Unsigned(value) => value as f64,
            Self::Signed(value) => value as f64,
            Self::Float(value) => value,
        }
    }

    fn to_u64(self) -> Option<u64> {
        match self {
            Self::Unsigned(value) => Some(value),
            Self::Signed(value) => u64::try_from(value).ok(),
            Self::Float(_) => None,
        }
    }
}

/// What a kept field held: enough for its checks and for naming it in an error.
#[derive(Debug, Clone, PartialEq)]
enum Got {
    Null,
    Boolean,
    Number(Num),
    /// A string: its first 40 characters and whether there were more, or for `unit` the whole
    /// text (a unit error quotes it whole).
    String {
        head: Cow<'static, str>,
        cut: bool,
    },
    Array,
    Object,
}

impl Got {
    fn json_type(&self) -> &'static str {
        match self {
            Self::Null => "null",
            Self::Boolean => "a boolean",
            Self::Number(_) => "a number",
            Self::String { .. } => "a string",
            Self::Array => "an array",
            Self::Object => "an object",
        }
    }

    /// How an error message names it: the number or the text itself (cut short), so a log or a
    /// report shows what the gateway sent.
    fn describe(&self) -> String {
        match self {
            Self::Number(number) => {
                let number = match *number {
                    Num::Unsigned(value) => Number::from(value),
                    Num::Signed(value) => Number::from(value),
                    // The parser yields only finite numbers.
                    Num::Float(value) => match Number::from_f64(value) {
                        Some(number) => number,
                        None => return Self::Null.json_type().to_owned(),
                    },
                };
                format!("the number {number}")
            }
            Self::String { head, cut: false } => format!("the string {head:?}"),
            Self::String { head, cut: true } => format!("the string {head:?}…"),
            other => other.json_type().to_owned(),
        }
    }
}

/// The value of an optional field; `null` counts as absent.
fn optional(slot: Option<&Got>) -> Option<&Got> {
    slot.filter(|got| **got != Got::Null)
}

/// A finite JSON number (the parser already rejected overflowing ones); strings are not coerced.
fn number(got: &Got, field: impl FnOnce() -> String) -> Result<f64, WireError> {
    match got {
        Got::Number(number) => Ok(number.to_f64()),
        other => Err(wrong_type(field(), "a number", other)),
    }
}

fn wrong_type(field: String, expected: &'static str, got: &Got) -> WireError {
    WireError::WrongType {
        field,
        expected,
        got: got.describe(),
    }
}

/// The `q` array: every item counted, the first `joint_count` numbers kept and the first item
/// that is not a number remembered.
#[derive(Debug, Default)]
struct AngleArray {
    count: usize,
    values: Vec<f64>,
    first_non_number: Option<(usize, Got)>,
}

/// The flat `q1..qN` fields.
#[derive(Debug, Default)]
struct FlatAngles {
    /// How many different `q<n>` fields there are.
    count: usize,
    /// The lowest `n`, for naming the field that clashes with `q`.
    lowest: Option<usize>,
    /// `q1..q{joint_count}`, allocated at the first of them.
    values: Vec<Option<Got>>,
    /// The `n` beyond the arm's joints seen so far, only to notice a repeated field.
    beyond: BTreeSet<usize>,
    /// Where the value of a field beyond the arm's joints is read.
    scratch: Option<Got>,
}

impl FlatAngles {
    /// The slot of `q<n>`, and whether the field was seen before.
    fn slot(&mut self, n: usize, joint_count: usize) -> (&mut Option<Got>, bool) {
        self.lowest = Some(self.lowest.map_or(n, |lowest| lowest.min(n)));
        let repeated = if n <= joint_count {
            if self.values.is_empty() {
                self.values.resize_with(joint_count, || None);
            }
            self.values[n - 1].is_some()
        } else {
            !self.beyond.insert(n)
        };
        if !repeated {
            self.count += 1;
        }
        let slot = if n <= joint_count {
            &mut self.values[n - 1]
        } else {
            &mut self.scratch
        };
        (slot, repeated)
    }
}

/// The fields of a measured pose, in [`POSE_KEYS`] order.
type PoseSlots = [Option<Got>; 13];

/// What the pass read from a message.
#[derive(Debug, Default)]
struct MessageSlots {
    t: Option<Got>,
    time: Option<Got>,
    seq: Option<Got>,
    unit: Option<Got>,
    q: Option<Got>,
    /// The items of `q` when it is an array.
    angles: AngleArray,
    flat: FlatAngles,
    measured: Option<Got>,
    /// The fields of `measured` when it is an object.
    measured_pose: PoseSlots,
    /// The pose fields of a measured-pose message.
    pose: PoseSlots,
}

impl MessageSlots {
    /// `t` or `time` (not both), a finite number, or `None`.
    fn stamp(&self) -> Result<Option<f64>, WireError> {
        match (optional(self.t.as_ref()), optional(self.time.as_ref())) {
            (Some(_), Some(_)) => Err(WireError::AmbiguousFields {
                first: "t".to_owned(),
                second: "time".to_owned(),
            }),
            (Some(got), None) => number(got, || "t".to_owned()).map(Some),
            (None, Some(got)) => number(got, || "time".to_owned()).map(Some),
            (None, None) => Ok(None),
        }
    }

    /// The stamp a refused message offers: `t` if present (a `null` or any non-number gives
    /// none), else `time`.
    fn stamp_hint(&self) -> Option<f64> {
        match self.t.as_ref().or(self.time.as_ref()) {
            Some(Got::Number(number)) => Some(number.to_f64()).filter(|t| t.is_finite()),
            _ => None,
        }
    }

    fn into_joints(self, joint_count: usize) -> Result<DecodedJoints, WireError> {
        let stamp_s = self.stamp()?;
        let seq = match optional(self.seq.as_ref()) {
            None => None,
            Some(got) => Some(
                match got {
                    Got::Number(number) => number.to_u64(),
                    _ => None,
                }
                .ok_or_else(|| wrong_type("seq".to_owned(), "a non-negative integer", got))?,
            ),
        };
        let degrees = match optional(self.unit.as_ref()) {
            None => false,
            Some(Got::String { head, .. }) if head == "rad" => false,
            Some(Got::String { head, .. }) if head == "deg" => true,
            Some(Got::String { head, .. }) => {
                return Err(WireError::Unit {
                    got: head.to_string(),
                });
            }
            Some(other) => return Err(wrong_type("unit".to_owned(), "a string", other)),
        };
        let (measured, measured_error) = match optional(self.measured.as_ref()) {
            None => (None, None),
            Some(Got::Object) => match pose_readout(&self.measured_pose, "measured.") {
                Ok(pose) => (Some(pose), None),
                Err(error) => (None, Some(error)),
            },
            Some(other) => (
                None,
                Some(wrong_type("measured".to_owned(), "an object", other)),
            ),
        };
        let mut q_rad = self.joint_angles(joint_count)?;
        if degrees {
            for angle in &mut q_rad {
                *angle = angle.to_radians();
            }
        }
        Ok(DecodedJoints {
            sample: JointSample {
                stamp_s,
                seq,
                q_rad,
                measured,
            },
            measured_error,
        })
    }

    /// Exactly `joint_count` angles, from the `q` array or from `q1..qn`, in message units.
    fn joint_angles(self, joint_count: usize) -> Result<Vec<f64>, WireError> {
        let flat = self.flat;
        if let Some(q) = &self.q {
            if let Some(lowest) = flat.lowest {
                return Err(WireError::AmbiguousFields {
                    first: "q".to_owned(),
                    second: format!("q{lowest}"),
                });
            }
            if *q != Got::Array {
                return Err(wrong_type("q".to_owned(), "an array", q));
            }
            let angles = self.angles;
            if angles.count != joint_count {
                return Err(WireError::JointCount {
                    field: "q".to_owned(),
                    expected: joint_count,
                    got: angles.count,
                });
            }
            if let Some((index, got)) = &angles.first_non_number {
                return Err(wrong_type(format!("q[{index}]"), "a number", got));
            }
            return Ok(angles.values);
        }
        if flat.count == 0 {
            return Err(WireError::MissingField {
                field: "q".to_owned(),
            });
        }
        if flat.count != joint_count {
            return Err(WireError::JointCount {
                field: format!("q1..q{joint_count}"),
                expected: joint_count,
                got: flat.count,
            });
        }
        (1..=joint_count)
            .map(|joint| {
                let field = || format!("q{joint}");
                match flat.values.get(joint - 1) {
                    Some(Some(got)) => number(got, field),
                    // As many `q<n>` fields as joints, so one beyond `q{joint_count}` takes its place.
                    _ => Err(WireError::MissingField { field: field() }),
                }
            })
            .collect()
    }

    fn into_measured(self) -> Result<MeasuredSample, WireError> {
        Ok(MeasuredSample {
            stamp_s: self.stamp()?,
            pose: pose_readout(&self.pose, "")?,
        })
    }
}

/// Where a value sits in the message (`measured.qx`, `q[2]`), as a chain on the parser's stack:
/// written out only for an error.
#[derive(Debug, Clone, Copy)]
struct Path<'a> {
    parent: Option<&'a Path<'a>>,
    segment: Segment<'a>,
}

#[derive(Debug, Clone, Copy)]
enum Segment<'a> {
    Key(&'a str),
    /// `q<n>`.
    Joint(usize),
    Index(usize),
}

impl Path<'_> {
    fn render(&self) -> String {
        let mut text = self.parent.map(Path::render).unwrap_or_default();
        let separator = if text.is_empty() { "" } else { "." };
        // Writing to a `String` cannot fail.
        let _ = match self.segment {
            Segment::Key(key) => write!(text, "{separator}{key}"),
            Segment::Joint(n) => write!(text, "{separator}q{n}"),
            Segment::Index(index) => write!(text, "[{index}]"),
        };
        text
    }
}

/// What the pass noticed besides the values: the first repeated field, and the kept value it
/// was reading when the parser failed.
#[derive(Debug, Default)]
struct Trace {
    repeated: Option<String>,
    failed_at: Option<String>,
}

impl Trace {
    fn note_repeated(&mut self, path: &Path<'_>) {
        if self.repeated.is_none() {
            self.repeated = Some(path.render());
        }
    }

    /// Passes `result` on, noting `path` if the parser failed inside it (the innermost value
    /// notes first).
    fn located<T, E>(&mut self, result: Result<T, E>, path: &Path<'_>) -> Result<T, E> {
        if result.is_err() && self.failed_at.is_none() {
            self.failed_at = Some(path.render());
        }
        result
    }

    fn into_error(self, error: &serde_json::Error) -> WireError {
        if let Some(field) = self.repeated {
            return WireError::DuplicateField { field };
        }
        // serde_json reports a number beyond f64 only through its message.
        let out_of_range = error.classify() == serde_json::error::Category::Syntax
            && error.to_string().starts_with("number out of range");
        match self.failed_at {
            Some(field) if out_of_range => WireError::NonFinite { field },
            _ => WireError::NotJson {
                detail: error.to_string(),
            },
        }
    }
}

/// Checks size and encoding, then reads the message with `schema` in one pass.
fn read_message(payload: &[u8], schema: Schema) -> Result<MessageSlots, Undecodable> {
    let refused = |error| Undecodable {
        error,
        stamp_s: None,
    };
    if payload.len() > MAX_PAYLOAD_BYTES {
        return Err(refused(WireError::TooLarge {
            bytes: payload.len(),
            limit: MAX_PAYLOAD_BYTES,
        }));
    }
    let text = std::str::from_utf8(payload).map_err(|error| {
        refused(WireError::NotUtf8 {
            valid_up_to: error.valid_up_to(),
        })
    })?;
    let mut slots = MessageSlots::default();
    let mut trace = Trace::default();
    let mut deserializer = serde_json::Deserializer::from_str(text);
    let parsed = Probe {
        into: Target::Message {
            schema,
            slots: &mut slots,
        },
        path: None,
        trace: &mut trace,
    }
    .deserialize(&mut deserializer)
    .and_then(|got| deserializer.end().map(|()| got));
    match parsed {
        Err(error) => Err(refused(trace.into_error(&error))),
        // A repeated field is reported even when the rest of the message is well formed; the
        // stamp is then the last `t` or `time`, as the last of a JSON object's repeated keys
        // usually counts.
        Ok(_) if trace.repeated.is_some() => Err(Undecodable {
            error: WireError::DuplicateField {
                field: trace.repeated.unwrap_or_default(),
            },
            stamp_s: slots.stamp_hint(),
        }),
        Ok(Got::Object) => Ok(slots),
        Ok(other) => Err(refused(WireError::NotObject {
            got: other.json_type(),
        })),
    }
}

/// Where the value being read goes.
enum Target<'a> {
    /// Inside a kept field: only what the value is (its contents are still checked: numbers
    /// within f64, no repeated key).
    Value,
    /// `unit`: a string is kept whole.
    WholeString,
    /// `q`: the items of an array.
    Angles {
        angles: &'a mut AngleArray,
        joint_count: usize,
    },
    /// A measured pose object embedded in a joint message (its own `t`/`time` skipped).
    Pose(&'a mut PoseSlots),
    /// A whole message.
    Message {
        schema: Schema,
        slots: &'a mut MessageSlots,
    },
}

/// Reads one JSON value into `into`, returning what it was.
struct Probe<'a> {
    into: Target<'a>,
    /// Where the value sits; `None` for the message itself.
    path: Option<&'a Path<'a>>,
    trace: &'a mut Trace,
}

impl<'de> DeserializeSeed<'de> for Probe<'_> {
    type Value = Got;

    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<Got, D::Error> {
        deserializer.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for Probe<'_> {
    type Value = Got;

    fn expecting(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        formatter.write_str("a JSON value")
    }

    fn visit_bool<E: de::Error>(self, _: bool) -> Result<Got, E> {
        Ok(Got::Boolean)
    }

    fn visit_i64<E: de::Error>(self, value: i64) -> Result<Got, E> {
        Ok(Got::Number(Num::Signed(value)))
    }

    fn visit_u64<E: de::Error>(self, value: u64) -> Result<Got, E> {
        Ok(Got::Number(Num::Unsigned(value)))
    }

    fn visit_f64<E: de::Error>(self, value: f64) -> Result<Got, E> {
        // serde_json never yields a non-finite number; if another parser did, it reads as null.
        Ok(if value.is_finite() {
            Got::Number(Num::Float(value))
        } else {
            Got::Null
        })
    }

    fn visit_str<E: de::Error>(self, text: &str) -> Result<Got, E> {
        const KEPT_CHARS: usize = 40;
        let head = match self.into {
            Target::WholeString => match text {
                "rad" => Cow::Borrowed("rad"),
                "deg" => Cow::Borrowed("deg"),
                other => Cow::Owned(other.to_owned()),
            },
            _ => Cow::Owned(text.chars().take(KEPT_CHARS).collect()),
        };
        let cut =
            !matches!(self.into, Target::WholeString) && text.chars().nth(KEPT_CHARS).is_some();
        Ok(Got::String { head, cut })
    }

    fn visit_unit<E: de::Error>(self) -> Result<Got, E> {
        Ok(Got::Null)
    }

    fn visit_none<E: de::Error>(self) -> Result<Got, E> {
        Ok(Got::Null)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Got, A::Error> {
        match self.into {
            // An array where an object is expected: skipped, the caller reports the type.
            Target::Message { .. } | Target::Pose(_) => {
                while seq.next_element::<IgnoredAny>()?.is_some() {}
            }
            Target::Angles {
                angles,
                joint_count,
            } => {
                *angles = AngleArray::default();
                angles.values.reserve_exact(joint_count);
                loop {
                    let path = Path {
                        parent: self.path,
                        segment: Segment::Index(angles.count),
                    };
                    let item = seq.next_element_seed(Probe {
                        into: Target::Value,
                        path: Some(&path),
                        trace: &mut *self.trace,
                    });
                    match self.trace.located(item, &path)? {
                        None => break,
                        Some(Got::Number(number)) if angles.count < joint_count => {
                            angles.values.push(number.to_f64());
                        }
                        Some(Got::Number(_)) => {}
                        Some(other) => {
                            if angles.first_non_number.is_none() {
                                angles.first_non_number = Some((angles.count, other));
                            }
                        }
                    }
                    angles.count += 1;
                }
            }
            Target::Value | Target::WholeString => {
                for index in 0.. {
                    let path = Path {
                        parent: self.path,
                        segment: Segment::Index(index),
                    };
                    let item = seq.next_element_seed(Probe {
                        into: Target::Value,
                        path: Some(&path),
                        trace: &mut *self.trace,
                    });
                    if self.trace.located(item, &path)?.is_none() {
                        break;
                    }
                }
            }
        }
        Ok(Got::Array)
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Got, A::Error> {
        match self.into {
            Target::Message { schema, slots } => read_members(&mut map, schema, slots, self.trace)?,
            Target::Pose(pose) => {
                *pose = PoseSlots::default();
                while let Some(key) = map.next_key_seed(KeySeed(pose_key))? {
                    let Some(index) = key else {
                        map.next_value::<IgnoredAny>()?;
                        continue;
                    };
                    let path = Path {
                        parent: self.path,
                        segment: Segment::Key(POSE_KEYS[index]),
                    };
                    let slot = &mut pose[index];
                    let repeated = slot.is_some();
                    keep(
                        &mut map,
                        slot,
                        repeated,
                        Target::Value,
                        &path,
                        &mut *self.trace,
                    )?;
                }
            }
            Target::Value | Target::WholeString | Target::Angles { .. } => {
                // Kept only to notice a repeated key; empty (unallocated) for most values.
                let mut keys = BTreeSet::new();
                while let Some(key) = map.next_key::<String>()? {
                    let path = Path {
                        parent: self.path,
                        segment: Segment::Key(&key),
                    };
                    if keys.contains(&key) {
                        self.trace.note_repeated(&path);
                    }
                    let value = map.next_value_seed(Probe {
                        into: Target::Value,
                        path: Some(&path),
                        trace: &mut *self.trace,
                    });
                    self.trace.located(value, &path)?;
                    keys.insert(key);
                }
            }
        }
        Ok(Got::Object)
    }
}

/// The members of a message's top-level object.
fn read_members<'de, A: MapAccess<'de>>(
    map: &mut A,
    schema: Schema,
    slots: &mut MessageSlots,
    trace: &mut Trace,
) -> Result<(), A::Error> {
    let joint_count = match schema {
        Schema::Joints { joint_count } => joint_count,
        Schema::Measured | Schema::Stamp => 0,
    };
    while let Some(key) = map.next_key_seed(KeySeed(|key: &str| MessageKey::of(schema, key)))? {
        let (slot, into, segment) = match key {
            MessageKey::T => (&mut slots.t, Target::Value, Segment::Key("t")),
            MessageKey::Time => (&mut slots.time, Target::Value, Segment::Key("time")),
            MessageKey::Seq => (&mut slots.seq, Target::Value, Segment::Key("seq")),
            MessageKey::Unit => (&mut slots.unit, Target::WholeString, Segment::Key("unit")),
            MessageKey::Q => (
                &mut slots.q,
                Target::Angles {
                    angles: &mut slots.angles,
                    joint_count,
                },
                Segment::Key("q"),
            ),
            MessageKey::Measured => (
                &mut slots.measured,
                Target::Pose(&mut slots.measured_pose),
                Segment::Key("measured"),
            ),
            MessageKey::Pose(index) => (
                &mut slots.pose[index],
                Target::Value,
                Segment::Key(POSE_KEYS[index]),
            ),
            MessageKey::Joint(n) => {
                let (slot, repeated) = slots.flat.slot(n, joint_count);
                let path = Path {
                    parent: None,
                    segment: Segment::Joint(n),
                };
                keep(map, slot, repeated, Target::Value, &path, trace)?;
                continue;
            }
            MessageKey::Other => {
                map.next_value::<IgnoredAny>()?;
                continue;
            }
        };
        let path = Path {
            parent: None,
            segment,
        };
        let repeated = slot.is_some();
        keep(map, slot, repeated, into, &path, trace)?;
    }
    Ok(())
}

/// Reads the value of a kept field into `slot` (a repeated field's last value wins, and the
/// repetition is noted).
fn keep<'de, A: MapAccess<'de>>(
    map: &mut A,
    slot: &mut Option<Got>,
    repeated: bool,
    into: Target<'_>,
    path: &Path<'_>,
    trace: &mut Trace,
) -> Result<(), A::Error> {
    if repeated {
        trace.note_repeated(path);
    }
    let got = map.next_value_seed(Probe {
        into,
        path: Some(path),
        trace: &mut *trace,
    });
    *slot = Some(trace.located(got, path)?);
    Ok(())
}

/// Reads an object key as what `classify` makes of it, without copying it.
struct KeySeed<F>(F);

impl<'de, K, F: FnOnce(&str) -> K> DeserializeSeed<'de> for KeySeed<F> {
    type Value = K;

    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<K, D::Error> {
        deserializer.deserialize_str(self)
    }
}

impl<K, F: FnOnce(&str) -> K> Visitor<'_> for KeySeed<F> {
    type Value = K;

    fn expecting(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        formatter.write_str("an object key")
    }

    fn visit_str<E: de::Error>(self, key: &str) -> Result<K, E> {
        Ok((self.0)(key))
    }
}

/// The fast path for messages in their usual shapes; it gives up on anything else, and the single
/// pass above decides.
mod fast;

// ---------------------------------------------------------------------------------------------
// Encoding
// ---------------------------------------------------------------------------------------------

/// Serialises an output message to JSON bytes.
///
/// # Panics
///
/// If `value`'s `Serialize` implementation fails, which armtwin's message types never do (plain
/// structs, string keys, no custom implementations).
#[must_use]
#[allow(
    clippy::expect_used,
    reason = "serialising armtwin's plain message structs into a Vec cannot fail"
)]
pub fn to_json_bytes<T: Serialize>(value: &T) -> Vec<u8> {
    // Room for most messages at once: growing from serde_json's small default copied each
    // message twice.
    let mut bytes = Vec::with_capacity(512);
    serde_json::to_writer(&mut bytes, value).expect("armtwin's wire messages always serialise");
    bytes
}

/// Room for a pose or deviation message (about 300 bytes with a long robot id) without growing.
const POSE_JSON_CAPACITY: usize = 384;

/// Room for a metrics message (about 1.6 kB with full-precision statistics) without growing.
const METRICS_JSON_CAPACITY: usize = 2048;

/// A twin (or measured) pose: `{robot, t, seq, frame, x, y, z, roll, pitch, yaw, qx, qy, qz, qw}`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PoseMessage {
    /// Robot id.
    pub robot: String,
    /// Source time (s).
    pub t: f64,
    /// The twin's pose sequence number.
    pub seq: u64,
    /// The frame the pose is expressed in (`base`, `base_link`).
    pub frame: &'static str,
    /// Position (m), roll/pitch/yaw (rad) and quaternion (`qw ≥ 0`).
    #[serde(flatten)]
    pub pose: PoseFields,
}

impl PoseMessage {
    /// The message of `readout`, expressed in `frame` ([`crate::kinematics::OutputFrame::as_str`]).
    #[must_use]
    pub fn new(
        robot: impl Into<String>,
        t: f64,
        seq: u64,
        frame: &'static str,
        readout: &PoseReadout,
    ) -> Self {
        Self {
            robot: robot.into(),
            t,
            seq,
            frame,
            pose: PoseFields::from(readout),
        }
    }

    /// The message's JSON: the bytes [`to_json_bytes`] writes for it, written directly (this is
    /// the message the service sends for every joint sample).
    #[must_use]
    pub fn to_json_bytes(&self) -> Vec<u8> {
        let mut object = FlatObject::with_capacity(POSE_JSON_CAPACITY);
        object.string("robot", &self.robot);
        object.number("t", self.t);
        object.unsigned("seq", self.seq);
        object.string("frame", self.frame);
        for (name, value) in PoseFields::NAMES.into_iter().zip(self.pose.values()) {
            object.number(name, value);
        }
        object.finish()
    }
}

/// Twin minus measured for one paired sample (metres, radians):
/// `{robot, t, dx, dy, dz, position, quat_distance, angle, droll, dpitch, dyaw}`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeviationMessage {
    /// Robot id.
    pub robot: String,
    /// Source time (s) of the pair.
    pub t: f64,
    /// `x_twin − x_measured` (m).
    pub dx: f64,
    /// `y_twin − y_measured` (m).
    pub dy: f64,
    /// `z_twin − z_measured` (m).
    pub dz: f64,
    /// Distance between the positions (m).
    pub position: f64,
    /// Quaternion distance `1 − |⟨a, b⟩|`, in [0, 1].
    pub quat_distance: f64,
    /// Rotation angle between the orientations (rad), in [0, π].
    pub angle: f64,
    /// Roll difference (rad), wrapped to (−π, π].
    pub droll: f64,
    /// Pitch difference (rad), wrapped to (−π, π].
    pub dpitch: f64,
    /// Yaw difference (rad), wrapped to (−π, π].
    pub dyaw: f64,
}

impl DeviationMessage {
    /// The message of `deviation`, observed at `t` (s).
    #[must_use]
    pub fn new(robot: impl Into<String>, t: f64, deviation: &Deviation) -> Self {
        Self {
            robot: robot.into(),
            t,
            dx: deviation.dx_m,
            dy: deviation.dy_m,
            dz: deviation.dz_m,
            position: deviation.position_m,
            quat_distance: deviation.quat_distance,
            angle: deviation.angle_rad,
            droll: deviation.droll_rad,
            dpitch: deviation.dpitch_rad,
            dyaw: deviation.dyaw_rad,
        }
    }

    /// The message's JSON: the bytes [`to_json_bytes`] writes for it, written directly (this is
    /// the message the service sends for every paired measured pose).
    #[must_use]
    pub fn to_json_bytes(&self) -> Vec<u8> {
        let mut object = FlatObject::with_capacity(POSE_JSON_CAPACITY);
        object.string("robot", &self.robot);
        object.number("t", self.t);
        object.number("dx", self.dx);
        object.number("dy", self.dy);
        object.number("dz", self.dz);
        object.number("position", self.position);
        object.number("quat_distance", self.quat_distance);
        object.number("angle", self.angle);
        object.number("droll", self.droll);
        object.number("dpitch", self.dpitch);
        object.number("dyaw", self.dyaw);
        object.finish()
    }
}

/// Something a dashboard should hear about: `{robot, t, kind, reason, key?, detail?}`, `kind`
/// one of `rejected`, `alarm`, `recovered`, `gap`, `unpaired`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EventMessage {
    /// Robot id.
    pub robot: String,
    /// Source time (s) of the sample concerned.
    pub t: f64,
    /// [`crate::pipeline::EventKind::as_str`].
    pub kind: &'static str,
    /// A sentence for people.
    pub reason: String,
    /// The key the input arrived on, if an input is concerned (omitted when `None`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub key: Option<String>,
    /// Details for machines (omitted when `null`): `rejected` → `{cause}`; `alarm` and
    /// `recovered` → `{metric, value, threshold}`; `gap` → `{gap_s}` or `{expected, got}`;
    /// `unpaired` → `{cause, measured_s}`.
    #[serde(skip_serializing_if = "Value::is_null")]
    pub detail: Value,
    /// Events of this robot the rate limit kept back since its previous published event (counted,
    /// not published; omitted when 0).
    #[serde(skip_serializing_if = "is_zero")]
    pub suppressed: u64,
}

#[allow(
    clippy::trivially_copy_pass_by_ref,
    reason = "serde's skip_serializing_if passes a reference"
)]
fn is_zero(n: &u64) -> bool {
    *n == 0
}

impl EventMessage {
    /// The message of a pipeline event (its `reason` the event's sentence, written here).
    #[must_use]
    pub fn new(event: &Event<'_>) -> Self {
        let detail = match event.detail {
            EventDetail::Rejected { cause } => json!({ "cause": cause.as_str() }),
            EventDetail::Alarm {
                metric,
                value,
                threshold,
            } => json!({ "metric": metric, "value": value, "threshold": threshold }),
            EventDetail::StampGap { gap_s } => json!({ "gap_s": gap_s }),
            EventDetail::Restart { from_s, to_s } => json!({ "from_s": from_s, "to_s": to_s }),
            EventDetail::SeqGap { expected, got } => json!({ "expected": expected, "got": got }),
            EventDetail::Unpaired { cause, measured_s } => {
                json!({ "cause": cause, "measured_s": measured_s })
            }
            EventDetail::Epoch { epoch } => json!({ "epoch": epoch }),
        };
        Self {
            robot: event.robot.to_owned(),
            t: event.stamp_s,
            kind: event.kind.as_str(),
            reason: event.to_string(),
            key: event.key.map(str::to_owned),
            detail,
            suppressed: 0,
        }
    }
}

/// Error statistics of one metric: `{mae, rmse, max}`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StatsJson {
    /// Mean absolute error.
    pub mae: f64,
    /// Root mean square error.
    pub rmse: f64,
    /// Largest magnitude.
    pub max: f64,
}

impl From<&Stats> for StatsJson {
    fn from(stats: &Stats) -> Self {
        Self {
            mae: stats.mae,
            rmse: stats.rmse,
            max: stats.max,
        }
    }
}

/// Statistics of every metric over `n` pairs:
/// `{n, position, x, y, z, quat_distance, angle, roll, pitch, yaw}` (the names of
/// [`crate::metrics::METRIC_NAMES`]; metres, radians, quaternion distance).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StatsSetJson {
    /// Pairs counted.
    pub n: u64,
    /// Position distance (m).
    pub position: StatsJson,
    /// |dx| (m).
    pub x: StatsJson,
    /// |dy| (m).
    pub y: StatsJson,
    /// |dz| (m).
    pub z: StatsJson,
    /// Quaternion distance.
    pub quat_distance: StatsJson,
    /// Rotation angle (rad).
    pub angle: StatsJson,
    /// |droll| (rad).
    pub roll: StatsJson,
    /// |dpitch| (rad).
    pub pitch: StatsJson,
    /// |dyaw| (rad).
    pub yaw: StatsJson,
}

impl StatsSetJson {
    /// Writes `n` and each metric's `{mae, rmse, max}` into `object`, in field order.
    fn write_members(&self, object: &mut FlatObject) {
        object.unsigned("n", self.n);
        // The order of `METRIC_NAMES`, as the fields.
        let stats = [
            &self.position,
            &self.x,
            &self.y,
            &self.z,
            &self.quat_distance,
            &self.angle,
            &self.roll,
            &self.pitch,
            &self.yaw,
        ];
        for (name, stats) in METRIC_NAMES.into_iter().zip(stats) {
            object.open(name);
            object.number("mae", stats.mae);
            object.number("rmse", stats.rmse);
            object.number("max", stats.max);
            object.close();
        }
    }
}

impl From<&StatsSet> for StatsSetJson {
    fn from(set: &StatsSet) -> Self {
        // The order of `METRIC_NAMES`.
        let [position, x, y, z, quat_distance, angle, roll, pitch, yaw] =
            set.stats.each_ref().map(StatsJson::from);
        Self {
            n: set.n,
            position,
            x,
            y,
            z,
            quat_distance,
            angle,
            roll,
            pitch,
            yaw,
        }
    }
}

/// Statistics over the sliding window: `{seconds, n, position, …, yaw}`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct WindowJson {
    /// Window length (s) of source time.
    pub seconds: f64,
    /// The statistics over the window.
    #[serde(flatten)]
    pub stats: StatsSetJson,
}

/// A robot's metrics: `{robot, t, paired, unpaired, rejected, epoch, cumulative, window}`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MetricsMessage {
    /// Robot id.
    pub robot: String,
    /// Newest source time (s) seen for the robot.
    pub t: f64,
    /// Measured poses paired with the twin.
    pub paired: u64,
    /// Measured poses that could not be paired.
    pub unpaired: u64,
    /// Inputs rejected.
    pub rejected: u64,
    /// The metrics epoch (one more each time the robot's model was replaced).
    pub epoch: u64,
    /// Since start or the last reset.
    pub cumulative: StatsSetJson,
    /// Over the sliding window.
    pub window: WindowJson,
}

impl MetricsMessage {
    /// The message of a pipeline snapshot.
    #[must_use]
    pub fn new(snapshot: &MetricsSnapshot) -> Self {
        Self {
            robot: snapshot.robot.clone(),
            t: snapshot.stamp_s,
            paired: snapshot.paired,
            unpaired: snapshot.unpaired,
            rejected: snapshot.rejected,
            epoch: snapshot.epoch,
            cumulative: StatsSetJson::from(&snapshot.cumulative),
            window: WindowJson {
                seconds: snapshot.window_s,
                stats: StatsSetJson::from(&snapshot.window),
            },
        }
    }

    /// The message's JSON: the bytes [`to_json_bytes`] writes for it, written directly (each
    /// tracked robot sends one every metrics period).
    #[must_use]
    pub fn to_json_bytes(&self) -> Vec<u8> {
        let mut object = FlatObject::with_capacity(METRICS_JSON_CAPACITY);
        object.string("robot", &self.robot);
        object.number("t", self.t);
        object.unsigned("paired", self.paired);
        object.unsigned("unpaired", self.unpaired);
        object.unsigned("rejected", self.rejected);
        object.unsigned("epoch", self.epoch);
        object.open("cumulative");
        self.cumulative.write_members(&mut object);
        object.close();
        object.open("window");
        object.number("seconds", self.window.seconds);
        self.window.stats.write_members(&mut object);
        object.close();
        object.finish()
    }
}

/// A stamped pose: `{t, x, y, z, roll, pitch, yaw, qx, qy, qz, qw}`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StampedPoseJson {
    /// Source time (s).
    pub t: f64,
    /// The pose.
    #[serde(flatten)]
    pub pose: PoseFields,
}

/// Stamped joint angles: `{t, q}` (rad).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StampedJointsJson {
    /// Source time (s).
    pub t: f64,
    /// Joint angles (rad).
    pub q: Vec<f64>,
}

/// Whether each alarm is active: `{position, angle}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct AlarmsJson {
    /// Position alarm.
    pub position: bool,
    /// Angle alarm.
    pub angle: bool,
}

/// A robot's state view: `{robot, model, calibration, tool, frame, joints, twin, measured,
/// alarms, metrics}`; `calibration`, `joints`, `twin`, `measured` are `null` until known.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StateMessage {
    /// Robot id.
    pub robot: String,
    /// Arm model name (`ur10e`, or a custom arm's name).
    pub model: String,
    /// Where the factory calibration came from; `null` for the nominal arm.
    pub calibration: Option<String>,
    /// Tool offset `[x, y, z, rx, ry, rz]` (m, rotation vector in rad) in the flange frame.
    pub tool: [f64; 6],
    /// The frame poses are expressed in.
    pub frame: &'static str,
    /// Last valid joint sample.
    pub joints: Option<StampedJointsJson>,
    /// Last twin pose.
    pub twin: Option<StampedPoseJson>,
    /// Last measured pose, in the output frame.
    pub measured: Option<StampedPoseJson>,
    /// Alarm states.
    pub alarms: AlarmsJson,
    /// Current metrics.
    pub metrics: MetricsMessage,
}

impl StateMessage {
    /// The message of a pipeline state view.
    #[must_use]
    pub fn new(state: &RobotState<'_>) -> Self {
        let stamped = |&(t, pose): &(f64, &PoseReadout)| StampedPoseJson {
            t,
            pose: PoseFields::from(pose),
        };
        let Alarms { position, angle } = state.alarms_active;
        Self {
            robot: state.robot.to_owned(),
            model: state.model.arm().name.clone(),
            calibration: state
                .model
                .calibration()
                .map(|calibration| calibration.source_name.clone()),
            tool: state.model.tool().to_ur_pose(),
            frame: state.model.frame().as_str(),
            joints: state
                .last_joints
                .map(|(t, q)| StampedJointsJson { t, q: q.to_vec() }),
            twin: state.last_twin_pose.as_ref().map(stamped),
            measured: state.last_measured.as_ref().map(stamped),
            alarms: AlarmsJson { position, angle },
            metrics: MetricsMessage::new(&state.metrics),
        }
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "decoded values are copied, not computed")]
mod tests {
    use super::*;

    /// Both decoders agree on every message the fast one accepts, and the fast one accepts the
    /// usual shapes.
    fn assert_paths_agree(payload: &str, joint_count: usize) -> bool {
        let bytes = payload.as_bytes();
        let fast_joints = fast::joints(bytes, joint_count);
        if let Some(fast) = &fast_joints {
            assert_eq!(
                Ok(fast),
                general_joints(bytes, joint_count)
                    .map_err(|refused| refused.error)
                    .as_ref(),
                "{payload}"
            );
        }
        let fast_measured = fast::measured(bytes);
        if let Some(fast) = &fast_measured {
            assert_eq!(
                Ok(fast),
                general_measured(bytes)
                    .map_err(|refused| refused.error)
                    .as_ref(),
                "{payload}"
            );
        }
        fast_joints.is_some() || fast_measured.is_some()
    }

    #[test]
    fn the_fast_path_takes_usual_messages_and_agrees_with_the_general_one() {
        let usual = [
            r#"{"t": 12.5, "q": [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739]}"#,
            r#"{"q":[1,2,3,-1,0,1e-3],"seq":7,"time":3}"#,
            r#"{"t":1,"unit":"deg","q":[90,-45,10,0,0,359.5],"extra":{"a":[1e400]}}"#,
            r#"{"t":2,"q":[0,0,0,0,0,0],"measured":{"t":9,"x":1,"y":2,"z":3,"qx":0,"qy":0,"qz":0,"qw":1.02}}"#,
            r#"{"t":2,"q":[0,0,0,0,0,0],"measured":{"x":1,"y":2,"z":3,"rx":0.1,"ry":2,"rz":0.3}}"#,
            r#"{"t": 12.5, "x": -0.807, "y": 0.436, "z": 0.42, "qx": -0.408, "qy": -0.9, "qz": -0.014, "qw": 0.152}"#,
            r#"{"time": 12.5, "x": -0.807, "y": 0.436, "z": 0.42, "roll": -3.038, "pitch": -0.289, "yaw": 2.275}"#,
            r#"{"x": -0.807, "y": 0.436, "z": 0.42, "rx": 0.92, "ry": 2.03, "rz": 0.03, "note": "x"}"#,
            r#"{"t":1,"q":[0,0,0,0,0,0],"note":"Zelle 3 · Roboter ä","flags":[true,false,null,[],{}],"n":-0.0e+0}"#,
            " \t\r\n{ \"t\" :\n1 , \"q\" : [ 0 ,0,0,0,0, 0 ] }\n ",
        ];
        for payload in usual {
            assert!(
                assert_paths_agree(payload, 6),
                "fast path refused {payload}"
            );
        }
        // Unusual or invalid: the general decoder decides (and names the problem).
        let unusual = [
            r#"{"t": null, "q": [0, 0, 0, 0, 0, 0]}"#,
            r#"{"t": 1, "time": 1, "q": [0, 0, 0, 0, 0, 0]}"#,
            r#"{"t": 1, "t": 2, "q": [0, 0, 0, 0, 0, 0]}"#,
            r#"{"t": 1, "q1": 0, "q2": 0, "q3": 0, "q4": 0, "q5": 0, "q6": 0}"#,
            r#"{"t": 1, "q": [0, 0, 0, 0, 0]}"#,
            r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0, 0]}"#,
            r#"{"t": 1, "q": [0, 0, "0", 0, 0, 0]}"#,
            r#"{"t": 1, "q": [0, 0, 0, 0, 0, 1e400]}"#,
            r#"{"t": 1, "seq": -1, "q": [0, 0, 0, 0, 0, 0]}"#,
            r#"{"t": 1, "seq": 1.5, "q": [0, 0, 0, 0, 0, 0]}"#,
            r#"{"t": 1, "unit": "grad", "q": [0, 0, 0, 0, 0, 0]}"#,
            r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0], "measured": {"x": 1, "y": 2, "z": 3}}"#,
            r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0], "measured": {"x": 1, "y": 2, "z": 3, "qx": 0, "qy": 0, "qz": 0, "qw": 2}}"#,
            r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0], "measured": null}"#,
            r#"{"t": 1, "x": 1, "y": 2, "z": 3, "qx": 0, "qy": 0, "qz": 0, "qw": 1, "roll": 0, "pitch": 0, "yaw": 0}"#,
            r#"{"t": 1, "x": 1, "y": 2, "z": 3, "qx": 0, "qy": 0, "qw": 1}"#,
            r#"{"t": 1, "x": 1, "y": 2, "z": 3, "rx": 1e200, "ry": 0, "rz": 0}"#,
            r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0]} trailing"#,
            "[1, 2]",
            // Escapes in a key or a string: rare, left to the general decoder.
            r#"{"\u0074": 1.5, "q": [1, 2, 3, 4, 5, 6]}"#,
            r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0], "note": "a \"quoted\" word"}"#,
            // Not JSON.
            r#"{"t": 01, "q": [0, 0, 0, 0, 0, 0]}"#,
            r#"{"t": 1., "q": [0, 0, 0, 0, 0, 0]}"#,
            r#"{"t": .5, "q": [0, 0, 0, 0, 0, 0]}"#,
            r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0], "note": tru}"#,
            r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0],}"#,
            r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0,]}"#,
            "{\"t\": 1, \"q\": [0, 0, 0, 0, 0, 0], \"note\": \"\u{1}\"}",
        ];
        for payload in unusual {
            assert!(!assert_paths_agree(payload, 6), "fast path took {payload}");
        }
    }

    proptest::proptest! {
        #[test]
        fn both_paths_agree_on_generated_messages(
            q in proptest::collection::vec(-6.0_f64..6.0, 5..8),
            stamp in proptest::option::of(-1e3_f64..1e6),
            seq in proptest::option::of(0_u64..u64::MAX),
            degrees in proptest::option::of(proptest::bool::ANY),
            pose in proptest::array::uniform7(-2.0_f64..2.0),
            form in 0_usize..4,
            integers in proptest::bool::ANY,
        ) {
            let number = |v: f64| if integers { format!("{}", v.round()) } else { format!("{v:e}") };
            let mut fields = Vec::new();
            if let Some(stamp) = stamp {
                fields.push(format!(r#""t":{}"#, number(stamp)));
            }
            if let Some(seq) = seq {
                fields.push(format!(r#""seq":{seq}"#));
            }
            if let Some(degrees) = degrees {
                fields.push(format!(r#""unit":"{}""#, if degrees { "deg" } else { "rad" }));
            }
            let q_text: Vec<String> = q.iter().map(|&v| number(v)).collect();
            fields.push(format!(r#""q":[{}]"#, q_text.join(",")));
            let [x, y, z, a, b, c, d] = pose;
            let orientation = match form {
                0 => format!(r#""qx":{a},"qy":{b},"qz":{c},"qw":{d}"#),
                1 => format!(r#""roll":{a},"pitch":{b},"yaw":{c}"#),
                2 => format!(r#""rx":{a},"ry":{b},"rz":{c}"#),
                _ => String::new(),
            };
            let pose_text = format!(r#""x":{},"y":{y},"z":{z},{orientation}"#, number(x));
            fields.push(format!(r#""measured":{{{pose_text}}}"#));
            let joints = format!("{{{}}}", fields.join(","));
            assert_paths_agree(&joints, 6);
            let measured = match stamp {
                Some(stamp) => format!(r#"{{"time":{stamp},{pose_text}}}"#),
                None => format!("{{{pose_text}}}"),
            };
            assert_paths_agree(&measured, 6);
        }
    }

    /// One of four valid messages with `edits` applied: (0 remove, 1 replace, 2 insert; position,
    /// byte).
    fn damaged(message: usize, edits: Vec<(usize, usize, u8)>) -> Vec<u8> {
        let mut bytes = [
            r#"{"t":1.25,"seq":3,"unit":"deg","q":[0.5,-1e-3,2E2,0,-0,12],"note":{"a":[true,null,"b"]}}"#,
            r#"{"t":1.25,"q":[0.5,-1,2,0,0,1],"measured":{"t":1,"x":0.25,"y":-1,"z":3,"qx":0,"qy":0,"qz":0,"qw":1}}"#,
            r#"{"time":7,"x":0.25,"y":-1,"z":3,"roll":0.1,"pitch":-0.2,"yaw":3.1,"extra":[]}"#,
            r#"{"t":7,"x":0.25,"y":-1,"z":3,"rx":0.1,"ry":-0.2,"rz":1.5}"#,
        ][message]
            .as_bytes()
            .to_vec();
        for (kind, position, byte) in edits {
            let at = position % (bytes.len() + 1);
            match kind {
                0 if at < bytes.len() => {
                    bytes.remove(at);
                }
                1 if at < bytes.len() => bytes[at] = byte,
                _ => bytes.insert(at, byte),
            }
        }
        bytes
    }

    proptest::proptest! {
        #![proptest_config(proptest::test_runner::Config::with_cases(4000))]

        /// Damaged messages: whatever the fast path still accepts, the general decoder reads the
        /// same (it must never take a message the general one refuses, nor read it differently).
        #[test]
        fn both_paths_agree_on_damaged_messages(
            message in 0_usize..4,
            edits in proptest::collection::vec(
                (0_usize..3, proptest::num::usize::ANY, proptest::sample::select(
                    br#"{}[]:,".-+eE0159 tfnul\x"#.to_vec(),
                )),
                1..4,
            ),
        ) {
            let bytes = damaged(message, edits);
            if let Ok(text) = std::str::from_utf8(&bytes) {
                assert_paths_agree(text, 6);
            }
        }
    }

    /// The stamp a refused message offered before the decoder read it in one pass: `t` if
    /// present (a `null` or non-number gives none), else `time`, of a payload that parses as a
    /// JSON object.
    fn stamp_of_parsed(payload: &[u8]) -> Result<Option<f64>, serde_json::Error> {
        let value: Value = serde_json::from_slice(payload)?;
        Ok(value.as_object().and_then(|object| {
            object
                .get("t")
                .or_else(|| object.get("time"))
                .and_then(Value::as_f64)
        }))
    }

    #[test]
    fn a_refused_message_carries_its_own_stamp() {
        let stamp = |payload: &str| {
            read_joints(payload.as_bytes(), 2)
                .expect_err(payload)
                .stamp_s
        };
        assert_eq!(stamp(r#"{"t": 3.5, "q": "x"}"#), Some(3.5));
        assert_eq!(stamp(r#"{"time": 4, "q": [1, 2, 3]}"#), Some(4.0));
        assert_eq!(stamp(r#"{"t": 1, "time": 2, "q": [1, 2]}"#), Some(1.0));
        // A `t` that is no number hides `time`.
        assert_eq!(stamp(r#"{"t": null, "time": 2, "q": [1]}"#), None);
        assert_eq!(stamp(r#"{"t": "5", "time": 2, "q": [1, 2]}"#), None);
        // A repeated field: the last value counts, as in a parsed object.
        assert_eq!(stamp(r#"{"t": 1, "q": [1, 2], "t": 6}"#), Some(6.0));
        // Not JSON, overflowing, or not an object: no stamp.
        assert_eq!(stamp(r#"{"t": 3.5, "q": [1, 2]"#), None);
        assert_eq!(stamp(r#"{"t": 3.5, "q": [1, 1e400]}"#), None);
        assert_eq!(stamp(r#"[{"t": 3.5}]"#), None);
        let refused =
            read_measured(br#"{"time": 2.5, "x": 0, "y": 0, "z": 0}"#).expect_err("no form");
        assert_eq!(refused.stamp_s, Some(2.5));
        assert_eq!(refused.error.kind(), "orientation_forms");
        assert_eq!(stamp_hint(br#"{"q": 1e400, "t": 7}"#), Some(7.0));
        assert_eq!(stamp_hint(b"{\"t\": 7} x"), None);
    }

    proptest::proptest! {
        #![proptest_config(proptest::test_runner::Config::with_cases(4000))]

        /// Damaged messages: a refused message offers the stamp of the parsed object, and none
        /// when the payload is not JSON.
        #[test]
        fn damaged_messages_offer_the_stamp_of_the_parsed_object(
            message in 0_usize..4,
            edits in proptest::collection::vec(
                (0_usize..3, proptest::num::usize::ANY, proptest::sample::select(
                    br#"{}[]:,".-+eE0159 tfnul\x"#.to_vec(),
                )),
                1..4,
            ),
        ) {
            let bytes = damaged(message, edits);
            let offered = [
                read_joints(&bytes, 6).err().map(|refused| (refused.error, refused.stamp_s)),
                read_measured(&bytes).err().map(|refused| (refused.error, refused.stamp_s)),
            ];
            for (error, stamp_s) in offered.into_iter().flatten() {
                match stamp_of_parsed(&bytes) {
                    Ok(parsed) => proptest::prop_assert_eq!(stamp_s, parsed, "{:?}", error),
                    Err(_) if matches!(error, WireError::NotJson { .. } | WireError::NonFinite { .. }) => {
                        proptest::prop_assert_eq!(stamp_s, None);
                    }
                    // Only a number beyond f64 in a field no decoder reads keeps such a payload
                    // readable.
                    Err(_) => {}
                }
            }
        }
    }

    #[test]
    fn joint_index_accepts_only_plain_positive_numbers() {
        assert_eq!(joint_index("q1"), Some(1));
        assert_eq!(joint_index("q12"), Some(12));
        for key in ["q", "q0", "q01", "q-1", "q+1", "qx", "q1a", "Q1", "time"] {
            assert_eq!(joint_index(key), None, "{key}");
        }
    }

    #[test]
    fn overflowing_numbers_are_located_and_unknown_ones_skipped() {
        let err = decode_joints(br#"{"q": [0, 1e400]}"#, 2).expect_err("overflow");
        assert_eq!(
            err,
            WireError::NonFinite {
                field: "q[1]".to_owned()
            }
        );
        let err = decode_joints(
            br#"{"q1": 0, "q2": 0, "measured": {"x": 0, "y": -1e999, "z": 0}}"#,
            2,
        )
        .expect_err("overflow");
        assert_eq!(
            err,
            WireError::NonFinite {
                field: "measured.y".to_owned()
            }
        );
        // Skipped: an unknown field, and the nested pose's own stamp.
        let sample = decode_joints(
            br#"{"extra": [1e400, {"a": -1e400}], "q": [0, 0],
                 "measured": {"t": 1e400, "x": 0, "y": 0, "z": 0, "rx": 0, "ry": 0, "rz": 0}}"#,
            2,
        )
        .expect("unknown fields are skipped");
        assert_eq!(sample.sample.q_rad, [0.0, 0.0]);
    }

    #[test]
    fn a_bare_overflowing_number_is_not_json() {
        let err = decode_measured(b"1e400").expect_err("not an object");
        assert_eq!(err.kind(), "not_json");
        assert!(err.to_string().contains("number out of range"), "{err}");
    }

    #[test]
    fn syntax_errors_after_a_field_are_not_blamed_on_it() {
        let err = decode_joints(br#"{"q": [1, 2] "t": 1}"#, 2).expect_err("missing comma");
        assert_eq!(err.kind(), "not_json");
        let err = decode_joints(br#"{"q": [1, 2]} x"#, 2).expect_err("trailing characters");
        assert_eq!(err.kind(), "not_json");
    }

    #[test]
    fn duplicate_known_fields_are_rejected() {
        let err = decode_joints(br#"{"q": [1], "t": 1, "t": 2}"#, 1).expect_err("duplicate");
        assert_eq!(
            err,
            WireError::DuplicateField {
                field: "t".to_owned()
            }
        );
        assert_eq!(err.to_string(), "field 't': appears more than once");
        // Unknown fields are not looked at, repeated or not.
        let sample = decode_joints(br#"{"q": [1], "v": 1, "v": 2}"#, 1).expect("valid");
        assert_eq!(sample.sample.q_rad, [1.0]);
    }

    #[test]
    fn rotation_vector_overflow_names_the_largest_component() {
        let err = decode_measured(br#"{"x": 0, "y": 0, "z": 0, "rx": 1, "ry": -1e200, "rz": 0}"#)
            .expect_err("overflow");
        assert_eq!(
            err,
            WireError::NonFinite {
                field: "ry".to_owned()
            }
        );
    }

    #[test]
    fn quaternion_norm_edges() {
        let pose = |q: [f64; 4]| {
            decode_measured(
                format!(
                    r#"{{"x": 0, "y": 0, "z": 0, "qx": {}, "qy": {}, "qz": {}, "qw": {}}}"#,
                    q[0], q[1], q[2], q[3]
                )
                .as_bytes(),
            )
        };
        assert!(pose([0.0, 0.0, 0.0, 1.0499]).is_ok());
        assert!(pose([0.0, 0.0, 0.0, 0.9501]).is_ok());
        assert!(pose([0.0, 0.0, 0.0, 1.051]).is_err());
        assert!(pose([0.0, 0.0, 0.0, 0.0]).is_err());
        let err = pose([1e200, 0.0, 0.0, 1.0]).expect_err("overflowing norm");
        assert!(matches!(err, WireError::QuaternionNorm { norm, .. } if norm.is_infinite()));
    }
}
