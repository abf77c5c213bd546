//! Smoke test of the benchmark harness: `armtwin-bench run --quick` end to end with tiny numbers,
//! real processes and real Zenoh sessions over loopback. It checks the report's structure and
//! that nothing was lost at a trivially low rate; it asserts no timing.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

/// The `armtwin` binary of this build profile: `cargo test --workspace` builds it (armtwin's own
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

fn number(value: &Value, path: &str) -> f64 {
    value
        .pointer(path)
        .and_then(Value::as_f64)
        .unwrap_or_else(|| panic!("{path} is not a number in {value:#}"))
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
    for field in ["echo_throughput", "armtwin_throughput", "throughput_ratio"] {
        assert!(number(&report, &format!("/{field}")) > 0.0, "{field}");
    }
    number(&report, "/added_latency_p99_us");
    number(&report, "/bytes_per_robot");

    // Both systems sustained the trivially low rate at every robot count: every pose and
    // deviation came back, and armtwin raised no event.
    let by_robots = report["by_robots"].as_array().expect("by_robots");
    assert_eq!(by_robots.len(), 2);
    for comparison in by_robots {
        for system in ["echo", "armtwin"] {
            let load = &comparison[system];
            let latency = &comparison[format!("{system}_latency")];
            let rounds = latency["rounds"].as_array().expect("latency rounds");
            assert_eq!(rounds.len(), 1);
            let trials = load["search"]["trials"].as_array().expect("trials");
            assert!(!trials.is_empty());
            for trial in trials
                .iter()
                .chain(rounds.iter().map(|round| &round["trial"]))
            {
                assert_eq!(trial["lost"], 0, "{system}: {trial:#}");
                assert_eq!(trial["replies"]["poses"], trial["samples"], "{system}");
                assert_eq!(trial["replies"]["deviations"], trial["samples"], "{system}");
            }
            assert!(number(&rounds[0], "/count") > 0.0);
            assert!(number(latency, "/p999_us") >= number(latency, "/p50_us"));
        }
        assert_eq!(comparison["armtwin"]["totals"]["events"], 0);
        assert!(number(&comparison["armtwin"], "/totals/metrics") > 0.0);
    }
    assert_eq!(report["fleet"]["robots"], 3);
    assert!(report["fleet"]["armtwin_sustained"].is_boolean());
    assert_eq!(report["memory"]["memory"]["robots"], 6);
}

/// Binary in and out: every reply of every load process comes back and armtwin raises no event,
/// so each load process took up each robot's gateway `seq` where the one before left it.
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
        .args(["--memory-robots", "0", "--fleet-duration", "0"])
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
    assert_eq!(report["settings"]["encoding"], "zenoh-serialized");
    let comparison = &report["by_robots"][0];
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
}
