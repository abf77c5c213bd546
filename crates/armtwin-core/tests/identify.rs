//! Identification: a known calibration recovered from its own synthetic stream (noise, outliers,
//! held-out rows), skew axes fitted and written in `calibration.conf`'s form, too little motion
//! refused.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]

use std::f64::consts::PI;

use armtwin_core::identify::{
    self, IdentifyError, IdentifyOptions, PairedSample, ParameterKind, holdout_start, pose_errors,
};
use armtwin_core::kinematics::{OutputFrame, Pose, TcpOffset};
use armtwin_core::model::calibration::{CalibrationForm, MountingDeltas};
use armtwin_core::model::{Calibration, RobotModel, catalog};
use armtwin_core::orientation;

mod common;

use common::Rng;

fn example() -> Calibration {
    Calibration::parse(
        include_str!("../../../config/examples/calibration.conf"),
        "calibration.conf",
    )
    .unwrap()
}

fn model_with(deltas: Option<MountingDeltas>, tool: TcpOffset) -> RobotModel {
    let calibration = deltas.map(|d| Calibration {
        source_name: "identified".to_owned(),
        form: CalibrationForm::MountingDeltas(d),
    });
    RobotModel::new(
        catalog::arm("ur10e").unwrap(),
        calibration,
        tool,
        OutputFrame::Base,
    )
    .unwrap()
}

fn round_to(value: f64, step: f64) -> f64 {
    (value / step).round() * step
}

/// A pose as a recording holds it: position rounded to `position_step` (m), quaternion
/// components to `quaternion_step`.
fn recorded(pose: &Pose, position_step: f64, quaternion_step: f64) -> Pose {
    let q = orientation::quaternion_to_xyzw(&orientation::quaternion_from_matrix(&pose.rotation))
        .map(|v| round_to(v, quaternion_step));
    Pose {
        position_m: pose.position_m.map(|v| round_to(v, position_step)),
        rotation: orientation::matrix_from_quaternion(
            &orientation::quaternion_from_xyzw(q).unwrap(),
        ),
    }
}

/// A smooth trajectory over the workspace: each joint a sum of two slow sines.
fn trajectory(rng: &mut Rng, rows: usize, amplitude: [f64; 6]) -> Vec<[f64; 6]> {
    let phases: Vec<[f64; 2]> = (0..6)
        .map(|_| [rng.unit() * 2.0 * PI, rng.unit() * 2.0 * PI])
        .collect();
    (0..rows)
        .map(|k| {
            let t = k as f64 / rows as f64;
            std::array::from_fn(|j| {
                let [a, b] = phases[j];
                let base = [0.0, -1.4, 1.3, -1.4, -1.5, 0.0][j];
                base + amplitude[j]
                    * (0.6 * (2.0 * PI * (3.0 + j as f64) * t + a).sin()
                        + 0.4 * (2.0 * PI * (7.0 + 2.0 * j as f64) * t + b).sin())
            })
        })
        .collect()
}

fn samples_of(
    model: &RobotModel,
    qs: &[[f64; 6]],
    position_step: f64,
    quaternion_step: f64,
) -> Vec<PairedSample> {
    qs.iter()
        .map(|q| PairedSample {
            q_rad: *q,
            measured: recorded(&model.pose(q).unwrap(), position_step, quaternion_step),
        })
        .collect()
}

const WIDE: [f64; 6] = [1.5, 0.8, 1.2, 1.5, 1.5, 2.0];

#[test]
fn the_example_calibration_is_recovered_to_the_noise_floor() {
    let CalibrationForm::MountingDeltas(true_deltas) = example().form else {
        panic!("conf form");
    };
    let truth = model_with(Some(true_deltas), TcpOffset::FLANGE);
    let mut rng = Rng(3);
    let qs = trajectory(&mut rng, 6000, WIDE);
    // Rounded as a careful RTDE log writes them: 1 µm and 1e-6 per quaternion component.
    let samples = samples_of(&truth, &qs, 1e-6, 1e-6);
    let split = holdout_start(samples.len(), 0.3);
    let fit = identify::identify(
        truth.arm(),
        OutputFrame::Base,
        &TcpOffset::FLANGE,
        &samples[..split],
        &IdentifyOptions::default(),
    )
    .unwrap();
    let identified = model_with(Some(fit.deltas), TcpOffset::FLANGE);
    let nominal = model_with(None, TcpOffset::FLANGE);
    let held_out = &samples[split..];
    let before = pose_errors(&nominal, held_out);
    let after = pose_errors(&identified, held_out);
    let floor = pose_errors(&truth, held_out);
    println!(
        "nominal {before:?}\nidentified {after:?}\ntruth {floor:?}\n{:?}",
        fit.excitation
    );
    // The example's axes 2–4 are skew (its δd of hundreds of metres); fitted with a tilt in
    // place of δd at the parallel axes, the estimate is as good on held-out rows as the truth
    // itself, whose error there is the samples' rounding.
    assert!(floor.position_mae_m < 1e-6, "{floor:?}");
    assert!(
        after.position_mae_m < 2.0 * floor.position_mae_m,
        "{after:?} against {floor:?}"
    );
    assert!(
        after.angle_mae_rad < 2.0 * floor.angle_mae_rad,
        "{after:?} against {floor:?}"
    );
    // The true calibration's FK reproduced on configurations the fit never saw, closer than
    // the rounding of any one sample.
    let fresh = trajectory(&mut Rng(99), 2000, WIDE);
    let (worst_m, worst_rad) = fresh.iter().fold((0.0, 0.0), |(position, angle), q| {
        let (a, b) = (identified.pose(q).unwrap(), truth.pose(q).unwrap());
        let between = orientation::rotation_angle_between(
            &orientation::quaternion_from_matrix(&a.rotation),
            &orientation::quaternion_from_matrix(&b.rotation),
        );
        (
            f64::max(position, (a.position_m - b.position_m).norm()),
            f64::max(angle, between),
        )
    });
    println!("fresh configurations: worst {worst_m:e} m, {worst_rad:e} rad");
    assert!(worst_m < floor.position_max_m, "{worst_m:e} m");
    assert!(worst_rad < floor.angle_max_rad, "{worst_rad:e} rad");
    // The tilts leave nothing indistinguishable, and the written file has the controller's
    // form: the same far common normals as the true file.
    assert_eq!(fit.excitation.identified, fit.excitation.candidates);
    let tilts: Vec<&str> = fit
        .parameters
        .iter()
        .filter(|p| p.kind == ParameterKind::Tilt)
        .map(|p| p.name.as_str())
        .collect();
    assert_eq!(tilts, ["beta[1]", "beta[2]"]);
    for joint in 1..4 {
        let (got, want) = (fit.deltas.delta_d_m[joint], true_deltas.delta_d_m[joint]);
        assert!(
            want.abs() > 10.0 && (got - want).abs() < 1e-3 * want.abs(),
            "delta_d[{joint}] {got} against {want}"
        );
    }
    // What the controller's format reader loads is the fitted chain.
    let written =
        Calibration::parse(&fit.deltas.to_conf_text("identified"), "written.conf").unwrap();
    assert_eq!(written.form, CalibrationForm::MountingDeltas(fit.deltas));
}

#[test]
fn outlier_rows_do_not_pull_the_fit() {
    let deltas = MountingDeltas {
        delta_theta_rad: [2e-4, -1.1e-3, 8e-4, 3e-4, -6e-4, 2e-4],
        delta_a_m: [1e-4, -1.3e-3, 9e-4, 2e-4, 1e-4, 0.0],
        delta_d_m: [3e-4, 0.0, 0.0, 8e-4, -3e-4, 2e-4],
        delta_alpha_rad: [-4e-4, 7e-4, 1.1e-3, 5e-4, -3e-4, 0.0],
    };
    let truth = model_with(Some(deltas), TcpOffset::FLANGE);
    let qs = trajectory(&mut Rng(5), 4000, WIDE);
    let mut samples = samples_of(&truth, &qs, 1e-6, 1e-6);
    // One packet in fifty paired with the joints of the cycle before.
    for k in (50..samples.len()).step_by(50) {
        samples[k].q_rad = qs[k - 1];
    }
    let fit = identify::identify(
        truth.arm(),
        OutputFrame::Base,
        &TcpOffset::FLANGE,
        &samples,
        &IdentifyOptions::default(),
    )
    .unwrap();
    assert!(
        fit.downweighted_rows >= samples.len() / 60,
        "{}",
        fit.downweighted_rows
    );
    let identified = model_with(Some(fit.deltas), TcpOffset::FLANGE);
    let clean = samples_of(&truth, &trajectory(&mut Rng(6), 1000, WIDE), 1e-6, 1e-6);
    let after = pose_errors(&identified, &clean);
    assert!(after.position_max_m < 2e-5, "{after:?}");
}

#[test]
fn the_tool_is_fitted_with_the_arm() {
    let tool = TcpOffset::from_ur_pose([0.01, -0.02, 0.18, 0.1, -0.05, 0.3]).unwrap();
    let deltas = MountingDeltas {
        delta_theta_rad: [2e-4, -1.1e-3, 8e-4, 3e-4, -6e-4, 0.0],
        delta_a_m: [1e-4, -1.3e-3, 9e-4, 2e-4, 1e-4, 0.0],
        delta_d_m: [3e-4, 0.0, 0.0, 8e-4, -3e-4, 0.0],
        delta_alpha_rad: [-4e-4, 7e-4, 1.1e-3, 5e-4, -3e-4, 0.0],
    };
    let truth = model_with(Some(deltas), tool);
    let samples = samples_of(&truth, &trajectory(&mut Rng(8), 4000, WIDE), 1e-6, 1e-6);
    let options = IdentifyOptions {
        fit_tool: true,
        ..IdentifyOptions::default()
    };
    let fit = identify::identify(
        truth.arm(),
        OutputFrame::Base,
        &TcpOffset::FLANGE,
        &samples,
        &options,
    )
    .unwrap();
    let identified = model_with(Some(fit.deltas), fit.tool);
    let fresh = samples_of(&truth, &trajectory(&mut Rng(9), 1000, WIDE), 1e-6, 1e-6);
    let after = pose_errors(&identified, &fresh);
    assert!(after.position_max_m < 2e-5, "{after:?}");
    assert!(after.angle_max_rad < 2e-5, "{after:?}");
}

#[test]
fn too_little_motion_is_refused() {
    let truth = model_with(None, TcpOffset::FLANGE);
    // Only the base and the last wrist turn.
    let samples = samples_of(
        &truth,
        &trajectory(&mut Rng(4), 2000, [1.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
        1e-3,
        1e-3,
    );
    let err = identify::identify(
        truth.arm(),
        OutputFrame::Base,
        &TcpOffset::FLANGE,
        &samples,
        &IdentifyOptions::default(),
    )
    .unwrap_err();
    assert!(
        matches!(err, IdentifyError::InsufficientExcitation { .. }),
        "{err}"
    );
    assert!(err.to_string().contains("motion"));
    let few = &samples[..10];
    assert!(matches!(
        identify::identify(
            truth.arm(),
            OutputFrame::Base,
            &TcpOffset::FLANGE,
            few,
            &IdentifyOptions::default()
        ),
        Err(IdentifyError::TooFewSamples { .. })
    ));
}

#[test]
fn the_conf_writer_round_trips() {
    let CalibrationForm::MountingDeltas(deltas) = example().form else {
        panic!("conf form");
    };
    let text = deltas.to_conf_text("identified by a test\nsecond line");
    let back = Calibration::parse(&text, "written.conf").unwrap();
    assert_eq!(back.form, CalibrationForm::MountingDeltas(deltas));
    assert!(text.starts_with("# identified by a test\n# second line\n[mounting]\n"));
}
