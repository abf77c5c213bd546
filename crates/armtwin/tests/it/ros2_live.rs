//! ROS 2 robots live: `[[sources]]` on `rmw_zenoh` and bridge keys (robots from namespaces or
//! fixed), `rmw_zenoh` attachments, the twin pose as a `PoseStamped` for ROS tools, and the
//! configurations refused at load time. Real Zenoh sessions over TCP loopback, one in-process
//! `serve`; messages from the MCAP bag `rosbags` wrote, attachments from zenoh-ext's serializer.
#![allow(clippy::float_cmp, reason = "decoded values are copied, not computed")]

use crate::common::{Outputs, RECEIVE_LIMIT, Service, connect_client, wait_for_subscriber};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use armtwin::codec::cdr;
use armtwin::codec::json::MetricsMessage;
use armtwin::config::{Overrides, ServiceConfig, SourceRobot};
use armtwin::ros2::{self, Attachment, AttachmentError, KeyScheme, NamespaceRule};
use armtwin::rosbag::{self, BagOptions};
use armtwin::service::ServeReport;
use armtwin::validate::validate;
use serde_json::{Value, json};
use zenoh::Session;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;
use zenoh_ext::ZSerializer;

/// Every test must end by itself within this time.
const TEST_LIMIT: Duration = Duration::from_secs(120);

const JOINT_TYPE: &str = ros2::JOINT_STATE_DDS_TYPE;
const POSE_TYPE: &str = ros2::POSE_STAMPED_DDS_TYPE;

fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/ros2")
}

fn parse(config_toml: &str, listen: Vec<String>) -> Result<ServiceConfig, String> {
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
fn bag_messages() -> (Vec<Vec<u8>>, Vec<Vec<u8>>) {
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
fn attachment(sequence_number: i64, source_timestamp_ns: i64, gid: &[u8]) -> Vec<u8> {
    let mut serializer = ZSerializer::new();
    serializer.serialize(sequence_number);
    serializer.serialize(source_timestamp_ns);
    serializer.serialize(gid);
    serializer.finish().to_bytes().into_owned()
}

/// The keyed form of early `rmw_zenoh` releases (each value after its name).
fn keyed_attachment(sequence_number: i64, source_timestamp_ns: i64, gid: &[u8]) -> Vec<u8> {
    let mut serializer = ZSerializer::new();
    serializer.serialize("sequence_number");
    serializer.serialize(sequence_number);
    serializer.serialize("source_timestamp");
    serializer.serialize(source_timestamp_ns);
    serializer.serialize("source_gid");
    serializer.serialize(gid);
    serializer.finish().to_bytes().into_owned()
}

struct Harness {
    service: Service,
    client: Session,
    outputs: Outputs,
}

/// The service on `config_toml`, and a client connected to it whose publishers on
/// `probe_keys` are matched by the service's subscribers.
async fn start(config_toml: &str, probe_keys: &[&str]) -> Harness {
    let service = Service::start(|endpoint| {
        parse(config_toml, vec![endpoint.to_owned()]).expect("valid test config")
    })
    .await;
    let (client, outputs) = connect_client(&service.endpoint).await;
    for key in probe_keys {
        wait_for_subscriber(&client, key).await;
    }
    let harness = Harness {
        service,
        client,
        outputs,
    };
    harness.round_trip().await;
    harness
}

impl Harness {
    /// A state query: answered after everything the client sent before it (one ordered link).
    async fn round_trip(&self) -> Vec<String> {
        let replies = self.client.get("twin/state/**").await.expect("get");
        let mut robots = Vec::new();
        while let Ok(reply) = tokio::time::timeout(RECEIVE_LIMIT, replies.recv_async())
            .await
            .expect("answered")
        {
            let sample = reply.result().expect("state");
            let state: Value = serde_json::from_slice(&sample.payload().to_bytes()).expect("json");
            robots.push(state["robot"].as_str().expect("robot").to_owned());
        }
        robots.sort();
        robots
    }

    async fn put(&self, key: &str, payload: &[u8], attachment: Option<Vec<u8>>) {
        self.client
            .put(key, payload.to_vec())
            .attachment(attachment)
            .await
            .expect("put");
    }

    async fn receive_until(&mut self, what: &str, done: impl Fn(&[(String, Value)]) -> bool) {
        self.outputs.receive_until(what, done).await;
    }

    fn on(&self, key: &str) -> Vec<&Value> {
        self.outputs.on(key)
    }

    fn last_metrics(&self, robot: &str) -> Option<&Value> {
        self.on(&format!("twin/metrics/{robot}")).last().copied()
    }

    async fn stop(&mut self) -> ServeReport {
        self.service.stop().await
    }
}

const NAMESPACE_SOURCES: &str = r#"
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[allow(clippy::too_many_lines, reason = "one scenario, in the order it runs")]
async fn ros2_namespaces_name_robots_under_both_key_schemes() {
    tokio::time::timeout(TEST_LIMIT, async {
        let rmw_joints = format!(
            "0/plant_a/cell_3/ur7/joint_states/{JOINT_TYPE}/{}",
            ros2::JOINT_STATE_TYPE_HASH
        );
        let rmw_poses = format!(
            "0/plant_a/cell_3/ur7/tcp_pose_broadcaster/pose/{POSE_TYPE}/{}",
            ros2::POSE_STAMPED_TYPE_HASH
        );
        let mut h = start(
            NAMESPACE_SOURCES,
            &[
                &rmw_joints,
                &rmw_poses,
                "bob/joint_states",
                "bob/tcp_pose_broadcaster/pose",
                "joint_states",
            ],
        )
        .await;
        let (joints, poses) = bag_messages();
        let gid = [3_u8; 16];
        for (i, (joint, pose)) in joints.iter().zip(&poses).enumerate() {
            let seq = i64::try_from(i).unwrap() + 1;
            h.put(&rmw_joints, joint, Some(attachment(seq, 1, &gid)))
                .await;
            h.put(&rmw_poses, pose, Some(attachment(seq, 1, &gid)))
                .await;
            h.put("bob/joint_states", joint, None).await;
            h.put("bob/tcp_pose_broadcaster/pose", pose, None).await;
            h.put("joint_states", joint, None).await;
        }
        // Keys that name no robot: the root namespace under a namespace rule, another type.
        h.put(
            &format!("0/joint_states/{JOINT_TYPE}/RIHS01_0"),
            &joints[0],
            None,
        )
        .await;
        h.put(
            "0/eve/joint_states/sensor_msgs::msg::dds_::Imu_/RIHS01_0",
            &joints[0],
            None,
        )
        .await;
        let robots = h.round_trip().await;
        assert_eq!(robots, ["bob", "plant_a/cell_3/ur7", "solo"]);
        h.receive_until("all metrics", |r| {
            let paired = |robot: &str| {
                r.iter()
                    .rev()
                    .find(|(k, _)| k == &format!("twin/metrics/{robot}"))
                    .map(|(_, m)| m["paired"].as_u64())
            };
            paired("plant_a/cell_3/ur7") == Some(Some(400))
                && paired("bob") == Some(Some(400))
                && r.iter().filter(|(k, _)| k == "twin/pose/solo").count() == 400
        })
        .await;
        // The bag validated offline: the live ROS 2 path gives its metrics to the last bit.
        let bag = rosbag::read(
            &data().join("ur10e_lasttest_head_mcap"),
            &BagOptions::default(),
        )
        .expect("bag");
        let config = parse(NAMESPACE_SOURCES, Vec::new()).expect("config");
        let times = armtwin::codec::recording::source_times(&bag.recording, None);
        let offline = validate(
            &bag.recording,
            &times,
            config.pipeline,
            config.default_robot.clone().expect("default"),
            |_| {},
        );
        let offline_gaps = offline.events.gaps;
        assert!(offline_gaps > 0);
        let offline = serde_json::to_value(MetricsMessage::new(&offline.metrics)).expect("json");
        for robot in ["plant_a/cell_3/ur7", "bob"] {
            let live = h.last_metrics(robot).expect("metrics");
            for field in ["paired", "unpaired", "rejected", "cumulative", "window"] {
                assert_eq!(live[field], offline[field], "{robot}: {field}");
            }
            assert_eq!(h.on(&format!("twin/pose/{robot}")).len(), 400);
            assert_eq!(h.on(&format!("twin/deviation/{robot}")).len(), 400);
            // The bag's own stamp gaps (its CSV's whole-second stamps spread over each second),
            // as offline, and nothing else.
            let kinds: Vec<&str> = h
                .on(&format!("twin/events/{robot}"))
                .iter()
                .map(|e| e["kind"].as_str().unwrap())
                .collect();
            assert_eq!(kinds, vec!["gap"; offline_gaps as usize], "{robot}");
        }
        // Poses at the messages' header stamps, equal across the schemes and the fixed robot.
        for ((a, b), c) in h
            .on("twin/pose/bob")
            .iter()
            .zip(h.on("twin/pose/plant_a/cell_3/ur7"))
            .zip(h.on("twin/pose/solo"))
        {
            for field in ["t", "x", "y", "z", "qx", "qy", "qz", "qw"] {
                assert_eq!(a[field], b[field]);
                assert_eq!(a[field], c[field]);
            }
        }
        let first =
            cdr::decode_joint_state(&joints[0], &cdr::JointNames::ur(""), None).expect("decodes");
        assert_eq!(h.on("twin/pose/bob")[0]["t"].as_f64(), first.stamp_s);
        h.stop().await;
    })
    .await
    .expect("test finished in time");
}

const ATTACHMENT_SOURCES: &str = r#"
[service]
metrics_period_ms = 50
# Every pose is counted: a client that falls behind slows the twin instead of missing poses.
pose_congestion = "block"
[robots.default]
model = "ur10e"
[[sources]]   # a driver without namespace, on rmw_zenoh
key = "0/joint_states/sensor_msgs::msg::dds_::JointState_/*"
codec = "ros2"
stream = "joints"
scheme = "rmw_zenoh"
robot = "r1"
[[sources]]
key = "0/tcp_pose_broadcaster/pose/geometry_msgs::msg::dds_::PoseStamped_/*"
codec = "ros2"
stream = "measured"
scheme = "rmw_zenoh"
robot = "r1"
tf_prefix = "alice_"
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[allow(clippy::too_many_lines, reason = "one scenario, in the order it runs")]
async fn rmw_sequence_numbers_raise_gaps_refuse_repeats_and_survive_damage_and_restarts() {
    tokio::time::timeout(TEST_LIMIT, async {
        let joints_key = format!(
            "0/joint_states/{JOINT_TYPE}/{}",
            ros2::JOINT_STATE_TYPE_HASH
        );
        let poses_key = format!(
            "0/tcp_pose_broadcaster/pose/{POSE_TYPE}/{}",
            ros2::POSE_STAMPED_TYPE_HASH
        );
        let mut h = start(ATTACHMENT_SOURCES, &[&joints_key, &poses_key]).await;
        let (joints, poses) = bag_messages();
        let (gid_a, gid_b) = ([1_u8; 16], [2_u8; 24]);
        // (the bag's message, its attachment)
        let plan: Vec<(usize, Option<Vec<u8>>)> = vec![
            (0, Some(attachment(1, 5, &gid_a))),
            (1, Some(attachment(2, 5, &gid_a))),
            (2, Some(attachment(3, 5, &gid_a))),
            (3, Some(attachment(5, 5, &gid_a))), // 4 lost upstream: a gap
            (3, Some(attachment(5, 5, &gid_a))), // resent, same stamp: refused
            (5, Some(attachment(6, 5, &gid_a)[..20].to_vec())), // cut: rejected, the sample taken
            (6, Some(attachment(1, 5, &gid_b))), // the driver restarted: a 24-byte gid, from 1 again
            (7, Some(attachment(2, 5, &gid_b))),
            (8, Some(keyed_attachment(3, 5, &gid_b))),
            (9, None),
        ];
        for (index, attachment) in plan {
            h.put(&joints_key, &joints[index], attachment).await;
        }
        // Damaged messages (written by rosbags, then cut or patched): each refused with its cause.
        let fixture = |name: &str| std::fs::read(data().join(name)).expect("fixture");
        h.put(&joints_key, &fixture("joint_state_truncated.cdr"), None)
            .await;
        h.put(&joints_key, &fixture("joint_state_missing_joint.cdr"), None)
            .await;
        h.put(&joints_key, &fixture("joint_state_xcdr2_header.cdr"), None)
            .await;
        h.put(&joints_key, &fixture("joint_state_huge_count.cdr"), None)
            .await;
        // The bag's first pose, in the frame of the robot's tf_prefix (paired), and as recorded,
        // in `base` (refused: not `alice_base`).
        let recorded = cdr::decode_pose_stamped(&poses[0]).expect("decodes");
        let stamp_s = recorded.sample.stamp_s.expect("stamped");
        let in_alice_base = cdr::encode_pose_stamped(stamp_s, "alice_base", &recorded.sample.pose);
        h.put(&poses_key, &in_alice_base, None).await;
        h.put(&poses_key, &poses[0], None).await;
        h.round_trip().await;
        h.receive_until("final metrics", |r| {
            r.iter()
                .rev()
                .find(|(k, _)| k == "twin/metrics/r1")
                .is_some_and(|(_, m)| m["rejected"] == 7 && m["paired"] == 1)
        })
        .await;
        assert_eq!(h.on("twin/pose/r1").len(), 9, "every sample but the repeat");
        let events: Vec<(String, Value)> = h
            .on("twin/events/r1")
            .iter()
            .map(|e| (e["kind"].as_str().unwrap().to_owned(), e["detail"].clone()))
            .collect();
        let causes: Vec<&str> = events
            .iter()
            .filter_map(|(_, d)| d["cause"].as_str())
            .collect();
        assert_eq!(
            causes,
            [
                "duplicate_stamp",
                "attachment",
                "cdr_truncated",
                "missing_joint",
                "cdr_header",
                "cdr_malformed",
                "frame_id"
            ]
        );
        let gaps: Vec<&Value> = events
            .iter()
            .filter(|(kind, _)| kind == "gap")
            .map(|(_, d)| d)
            .collect();
        assert_eq!(
            gaps,
            [&json!({"expected": 4, "got": 5})],
            "one gap; the restart is none"
        );
        assert!(
            events.iter().all(|(kind, _)| kind != "restart"),
            "a new publisher's numbers carry on from the previous one's: {events:?}"
        );
        let attachment_event = h
            .on("twin/events/r1")
            .into_iter()
            .find(|e| e["detail"]["cause"] == "attachment")
            .unwrap();
        assert!(
            attachment_event["reason"]
                .as_str()
                .unwrap()
                .contains("ends inside"),
            "{attachment_event}"
        );
        assert_eq!(attachment_event["key"], joints_key.as_str());
        let missing = h
            .on("twin/events/r1")
            .into_iter()
            .find(|e| e["detail"]["cause"] == "missing_joint")
            .unwrap();
        // Reported at the refused message's own header stamp.
        assert_eq!(missing["t"], 1_748_954_669.25);
        h.stop().await;
    })
    .await
    .expect("test finished in time");
}

const OUTPUT_CONFIG: &str = r#"
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

/// The twin poses of a robot as `PoseStamped` samples: payload and attachment.
type RosSamples = Subscriber<FifoChannelHandler<Sample>>;

async fn drain(subscriber: &RosSamples, n: usize) -> Vec<(String, Vec<u8>, Option<Vec<u8>>)> {
    let mut out = Vec::new();
    while out.len() < n {
        let sample = tokio::time::timeout(RECEIVE_LIMIT, subscriber.recv_async())
            .await
            .expect("a PoseStamped in time")
            .expect("open");
        out.push((
            sample.key_expr().as_str().to_owned(),
            sample.payload().to_bytes().into_owned(),
            sample.attachment().map(|a| a.to_bytes().into_owned()),
        ));
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_twin_pose_goes_out_as_pose_stamped_for_ros_tools() {
    tokio::time::timeout(TEST_LIMIT, async {
        let mut h = start(OUTPUT_CONFIG, &["twin/joints/ur"]).await;
        let rmw = h
            .client
            .declare_subscriber("0/**")
            .with(zenoh::handlers::FifoChannel::new(10_000))
            .await
            .expect("sub");
        let bridge = h
            .client
            .declare_subscriber("bob/**")
            .with(zenoh::handlers::FifoChannel::new(10_000))
            .await
            .expect("sub");
        h.round_trip().await;
        let started_ns = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap()
            .as_nanos() as i64;
        let n = 20_usize;
        for robot in ["ur", "bob", "bl", "quiet"] {
            for i in 0..n {
                let q = [-0.7 + 0.01 * i as f64, -0.8, 0.9, 1.1, 1.5, 1.7];
                let message = json!({"t": 1_748_954_669.0 + 0.002 * i as f64, "q": q});
                h.put(
                    &format!("twin/joints/{robot}"),
                    message.to_string().as_bytes(),
                    None,
                )
                .await;
            }
        }
        h.round_trip().await;
        h.receive_until("every pose", |r| {
            ["ur", "bob", "bl", "quiet"].iter().all(|robot| {
                r.iter()
                    .filter(|(k, _)| k == &format!("twin/pose/{robot}"))
                    .count()
                    == 20
            })
        })
        .await;
        let from_rmw = drain(&rmw, 2 * n).await;
        let from_bridge = drain(&bridge, n).await;
        let key_of = |robot: &str| {
            format!(
                "0/{robot}/armtwin/tcp_pose/{POSE_TYPE}/{}",
                ros2::POSE_STAMPED_TYPE_HASH
            )
        };
        let keys: BTreeSet<&str> = from_rmw.iter().map(|(k, _, _)| k.as_str()).collect();
        assert_eq!(
            keys,
            BTreeSet::from([key_of("ur").as_str(), key_of("bl").as_str()]),
            "quiet has none, bob its bridge key"
        );
        for (robot, frame) in [
            ("ur", "alice_base"),
            ("bl", "alice_base_link"),
            ("bob", "base"),
        ] {
            let samples: Vec<_> = from_rmw
                .iter()
                .chain(&from_bridge)
                .filter(|(k, _, _)| {
                    *k == key_of(robot) || (robot == "bob" && k == "bob/armtwin/tcp_pose")
                })
                .collect();
            let json_poses = h.on(&format!("twin/pose/{robot}"));
            assert_eq!(samples.len(), json_poses.len(), "{robot}");
            let mut gids = BTreeSet::new();
            for (i, ((_, payload, attachment), json_pose)) in
                samples.iter().zip(&json_poses).enumerate()
            {
                let pose = cdr::decode_pose_stamped(payload).expect("a PoseStamped");
                assert_eq!(pose.frame_id, frame);
                assert_eq!(pose.sample.stamp_s, json_pose["t"].as_f64(), "{robot} #{i}");
                let [x, y, z] = pose.sample.pose.position_m;
                assert_eq!(
                    [x, y, z],
                    [
                        json_pose["x"].as_f64().unwrap(),
                        json_pose["y"].as_f64().unwrap(),
                        json_pose["z"].as_f64().unwrap()
                    ]
                );
                assert_eq!(pose.xyzw_as_sent[3], json_pose["qw"].as_f64().unwrap());
                if robot == "bob" {
                    assert!(attachment.is_none(), "bridge form: no attachment");
                    continue;
                }
                let bytes = zenoh::bytes::ZBytes::from(
                    attachment.clone().expect("rmw_zenoh form: attachment"),
                );
                let (seq, stamp_ns, gid): (i64, i64, [u8; 16]) =
                    zenoh_ext::z_deserialize(&bytes).expect("i64, i64, 16-byte gid");
                assert_eq!(
                    seq,
                    i64::try_from(i).unwrap() + 1,
                    "{robot}: seq from 1, increasing"
                );
                assert!(stamp_ns >= started_ns, "{robot}: publication time");
                gids.insert(gid);
            }
            if robot != "bob" {
                assert_eq!(gids.len(), 1, "{robot}: one fixed gid");
            }
        }
        let gid_of = |robot: &str| {
            let (_, _, attachment) = from_rmw
                .iter()
                .find(|(k, _, _)| *k == key_of(robot))
                .unwrap();
            Attachment::parse(attachment.as_ref().unwrap())
                .unwrap()
                .gid()
                .to_vec()
        };
        assert_ne!(gid_of("ur"), gid_of("bl"), "a gid per robot");
        h.stop().await;
    })
    .await
    .expect("test finished in time");
}

#[test]
fn attachments_read_in_both_forms_and_every_damage_is_named() {
    for gid in [&[9_u8; 16][..], &[8_u8; 24][..]] {
        for bytes in [
            attachment(42, 1_700_000_000_123_456_789, gid),
            keyed_attachment(42, 1_700_000_000_123_456_789, gid),
        ] {
            let parsed = Attachment::parse(&bytes).expect("an rmw_zenoh attachment");
            assert_eq!(parsed.sequence_number, 42);
            assert_eq!(parsed.source_timestamp_ns, 1_700_000_000_123_456_789);
            assert_eq!(parsed.gid(), gid);
            assert_eq!(
                parsed.source_timestamp_s(),
                Some(1_700_000_000.0 + 123_456_789.0 * 1e-9)
            );
        }
    }
    let good = attachment(7, 1, &[1; 16]);
    assert_eq!(good.len(), 33);
    assert_eq!(
        good,
        ros2::encode_attachment(7, 1, &[1; 16]),
        "armtwin writes what zenoh-ext writes"
    );
    for cut in 0..good.len() {
        let error = Attachment::parse(&good[..cut]).unwrap_err();
        assert!(
            matches!(error, AttachmentError::Truncated { .. }),
            "cut at {cut}: {error}"
        );
    }
    let mut trailing = good.clone();
    trailing.push(0);
    assert_eq!(
        Attachment::parse(&trailing),
        Err(AttachmentError::Trailing { extra: 1 })
    );
    assert_eq!(
        Attachment::parse(&attachment(7, 1, &[1; 25])),
        Err(AttachmentError::GidLength { length: 25 })
    );
    assert_eq!(
        Attachment::parse(&attachment(-1, 1, &[1; 16])),
        Err(AttachmentError::NegativeSequence {
            sequence_number: -1
        })
    );
    // A gid length of 2^63: refused before anything of that size is looked at.
    let mut huge = good[..16].to_vec();
    huge.extend_from_slice(&[0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0x7f]);
    assert!(matches!(
        Attachment::parse(&huge),
        Err(AttachmentError::GidLength { .. })
    ));
    let mut overlong = good[..16].to_vec();
    overlong.extend_from_slice(&[0xff; 11]);
    assert!(matches!(
        Attachment::parse(&overlong),
        Err(AttachmentError::Length { .. })
    ));
    let mut wrong_key = keyed_attachment(7, 1, &[1; 16]);
    let at = wrong_key.windows(6).position(|w| w == b"source").unwrap();
    wrong_key[at] = b'S';
    assert!(matches!(
        Attachment::parse(&wrong_key),
        Err(AttachmentError::Key {
            expected: "source_timestamp",
            ..
        })
    ));
    assert!(matches!(
        Attachment::parse(&[0; 300]),
        Err(AttachmentError::TooLarge { bytes: 300 })
    ));
    assert_eq!(
        Attachment::parse(&attachment(7, 0, &[]))
            .unwrap()
            .source_timestamp_s(),
        None
    );
}

#[test]
fn namespace_rules_read_robots_of_both_layouts() {
    let rmw = NamespaceRule::new(KeyScheme::RmwZenoh, "/joint_states", JOINT_TYPE).unwrap();
    let hash = ros2::JOINT_STATE_TYPE_HASH;
    for (key, robot) in [
        (format!("0/ur/joint_states/{JOINT_TYPE}/{hash}"), Some("ur")),
        (
            format!("12/a/b/c/joint_states/{JOINT_TYPE}/TypeHashNotSupported"),
            Some("a/b/c"),
        ),
        (format!("0/joint_states/{JOINT_TYPE}/{hash}"), None),
        (format!("0/ur/my_joint_states/{JOINT_TYPE}/{hash}"), None),
        (format!("0/ur/joint_states/extra/{JOINT_TYPE}/{hash}"), None),
        (format!("0/ur/joint_states/{POSE_TYPE}/{hash}"), None),
        (format!("x/ur/joint_states/{JOINT_TYPE}/{hash}"), None),
        (format!("0/ur/joint_states/{JOINT_TYPE}"), None),
        ("ur/joint_states".to_owned(), None),
    ] {
        assert_eq!(rmw.robot_of(&key), robot, "{key}");
    }
    let bridge =
        NamespaceRule::new(KeyScheme::Bridge, "tcp_pose_broadcaster/pose", POSE_TYPE).unwrap();
    for (key, robot) in [
        ("ur/tcp_pose_broadcaster/pose", Some("ur")),
        ("site/bot1/tcp_pose_broadcaster/pose", Some("site/bot1")),
        ("tcp_pose_broadcaster/pose", None),
        ("ur/pose", None),
        ("ur/x_tcp_pose_broadcaster/pose", None),
    ] {
        assert_eq!(bridge.robot_of(key), robot, "{key}");
    }
}

#[test]
fn sources_that_cannot_work_are_refused_at_load_time() {
    let source = |fields: &str| format!("[[sources]]\n{fields}\n");
    let ros2_joints = "key = \"0/**/joint_states/**\"\ncodec = \"ros2\"\nstream = \"joints\"\n";
    let cases = [
        (
            source("key = \"a/b\"\ncodec = \"json\"\nstream = \"joints\""),
            "sources[0]: needs robot = \"<id>\"",
        ),
        (
            source(&format!("{ros2_joints}robot = \"r\"")),
            "sources[0].scheme: codec = \"ros2\" needs scheme",
        ),
        (
            source(&format!(
                "{ros2_joints}scheme = \"rmw_zenoh\"\nrobot = \"r\"\nrobot_from_key = \"ros2_namespace\""
            )),
            "robot and robot_from_key exclude each other",
        ),
        (
            source(
                "key = \"a/b\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"r\"\ntf_prefix = \"x_\"",
            ),
            "sources[0].tf_prefix: is read only with codec = \"ros2\"",
        ),
        (
            source(
                "key = \"a/b\"\ncodec = \"json\"\nstream = \"joints\"\nrobot_from_key = \"ros2_namespace\"",
            ),
            "sources[0].robot_from_key: is read only with codec = \"ros2\"",
        ),
        (
            source("key = \"twin/**\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"r\""),
            "intersects armtwin's own 'twin/pose/**'",
        ),
        (
            source(
                "key = \"a/**\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"r\"\n[[sources]]\nkey = \"a/b\"\ncodec = \"json\"\nstream = \"measured\"\nrobot = \"r\"",
            ),
            "sources[1].key: 'a/b' intersects sources[0].key 'a/**'",
        ),
        (
            source(
                "key = \"a/b/c\"\ncodec = \"ros2\"\nstream = \"joints\"\nscheme = \"bridge\"\nrobot_from_key = \"ros2_namespace\"",
            ),
            "never carries topic '/joint_states' under a namespace in the bridge layout",
        ),
        (
            source(
                "key = \"joint_states\"\ncodec = \"ros2\"\nstream = \"joints\"\nscheme = \"bridge\"\nrobot_from_key = \"ros2_namespace\"",
            ),
            "never carries topic '/joint_states'",
        ),
        (
            source(&format!(
                "{ros2_joints}scheme = \"rmw_zenoh\"\nrobot_from_key = \"ros2_namespace\"\ntopic = \"joint-states\""
            )),
            "sources[0].topic: 'joint-states' is not a ROS name",
        ),
        (
            source(&format!(
                "{ros2_joints}scheme = \"rmw_zenoh\"\nrobot = \"r\"\ntopic = \"/joint_states\""
            )),
            "sources[0].topic: is read only with robot_from_key",
        ),
        (
            source(&format!(
                "{ros2_joints}scheme = \"rmw_zenoh\"\nrobot = \"a/*\""
            )),
            "'a/*' is not a robot id",
        ),
        (
            format!(
                "[service]\nreject_unknown = true\n{}",
                source(&format!(
                    "{ros2_joints}scheme = \"rmw_zenoh\"\nrobot = \"r\""
                ))
            ),
            "robot 'r' is not configured and service.reject_unknown is true",
        ),
        (
            format!(
                "[robots.r]\nmodel = \"../../config/examples/franka-panda.toml\"\n{}",
                source(&format!(
                    "{ros2_joints}scheme = \"rmw_zenoh\"\nrobot = \"r\""
                ))
            ),
            "6 joint names for robot 'r', whose arm has 7 joints",
        ),
        (
            source(
                "key = \"0/**/tcp_pose_broadcaster/pose/**\"\ncodec = \"ros2\"\nstream = \"measured\"\nscheme = \"bridge\"\nrobot = \"r\"\njoint_names = [\"a\"]",
            ),
            "sources[0].joint_names: is read only with stream = \"joints\"",
        ),
        (
            source(
                "key = \"0/**/tcp_pose_broadcaster/pose/**\"\ncodec = \"ros2\"\nstream = \"measured\"\nscheme = \"bridge\"\nrobot = \"r\"\neffort = \"current_a\"",
            ),
            "sources[0].effort: is read only with stream = \"joints\"",
        ),
        (
            source("key = \"a/b\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"r\"\neffort = \"torque_nm\""),
            "sources[0].effort: is read only with codec = \"ros2\"",
        ),
        (
            source(&format!(
                "{ros2_joints}scheme = \"bridge\"\nrobot = \"r\"\neffort = \"amperes\""
            )),
            "unknown variant `amperes`, expected `current_a` or `torque_nm`",
        ),
        (
            source("key = \"a/b\"\ncodec = \"ros3\"\nstream = \"joints\"\nrobot = \"r\""),
            "unknown variant `ros3`",
        ),
        (
            format!(
                "[robots.default.ros2_pose]\nscheme = \"rmw_zenoh\"\n{}",
                source("key = \"0/**\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"r\"")
            ),
            "intersects the twin pose output '0/**/armtwin/tcp_pose/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_10f3",
        ),
        (
            "[robots.r]\n[[robots.r.sensors]]\nkey_expr = \"0/x\"\n[robots.default.ros2_pose]\nscheme = \"bridge\"\ntopic = \"x\"\n"
                .to_owned(),
            "robots.\"r\".sensors[0].key_expr: '0/x' intersects the twin pose output '**/x'",
        ),
        (
            "[robots.default.ros2_pose]\ntf_prefix = \"a_\"\n".to_owned(),
            "robots.\"default\".ros2_pose.scheme: is needed",
        ),
        (
            "[robots.default.ros2_pose]\nscheme = \"bridge\"\nnamespace = \"ur\"\n".to_owned(),
            "robots.default.ros2_pose.namespace: would give every robot the same key",
        ),
        (
            "[robots.r.ros2_pose]\nscheme = \"bridge\"\nnamespace = \"u-r\"\n".to_owned(),
            "robots.\"r\".ros2_pose.namespace: 'u-r' is not a ROS name",
        ),
    ];
    for (text, expected) in cases {
        let error = parse(&text, Vec::new()).expect_err(&text);
        assert!(
            error.contains(expected),
            "{text}\n→ {error}\nexpected: {expected}"
        );
    }
    // What works: both schemes, both robot rules, the UR driver's topics by default.
    let config = parse(NAMESPACE_SOURCES, Vec::new()).expect("valid");
    assert_eq!(config.sources.len(), 5);
    let SourceRobot::FromKey(rule) = &config.sources[1].robot else {
        panic!("a rule")
    };
    assert_eq!(rule.topic(), "tcp_pose_broadcaster/pose");
    assert_eq!(
        config.sources[4].robot,
        SourceRobot::Fixed("solo".to_owned())
    );
    let config = parse(OUTPUT_CONFIG, Vec::new()).expect("valid");
    assert_eq!(
        config.ros2_pose.of("anyone").unwrap().key("anyone"),
        format!(
            "0/anyone/armtwin/tcp_pose/{POSE_TYPE}/{}",
            ros2::POSE_STAMPED_TYPE_HASH
        )
    );
    assert_eq!(
        config.ros2_pose.of("bob").unwrap().key("bob"),
        "bob/armtwin/tcp_pose"
    );
    assert_eq!(
        config.ros2_pose.of("bob").unwrap().tf_prefix,
        "",
        "the robot's own field wins"
    );
    assert_eq!(
        config.ros2_pose.of("bl").unwrap().tf_prefix,
        "alice_",
        "the default's fills in"
    );
    assert!(config.ros2_pose.of("quiet").is_none());
}

/// The `toml` block of README.md after `marker`.
fn readme_toml(marker: &str) -> String {
    let readme = std::fs::read_to_string(data().join("../../../README.md")).expect("README");
    let after = &readme[readme.find(marker).expect("marker")..];
    let block = &after[after.find("```toml\n").expect("a toml block") + 8..];
    block[..block.find("```").expect("its end")].to_owned()
}

#[test]
fn the_readme_recipes_load_as_documented() {
    let block = readme_toml("The exact lines for a UR driver");
    let recipes: Vec<&str> = block.split("\n\n").collect();
    assert_eq!(recipes.len(), 4, "{block}");
    for (recipe, from_key) in recipes.iter().zip([true, false, true, false]) {
        let config = parse(recipe, Vec::new()).unwrap_or_else(|e| panic!("{recipe}\n→ {e}"));
        assert_eq!(config.sources.len(), 2);
        for source in &config.sources {
            assert_eq!(
                matches!(source.robot, SourceRobot::FromKey(_)),
                from_key,
                "{recipe}"
            );
        }
        let prefixed = recipe.replace(
            "codec = \"ros2\"",
            "codec = \"ros2\"\ntf_prefix = \"alice_\"",
        );
        let config = parse(&prefixed, Vec::new()).expect("with a tf_prefix");
        let ros2 = config.sources[1].ros2.as_ref().expect("ros2");
        assert_eq!(ros2.base_frame, "alice_base");
    }
    // As the README says: the two bridge recipes combine, the two rmw_zenoh ones do not.
    parse(&format!("{}\n{}", recipes[2], recipes[3]), Vec::new()).expect("bridge forms combine");
    let error = parse(&format!("{}\n{}", recipes[0], recipes[1]), Vec::new()).unwrap_err();
    assert!(error.contains("a sample would be taken twice"), "{error}");
    let pose = readme_toml("**The twin in RViz.**");
    let config = parse(&pose, Vec::new()).expect("the ros2_pose example");
    let fixed = config.ros2_pose.of("ur10e-07").expect("output");
    assert_eq!(
        fixed.key("ur10e-07"),
        format!(
            "0/armtwin/tcp_pose/{POSE_TYPE}/{}",
            ros2::POSE_STAMPED_TYPE_HASH
        )
    );
    assert_eq!(
        config
            .ros2_pose
            .of("plant_a/ur7")
            .expect("output")
            .key("plant_a/ur7"),
        format!(
            "0/plant_a/ur7/armtwin/tcp_pose/{POSE_TYPE}/{}",
            ros2::POSE_STAMPED_TYPE_HASH
        )
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_namespace_that_is_no_known_robot_is_rejected_at_its_header_stamp() {
    tokio::time::timeout(TEST_LIMIT, async {
        let config = r#"
[service]
reject_unknown = true
[robots.ur7]
model = "ur10e"
[[sources]]
key = "0/**/joint_states/sensor_msgs::msg::dds_::JointState_/*"
codec = "ros2"
stream = "joints"
scheme = "rmw_zenoh"
robot_from_key = "ros2_namespace"
"#;
        let key = |namespace: &str| {
            format!(
                "0/{namespace}/joint_states/{JOINT_TYPE}/{}",
                ros2::JOINT_STATE_TYPE_HASH
            )
        };
        let mut h = start(config, &[&key("ur7")]).await;
        let (joints, _) = bag_messages();
        h.put(&key("ur7"), &joints[0], None).await;
        h.put(&key("stranger"), &joints[0], None).await;
        h.round_trip().await;
        h.receive_until("the rejection", |r| {
            r.iter().any(|(k, _)| k == "twin/events/stranger")
                && r.iter().any(|(k, _)| k == "twin/pose/ur7")
        })
        .await;
        let stamp_s = cdr::decode_joint_state(&joints[0], &cdr::JointNames::ur(""), None)
            .unwrap()
            .stamp_s;
        let event = h.on("twin/events/stranger")[0];
        assert_eq!(event["detail"]["cause"], "unknown_robot");
        assert_eq!(event["t"].as_f64(), stamp_s);
        assert_eq!(h.round_trip().await, ["ur7"]);
        h.stop().await;
    })
    .await
    .expect("test finished in time");
}

/// The `rmw_zenoh` type hashes armtwin writes into keys are the ones real rclpy reports for a
/// live publisher (`topic_type_hash`, captured by `tools/capture_rclpy_fixtures.py`; the
/// bridge test asserts the live value against the same file).
#[test]
fn type_hashes_are_the_ones_rclpy_reports() {
    let text = std::fs::read_to_string(data().join("rclpy/type_hashes.json")).expect("file");
    let hashes: Value = serde_json::from_str(&text).expect("JSON");
    assert_eq!(
        hashes["sensor_msgs/msg/JointState"],
        ros2::JOINT_STATE_TYPE_HASH
    );
    assert_eq!(
        hashes["geometry_msgs/msg/PoseStamped"],
        ros2::POSE_STAMPED_TYPE_HASH
    );
}
