//! `armtwin validate`'s library side: every malformed-row class, column mapping, the report files
//! and the gate (its exit status is tested with the binary, in armtwin-cli; the figures on real
//! data are checked against numpy in `tests/python`).

use std::collections::BTreeMap;
use std::sync::Arc;

use armtwin_codec::json::MetricsMessage;
use armtwin_codec::recording::{self, ColumnMap, PoseForm};
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::{AlarmConfig, PipelineConfig, RobotSettings};
use armtwin_offline::validate::report::{self, Context, PLOT_FILES};
use armtwin_offline::validate::{Validation, validate};
use serde_json::Value;

const Q: [f64; 6] = [0.1, -1.2, 1.3, -1.5, -1.6, 0.2];

fn settings() -> RobotSettings {
    RobotSettings {
        model: Arc::new(RobotModel::nominal("ur10e").expect("catalog")),
        alarm: AlarmConfig::default(),
        sensors: Vec::new(),
        self_calibration: None,
        effort: None,
    }
}

fn run(text: &str, map: Option<&ColumnMap>) -> Validation {
    let recording = recording::read_with(text, map).expect("recognised");
    let times = recording::source_times(&recording, None);
    validate(
        &recording,
        &times,
        PipelineConfig::default(),
        settings(),
        |_| {},
    )
}

/// `x,y,z,qx,qy,qz,qw` of the twin at [`Q`], as a recording would hold it.
fn measured_cells() -> [String; 7] {
    let pose = settings().model.pose(&Q).expect("fk").readout();
    let [x, y, z] = pose.position_m;
    let [qx, qy, qz, qw] = pose.quaternion_xyzw;
    [x, y, z, qx, qy, qz, qw].map(|v| v.to_string())
}

fn joined(q: &[f64]) -> String {
    q.iter().map(f64::to_string).collect::<Vec<_>>().join(",")
}

/// A recording in the UR10e FMU report's CSV form with one line of every bad-input class, and the cause each raises.
fn recording_with_every_bad_line() -> (String, Vec<(u64, &'static str)>) {
    let m = measured_cells();
    let m_all = m.join(",");
    let q = joined(&Q);
    let lines = [
        "time,q1,q2,q3,q4,q5,q6,x,y,z,qx,qy,qz,qw".to_owned(),
        format!("0.0,{q},{m_all}"),
        format!("0.1,{q},{m_all},9"),
        format!("0.2,{q}"),
        format!("0.3,0.1,abc,1.3,-1.5,-1.6,0.2,{m_all}"),
        format!("0.4,0.1,,1.3,-1.5,-1.6,0.2,{m_all}"),
        format!("0.5,0.1,nan,1.3,-1.5,-1.6,0.2,{m_all}"),
        format!("0.6,0.1,7.0,1.3,-1.5,-1.6,0.2,{m_all}"),
        format!("0.7,{q},{},{},{},0,0,0,2", m[0], m[1], m[2]),
        format!("0.8,{q},{},{},oops,{}", m[0], m[1], m[3..].join(",")),
        format!("0.9,{q},500,0,0,{}", m[3..].join(",")),
        format!("0.85,{q},{m_all}"),
        format!("1.0,{q},{m_all}"),
        String::new(),
        format!("1.1,{q},{m_all}"),
        format!("1.2,{q},inf,0,0,0,0,0,1"),
    ];
    let expected = vec![
        (3, "not_json"),
        (4, "not_json"),
        (5, "wrong_type"),
        (6, "wrong_type"),
        (7, "wrong_type"),
        (8, "joint_limits"),
        (9, "quaternion_norm"),
        (10, "wrong_type"),
        (11, "out_of_range"),
        (12, "out_of_order"),
        (16, "wrong_type"),
    ];
    (lines.join("\n") + "\n", expected)
}

#[test]
fn every_bad_line_is_counted_with_its_line_and_never_stops_the_run() {
    let (text, expected) = recording_with_every_bad_line();
    let v = run(&text, None);
    let got: Vec<(u64, &str)> = v.rejections.iter().map(|r| (r.line, r.cause)).collect();
    assert_eq!(got, expected);
    assert_eq!(v.malformed_lines, [3, 4]);
    assert_eq!(v.metrics.rejected, expected.len() as u64);
    // Rows 2, 13, 15 pair exactly; an invalid measured part (9, 10, 11, 16) keeps the twin pose.
    let paired: Vec<u64> = v
        .rows
        .iter()
        .filter(|r| r.paired.is_some())
        .map(|r| r.line)
        .collect();
    assert_eq!(paired, [2, 13, 15]);
    let posed: Vec<u64> = v
        .rows
        .iter()
        .filter(|r| r.twin.is_some())
        .map(|r| r.line)
        .collect();
    assert_eq!(posed, [2, 9, 10, 11, 13, 15, 16]);
    // Line 8's joints are out of limits but its measured pose is valid input: it waits for
    // joints, and the next ones are too far away (0.6 s → 0.7 s is fine, but 0.0 → 0.7 s is a
    // gap), so it ends unpaired, as in the service.
    assert_eq!(v.metrics.unpaired, 1);
    assert_eq!(v.events.unpaired, 1);
    assert!(v.metrics.cumulative.stats[0].max < 1e-12);
    // The blank line is not a data line.
    assert_eq!(v.rows.len(), 14);
    let reason = &v.rejections[4].reason;
    assert!(reason.contains("\"nan\""), "{reason}");
    assert!(
        v.rejections[0]
            .reason
            .contains("15 columns, the header has 14"),
        "{}",
        v.rejections[0].reason
    );
}

#[test]
fn mapped_columns_in_milliseconds_with_rpy() {
    let mut text = String::from("stamp_ms;note;J0;J1;J2;J3;J4;J5;X;Y;Z;R;P;W\n");
    for k in 0..5 {
        let q = Q.map(|v| v + f64::from(k) * 1e-3);
        let p = settings().model.pose(&q).expect("fk").readout();
        let [x, y, z] = p.position_m;
        let cells: Vec<String> = [f64::from(k) * 8.0]
            .into_iter()
            .map(|v| v.to_string())
            .chain(["ok".to_owned()])
            .chain(q.iter().map(f64::to_string))
            .chain(
                [x, y, z, p.rpy.roll_rad, p.rpy.pitch_rad, p.rpy.yaw_rad]
                    .iter()
                    .map(f64::to_string),
            )
            .collect();
        text.push_str(&cells.join(" "));
        text.push('\n');
    }
    let names = |s: &str| s.split(',').map(str::to_owned).collect::<Vec<_>>();
    let map = ColumnMap {
        time: Some("stamp_ms".to_owned()),
        time_scale_s: 1e-3,
        joints: names("J0,J1,J2,J3,J4,J5"),
        pose: Some((PoseForm::Rpy, names("X,Y,Z,R,P,W"))),
    };
    // Semicolons are not a separator armtwin knows: the header is one column and J0 is missing.
    assert!(recording::read_with(&text, Some(&map)).is_err());
    let text = text.replace(';', " ");
    let v = run(&text, Some(&map));
    assert_eq!(v.metrics.paired, 5, "{:?}", v.rejections);
    assert!(v.metrics.cumulative.stats[0].max < 1e-12);
    assert!(v.metrics.cumulative.stats[5].max < 1e-7);
    assert!((v.rows[4].stamp_s - 0.032).abs() < 1e-15);
    let wrong = ColumnMap {
        pose: Some((PoseForm::Quaternion, names("X,Y,Z,R,P,W"))),
        ..map
    };
    let error = recording::read_with(&text, Some(&wrong)).expect_err("6 names for 7 columns");
    assert!(
        error.to_string().contains("7 columns, 6 were named"),
        "{error}"
    );
}

#[test]
fn report_files_carry_the_services_metrics_shape_and_every_row() {
    let (text, expected) = recording_with_every_bad_line();
    let v = run(&text, None);
    let dir = tempfile::tempdir().expect("tmp");
    let model = settings().model;
    let context = Context {
        recording: "bad.csv",
        model: &model,
        max_position_error_m: Some(0.001),
        max_angle_error_rad: None,
        dynamics: None,
    };
    let (json, written) = report::write_all(dir.path(), &v, &context).expect("written");
    assert_eq!(written.len(), 3 + PLOT_FILES.len());
    assert!(json.gate.passed, "{:?}", json.gate);
    let report: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("report.json")).expect("json"))
            .expect("parses");
    let service = serde_json::to_value(MetricsMessage::new(&v.metrics)).expect("json");
    assert_eq!(report["cumulative"], service["cumulative"]);
    for (field, value) in [
        ("rows", 14),
        ("poses", 7),
        ("paired", 3),
        ("rejected", expected.len() as u64),
    ] {
        assert_eq!(report[field], value, "{field}");
    }
    let by_cause: BTreeMap<String, u64> =
        serde_json::from_value(report["rejected_by_cause"].clone()).expect("map");
    assert_eq!(by_cause["wrong_type"], 5);
    assert_eq!(report["malformed"]["lines"], serde_json::json!([3, 4]));
    let csv = std::fs::read_to_string(dir.path().join("rows.csv")).expect("csv");
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 1 + 14);
    let header: Vec<&str> = lines[0].split(',').collect();
    assert!(lines.iter().all(|l| l.split(',').count() == header.len()));
    assert!(lines[8].starts_with("9,") && lines[8].ends_with(",quaternion_norm"));
    let md = std::fs::read_to_string(dir.path().join("report.md")).expect("md");
    assert!(md.contains("| Position error (mm) |"), "{md}");
    assert!(md.contains("The gate passed"), "{md}");
    for plot in PLOT_FILES {
        let svg = std::fs::read_to_string(dir.path().join(plot)).expect("svg");
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    }
}

#[test]
fn joints_only_recordings_yield_poses_and_no_gate_can_pass_without_pairs() {
    let q = joined(&Q);
    let text = format!("time,q1,q2,q3,q4,q5,q6\n0.0,{q}\n0.1,{q}\n0.2,{q}\n");
    let v = run(&text, None);
    assert_eq!((v.poses(), v.metrics.paired, v.metrics.rejected), (3, 0, 0));
    assert!(!v.has_pose);
    let model = settings().model;
    let dir = tempfile::tempdir().expect("tmp");
    let mut context = Context {
        recording: "joints.csv",
        model: &model,
        max_position_error_m: None,
        max_angle_error_rad: None,
        dynamics: None,
    };
    let (json, _) = report::write_all(dir.path(), &v, &context).expect("written");
    assert!(json.gate.passed);
    let md = std::fs::read_to_string(dir.path().join("report.md")).expect("md");
    assert!(md.contains("only twin poses were computed"), "{md}");
    let csv = std::fs::read_to_string(dir.path().join("rows.csv")).expect("csv");
    let expected = settings().model.pose(&Q).expect("fk").readout().position_m[0];
    let second = csv
        .lines()
        .nth(1)
        .expect("row")
        .split(',')
        .nth(2)
        .expect("x");
    assert_eq!(
        second.parse::<f64>().expect("number").to_bits(),
        expected.to_bits(),
        "written in shortest round-trip form"
    );
    context.max_position_error_m = Some(1.0);
    let (json, _) = report::write_all(dir.path(), &v, &context).expect("written");
    assert!(
        !json.gate.passed,
        "a gate with nothing to check must not pass"
    );
}
