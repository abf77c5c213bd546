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

use std::fmt::{self, Write as _};

use nalgebra::{UnitQuaternion, Vector3};
use serde::Serialize;
use serde::de::{self, DeserializeSeed, Deserializer, IgnoredAny, MapAccess, SeqAccess, Visitor};
use serde_json::{Map, Number, Value, json};
use thiserror::Error;

use super::PoseFields;
use super::flat_json::FlatObject;
use crate::kinematics::PoseReadout;
use crate::metrics::{Deviation, METRIC_NAMES, Stats, StatsSet};
use crate::orientation::{self, Rpy};
use crate::pipeline::{Event, EventDetail, MetricsSnapshot, RobotState};
use crate::sample::{JointSample, MeasuredSample};

/// Largest accepted payload (bytes); larger ones are rejected before parsing.
pub const MAX_PAYLOAD_BYTES: usize = 64 * 1024;

/// How far a quaternion's norm may be from 1 before it is rejected rather than normalised
/// (gateways round their components; a larger error means a wrong field, not rounding).
const QUATERNION_NORM_TOLERANCE: f64 = 0.05;

/// Why a gateway message was rejected.
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
}

impl WireError {
    /// A stable `snake_case` name of the error class, for event messages and counters.
    #[must_use]
    pub fn kind(&self) -> &'static str {
        match self {
            Self::TooLarge { .. } => "too_large",
            Self::NotUtf8 { .. } => "not_utf8",
            Self::NotJson { .. } => "not_json",
            Self::NotObject { .. } => "not_object",
            Self::MissingField { .. } => "missing_field",
            Self::WrongType { .. } => "wrong_type",
            Self::NonFinite { .. } => "non_finite",
            Self::JointCount { .. } => "joint_count",
            Self::AmbiguousFields { .. } => "ambiguous_fields",
            Self::DuplicateField { .. } => "duplicate_field",
            Self::Unit { .. } => "unit",
            Self::OrientationForms { .. } => "orientation_forms",
            Self::QuaternionNorm { .. } => "quaternion_norm",
        }
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

/// The stamp (`t` or `time`) of a message that failed to decode, if it has a usable one, so
/// that its rejection is reported at the message's own time.
#[must_use]
pub fn stamp_hint(payload: &[u8]) -> Option<f64> {
    if payload.len() > MAX_PAYLOAD_BYTES {
        return None;
    }
    let value: Value = serde_json::from_slice(payload).ok()?;
    let object = value.as_object()?;
    object
        .get("t")
        .or_else(|| object.get("time"))
        .and_then(Value::as_f64)
        .filter(|t| t.is_finite())
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
    match fast::joints(payload, joint_count) {
        Some(decoded) => Ok(decoded),
        None => general_joints(payload, joint_count),
    }
}

/// [`decode_joints`] for any message, naming what is wrong with an invalid one.
fn general_joints(payload: &[u8], joint_count: usize) -> Result<DecodedJoints, WireError> {
    let fields = parse_object(payload, Schema::JointMessage)?;
    let stamp_s = stamp(&fields)?;
    let seq = optional(&fields, "seq").map(sequence_number).transpose()?;
    let degrees = match optional(&fields, "unit") {
        None => false,
        Some(Value::String(unit)) if unit == "rad" => false,
        Some(Value::String(unit)) if unit == "deg" => true,
        Some(Value::String(unit)) => {
            return Err(WireError::Unit { got: unit.clone() });
        }
        Some(other) => return Err(wrong_type("unit".to_owned(), "a string", other)),
    };
    let mut q_rad = joint_angles(&fields, joint_count)?;
    if degrees {
        for angle in &mut q_rad {
            *angle = angle.to_radians();
        }
    }
    let (measured, measured_error) = match optional(&fields, "measured") {
        None => (None, None),
        Some(Value::Object(pose)) => match pose_readout(pose, "measured.") {
            Ok(pose) => (Some(pose), None),
            Err(error) => (None, Some(error)),
        },
        Some(other) => (
            None,
            Some(wrong_type("measured".to_owned(), "an object", other)),
        ),
    };
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

/// Decodes a measured-pose message: position (m) and exactly one orientation form, the
/// quaternion normalised (within 5 % of unit norm) and canonicalised to `qw ≥ 0`.
pub fn decode_measured(payload: &[u8]) -> Result<MeasuredSample, WireError> {
    match fast::measured(payload) {
        Some(measured) => Ok(measured),
        None => general_measured(payload),
    }
}

/// [`decode_measured`] for any message, naming what is wrong with an invalid one.
fn general_measured(payload: &[u8]) -> Result<MeasuredSample, WireError> {
    let fields = parse_object(payload, Schema::MeasuredPose { with_stamp: true })?;
    Ok(MeasuredSample {
        stamp_s: stamp(&fields)?,
        pose: pose_readout(&fields, "")?,
    })
}

/// The value of an optional field; `null` counts as absent.
fn optional<'a>(fields: &'a Map<String, Value>, key: &str) -> Option<&'a Value> {
    fields.get(key).filter(|value| !value.is_null())
}

/// `t` or `time` (not both), a finite number, or `None`.
fn stamp(fields: &Map<String, Value>) -> Result<Option<f64>, WireError> {
    match (optional(fields, "t"), optional(fields, "time")) {
        (Some(_), Some(_)) => Err(WireError::AmbiguousFields {
            first: "t".to_owned(),
            second: "time".to_owned(),
        }),
        (Some(value), None) => number(value, || "t".to_owned()).map(Some),
        (None, Some(value)) => number(value, || "time".to_owned()).map(Some),
        (None, None) => Ok(None),
    }
}

fn sequence_number(value: &Value) -> Result<u64, WireError> {
    value
        .as_u64()
        .ok_or_else(|| wrong_type("seq".to_owned(), "a non-negative integer", value))
}

/// The `n` in a flat joint field `qn` (`q1`, `q2`, …; no sign, no leading zero).
fn joint_index(key: &str) -> Option<usize> {
    let digits = key.strip_prefix('q')?;
    if digits.is_empty() || digits.starts_with('0') || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

/// Exactly `joint_count` angles, from the `q` array or from `q1..qn`, in message units.
fn joint_angles(fields: &Map<String, Value>, joint_count: usize) -> Result<Vec<f64>, WireError> {
    let flat_keys = fields
        .keys()
        .filter(|key| joint_index(key).is_some())
        .count();
    if let Some(array) = fields.get("q") {
        if flat_keys > 0 {
            let lowest = fields
                .keys()
                .filter_map(|key| joint_index(key))
                .min()
                .unwrap_or(1);
            return Err(WireError::AmbiguousFields {
                first: "q".to_owned(),
                second: format!("q{lowest}"),
            });
        }
        let Value::Array(items) = array else {
            return Err(wrong_type("q".to_owned(), "an array", array));
        };
        if items.len() != joint_count {
            return Err(WireError::JointCount {
                field: "q".to_owned(),
                expected: joint_count,
                got: items.len(),
            });
        }
        return items
            .iter()
            .enumerate()
            .map(|(index, item)| number(item, || format!("q[{index}]")))
            .collect();
    }
    if flat_keys == 0 {
        return Err(WireError::MissingField {
            field: "q".to_owned(),
        });
    }
    if flat_keys != joint_count {
        return Err(WireError::JointCount {
            field: format!("q1..q{joint_count}"),
            expected: joint_count,
            got: flat_keys,
        });
    }
    (1..=joint_count)
        .map(|joint| {
            let key = format!("q{joint}");
            match fields.get(&key) {
                Some(value) => number(value, || key.clone()),
                // As many `q<n>` fields as joints, so one beyond `q{joint_count}` takes its place.
                None => Err(WireError::MissingField { field: key }),
            }
        })
        .collect()
}

/// A required number.
fn required(fields: &Map<String, Value>, prefix: &str, key: &str) -> Result<f64, WireError> {
    match fields.get(key) {
        Some(value) => number(value, || format!("{prefix}{key}")),
        None => Err(WireError::MissingField {
            field: format!("{prefix}{key}"),
        }),
    }
}

/// A finite JSON number (the parser already rejected overflowing ones); strings are not coerced.
fn number(value: &Value, field: impl FnOnce() -> String) -> Result<f64, WireError> {
    match value.as_f64() {
        Some(number) if number.is_finite() => Ok(number),
        Some(_) => Err(WireError::NonFinite { field: field() }),
        None => Err(wrong_type(field(), "a number", value)),
    }
}

fn wrong_type(field: String, expected: &'static str, value: &Value) -> WireError {
    WireError::WrongType {
        field,
        expected,
        got: match value {
            Value::Number(number) => format!("the number {number}"),
            // The text itself (cut short), so a log or a report shows what the gateway sent.
            Value::String(text) if text.chars().count() <= 40 => format!("the string {text:?}"),
            Value::String(text) => {
                format!(
                    "the string {:?}…",
                    text.chars().take(40).collect::<String>()
                )
            }
            other => json_type(other).to_owned(),
        },
    }
}

fn json_type(value: &Value) -> &'static str {
    match value {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

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

    /// The form's fields, in wire order.
    fn keys(self) -> &'static [&'static str] {
        match self {
            Self::Quaternion => &["qx", "qy", "qz", "qw"],
            Self::RollPitchYaw => &["roll", "pitch", "yaw"],
            Self::RotationVector => &["rx", "ry", "rz"],
        }
    }

    /// The first of the form's fields present in `fields`.
    fn first_present(self, fields: &Map<String, Value>) -> Option<&'static str> {
        self.keys()
            .iter()
            .copied()
            .find(|key| fields.contains_key(*key))
    }
}

/// Position and exactly one orientation form, from a measured pose object.
fn pose_readout(fields: &Map<String, Value>, prefix: &str) -> Result<PoseReadout, WireError> {
    let position_m = [
        required(fields, prefix, "x")?,
        required(fields, prefix, "y")?,
        required(fields, prefix, "z")?,
    ];
    let present: Vec<(OrientationForm, &str)> = OrientationForm::ALL
        .into_iter()
        .filter_map(|form| form.first_present(fields).map(|key| (form, key)))
        .collect();
    let [(form, _)] = present[..] else {
        return Err(WireError::OrientationForms {
            found: present
                .iter()
                .map(|(_, key)| format!("{prefix}{key}"))
                .collect(),
        });
    };
    let mut values = [0.0; 4];
    for (value, key) in values.iter_mut().zip(form.keys()) {
        *value = required(fields, prefix, key)?;
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
// The JSON layer: parse only the fields a decoder reads, remembering where a failure occurred.
// ---------------------------------------------------------------------------------------------

/// Which fields of an object are kept; the rest are skipped without converting their numbers,
/// so an unknown field can hold anything, even `1e400`.
#[derive(Debug, Clone, Copy)]
enum Schema {
    /// The top level of a joint message.
    JointMessage,
    /// A measured pose; `with_stamp` is false inside a joint message, whose stamp applies.
    MeasuredPose { with_stamp: bool },
    /// Inside a kept field: everything.
    Everything,
}

impl Schema {
    /// How to read the field `key` of an object read with this schema; `None` skips it.
    fn field(self, key: &str) -> Option<Self> {
        match self {
            Self::JointMessage => match key {
                "measured" => Some(Self::MeasuredPose { with_stamp: false }),
                "t" | "time" | "seq" | "unit" | "q" => Some(Self::Everything),
                _ => joint_index(key).map(|_| Self::Everything),
            },
            Self::MeasuredPose { with_stamp } => match key {
                "t" | "time" => with_stamp.then_some(Self::Everything),
                "x" | "y" | "z" | "qx" | "qy" | "qz" | "qw" | "roll" | "pitch" | "yaw" | "rx"
                | "ry" | "rz" => Some(Self::Everything),
                _ => None,
            },
            Self::Everything => Some(Self::Everything),
        }
    }
}

/// What the parser was doing when it failed.
#[derive(Debug, Default)]
struct ParseState {
    /// The value being read, as `measured.qx` or `q[2]`; left in place by a failure.
    path: String,
    /// The failure is a repeated field.
    duplicate: bool,
}

impl ParseState {
    fn into_error(self, error: &serde_json::Error) -> WireError {
        if self.duplicate {
            return WireError::DuplicateField { field: self.path };
        }
        // serde_json reports a number beyond f64 only through its message.
        let out_of_range = error.classify() == serde_json::error::Category::Syntax
            && error.to_string().starts_with("number out of range");
        if out_of_range && !self.path.is_empty() {
            return WireError::NonFinite { field: self.path };
        }
        WireError::NotJson {
            detail: error.to_string(),
        }
    }
}

/// Checks size and encoding, then parses an object with `schema`.
fn parse_object(payload: &[u8], schema: Schema) -> Result<Map<String, Value>, WireError> {
    if payload.len() > MAX_PAYLOAD_BYTES {
        return Err(WireError::TooLarge {
            bytes: payload.len(),
            limit: MAX_PAYLOAD_BYTES,
        });
    }
    let text = std::str::from_utf8(payload).map_err(|error| WireError::NotUtf8 {
        valid_up_to: error.valid_up_to(),
    })?;
    let mut state = ParseState::default();
    let mut deserializer = serde_json::Deserializer::from_str(text);
    let parsed = ValueSeed {
        schema,
        state: &mut state,
    }
    .deserialize(&mut deserializer)
    .and_then(|value| deserializer.end().map(|()| value));
    match parsed {
        Ok(Value::Object(fields)) => Ok(fields),
        Ok(other) => Err(WireError::NotObject {
            got: json_type(&other),
        }),
        Err(error) => Err(state.into_error(&error)),
    }
}

/// Reads one JSON value into a [`Value`], keeping what `schema` asks for.
struct ValueSeed<'s> {
    schema: Schema,
    state: &'s mut ParseState,
}

impl<'de> DeserializeSeed<'de> for ValueSeed<'_> {
    type Value = Value;

    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<Value, D::Error> {
        deserializer.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for ValueSeed<'_> {
    type Value = Value;

    fn expecting(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        formatter.write_str("a JSON value")
    }

    fn visit_bool<E: de::Error>(self, value: bool) -> Result<Value, E> {
        Ok(Value::Bool(value))
    }

    fn visit_i64<E: de::Error>(self, value: i64) -> Result<Value, E> {
        Ok(Value::from(value))
    }

    fn visit_u64<E: de::Error>(self, value: u64) -> Result<Value, E> {
        Ok(Value::from(value))
    }

    fn visit_f64<E: de::Error>(self, value: f64) -> Result<Value, E> {
        // serde_json never yields a non-finite number; if another parser did, it reads as null.
        Ok(Number::from_f64(value).map_or(Value::Null, Value::Number))
    }

    fn visit_str<E: de::Error>(self, value: &str) -> Result<Value, E> {
        Ok(Value::String(value.to_owned()))
    }

    fn visit_string<E: de::Error>(self, value: String) -> Result<Value, E> {
        Ok(Value::String(value))
    }

    fn visit_unit<E: de::Error>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }

    fn visit_none<E: de::Error>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Value, A::Error> {
        let mut items = Vec::new();
        if !matches!(self.schema, Schema::Everything) {
            // An array where an object is expected: skip it, the caller reports the type.
            while seq.next_element::<IgnoredAny>()?.is_some() {}
            return Ok(Value::Array(items));
        }
        loop {
            let mark = self.state.path.len();
            // Writing to a `String` cannot fail.
            let _ = write!(self.state.path, "[{}]", items.len());
            let item = seq.next_element_seed(ValueSeed {
                schema: Schema::Everything,
                state: &mut *self.state,
            })?;
            self.state.path.truncate(mark);
            match item {
                Some(item) => items.push(item),
                None => return Ok(Value::Array(items)),
            }
        }
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Value, A::Error> {
        let mut fields = Map::new();
        while let Some(key) = map.next_key::<String>()? {
            let Some(schema) = self.schema.field(&key) else {
                map.next_value::<IgnoredAny>()?;
                continue;
            };
            let mark = self.state.path.len();
            if mark > 0 {
                self.state.path.push('.');
            }
            self.state.path.push_str(&key);
            if fields.contains_key(&key) {
                self.state.duplicate = true;
                return Err(de::Error::custom(format_args!("duplicate field `{key}`")));
            }
            let value = map.next_value_seed(ValueSeed {
                schema,
                state: &mut *self.state,
            })?;
            self.state.path.truncate(mark);
            fields.insert(key, value);
        }
        Ok(Value::Object(fields))
    }
}

/// The fast path for messages in their usual shapes; it gives up on anything else, and the general
/// decoder above decides.
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
    /// The message of a pipeline event.
    #[must_use]
    pub fn new(event: &Event<'_>) -> Self {
        let detail = match event.detail {
            EventDetail::Rejected { cause } => json!({ "cause": cause }),
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
        };
        Self {
            robot: event.robot.to_owned(),
            t: event.stamp_s,
            kind: event.kind.as_str(),
            reason: event.reason.clone(),
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

/// A robot's metrics: `{robot, t, paired, unpaired, rejected, cumulative, window}`.
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
        let [position, angle] = state.alarms_active;
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
            twin: state.last_twin.as_ref().map(stamped),
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
                general_joints(bytes, joint_count).as_ref(),
                "{payload}"
            );
        }
        let fast_measured = fast::measured(bytes);
        if let Some(fast) = &fast_measured {
            assert_eq!(Ok(fast), general_measured(bytes).as_ref(), "{payload}");
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
            if let Ok(text) = std::str::from_utf8(&bytes) {
                assert_paths_agree(text, 6);
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
