//! Identification: a known calibration recovered from its own synthetic stream (noise, outliers,
//! held-out rows), the parallel-axis degeneracy reported, too little motion refused.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]

use std::f64::consts::PI;

use armtwin_core::identify::{
    self, IdentifyError, IdentifyOptions, PairedSample, holdout_start, pose_errors,
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
fn the_example_calibration_is_recovered_far_below_a_millimetre() {
    let truth = model_with(
        match example().form {
            CalibrationForm::MountingDeltas(d) => Some(d),
            CalibrationForm::JointOrigins { .. } => None,
        },
        TcpOffset::FLANGE,
    );
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
    // The example's far common normals (δd of hundreds of metres) tilt axes 3 and 4 out of the
    // plane of the parallel axes, which small deltas around the nominal table cannot express:
    // what is left is tens of micrometres and a few tenths of a milliradian, far below the
    // 1 mm / 1 mrad resolution of the sample recordings and 1000× below nominal. A
    // realistically sized calibration is recovered to the noise floor (the tests below).
    assert!(
        after.position_mae_m < 1e-3 * before.position_mae_m,
        "{after:?}"
    );
    assert!(after.position_mae_m < 2e-4, "{after:?}");
    assert!(after.angle_mae_rad < 1e-3, "{after:?}");
    assert!(floor.position_mae_m < 1e-6);
    // The true calibration's FK reproduced on configurations the fit never saw.
    let fresh = trajectory(&mut Rng(99), 2000, WIDE);
    let worst = fresh
        .iter()
        .map(|q| {
            (identified.pose(q).unwrap().position_m - truth.pose(q).unwrap().position_m).norm()
        })
        .fold(0.0, f64::max);
    assert!(worst < 1e-3, "{worst:e} m");
    // Translations along the three parallel axes of joints 2–4 are one: two are fixed.
    let fixed: Vec<&str> = fit
        .parameters
        .iter()
        .filter(|p| !p.identified)
        .map(|p| p.name.as_str())
        .collect();
    assert!(fixed.len() >= 2, "{fixed:?}");
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
