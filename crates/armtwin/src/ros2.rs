//! ROS 2 robots on Zenoh as they publish: the key layouts of `rmw_zenoh` and of
//! `zenoh-bridge-ros2dds`, the robot id a key names (its ROS namespace), `rmw_zenoh`'s sample
//! attachment, and the key, attachment and publisher gid of the twin pose armtwin publishes for
//! ROS tools.
//!
//! Key layouts (checked against `ros2/rmw_zenoh` `docs/design.md` and
//! `eclipse-zenoh/zenoh-plugin-ros2dds` `src/ros2_utils.rs`):
//! - `rmw_zenoh`: `<domain id>/<namespace…>/<topic…>/<DDS type name>/<type hash>`, e.g.
//!   `0/ur/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_a13e…` (Humble writes
//!   `TypeHashNotSupported` for the hash).
//! - the bridge: `<namespace…>/<topic…>` (its own `namespace` setting, if any, first), e.g.
//!   `ur/joint_states`.
//!
//! Payloads are CDR either way ([`crate::codec::cdr`]); only `rmw_zenoh` attaches
//! `(i64 sequence number, i64 source timestamp ns, gid)` to each sample. Pure: strings and
//! bytes in, values out; the service does the I/O.

use serde::Deserialize;
use thiserror::Error;

use crate::keys;

/// The DDS type name `rmw_zenoh` puts in the key of `sensor_msgs/msg/JointState`.
pub const JOINT_STATE_DDS_TYPE: &str = "sensor_msgs::msg::dds_::JointState_";
/// The DDS type name `rmw_zenoh` puts in the key of `geometry_msgs/msg/PoseStamped`.
pub const POSE_STAMPED_DDS_TYPE: &str = "geometry_msgs::msg::dds_::PoseStamped_";
/// The RIHS01 type hash of `sensor_msgs/msg/JointState` (Jazzy, Kilted, Rolling).
pub const JOINT_STATE_TYPE_HASH: &str =
    "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e";
/// The RIHS01 type hash of `geometry_msgs/msg/PoseStamped` (Jazzy, Kilted, Rolling).
pub const POSE_STAMPED_TYPE_HASH: &str =
    "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8";

/// The UR driver's joint topic, the default of a `joints` source.
pub const UR_JOINT_TOPIC: &str = "/joint_states";
/// The UR driver's measured TCP pose topic (`<tf_prefix>base` frame), the default of a
/// `measured` source.
pub const UR_POSE_TOPIC: &str = "/tcp_pose_broadcaster/pose";
/// The topic of the twin pose output unless configured.
pub const DEFAULT_POSE_OUTPUT_TOPIC: &str = "armtwin/tcp_pose";

/// How ROS 2 topics are laid out on Zenoh.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KeyScheme {
    /// ROS 2 on Zenoh natively: `<domain>/<namespace…>/<topic…>/<type>/<hash>`, with an
    /// attachment on every sample.
    RmwZenoh,
    /// A DDS robot through `zenoh-bridge-ros2dds`: `<namespace…>/<topic…>`, no attachment.
    Bridge,
}

impl KeyScheme {
    /// The configuration's name.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::RmwZenoh => "rmw_zenoh",
            Self::Bridge => "bridge",
        }
    }
}

/// A ROS name that is not one (`/` separated chunks of letters, digits and `_`, none empty or
/// starting with a digit).
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error(
    "'{name}' is not a ROS name ('/'-separated tokens of letters, digits and '_', none empty or starting with a digit)"
)]
pub struct RosNameError {
    /// The name as given.
    pub name: String,
}

/// `name` without its leading `/`, if it is a ROS topic or namespace name; `""` (and `"/"`)
/// only when `empty_allowed` (the root namespace).
pub fn relative_ros_name(name: &str, empty_allowed: bool) -> Result<&str, RosNameError> {
    let relative = name.strip_prefix('/').unwrap_or(name);
    let token = |token: &str| {
        token
            .bytes()
            .next()
            .is_some_and(|first| !first.is_ascii_digit())
            && token
                .bytes()
                .all(|byte| byte.is_ascii_alphanumeric() || byte == b'_')
    };
    if (relative.is_empty() && empty_allowed) || relative.split('/').all(token) {
        Ok(relative)
    } else {
        Err(RosNameError {
            name: name.to_owned(),
        })
    }
}

/// Reads a robot id from a key: the ROS namespace of the topic it carries, chunks joined by `/`
/// (`0/plant_a/ur7/joint_states/…` → `plant_a/ur7`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NamespaceRule {
    scheme: KeyScheme,
    /// The topic without namespace and without its leading `/` (`joint_states`).
    topic: String,
    /// The DDS type name an `rmw_zenoh` key must carry.
    dds_type: &'static str,
}

impl NamespaceRule {
    /// The rule for `topic` (a ROS name, e.g. `/joint_states`) of type `dds_type` under `scheme`.
    pub fn new(
        scheme: KeyScheme,
        topic: &str,
        dds_type: &'static str,
    ) -> Result<Self, RosNameError> {
        Ok(Self {
            scheme,
            topic: relative_ros_name(topic, false)?.to_owned(),
            dds_type,
        })
    }

    /// The robot id `key` names, if it carries this rule's topic (and, for `rmw_zenoh`, type)
    /// under a non-empty namespace that is a robot id ([`keys::robot_id`]). `None` for any other
    /// key: the root namespace names no robot, nor does one over the robot id's length bound.
    #[must_use]
    pub fn robot_of<'k>(&self, key: &'k str) -> Option<&'k str> {
        let path = match self.scheme {
            KeyScheme::RmwZenoh => {
                let (domain, rest) = key.split_once('/')?;
                if domain.is_empty() || !domain.bytes().all(|b| b.is_ascii_digit()) {
                    return None;
                }
                let (rest, _type_hash) = rest.rsplit_once('/')?;
                let (path, dds_type) = rest.rsplit_once('/')?;
                (dds_type == self.dds_type).then_some(path)?
            }
            KeyScheme::Bridge => key,
        };
        let namespace = path.strip_suffix(self.topic.as_str())?.strip_suffix('/')?;
        keys::robot_id(namespace).ok()
    }

    /// A key expression every key this rule reads a robot from matches: a source's key
    /// expression that does not intersect it can never name a robot.
    #[must_use]
    pub fn key_pattern(&self) -> String {
        match self.scheme {
            KeyScheme::RmwZenoh => format!("*/*/**/{}/{}/*", self.topic, self.dds_type),
            KeyScheme::Bridge => format!("*/**/{}", self.topic),
        }
    }

    /// The topic, without its leading `/`.
    #[must_use]
    pub fn topic(&self) -> &str {
        &self.topic
    }
}

/// Longest publisher gid accepted in an attachment (16 bytes since Iron, 24 in Humble).
pub const MAX_GID_BYTES: usize = 24;

/// Longest attachment read (the keyed form with a 24-byte gid takes 83 bytes).
const MAX_ATTACHMENT_BYTES: usize = 256;

/// Why an `rmw_zenoh` attachment was refused.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum AttachmentError {
    /// Longer than any attachment `rmw_zenoh` writes.
    #[error("attachment of {bytes} bytes exceeds the limit of {MAX_ATTACHMENT_BYTES} bytes")]
    TooLarge {
        /// Its size.
        bytes: usize,
    },
    /// It ends inside a field.
    #[error("attachment of {bytes} bytes ends inside '{field}'")]
    Truncated {
        /// The field.
        field: &'static str,
        /// Its size.
        bytes: usize,
    },
    /// A length that is not a LEB128 number of at most 64 bits.
    #[error("attachment '{field}': length is not a LEB128 number")]
    Length {
        /// The field.
        field: &'static str,
    },
    /// A gid longer than [`MAX_GID_BYTES`].
    #[error("attachment gid of {length} bytes exceeds {MAX_GID_BYTES} bytes")]
    GidLength {
        /// The length sent.
        length: u64,
    },
    /// The keyed form (`"sequence_number"`, …) with another key.
    #[error("attachment key '{found}' where '{expected}' belongs")]
    Key {
        /// The key expected.
        expected: &'static str,
        /// The key found (lossy UTF-8).
        found: String,
    },
    /// Bytes after the gid.
    #[error("attachment has {extra} bytes after the gid")]
    Trailing {
        /// How many.
        extra: usize,
    },
    /// A negative sequence number.
    #[error("attachment sequence number {sequence_number} is negative")]
    NegativeSequence {
        /// The value sent.
        sequence_number: i64,
    },
}

/// An `rmw_zenoh` sample attachment: zenoh-ext serialized (little-endian, sequences with a
/// LEB128 length) `i64 sequence_number, i64 source_timestamp, gid bytes`. Also read: the keyed
/// form of early `rmw_zenoh` releases, each value preceded by its name as a string.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    /// The publisher's sequence number (counts from 1, never negative).
    pub sequence_number: u64,
    /// When the publisher sent the sample (ns since the Unix epoch, its clock).
    pub source_timestamp_ns: i64,
    gid: [u8; MAX_GID_BYTES],
    gid_len: u8,
}

/// A bounds-checked reader of zenoh-ext serialized values.
struct Serialized<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Serialized<'a> {
    fn take(&mut self, n: usize, field: &'static str) -> Result<&'a [u8], AttachmentError> {
        let taken = self
            .at
            .checked_add(n)
            .and_then(|end| self.bytes.get(self.at..end))
            .ok_or(AttachmentError::Truncated {
                field,
                bytes: self.bytes.len(),
            })?;
        self.at += n;
        Ok(taken)
    }

    fn i64(&mut self, field: &'static str) -> Result<i64, AttachmentError> {
        let mut value = [0; 8];
        value.copy_from_slice(self.take(8, field)?);
        Ok(i64::from_le_bytes(value))
    }

    fn length(&mut self, field: &'static str) -> Result<u64, AttachmentError> {
        let mut value = 0_u64;
        for shift in (0..64).step_by(7) {
            let &[byte] = self.take(1, field)? else {
                return Err(AttachmentError::Length { field });
            };
            let bits = u64::from(byte & 0x7f);
            if shift == 63 && bits > 1 {
                return Err(AttachmentError::Length { field });
            }
            value |= bits << shift;
            if byte & 0x80 == 0 {
                return Ok(value);
            }
        }
        Err(AttachmentError::Length { field })
    }

    /// A length-prefixed byte sequence of at most `limit` bytes (`too_long` builds the error).
    fn sequence(
        &mut self,
        field: &'static str,
        limit: usize,
        too_long: impl FnOnce(u64) -> AttachmentError,
    ) -> Result<&'a [u8], AttachmentError> {
        let length = self.length(field)?;
        match usize::try_from(length) {
            Ok(length) if length <= limit => self.take(length, field),
            _ => Err(too_long(length)),
        }
    }

    /// The keyed form's name of the next value.
    fn key(&mut self, expected: &'static str) -> Result<(), AttachmentError> {
        let found = self.sequence(expected, MAX_ATTACHMENT_BYTES, |_| {
            AttachmentError::Length { field: expected }
        })?;
        if found == expected.as_bytes() {
            Ok(())
        } else {
            Err(AttachmentError::Key {
                expected,
                found: String::from_utf8_lossy(found).into_owned(),
            })
        }
    }
}

/// How the keyed form starts: the string `sequence_number` with its length.
const KEYED_PREFIX: &[u8] = b"\x0fsequence_number";

impl Attachment {
    /// Parses an attachment; every length is checked against the bytes there are.
    pub fn parse(bytes: &[u8]) -> Result<Self, AttachmentError> {
        if bytes.len() > MAX_ATTACHMENT_BYTES {
            return Err(AttachmentError::TooLarge { bytes: bytes.len() });
        }
        let mut reader = Serialized { bytes, at: 0 };
        // A keyless attachment would start so only with a sequence number near 7e18.
        let keyed = bytes.starts_with(KEYED_PREFIX);
        if keyed {
            reader.key("sequence_number")?;
        }
        let sequence_number = reader.i64("sequence_number")?;
        if keyed {
            reader.key("source_timestamp")?;
        }
        let source_timestamp_ns = reader.i64("source_timestamp")?;
        if keyed {
            reader.key("source_gid")?;
        }
        let gid_bytes = reader.sequence("source_gid", MAX_GID_BYTES, |length| {
            AttachmentError::GidLength { length }
        })?;
        if reader.at != bytes.len() {
            return Err(AttachmentError::Trailing {
                extra: bytes.len() - reader.at,
            });
        }
        let sequence_number = u64::try_from(sequence_number)
            .map_err(|_| AttachmentError::NegativeSequence { sequence_number })?;
        let mut gid = [0; MAX_GID_BYTES];
        gid[..gid_bytes.len()].copy_from_slice(gid_bytes);
        Ok(Self {
            sequence_number,
            source_timestamp_ns,
            gid,
            // At most MAX_GID_BYTES, checked above.
            gid_len: u8::try_from(gid_bytes.len()).unwrap_or(u8::MAX),
        })
    }

    /// The publisher's gid.
    #[must_use]
    pub fn gid(&self) -> &[u8] {
        &self.gid[..usize::from(self.gid_len)]
    }

    /// The source timestamp in seconds since the epoch, if it is set (positive).
    #[must_use]
    pub fn source_timestamp_s(&self) -> Option<f64> {
        (self.source_timestamp_ns > 0).then(|| {
            let ns = self.source_timestamp_ns;
            (ns / 1_000_000_000) as f64 + (ns % 1_000_000_000) as f64 * 1e-9
        })
    }
}

/// The attachment `rmw_zenoh` puts on a sample: `sequence_number`, `source_timestamp_ns`, and
/// the 16-byte `gid` with its length (33 bytes).
#[must_use]
pub fn encode_attachment(
    sequence_number: i64,
    source_timestamp_ns: i64,
    gid: &[u8; 16],
) -> Vec<u8> {
    let mut out = Vec::with_capacity(33);
    out.extend_from_slice(&sequence_number.to_le_bytes());
    out.extend_from_slice(&source_timestamp_ns.to_le_bytes());
    out.push(16);
    out.extend_from_slice(gid);
    out
}

/// One robot's `rmw_zenoh` sequence numbers as the gateway `seq` of its joint samples.
///
/// A publisher counts from 1 again when it restarts (and gets another gid): numbers from a new
/// gid carry on from the last one passed on, so a restarted driver is neither refused as going
/// back nor reported as a gap. Within one publisher the numbers pass on with their spacing, so
/// skips raise `gap` events and repeats are refused, as for a JSON gateway's `seq`.
#[derive(Debug, Clone, Default)]
pub struct PublisherSeq {
    gid: Option<([u8; MAX_GID_BYTES], u8)>,
    /// Added to the publisher's numbers.
    offset: i128,
    last: u64,
}

impl PublisherSeq {
    /// The gateway `seq` of a sample with `attachment`, and whether it came from another
    /// publisher than the previous one.
    pub fn gateway_seq(&mut self, attachment: &Attachment) -> (u64, bool) {
        let gid = (attachment.gid, attachment.gid_len);
        let sequence_number = i128::from(attachment.sequence_number);
        let changed = self.gid.is_some_and(|last| last != gid);
        if changed {
            self.offset = i128::from(self.last) + 1 - sequence_number;
        }
        self.gid = Some(gid);
        // A number far below the one a publisher switched at maps below 0: a step back.
        let seq = u64::try_from((sequence_number + self.offset).max(0)).unwrap_or(u64::MAX);
        self.last = self.last.max(seq);
        (seq, changed)
    }
}

/// Where and how the twin pose of a robot goes out for ROS tools (`ros2_pose` of a robot).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PoseOutput {
    /// `rmw_zenoh` (with attachment) or bridge keys.
    pub scheme: KeyScheme,
    /// The ROS domain id (`rmw_zenoh` keys).
    pub domain_id: u32,
    /// The ROS namespace without its leading `/` (`""` the root); `None`: the robot id.
    pub namespace: Option<String>,
    /// The topic within the namespace, without its leading `/`.
    pub topic: String,
    /// Prepended to the frame id (`<tf_prefix>base`).
    pub tf_prefix: String,
    /// The type hash in `rmw_zenoh` keys (`TypeHashNotSupported` for Humble subscribers).
    pub type_hash: String,
}

impl PoseOutput {
    /// The key of `robot`'s twin pose; `robot` may be a key expression (`**`) to cover every
    /// robot without a namespace of its own.
    #[must_use]
    pub fn key(&self, robot: &str) -> String {
        let namespace = self.namespace.as_deref().unwrap_or(robot);
        let path = if namespace.is_empty() {
            self.topic.clone()
        } else {
            format!("{namespace}/{}", self.topic)
        };
        match self.scheme {
            KeyScheme::RmwZenoh => format!(
                "{}/{path}/{POSE_STAMPED_DDS_TYPE}/{}",
                self.domain_id, self.type_hash
            ),
            KeyScheme::Bridge => path,
        }
    }

    /// Whether samples carry `rmw_zenoh`'s attachment.
    #[must_use]
    pub fn attaches(&self) -> bool {
        self.scheme == KeyScheme::RmwZenoh
    }
}

/// The twin pose outputs of every robot: `[robots.default.ros2_pose]` and each robot's own.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PoseOutputs {
    /// Robots without a section of their own.
    pub default: Option<PoseOutput>,
    /// Configured robots (`None`: the output is disabled for the robot).
    pub robots: std::collections::HashMap<String, Option<PoseOutput>>,
}

impl PoseOutputs {
    /// The output of robot `id`, if it has one.
    #[must_use]
    pub fn of(&self, id: &str) -> Option<&PoseOutput> {
        match self.robots.get(id) {
            Some(output) => output.as_ref(),
            None => self.default.as_ref(),
        }
    }

    /// Key expressions covering every twin pose output key (robots without a namespace of
    /// their own under `**`).
    #[must_use]
    pub fn key_patterns(&self) -> Vec<String> {
        self.default
            .iter()
            .chain(self.robots.values().flatten())
            .map(|output| output.key("**"))
            .collect()
    }
}

/// The gid armtwin's twin pose publisher of `robot` announces: 128-bit FNV-1a of the session's
/// Zenoh id and the robot id, fixed for the service's lifetime and distinct per robot.
#[must_use]
pub fn publisher_gid(zid_le: &[u8; 16], robot: &str) -> [u8; 16] {
    const OFFSET: u128 = 0x6c62_272e_07bb_0142_62b8_2175_6295_c58d;
    const PRIME: u128 = 0x0000_0000_0100_0000_0000_0000_0000_013b;
    let mut hash = OFFSET;
    for &byte in zid_le.iter().chain(robot.as_bytes()) {
        hash ^= u128::from(byte);
        hash = hash.wrapping_mul(PRIME);
    }
    hash.to_le_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ros_names() {
        assert_eq!(
            relative_ros_name("/joint_states", false),
            Ok("joint_states")
        );
        assert_eq!(
            relative_ros_name("tcp_pose_broadcaster/pose", false),
            Ok("tcp_pose_broadcaster/pose")
        );
        assert_eq!(relative_ros_name("/", true), Ok(""));
        for bad in ["", "/", "a//b", "a/", "9lives", "ur-10", "a/*"] {
            assert!(relative_ros_name(bad, false).is_err(), "{bad}");
        }
    }

    #[test]
    fn leb128_lengths_are_read_and_bounded() {
        let mut reader = Serialized {
            bytes: &[0x98, 0x00],
            at: 0,
        };
        assert_eq!(reader.length("x"), Ok(24), "a non-minimal LEB128 24");
        let mut reader = Serialized {
            bytes: &[0xff; 11],
            at: 0,
        };
        assert_eq!(
            reader.length("x"),
            Err(AttachmentError::Length { field: "x" })
        );
        let mut bytes = vec![0xff; 9];
        bytes.push(0x01);
        let mut reader = Serialized {
            bytes: &bytes,
            at: 0,
        };
        assert_eq!(reader.length("x"), Ok(u64::MAX));
    }

    fn from(gid: u8, sequence_number: u64) -> Attachment {
        let mut bytes = [0; MAX_GID_BYTES];
        bytes[0] = gid;
        Attachment {
            sequence_number,
            source_timestamp_ns: 0,
            gid: bytes,
            gid_len: 16,
        }
    }

    #[test]
    fn a_publishers_numbers_pass_on_and_a_new_publisher_carries_on_from_them() {
        let mut seq = PublisherSeq::default();
        let mapped: Vec<(u64, bool)> = [from(1, 10), from(1, 11), from(1, 13), from(1, 12)]
            .iter()
            .map(|attachment| seq.gateway_seq(attachment))
            .collect();
        // As sent: the pipeline sees the skip (gap) and the step back (refused).
        assert_eq!(mapped, [(10, false), (11, false), (13, false), (12, false)]);
        // A restart: numbers from 1 again under another gid continue from the highest, 13.
        assert_eq!(seq.gateway_seq(&from(2, 1)), (14, true));
        assert_eq!(seq.gateway_seq(&from(2, 2)), (15, false));
        assert_eq!(
            seq.gateway_seq(&from(2, 4)),
            (17, false),
            "a skip stays a skip"
        );
        // A publisher that starts high, and a number far below the one it switched at.
        assert_eq!(seq.gateway_seq(&from(3, 1000)), (18, true));
        assert_eq!(
            seq.gateway_seq(&from(3, 1)),
            (0, false),
            "a step back, as such"
        );
        assert_eq!(seq.gateway_seq(&from(3, 1001)), (19, false));
    }

    #[test]
    fn publisher_gids_differ_per_robot_and_session() {
        let zid = [7; 16];
        assert_eq!(publisher_gid(&zid, "a"), publisher_gid(&zid, "a"));
        assert_ne!(publisher_gid(&zid, "a"), publisher_gid(&zid, "b"));
        assert_ne!(publisher_gid(&zid, "a"), publisher_gid(&[8; 16], "a"));
    }
}
