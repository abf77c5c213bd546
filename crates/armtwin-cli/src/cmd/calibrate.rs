//! `armtwin calibrate`: a recording's kinematics identified, judged on held-out rows, written as
//! calibration.conf with a report.
//!
//! Owns the flags' checks, the split into fitted and held-out rows and the files' names; must not
//! fit or format the report (the library's `identify` and `calibrate` do).

use std::sync::Arc;

use anyhow::{Context, Result, bail};
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::RobotSettings;
use armtwin_offline::validate;
use armtwin_service::config::{Overrides, ServiceConfig};

use crate::flags::CalibrateArgs;

#[allow(
    clippy::too_many_lines,
    reason = "one command: pair, fit, evaluate, write"
)]
pub(super) fn run(args: &CalibrateArgs) -> Result<()> {
    if args.robot.calibration.is_some() {
        bail!("calibrate fits deltas to the nominal arm: leave out --calibration");
    }
    if !(args.holdout.is_finite() && (0.0..0.9).contains(&args.holdout)) {
        bail!("--holdout must be in [0, 0.9), got {}", args.holdout);
    }
    let model = Arc::new(args.robot.load()?);
    let config = ServiceConfig::load(None, &Overrides::default())?;
    let (recording, times) = args.input.load()?;
    if !recording.has_pose {
        bail!("the recording has no measured poses to identify from");
    }
    let settings = RobotSettings {
        model: Arc::clone(&model),
        alarm: armtwin_core::pipeline::AlarmConfig::default(),
        sensors: Vec::new(),
        self_calibration: None,
        effort: None,
    };
    let validation = validate::validate(&recording, &times, config.pipeline, settings, |_| {});
    let (samples, lines) = armtwin_offline::calibrate::paired_samples(&recording, &validation);
    let split = armtwin_core::identify::holdout_start(samples.len(), args.holdout);
    let options = armtwin_core::identify::IdentifyOptions {
        fit_tool: args.fit_tcp,
        orientation_weight_m_per_rad: args.orientation_weight,
        ..armtwin_core::identify::IdentifyOptions::default()
    };
    let fit = armtwin_core::identify::identify(
        model.arm(),
        model.frame(),
        model.tool(),
        &samples[..split],
        &options,
    )?;
    let identified = model.with_deltas(fit.deltas, fit.tool, "identified")?;
    let held_out = &samples[split..];
    let per_row = |m: &RobotModel| -> Vec<f64> {
        held_out
            .iter()
            .map(|s| {
                m.pose(&s.q_rad).map_or(f64::NAN, |p| {
                    (p.position_m - s.measured.position_m).norm() * 1e3
                })
            })
            .collect()
    };
    let recording_name = args.input.recording.display().to_string();
    let report = armtwin_offline::calibrate::report(
        &recording_name,
        &model.arm().name,
        &fit,
        split,
        lines.get(split).copied(),
        armtwin_core::identify::pose_errors(&model, held_out),
        armtwin_core::identify::pose_errors(&identified, held_out),
        armtwin_core::identify::pose_errors(&identified, &samples[..split]),
    );
    let comment = format!(
        "Identified by armtwin calibrate from {recording_name} ({} rows fitted, {} held out).\nTool [x, y, z, rx, ry, rz] = {:?}",
        split,
        held_out.len(),
        fit.tool.to_ur_pose()
    );
    let files = [
        ("calibration.conf", fit.deltas.to_conf_text(&comment)),
        ("report.json", serde_json::to_string_pretty(&report)? + "\n"),
        ("report.md", armtwin_offline::calibrate::report_md(&report)),
        (
            "held_out_error.svg",
            armtwin_offline::calibrate::held_out_plot(
                &lines[split..],
                &per_row(&model),
                &per_row(&identified),
            ),
        ),
    ]
    .map(|(name, text)| (name, text.into_bytes()));
    validate::report::write_files(&args.out, &files)
        .with_context(|| format!("cannot write the report into {}", args.out.display()))?;
    eprintln!(
        "held out {} rows: position MAE nominal {:.4} mm → identified {:.4} mm; angle MAE {:.4} → {:.4} mrad; {} of {} parameters identified; wrote {} files into {}",
        report.held_out_rows,
        report.nominal.position_mae_mm,
        report.identified.position_mae_mm,
        report.nominal.angle_mae_mrad,
        report.identified.angle_mae_mrad,
        fit.excitation.identified,
        fit.excitation.candidates,
        files.len(),
        args.out.display()
    );
    Ok(())
}
