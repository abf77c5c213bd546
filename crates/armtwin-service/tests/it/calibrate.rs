//! `armtwin calibrate` on the real sample recordings: identified on the long recording, judged
//! on its later rows and on the other recording of the same arm.

use std::path::Path;
use std::sync::Arc;

use armtwin_codec::recording;
use armtwin_core::identify::{self, IdentifyOptions, PairedSample, PoseErrors, holdout_start};
use armtwin_core::kinematics::{OutputFrame, TcpOffset};
use armtwin_core::model::{Calibration, CalibrationForm, RobotModel, catalog};
use armtwin_core::pipeline::{AlarmConfig, PipelineConfig, RobotSettings};
use armtwin_offline::calibrate::paired_samples;
use armtwin_offline::validate::validate;

fn nominal() -> Arc<RobotModel> {
    Arc::new(RobotModel::nominal("ur10e").expect("catalog"))
}

/// The recording's rows paired by the pipeline, as `calibrate` pairs them.
fn pairs(file: &str, spacing_s: Option<f64>) -> Vec<PairedSample> {
    let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data")).join(file);
    let text = std::fs::read_to_string(path).expect("data");
    let recording = recording::read(&text).expect("recognised");
    let times = recording::source_times(&recording, spacing_s);
    let settings = RobotSettings {
        model: nominal(),
        alarm: AlarmConfig::default(),
        sensors: Vec::new(),
        self_calibration: None,
        effort: None,
    };
    let validation = validate(
        &recording,
        &times,
        PipelineConfig::default(),
        settings,
        |_| {},
    );
    paired_samples(&recording, &validation).0
}

fn describe(name: &str, e: &PoseErrors) -> String {
    format!(
        "{name}: {} pairs, position MAE {:.4} mm, angle MAE {:.4} mrad",
        e.count,
        e.position_mae_m * 1e3,
        e.angle_mae_rad * 1e3
    )
}

#[test]
fn identified_on_one_recording_it_is_better_on_its_later_rows_and_never_worse_on_the_other() {
    let lasttest = pairs("ur10e_lasttest.csv", None);
    assert_eq!(lasttest.len(), 29_054);
    let split = holdout_start(lasttest.len(), 0.3);
    // Every 4th training row: 500 Hz rows a couple of milliseconds apart add little, and the
    // fit stays quick in a debug build.
    let training: Vec<PairedSample> = lasttest[..split].iter().step_by(4).copied().collect();
    let model = nominal();
    let fit = identify::identify(
        model.arm(),
        OutputFrame::Base,
        &TcpOffset::FLANGE,
        &training,
        &IdentifyOptions::default(),
    )
    .expect("the recording excites the arm");
    // Through the controller's file format, as `calibrate` writes it and `serve` loads it.
    let text = fit.deltas.to_conf_text("identified by a test");
    let calibration = Calibration::parse(&text, "identified.conf").expect("loadable");
    assert_eq!(
        calibration.form,
        CalibrationForm::MountingDeltas(fit.deltas)
    );
    let identified = RobotModel::new(
        catalog::arm("ur10e").expect("catalog"),
        Some(calibration),
        TcpOffset::FLANGE,
        OutputFrame::Base,
    )
    .expect("model");

    let held_out = &lasttest[split..];
    let (before, after) = (
        identify::pose_errors(&model, held_out),
        identify::pose_errors(&identified, held_out),
    );
    // The other recording of the same arm: the UR10e FMU report's 54 rows, 0.1 s apart.
    let other = pairs("fmpy_inputs.csv", Some(0.1));
    assert_eq!(other.len(), 54);
    let (other_before, other_after) = (
        identify::pose_errors(&model, &other),
        identify::pose_errors(&identified, &other),
    );
    println!(
        "{}\n{}\n{}\n{}",
        describe("held out, nominal", &before),
        describe("held out, identified", &after),
        describe("other recording, nominal", &other_before),
        describe("other recording, identified", &other_after)
    );
    // Rounded to 1 mm / 1 mrad, the recordings floor any model near 0.5 mm: nominal's ~1 mm
    // can only come down by about half, which it must.
    assert!(after.position_mae_m < 0.7 * before.position_mae_m);
    assert!(after.angle_mae_rad < 0.5 * before.angle_mae_rad);
    assert!(other_after.position_mae_m <= other_before.position_mae_m);
    assert!(other_after.angle_mae_rad <= other_before.angle_mae_rad);
}
