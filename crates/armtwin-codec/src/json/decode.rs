//! Decoding armtwin's JSON gateway messages: one pass of `serde_json`'s parser over the payload
//! into fixed slots, then the checks that name what is wrong ([`super::WireError`]); the usual
//! shapes first go through the fast path (`fast`), which gives up on anything else.
//!
//! Must not know the network: bytes in, [`JointSample`] / [`MeasuredSample`] out.

use std::borrow::Cow;
use std::collections::BTreeSet;
use std::fmt::{self, Write as _};

use armtwin_core::kinematics::PoseReadout;
use armtwin_core::orientation::{self, Rpy};
use armtwin_core::sample::{
    ControllerStatus, JointAngles, JointQuantity, JointSample, JointState, MeasuredSample, Payload,
};
use nalgebra::{UnitQuaternion, Vector3};
use serde::de::{self, DeserializeSeed, Deserializer, IgnoredAny, MapAccess, SeqAccess, Visitor};
use serde_json::{Number, Value};

use super::{MAX_PAYLOAD_BYTES, Undecodable, WireError, fast};

/// How far a quaternion's norm may be from 1 before it is rejected rather than normalised
/// (gateways round their components; a larger error means a wrong field, not rounding).
const QUATERNION_NORM_TOLERANCE: f64 = 0.05;

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
/// use armtwin_codec::json::decode_joints;
/// let sample = decode_joints(br#"{"time": 2.5, "unit": "deg", "q1": 90, "q2": -45}"#, 2)?.sample;
/// assert_eq!(sample.stamp_s, Some(2.5));
/// assert!((sample.q_rad[0] - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
/// let error = decode_joints(br#"{"q": [0, "1.2"]}"#, 2).unwrap_err();
/// assert_eq!(error.kind(), "wrong_type");
/// assert_eq!(error.to_string(), "field 'q[1]': expected a number, got the string \"1.2\"");
/// # Ok::<(), armtwin_codec::json::WireError>(())
/// ```
pub fn decode_joints(payload: &[u8], joint_count: usize) -> Result<DecodedJoints, WireError> {
    read_joints(payload, joint_count).map_err(|undecodable| undecodable.error)
}

/// [`decode_joints`], and for a refused message the stamp it offers, from the same pass.
///
/// ```
/// use armtwin_codec::json::read_joints;
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
pub fn general_joints(payload: &[u8], joint_count: usize) -> Result<DecodedJoints, Undecodable> {
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
pub fn general_measured(payload: &[u8]) -> Result<MeasuredSample, Undecodable> {
    let slots = read_message(payload, Schema::Measured)?;
    let stamp_s = slots.stamp_hint();
    slots
        .into_measured()
        .map_err(|error| Undecodable { error, stamp_s })
}

/// The joint state of a joint message's `state` object: per-joint arrays named by
/// [`JointQuantity::name`], `robot_mode`, `safety_mode`, `status_bits` and `speed_scaling`
/// (together or none), and `payload` (`mass_kg`, `cog_m`, optional `inertia_kg_m2`). Fields it does
/// not know are skipped, as at the top level; `null` counts as absent.
fn joint_state(value: &Value, joint_count: usize) -> Result<JointState, WireError> {
    let bad = |field: &str, detail: String| WireError::JointState {
        field: format!("state.{field}"),
        detail,
    };
    let Value::Object(fields) = value else {
        return Err(bad(
            "",
            format!("expected an object, got {}", json_type(value)),
        ));
    };
    let number = |field: &str, value: &Value| -> Result<f64, WireError> {
        value.as_f64().ok_or_else(|| {
            bad(
                field,
                format!("expected a number, got {}", json_type(value)),
            )
        })
    };
    let numbers = |field: &str, value: &Value, count: usize| -> Result<Vec<f64>, WireError> {
        let Value::Array(items) = value else {
            return Err(bad(
                field,
                format!("expected an array, got {}", json_type(value)),
            ));
        };
        if items.len() != count {
            return Err(bad(
                field,
                format!("expected {count} values, got {}", items.len()),
            ));
        }
        items
            .iter()
            .enumerate()
            .map(|(index, item)| {
                // The field's name is written only for an error.
                item.as_f64().ok_or_else(|| {
                    bad(
                        &format!("{field}[{index}]"),
                        format!("expected a number, got {}", json_type(item)),
                    )
                })
            })
            .collect()
    };
    let mut state = JointState::new(joint_count);
    for quantity in JointQuantity::ALL {
        if let Some(value) = fields.get(quantity.name()).filter(|value| !value.is_null()) {
            state.set(quantity, &numbers(quantity.name(), value, joint_count)?);
        }
    }
    let status_fields = ["robot_mode", "safety_mode", "status_bits", "speed_scaling"]
        .map(|name| (name, fields.get(name).filter(|value| !value.is_null())));
    if status_fields.iter().any(|(_, value)| value.is_some()) {
        let [robot_mode, safety_mode, status_bits, speed_scaling] =
            status_fields.map(|(name, value)| {
                value.ok_or_else(|| {
                    bad(
                        name,
                        "missing: robot_mode, safety_mode, status_bits and speed_scaling come together"
                            .to_owned(),
                    )
                })
            });
        let int = |name: &str, value: &Value| -> Result<i32, WireError> {
            value
                .as_i64()
                .and_then(|value| i32::try_from(value).ok())
                .ok_or_else(|| bad(name, format!("expected a 32-bit integer, got {value}")))
        };
        state.status = Some(ControllerStatus {
            robot_mode: int("robot_mode", robot_mode?)?,
            safety_mode: int("safety_mode", safety_mode?)?,
            status_bits: status_bits?
                .as_u64()
                .and_then(|value| u32::try_from(value).ok())
                .ok_or_else(|| {
                    bad(
                        "status_bits",
                        "expected a 32-bit unsigned integer".to_owned(),
                    )
                })?,
            speed_scaling: number("speed_scaling", speed_scaling?)?,
        });
    }
    if let Some(value) = fields.get("payload").filter(|value| !value.is_null()) {
        state.payload = Some(payload_json(value)?);
    }
    Ok(state)
}

/// The `payload` of a `state` object: `mass_kg` (not negative), `cog_m` and optionally
/// `inertia_kg_m2`.
fn payload_json(value: &Value) -> Result<Payload, WireError> {
    let bad = |field: &str, detail: String| WireError::JointState {
        field: format!("state.payload.{field}"),
        detail,
    };
    let Value::Object(payload) = value else {
        return Err(bad(
            "",
            format!("expected an object, got {}", json_type(value)),
        ));
    };
    let numbers = |field: &str, count: usize| -> Result<Option<Vec<f64>>, WireError> {
        let Some(value) = payload.get(field).filter(|value| !value.is_null()) else {
            return Ok(None);
        };
        let values = match value {
            Value::Array(items) if items.len() == count => items
                .iter()
                .map(Value::as_f64)
                .collect::<Option<Vec<f64>>>(),
            _ => None,
        };
        values
            .map(Some)
            .ok_or_else(|| bad(field, format!("expected {count} numbers, got {value}")))
    };
    let mass_kg = match payload.get("mass_kg") {
        Some(value) => value
            .as_f64()
            .ok_or_else(|| bad("mass_kg", format!("expected a number, got {value}")))?,
        None => return Err(bad("mass_kg", "missing".to_owned())),
    };
    if mass_kg < 0.0 {
        return Err(bad(
            "mass_kg",
            format!("a mass of {mass_kg} kg: a mass is not negative"),
        ));
    }
    let cog = numbers("cog_m", 3)?.ok_or_else(|| bad("cog_m", "missing".to_owned()))?;
    let inertia = numbers("inertia_kg_m2", 6)?;
    Ok(Payload {
        mass_kg,
        cog_m: [cog[0], cog[1], cog[2]],
        inertia_kg_m2: inertia.map(|values| std::array::from_fn(|index| values[index])),
    })
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

/// The `n` in a flat joint field `qn` (`q1`, `q2`, …; no sign, no leading zero).
#[must_use]
pub fn joint_index(key: &str) -> Option<usize> {
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
pub(super) enum OrientationForm {
    /// `qx, qy, qz, qw`.
    Quaternion,
    /// `roll, pitch, yaw` (rad), `R = Rz(yaw) · Ry(pitch) · Rx(roll)`.
    RollPitchYaw,
    /// UR rotation vector `rx, ry, rz` (rad).
    RotationVector,
}

impl OrientationForm {
    pub(super) const ALL: [Self; 3] = [Self::Quaternion, Self::RollPitchYaw, Self::RotationVector];

    /// Where the form's fields are in [`POSE_KEYS`], in wire order.
    fn slots(self) -> std::ops::Range<usize> {
        match self {
            Self::Quaternion => 3..7,
            Self::RollPitchYaw => 7..10,
            Self::RotationVector => 10..13,
        }
    }

    /// The form's fields, in wire order.
    pub(super) fn keys(self) -> &'static [&'static str] {
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
pub(super) fn pose_of(
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
    /// `state`: the joint state beside the angles.
    State,
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
            (Schema::Joints { .. }, "state") => Self::State,
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
    /// `state`, read whole: it is rarer than the angles, and read again field by field.
    state: Option<Value>,
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
        let (state, state_error) = match self.state.as_ref().filter(|value| !value.is_null()) {
            None => (None, None),
            Some(value) => match joint_state(value, joint_count) {
                Ok(state) => (
                    Some(Box::new(state)).filter(|state| !state.is_empty()),
                    None,
                ),
                Err(error) => (None, Some(error)),
            },
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
                q_rad: JointAngles::from_vec(q_rad),
                measured,
                state,
            },
            measured_error,
            state_error,
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
            MessageKey::State => {
                if slots.state.is_some() {
                    trace.note_repeated(&Path {
                        parent: None,
                        segment: Segment::Key("state"),
                    });
                }
                slots.state = Some(map.next_value::<Value>()?);
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
