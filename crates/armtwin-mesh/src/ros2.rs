//! ROS 2 robots on Zenoh as they publish: the key layouts of `rmw_zenoh` and of
//! `zenoh-bridge-ros2dds`, the robot id a key names (its ROS namespace), and the key and
//! publisher gid of the twin pose armtwin publishes for ROS tools. `rmw_zenoh`'s sample
//! attachment is a codec's ([`armtwin_codec::ros2_attachment`], re-exported here).
//!
//! Key layouts (checked against `ros2/rmw_zenoh` `docs/design.md` and
//! `eclipse-zenoh/zenoh-plugin-ros2dds` `src/ros2_utils.rs`):
//! - `rmw_zenoh`: `<domain id>/<namespace…>/<topic…>/<DDS type name>/<type hash>`, e.g.
//!   `0/ur/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_a13e…` (Humble writes
//!   `TypeHashNotSupported` for the hash).
//! - the bridge: `<namespace…>/<topic…>` (its own `namespace` setting, if any, first), e.g.
//!   `ur/joint_states`.
//!
//! Payloads are CDR either way ([`armtwin_codec::cdr`]); only `rmw_zenoh` attaches
//! `(i64 sequence number, i64 source timestamp ns, gid)` to each sample. Pure: strings and
//! bytes in, values out; the service does the I/O.

use serde::Deserialize;
use thiserror::Error;

use crate::keys;
pub use armtwin_codec::ros2_attachment::{
    Attachment, AttachmentError, MAX_GID_BYTES, PublisherSeq, encode_attachment,
};

/// The DDS type name `rmw_zenoh` puts in the key of `sensor_msgs/msg/JointState`.
pub const JOINT_STATE_DDS_TYPE: &str = "sensor_msgs::msg::dds_::JointState_";
/// The DDS type name `rmw_zenoh` puts in the key of `geometry_msgs/msg/PoseStamped`.
pub const POSE_STAMPED_DDS_TYPE: &str = "geometry_msgs::msg::dds_::PoseStamped_";
/// The DDS type name `rmw_zenoh` puts in the key of `std_msgs/msg/String`.
pub const STRING_DDS_TYPE: &str = "std_msgs::msg::dds_::String_";
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
/// The topic `robot_state_publisher` publishes a robot's URDF on (transient local).
pub const DESCRIPTION_TOPIC: &str = "/robot_description";
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
    fn publisher_gids_differ_per_robot_and_session() {
        let zid = [7; 16];
        assert_eq!(publisher_gid(&zid, "a"), publisher_gid(&zid, "a"));
        assert_ne!(publisher_gid(&zid, "a"), publisher_gid(&zid, "b"));
        assert_ne!(publisher_gid(&zid, "a"), publisher_gid(&[8; 16], "a"));
    }
}
