//! Recordings replayed into the live service: every row twinned as offline validation twins it,
//! and self-calibration converging on a replayed recording and applied on request.

use super::{CONFIG, TEST_LIMIT, number, start};
use crate::common::{Harness, RECEIVE_LIMIT};
use std::path::Path;
use std::time::Duration;

use armtwin_codec::json::MetricsMessage;
use armtwin_codec::recording;
use armtwin_offline::replay::{ReplaySettings, replay};
use armtwin_offline::validate::validate;
use armtwin_service::config::{Overrides, ServiceConfig, ZenohMode, ZenohSection};
use serde_json::json;

/// Held by the tests that replay a whole recording at full rate: Zenoh's runtime is shared by
/// every session of a process, and two services each taking 29 000 samples as fast as they come,
/// with blocking puts in their callbacks, starve each other's links until Zenoh closes one.
static FULL_RATE_REPLAY: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

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
                multicast_scouting: false,
                ..ZenohSection::default()
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
async fn self_calibration_converges_on_a_replayed_recording() {
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
                multicast_scouting: false,
                ..ZenohSection::default()
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
