//! ROS 2 robots live: `[[sources]]` on `rmw_zenoh` and bridge keys (robots from namespaces or
//! fixed), `rmw_zenoh` attachments, and the twin pose as a `PoseStamped` for ROS tools. Real
//! Zenoh sessions over TCP loopback, one in-process `serve`; messages from the MCAP bag `rosbags`
//! wrote, attachments from zenoh-ext's serializer.
#![allow(clippy::float_cmp, reason = "decoded values are copied, not computed")]

use crate::common::{Harness, RECEIVE_LIMIT};
use crate::ros2_fixtures::{
    JOINT_TYPE, NAMESPACE_SOURCES, OUTPUT_CONFIG, POSE_TYPE, attachment, bag_messages, data,
    keyed_attachment, parse,
};
use std::collections::BTreeSet;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use armtwin_codec::cdr;
use armtwin_codec::json::MetricsMessage;
use armtwin_mesh::ros2::{self, Attachment};
use armtwin_offline::rosbag::{self, BagOptions};
use armtwin_offline::validate::validate;
use serde_json::{Value, json};
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;

/// Every test must end by itself within this time.
const TEST_LIMIT: Duration = Duration::from_secs(120);

/// The service on `config_toml`, and a client connected to it whose publishers on
/// `probe_keys` are matched by the service's subscribers.
async fn start(config_toml: &str, probe_keys: &[&str]) -> Harness {
    Harness::start(
        |endpoint| parse(config_toml, vec![endpoint.to_owned()]).expect("valid test config"),
        probe_keys,
    )
    .await
}

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
            h.put_attached(&rmw_joints, joint, Some(attachment(seq, 1, &gid)))
                .await;
            h.put_attached(&rmw_poses, pose, Some(attachment(seq, 1, &gid)))
                .await;
            h.put_attached("bob/joint_states", joint, None).await;
            h.put_attached("bob/tcp_pose_broadcaster/pose", pose, None)
                .await;
            h.put_attached("joint_states", joint, None).await;
        }
        // Keys that name no robot: the root namespace under a namespace rule, another type.
        h.put_attached(
            &format!("0/joint_states/{JOINT_TYPE}/RIHS01_0"),
            &joints[0],
            None,
        )
        .await;
        h.put_attached(
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
        let times = armtwin_codec::recording::source_times(&bag.recording, None);
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
async fn rmw_sequence_numbers_account_for_every_message() {
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
            h.put_attached(&joints_key, &joints[index], attachment)
                .await;
        }
        // Damaged messages (written by rosbags, then cut or patched): each refused with its cause.
        let fixture = |name: &str| std::fs::read(data().join(name)).expect("fixture");
        h.put_attached(&joints_key, &fixture("joint_state_truncated.cdr"), None)
            .await;
        h.put_attached(&joints_key, &fixture("joint_state_missing_joint.cdr"), None)
            .await;
        h.put_attached(&joints_key, &fixture("joint_state_xcdr2_header.cdr"), None)
            .await;
        h.put_attached(&joints_key, &fixture("joint_state_huge_count.cdr"), None)
            .await;
        // The bag's first pose, in the frame of the robot's tf_prefix (paired), and as recorded,
        // in `base` (refused: not `alice_base`).
        let recorded = cdr::decode_pose_stamped(&poses[0]).expect("decodes");
        let stamp_s = recorded.sample.stamp_s.expect("stamped");
        let in_alice_base = cdr::encode_pose_stamped(stamp_s, "alice_base", &recorded.sample.pose);
        h.put_attached(&poses_key, &in_alice_base, None).await;
        h.put_attached(&poses_key, &poses[0], None).await;
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
                h.put_attached(
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
        h.put_attached(&key("ur7"), &joints[0], None).await;
        h.put_attached(&key("stranger"), &joints[0], None).await;
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
