//! Smoke test of the benchmark harness: `armtwin-bench run --quick` end to end with tiny numbers,
//! real processes and real Zenoh sessions over loopback, in both encodings and over one and two
//! gateway sessions, and a 30-second `armtwin-bench soak` with churn. It checks the reports'
//! structure, that nothing was lost at a trivially low rate and that memory stayed far below a
//! generous bound; it asserts no timing.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

/// The `armtwin` binary of this build profile: `cargo test --workspace` builds it (armtwin-cli's
/// integration tests need it). Building it from here would run a second cargo whose environment
/// differs from the outer one's, and each would rebuild what the other built.
fn armtwin_binary(bench: &Path) -> PathBuf {
    let armtwin = bench.with_file_name(format!("armtwin{}", std::env::consts::EXE_SUFFIX));
    assert!(
        armtwin.is_file(),
        "{} is missing: run `cargo test --workspace` (or `cargo build` first)",
        armtwin.display()
    );
    armtwin
}

/// Every reply of `trial` came back: nothing lost, a pose per sample, and a deviation per sample
/// unless the echo was sent embedded samples (it then returns one message per sample).
fn assert_lossless(trial: &Value, system: &str, deviations: bool) {
    assert_eq!(trial["lost"], 0, "{system}: {trial:#}");
    assert_eq!(trial["replies"]["poses"], trial["samples"], "{system}");
    if deviations {
        assert_eq!(trial["replies"]["deviations"], trial["samples"], "{system}");
    }
}

/// Both systems sustained the trivially low rate in `comparison`: every pose and deviation of
/// every trial came back, and armtwin raised no event.
fn assert_row_lossless(comparison: &Value, latency_rounds: usize) {
    for system in ["echo", "armtwin"] {
        let load = &comparison[system];
        let latency = &comparison[format!("{system}_latency")];
        let rounds = latency["rounds"].as_array().expect("latency rounds");
        assert_eq!(rounds.len(), latency_rounds);
        let trials = load["search"]["trials"].as_array().expect("trials");
        assert!(!trials.is_empty());
        for trial in trials
            .iter()
            .chain(rounds.iter().map(|round| &round["trial"]))
        {
            assert_lossless(trial, system, true);
        }
        assert_eq!(load["gateways"], comparison["gateways"]);
        assert!(number(&rounds[0], "/count") > 0.0);
        assert!(number(latency, "/p999_us") >= number(latency, "/p50_us"));
    }
    assert_eq!(comparison["armtwin"]["totals"]["events"], 0);
    assert!(number(&comparison["armtwin"], "/totals/metrics") > 0.0);
}

fn number(value: &Value, path: &str) -> f64 {
    value
        .pointer(path)
        .and_then(Value::as_f64)
        .unwrap_or_else(|| panic!("{path} is not a number in {value:#}"))
}

/// The paced comparison of 4 robots × 10 Hz, one 0.5-s round: the same schedule to both, every
/// reply back, CPU and latency measured for each.
fn assert_paced(paced: &Value) {
    assert_eq!(paced["robots"], 4);
    assert_eq!(paced["rate"], 40.0);
    assert_eq!(paced["echo_lost"], 0);
    assert_eq!(paced["armtwin_lost"], 0);
    for system in ["echo", "armtwin"] {
        // CPU time counts in clock ticks: the echo's 0.5 s at 40 samples/s may take none.
        assert!(
            number(paced, &format!("/{system}_cores")) >= 0.0,
            "{system}"
        );
        let rounds = paced[format!("{system}_latency")]["rounds"]
            .as_array()
            .expect("paced rounds");
        assert_eq!(rounds.len(), 1, "{system}: one measured round");
        // 40 samples/s for 0.5 s, each timed.
        assert_eq!(rounds[0]["count"], 20, "{system}");
    }
    number(paced, "/p99_ratio");
}

/// Memory per streaming robot, 4 robots at 20 Hz for 11 s of source time, each sample answered
/// by both systems (the load fails otherwise); then 5 robots streaming at the same rate.
fn assert_streaming(report: &Value) {
    let streaming = report["streaming_memory"]
        .as_array()
        .expect("streaming_memory");
    assert_eq!(streaming.len(), 1, "one rate");
    let row = &streaming[0];
    assert_eq!(row["hz_per_robot"], 20.0);
    assert_eq!(row["armtwin"]["samples_per_robot"], 220);
    assert_eq!(row["armtwin"]["stream_hz"], 20.0);
    assert_eq!(row["armtwin"]["robots"], 4);
    assert_eq!(row["echo"]["robots"], 4);
    number(row, "/added_bytes_per_robot");
    assert_eq!(report["streaming_fleet"]["robots"], 5);
    assert!(number(report, "/streaming_fleet/rss_full_kib") > 0.0);
}

#[test]
fn a_quick_run_reports_every_figure_and_loses_nothing() {
    let bench = PathBuf::from(env!("CARGO_BIN_EXE_armtwin-bench"));
    let armtwin = armtwin_binary(&bench);
    let dir = tempfile::tempdir().expect("temporary directory");
    let out = dir.path().join("bench.json");
    let status = Command::new(&bench)
        .arg("run")
        .arg("--quick")
        .args([
            "--robots",
            "1,3",
            "--memory-robots",
            "6",
            "--memory-base-robots",
            "2",
        ])
        .args(["--memory-stream-robots", "4", "--memory-stream-hz", "20"])
        .args(["--memory-stream-fleet-robots", "5"])
        .args(["--encodings", "json,zenoh-serialized", "--gateways", "1,2"])
        .args([
            "--start-rate",
            "40",
            "--max-rate",
            "40",
            "--duration",
            "0.25",
        ])
        .args(["--latency-rate", "40", "--latency-duration", "0.25"])
        .args(["--fleet-hz", "10", "--fleet-duration", "0.3"])
        .args([
            "--paced-robots",
            "4",
            "--paced-hz",
            "10",
            "--paced-duration",
            "0.5",
        ])
        .arg("--armtwin")
        .arg(&armtwin)
        .arg("--out")
        .arg(&out)
        .status()
        .expect("running armtwin-bench");
    assert!(status.success(), "armtwin-bench run failed: {status}");
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(&out).expect("bench.json")).expect("JSON");

    // The headline figures, at the largest robot count.
    assert_eq!(report["headline_robots"], 3);
    assert_eq!(report["headline_encoding"], "zenoh-serialized");
    for field in ["echo_throughput", "armtwin_throughput", "throughput_ratio"] {
        assert!(number(&report, &format!("/{field}")) > 0.0, "{field}");
    }
    number(&report, "/added_latency_p99_us");
    number(&report, "/bytes_per_robot");

    // Both systems sustained the trivially low rate in every row: every pose and deviation came
    // back, and armtwin raised no event. Rows: each robot count in each encoding over one
    // gateway, then the largest over two in the last encoding.
    let by_robots = report["by_robots"].as_array().expect("by_robots");
    let rows: Vec<(u64, &str, u64)> = by_robots
        .iter()
        .map(|c| {
            (
                c["robots"].as_u64().expect("robots"),
                c["encoding"].as_str().expect("encoding"),
                c["gateways"].as_u64().expect("gateways"),
            )
        })
        .collect();
    assert_eq!(
        rows,
        [
            (1, "json", 1),
            (3, "json", 1),
            (1, "zenoh-serialized", 1),
            (3, "zenoh-serialized", 1),
            (3, "zenoh-serialized", 2),
        ]
    );
    for comparison in by_robots {
        assert_row_lossless(comparison, 1);
    }

    // The fleet check rides on the row of the most gateways, embedded samples.
    assert_eq!(report["fleet"]["robots"], 3);
    assert_eq!(report["fleet"]["gateways"], 2);
    assert!(report["fleet"]["armtwin_sustained"].is_boolean());
    let fleet_row = &by_robots[4];
    assert_lossless(&fleet_row["echo"]["check"], "echo", false);
    assert_lossless(&fleet_row["armtwin"]["check"], "armtwin", true);

    // First contact: every robot new, every reply awaited.
    let contact = &report["first_contact"][0];
    assert_eq!(contact["robots"], 3);
    assert_lossless(&contact["echo"], "echo --lazy", true);
    assert_lossless(&contact["armtwin"], "armtwin", true);
    assert!(number(contact, "/ratio") > 0.0);

    assert_paced(&report["paced"]);

    // Memory, the robots' declaration and the restart on the snapshot.
    assert_eq!(report["memory"]["memory"]["robots"], 6);
    assert_eq!(report["memory"]["gateways"], 2);
    assert!(number(&report, "/declare_s") > 0.0);
    assert!(number(&report, "/restart_s") > 0.0);
    number(&report, "/echo_bytes_per_robot");

    assert_streaming(&report);

    let targets = report["targets"].as_array().expect("targets");
    assert!(targets.len() >= by_robots.len() + 8, "{targets:#?}");
    assert!(number(&report, "/wall_s") > 0.0);
}

/// Binary in and out, two gateway sessions: every reply of every load process comes back and
/// armtwin raises no event, so each load process took up each robot's gateway `seq` where the
/// one before left it.
#[test]
fn a_quick_zenoh_serialized_run_loses_nothing_and_raises_no_event() {
    let bench = PathBuf::from(env!("CARGO_BIN_EXE_armtwin-bench"));
    let armtwin = armtwin_binary(&bench);
    let dir = tempfile::tempdir().expect("temporary directory");
    let out = dir.path().join("bench.json");
    let status = Command::new(&bench)
        .arg("run")
        .arg("--quick")
        .args(["--encoding", "zenoh-serialized", "--robots", "2"])
        .args(["--gateways", "2", "--first-contact-robots", "0"])
        .args(["--memory-robots", "0", "--fleet-duration", "0"])
        .args(["--paced-duration", "0", "--memory-stream-robots", "0"])
        .args(["--memory-stream-fleet-robots", "0"])
        .args([
            "--start-rate",
            "40",
            "--max-rate",
            "40",
            "--duration",
            "0.25",
        ])
        .args(["--latency-rate", "40", "--latency-duration", "0.25"])
        .args(["--latency-rounds", "2"])
        .arg("--armtwin")
        .arg(&armtwin)
        .arg("--out")
        .arg(&out)
        .status()
        .expect("running armtwin-bench");
    assert!(status.success(), "armtwin-bench run failed: {status}");
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(&out).expect("bench.json")).expect("JSON");
    assert_eq!(report["settings"]["encodings"][0], "zenoh-serialized");
    let comparison = &report["by_robots"][0];
    assert_eq!(comparison["gateways"], 2);
    for system in ["echo", "armtwin"] {
        let rounds = comparison[format!("{system}_latency")]["rounds"]
            .as_array()
            .expect("latency rounds");
        assert_eq!(rounds.len(), 2);
        assert!(number(&rounds[1], "/count") > 0.0, "{system}: poses timed");
        for trial in comparison[system]["search"]["trials"]
            .as_array()
            .expect("trials")
            .iter()
            .chain(rounds.iter().map(|round| &round["trial"]))
        {
            assert_eq!(trial["lost"], 0, "{system}: {trial:#}");
        }
    }
    assert_eq!(comparison["armtwin"]["totals"]["events"], 0);
    assert!(
        report["paced"].is_null(),
        "the paced comparison was skipped"
    );
    assert_eq!(report["streaming_memory"], serde_json::json!([]));
    assert!(report["streaming_fleet"].is_null());
}

/// Far above what armtwin needs for a few robots: a bound that only a leak of megabytes per
/// second crosses.
const SOAK_RSS_BOUND_MIB: f64 = 200.0;

/// Thirty seconds of the soak at a low rate, a third of the robots replaced by new ones every
/// ten seconds and retired three seconds after they leave, `/metrics` scraped and the dashboard
/// fetched every second: nothing lost, memory bounded, every interval reported with the robots
/// tracked, the robots that left forgotten, the curves written.
#[test]
fn a_thirty_second_soak_with_churn_loses_nothing_and_stays_bounded() {
    let bench = PathBuf::from(env!("CARGO_BIN_EXE_armtwin-bench"));
    let armtwin = armtwin_binary(&bench);
    let dir = tempfile::tempdir().expect("temporary directory");
    let out = dir.path().join("soak.json");
    let svg = dir.path().join("soak.svg");
    let status = Command::new(&bench)
        .arg("soak")
        .args(["--robots", "6", "--hz", "20", "--gateways", "2"])
        .args(["--duration", "30", "--interval", "5", "--warm-up", "10"])
        .args(["--churn", "0.34", "--churn-period", "10"])
        .args(["--scrape-interval", "1", "--dashboard-period", "1"])
        .args(["--forget-after", "3"])
        .arg("--armtwin")
        .arg(&armtwin)
        .arg("--out")
        .arg(&out)
        .arg("--svg")
        .arg(&svg)
        .status()
        .expect("running armtwin-bench soak");
    assert!(status.success(), "armtwin-bench soak failed: {status}");
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(&out).expect("soak.json")).expect("JSON");

    let summary = &report["summary"];
    assert_eq!(summary["lost"], 0, "{summary:#}");
    assert_eq!(summary["sent"], 6 * 20 * 30);
    assert!(
        number(summary, "/rss_max_mib") < SOAK_RSS_BOUND_MIB,
        "{summary:#}"
    );
    assert_eq!(
        report["load"]["churned"], 4,
        "two robots replaced at 10 s and at 20 s"
    );
    assert_eq!(report["load"]["ids_used"], 10);

    let rows = report["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 6);
    for row in rows {
        assert!(number(row, "/robots_tracked") >= 1.0, "{row:#}");
        assert!(number(row, "/rss_mib") > 0.0);
        assert!(number(row, "/max_us") >= number(row, "/p50_us"));
    }
    let last = rows.last().expect("a last row");
    assert!(
        number(last, "/robots_tracked") < 10.0,
        "the four robots that left 10 s and more before the end are retired: {last:#}"
    );
    let watchers = &report["watchers"];
    assert!(number(watchers, "/scrapes") > 0.0, "{watchers:#}");
    assert!(number(watchers, "/dashboard_fetches") > 0.0, "{watchers:#}");
    assert_eq!(report["targets"].as_array().expect("targets").len(), 3);

    let curves = std::fs::read_to_string(&svg).expect("soak.svg");
    assert_eq!(
        curves.matches(r#"class="series""#).count(),
        4,
        "RSS, p99, p50, tracked"
    );
}
