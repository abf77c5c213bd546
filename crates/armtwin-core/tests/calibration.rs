//! Factory calibration: both file forms, their equivalence, huge cancelling δd, and the errors.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]

use std::fmt::Write;

use armtwin_core::kinematics::{OutputFrame, Pose, TcpOffset};
use armtwin_core::model::calibration::YAML_SEGMENTS;
use armtwin_core::model::{Calibration, ModelError, RobotModel, catalog, custom};
use armtwin_core::orientation::{Rpy, rpy_from_matrix};
use nalgebra::{Matrix3, Vector3};

struct Deltas {
    theta: [f64; 6],
    a: [f64; 6],
    d: [f64; 6],
    alpha: [f64; 6],
}

fn list(values: &[f64; 6]) -> String {
    let items: Vec<String> = values.iter().map(|v| format!("{v:?}")).collect();
    format!("[ {} ]", items.join(", "))
}

fn conf_text(deltas: &Deltas) -> String {
    format!(
        "# written by a test\n[mounting]\ndelta_theta = {}\ndelta_a = {}\ndelta_d = {}\ndelta_alpha = {}\njoint_checksum = [ 1, 2, 3, 4, 5, 6 ]\n\n[other]\ndelta_d = [ 1 ]\n",
        list(&deltas.theta),
        list(&deltas.a),
        list(&deltas.d),
        list(&deltas.alpha)
    )
}

fn calibrated(model: &str, text: &str) -> RobotModel {
    let calibration = Calibration::parse(text, "test.calibration").expect("parses");
    RobotModel::new(
        catalog::arm(model).expect("catalog"),
        Some(calibration),
        TcpOffset::FLANGE,
        OutputFrame::Base,
    )
    .expect("fits")
}

/// Deterministic joint configurations spread over the joint ranges.
fn configurations(count: usize) -> Vec<[f64; 6]> {
    let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 * 12.0 - 6.0
    };
    (0..count)
        .map(|_| [next(), next(), next(), next(), next(), next()])
        .collect()
}

fn max_difference(a: &RobotModel, b: &RobotModel) -> (f64, f64) {
    let mut worst = (0.0_f64, 0.0_f64);
    for q in configurations(500) {
        let (pa, pb): (Pose, Pose) = (a.pose(&q).expect("valid"), b.pose(&q).expect("valid"));
        worst.0 = worst.0.max((pa.position_m - pb.position_m).norm());
        worst.1 = worst.1.max((pa.rotation - pb.rotation).norm());
    }
    worst
}

const SMALL: Deltas = Deltas {
    theta: [1.2e-6, 3.1e-4, -2.2e-4, 1.5e-4, -3.1e-6, 2.0e-6],
    a: [2.5e-5, -4.5e-4, 2.5e-4, 8.6e-5, 5.9e-5, 0.0],
    d: [1.3e-4, 2.0e-4, -1.0e-4, 3.0e-4, -6.5e-5, 2.0e-4],
    alpha: [-2.2e-4, 0.0, 0.0, 5.6e-4, 5.4e-4, 0.0],
};

#[test]
fn zero_deltas_equal_nominal() {
    let zero = Deltas {
        theta: [0.0; 6],
        a: [0.0; 6],
        d: [0.0; 6],
        alpha: [0.0; 6],
    };
    for entry in &catalog::UNIVERSAL_ROBOTS {
        let nominal = RobotModel::nominal(entry.name).expect("catalog");
        let with_zero = calibrated(entry.name, &conf_text(&zero));
        assert_eq!(
            max_difference(&nominal, &with_zero),
            (0.0, 0.0),
            "{}",
            entry.name
        );
    }
}

#[test]
fn large_cancelling_delta_d_equals_small_parameters() {
    // Joints 2–4 have parallel axes when α₂ = α₃ = 0: translations along them add, so moving
    // hundreds of metres between d₂, d₃ and d₄ leaves the kinematics unchanged. Real files look
    // like this; f64 must keep the pose to far below a micrometre.
    let mut large = SMALL;
    large.d[1] += 412.371_5;
    large.d[2] += -763.002_25;
    large.d[3] += 350.630_75;
    let small = calibrated("ur10e", &conf_text(&SMALL));
    let huge = calibrated("ur10e", &conf_text(&large));
    let (position_m, rotation) = max_difference(&small, &huge);
    assert!(position_m < 1e-9, "position differs by {position_m} m");
    assert!(rotation < 1e-12, "rotation differs by {rotation}");
    // And the calibration matters: it is not the nominal arm.
    let (moved_m, _) = max_difference(&small, &RobotModel::nominal("ur10e").expect("catalog"));
    assert!(
        moved_m > 1e-4,
        "calibration moved the TCP by only {moved_m} m"
    );
}

/// `Tx(a) · Rx(α) · Rz(θ) · Tz(d)` as a URDF origin `(x, y, z, roll, pitch, yaw)`.
fn origin(a: f64, alpha: f64, theta: f64, d: f64) -> [f64; 6] {
    let (sa, ca) = alpha.sin_cos();
    let (st, ct) = theta.sin_cos();
    let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, ca, -sa, 0.0, sa, ca);
    let rz = Matrix3::new(ct, -st, 0.0, st, ct, 0.0, 0.0, 0.0, 1.0);
    let translation = Vector3::new(a, 0.0, 0.0) + rx * Vector3::new(0.0, 0.0, d);
    let Rpy {
        roll_rad,
        pitch_rad,
        yaw_rad,
    } = rpy_from_matrix(&(rx * rz));
    [
        translation.x,
        translation.y,
        translation.z,
        roll_rad,
        pitch_rad,
        yaw_rad,
    ]
}

/// The `ur_calibration` YAML of a standard-DH table with deltas: `O₁ = Rz(θ₁)·Tz(d₁)`,
/// `Oᵢ = Tx(aᵢ₋₁)·Rx(αᵢ₋₁)·Rz(θᵢ)·Tz(dᵢ)` (exact when δa₆ = δα₆ = 0, as on real robots).
fn yaml_from_deltas(model: &str, deltas: &Deltas) -> String {
    let arm = catalog::arm(model).expect("catalog");
    let a: Vec<f64> = (0..6).map(|i| arm.dh[i].a_m + deltas.a[i]).collect();
    let alpha: Vec<f64> = (0..6)
        .map(|i| arm.dh[i].alpha_rad + deltas.alpha[i])
        .collect();
    let d: Vec<f64> = (0..6).map(|i| arm.dh[i].d_m + deltas.d[i]).collect();
    let mut text = String::from("kinematics:\n");
    for (i, segment) in YAML_SEGMENTS.iter().enumerate() {
        let values = if i == 0 {
            origin(0.0, 0.0, deltas.theta[0], d[0])
        } else {
            origin(a[i - 1], alpha[i - 1], deltas.theta[i], d[i])
        };
        writeln!(text, "  {segment}:").expect("string");
        for (key, value) in ["x", "y", "z", "roll", "pitch", "yaw"].iter().zip(values) {
            writeln!(text, "    {key}: {value:?}").expect("string");
        }
    }
    text.push_str("  hash: calib_1234567890\n");
    text
}

#[test]
fn yaml_form_equals_conf_form() {
    let mut large = SMALL;
    large.d[1] += 154.6;
    large.d[2] += -219.5;
    large.d[3] += 64.9;
    large.alpha[1] = 5e-4;
    large.alpha[2] = 2.4e-3;
    for deltas in [SMALL, large] {
        for entry in &catalog::UNIVERSAL_ROBOTS {
            let from_conf = calibrated(entry.name, &conf_text(&deltas));
            let from_yaml = calibrated(entry.name, &yaml_from_deltas(entry.name, &deltas));
            let (position_m, rotation) = max_difference(&from_conf, &from_yaml);
            assert!(position_m < 1e-9, "{}: {position_m} m", entry.name);
            assert!(rotation < 1e-12, "{}: {rotation}", entry.name);
        }
    }
}

#[test]
fn urs_default_kinematics_yaml_equals_the_catalog() {
    // The layout and rounding of UR's own default_kinematics.yaml for the UR30.
    let text = "kinematics:
  shoulder: {x: 0, y: 0, z: 0.23630000000000001, roll: -0, pitch: 0, yaw: -0}
  upper_arm: {x: 0, y: 0, z: 0, roll: 1.570796327, pitch: 0, yaw: -0}
  forearm: {x: -0.637, y: 0, z: 0, roll: -0, pitch: 0, yaw: -0}
  wrist_1: {x: -0.5037, y: 0, z: 0.20100000000000001, roll: -0, pitch: 0, yaw: -0}
  wrist_2: {x: 0, y: -0.1593, z: 0, roll: 1.570796327, pitch: 0, yaw: -0}
  wrist_3:
    x: 0
    y: 0.15429999999999999
    z: -3.1647459019915597e-11
    roll: 1.5707963265897931
    pitch: 3.1415926535897931
    yaw: 3.1415926535897931
  hash: calib_4890363623803256388
";
    let yaml = calibrated("ur30", text);
    let (position_m, rotation) = max_difference(&yaml, &RobotModel::nominal("ur30").expect("ur30"));
    // The file rounds π/2 to 1e-9; over ~1.5 m of arm that is nanometres.
    assert!(position_m < 1e-8, "{position_m} m");
    assert!(rotation < 1e-8, "{rotation}");
}

fn parse_error(text: &str) -> String {
    match Calibration::parse(text, "/robots/r7/calibration.conf") {
        Ok(_) => panic!("expected an error for:\n{text}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn conf_errors_name_file_field_and_problem() {
    let good = conf_text(&SMALL);
    let short = good.replacen(&list(&SMALL.d), "[ 1, 2, 3, 4, 5 ]", 1);
    assert_eq!(
        parse_error(&short),
        "/robots/r7/calibration.conf: [mounting] delta_d: expected 6 values (one per joint), got 5"
    );
    let missing = good.replacen("delta_alpha", "delta_beta", 1);
    assert_eq!(
        parse_error(&missing),
        "/robots/r7/calibration.conf: [mounting] delta_alpha: missing"
    );
    let word = good.replacen("2.5e-5", "2.5e-5x", 1);
    assert!(parse_error(&word).contains("[mounting] delta_a: '2.5e-5x' is not a number"));
    let nan = good.replacen("2.5e-5", "nan", 1);
    assert!(parse_error(&nan).contains("delta_a: value is not finite"));
    let no_section = good.replacen("[mounting]", "[mount]", 1);
    assert!(parse_error(&no_section).ends_with("[mounting]: missing"));
    let duplicate = format!("{good}\n[mounting]\ndelta_d = {}\n", list(&SMALL.d));
    assert!(parse_error(&duplicate).contains("delta_d: given a second time on line"));
    let not_a_list = good.replacen(&list(&SMALL.d), "0.1", 1);
    assert!(parse_error(&not_a_list).contains("delta_d: expected a list"));
    assert!(parse_error("just words\n").contains("line 1"));
}

#[test]
fn multi_line_lists_parse() {
    let text = "[mounting]\ndelta_theta = [ 0, 0, 0,\n  0, 0, 0 ]\ndelta_a = [0,0,0,0,0,0]\ndelta_d = [0,0,0,0,0,0]\ndelta_alpha = [0,0,0,0,0,0]\n";
    let model = calibrated("ur5e", text);
    assert_eq!(
        max_difference(&model, &RobotModel::nominal("ur5e").expect("ur5e")),
        (0.0, 0.0)
    );
}

#[test]
fn yaml_errors_name_file_field_and_problem() {
    let good = yaml_from_deltas("ur10e", &SMALL);
    let parse = |text: &str| {
        Calibration::parse(text, "cal.yaml")
            .expect_err("invalid")
            .to_string()
    };
    let without_wrist_2 = good.replace("  wrist_2:", "  wrist_two:");
    assert_eq!(
        parse(&without_wrist_2),
        "cal.yaml: kinematics.wrist_2: missing"
    );
    let lines: Vec<&str> = good.lines().collect();
    let roll_line = lines
        .iter()
        .position(|l| l.trim_start().starts_with("roll:"))
        .expect("roll");
    let mut edited = lines.clone();
    edited[roll_line] = "    roll: ninety";
    assert_eq!(
        parse(&edited.join("\n")),
        "cal.yaml: kinematics.shoulder.roll: 'ninety' is not a number"
    );
    edited[roll_line] = "    roll: .nan";
    assert!(parse(&edited.join("\n")).contains("kinematics.shoulder.roll: value is not finite"));
    edited.remove(roll_line);
    assert!(parse(&edited.join("\n")).contains("kinematics.shoulder.roll: missing"));
    assert!(parse("kinematics: [unclosed\n").starts_with("cal.yaml: file: not valid YAML"));
}

#[test]
fn calibration_must_fit_the_arm() {
    let modified_arm = custom::parse_arm(
        "name = \"craig\"\nconvention = \"modified\"\n[[joints]]\na = 0\nalpha = 0\nd = 0.1\n",
        "craig.toml",
    )
    .expect("arm");
    let calibration = Calibration::parse(&conf_text(&SMALL), "c.conf").expect("parses");
    let err = RobotModel::new(
        modified_arm,
        Some(calibration),
        TcpOffset::FLANGE,
        OutputFrame::Base,
    )
    .expect_err("one joint");
    assert!(matches!(err, ModelError::CalibrationMismatch { .. }));
    assert!(err.to_string().contains("6 joints"), "{err}");
}
