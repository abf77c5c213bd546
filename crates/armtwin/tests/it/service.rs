//! The live service end to end: real Zenoh sessions over TCP loopback, one in-process `serve`.
#![allow(
    clippy::float_cmp,
    reason = "counts and exact pairings have exact answers"
)]

use crate::common::{Outputs, RECEIVE_LIMIT, Service, connect_client, wait_for_subscriber};
use std::collections::HashMap;
use std::path::Path;
use std::time::Duration;

use armtwin::codec::json::MetricsMessage;
use armtwin::codec::recording;
use armtwin::config::{ConfigError, Overrides, ServiceConfig, ZenohMode, ZenohSection};
use armtwin::ingest::{self, Codec};
use armtwin::kinematics::PoseReadout;
use armtwin::model::RobotModel;
use armtwin::pipeline::{Discard, Pipeline, RobotDirectory};
use armtwin::replay::{ReplaySettings, replay};
use armtwin::service::ServeReport;
use armtwin::validate::validate;
use serde_json::{Value, json};
use zenoh::Session;
use zenoh::sample::SampleKind;

/// Every test must end by itself within this time.
const TEST_LIMIT: Duration = Duration::from_secs(180);

/// Held by the tests that replay a whole recording at full rate: Zenoh's runtime is shared by
/// every session of a process, and two services each taking 29 000 samples as fast as they come,
/// with blocking puts in their callbacks, starve each other's links until Zenoh closes one.
static FULL_RATE_REPLAY: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

struct Harness {
    service: Service,
    client: Session,
    outputs: Outputs,
}

async fn start(config_toml: &str) -> Harness {
    let service = Service::start(|endpoint| {
        ServiceConfig::parse(
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
        .expect("valid test config")
    })
    .await;
    let (client, outputs) = connect_client(&service.endpoint).await;
    wait_for_subscriber(&client, "twin/joints/probe").await;
    // A query travels after our subscriber's declaration on the same link: once it is answered,
    // the service knows where to send outputs.
    let replies = client.get("twin/state/**").await.expect("get");
    while tokio::time::timeout(RECEIVE_LIMIT, replies.recv_async())
        .await
        .expect("state query answered")
        .is_ok()
    {}
    Harness {
        service,
        client,
        outputs,
    }
}

impl Harness {
    async fn put(&self, key: &str, payload: &Value) {
        self.client
            .put(key, payload.to_string())
            .await
            .expect("put");
    }

    async fn put_raw(&self, key: &str, payload: Vec<u8>) {
        // Blocking, not dropped under congestion: a large payload is fragmented, and on a loaded
        // machine a dropped fragment would lose the message the test counts on.
        self.client
            .put(key, payload)
            .congestion_control(zenoh::qos::CongestionControl::Block)
            .await
            .expect("put");
    }

    async fn receive_until(&mut self, what: &str, done: impl Fn(&[(String, Value)]) -> bool) {
        self.outputs.receive_until(what, done).await;
    }

    fn on(&self, key: &str) -> Vec<&Value> {
        self.outputs.on(key)
    }

    async fn stop(&mut self) -> ServeReport {
        self.service.stop().await
    }

    async fn get(
        &self,
        selector: &str,
        payload: Option<Value>,
    ) -> Vec<Result<(String, Value), Value>> {
        let mut get = self.client.get(selector);
        if let Some(payload) = payload {
            get = get.payload(payload.to_string());
        }
        let replies = get.await.expect("get");
        let mut out = Vec::new();
        while let Ok(reply) = tokio::time::timeout(RECEIVE_LIMIT, replies.recv_async())
            .await
            .expect("replies end in time")
        {
            match reply.result() {
                Ok(sample) => out.push(Ok((
                    sample.key_expr().as_str().to_owned(),
                    serde_json::from_slice(&sample.payload().to_bytes()).expect("json reply"),
                ))),
                Err(error) => out.push(Err(
                    serde_json::from_slice(&error.payload().to_bytes()).expect("json error")
                )),
            }
        }
        out
    }
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
    harness
        .on(&format!("twin/metrics/{robot}"))
        .last()
        .copied()
        .expect("metrics")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn several_robots_poses_deviations_metrics_and_fleet_queries() {
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
async fn bad_input_is_rejected_with_an_event_and_neighbours_are_processed() {
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
async fn alignment_exact_interpolated_waiting_and_unpaired() {
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
async fn window_forgets_what_cumulative_keeps_and_alarms_fire_and_recover() {
    // 0.99 s, so that no sample sits exactly on the window's edge.
    let config = r#"
[service]
metrics_period_ms = 50
# Every pose is counted: a client that falls behind slows the twin instead of missing poses.
pose_congestion = "block"
window_s = 0.99
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
async fn liveliness_token_lives_while_tracked_and_final_metrics_go_out_on_shutdown() {
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
async fn sensor_streams_are_transformed_and_unknown_robots_rejected() {
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
        let q_sensor = armtwin::orientation::quaternion_from_matrix(&(r_sensor_from_base * pose.rotation));
        let [qx, qy, qz, qw] = armtwin::orientation::quaternion_to_xyzw(&q_sensor);
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
async fn replaying_the_sample_recordings_twins_every_row() {
    let _alone = FULL_RATE_REPLAY.lock().await;
    tokio::time::timeout(TEST_LIMIT, async {
        let mut h = start(CONFIG).await;
        let endpoint = h.service.endpoint.clone();
        let data = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join("tests/data");
        let settings = |robot: &str| ReplaySettings {
            zenoh: ZenohSection {
                mode: ZenohMode::Peer,
                listen: Vec::new(),
                connect: vec![endpoint.clone()],
                file: None,
                multicast_scouting: false,
                cfg: Vec::new(),
            },
            key_prefix: "twin".to_owned(),
            robot: robot.to_owned(),
            speed: None,
        };
        // The UR10e FMU report's FMPy input: its time column is a row index; 0.1 s apart as the
        // report streamed it.
        let text = std::fs::read_to_string(data.join("fmpy_inputs.csv")).expect("data");
        let fmpy = recording::read(&text).expect("recognised");
        let times = recording::source_times(&fmpy, Some(0.1));
        let report = replay(
            &fmpy,
            &times,
            &settings("fmpy"),
            std::future::pending(),
            |_| {},
        )
        .await
        .expect("replay");
        assert_eq!(report.published, 54);
        // The ROS 2 export: whole-second stamps spread over each second, 7 malformed lines.
        let text = std::fs::read_to_string(data.join("ur10e_lasttest.csv")).expect("data");
        let ros = recording::read(&text).expect("recognised");
        let times = recording::source_times(&ros, None);
        assert!(times.windows(2).all(|w| w[1] > w[0]), "strictly increasing");
        let report = replay(
            &ros,
            &times,
            &settings("lasttest"),
            std::future::pending(),
            |_| {},
        )
        .await
        .expect("replay");
        assert_eq!((report.published, report.malformed), (29_061, 7));
        h.receive_until("every row twinned", |r| {
            let last = |key: &str| {
                r.iter()
                    .rev()
                    .find(|(k, _)| k == key)
                    .map(|(_, m)| (m["paired"].as_u64(), m["rejected"].as_u64()))
            };
            last("twin/metrics/fmpy") == Some((Some(54), Some(0)))
                && last("twin/metrics/lasttest") == Some((Some(29_054), Some(7)))
        })
        .await;
        assert_eq!(h.on("twin/pose/fmpy").len(), 54);
        assert_eq!(h.on("twin/pose/lasttest").len(), 29_054);
        // Offline validation of the same recordings gives exactly the service's metrics.
        let config = ServiceConfig::parse(CONFIG, "test", Path::new("."), &Overrides::default())
            .expect("config");
        let robot = config.default_robot.clone().expect("default robot");
        for (name, recording, times) in [
            ("fmpy", &fmpy, recording::source_times(&fmpy, Some(0.1))),
            ("lasttest", &ros, recording::source_times(&ros, None)),
        ] {
            let offline = validate(recording, &times, config.pipeline, robot.clone(), |_| {});
            let offline =
                serde_json::to_value(MetricsMessage::new(&offline.metrics)).expect("json");
            let live = h
                .on(&format!("twin/metrics/{name}"))
                .last()
                .copied()
                .expect("metrics");
            for field in ["paired", "unpaired", "rejected", "cumulative", "window"] {
                assert_eq!(live[field], offline[field], "{name}: {field}");
            }
        }
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn self_calibration_converges_on_a_replayed_recording_and_applies_on_request() {
    let _alone = FULL_RATE_REPLAY.lock().await;
    tokio::time::timeout(TEST_LIMIT, async {
        let config = format!(
            "{CONFIG}[robots.lasttest]\nmodel = \"ur10e\"\nself_calibrate = true\n\
             [self_calibration]\nrefit_period_s = 0.3\ntrain_capacity = 1500\nheld_out_capacity = 500\n"
        );
        let mut h = start(&config).await;
        // Configured, no input yet: nothing kept, nothing fitted.
        let before = h.get("twin/calibrate/lasttest", None).await;
        let [Ok((_, before))] = before.as_slice() else {
            panic!("status answered: {before:?}");
        };
        assert_eq!((before["offered"].as_u64(), before["fits"].as_u64()), (Some(0), Some(0)));
        assert!(before["pending"].is_null());
        let data = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join("tests/data");
        let text = std::fs::read_to_string(data.join("ur10e_lasttest.csv")).expect("data");
        let ros = recording::read(&text).expect("recognised");
        let times = recording::source_times(&ros, None);
        let settings = ReplaySettings {
            zenoh: ZenohSection {
                mode: ZenohMode::Peer,
                listen: Vec::new(),
                connect: vec![h.service.endpoint.clone()],
                file: None,
                multicast_scouting: false,
                cfg: Vec::new(),
            },
            key_prefix: "twin".to_owned(),
            robot: "lasttest".to_owned(),
            speed: None,
        };
        replay(&ros, &times, &settings, std::future::pending(), |_| {})
            .await
            .expect("replay");
        h.receive_until("every row paired", |r| {
            r.iter()
                .rev()
                .find(|(k, _)| k == "twin/metrics/lasttest")
                .is_some_and(|(_, m)| m["paired"].as_u64() == Some(29_054))
        })
        .await;
        // The fit of every pair offered (the reservoir skips pairs closer than 8 ms): the last
        // fit has seen as many as the reservoir has.
        let deadline = tokio::time::Instant::now() + RECEIVE_LIMIT;
        let status = loop {
            let status = h.get("twin/calibrate/lasttest", None).await;
            let [Ok((_, status))] = status.as_slice() else {
                panic!("one status: {status:?}");
            };
            if status["offered"].as_u64().is_some_and(|n| n > 5000)
                && status["last"]["offered"] == status["offered"]
                && status["fitting"] == false
            {
                break status.clone();
            }
            assert!(tokio::time::Instant::now() < deadline, "no final fit: {status}");
            tokio::time::sleep(Duration::from_millis(100)).await;
        };
        let offered = status["offered"].clone();
        h.receive_until("the final estimate published", |r| {
            r.iter()
                .any(|(k, m)| k == "twin/calibration/lasttest" && m["offered"] == offered)
        })
        .await;
        let pending = &status["pending"];
        assert_eq!(pending["status"], "estimate", "{status}");
        assert_eq!(status["epoch"], 0);
        let current_mm = number(pending, &["current", "position_mae_mm"]);
        let identified_mm = number(pending, &["identified", "position_mae_mm"]);
        println!(
            "live estimate from {} pairs offered ({} fitted, {} held out): position MAE {current_mm:.4} → {identified_mm:.4} mm, angle MAE {:.4} → {:.4} mrad",
            pending["offered"],
            pending["train_pairs"],
            pending["held_out_pairs"],
            number(pending, &["current", "angle_mae_mrad"]),
            number(pending, &["identified", "angle_mae_mrad"]),
        );
        // The recording is rounded to 1 mm / 1 mrad: nominal DH is ~1 mm off, the rounding
        // floor ~0.5 mm (see `armtwin calibrate` on the same file).
        assert!(current_mm > 0.9 && identified_mm < 0.75, "held out: {current_mm} mm → {identified_mm} mm");
        assert!(number(pending, &["improvement"]) > 1.3);
        assert!(pending["held_out_pairs"].as_u64().unwrap_or(0) >= 400);
        assert!(pending["calibration_conf"].as_str().is_some_and(|c| c.contains("delta_d")));
        apply_then_fk_and_ik_answer_with_the_estimate(&mut h).await;
        h.stop().await;
    })
    .await
    .expect("test finished in time");
}

/// Applies `lasttest`'s pending estimate; checks the epoch, and that FK and IK use it.
async fn apply_then_fk_and_ik_answer_with_the_estimate(h: &mut Harness) {
    // Applying starts epoch 1: the old epoch's final metrics, an `epoch` event, the twin's
    // model replaced (FK and IK answer with it).
    let q = [0.3, -1.2, 1.1, -1.4, -1.5, 0.2];
    let fk_before = h.get("twin/fk/lasttest", Some(json!({ "q": q }))).await;
    let applied = h
        .get("twin/admin/calibrate/lasttest?action=apply", None)
        .await;
    let [Ok((_, applied))] = applied.as_slice() else {
        panic!("apply answered: {applied:?}");
    };
    assert_eq!(applied["epoch"], 1, "{applied}");
    assert_eq!(applied["calibration"], "self-calibration");
    assert!(applied["pending"].is_null());
    h.receive_until("the epoch event", |r| {
        r.iter()
            .any(|(k, m)| k == "twin/events/lasttest" && m["kind"] == "epoch")
    })
    .await;
    let event = h
        .on("twin/events/lasttest")
        .into_iter()
        .find(|m| m["kind"] == "epoch")
        .expect("epoch");
    assert_eq!(event["detail"]["epoch"], 1);
    let again = h
        .get("twin/admin/calibrate/lasttest?action=apply", None)
        .await;
    assert!(
        matches!(again.as_slice(), [Err(_)]),
        "nothing left to apply: {again:?}"
    );
    let fk_after = h.get("twin/fk/lasttest", Some(json!({ "q": q }))).await;
    let (Ok((_, before)), Ok((_, after))) = (&fk_before[0], &fk_after[0]) else {
        panic!("fk answered: {fk_before:?} {fk_after:?}");
    };
    let moved_m = ["x", "y", "z"]
        .map(|k| number(before, &[k]) - number(after, &[k]))
        .iter()
        .map(|d| d * d)
        .sum::<f64>()
        .sqrt();
    assert!(
        moved_m > 1e-4 && moved_m < 0.02,
        "the calibrated FK moved the TCP by {moved_m} m"
    );
    // IK with the applied model inverts its FK.
    let pose = ["x", "y", "z", "qx", "qy", "qz", "qw"].map(|k| number(after, &[k]));
    let ik = h
        .get("twin/ik/lasttest", Some(json!({ "pose": pose, "seed": q })))
        .await;
    let [Ok((_, ik))] = ik.as_slice() else {
        panic!("ik answered: {ik:?}");
    };
    let nearest = &ik["solutions"][0];
    for (i, expected) in q.iter().enumerate() {
        let got = nearest["q"][i].as_f64().expect("angle");
        assert!(
            (got - expected).abs() < 1e-9,
            "joint {i}: {got} vs {expected}"
        );
    }
    let bad = h
        .get("twin/ik/lasttest", Some(json!({ "pose": [1.0] })))
        .await;
    assert!(
        matches!(bad.as_slice(), [Err(e)] if e["error"].as_str().is_some_and(|e| e.contains("7 values"))),
        "{bad:?}"
    );
    let unknown = h.get("twin/calibrate/lasttest?action=undo", None).await;
    assert!(matches!(unknown.as_slice(), [Err(_)]), "{unknown:?}");
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
async fn two_gateways_stream_two_robots_at_once_and_each_gets_exact_metrics() {
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
    armtwin::mesh::aggregate_publishers(&mut config, &outputs).unwrap();
    assert_eq!(aggregated(&config), outputs);

    let mut chosen = zenoh::Config::default();
    chosen
        .insert_json5("aggregation/publishers", r#"["plant/**"]"#)
        .unwrap();
    armtwin::mesh::aggregate_publishers(&mut chosen, &outputs).unwrap();
    assert_eq!(aggregated(&chosen), ["plant/**"]);
}
