//! The live service end to end: real Zenoh sessions over TCP loopback, one in-process `serve`.
#![allow(
    clippy::float_cmp,
    reason = "counts and exact pairings have exact answers"
)]

mod replay;

use crate::common::{Harness, RECEIVE_LIMIT, connect_client, wait_for_subscriber};
use std::collections::HashMap;
use std::path::Path;
use std::time::Duration;

use armtwin_codec::json::MetricsMessage;
use armtwin_core::kinematics::PoseReadout;
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::{Discard, Pipeline, RobotDirectory};
use armtwin_mesh::ingest::{self, Codec};
use armtwin_service::config::{ConfigError, Overrides, ServiceConfig};
use serde_json::{Value, json};
use zenoh::sample::SampleKind;

/// Every test must end by itself within this time.
const TEST_LIMIT: Duration = Duration::from_secs(180);

/// The service on `config_toml` (files it names relative to the repository's `config/`), and a
/// client whose joints publishers the service's subscribers match. Its incident files go to
/// Cargo's scratch folder for tests, not beside the repository's configuration.
async fn start(config_toml: &str) -> Harness {
    Harness::start(
        |endpoint| {
            let mut config = ServiceConfig::parse(
                config_toml,
                "test config",
                Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
                    .join("config")
                    .as_path(),
                &Overrides {
                    listen: vec![endpoint.to_owned()],
                    ..Overrides::default()
                },
            )
            .expect("valid test config");
            config.recorder.store.dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("recordings");
            config
        },
        &["twin/joints/probe"],
    )
    .await
}

const CONFIG: &str = r#"
[service]
metrics_period_ms = 50
# Every pose is counted: a client that falls behind slows the twin instead of missing poses.
pose_congestion = "block"
window_s = 1.0
[align]
max_gap_s = 0.25
max_wait_s = 0.5
[robots.default]
model = "ur10e"
"#;

fn ur10e() -> RobotModel {
    RobotModel::nominal("ur10e").expect("catalog")
}

/// A smooth joint trajectory, `i` at 100 Hz.
fn q_at(i: usize) -> Vec<f64> {
    let t = i as f64 * 0.01;
    vec![
        -0.7 + 0.3 * (0.5 * t).sin(),
        -0.8 + 0.2 * (0.7 * t).cos(),
        0.9 + 0.1 * t.sin(),
        1.1,
        1.5 - 0.05 * t,
        1.7 + 0.2 * t,
    ]
}

fn measured_json(pose: &PoseReadout, dx_m: f64) -> Value {
    let [x, y, z] = pose.position_m;
    let [qx, qy, qz, qw] = pose.quaternion_xyzw;
    json!({"x": x + dx_m, "y": y, "z": z, "qx": qx, "qy": qy, "qz": qz, "qw": qw})
}

fn number(value: &Value, path: &[&str]) -> f64 {
    let mut node = value;
    for key in path {
        node = &node[*key];
    }
    node.as_f64()
        .unwrap_or_else(|| panic!("{path:?} is not a number in {value}"))
}

fn final_metrics<'a>(harness: &'a Harness, robot: &str) -> &'a Value {
    harness.last_metrics(robot).expect("metrics")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn several_robots_are_twinned_side_by_side() {
    tokio::time::timeout(TEST_LIMIT, async {
        let mut h = start(CONFIG).await;
        let model = ur10e();
        let robots = [
            ("plant-a/cell-1/r1", 0.0),
            ("plant-a/cell-1/r2", 0.001),
            ("r3", 0.0),
        ];
        for i in 0..50 {
            for (robot, offset_m) in robots {
                let q = q_at(i);
                let pose = model.pose(&q).expect("valid").readout();
                let message = json!({
                    "t": i as f64 * 0.01, "q": q, "seq": i,
                    "measured": measured_json(&pose, offset_m),
                });
                h.put(&format!("twin/joints/{robot}"), &message).await;
            }
        }
        // A put on a wildcard key names no robot: nothing is tracked for it.
        h.put("twin/joints/**", &json!({"t": 0.0, "q": q_at(0)}))
            .await;
        h.receive_until("150 poses and 150 deviations", |r| {
            r.iter()
                .filter(|(k, _)| k.starts_with("twin/pose/"))
                .count()
                == 150
                && r.iter()
                    .filter(|(k, _)| k.starts_with("twin/deviation/"))
                    .count()
                    == 150
        })
        .await;
        for (robot, offset_m) in robots {
            let poses = h.on(&format!("twin/pose/{robot}"));
            assert_eq!(poses.len(), 50, "{robot}");
            for (i, pose) in poses.iter().enumerate() {
                assert_eq!(pose["seq"].as_u64(), Some(i as u64), "seq without gaps");
                assert_eq!(pose["robot"], robot);
                assert_eq!(pose["frame"], "base");
                let expected = model.pose(&q_at(i)).expect("valid").readout();
                assert!((number(pose, &["x"]) - expected.position_m[0]).abs() < 1e-12);
                assert!((number(pose, &["qw"]) - expected.quaternion_xyzw[3]).abs() < 1e-12);
                assert!((number(pose, &["t"]) - i as f64 * 0.01).abs() < 1e-12);
            }
            for deviation in h.on(&format!("twin/deviation/{robot}")) {
                // Twin minus measured.
                assert!(
                    (number(deviation, &["dx"]) + offset_m).abs() < 1e-12,
                    "{deviation}"
                );
                assert!((number(deviation, &["position"]) - offset_m).abs() < 1e-12);
                assert!(number(deviation, &["angle"]) < 1e-7);
            }
        }
        // The fleet view: one reply per robot.
        let states = h.get("twin/state/**", None).await;
        let mut ids: Vec<String> = states
            .iter()
            .map(|r| {
                r.as_ref().expect("state reply").1["robot"]
                    .as_str()
                    .expect("id")
                    .to_owned()
            })
            .collect();
        ids.sort();
        assert_eq!(ids, ["plant-a/cell-1/r1", "plant-a/cell-1/r2", "r3"]);
        let site = h.get("twin/state/plant-a/**", None).await;
        assert_eq!(site.len(), 2);
        let r2 = h.get("twin/state/plant-a/cell-1/r2", None).await;
        let (key, state) = r2[0].as_ref().expect("r2 state");
        assert_eq!(key, "twin/state/plant-a/cell-1/r2");
        assert_eq!(state["model"], "ur10e");
        assert_eq!(number(state, &["metrics", "paired"]), 50.0);
        assert!(
            (number(state, &["metrics", "cumulative", "position", "mae"]) - 0.001).abs() < 1e-12
        );
        assert!((number(state, &["metrics", "cumulative", "x", "max"]) - 0.001).abs() < 1e-12);
        assert_eq!(number(state, &["metrics", "cumulative", "y", "max"]), 0.0);
        // FK on demand under that robot's model.
        let fk = h.get("twin/fk/r3", Some(json!({"q": q_at(7)}))).await;
        let (_, pose) = fk[0].as_ref().expect("fk reply");
        let expected = model.pose(&q_at(7)).expect("valid").readout();
        assert!((number(pose, &["z"]) - expected.position_m[2]).abs() < 1e-12);
        let bad_fk = h.get("twin/fk/r3", Some(json!({"q": [1, 2]}))).await;
        assert!(bad_fk[0].is_err(), "{bad_fk:?}");
        // Reset replies with the final metrics, then counts start again.
        let reset = h.get("twin/admin/reset/plant-a/cell-1/r2", None).await;
        let (_, last) = reset[0].as_ref().expect("reset reply");
        assert_eq!(number(last, &["paired"]), 50.0);
        let after = h.get("twin/state/plant-a/cell-1/r2", None).await;
        let (_, state) = after[0].as_ref().expect("state");
        assert_eq!(number(state, &["metrics", "paired"]), 0.0);
        assert_eq!(number(state, &["metrics", "cumulative", "n"]), 0.0);
        h.stop().await;
    })
    .await
    .expect("test finished in time");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_is_rejected_without_harming_its_neighbours() {
    tokio::time::timeout(TEST_LIMIT, async {
        let mut h = start(CONFIG).await;
        let model = ur10e();
        let key = "twin/joints/cell/bad";
        let measured_key = "twin/measured/cell/bad";
        let q = q_at(0);
        let pose = model.pose(&q).expect("valid").readout();
        let mut valid = 0;
        let mut t = 0.0;
        let mut next_valid = |h: &Harness, t: &mut f64| {
            *t += 0.01;
            valid += 1;
            let message = json!({"t": *t, "q": q_at(valid)});
            let key = key.to_owned();
            let client = h.client.clone();
            async move { client.put(key, message.to_string()).await.expect("put") }
        };
        let invalid_joints: Vec<(Vec<u8>, &str)> = vec![
            (b"not json".to_vec(), "not_json"),
            (json!([1, 2, 3]).to_string().into_bytes(), "not_object"),
            (json!({"t": 100.0, "q": [0, 0, "x", 0, 0, 0]}).to_string().into_bytes(), "wrong_type"),
            (json!({"t": 100.0, "q": [0, 0, 0, 0, 0]}).to_string().into_bytes(), "joint_count"),
            (json!({"t": 100.0, "q": [0, 0, 7.5, 0, 0, 0]}).to_string().into_bytes(), "joint_limits"),
            (json!({"t": 100.0, "q": [0, 0, 0, 0, 0, 0], "unit": "grad"}).to_string().into_bytes(), "unit"),
            (vec![b' '; 70 * 1024], "too_large"),
        ];
        // The joint cases, two stamp cases, four measured poses, one embedded measured pose.
        let expected_rejections = invalid_joints.len() + 7;
        next_valid(&h, &mut t).await;
        for (payload, _) in invalid_joints.clone() {
            h.put_raw(key, payload).await;
            next_valid(&h, &mut t).await;
        }
        // Stamps that go back or repeat.
        h.put(key, &json!({"t": 0.005, "q": q})).await;
        h.put(key, &json!({"t": t, "q": q})).await;
        next_valid(&h, &mut t).await;
        // Measured poses: zero quaternion, norm off by 20 %, two orientation forms.
        h.put(measured_key, &json!({"t": t, "x": 0, "y": 0, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 0})).await;
        h.put(measured_key, &json!({"t": t, "x": 0, "y": 0, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 1.2})).await;
        h.put(measured_key, &json!({"t": t, "x": 0, "y": 0, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 1, "roll": 0, "pitch": 0, "yaw": 0})).await;
        // Well-formed, but a kilometre away: not a pose of this robot.
        h.put(measured_key, &json!({"t": t, "x": 1000.0, "y": 0, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 1})).await;
        next_valid(&h, &mut t).await;
        // A valid joint sample with an invalid measured pose: the joints still count.
        let mut broken = measured_json(&pose, 0.0);
        broken["qz"] = json!("8.506,978");
        t += 0.01;
        h.put(key, &json!({"t": t, "q": q, "measured": broken})).await;
        let valid_joint_samples = valid + 1;
        h.receive_until("every pose and rejection", |r| {
            r.iter().filter(|(k, _)| k == "twin/pose/cell/bad").count() == valid_joint_samples
                && r.iter().filter(|(k, v)| k == "twin/events/cell/bad" && v["kind"] == "rejected").count()
                    == expected_rejections
        })
        .await;
        let causes: Vec<String> = h
            .on("twin/events/cell/bad")
            .iter()
            .filter(|e| e["kind"] == "rejected")
            .map(|e| e["detail"]["cause"].as_str().unwrap_or("?").to_owned())
            .collect();
        for (_, cause) in &invalid_joints {
            assert!(causes.iter().any(|c| c == cause), "no {cause} rejection in {causes:?}");
        }
        for cause in [
            "out_of_order",
            "duplicate_stamp",
            "quaternion_norm",
            "orientation_forms",
            "wrong_type",
            "out_of_range",
        ] {
            assert!(causes.iter().any(|c| c == cause), "no {cause} rejection in {causes:?}");
        }
        for event in h.on("twin/events/cell/bad") {
            assert!(event["reason"].as_str().is_some_and(|r| !r.is_empty()), "{event}");
            assert!(event["key"].as_str().is_some(), "{event}");
        }
        h.receive_until("metrics counting the rejections", |r| {
            r.iter().rev().find(|(k, _)| k == "twin/metrics/cell/bad").is_some_and(|(_, m)| {
                m["rejected"].as_u64() == Some(expected_rejections as u64)
            })
        })
        .await;
        h.stop().await;
    })
    .await
    .expect("test finished in time");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn measured_poses_pair_with_the_joints_they_align_to() {
    tokio::time::timeout(TEST_LIMIT, async {
        let mut h = start(CONFIG).await;
        let model = ur10e();
        let robot = "align/r1";
        let measure = |q: &[f64]| measured_json(&model.pose(q).expect("valid").readout(), 0.0);
        // Before any joint sample: nothing to pair with.
        let mut early = measure(&q_at(0));
        early["t"] = json!(-1.0);
        h.put(&format!("twin/measured/{robot}"), &early).await;
        for i in 0..10 {
            h.put(
                &format!("twin/joints/{robot}"),
                &json!({"t": i as f64 * 0.01, "q": q_at(i)}),
            )
            .await;
        }
        // Exact stamp.
        let mut exact = measure(&q_at(3));
        exact["t"] = json!(0.03);
        h.put(&format!("twin/measured/{robot}"), &exact).await;
        // Between two joint samples: the robot's own pose at the interpolated joints.
        let q_mid: Vec<f64> = q_at(4)
            .iter()
            .zip(q_at(5))
            .map(|(a, b)| a + 0.25 * (b - a))
            .collect();
        let mut between = measure(&q_mid);
        between["t"] = json!(0.0425);
        h.put(&format!("twin/measured/{robot}"), &between).await;
        // Newer than every joint sample: waits for the next one, then pairs.
        let q_wait: Vec<f64> = q_at(9)
            .iter()
            .zip(q_at(10))
            .map(|(a, b)| a + 0.5 * (b - a))
            .collect();
        let mut waiting = measure(&q_wait);
        waiting["t"] = json!(0.095);
        h.put(&format!("twin/measured/{robot}"), &waiting).await;
        h.put(
            &format!("twin/joints/{robot}"),
            &json!({"t": 0.10, "q": q_at(10)}),
        )
        .await;
        // A joint gap of 1 s (> max_gap_s 0.25): a measured pose inside it is unpaired.
        h.put(
            &format!("twin/joints/{robot}"),
            &json!({"t": 1.10, "q": q_at(11)}),
        )
        .await;
        let mut in_gap = measure(&q_at(10));
        in_gap["t"] = json!(0.6);
        h.put(&format!("twin/measured/{robot}"), &in_gap).await;
        h.receive_until("three deviations and the unpaired events", |r| {
            r.iter()
                .filter(|(k, _)| k == "twin/deviation/align/r1")
                .count()
                == 3
                && r.iter()
                    .filter(|(k, v)| k == "twin/events/align/r1" && v["kind"] == "unpaired")
                    .count()
                    == 2
        })
        .await;
        for deviation in h.on("twin/deviation/align/r1") {
            assert!(number(deviation, &["position"]) < 1e-9, "{deviation}");
            assert!(number(deviation, &["angle"]) < 1e-7, "{deviation}");
        }
        let stamps: Vec<f64> = h
            .on("twin/deviation/align/r1")
            .iter()
            .map(|d| number(d, &["t"]))
            .collect();
        assert_eq!(stamps, [0.03, 0.0425, 0.095]);
        let unpaired: Vec<&str> = h
            .on("twin/events/align/r1")
            .iter()
            .filter(|e| e["kind"] == "unpaired")
            .map(|e| e["detail"]["cause"].as_str().unwrap_or("?"))
            .collect();
        assert_eq!(unpaired, ["before_joint_history", "joint_gap"]);
        let gaps = h
            .on("twin/events/align/r1")
            .iter()
            .filter(|e| e["kind"] == "gap")
            .count();
        assert_eq!(gaps, 1, "the 1 s joint gap is reported");
        h.receive_until("metrics with the counts", |r| {
            r.iter()
                .rev()
                .find(|(k, _)| k == "twin/metrics/align/r1")
                .is_some_and(|(_, m)| {
                    m["paired"].as_u64() == Some(3) && m["unpaired"].as_u64() == Some(2)
                })
        })
        .await;
        h.stop().await;
    })
    .await
    .expect("test finished in time");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_window_and_its_alarms_forget_old_samples() {
    // 0.99 s, so that no sample sits exactly on the window's edge.
    let config = r#"
[service]
metrics_period_ms = 50
# Every pose is counted: a client that falls behind slows the twin instead of missing poses.
pose_congestion = "block"
window_s = 0.99
# 9.9-ms slices, finer than the 20-ms samples: the window's edge falls between two samples.
window_slices = 100
[robots.default]
model = "ur10e"
alarm_position_m = 0.0015
alarm_hold_s = 0.2
"#;
    tokio::time::timeout(TEST_LIMIT, async {
        let mut h = start(config).await;
        let model = ur10e();
        let robot = "win/r1";
        // 2 s at 2 mm off, then 2 s at 1 mm off, 50 Hz.
        for i in 0..200 {
            let q = q_at(i);
            let offset = if i < 100 { 0.002 } else { 0.001 };
            let pose = model.pose(&q).expect("valid").readout();
            let message =
                json!({"t": i as f64 * 0.02, "q": q, "measured": measured_json(&pose, offset)});
            h.put(&format!("twin/joints/{robot}"), &message).await;
        }
        h.receive_until("200 deviations", |r| {
            r.iter()
                .filter(|(k, _)| k == "twin/deviation/win/r1")
                .count()
                == 200
        })
        .await;
        let mut h = {
            let stop_at = h.stop().await;
            assert!(stop_at.poses >= 200);
            h
        };
        h.receive_until("final metrics", |r| {
            r.iter()
                .rev()
                .find(|(k, _)| k == "twin/metrics/win/r1")
                .is_some_and(|(_, m)| m["paired"] == 200)
        })
        .await;
        let metrics = final_metrics(&h, robot);
        // The window holds the last second only: 1 mm everywhere.
        assert!((number(metrics, &["window", "position", "mae"]) - 0.001).abs() < 1e-12);
        assert!((number(metrics, &["window", "position", "max"]) - 0.001).abs() < 1e-12);
        assert_eq!(number(metrics, &["window", "seconds"]), 0.99);
        assert_eq!(number(metrics, &["window", "n"]), 50.0);
        // Cumulative keeps everything: half at 2 mm, half at 1 mm.
        assert!((number(metrics, &["cumulative", "position", "mae"]) - 0.0015).abs() < 1e-12);
        assert!(
            (number(metrics, &["cumulative", "position", "rmse"]) - (2.5e-6_f64).sqrt()).abs()
                < 1e-12
        );
        assert!((number(metrics, &["cumulative", "position", "max"]) - 0.002).abs() < 1e-12);
        assert_eq!(number(metrics, &["cumulative", "n"]), 200.0);
        // Alarm after 0.2 s above 1.5 mm, recovery 0.2 s after dropping to 1 mm.
        let events = h.on("twin/events/win/r1");
        let alarms: Vec<(&str, f64)> = events
            .iter()
            .filter(|e| e["kind"] == "alarm" || e["kind"] == "recovered")
            .map(|e| (e["kind"].as_str().unwrap_or("?"), number(e, &["t"])))
            .collect();
        assert_eq!(alarms.len(), 2, "{alarms:?}");
        assert_eq!(alarms[0].0, "alarm");
        assert!((alarms[0].1 - 0.2).abs() < 1e-9, "{alarms:?}");
        assert_eq!(alarms[1].0, "recovered");
        assert!((alarms[1].1 - 2.2).abs() < 1e-9, "{alarms:?}");
    })
    .await
    .expect("test finished in time");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_robots_presence_lasts_from_its_first_sample_to_shutdown() {
    tokio::time::timeout(TEST_LIMIT, async {
        let mut h = start(CONFIG).await;
        let alive = h
            .client
            .liveliness()
            .declare_subscriber("twin/alive/**")
            .with(zenoh::handlers::FifoChannel::new(64))
            .await
            .expect("liveliness subscriber");
        let before = h
            .client
            .liveliness()
            .get("twin/alive/**")
            .await
            .expect("get");
        let mut tokens = 0;
        while let Ok(Ok(_)) =
            tokio::time::timeout(Duration::from_secs(2), before.recv_async()).await
        {
            tokens += 1;
        }
        assert_eq!(tokens, 0, "no robot tracked yet");
        h.put("twin/joints/live/r1", &json!({"t": 0.0, "q": q_at(0)}))
            .await;
        let appeared = tokio::time::timeout(RECEIVE_LIMIT, alive.recv_async())
            .await
            .expect("token in time")
            .expect("sample");
        assert_eq!(appeared.key_expr().as_str(), "twin/alive/live/r1");
        assert_eq!(appeared.kind(), SampleKind::Put);
        h.put("twin/joints/live/r1", &json!({"t": 0.01, "q": q_at(1)}))
            .await;
        h.receive_until("two poses", |r| {
            r.iter().filter(|(k, _)| k == "twin/pose/live/r1").count() == 2
        })
        .await;
        let metrics_before_stop = h.on("twin/metrics/live/r1").len();
        let report = h.stop().await;
        assert_eq!(report.poses, 2);
        assert_eq!(report.robots, 1);
        let gone = tokio::time::timeout(RECEIVE_LIMIT, alive.recv_async())
            .await
            .expect("token removal in time")
            .expect("sample");
        assert_eq!(gone.kind(), SampleKind::Delete);
        h.receive_until("the final metrics", |r| {
            r.iter()
                .filter(|(k, _)| k == "twin/metrics/live/r1")
                .count()
                > metrics_before_stop
        })
        .await;
        let last = final_metrics(&h, "live/r1");
        assert_eq!(number(last, &["paired"]), 0.0);
        assert!((number(last, &["t"]) - 0.01).abs() < 1e-12);
    })
    .await
    .expect("test finished in time");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sensor_stream_is_transformed_into_its_robots_base() {
    let config = r#"
[service]
metrics_period_ms = 50
# Every pose is counted: a client that falls behind slows the twin instead of missing poses.
pose_congestion = "block"
reject_unknown = true
[robots."lab/r7"]
model = "ur5e"
[[robots."lab/r7".sensors]]
key_expr = "mocap/body/7"
base_from_sensor = [1.0, -0.5, 0.2, 0.0, 0.0, 1.5707963267948966]
"#;
    tokio::time::timeout(TEST_LIMIT, async {
        let mut h = start(config).await;
        let model = RobotModel::nominal("ur5e").expect("catalog");
        let q = q_at(3);
        h.put("twin/joints/lab/r7", &json!({"t": 1.0, "q": q})).await;
        // The sensor sees the TCP in its own frame: sensor_from_base · pose.
        let pose = model.pose(&q).expect("valid");
        let (c, s) = (0.0_f64, 1.0_f64); // cos, sin of π/2 about z
        let p = pose.position_m - nalgebra::Vector3::new(1.0, -0.5, 0.2);
        let in_sensor = [c * p.x + s * p.y, -s * p.x + c * p.y, p.z];
        let r_sensor_from_base = nalgebra::Matrix3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0);
        let q_sensor = armtwin_core::orientation::quaternion_from_matrix(&(r_sensor_from_base * pose.rotation));
        let [qx, qy, qz, qw] = armtwin_core::orientation::quaternion_to_xyzw(&q_sensor);
        h.put(
            "mocap/body/7",
            &json!({"t": 1.0, "x": in_sensor[0], "y": in_sensor[1], "z": in_sensor[2], "qx": qx, "qy": qy, "qz": qz, "qw": qw}),
        )
        .await;
        h.put("twin/joints/stranger", &json!({"t": 1.0, "q": q})).await;
        h.receive_until("the deviation and the rejection", |r| {
            r.iter().any(|(k, _)| k == "twin/deviation/lab/r7")
                && r.iter().any(|(k, _)| k == "twin/events/stranger")
        })
        .await;
        let deviation = h.on("twin/deviation/lab/r7")[0];
        assert!(number(deviation, &["position"]) < 1e-12, "{deviation}");
        assert!(number(deviation, &["angle"]) < 1e-7, "{deviation}");
        let rejection = h.on("twin/events/stranger")[0];
        assert_eq!(rejection["detail"]["cause"], "unknown_robot");
        assert!(h.on("twin/pose/stranger").is_empty());
        let mut counts: HashMap<&str, usize> = HashMap::new();
        for (key, _) in &h.outputs.received {
            *counts.entry(key.as_str()).or_default() += 1;
        }
        assert_eq!(counts.get("twin/pose/lab/r7"), Some(&1));
        h.stop().await;
    })
    .await
    .expect("test finished in time");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_of_bad_input_is_counted_but_its_events_are_rate_limited() {
    tokio::time::timeout(TEST_LIMIT, async {
        let config = CONFIG.replace(
            "window_s = 1.0\n",
            "window_s = 1.0\nevents_per_s = 0.5\nevents_burst = 5\n",
        );
        let mut h = start(&config).await;
        let key = "twin/joints/flood";
        for _ in 0..50 {
            h.put_raw(key, b"not json".to_vec()).await;
        }
        h.receive_until("50 rejections counted", |r| {
            r.iter()
                .rev()
                .find(|(k, _)| k == "twin/metrics/flood")
                .is_some_and(|(_, m)| m["rejected"] == 50)
        })
        .await;
        assert_eq!(
            h.on("twin/events/flood").len(),
            5,
            "the burst, then nothing"
        );
        // How the bucket refills and what the next event then reports is the event budget's
        // own unit test (`service::events`), with the time passed in rather than waited for.
        let events = h.on("twin/events/flood");
        assert!(events.iter().all(|e| e.get("suppressed").is_none()));
        h.stop().await;
    })
    .await
    .expect("test finished in time");
}

#[test]
fn a_sensor_key_that_would_receive_the_twins_own_outputs_is_refused() {
    let config = r#"
[robots."lab/r7"]
model = "ur5e"
[[robots."lab/r7".sensors]]
key_expr = "twin/*/lab/**"
base_from_sensor = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
"#;
    // Refused when the configuration loads, before any session is opened.
    let error = ServiceConfig::parse(config, "test config", Path::new("."), &Overrides::default())
        .expect_err("refused");
    assert!(matches!(error, ConfigError::Invalid { .. }), "{error}");
    assert!(error.to_string().contains("twin/*/lab/**"), "{error}");
    assert!(
        error
            .to_string()
            .contains("robots.\"lab/r7\".sensors[0].key_expr"),
        "{error}"
    );
}

/// The messages a gateway sends for `robot`: joints at 100 Hz, each with a measured pose off by
/// a pattern of its own, and every 40th message sent twice (its repeated stamp is rejected).
fn gateway_messages(model: &RobotModel, robot_offset_m: f64, count: usize) -> Vec<Vec<u8>> {
    let mut messages = Vec::new();
    for i in 0..count {
        let q = q_at(i);
        let pose = model.pose(&q).expect("valid").readout();
        let offset_m = robot_offset_m * (1.0 + (i % 7) as f64);
        let message = json!({
            "t": i as f64 * 0.01, "q": q, "seq": i,
            "measured": measured_json(&pose, offset_m),
        })
        .to_string()
        .into_bytes();
        if i % 40 == 39 {
            messages.push(message.clone());
        }
        messages.push(message);
    }
    messages
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_gateways_at_once_each_get_exact_metrics() {
    tokio::time::timeout(TEST_LIMIT, async {
        let mut h = start(CONFIG).await;
        let model = ur10e();
        let count = 400;
        let robots = [("duo/a", 0.0005), ("duo/b", 0.0013)];
        let messages: Vec<Vec<Vec<u8>>> = robots
            .iter()
            .map(|(_, offset_m)| gateway_messages(&model, *offset_m, count))
            .collect();
        // One session per gateway: each robot's samples arrive on a link of their own.
        let mut gateways = Vec::new();
        for _ in &robots {
            let (gateway, outputs) = connect_client(&h.service.endpoint).await;
            drop(outputs);
            wait_for_subscriber(&gateway, "twin/joints/probe").await;
            gateways.push(gateway);
        }
        let sends: Vec<_> = robots
            .iter()
            .zip(&messages)
            .zip(&gateways)
            .map(|(((robot, _), messages), gateway)| {
                let (key, messages, gateway) = (
                    format!("twin/joints/{robot}"),
                    messages.clone(),
                    gateway.clone(),
                );
                tokio::spawn(async move {
                    for message in messages {
                        gateway.put(&key, message).await.expect("put");
                    }
                })
            })
            .collect();
        for send in sends {
            send.await.expect("gateway task");
        }
        h.receive_until("every pose of both robots", |r| {
            r.iter()
                .filter(|(k, _)| k.starts_with("twin/pose/duo/"))
                .count()
                == 2 * count
        })
        .await;
        let report = h.stop().await;
        let sent: usize = messages.iter().map(Vec::len).sum();
        assert_eq!(report.poses, 2 * count as u64);
        assert_eq!(report.robots, 2);
        // Every sample, and the state query that started the harness.
        assert_eq!(report.inputs, sent as u64 + 1);
        for (robot, _) in robots {
            let poses = h.on(&format!("twin/pose/{robot}"));
            let seqs: Vec<u64> = poses.iter().filter_map(|p| p["seq"].as_u64()).collect();
            assert_eq!(seqs, (0..count as u64).collect::<Vec<_>>(), "{robot}");
        }
        h.receive_until("both robots' final metrics", |r| {
            robots.iter().all(|(robot, _)| {
                r.iter()
                    .rev()
                    .find(|(k, _)| *k == format!("twin/metrics/{robot}"))
                    .is_some_and(|(_, m)| m["paired"].as_u64() == Some(count as u64))
            })
        })
        .await;
        // The same messages through one offline pipeline give exactly the service's metrics.
        let config = ServiceConfig::parse(CONFIG, "test", Path::new("."), &Overrides::default())
            .expect("config");
        let settings = config.default_robot.clone().expect("default robot");
        let mut directory = RobotDirectory::new(Some(settings), HashMap::new());
        let mut pipeline = Pipeline::new(config.pipeline);
        for ((robot, _), messages) in robots.iter().zip(&messages) {
            let handle = directory.admit(robot).expect("default settings").clone();
            let key = format!("twin/joints/{robot}");
            for message in messages {
                let no_stamp = || panic!("every message has its stamp");
                ingest::joint_message(
                    &mut pipeline,
                    &handle,
                    &key,
                    Codec::Json,
                    message,
                    no_stamp,
                    &mut Discard,
                );
            }
        }
        pipeline.finish(&mut Discard);
        for (robot, _) in robots {
            let index = directory.find(robot).expect("admitted").index();
            let offline = pipeline.state(index).expect("tracked").metrics;
            let offline: Value =
                serde_json::from_slice(&MetricsMessage::new(&offline).to_json_bytes())
                    .expect("json");
            assert_eq!(offline["rejected"], (count / 40) as u64, "{robot}");
            assert_eq!(final_metrics(&h, robot), &offline, "{robot}");
        }
    })
    .await
    .expect("test finished in time");
}

#[test]
fn output_publishers_are_aggregated_unless_the_operator_chose_otherwise() {
    let outputs = ["twin/pose/**".to_owned(), "twin/deviation/**".to_owned()];
    let aggregated = |config: &zenoh::Config| -> Vec<String> {
        serde_json::from_str(&config.get_json("aggregation/publishers").unwrap()).unwrap()
    };
    let mut config = zenoh::Config::default();
    armtwin_mesh::aggregate_publishers(&mut config, &outputs).unwrap();
    assert_eq!(aggregated(&config), outputs);

    let mut chosen = zenoh::Config::default();
    chosen
        .insert_json5("aggregation/publishers", r#"["plant/**"]"#)
        .unwrap();
    armtwin_mesh::aggregate_publishers(&mut chosen, &outputs).unwrap();
    assert_eq!(aggregated(&chosen), ["plant/**"]);
}
