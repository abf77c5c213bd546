//! The ROS 2 messages an armtwin MCAP file holds: their `ros2msg` schema texts (each with the
//! definitions it depends on, as rosbag2 writes them) and little-endian CDR encoders of them.
//!
//! Pure: bytes in, bytes out. The stamps are split as the twin pose output splits them
//! ([`cdr::split_stamp`]), so a stamp reads back to the last bit.

use armtwin_codec::cdr;

/// The separator between a schema's definition and those it uses (rosbag2's).
#[cfg(test)]
const SEPARATOR: &str =
    "================================================================================\n";

/// A message type: its name and its `ros2msg` schema text.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MessageType {
    /// `package/msg/Name`.
    pub name: &'static str,
    /// The definition, then each one it uses.
    pub definition: &'static str,
}

/// `sensor_msgs/msg/JointState`.
pub const JOINT_STATE: MessageType = MessageType {
    name: "sensor_msgs/msg/JointState",
    definition: concat!(
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n",
        "float64[] effort\n",
        "================================================================================\n",
        "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n",
        "================================================================================\n",
        "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n",
    ),
};

/// `geometry_msgs/msg/PoseStamped`.
pub const POSE_STAMPED: MessageType = MessageType {
    name: "geometry_msgs/msg/PoseStamped",
    definition: concat!(
        "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
        "================================================================================\n",
        "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n",
        "================================================================================\n",
        "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n",
        "================================================================================\n",
        "MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\n",
        "geometry_msgs/Quaternion orientation\n",
        "================================================================================\n",
        "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n",
        "================================================================================\n",
        "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    ),
};

/// `armtwin_msgs/msg/Deviation`: the twin minus the measured pose, as `…/deviation/<robot>`.
pub const DEVIATION: MessageType = MessageType {
    name: "armtwin_msgs/msg/Deviation",
    definition: concat!(
        "# The twin pose minus the measured pose, in the robot's output frame.\n",
        "std_msgs/Header header\n",
        "float64 dx_m\nfloat64 dy_m\nfloat64 dz_m\n",
        "float64 position_m\nfloat64 quat_distance\nfloat64 angle_rad\n",
        "float64 droll_rad\nfloat64 dpitch_rad\nfloat64 dyaw_rad\n",
        "================================================================================\n",
        "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n",
        "================================================================================\n",
        "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n",
    ),
};

/// `armtwin_msgs/msg/Effort`: a joint sample's torques, as `…/effort/<robot>`; an array is empty
/// when the twin did not have it.
pub const EFFORT: MessageType = MessageType {
    name: "armtwin_msgs/msg/Effort",
    definition: concat!(
        "# Joint torques (N m), one per joint.\n",
        "std_msgs/Header header\n",
        "float64[] model_nm\nfloat64[] measured_nm\nfloat64[] residual_nm\nfloat64[] observer_nm\n",
        "================================================================================\n",
        "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n",
        "================================================================================\n",
        "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n",
    ),
};

/// `rcl_interfaces/msg/Log`, what `/rosout` carries.
pub const LOG: MessageType = MessageType {
    name: "rcl_interfaces/msg/Log",
    definition: concat!(
        "byte DEBUG=10\nbyte INFO=20\nbyte WARN=30\nbyte ERROR=40\nbyte FATAL=50\n",
        "builtin_interfaces/Time stamp\nuint8 level\nstring name\nstring msg\nstring file\n",
        "string function\nuint32 line\n",
        "================================================================================\n",
        "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n",
    ),
};

/// `std_msgs/msg/String`: what `/robot_description` carries (a URDF).
pub const STRING: MessageType = MessageType {
    name: "std_msgs/msg/String",
    definition: "string data\n",
};

/// `tf2_msgs/msg/TFMessage`: what `/tf` carries.
pub const TF_MESSAGE: MessageType = MessageType {
    name: "tf2_msgs/msg/TFMessage",
    definition: concat!(
        "geometry_msgs/TransformStamped[] transforms\n",
        "================================================================================\n",
        "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n",
        "geometry_msgs/Transform transform\n",
        "================================================================================\n",
        "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n",
        "================================================================================\n",
        "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n",
        "================================================================================\n",
        "MSG: geometry_msgs/Transform\ngeometry_msgs/Vector3 translation\n",
        "geometry_msgs/Quaternion rotation\n",
        "================================================================================\n",
        "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n",
        "================================================================================\n",
        "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    ),
};

/// `rcl_interfaces/msg/Log` levels.
pub const LOG_INFO: u8 = 20;
/// The same, a warning.
pub const LOG_WARN: u8 = 30;

/// A stamp (s) as nanoseconds since the epoch, as MCAP's log times count (0 before it).
#[must_use]
pub fn stamp_ns(stamp_s: f64) -> u64 {
    let (sec, nanosec) = cdr::split_stamp(stamp_s);
    u64::try_from(sec).map_or(0, |sec| sec * 1_000_000_000 + u64::from(nanosec))
}

/// A little-endian CDR message being written: alignment counts from the body's first byte.
struct Writer {
    out: Vec<u8>,
}

impl Writer {
    fn new() -> Self {
        let mut out = Vec::with_capacity(256);
        out.extend_from_slice(&[0x00, 0x01, 0x00, 0x00]);
        Self { out }
    }

    fn align(&mut self, size: usize) {
        let body = self.out.len() - 4;
        self.out
            .resize(self.out.len() + body.next_multiple_of(size) - body, 0);
    }

    fn u32(&mut self, value: u32) {
        self.align(4);
        self.out.extend_from_slice(&value.to_le_bytes());
    }

    fn f64(&mut self, value: f64) {
        self.align(8);
        self.out.extend_from_slice(&value.to_le_bytes());
    }

    fn length(&mut self, length: usize) {
        self.u32(u32::try_from(length).unwrap_or(u32::MAX));
    }

    fn string(&mut self, text: &str) {
        self.length(text.len() + 1);
        self.out.extend_from_slice(text.as_bytes());
        self.out.push(0);
    }

    fn f64s(&mut self, values: &[f64]) {
        self.length(values.len());
        for &value in values {
            self.f64(value);
        }
    }

    fn time(&mut self, stamp_s: f64) {
        let (sec, nanosec) = cdr::split_stamp(stamp_s);
        self.align(4);
        self.out.extend_from_slice(&sec.to_le_bytes());
        self.out.extend_from_slice(&nanosec.to_le_bytes());
    }

    fn header(&mut self, stamp_s: f64, frame_id: &str) {
        self.time(stamp_s);
        self.string(frame_id);
    }
}

/// A `sensor_msgs/msg/JointState`: `velocity` and `effort` empty when absent.
#[must_use]
pub fn joint_state(
    stamp_s: f64,
    frame_id: &str,
    joint_names: &[String],
    position: &[f64],
    velocity: &[f64],
    effort: &[f64],
) -> Vec<u8> {
    let mut writer = Writer::new();
    writer.header(stamp_s, frame_id);
    writer.length(joint_names.len());
    for name in joint_names {
        writer.string(name);
    }
    writer.f64s(position);
    writer.f64s(velocity);
    writer.f64s(effort);
    writer.out
}

/// An `armtwin_msgs/msg/Deviation` of the nine values in [`DEVIATION`]'s order.
#[must_use]
pub fn deviation(stamp_s: f64, frame_id: &str, values: &[f64]) -> Vec<u8> {
    let mut writer = Writer::new();
    writer.header(stamp_s, frame_id);
    for &value in values.iter().take(9) {
        writer.f64(value);
    }
    writer.out
}

/// An `armtwin_msgs/msg/Effort`: each array empty when absent.
#[must_use]
pub fn effort(stamp_s: f64, arrays: [&[f64]; 4]) -> Vec<u8> {
    let mut writer = Writer::new();
    writer.header(stamp_s, "");
    for values in arrays {
        writer.f64s(values);
    }
    writer.out
}

/// An `rcl_interfaces/msg/Log` from `name` (the logger: `armtwin`).
#[must_use]
pub fn log(stamp_s: f64, level: u8, name: &str, text: &str) -> Vec<u8> {
    let mut writer = Writer::new();
    writer.time(stamp_s);
    writer.out.push(level);
    writer.string(name);
    writer.string(text);
    writer.string("");
    writer.string("");
    writer.u32(0);
    writer.out
}

/// A `std_msgs/msg/String`.
#[must_use]
pub fn string(text: &str) -> Vec<u8> {
    let mut writer = Writer::new();
    writer.string(text);
    writer.out
}

/// One transform of a `tf2_msgs/msg/TFMessage`: `child` in `parent` as
/// `[x, y, z]` (m) and `[qx, qy, qz, qw]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform<'a> {
    /// `header.frame_id`.
    pub parent: &'a str,
    /// `child_frame_id`.
    pub child: &'a str,
    /// `transform.translation` (m).
    pub translation_m: [f64; 3],
    /// `transform.rotation`, `[x, y, z, w]`.
    pub rotation_xyzw: [f64; 4],
}

/// A `tf2_msgs/msg/TFMessage` of `transforms`, each stamped `stamp_s`.
#[must_use]
pub fn tf_message(stamp_s: f64, transforms: &[Transform<'_>]) -> Vec<u8> {
    let mut writer = Writer::new();
    writer.length(transforms.len());
    for transform in transforms {
        writer.header(stamp_s, transform.parent);
        writer.string(transform.child);
        for &value in transform
            .translation_m
            .iter()
            .chain(&transform.rotation_xyzw)
        {
            writer.f64(value);
        }
    }
    writer.out
}

#[cfg(test)]
mod tests {
    #![allow(clippy::float_cmp, reason = "decoded values are copied, not computed")]
    use super::{JOINT_STATE, POSE_STAMPED, SEPARATOR, TF_MESSAGE, joint_state};
    use armtwin_codec::cdr::{self, EffortMeaning, JointNames};

    #[test]
    fn a_joint_state_reads_back_through_the_bag_decoder_bit_for_bit() {
        let names = JointNames::ur("");
        let q = [0.1, -1.2, 1.3, -0.4, 1.5, 1e-17];
        let velocity = [0.5; 6];
        let effort = [2.0, 3.0, 4.0, 5.0, 6.0, 7.0];
        let stamp_s = 1_748_954_669.123_456;
        let payload = joint_state(stamp_s, "base", names.as_slice(), &q, &velocity, &effort);
        let sample = cdr::decode_joint_state(&payload, &names, Some(EffortMeaning::TorqueNm))
            .expect("decodes");
        assert_eq!(sample.stamp_s, Some(stamp_s));
        assert_eq!(sample.q_rad.as_slice(), q);
    }

    #[test]
    fn schemas_name_every_type_they_use_once() {
        for schema in [JOINT_STATE, POSE_STAMPED, TF_MESSAGE] {
            let sections: Vec<&str> = schema.definition.split(SEPARATOR).collect();
            assert!(sections[1..].iter().all(|s| s.starts_with("MSG: ")));
        }
    }
}
