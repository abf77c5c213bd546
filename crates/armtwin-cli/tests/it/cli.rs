//! The `armtwin` binary end to end: output shapes, CSV mode, exit codes and error messages.

use std::io::Write;
use std::path::Path;
use std::process::{Command, Output, Stdio};

fn armtwin(args: &[&str], stdin: Option<&str>) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_armtwin"))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("armtwin runs");
    if let Some(text) = stdin {
        child
            .stdin
            .take()
            .expect("stdin")
            .write_all(text.as_bytes())
            .expect("write stdin");
    }
    drop(child.stdin.take());
    child.wait_with_output().expect("armtwin exits")
}

fn stdout(output: &Output) -> String {
    assert!(
        output.status.success(),
        "failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout.clone()).expect("utf-8")
}

fn failure(args: &[&str], stdin: Option<&str>) -> String {
    let output = armtwin(args, stdin);
    assert!(!output.status.success(), "expected failure for {args:?}");
    String::from_utf8(output.stderr).expect("utf-8")
}

#[test]
fn fk_prints_the_report_names_and_optionally_the_matrix() {
    let text = stdout(&armtwin(
        &[
            "fk", "--model", "ur10e", "0", "-1.2", "0.5", "-0.3", "1", "2",
        ],
        None,
    ));
    let value: serde_json::Value = serde_json::from_str(&text).expect("json");
    let keys: Vec<&str> = value
        .as_object()
        .expect("object")
        .keys()
        .map(String::as_str)
        .collect();
    let mut sorted = keys.clone();
    sorted.sort_unstable();
    assert_eq!(
        sorted,
        [
            "pitch", "qw", "qx", "qy", "qz", "roll", "x", "y", "yaw", "z"
        ]
    );
    let with_matrix = stdout(&armtwin(
        &[
            "fk", "--matrix", "--deg", "--", "0", "-90", "0", "-90", "0", "0",
        ],
        None,
    ));
    let value: serde_json::Value = serde_json::from_str(&with_matrix).expect("json");
    let matrix = value["matrix"].as_array().expect("matrix");
    assert_eq!(matrix.len(), 4);
    assert_eq!(matrix[3], serde_json::json!([0.0, 0.0, 0.0, 1.0]));
    // Upright UR10e (the default model): z = d1 − a2 − a3 + d5.
    assert!((value["z"].as_f64().expect("z") - 1.4848).abs() < 1e-12);
}

#[test]
fn fk_csv_reads_a_recording_and_writes_one_row_per_row() {
    let recording =
        Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join("tests/data/fmpy_inputs.csv");
    let text = stdout(&armtwin(
        &[
            "fk",
            "--model",
            "ur10e",
            "--csv",
            recording.to_str().expect("path"),
        ],
        None,
    ));
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "time,x,y,z,roll,pitch,yaw,qx,qy,qz,qw");
    assert_eq!(lines.len(), 55);
    assert!(lines[1].starts_with("1.0,"), "{}", lines[1]);
    // Stdin, no time column: time is the row index.
    let text = stdout(&armtwin(
        &["fk", "--csv", "-"],
        Some("q1,q2,q3,q4,q5,q6\n0,0,0,0,0,0\n0.1,0,0,0,0,0\n"),
    ));
    let times: Vec<&str> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap_or(""))
        .collect();
    assert_eq!(times, ["0.0", "1.0"]);
}

#[test]
fn fk_errors_are_clear_and_exit_non_zero() {
    assert!(
        failure(&["fk", "0", "0", "0", "0", "0"], None).contains("expected 6 joint angles, got 5")
    );
    assert!(
        failure(&["fk", "0", "0", "NaN", "0", "0", "0"], None)
            .contains("q3 is not a finite number")
    );
    assert!(failure(&["fk", "--model", "ur99", "0"], None).contains("unknown model 'ur99'"));
    assert!(
        failure(
            &["fk", "--tcp", "0,0,0.1,0,0", "0", "0", "0", "0", "0", "0"],
            None
        )
        .contains("expected 6 values")
    );
    assert!(
        failure(
            &["fk", "--csv", "-"],
            Some("q1,q2,q3,q4,q5,q6\n0,0,0,0,0,0\n0,x,0,0,0,0\n")
        )
        .contains("line 3, column 'q2': 'x' is not a number")
    );
    assert!(failure(&["fk", "--csv", "-"], Some("time,q1,q2\n0,0,0\n")).contains("no column 'q3'"));
    assert!(
        failure(
            &[
                "fk",
                "--calibration",
                "/nonexistent/calibration.conf",
                "0",
                "0",
                "0",
                "0",
                "0",
                "0"
            ],
            None
        )
        .contains("cannot read /nonexistent/calibration.conf")
    );
}

#[test]
fn models_lists_the_catalog() {
    let text = stdout(&armtwin(&["models", "--json"], None));
    let value: serde_json::Value = serde_json::from_str(&text).expect("json");
    let models = value.as_array().expect("array");
    assert_eq!(models.len(), 9);
    assert_eq!(models[5]["name"], "ur10e");
    assert_eq!(models[5]["joints"][1]["a_m"], -0.6127);
    assert!(stdout(&armtwin(&["models"], None)).contains("ur16e"));
}

#[test]
fn example_configs_work_as_documented() {
    let root = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."));
    let example = |name: &str| {
        root.join("config/examples")
            .join(name)
            .display()
            .to_string()
    };
    let pose = |args: &[&str]| -> serde_json::Value {
        serde_json::from_str(&stdout(&armtwin(args, None))).expect("json")
    };
    // The two calibration forms of one robot give one pose.
    let q = ["0.1", "-1", "1", "-1", "1", "1"];
    let conf = example("calibration.conf");
    let yaml = example("ur_calibration.yaml");
    let from_conf = pose(&[&["fk", "--calibration", &conf][..], &q].concat());
    let from_yaml = pose(&[&["fk", "--calibration", &yaml][..], &q].concat());
    for key in ["x", "y", "z", "qx", "qy", "qz", "qw"] {
        let (a, b) = (
            from_conf[key].as_f64().expect("num"),
            from_yaml[key].as_f64().expect("num"),
        );
        assert!((a - b).abs() < 1e-9, "{key}: {a} vs {b}");
    }
    // The custom 7-joint modified-DH arm in its ready pose, against an independent numpy
    // evaluation of Craig's convention: flange at (0.3068905665929, 0, 0.5902820523028).
    let panda = example("franka-panda.toml");
    let ready = pose(&[
        "fk",
        "--model",
        &panda,
        "--tcp=0,0,0.107,0,0,0",
        "--deg",
        "0",
        "-45",
        "0",
        "-135",
        "0",
        "90",
        "45",
    ]);
    assert!((ready["x"].as_f64().expect("x") - 0.306_890_566_592_9).abs() < 1e-12);
    assert!(ready["y"].as_f64().expect("y").abs() < 1e-12);
    assert!((ready["z"].as_f64().expect("z") - 0.590_282_052_302_8).abs() < 1e-12);
}

#[test]
fn record_refuses_what_it_cannot_record_before_any_session() {
    let error = failure(&["record", "r1", "-o", "out", "--duration", "0"], None);
    assert!(
        error.contains("--duration must be a positive number"),
        "{error}"
    );
    // `?` is no key expression's: the robots and Zenoh's reason are named.
    let error = failure(&["record", "r1?x", "-o", "out", "--duration", "1"], None);
    assert!(error.contains("robots 'r1?x'"), "{error}");
    let error = failure(&["record", "r1", "-o", "out", "--max-robots", "0"], None);
    assert!(error.contains("--max-robots"), "{error}");
}

#[test]
fn a_bad_zenoh_flag_is_a_clear_error_before_any_session() {
    // Not KEY:VALUE: refused by the argument parser, for every command that opens a session.
    for command in [
        &["serve"][..],
        &["replay", "recording.csv", "--robot", "r1"],
        &["record", "r1", "-o", "recordings"],
    ] {
        let error = failure(&[command, &["--cfg", "shared_memory"]].concat(), None);
        assert!(
            error.contains("'shared_memory' is not KEY:VALUE"),
            "{command:?}: {error}"
        );
    }
    // A key Zenoh does not have, and a value its key does not take: the key and value are named.
    let error = failure(&["serve", "--cfg", "transport/no_such_key:true"], None);
    assert!(
        error.contains("cannot set 'transport/no_such_key' to 'true'")
            && error.contains("no such key"),
        "{error}"
    );
    let error = failure(
        &["serve", "--cfg", "transport/shared_memory/enabled:7"],
        None,
    );
    assert!(
        error.contains("cannot set 'transport/shared_memory/enabled' to '7'")
            && error.contains("expected a boolean"),
        "{error}"
    );
    assert!(
        failure(&["serve", "-m", "hub"], None).contains("possible values: peer, client, router")
    );
}
