//! The ROS 2 inputs the tests share: the fixtures of tests/data/ros2 (the MCAP bag `rosbags`
//! wrote), `rmw_zenoh` attachments as zenoh-ext serializes them, and configurations parsed with
//! a listen endpoint of the test's own.

use std::path::{Path, PathBuf};

use armtwin_mesh::ros2;
use armtwin_service::config::{Overrides, ServiceConfig};
use zenoh_ext::ZSerializer;

pub const JOINT_TYPE: &str = ros2::JOINT_STATE_DDS_TYPE;
pub const POSE_TYPE: &str = ros2::POSE_STAMPED_DDS_TYPE;

/// tests/data/ros2.
pub fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/ros2")
}

/// `config_toml` as the service's configuration, listening on `listen`.
pub fn parse(config_toml: &str, listen: Vec<String>) -> Result<ServiceConfig, String> {
    ServiceConfig::parse(
        config_toml,
        "test config",
        Path::new("."),
        &Overrides {
            listen,
            ..Overrides::default()
        },
    )
    .map_err(|e| e.to_string())
}

/// The `JointState` and `PoseStamped` messages of the MCAP bag, as recorded (CDR with header).
pub fn bag_messages() -> (Vec<Vec<u8>>, Vec<Vec<u8>>) {
    let file = data().join("ur10e_lasttest_head_mcap/ur10e_lasttest_head_mcap.mcap");
    let bytes = std::fs::read(file).expect("bag");
    let (mut joints, mut poses) = (Vec::new(), Vec::new());
    for message in mcap::MessageStream::new(&bytes).expect("MCAP") {
        let message = message.expect("message");
        match message.channel.topic.as_str() {
            "/joint_states" => joints.push(message.data.into_owned()),
            "/tcp_pose_broadcaster/pose" => poses.push(message.data.into_owned()),
            other => panic!("unexpected topic {other}"),
        }
    }
    assert_eq!((joints.len(), poses.len()), (400, 400));
    (joints, poses)
}

/// An `rmw_zenoh` attachment as zenoh-ext serializes it.
pub fn attachment(sequence_number: i64, source_timestamp_ns: i64, gid: &[u8]) -> Vec<u8> {
    let mut serializer = ZSerializer::new();
    serializer.serialize(sequence_number);
    serializer.serialize(source_timestamp_ns);
    serializer.serialize(gid);
    serializer.finish().to_bytes().into_owned()
}

/// The keyed form of early `rmw_zenoh` releases (each value after its name).
pub fn keyed_attachment(sequence_number: i64, source_timestamp_ns: i64, gid: &[u8]) -> Vec<u8> {
    let mut serializer = ZSerializer::new();
    serializer.serialize("sequence_number");
    serializer.serialize(sequence_number);
    serializer.serialize("source_timestamp");
    serializer.serialize(source_timestamp_ns);
    serializer.serialize("source_gid");
    serializer.serialize(gid);
    serializer.finish().to_bytes().into_owned()
}

/// ROS 2 sources on both key schemes (`rmw_zenoh` at any namespace depth, the bridge with one
/// namespace chunk), robots named by their namespace, and a driver without one as a fixed robot.
pub const NAMESPACE_SOURCES: &str = r#"
[service]
metrics_period_ms = 50
# Every pose is counted: a client that falls behind slows the twin instead of missing poses.
pose_congestion = "block"
[robots.default]
model = "ur10e"

[[sources]]   # rmw_zenoh, any namespace depth
key = "0/**/joint_states/sensor_msgs::msg::dds_::JointState_/*"
codec = "ros2"
stream = "joints"
scheme = "rmw_zenoh"
robot_from_key = "ros2_namespace"
[[sources]]
key = "0/**/tcp_pose_broadcaster/pose/geometry_msgs::msg::dds_::PoseStamped_/*"
codec = "ros2"
stream = "measured"
scheme = "rmw_zenoh"
robot_from_key = "ros2_namespace"

[[sources]]   # the bridge, one namespace chunk
key = "*/joint_states"
codec = "ros2"
stream = "joints"
scheme = "bridge"
robot_from_key = "ros2_namespace"
[[sources]]
key = "*/tcp_pose_broadcaster/pose"
codec = "ros2"
stream = "measured"
scheme = "bridge"
robot_from_key = "ros2_namespace"

[[sources]]   # the bridge, a driver without namespace
key = "joint_states"
codec = "ros2"
stream = "joints"
scheme = "bridge"
robot = "solo"
"#;

/// The twin pose out as `PoseStamped`: every robot on `rmw_zenoh` keys, one on the bridge's with
/// its own frame prefix, one in `base_link`, one with it off.
pub const OUTPUT_CONFIG: &str = r#"
[service]
metrics_period_ms = 50
# Every pose is counted: a client that falls behind slows the twin instead of missing poses.
pose_congestion = "block"
[robots.default]
model = "ur10e"
[robots.default.ros2_pose]     # every robot: rmw_zenoh, namespace = robot id
scheme = "rmw_zenoh"
tf_prefix = "alice_"
[robots.bob]
[robots.bob.ros2_pose]
scheme = "bridge"
tf_prefix = ""
[robots.bl]
frame = "base_link"
[robots.quiet.ros2_pose]
enabled = false
"#;
