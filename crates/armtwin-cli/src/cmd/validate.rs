//! `armtwin validate`: a recording through the twin offline, its report written and summed up on
//! stderr, and the gate's exit status.
//!
//! Owns the flags' checks, the summary and the gate's failure; must not compute metrics or write
//! report files itself (the library's `validate` does).

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use armtwin_core::pipeline::RobotSettings;
use armtwin_offline::validate;
use armtwin_service::config::{Overrides, ServiceConfig};

use super::{progress_bar, read_text};
use crate::flags::ValidateArgs;
use armtwin_codec::recording;
use armtwin_core::dynamics::Payload;
use armtwin_core::model::RobotModel;
use armtwin_offline::validate::dynamics::{self as validate_dynamics, DynamicsValidation};
use armtwin_offline::validate::report::DynamicsJson;

/// Exit status of `validate` when a gate limit is exceeded.
pub const EXIT_GATE_FAILED: u8 = 3;

/// `validate` ran, but a `--max-…-error` limit was exceeded.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct GateFailed(pub String);

pub(super) fn run(args: &ValidateArgs) -> Result<()> {
    for (flag, value) in [
        ("--max-position-error", args.max_position_error),
        ("--max-angle-error", args.max_angle_error),
    ] {
        if let Some(v) = value
            && !(v.is_finite() && v >= 0.0)
        {
            bail!("{flag} must be a non-negative number, got {v}");
        }
    }
    let payload = payload_flag(&args.payload)?;
    let model = args.robot.load()?;
    let config = ServiceConfig::load(args.config.as_deref(), &Overrides::default())?;
    let (recording, times) = args.input.load()?;
    let alarm = config
        .default_robot
        .as_ref()
        .map(|robot| robot.alarm)
        .unwrap_or_default();
    let model = Arc::new(model);
    let settings = RobotSettings {
        model: Arc::clone(&model),
        alarm,
        sensors: Vec::new(),
        self_calibration: None,
        effort: None,
    };
    let bar = progress_bar(recording.entries.len(), "validate");
    let validation = validate::validate(&recording, &times, config.pipeline, settings, |done| {
        if done % 1024 == 0 {
            bar.set_position(done as u64);
        }
    });
    bar.finish_and_clear();
    let dynamics = if args.dynamics {
        Some(compare_dynamics(args, &model, payload)?)
    } else {
        None
    };
    let out = args.out.clone().unwrap_or_else(|| {
        let stem = args
            .input
            .recording
            .file_stem()
            .map_or_else(|| "recording".into(), |s| s.to_string_lossy().into_owned());
        PathBuf::from(format!("{stem}-validation"))
    });
    let recording_name = args.input.recording.display().to_string();
    let context = validate::report::Context {
        recording: &recording_name,
        model: &model,
        max_position_error_m: args.max_position_error,
        max_angle_error_rad: args.max_angle_error,
        dynamics: dynamics.as_ref(),
    };
    let (report, written) = validate::report::write_all(&out, &validation, &context)
        .with_context(|| format!("cannot write the report into {}", out.display()))?;
    let position = &report.cumulative.position;
    eprintln!(
        "{} rows: {} twin poses, {} paired, {} rejected, {} unpaired",
        report.rows, report.poses, report.paired, report.rejected, report.unpaired
    );
    if report.paired > 0 {
        eprintln!(
            "position error: MAE {:.4} mm, RMSE {:.4} mm, max {:.4} mm; rotation angle MAE {:.4e} rad, max {:.4e} rad",
            position.mae * 1e3,
            position.rmse * 1e3,
            position.max * 1e3,
            report.cumulative.angle.mae,
            report.cumulative.angle.max
        );
    }
    for rejection in report.rejections.iter().take(5) {
        eprintln!(
            "  rejected line {} ({}): {}",
            rejection.line, rejection.cause, rejection.reason
        );
    }
    if report.rejections.len() > 5 {
        eprintln!(
            "  … {} rejections in all, listed in report.json",
            report.rejections.len()
        );
    }
    if let Some(dynamics) = &report.dynamics {
        summarise_dynamics(dynamics);
    }
    eprintln!("wrote {} files into {}", written.len(), out.display());
    if !report.gate.passed {
        return Err(GateFailed(report.gate.failures.join("; ")).into());
    }
    Ok(())
}

/// `--dynamics`: the recording's torque columns read again beside its joint rows (a text
/// recording; rosbag2 has no currents) and compared with the model.
fn compare_dynamics(
    args: &ValidateArgs,
    model: &RobotModel,
    payload: Option<Payload>,
) -> Result<DynamicsValidation> {
    let text = read_text(&args.input.recording)?;
    let names = validate_dynamics::wanted_columns();
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    let table = recording::read_columns(&text, &names)?;
    Ok(validate_dynamics::compare(&table, model.arm(), payload)?)
}

fn summarise_dynamics(dynamics: &DynamicsJson) {
    let modes: Vec<String> = dynamics
        .modes
        .iter()
        .map(|(mode, rows)| format!("{rows} {mode}"))
        .collect();
    eprintln!(
        "dynamics: {} rows modelled on the {} state ({}), {} skipped",
        dynamics.rows,
        dynamics.state,
        modes.join(", "),
        dynamics.skipped
    );
    let rms = |stats: &validate::report::JointTorqueStatsJson| {
        stats
            .rms_nm
            .iter()
            .map(|v| format!("{v:.3}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    if let Some(stats) = &dynamics.model_vs_target_moment {
        eprintln!(
            "  model − target_moment RMS per joint (N·m): {}",
            rms(stats)
        );
    }
    if let Some(stats) = &dynamics.model_vs_currents {
        eprintln!("  currents − model RMS per joint (N·m): {}", rms(stats));
    }
    if let Some(stats) = &dynamics.currents_vs_target_current {
        eprintln!(
            "  currents − target current RMS per joint (N·m): {}",
            rms(stats)
        );
    }
    if let Some(identified) = &dynamics.payload.identified {
        eprintln!(
            "  payload identified from currents: {:.3} ± {:.3} kg ({} rows at rest; {})",
            identified.mass_kg,
            identified.mass_std_kg.unwrap_or(f64::NAN),
            identified.samples.unwrap_or(0),
            identified.source
        );
    } else if let Some(reason) = dynamics.payload.not_identifiable {
        eprintln!("  payload: not identifiable from this motion ({reason})");
    }
}

/// `--payload MASS,CX,CY,CZ`, checked.
fn payload_flag(values: &[f64]) -> Result<Option<Payload>> {
    Ok(match values[..] {
        [] => None,
        [mass_kg, x, y, z] => {
            if !([mass_kg, x, y, z].iter().all(|v| v.is_finite()) && mass_kg >= 0.0) {
                bail!("--payload needs a mass of at least 0 kg and a finite centre of gravity");
            }
            Some(Payload::point_mass(mass_kg, [x, y, z]))
        }
        _ => bail!(
            "--payload takes MASS,CX,CY,CZ (4 values), got {}",
            values.len()
        ),
    })
}
