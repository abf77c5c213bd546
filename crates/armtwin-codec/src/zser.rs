//! armtwin's binary messages in Zenoh's own serialization (zenoh-ext `z_serialize`, Python
//! `zenoh.ext.z_serialize`): decoding the `armtwin/joints/v1` and `armtwin/pose/v1` inputs into
//! the samples the JSON decoder produces, and encoding the `armtwin/twin-pose/v1`,
//! `armtwin/deviation/v1` and `armtwin/paired/v1` outputs.
//!
//! The format: little-endian fixed-size numbers (IEEE-754 `f64`, `u64`), no padding; a sequence
//! is its LEB128 length then its items; a tuple is its fields one after the other. A message is
//! one tuple and nothing after it:
//! - `armtwin/joints/v1`: `(t: f64, q: seq<f64>, seq: u64, measured: seq<f64>)`, `measured`
//!   empty or `x, y, z, qx, qy, qz, qw` (m, base frame; quaternion within 5 % of unit norm);
//! - `armtwin/pose/v1`: `(t: f64, pose: seq<f64>)`, `pose` the same 7 values;
//! - `armtwin/twin-pose/v1`: `(t: f64, seq: u64, pose: seq<f64>)`, `pose` in
//!   [`PoseFields::NAMES`] order (`x, y, z, roll, pitch, yaw, qx, qy, qz, qw`);
//! - `armtwin/deviation/v1`: `(t: f64, d: seq<f64>)`, `d` in [`DEVIATION_NAMES`] order;
//! - `armtwin/paired/v1`: `(t: f64, seq: u64, pose: seq<f64>, d: seq<f64>)`: a twin pose's
//!   fields, then `d` empty or the deviation paired at its stamp.
//!
//! A hand-written reader rather than zenoh-ext's `z_deserialize`, for safety more than speed:
//! that one sizes its `Vec` by the untrusted length before reading an item (a 10-byte message
//! claiming 2^40 values asks for 8 TiB) and names no field in its error. Here every length is
//! compared with the schema and with the bytes left before anything is read, so a damaged
//! message is a [`WireError`] naming the field and nothing is allocated by a length. Speed is no
//! reason either way: with the allocation a joint sample needs for its angles, both read in the
//! same order of time (crates/armtwin-bench/README.md, `decode/joints_zser` against
//! `decode/joints_zenoh_ext`).
//! zenoh-ext is the oracle of this module's tests. Must not know the network or the filesystem.

use std::fmt;

use crate::PoseFields;
use crate::json::{self, DecodedJoints, MAX_PAYLOAD_BYTES, Undecodable, WireError};
use armtwin_core::metrics::Deviation;
use armtwin_core::sample::{
    ControllerStatus, JointAngles, JointQuantity, JointSample, JointState, MeasuredSample, Payload,
};

/// The schema of a joint message (`twin/joints/<robot>`).
pub const JOINTS_SCHEMA: &str = "armtwin/joints/v1";
/// The schema of a joint message with the joint state beside the angles
/// (`twin/joints/<robot>`): `armtwin/joints/v1`'s fields, then the state's.
pub const JOINTS_STATE_SCHEMA: &str = "armtwin/joints/v2";
/// The schema of a measured-pose message (`twin/measured/<robot>`).
pub const POSE_SCHEMA: &str = "armtwin/pose/v1";
/// The schema of the twin pose (`twin/pose/<robot>`).
pub const TWIN_POSE_SCHEMA: &str = "armtwin/twin-pose/v1";
/// The schema of a deviation (`twin/deviation/<robot>`).
pub const DEVIATION_SCHEMA: &str = "armtwin/deviation/v1";
/// The schema of a twin pose with the deviation paired at its stamp (`twin/paired/<robot>`).
pub const PAIRED_SCHEMA: &str = "armtwin/paired/v1";

/// The values of a measured pose: position (m), then the quaternion in wire order.
pub const MEASURED_NAMES: [&str; 7] = ["x", "y", "z", "qx", "qy", "qz", "qw"];

/// The values of `armtwin/deviation/v1`'s `d`, in order (the JSON deviation's field names).
pub const DEVIATION_NAMES: [&str; 9] = [
    "dx",
    "dy",
    "dz",
    "position",
    "quat_distance",
    "angle",
    "droll",
    "dpitch",
    "dyaw",
];

/// An input schema armtwin reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Schema {
    /// [`JOINTS_SCHEMA`].
    Joints,
    /// [`JOINTS_STATE_SCHEMA`].
    JointsState,
    /// [`POSE_SCHEMA`].
    Pose,
}

impl Schema {
    /// The schema's name, as in the sample's encoding (`zenoh/serialized;armtwin/joints/v1`).
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Joints => JOINTS_SCHEMA,
            Self::JointsState => JOINTS_STATE_SCHEMA,
            Self::Pose => POSE_SCHEMA,
        }
    }

    /// The schema named `name`, if armtwin reads it.
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            JOINTS_SCHEMA => Some(Self::Joints),
            JOINTS_STATE_SCHEMA => Some(Self::JointsState),
            POSE_SCHEMA => Some(Self::Pose),
            _ => None,
        }
    }
}

/// A field's name in error messages, formatted only when an error is built.
#[derive(Debug, Clone, Copy)]
enum Field {
    Plain(&'static str),
    /// Item `index` of a sequence.
    At(&'static str, usize),
    /// A sequence's length.
    Length(&'static str),
}

impl fmt::Display for Field {
    fn fmt(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Plain(name) => formatter.write_str(name),
            Self::At(name, index) => write!(formatter, "{name}[{index}]"),
            Self::Length(name) => write!(formatter, "{name}.length"),
        }
    }
}

/// A bounds-checked reader over a whole payload.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn new(payload: &'a [u8]) -> Result<Self, WireError> {
        if payload.len() > MAX_PAYLOAD_BYTES {
            return Err(WireError::TooLarge {
                bytes: payload.len(),
                limit: MAX_PAYLOAD_BYTES,
            });
        }
        Ok(Self {
            bytes: payload,
            at: 0,
        })
    }

    #[cold]
    fn truncated(&self, field: Field, needed: usize) -> WireError {
        WireError::Truncated {
            field: field.to_string(),
            needed,
            offset: self.at,
            bytes: self.bytes.len(),
        }
    }

    #[inline]
    fn array<const N: usize>(&mut self, field: Field) -> Result<[u8; N], WireError> {
        let Some(bytes) = self.bytes.get(self.at..self.at + N) else {
            return Err(self.truncated(field, N));
        };
        let mut array = [0; N];
        array.copy_from_slice(bytes);
        self.at += N;
        Ok(array)
    }

    #[inline]
    fn u64(&mut self, field: Field) -> Result<u64, WireError> {
        self.array(field).map(u64::from_le_bytes)
    }

    fn i32(&mut self, field: Field) -> Result<i32, WireError> {
        self.array(field).map(i32::from_le_bytes)
    }

    fn u32(&mut self, field: Field) -> Result<u32, WireError> {
        self.array(field).map(u32::from_le_bytes)
    }

    /// An `f64` whatever its value, for a part whose non-finite values refuse only the part.
    fn any_f64(&mut self, field: Field) -> Result<f64, WireError> {
        self.array(field).map(f64::from_le_bytes)
    }

    /// A finite `f64`.
    #[inline]
    fn f64(&mut self, field: Field) -> Result<f64, WireError> {
        let value = f64::from_le_bytes(self.array(field)?);
        if value.is_finite() {
            Ok(value)
        } else {
            Err(WireError::NonFinite {
                field: field.to_string(),
            })
        }
    }

    /// A sequence length: LEB128, at most 10 bytes and 64 bits.
    #[inline]
    fn length(&mut self, name: &'static str) -> Result<u64, WireError> {
        let start = self.at;
        let mut value = 0_u64;
        for shift in (0..64).step_by(7) {
            let Some(&byte) = self.bytes.get(self.at) else {
                return Err(self.truncated(Field::Length(name), 1));
            };
            self.at += 1;
            let bits = u64::from(byte & 0x7f);
            // The tenth byte holds bit 63 only.
            if shift == 63 && bits > 1 {
                break;
            }
            value |= bits << shift;
            if byte & 0x80 == 0 {
                return Ok(value);
            }
        }
        Err(WireError::MalformedLength {
            field: Field::Length(name).to_string(),
            offset: start,
        })
    }

    /// `count` finite `f64` items of sequence `name` into `values` (`count` already checked
    /// against the schema, so at most `values.len()`).
    #[inline]
    fn f64s(&mut self, name: &'static str, values: &mut [f64]) -> Result<(), WireError> {
        let needed = values.len() * 8;
        if self.bytes.len() - self.at < needed {
            // Name the first item that is cut.
            let complete = (self.bytes.len() - self.at) / 8;
            self.at += complete * 8;
            return Err(self.truncated(Field::At(name, complete), 8));
        }
        for (index, value) in values.iter_mut().enumerate() {
            *value = self.f64(Field::At(name, index))?;
        }
        Ok(())
    }

    /// Nothing may follow the last field.
    fn end(&self) -> Result<(), WireError> {
        match self.bytes.len() - self.at {
            0 => Ok(()),
            extra => Err(WireError::TrailingBytes {
                extra,
                end: self.at,
            }),
        }
    }
}

/// The stamp (`t`, the first field of every armtwin schema) of a binary message, if it has a
/// finite one.
#[must_use]
pub fn stamp_hint(payload: &[u8]) -> Option<f64> {
    let t = f64::from_le_bytes(payload.get(..8)?.try_into().ok()?);
    t.is_finite().then_some(t)
}

/// Decodes an `armtwin/joints/v1` message for an arm with `joint_count` joints.
///
/// As the JSON decoder, an invalid `measured` part (a length other than 0 or 7 with that many
/// values after it, a non-finite value, a quaternion norm off by more than 5 %) is reported in
/// [`DecodedJoints::measured_error`] and the joint sample stays valid; damage to the message's
/// framing (truncation, a malformed length, a length the bytes left do not match, trailing
/// bytes) refuses the whole message.
///
/// ```
/// use armtwin_codec::zser::read_joints;
/// let mut payload = 2.5_f64.to_le_bytes().to_vec();
/// payload.push(2); // q: 2 values
/// payload.extend([0.5_f64, -1.0].iter().flat_map(|q| q.to_le_bytes()));
/// payload.extend(7_u64.to_le_bytes()); // seq
/// payload.push(0); // measured: empty
/// let sample = read_joints(&payload, 2)?.sample;
/// assert_eq!((sample.stamp_s, sample.seq), (Some(2.5), Some(7)));
/// assert_eq!(sample.q_rad[..], [0.5, -1.0]);
/// let refused = read_joints(&payload[..12], 2).unwrap_err();
/// assert_eq!(refused.error.kind(), "truncated");
/// assert_eq!(refused.stamp_s, Some(2.5));
/// # Ok::<(), armtwin_codec::json::Undecodable>(())
/// ```
pub fn read_joints(payload: &[u8], joint_count: usize) -> Result<DecodedJoints, Undecodable> {
    read_joints_of(payload, joint_count, Schema::Joints)
}

/// Decodes an `armtwin/joints/v2` message: [`read_joints`]'s fields, then the joint state
/// (see [`JOINTS_STATE_SCHEMA`] in `docs/protocol/messages.md`). A state part that is well
/// framed but holds a non-finite value or a bad payload length is reported in
/// [`DecodedJoints::state_error`], and the joints stay valid; a per-joint sequence of another
/// length than the arm's joint count (or 0) refuses the whole message.
pub fn read_joints_with_state(
    payload: &[u8],
    joint_count: usize,
) -> Result<DecodedJoints, Undecodable> {
    read_joints_of(payload, joint_count, Schema::JointsState)
}

fn read_joints_of(
    payload: &[u8],
    joint_count: usize,
    schema: Schema,
) -> Result<DecodedJoints, Undecodable> {
    let with_state = schema == Schema::JointsState;
    let refused = |error| Undecodable {
        error,
        stamp_s: stamp_hint(payload),
    };
    let mut reader = Reader::new(payload).map_err(refused)?;
    let stamp_s = reader.f64(Field::Plain("t")).map_err(refused)?;
    let count = reader.length("q").map_err(refused)?;
    if count != joint_count as u64 {
        return Err(refused(WireError::JointCount {
            field: "q".to_owned(),
            expected: joint_count,
            got: usize::try_from(count).unwrap_or(usize::MAX),
        }));
    }
    let mut q_rad = JointAngles::from_elem(0.0, joint_count);
    reader.f64s("q", &mut q_rad).map_err(refused)?;
    let seq = reader.u64(Field::Plain("seq")).map_err(refused)?;
    let measured_count = reader.length("measured").map_err(refused)?;
    let (measured, measured_error) = match measured_count {
        0 => (None, None),
        7 => {
            let mut values = [0.0; 7];
            let start = reader.at;
            match reader.f64s("measured", &mut values) {
                Ok(()) => match pose_of("measured", values) {
                    Ok(pose) => (Some(pose), None),
                    Err(error) => (None, Some(error)),
                },
                Err(error @ WireError::NonFinite { .. }) => {
                    // All seven values are there (`f64s` checks the length first): skip past
                    // them, so the framing after them is still checked.
                    reader.at = start + 8 * values.len();
                    (None, Some(error))
                }
                Err(error) => return Err(refused(error)),
            }
        }
        got => {
            let error = WireError::SequenceLength {
                field: "measured".to_owned(),
                expected: "0 or 7",
                got,
            };
            // In v1 `measured` is the last field: when exactly its values follow, only the part
            // is bad; any other length (or any in v2) breaks the framing, and the whole message
            // is refused.
            let left = payload.len() - reader.at;
            if with_state || got.checked_mul(8) != Some(left as u64) {
                return Err(refused(error));
            }
            reader.at = payload.len();
            (None, Some(error))
        }
    };
    let (state, state_error) = if with_state {
        match read_state(&mut reader, joint_count).map_err(refused)? {
            Ok(state) => (
                Some(Box::new(state)).filter(|state| !state.is_empty()),
                None,
            ),
            Err(error) => (None, Some(error)),
        }
    } else {
        (None, None)
    };
    reader.end().map_err(refused)?;
    Ok(DecodedJoints {
        sample: JointSample {
            stamp_s: Some(stamp_s),
            seq: Some(seq),
            q_rad,
            measured,
            state,
        },
        measured_error,
        state_error,
    })
}

/// The joint state of an `armtwin/joints/v2` message, after `measured`: the outer error breaks
/// the framing (the whole message is refused), the inner one only the state.
fn read_state(
    reader: &mut Reader<'_>,
    joint_count: usize,
) -> Result<Result<JointState, WireError>, WireError> {
    let mut state = JointState::new(joint_count);
    let mut part_error = None;
    let mut values = vec![0.0; joint_count];
    for quantity in JointQuantity::ALL {
        let name = quantity.name();
        match reader.length(name)? {
            0 => {}
            count if count == joint_count as u64 => {
                for (index, value) in values.iter_mut().enumerate() {
                    *value = reader.any_f64(Field::At(name, index))?;
                }
                match values.iter().position(|value| !value.is_finite()) {
                    None => {
                        state.set(quantity, &values);
                    }
                    Some(index) => {
                        part_error.get_or_insert(WireError::NonFinite {
                            field: Field::At(name, index).to_string(),
                        });
                    }
                }
            }
            got => {
                return Err(WireError::SequenceLength {
                    field: name.to_owned(),
                    expected: "0 or the joint count",
                    got,
                });
            }
        }
    }
    match reader.length("status")? {
        0 => {}
        1 => {
            let status = ControllerStatus {
                robot_mode: reader.i32(Field::Plain("status.robot_mode"))?,
                safety_mode: reader.i32(Field::Plain("status.safety_mode"))?,
                status_bits: reader.u32(Field::Plain("status.status_bits"))?,
                speed_scaling: reader.any_f64(Field::Plain("status.speed_scaling"))?,
            };
            if status.speed_scaling.is_finite() {
                state.status = Some(status);
            } else {
                part_error.get_or_insert(WireError::NonFinite {
                    field: "status.speed_scaling".to_owned(),
                });
            }
        }
        got => {
            return Err(WireError::SequenceLength {
                field: "status".to_owned(),
                expected: "0 or 1",
                got,
            });
        }
    }
    let payload_count = reader.length("payload")?;
    let mut payload = [0.0; 10];
    match payload_count {
        0 => {}
        4 | 10 => {
            let values = &mut payload[..payload_count as usize];
            for (index, value) in values.iter_mut().enumerate() {
                *value = reader.any_f64(Field::At("payload", index))?;
            }
            match payload_of(values) {
                Ok(payload) => state.payload = Some(payload),
                Err(error) => {
                    part_error.get_or_insert(error);
                }
            }
        }
        got => {
            return Err(WireError::SequenceLength {
                field: "payload".to_owned(),
                expected: "0, 4 or 10",
                got,
            });
        }
    }
    Ok(match part_error {
        None => Ok(state),
        Some(error) => Err(error),
    })
}

/// A payload of `mass, cx, cy, cz` and optionally `Ixx, Iyy, Izz, Ixy, Ixz, Iyz`: finite, the mass
/// not negative.
fn payload_of(values: &[f64]) -> Result<Payload, WireError> {
    if let Some(index) = values.iter().position(|value| !value.is_finite()) {
        return Err(WireError::NonFinite {
            field: Field::At("payload", index).to_string(),
        });
    }
    if values[0] < 0.0 {
        return Err(WireError::JointState {
            field: "payload[0]".to_owned(),
            detail: format!("a mass of {} kg: a mass is not negative", values[0]),
        });
    }
    Ok(Payload {
        mass_kg: values[0],
        cog_m: [values[1], values[2], values[3]],
        inertia_kg_m2: values
            .get(4..10)
            .map(|inertia| std::array::from_fn(|index| inertia[index])),
    })
}

/// Decodes an `armtwin/pose/v1` message: position (m) and quaternion, normalised (within 5 % of
/// unit norm) and canonicalised to `qw ≥ 0`.
pub fn read_measured(payload: &[u8]) -> Result<MeasuredSample, Undecodable> {
    let refused = |error| Undecodable {
        error,
        stamp_s: stamp_hint(payload),
    };
    let mut reader = Reader::new(payload).map_err(refused)?;
    let stamp_s = reader.f64(Field::Plain("t")).map_err(refused)?;
    let count = reader.length("pose").map_err(refused)?;
    if count != 7 {
        return Err(refused(WireError::SequenceLength {
            field: "pose".to_owned(),
            expected: "7",
            got: count,
        }));
    }
    let mut values = [0.0; 7];
    reader.f64s("pose", &mut values).map_err(refused)?;
    reader.end().map_err(refused)?;
    let pose = pose_of("pose", values).map_err(refused)?;
    Ok(MeasuredSample {
        stamp_s: Some(stamp_s),
        pose,
    })
}

/// The pose of `x, y, z, qx, qy, qz, qw` (sequence `name`), with the JSON decoder's quaternion
/// checks.
fn pose_of(
    name: &str,
    values: [f64; 7],
) -> Result<armtwin_core::kinematics::PoseReadout, WireError> {
    let [x, y, z, qx, qy, qz, qw] = values;
    json::pose_from_quaternion([x, y, z], [qx, qy, qz, qw]).map_err(|error| match error {
        WireError::QuaternionNorm { norm, .. } => WireError::QuaternionNorm {
            fields: format!("{name}[3..7]"),
            norm,
        },
        other => other,
    })
}

/// Bytes of an `armtwin/joints/v1` message, as a gateway sends it: `t` (s), the joint angles
/// (rad), the gateway's `seq`, and the measured pose read in the same packet (`x, y, z` in m and
/// the quaternion `qx, qy, qz, qw`, [`MEASURED_NAMES`] order) or nothing. At most 127 joints.
///
/// ```
/// use armtwin_codec::zser::{joints_bytes, read_joints};
/// let pose = [0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 1.0];
/// let bytes = joints_bytes(2.5, &[0.5, -1.0], 7, Some(&pose));
/// let decoded = read_joints(&bytes, 2)?;
/// assert_eq!((decoded.sample.stamp_s, decoded.sample.seq), (Some(2.5), Some(7)));
/// assert_eq!(decoded.sample.measured.map(|pose| pose.position_m), Some([0.1, 0.2, 0.3]));
/// # Ok::<(), armtwin_codec::json::Undecodable>(())
/// ```
#[must_use]
pub fn joints_bytes(stamp_s: f64, q_rad: &[f64], seq: u64, measured: Option<&[f64; 7]>) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(8 + 1 + 8 * q_rad.len() + 8 + 1 + 8 * 7);
    bytes.extend_from_slice(&stamp_s.to_le_bytes());
    push_f64s(&mut bytes, q_rad);
    bytes.extend_from_slice(&seq.to_le_bytes());
    push_f64s(&mut bytes, measured.map_or(&[], |pose| &pose[..]));
    bytes
}

/// Bytes of an `armtwin/joints/v2` message: [`joints_bytes`]'s fields, then `state`'s (each
/// per-joint quantity in [`JointQuantity::ALL`] order, empty when absent; the status; the
/// payload). At most 127 joints.
///
/// ```
/// use armtwin_codec::zser::{joints_state_bytes, read_joints_with_state};
/// use armtwin_core::sample::{JointQuantity, JointState};
/// let mut state = JointState::new(2);
/// state.set(JointQuantity::Temperature, &[31.5, 32.0]);
/// let bytes = joints_state_bytes(2.5, &[0.5, -1.0], 7, None, &state);
/// let decoded = read_joints_with_state(&bytes, 2)?;
/// assert_eq!(decoded.sample.state.as_deref(), Some(&state));
/// # Ok::<(), armtwin_codec::json::Undecodable>(())
/// ```
#[must_use]
pub fn joints_state_bytes(
    stamp_s: f64,
    q_rad: &[f64],
    seq: u64,
    measured: Option<&[f64; 7]>,
    state: &JointState,
) -> Vec<u8> {
    let mut bytes = joints_bytes(stamp_s, q_rad, seq, measured);
    for quantity in JointQuantity::ALL {
        push_f64s(&mut bytes, state.get(quantity).unwrap_or(&[]));
    }
    match &state.status {
        None => bytes.push(0),
        Some(status) => {
            bytes.push(1);
            bytes.extend_from_slice(&status.robot_mode.to_le_bytes());
            bytes.extend_from_slice(&status.safety_mode.to_le_bytes());
            bytes.extend_from_slice(&status.status_bits.to_le_bytes());
            bytes.extend_from_slice(&status.speed_scaling.to_le_bytes());
        }
    }
    match &state.payload {
        None => bytes.push(0),
        Some(payload) => {
            let mut values = [0.0; 10];
            values[0] = payload.mass_kg;
            values[1..4].copy_from_slice(&payload.cog_m);
            let count = match payload.inertia_kg_m2 {
                Some(inertia) => {
                    values[4..].copy_from_slice(&inertia);
                    10
                }
                None => 4,
            };
            push_f64s(&mut bytes, &values[..count]);
        }
    }
    bytes
}

/// Bytes of an `armtwin/twin-pose/v1` message: `t` (s), the twin's pose `seq`, then the pose's
/// 10 values in [`PoseFields::NAMES`] order (97 bytes).
///
/// ```
/// use armtwin_codec::{PoseFields, zser};
/// let pose = PoseFields { x: 1.0, y: 2.0, z: 3.0, roll: 0.0, pitch: 0.0, yaw: 0.0,
///                         qx: 0.0, qy: 0.0, qz: 0.0, qw: 1.0 };
/// let bytes = zser::twin_pose_bytes(0.5, 3, &pose);
/// assert_eq!(bytes.len(), 97);
/// assert_eq!(&bytes[..17], &[0, 0, 0, 0, 0, 0, 0xe0, 0x3f, 3, 0, 0, 0, 0, 0, 0, 0, 10]);
/// ```
#[must_use]
pub fn twin_pose_bytes(stamp_s: f64, seq: u64, pose: &PoseFields) -> [u8; TWIN_POSE_BYTES] {
    let mut bytes = [0; TWIN_POSE_BYTES];
    bytes[..8].copy_from_slice(&stamp_s.to_le_bytes());
    bytes[8..16].copy_from_slice(&seq.to_le_bytes());
    write_f64s(&mut bytes[16..], &pose.values());
    bytes
}

/// Length of an `armtwin/twin-pose/v1` message.
pub const TWIN_POSE_BYTES: usize = 8 + 8 + 1 + 8 * PoseFields::NAMES.len();

/// Length of an `armtwin/deviation/v1` message.
pub const DEVIATION_BYTES: usize = 8 + 1 + 8 * DEVIATION_NAMES.len();

/// Bytes of an `armtwin/deviation/v1` message: `t` (s), then the 9 values in
/// [`DEVIATION_NAMES`] order (81 bytes).
#[must_use]
pub fn deviation_bytes(stamp_s: f64, deviation: &Deviation) -> [u8; DEVIATION_BYTES] {
    let values = deviation.fields();
    let mut bytes = [0; DEVIATION_BYTES];
    bytes[..8].copy_from_slice(&stamp_s.to_le_bytes());
    write_f64s(&mut bytes[8..], &values);
    bytes
}

/// Length of an `armtwin/paired/v1` message with its deviation.
pub const PAIRED_BYTES: usize = TWIN_POSE_BYTES + 1 + 8 * DEVIATION_NAMES.len();

/// Length of an `armtwin/paired/v1` message without a deviation.
pub const PAIRED_POSE_BYTES: usize = TWIN_POSE_BYTES + 1;

/// Bytes of an `armtwin/paired/v1` message: the [`twin_pose_bytes`] of `stamp_s`, `seq` and
/// `pose`, then the 9 values of the deviation paired at `stamp_s` in [`DEVIATION_NAMES`] order
/// (170 bytes).
#[must_use]
pub fn paired_bytes(
    stamp_s: f64,
    seq: u64,
    pose: &PoseFields,
    deviation: &Deviation,
) -> [u8; PAIRED_BYTES] {
    let mut bytes = [0; PAIRED_BYTES];
    bytes[..TWIN_POSE_BYTES].copy_from_slice(&twin_pose_bytes(stamp_s, seq, pose));
    write_f64s(&mut bytes[TWIN_POSE_BYTES..], &deviation.fields());
    bytes
}

/// Bytes of an `armtwin/paired/v1` message of a twin pose that has no deviation: the
/// [`twin_pose_bytes`] of `stamp_s`, `seq` and `pose`, then an empty `d` (98 bytes).
///
/// ```
/// use armtwin_codec::{PoseFields, zser};
/// let pose = PoseFields { x: 1.0, y: 2.0, z: 3.0, roll: 0.0, pitch: 0.0, yaw: 0.0,
///                         qx: 0.0, qy: 0.0, qz: 0.0, qw: 1.0 };
/// let bytes = zser::paired_pose_bytes(0.5, 3, &pose);
/// assert_eq!(&bytes[..97], &zser::twin_pose_bytes(0.5, 3, &pose));
/// assert_eq!(bytes[97], 0);
/// ```
#[must_use]
pub fn paired_pose_bytes(stamp_s: f64, seq: u64, pose: &PoseFields) -> [u8; PAIRED_POSE_BYTES] {
    let mut bytes = [0; PAIRED_POSE_BYTES];
    bytes[..TWIN_POSE_BYTES].copy_from_slice(&twin_pose_bytes(stamp_s, seq, pose));
    bytes
}

/// [`push_f64s`] into `bytes`, which holds exactly the length byte and the values. The fixed-size
/// outputs are arrays because Zenoh wraps whatever it is given in an `Arc`: an array is that one
/// allocation, a `Vec` two.
fn write_f64s(bytes: &mut [u8], values: &[f64]) {
    debug_assert!(values.len() < 0x80, "a one-byte LEB128 length");
    debug_assert_eq!(bytes.len(), 1 + 8 * values.len());
    bytes[0] = values.len() as u8;
    for (chunk, value) in bytes[1..].chunks_exact_mut(8).zip(values) {
        chunk.copy_from_slice(&value.to_le_bytes());
    }
}

/// A sequence of fewer than 128 `f64`: a one-byte LEB128 length, then the values.
fn push_f64s(bytes: &mut Vec<u8>, values: &[f64]) {
    let start = bytes.len();
    bytes.resize(start + 1 + 8 * values.len(), 0);
    write_f64s(&mut bytes[start..], values);
}
