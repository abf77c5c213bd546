//! `armtwin validate` from the command line: the gate's exit status, unusable files, and a rosbag2
//! recording validating as its CSV export does.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn armtwin(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_armtwin"))
        .args(args)
        .output()
        .expect("armtwin runs")
}

#[test]
fn the_gate_sets_the_exit_status() {
    let data =
        Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join("tests/data/fmpy_inputs.csv");
    let data = data.to_str().expect("utf-8 path");
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("report");
    let out = out.to_str().expect("utf-8 path");
    let pass = armtwin(&[
        "validate",
        data,
        "--period",
        "0.1",
        "--out",
        out,
        "--max-position-error",
        "0.002",
    ]);
    assert_eq!(pass.status.code(), Some(0), "{pass:?}");
    let fail = armtwin(&[
        "validate",
        data,
        "--period",
        "0.1",
        "--out",
        out,
        "--max-angle-error",
        "0.001",
    ]);
    assert_eq!(fail.status.code(), Some(3), "{fail:?}");
    let stderr = String::from_utf8_lossy(&fail.stderr);
    assert!(stderr.contains("exceeds --max-angle-error"), "{stderr}");
    let report: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("report/report.json")).expect("r"))
            .expect("json");
    assert_eq!(report["gate"]["passed"], false);
    // An unusable file is an error (exit 1), not a failed gate.
    let empty = dir.path().join("empty.csv");
    std::fs::write(&empty, "\n\n").expect("write");
    let unusable = armtwin(&["validate", empty.to_str().expect("utf-8"), "--out", out]);
    assert_eq!(unusable.status.code(), Some(1), "{unusable:?}");
    assert!(String::from_utf8_lossy(&unusable.stderr).contains("the recording is empty"));
    let unknown = dir.path().join("unknown.csv");
    std::fs::write(&unknown, "a,b,c\n1,2,3\n").expect("write");
    let unusable = armtwin(&["validate", unknown.to_str().expect("utf-8"), "--out", out]);
    assert_eq!(unusable.status.code(), Some(1), "{unusable:?}");
    assert!(String::from_utf8_lossy(&unusable.stderr).contains("header not recognised"));
}

fn ros2_fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/ros2")
}

#[test]
fn validate_takes_a_bag_on_the_command_line() {
    let out = tempfile::tempdir().expect("temporary directory");
    let output = Command::new(env!("CARGO_BIN_EXE_armtwin"))
        .arg("validate")
        .arg(ros2_fixtures().join("ur10e_lasttest_head_mcap"))
        .arg("--out")
        .arg(out.path())
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(
        stderr.contains("Mcap storage, 400 joint messages, 400 poses"),
        "{stderr}"
    );
    let csv = tempfile::tempdir().expect("temporary directory");
    let from_csv = Command::new(env!("CARGO_BIN_EXE_armtwin"))
        .arg("validate")
        .arg(ros2_fixtures().join("ur10e_lasttest_head.csv"))
        .arg("--out")
        .arg(csv.path())
        .output()
        .expect("runs");
    assert!(from_csv.status.success());
    let metrics = |dir: &Path| {
        let report: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join("report.json")).expect("report"),
        )
        .expect("JSON");
        [
            "rows",
            "paired",
            "rejected",
            "cumulative",
            "mean_offset_m",
            "t_first",
            "t_last",
        ]
        .map(|key| report[key].clone())
    };
    assert_eq!(metrics(out.path()), metrics(csv.path()));
}
