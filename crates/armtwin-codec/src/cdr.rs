//! ROS 2 messages in CDR (XCDR1, the encoding of rmw, rosbag2 and the DDS bridge): decoding
//! `sensor_msgs/msg/JointState` and `geometry_msgs/msg/PoseStamped` into the samples the JSON
//! decoder produces, and encoding the twin pose as a `PoseStamped`.
//!
//! A payload is the 4-byte encapsulation header (`00 01` little-endian, `00 00` big-endian, two
//! option bytes ignored) and the body; alignment is counted from the body's first byte. Every
//! length and count is checked against the bytes left and against a limit before it is used, so
//! a damaged message is a [`CdrError`] naming the field, never an allocation of the size it
//! claims. Must not know the network or the filesystem.
//!
//! Joints are matched **by name**: the UR driver does not publish them in the model's order.
//! Names the arm does not have (a gripper's) are skipped; a missing one is an error naming it.

use std::fmt;

use thiserror::Error;

use crate::decoded::{CodecError, Decoder, Refused};
use crate::json::{self, MAX_PAYLOAD_BYTES, WireError};
use armtwin_core::kinematics::{OutputFrame, PoseReadout};
use armtwin_core::model::catalog::UR_JOINT_NAMES;
use armtwin_core::pipeline::{RejectCause, Robot};
use armtwin_core::sample::{JointAngles, JointQuantity, JointSample, JointState, MeasuredSample};

/// Most names (and values per array) a `JointState` may carry; more is a damaged message.
pub const MAX_JOINT_STATE_ENTRIES: usize = 256;

/// Longest accepted string (bytes with the terminating NUL): a joint name or a frame id.
pub const MAX_STRING_BYTES: usize = 256;

/// Most joints an arm may have for name matching (the positions are kept on the stack).
pub const MAX_ARM_JOINTS: usize = 32;

/// Why a CDR message was rejected.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CdrError {
    /// The payload exceeds [`MAX_PAYLOAD_BYTES`].
    #[error("payload of {bytes} bytes exceeds the limit of {limit} bytes")]
    TooLarge {
        /// Payload size.
        bytes: usize,
        /// The limit.
        limit: usize,
    },
    /// The payload is shorter than the encapsulation header.
    #[error("payload of {bytes} bytes has no 4-byte CDR encapsulation header")]
    NoHeader {
        /// Payload size.
        bytes: usize,
    },
    /// The encapsulation is not plain XCDR1 (parameter lists and XCDR2 are not read).
    #[error("encapsulation {id:#06x} is not plain CDR (0x0000 big-endian or 0x0001 little-endian)")]
    Representation {
        /// The representation identifier (header bytes 0–1, big-endian).
        id: u16,
    },
    /// A field runs past the end of the payload.
    #[error("'{field}': needs {needed} bytes at body offset {offset}, the body has {body}")]
    Truncated {
        /// The field (`JointState.position[3]`).
        field: String,
        /// Bytes the field needs.
        needed: usize,
        /// Where it starts in the body.
        offset: usize,
        /// Body size.
        body: usize,
    },
    /// A string length or sequence count beyond any sane message.
    #[error("'{field}': count {count} exceeds the limit of {limit}")]
    Count {
        /// The field.
        field: String,
        /// The count in the message.
        count: u64,
        /// The limit.
        limit: usize,
    },
    /// A string without its terminating NUL.
    #[error("'{field}': string is not NUL-terminated")]
    Unterminated {
        /// The field.
        field: String,
    },
    /// A string that is not UTF-8.
    #[error("'{field}': not UTF-8")]
    NotUtf8 {
        /// The field.
        field: String,
    },
    /// `header.stamp.nanosec` of a second or more.
    #[error("'{field}': nanosec {nanosec} is not below 1e9")]
    Nanosec {
        /// The field.
        field: String,
        /// The value sent.
        nanosec: u32,
    },
    /// `position` does not hold one value per name.
    #[error("'{field}': {got} values for {expected} names")]
    LengthMismatch {
        /// The field.
        field: String,
        /// Names in the message.
        expected: usize,
        /// Values in the field.
        got: usize,
    },
    /// One of the arm's joints is not among the message's names.
    #[error("missing joint '{joint}'")]
    MissingJoint {
        /// The joint's full name (with its `tf_prefix`).
        joint: String,
    },
    /// One of the arm's joints appears twice among the names.
    #[error("joint '{joint}' appears more than once ('{field}')")]
    DuplicateJoint {
        /// The joint's full name.
        joint: String,
        /// Where it appears again (`JointState.name[4]`).
        field: String,
    },
    /// A value the twin uses is NaN or infinite.
    #[error("'{field}': not a finite number")]
    NonFinite {
        /// The field.
        field: String,
    },
    /// The orientation's norm is zero, not finite, or more than 5 % away from 1.
    #[error("'{field}': quaternion norm {norm} is not within 5 % of 1")]
    QuaternionNorm {
        /// The field.
        field: String,
        /// Its norm.
        norm: f64,
    },
    /// A `PoseStamped` in another frame than the one the robot's poses are read in.
    #[error("'PoseStamped.header.frame_id' is '{frame_id}', expected '{expected}'")]
    FrameId {
        /// The frame sent.
        frame_id: String,
        /// The frame expected (`<tf_prefix>base`).
        expected: String,
    },
}

impl CdrError {
    /// A stable `snake_case` name of the error class, for event messages and counters (the
    /// classes both decoders share have [`WireError::kind`]'s names).
    #[must_use]
    pub fn kind(&self) -> &'static str {
        match self {
            Self::TooLarge { .. } => "too_large",
            Self::NoHeader { .. } => "no_header",
            Self::Representation { .. } => "representation",
            Self::Truncated { .. } => "truncated",
            Self::Count { .. } => "count",
            Self::Unterminated { .. } => "unterminated",
            Self::NotUtf8 { .. } => "not_utf8",
            Self::Nanosec { .. } => "nanosec",
            Self::LengthMismatch { .. } => "length_mismatch",
            Self::MissingJoint { .. } => "missing_joint",
            Self::DuplicateJoint { .. } => "duplicate_joint",
            Self::NonFinite { .. } => "non_finite",
            Self::QuaternionNorm { .. } => "quaternion_norm",
            Self::FrameId { .. } => "frame_id",
        }
    }

    /// The rejection cause of a message refused for this error: the JSON decoder's where both
    /// decoders share the class, else a CDR one (`cdr_header`, `cdr_truncated`, `cdr_malformed`,
    /// `missing_joint`, `duplicate_joint`, `frame_id`).
    #[must_use]
    pub fn cause(&self) -> RejectCause {
        match self {
            Self::TooLarge { .. } => RejectCause::Decode("too_large"),
            Self::NoHeader { .. } | Self::Representation { .. } => {
                RejectCause::Decode("cdr_header")
            }
            Self::Truncated { .. } => RejectCause::Decode("cdr_truncated"),
            Self::Count { .. }
            | Self::Unterminated { .. }
            | Self::Nanosec { .. }
            | Self::LengthMismatch { .. } => RejectCause::Decode("cdr_malformed"),
            Self::NotUtf8 { .. } => RejectCause::Decode("not_utf8"),
            Self::MissingJoint { .. } => RejectCause::Decode("missing_joint"),
            Self::DuplicateJoint { .. } => RejectCause::Decode("duplicate_joint"),
            Self::NonFinite { .. } => RejectCause::NonFinite,
            Self::QuaternionNorm { .. } => RejectCause::Decode("quaternion_norm"),
            Self::FrameId { .. } => RejectCause::Decode("frame_id"),
        }
    }
}

impl CodecError for CdrError {
    fn reject_cause(&self) -> RejectCause {
        CdrError::cause(self)
    }
}

/// A field's name in error messages, formatted only when an error is built.
#[derive(Debug, Clone, Copy)]
struct Field {
    name: &'static str,
    index: Option<usize>,
}

impl Field {
    const fn plain(name: &'static str) -> Self {
        Self { name, index: None }
    }

    const fn at(name: &'static str, index: usize) -> Self {
        Self {
            name,
            index: Some(index),
        }
    }
}

impl fmt::Display for Field {
    fn fmt(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.index {
            Some(index) => write!(formatter, "{}[{index}]", self.name),
            None => formatter.write_str(self.name),
        }
    }
}

/// A bounds-checked reader over a CDR body.
struct Reader<'a> {
    body: &'a [u8],
    at: usize,
    big_endian: bool,
}

impl<'a> Reader<'a> {
    /// The reader of a whole payload, its header checked.
    fn new(payload: &'a [u8]) -> Result<Self, CdrError> {
        Self::with_limit(payload, MAX_PAYLOAD_BYTES)
    }

    /// The same, for a payload of at most `limit` bytes.
    fn with_limit(payload: &'a [u8], limit: usize) -> Result<Self, CdrError> {
        if payload.len() > limit {
            return Err(CdrError::TooLarge {
                bytes: payload.len(),
                limit,
            });
        }
        let [a, b, _, _, body @ ..] = payload else {
            return Err(CdrError::NoHeader {
                bytes: payload.len(),
            });
        };
        let big_endian = match u16::from_be_bytes([*a, *b]) {
            0x0000 => true,
            0x0001 => false,
            id => return Err(CdrError::Representation { id }),
        };
        Ok(Self {
            body,
            at: 0,
            big_endian,
        })
    }

    #[cold]
    fn truncated(&self, field: Field, needed: usize, offset: usize) -> CdrError {
        CdrError::Truncated {
            field: field.to_string(),
            needed,
            offset,
            body: self.body.len(),
        }
    }

    /// `n` bytes at the next multiple of `align` (nothing, not even padding, for `n = 0`: an
    /// empty sequence has no element to align).
    #[inline]
    fn take(&mut self, n: usize, align: usize, field: Field) -> Result<&'a [u8], CdrError> {
        if n == 0 {
            return Ok(&[]);
        }
        let start = self.at.next_multiple_of(align);
        let bytes = start
            .checked_add(n)
            .and_then(|end| self.body.get(start..end))
            .ok_or_else(|| self.truncated(field, n, start))?;
        self.at = start + n;
        Ok(bytes)
    }

    #[inline]
    fn array<const N: usize>(&mut self, field: Field) -> Result<[u8; N], CdrError> {
        let bytes = self.take(N, N, field)?;
        let mut array = [0; N];
        array.copy_from_slice(bytes);
        if self.big_endian {
            array.reverse();
        }
        // Little-endian order from here on.
        Ok(array)
    }

    #[inline]
    fn u32(&mut self, field: Field) -> Result<u32, CdrError> {
        self.array(field).map(u32::from_le_bytes)
    }

    #[inline]
    fn i32(&mut self, field: Field) -> Result<i32, CdrError> {
        self.array(field).map(i32::from_le_bytes)
    }

    #[inline]
    fn f64(&mut self, field: Field) -> Result<f64, CdrError> {
        self.array(field).map(f64::from_le_bytes)
    }

    /// A finite `f64`.
    fn finite(&mut self, field: Field) -> Result<f64, CdrError> {
        let value = self.f64(field)?;
        if value.is_finite() {
            Ok(value)
        } else {
            Err(CdrError::NonFinite {
                field: field.to_string(),
            })
        }
    }

    /// A sequence count, at most `limit`, whose `element_bytes`-sized elements fit in the body.
    #[inline]
    fn count(
        &mut self,
        field: Field,
        element_bytes: usize,
        limit: usize,
    ) -> Result<usize, CdrError> {
        let count = self.u32(field)? as usize;
        if count > limit {
            return Err(CdrError::Count {
                field: field.to_string(),
                count: count as u64,
                limit,
            });
        }
        // An empty sequence has no element to align: the message may end at its count.
        if count == 0 {
            return Ok(0);
        }
        let start = self.at.next_multiple_of(element_bytes.max(1));
        let needed = count * element_bytes;
        if start.saturating_add(needed) > self.body.len() {
            return Err(self.truncated(field, needed, start));
        }
        Ok(count)
    }

    /// A string's bytes: u32 length including the NUL, the bytes, the NUL (a length of 0, which
    /// some writers use for the empty string, reads as empty). Not checked for UTF-8: joint
    /// names are only compared with the arm's.
    #[inline]
    fn string_bytes(&mut self, field: Field) -> Result<&'a [u8], CdrError> {
        self.string_bytes_up_to(field, MAX_STRING_BYTES)
    }

    /// [`Self::string_bytes`] of a string of at most `limit` bytes (its NUL included).
    fn string_bytes_up_to(&mut self, field: Field, limit: usize) -> Result<&'a [u8], CdrError> {
        let length = self.count(field, 1, limit)?;
        let bytes = self.take(length, 1, field)?;
        match bytes.split_last() {
            None => Ok(&[]),
            Some((0, text)) => Ok(text),
            Some(_) => Err(CdrError::Unterminated {
                field: field.to_string(),
            }),
        }
    }

    /// A UTF-8 string.
    fn string(&mut self, field: Field) -> Result<&'a str, CdrError> {
        std::str::from_utf8(self.string_bytes(field)?).map_err(|_| CdrError::NotUtf8 {
            field: field.to_string(),
        })
    }

    /// `std_msgs/Header`: the stamp (s; `None` for the unset stamp 0.0); the frame id follows.
    fn stamp(&mut self, sec: Field, nanosec: Field) -> Result<Option<f64>, CdrError> {
        let seconds = self.i32(sec)?;
        let nanoseconds = self.u32(nanosec)?;
        if nanoseconds >= 1_000_000_000 {
            return Err(CdrError::Nanosec {
                field: nanosec.to_string(),
                nanosec: nanoseconds,
            });
        }
        // The same sum a ROS 2 export's `header.stamp.sec` and `.nanosec` columns give.
        Ok((seconds != 0 || nanoseconds != 0)
            .then(|| f64::from(seconds) + f64::from(nanoseconds) * 1e-9))
    }
}

/// The joint names an arm's `JointState` messages carry, in the arm's joint order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct JointNames {
    names: Vec<String>,
}

impl JointNames {
    /// A UR arm's names with `tf_prefix` (`""`, or e.g. `alice_`): `<prefix>shoulder_pan_joint`,
    /// …, `<prefix>wrist_3_joint`, as the Universal Robots driver publishes them.
    #[must_use]
    pub fn ur(tf_prefix: &str) -> Self {
        Self {
            names: UR_JOINT_NAMES
                .iter()
                .map(|joint| format!("{tf_prefix}{joint}_joint"))
                .collect(),
        }
    }

    /// Names given one by one, base to flange; `None` for no names or more than an arm has.
    #[must_use]
    pub fn new(names: Vec<String>) -> Option<Self> {
        (!names.is_empty() && names.len() <= MAX_ARM_JOINTS).then_some(Self { names })
    }

    /// The names, base to flange.
    #[must_use]
    pub fn as_slice(&self) -> &[String] {
        &self.names
    }
}

const NAME: &str = "JointState.name";
const POSITION: &str = "JointState.position";

/// What a `JointState`'s `effort` holds. The message defines it as the joint's effort (N·m),
/// but the Universal Robots driver has published motor currents (A) there, and newer releases
/// publish torques on controllers that report them: only the source's configuration can say.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
pub enum EffortMeaning {
    /// Motor currents (A).
    #[serde(rename = "current_a")]
    CurrentA,
    /// Joint torques (N·m).
    #[serde(rename = "torque_nm")]
    TorqueNm,
}

impl EffortMeaning {
    /// The joint state quantity the values become.
    #[must_use]
    pub fn quantity(self) -> JointQuantity {
        match self {
            Self::CurrentA => JointQuantity::Current,
            Self::TorqueNm => JointQuantity::Torque,
        }
    }

    /// The configuration's name.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::CurrentA => "current_a",
            Self::TorqueNm => "torque_nm",
        }
    }
}

/// Decodes a `sensor_msgs/msg/JointState` into a joint sample of the arm named by `joints`.
///
/// Angles (rad) come in the arm's joint order whatever the message's order; names the arm does
/// not have are skipped; velocity, and effort when `effort` says what it holds, become the
/// sample's joint state when they hold one finite value per name, else are skipped.
/// `stamp_s` is `header.stamp` (sec + nanosec · 1e-9), `None` when the stamp is unset (0).
///
/// Only the message's own bytes are read: alignment padding may hold anything (rclpy's
/// serializer leaves it uninitialised) and bytes after the last field are ignored.
pub fn decode_joint_state(
    payload: &[u8],
    joints: &JointNames,
    effort: Option<EffortMeaning>,
) -> Result<JointSample, CdrError> {
    let mut reader = Reader::new(payload)?;
    let stamp_s = reader.stamp(
        Field::plain("JointState.header.stamp.sec"),
        Field::plain("JointState.header.stamp.nanosec"),
    )?;
    reader.string_bytes(Field::plain("JointState.header.frame_id"))?;
    let wanted = joints.as_slice();
    // Message index of each of the arm's joints.
    let mut index_of = [usize::MAX; MAX_ARM_JOINTS];
    // A string takes at least its 4-byte length.
    let name_count = reader.count(Field::plain(NAME), 4, MAX_JOINT_STATE_ENTRIES)?;
    // The joint after the last one matched is tried first: a driver's order, whether the arm's
    // or rotated (the UR driver's), then costs one comparison per name.
    let mut next = 0;
    for index in 0..name_count {
        let field = Field::at(NAME, index);
        let name = reader.string_bytes(field)?;
        let joint = if wanted[next].as_bytes() == name {
            Some(next)
        } else {
            wanted.iter().position(|wanted| wanted.as_bytes() == name)
        };
        if let Some(joint) = joint {
            if index_of[joint] != usize::MAX {
                return Err(CdrError::DuplicateJoint {
                    joint: wanted[joint].clone(),
                    field: field.to_string(),
                });
            }
            index_of[joint] = index;
            next = (joint + 1) % wanted.len();
        }
    }
    if let Some(joint) = index_of[..wanted.len()]
        .iter()
        .position(|&index| index == usize::MAX)
    {
        return Err(CdrError::MissingJoint {
            joint: wanted[joint].clone(),
        });
    }
    let position_count = reader.count(Field::plain(POSITION), 8, MAX_JOINT_STATE_ENTRIES)?;
    if position_count != name_count {
        return Err(CdrError::LengthMismatch {
            field: POSITION.to_owned(),
            expected: name_count,
            got: position_count,
        });
    }
    // `count` checked that the values fit: take them all, then pick the arm's.
    let positions = reader.take(8 * position_count, 8, Field::plain(POSITION))?;
    let big_endian = reader.big_endian;
    let mut q_rad = JointAngles::with_capacity(wanted.len());
    for &index in &index_of[..wanted.len()] {
        let mut bytes = [0; 8];
        bytes.copy_from_slice(&positions[8 * index..8 * index + 8]);
        let value = if big_endian {
            f64::from_be_bytes(bytes)
        } else {
            f64::from_le_bytes(bytes)
        };
        if !value.is_finite() {
            return Err(CdrError::NonFinite {
                field: Field::at(POSITION, index).to_string(),
            });
        }
        q_rad.push(value);
    }
    let mut state: Option<Box<JointState>> = None;
    for (name, quantity) in [
        ("JointState.velocity", Some(JointQuantity::Velocity)),
        ("JointState.effort", effort.map(EffortMeaning::quantity)),
    ] {
        let count = reader.count(Field::plain(name), 8, MAX_JOINT_STATE_ENTRIES)?;
        let values = reader.take(8 * count, 8, Field::plain(name))?;
        // Empty (the driver has none) or of another length than the names (not per joint) is
        // not carried; nor is one with a value that is not finite (drivers send NaN for unknown),
        // nor an effort whose meaning the source does not say.
        let Some(quantity) = quantity.filter(|_| count == name_count) else {
            continue;
        };
        let mut picked = [0.0; MAX_ARM_JOINTS];
        let mut finite = true;
        for (slot, &index) in picked.iter_mut().zip(&index_of[..wanted.len()]) {
            let mut bytes = [0; 8];
            bytes.copy_from_slice(&values[8 * index..8 * index + 8]);
            *slot = if big_endian {
                f64::from_be_bytes(bytes)
            } else {
                f64::from_le_bytes(bytes)
            };
            finite &= slot.is_finite();
        }
        if finite {
            state
                .get_or_insert_with(|| Box::new(JointState::new(wanted.len())))
                .set(quantity, &picked[..wanted.len()]);
        }
    }
    Ok(JointSample {
        stamp_s,
        seq: None,
        q_rad,
        measured: None,
        state,
    })
}

/// A decoded `PoseStamped`: the measured sample and the frame it is expressed in.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedPose<'a> {
    /// Stamp and pose (quaternion normalised and canonicalised as the JSON decoder does).
    pub sample: MeasuredSample,
    /// `header.frame_id` (the UR driver's `/tcp_pose_broadcaster/pose`: `<tf_prefix>base`).
    pub frame_id: &'a str,
    /// The orientation `[x, y, z, w]` as sent, before normalisation (to hand the pose on to
    /// the JSON decoder, which normalises it itself).
    pub xyzw_as_sent: [f64; 4],
}

/// Decodes a `std_msgs/msg/String` whose text is at most `limit` bytes (a robot's
/// `/robot_description`, a URDF): the text, checked UTF-8.
pub fn decode_string(payload: &[u8], limit: usize) -> Result<&str, CdrError> {
    // The header and the length before the text, its NUL after.
    let mut reader = Reader::with_limit(payload, limit.saturating_add(9))?;
    let field = Field::plain("String.data");
    let bytes = reader.string_bytes_up_to(field, limit.saturating_add(1))?;
    std::str::from_utf8(bytes).map_err(|_| CdrError::NotUtf8 {
        field: field.to_string(),
    })
}

/// Decodes a `geometry_msgs/msg/PoseStamped`: position (m), and orientation `[x, y, z, w]`
/// within 5 % of unit norm, normalised and canonicalised to `w ≥ 0` (the JSON decoder's checks).
pub fn decode_pose_stamped(payload: &[u8]) -> Result<DecodedPose<'_>, CdrError> {
    let mut reader = Reader::new(payload)?;
    let stamp_s = reader.stamp(
        Field::plain("PoseStamped.header.stamp.sec"),
        Field::plain("PoseStamped.header.stamp.nanosec"),
    )?;
    let frame_id = reader.string(Field::plain("PoseStamped.header.frame_id"))?;
    let position_m = [
        reader.finite(Field::plain("PoseStamped.pose.position.x"))?,
        reader.finite(Field::plain("PoseStamped.pose.position.y"))?,
        reader.finite(Field::plain("PoseStamped.pose.position.z"))?,
    ];
    let xyzw = [
        reader.f64(Field::plain("PoseStamped.pose.orientation.x"))?,
        reader.f64(Field::plain("PoseStamped.pose.orientation.y"))?,
        reader.f64(Field::plain("PoseStamped.pose.orientation.z"))?,
        reader.f64(Field::plain("PoseStamped.pose.orientation.w"))?,
    ];
    let pose = json::pose_from_quaternion(position_m, xyzw).map_err(|error| match error {
        WireError::QuaternionNorm { norm, .. } => CdrError::QuaternionNorm {
            field: "PoseStamped.pose.orientation".to_owned(),
            norm,
        },
        // The quaternion check raises nothing else; keep the message if that ever changes.
        other => CdrError::NonFinite {
            field: format!("PoseStamped.pose.orientation ({other})"),
        },
    })?;
    Ok(DecodedPose {
        sample: MeasuredSample { stamp_s, pose },
        frame_id,
        xyzw_as_sent: xyzw,
    })
}

/// [`decode_pose_stamped`], refusing a pose whose `header.frame_id` is not `expected_frame`.
pub fn decode_pose_stamped_in<'a>(
    payload: &'a [u8],
    expected_frame: &str,
) -> Result<DecodedPose<'a>, CdrError> {
    let pose = decode_pose_stamped(payload)?;
    if pose.frame_id == expected_frame {
        Ok(pose)
    } else {
        Err(CdrError::FrameId {
            frame_id: pose.frame_id.to_owned(),
            expected: expected_frame.to_owned(),
        })
    }
}

/// The `header.stamp` (s) of a message that starts with a `std_msgs/Header` (`JointState`,
/// `PoseStamped`), if the header reads and the stamp is set: the stamp a refused message is
/// reported at.
#[must_use]
pub fn stamp_hint(payload: &[u8]) -> Option<f64> {
    let mut reader = Reader::new(payload).ok()?;
    reader
        .stamp(
            Field::plain("header.stamp.sec"),
            Field::plain("header.stamp.nanosec"),
        )
        .ok()
        .flatten()
}

/// A refused message with the stamp its header still offers.
fn refused(payload: &[u8]) -> impl FnOnce(CdrError) -> Refused<CdrError> + '_ {
    |error| Refused {
        error,
        stamp_s: stamp_hint(payload),
    }
}

/// A ROS 2 source's `sensor_msgs/msg/JointState` messages, matched by name to the arm's joints.
#[derive(Debug, Clone, Copy)]
pub struct JointStates<'a> {
    /// The arm's joint names.
    pub names: &'a JointNames,
    /// What `effort` holds (`None`: it is not read).
    pub effort: Option<EffortMeaning>,
}

impl Decoder for JointStates<'_> {
    type Message = JointSample;
    type Error = CdrError;

    fn read(&self, _robot: &Robot, payload: &[u8]) -> Result<JointSample, Refused<CdrError>> {
        decode_joint_state(payload, self.names, self.effort).map_err(refused(payload))
    }

    fn stamp_hint(&self, payload: &[u8]) -> Option<f64> {
        stamp_hint(payload)
    }
}

/// A ROS 2 source's `geometry_msgs/msg/PoseStamped` messages, in the frame the robot's poses are
/// read in (`<tf_prefix>base`).
#[derive(Debug, Clone, Copy)]
pub struct PosesStamped<'a> {
    /// The frame every pose must be in.
    pub expected_frame: &'a str,
}

impl Decoder for PosesStamped<'_> {
    type Message = MeasuredSample;
    type Error = CdrError;

    fn read(&self, _robot: &Robot, payload: &[u8]) -> Result<MeasuredSample, Refused<CdrError>> {
        decode_pose_stamped_in(payload, self.expected_frame)
            .map(|pose| pose.sample)
            .map_err(refused(payload))
    }

    fn stamp_hint(&self, payload: &[u8]) -> Option<f64> {
        stamp_hint(payload)
    }
}

/// The ROS frame id of a twin pose expressed in `frame`, for an arm with `tf_prefix`:
/// `<tf_prefix>base` (the frame of the driver's `tool0_controller` and of
/// `/tcp_pose_broadcaster/pose`) or `<tf_prefix>base_link`.
#[must_use]
pub fn frame_id(tf_prefix: &str, frame: OutputFrame) -> String {
    format!("{tf_prefix}{}", frame.as_str())
}

/// Appends a little-endian CDR `geometry_msgs/msg/PoseStamped` (with its header) of `pose` at
/// `stamp_s` in `frame_id` to `out`. The stamp is split into whole seconds and the nanoseconds
/// that read back as `stamp_s` (saturating at the range of `int32` seconds).
pub fn encode_pose_stamped_into(
    out: &mut Vec<u8>,
    stamp_s: f64,
    frame_id: &str,
    pose: &PoseReadout,
) {
    let (sec, nanosec) = split_stamp(stamp_s);
    let start = out.len() + 4;
    out.extend_from_slice(&[0x00, 0x01, 0x00, 0x00]);
    out.extend_from_slice(&sec.to_le_bytes());
    out.extend_from_slice(&nanosec.to_le_bytes());
    // A frame id longer than u32::MAX bytes cannot be built in memory here.
    let length = u32::try_from(frame_id.len() + 1).unwrap_or(u32::MAX);
    out.extend_from_slice(&length.to_le_bytes());
    out.extend_from_slice(frame_id.as_bytes());
    out.push(0);
    let padding = (out.len() - start).next_multiple_of(8) - (out.len() - start);
    out.resize(out.len() + padding, 0);
    for value in pose.position_m.iter().chain(&pose.quaternion_xyzw) {
        out.extend_from_slice(&value.to_le_bytes());
    }
}

/// [`encode_pose_stamped_into`] a new buffer.
#[must_use]
pub fn encode_pose_stamped(stamp_s: f64, frame_id: &str, pose: &PoseReadout) -> Vec<u8> {
    let mut out = Vec::with_capacity(64 + frame_id.len());
    encode_pose_stamped_into(&mut out, stamp_s, frame_id, pose);
    out
}

/// `builtin_interfaces/Time` of a stamp (s): whole seconds (floor) and nanoseconds.
///
/// A stamp in seconds resolves about 0.24 µs at today's Unix times, so several nanosecond
/// counts read back (sec + nanosec · 1e-9, as [`decode_pose_stamped`] sums them) as the same
/// stamp: the roundest of them is taken (whole milliseconds before whole microseconds, …), so a
/// stamp of whole microseconds read from a ROS header goes out as it came, and the message
/// always reads back as `stamp_s` to the last bit. With none, the nearest count.
#[allow(clippy::float_cmp, reason = "reading back exactly is the point")]
#[must_use]
pub fn split_stamp(stamp_s: f64) -> (i32, u32) {
    let floor = stamp_s.floor();
    if !floor.is_finite() {
        return (0, 0);
    }
    let mut nearest = ((stamp_s - floor) * 1e9).round();
    let mut sec = floor;
    if nearest >= 1e9 {
        sec += 1.0;
        nearest = 0.0;
    }
    let sec = sec.clamp(f64::from(i32::MIN), f64::from(i32::MAX));
    let mut nanosec = nearest;
    let mut step = 1e9;
    while step >= 1.0 {
        let candidate = (nearest / step).round() * step;
        if candidate < 1e9 && sec + candidate * 1e-9 == stamp_s {
            nanosec = candidate;
            break;
        }
        step /= 10.0;
    }
    // Both are integral and within their types' ranges here.
    #[allow(clippy::cast_sign_loss, reason = "nanosec is in 0..1e9")]
    (sec as i32, nanosec as u32)
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "decoded values are copied, not computed")]
mod tests {
    use super::*;

    #[test]
    fn stamps_split_into_seconds_and_rounded_nanoseconds() {
        assert_eq!(split_stamp(1748954669.5), (1748954669, 500_000_000));
        assert_eq!(split_stamp(-0.25), (-1, 750_000_000));
        assert_eq!(split_stamp(2.999_999_999_9), (3, 0));
        assert_eq!(split_stamp(f64::NAN), (0, 0));
    }

    #[test]
    fn stamps_read_from_ros_headers_split_back_into_them() {
        let sec = 1_748_954_669;
        for nanosec in [0, 2_000_000, 998_000_000, 123_000, 999_999_000, 1_000] {
            let stamp_s = f64::from(sec) + f64::from(nanosec) * 1e-9;
            assert_eq!(split_stamp(stamp_s), (sec, nanosec), "{nanosec} ns");
        }
        // Any stamp: the split reads back as it, bit for bit.
        for nanosec in (0..1_000_000_000).step_by(7_919_777) {
            let stamp_s = f64::from(sec) + f64::from(nanosec) * 1e-9 + 3.3e-8;
            let (s, n) = split_stamp(stamp_s);
            assert_eq!(f64::from(s) + f64::from(n) * 1e-9, stamp_s, "{stamp_s}");
        }
    }

    #[test]
    fn a_string_message_reads_back_within_its_limit() {
        let text = "<robot name=\"r\"/>";
        let mut payload = vec![0x00, 0x01, 0x00, 0x00];
        payload.extend_from_slice(&u32::try_from(text.len() + 1).unwrap().to_le_bytes());
        payload.extend_from_slice(text.as_bytes());
        payload.push(0);
        assert_eq!(decode_string(&payload, 64).unwrap(), text);
        assert!(matches!(
            decode_string(&payload, 4),
            Err(CdrError::TooLarge { .. } | CdrError::Count { .. })
        ));
        let unterminated = &payload[..payload.len() - 1];
        assert!(decode_string(unterminated, 64).is_err());
        let mut not_utf8 = payload.clone();
        not_utf8[9] = 0xff;
        assert!(matches!(
            decode_string(&not_utf8, 64),
            Err(CdrError::NotUtf8 { .. })
        ));
    }

    #[test]
    fn header_errors_are_typed() {
        let names = JointNames::ur("");
        assert_eq!(
            decode_joint_state(&[0, 1], &names, None),
            Err(CdrError::NoHeader { bytes: 2 })
        );
        let error = decode_joint_state(&[0, 7, 0, 0, 1, 2, 3, 4], &names, None).unwrap_err();
        assert_eq!(error.kind(), "representation");
        let big = vec![0; MAX_PAYLOAD_BYTES + 1];
        assert_eq!(decode_pose_stamped(&big).unwrap_err().kind(), "too_large");
    }
}
