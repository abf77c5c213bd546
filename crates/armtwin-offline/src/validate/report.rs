//! The files of a validation: `report.json`, `report.md`, the per-row `rows.csv` and the SVG
//! plots. Building each is pure (strings and writers); [`write_all`] puts them in a directory.
//!
//! `report.json`'s `cumulative` object is the service's metrics `cumulative`, serialised by the
//! same type ([`StatsSetJson`]), so a dashboard or a CI script reads both the same way.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::dynamics::{DynamicsValidation, PayloadSource};
use super::svg::{self, Series};
use super::{EventCounts, Rejection, Validation};
use armtwin_codec::PoseFields;
use armtwin_codec::json::StatsSetJson;
use armtwin_core::dynamics::payload::PayloadIdentification;
use armtwin_core::kinematics::PoseReadout;
use armtwin_core::metrics::{Deviation, METRIC_NAMES};
use armtwin_core::model::RobotModel;

/// What the validation was run on, for the report.
#[derive(Debug, Clone)]
pub struct Context<'a> {
    /// The recording's path as given.
    pub recording: &'a str,
    /// The model, calibration, tool and frame used.
    pub model: &'a RobotModel,
    /// Gate on the largest position error (m), if given.
    pub max_position_error_m: Option<f64>,
    /// Gate on the largest rotation angle (rad), if given.
    pub max_angle_error_rad: Option<f64>,
    /// The recording's joint torques against the model (`--dynamics`), if asked for.
    pub dynamics: Option<&'a DynamicsValidation>,
}

/// The robot description in the report.
#[derive(Debug, Clone, Serialize)]
pub struct RobotJson {
    /// Model name.
    pub model: String,
    /// The calibration file, if one was used.
    pub calibration: Option<String>,
    /// Tool offset `[x, y, z, rx, ry, rz]` (m, rotation vector in rad).
    pub tool: [f64; 6],
    /// Output frame (`base` or `base_link`).
    pub frame: &'static str,
}

/// `malformed`: lines that did not split into the header's columns.
#[derive(Debug, Clone, Serialize)]
pub struct MalformedJson {
    /// How many.
    pub count: usize,
    /// Their 1-based line numbers, all of them.
    pub lines: Vec<u64>,
}

/// One rejection in the report.
#[derive(Debug, Clone, Serialize)]
pub struct RejectionJson {
    /// 1-based line.
    pub line: u64,
    /// Stable cause, as on the service's events key.
    pub cause: &'static str,
    /// A sentence for people.
    pub reason: String,
}

/// The pass/fail gate.
#[derive(Debug, Clone, Serialize)]
pub struct GateJson {
    /// `--max-position-error` (m), if given.
    pub max_position_error_m: Option<f64>,
    /// `--max-angle-error` (rad), if given.
    pub max_angle_error_rad: Option<f64>,
    /// Whether every given limit held.
    pub passed: bool,
    /// A sentence per limit exceeded.
    pub failures: Vec<String>,
}

/// `events`: counts of the pipeline's other events.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct EventsJson {
    /// Alarms raised (with the service's default thresholds).
    pub alarms: u64,
    /// Alarms recovered.
    pub recoveries: u64,
    /// Gaps.
    pub gaps: u64,
    /// Unpaired measured poses.
    pub unpaired: u64,
    /// Clock restarts.
    pub restarts: u64,
}

impl From<EventCounts> for EventsJson {
    fn from(e: EventCounts) -> Self {
        Self {
            alarms: e.alarms,
            recoveries: e.recoveries,
            gaps: e.gaps,
            unpaired: e.unpaired,
            restarts: e.restarts,
        }
    }
}

/// `report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct ReportJson {
    /// The recording's path.
    pub recording: String,
    /// The layout recognised.
    pub format: &'static str,
    /// The robot used.
    pub robot: RobotJson,
    /// Data lines (rows and malformed lines).
    pub rows: usize,
    /// Rows that yielded a twin pose.
    pub poses: usize,
    /// Measured poses paired with the twin.
    pub paired: u64,
    /// Measured poses that could not be paired.
    pub unpaired: u64,
    /// Inputs rejected (a row whose joints and measured pose are both bad counts twice).
    pub rejected: u64,
    /// Rejections per cause.
    pub rejected_by_cause: BTreeMap<&'static str, usize>,
    /// Malformed lines.
    pub malformed: MalformedJson,
    /// Every rejection.
    pub rejections: Vec<RejectionJson>,
    /// Other events.
    pub events: EventsJson,
    /// Source time span (s) of the rows.
    pub t_first: f64,
    /// Last source time (s).
    pub t_last: f64,
    /// Statistics over every paired row: the service's metrics `cumulative`.
    pub cumulative: StatsSetJson,
    /// Mean signed deviation `twin − measured` (m) over the paired rows.
    pub mean_offset_m: [f64; 3],
    /// The gate.
    pub gate: GateJson,
    /// The joint torques against the model, with `--dynamics`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dynamics: Option<DynamicsJson>,
    /// The armtwin version that computed this.
    pub armtwin_version: &'static str,
}

/// Per joint, the RMS and largest absolute value of a torque difference (N·m).
#[derive(Debug, Clone, Serialize)]
pub struct JointTorqueStatsJson {
    /// Rows compared.
    pub rows: usize,
    /// Root mean square per joint (N·m).
    pub rms_nm: [f64; 6],
    /// Largest absolute value per joint (N·m).
    pub max_nm: [f64; 6],
}

impl JointTorqueStatsJson {
    fn of(differences: impl Iterator<Item = [f64; 6]>) -> Option<Self> {
        let mut rows = 0;
        let mut sum_squares = [0.0; 6];
        let mut max_nm = [0.0_f64; 6];
        for difference in differences {
            rows += 1;
            for k in 0..6 {
                sum_squares[k] += difference[k] * difference[k];
                max_nm[k] = max_nm[k].max(difference[k].abs());
            }
        }
        (rows > 0).then(|| Self {
            rows,
            rms_nm: sum_squares.map(|s| (s / rows as f64).sqrt()),
            max_nm,
        })
    }
}

/// A payload in the report: mass and centre of gravity in the flange frame.
#[derive(Debug, Clone, Serialize)]
pub struct PayloadJson {
    /// Mass (kg).
    pub mass_kg: f64,
    /// Centre of gravity (m) in the flange frame; `null` when the identified mass is not positive.
    pub cog_m: Option<[f64; 3]>,
    /// Where it came from: `recording`, `command line`, or for an identified payload how.
    pub source: &'static str,
    /// For an identified payload: the standard deviation of its mass (kg).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mass_std_kg: Option<f64>,
    /// For an identified payload: the rows it was identified from.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub samples: Option<usize>,
}

/// `payload`: what the controller was told, and what the currents say.
#[derive(Debug, Clone, Serialize)]
pub struct PayloadsJson {
    /// The configured payload (of the first modelled row), if any.
    pub configured: Option<PayloadJson>,
    /// The payload identified from the currents, if the rows at rest determine it.
    pub identified: Option<PayloadJson>,
    /// Else why not: `too_few_poses`, `poses_alike` or `unphysical`.
    pub not_identifiable: Option<&'static str>,
}

/// `dynamics`: the recording's joint torques against the model.
#[derive(Debug, Clone, Serialize)]
pub struct DynamicsJson {
    /// The state modelled: `target` (the controller's own) or `actual` (q̈ from differences).
    pub state: &'static str,
    /// Rows modelled.
    pub rows: usize,
    /// Data lines without a complete state.
    pub skipped: usize,
    /// Rows per controller mode: the model is the full dynamics in `program`, gravity in
    /// `freedrive`, as the controller's `target_moment` is.
    pub modes: BTreeMap<&'static str, usize>,
    /// Model minus `target_moment`, where recorded.
    pub model_vs_target_moment: Option<JointTorqueStatsJson>,
    /// Torque from currents minus the model (the residual), for arms with public drive data.
    pub model_vs_currents: Option<JointTorqueStatsJson>,
    /// Measured minus target current as torque, where both are recorded.
    pub currents_vs_target_current: Option<JointTorqueStatsJson>,
    /// The payloads.
    pub payload: PayloadsJson,
}

/// The `dynamics` object of `report.json`.
#[must_use]
pub fn dynamics_json(dynamics: &DynamicsValidation) -> DynamicsJson {
    let mut modes = BTreeMap::from([("program", 0), ("freedrive", 0)]);
    for row in &dynamics.rows {
        *modes.entry(row.mode.as_str()).or_insert(0) += 1;
    }
    let difference = |a: [f64; 6], b: [f64; 6]| std::array::from_fn(|k| a[k] - b[k]);
    DynamicsJson {
        state: dynamics.state_source.as_str(),
        rows: dynamics.rows.len(),
        skipped: dynamics.skipped_lines.len(),
        modes,
        model_vs_target_moment: JointTorqueStatsJson::of(dynamics.rows.iter().filter_map(|row| {
            row.target_moment_nm
                .map(|target| difference(row.tau_model_nm, target))
        })),
        model_vs_currents: JointTorqueStatsJson::of(dynamics.rows.iter().filter_map(|row| {
            row.tau_measured_nm
                .map(|measured| difference(measured, row.tau_model_nm))
        })),
        currents_vs_target_current: JointTorqueStatsJson::of(
            dynamics.rows.iter().filter_map(|row| row.current_vs_target_nm),
        ),
        payload: PayloadsJson {
            configured: dynamics.payload_configured.map(|p| PayloadJson {
                mass_kg: p.mass_kg,
                cog_m: Some(p.cog_flange_m),
                source: match dynamics.payload_source {
                    PayloadSource::Recording => "recording",
                    PayloadSource::CommandLine => "command line",
                    PayloadSource::None => "none",
                },
                mass_std_kg: None,
                samples: None,
            }),
            identified: dynamics
                .payload_identification
                .estimate()
                .map(|p| PayloadJson {
                    mass_kg: p.mass_kg,
                    cog_m: p.cog_flange_m,
                    source: if p.cog_identified {
                        "currents, program-mode rows at rest"
                    } else {
                        "currents, program-mode rows at rest; mass only, centre of gravity as configured"
                    },
                    mass_std_kg: Some(p.mass_std_kg),
                    samples: Some(p.samples),
                }),
            not_identifiable: match dynamics.payload_identification {
                PayloadIdentification::NotIdentifiable { reason, .. } => Some(reason.as_str()),
                PayloadIdentification::Identified(_) => None,
            },
        },
    }
}

/// `dynamics.csv`: per modelled row `t`, `line`, `mode`, then six each of `tau_model`,
/// `tau_measured` (from currents), `residual` (measured − model) and `target_moment`; cells the
/// recording cannot give are empty. Numbers in Rust's shortest round-trip form.
pub fn write_dynamics_csv(dynamics: &DynamicsValidation, out: &mut impl Write) -> io::Result<()> {
    let mut header = vec!["t".to_owned(), "line".to_owned(), "mode".to_owned()];
    for group in ["tau_model", "tau_measured", "residual", "target_moment"] {
        header.extend((0..6).map(|k| format!("{group}_{k}")));
    }
    writeln!(out, "{}", header.join(","))?;
    let cells = |values: Option<[f64; 6]>| -> Vec<String> {
        match values {
            Some(values) => values.iter().map(|v| format!("{v:?}")).collect(),
            None => vec![String::new(); 6],
        }
    };
    for row in &dynamics.rows {
        let residual = row
            .tau_measured_nm
            .map(|m| std::array::from_fn(|k| m[k] - row.tau_model_nm[k]));
        let mut line = vec![
            row.t_s.map(|t| format!("{t:?}")).unwrap_or_default(),
            row.line.to_string(),
            row.mode.as_str().to_owned(),
        ];
        line.extend(cells(Some(row.tau_model_nm)));
        line.extend(cells(row.tau_measured_nm));
        line.extend(cells(residual));
        line.extend(cells(row.target_moment_nm));
        writeln!(out, "{}", line.join(","))?;
    }
    Ok(())
}

#[allow(
    clippy::expect_used,
    reason = "callers name statistics by the literals of METRIC_NAMES"
)]
fn statistic(validation: &Validation, name: &str) -> armtwin_core::metrics::Stats {
    let index = METRIC_NAMES
        .iter()
        .position(|n| *n == name)
        .expect("a metric name from METRIC_NAMES");
    validation.metrics.cumulative.stats[index]
}

fn paired(validation: &Validation) -> impl Iterator<Item = (f64, &PoseReadout, &Deviation)> {
    validation
        .rows
        .iter()
        .filter_map(|r| r.paired.as_ref().map(|(m, d)| (r.stamp_s, m, d)))
}

/// The gate's verdict.
fn gate(validation: &Validation, context: &Context<'_>) -> GateJson {
    let mut failures = Vec::new();
    let position = statistic(validation, "position").max;
    let angle = statistic(validation, "angle").max;
    if let Some(limit) = context.max_position_error_m
        && position > limit
    {
        failures.push(format!(
            "largest position error {:.3} mm exceeds --max-position-error {:.3} mm",
            position * 1e3,
            limit * 1e3
        ));
    }
    if let Some(limit) = context.max_angle_error_rad
        && angle > limit
    {
        failures.push(format!(
            "largest rotation angle {angle:.3e} rad exceeds --max-angle-error {limit:.3e} rad"
        ));
    }
    let any_limit = context.max_position_error_m.is_some() || context.max_angle_error_rad.is_some();
    if any_limit && validation.metrics.paired == 0 {
        failures.push("no row was paired, so no limit can be checked".to_owned());
    }
    GateJson {
        max_position_error_m: context.max_position_error_m,
        max_angle_error_rad: context.max_angle_error_rad,
        passed: failures.is_empty(),
        failures,
    }
}

/// Builds `report.json`'s content.
#[must_use]
pub fn report_json(validation: &Validation, context: &Context<'_>) -> ReportJson {
    let tool = context.model.tool();
    let mut rejected_by_cause = BTreeMap::new();
    for rejection in &validation.rejections {
        *rejected_by_cause.entry(rejection.cause).or_insert(0) += 1;
    }
    let mut sum = [0.0; 3];
    let mut count = 0.0;
    for (_, _, d) in paired(validation) {
        sum[0] += d.dx_m;
        sum[1] += d.dy_m;
        sum[2] += d.dz_m;
        count += 1.0;
    }
    let mean_offset_m = if count > 0.0 {
        sum.map(|s| s / count)
    } else {
        [0.0; 3]
    };
    ReportJson {
        recording: context.recording.to_owned(),
        format: validation.format.describe(),
        robot: RobotJson {
            model: context.model.arm().name.clone(),
            calibration: context.model.calibration().map(|c| c.source_name.clone()),
            tool: [
                tool.position_m[0],
                tool.position_m[1],
                tool.position_m[2],
                tool.rotation_vector_rad[0],
                tool.rotation_vector_rad[1],
                tool.rotation_vector_rad[2],
            ],
            frame: validation.frame.as_str(),
        },
        rows: validation.rows.len(),
        poses: validation.poses(),
        paired: validation.metrics.paired,
        unpaired: validation.metrics.unpaired,
        rejected: validation.metrics.rejected,
        rejected_by_cause,
        malformed: MalformedJson {
            count: validation.malformed_lines.len(),
            lines: validation.malformed_lines.clone(),
        },
        rejections: validation
            .rejections
            .iter()
            .map(|r: &Rejection| RejectionJson {
                line: r.line,
                cause: r.cause,
                reason: r.reason.clone(),
            })
            .collect(),
        events: validation.events.into(),
        t_first: validation.rows.first().map_or(0.0, |r| r.stamp_s),
        t_last: validation.rows.last().map_or(0.0, |r| r.stamp_s),
        cumulative: StatsSetJson::from(&validation.metrics.cumulative),
        mean_offset_m,
        gate: gate(validation, context),
        dynamics: context.dynamics.map(dynamics_json),
        armtwin_version: env!("CARGO_PKG_VERSION"),
    }
}

/// Column names of `rows.csv`.
fn rows_header() -> Vec<String> {
    let mut names = vec!["line".to_owned(), "t".to_owned()];
    for prefix in ["twin", "measured"] {
        names.extend(PoseFields::NAMES.iter().map(|n| format!("{prefix}_{n}")));
    }
    names.extend(
        [
            "dx_m",
            "dy_m",
            "dz_m",
            "position_error_m",
            "quat_distance",
            "angle",
            "droll_rad",
            "dpitch_rad",
            "dyaw_rad",
            "rejected",
        ]
        .map(str::to_owned),
    );
    names
}

/// Writes `rows.csv`: one line per data line of the recording, empty cells where a value does
/// not exist (no twin pose, not paired), and the rejection causes joined by `;`.
pub fn write_rows_csv(validation: &Validation, out: &mut impl Write) -> io::Result<()> {
    writeln!(out, "{}", rows_header().join(","))?;
    let mut line = String::new();
    for row in &validation.rows {
        line.clear();
        let _ = write!(line, "{},{}", row.line, row.stamp_s);
        let mut pose_cells = |pose: Option<&PoseReadout>| match pose {
            Some(pose) => {
                for v in PoseFields::from(pose).values() {
                    let _ = write!(line, ",{v}");
                }
            }
            None => line.push_str(&",".repeat(PoseFields::NAMES.len())),
        };
        pose_cells(row.twin.as_ref());
        pose_cells(row.paired.as_ref().map(|(m, _)| m));
        match &row.paired {
            Some((_, d)) => {
                for v in d.fields() {
                    let _ = write!(line, ",{v}");
                }
            }
            None => line.push_str(&",".repeat(9)),
        }
        let _ = write!(line, ",{}", row.rejected.join(";"));
        writeln!(out, "{line}")?;
    }
    Ok(())
}

/// The plot files, in the order [`plots`] returns them.
pub const PLOT_FILES: [&str; 4] = [
    "position.svg",
    "position_error.svg",
    "quaternion_distance.svg",
    "position_error_histogram.svg",
];

/// The plots: file name and SVG text.
#[must_use]
pub fn plots(validation: &Validation) -> Vec<(&'static str, String)> {
    // Time axes start at the first row: recordings stamped in Unix time would otherwise label
    // every tick with ten digits.
    let t0 = validation.rows.first().map_or(0.0, |r| r.stamp_s);
    let twin = |axis: usize| Series {
        name: ["twin x", "twin y", "twin z"][axis],
        points: validation
            .rows
            .iter()
            .filter_map(|r| r.twin.map(|p| (r.stamp_s - t0, p.position_m[axis])))
            .collect(),
        dashed: true,
    };
    let measured = |axis: usize| Series {
        name: ["measured x", "measured y", "measured z"][axis],
        points: paired(validation)
            .map(|(t, m, _)| (t - t0, m.position_m[axis]))
            .collect(),
        dashed: false,
    };
    let mut position_series = Vec::new();
    for axis in 0..3 {
        position_series.push(measured(axis));
        position_series.push(twin(axis));
    }
    let error_mm: Vec<(f64, f64)> = paired(validation)
        .map(|(t, _, d)| (t - t0, d.position_m * 1e3))
        .collect();
    let quat: Vec<(f64, f64)> = paired(validation)
        .map(|(t, _, d)| (t - t0, d.quat_distance))
        .collect();
    let histogram_values: Vec<f64> = error_mm.iter().map(|p| p.1).collect();
    vec![
        (
            PLOT_FILES[0],
            svg::line_chart(
                "TCP position: twin vs measured",
                "time since the first row (s)",
                "position (m)",
                &position_series,
            ),
        ),
        (
            PLOT_FILES[1],
            svg::line_chart(
                "Position error |twin − measured|",
                "time since the first row (s)",
                "position error (mm)",
                &[Series {
                    name: "position error",
                    points: error_mm,
                    dashed: false,
                }],
            ),
        ),
        (
            PLOT_FILES[2],
            svg::line_chart(
                "Quaternion distance 1 − |⟨q_twin, q_measured⟩|",
                "time since the first row (s)",
                "quaternion distance",
                &[Series {
                    name: "quaternion distance",
                    points: quat,
                    dashed: false,
                }],
            ),
        ),
        (
            PLOT_FILES[3],
            svg::histogram(
                "Position error distribution",
                "position error (mm)",
                &histogram_values,
                40,
            ),
        ),
    ]
}

/// The dynamics plots (`--dynamics`): file name and SVG text.
pub const DYNAMICS_PLOT_FILES: [&str; 2] = ["dynamics_torques.svg", "dynamics_residual.svg"];

/// The dynamics plots: the model's torques (dashed) against the currents' (or, without currents,
/// the recorded `target_moment`), and their difference, per joint over the recording's time.
#[must_use]
pub fn dynamics_plots(dynamics: &DynamicsValidation) -> Vec<(&'static str, String)> {
    const MODEL: [&str; 6] = [
        "model 1", "model 2", "model 3", "model 4", "model 5", "model 6",
    ];
    const MEASURED: [&str; 6] = [
        "measured 1",
        "measured 2",
        "measured 3",
        "measured 4",
        "measured 5",
        "measured 6",
    ];
    const JOINT: [&str; 6] = [
        "joint 1", "joint 2", "joint 3", "joint 4", "joint 5", "joint 6",
    ];
    let rows = &dynamics.rows;
    let from_currents = rows.iter().any(|row| row.tau_measured_nm.is_some());
    let reference = |row: &super::dynamics::DynamicsRow| {
        if from_currents {
            row.tau_measured_nm
        } else {
            row.target_moment_nm
        }
    };
    let t0 = rows.iter().find_map(|row| row.t_s).unwrap_or(0.0);
    // Rows without a timestamp are placed by their line.
    let t = |row: &super::dynamics::DynamicsRow| {
        #[allow(clippy::cast_precision_loss, reason = "a line number")]
        row.t_s.map_or(row.line as f64, |t| t - t0)
    };
    let mut torques = Vec::new();
    let mut residuals = Vec::new();
    for joint in 0..6 {
        torques.push(Series {
            name: MEASURED[joint],
            points: rows
                .iter()
                .filter_map(|row| Some((t(row), reference(row)?[joint])))
                .collect(),
            dashed: false,
        });
        torques.push(Series {
            name: MODEL[joint],
            points: rows
                .iter()
                .map(|row| (t(row), row.tau_model_nm[joint]))
                .collect(),
            dashed: true,
        });
        residuals.push(Series {
            name: JOINT[joint],
            points: rows
                .iter()
                .filter_map(|row| Some((t(row), reference(row)?[joint] - row.tau_model_nm[joint])))
                .collect(),
            dashed: false,
        });
    }
    let reference_name = if from_currents {
        "currents × torque factors"
    } else {
        "target_moment"
    };
    vec![
        (
            DYNAMICS_PLOT_FILES[0],
            svg::line_chart(
                &format!("Joint torques: model (dashed) vs {reference_name}"),
                "time since the first row (s)",
                "torque (N·m)",
                &torques,
            ),
        ),
        (
            DYNAMICS_PLOT_FILES[1],
            svg::line_chart(
                &format!("Joint torque residual: {reference_name} − model"),
                "time since the first row (s)",
                "residual (N·m)",
                &residuals,
            ),
        ),
    ]
}

/// `report.md`: the UR10e FMU report's table and a short reading of it.
#[must_use]
pub fn report_md(validation: &Validation, report: &ReportJson) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# Twin validation: `{}`\n", report.recording);
    let calibration = report.robot.calibration.as_deref().map_or_else(
        || "nominal (no calibration)".to_owned(),
        |c| format!("`{c}`"),
    );
    let _ = writeln!(
        md,
        "- Recording: {} — {} data lines, {} twin poses, {} paired, {} rejected, {} unpaired\n\
         - Robot: `{}`, calibration {calibration}, tool `{:?}`, frame `{}`\n\
         - Source time {} s to {} s; armtwin {}\n",
        report.format,
        report.rows,
        report.poses,
        report.paired,
        report.rejected,
        report.unpaired,
        report.robot.model,
        report.robot.tool,
        report.robot.frame,
        report.t_first,
        report.t_last,
        report.armtwin_version,
    );
    let _ = writeln!(md, "| Metric | MAE | RMSE | Max |\n|---|---:|---:|---:|");
    // (metric, title, unit shown: value × 1000 in mm or mrad, or `None` for the unitless
    // quaternion distance in scientific notation)
    let rows: [(&str, &str, Option<&str>); 9] = [
        ("position", "Position error", Some("mm")),
        ("x", "  |dx|", Some("mm")),
        ("y", "  |dy|", Some("mm")),
        ("z", "  |dz|", Some("mm")),
        ("quat_distance", "Quaternion distance", None),
        ("angle", "Rotation angle", Some("mrad")),
        ("roll", "  |droll|", Some("mrad")),
        ("pitch", "  |dpitch|", Some("mrad")),
        ("yaw", "  |dyaw|", Some("mrad")),
    ];
    for (name, title, unit) in rows {
        let s = statistic(validation, name);
        let cell = |v: f64| match unit {
            Some(_) => format!("{:.4}", v * 1e3),
            None => format!("{v:.3e}"),
        };
        let unit = unit.map_or_else(String::new, |u| format!(" ({u})"));
        let _ = writeln!(
            md,
            "| {title}{unit} | {} | {} | {} |",
            cell(s.mae),
            cell(s.rmse),
            cell(s.max)
        );
    }
    md.push_str("\n## Reading\n\n");
    md.push_str(&reading(validation, report));
    if let Some(dynamics) = &report.dynamics {
        md.push_str(&dynamics_md(dynamics));
    }
    md.push_str("\n## Plots\n\n");
    for file in PLOT_FILES {
        let _ = writeln!(md, "![{file}]({file})");
    }
    md
}

/// The `## Dynamics` section of `report.md`: the per-joint table and the payloads.
fn dynamics_md(dynamics: &DynamicsJson) -> String {
    let mut md = String::from("\n## Dynamics\n\n");
    let modes: Vec<String> = dynamics
        .modes
        .iter()
        .map(|(mode, rows)| format!("{rows} {mode}"))
        .collect();
    let _ = writeln!(
        md,
        "{} rows modelled on the {} state ({}; the model is the full dynamics in program mode and \
         gravity in freedrive, as the controller's `target_moment`), {} lines without a state.\n",
        dynamics.rows,
        dynamics.state,
        modes.join(", "),
        dynamics.skipped
    );
    let _ = writeln!(
        md,
        "| Joint | model − target_moment RMS (N·m) | max (N·m) | currents − model RMS (N·m) | max (N·m) | currents − target current RMS (N·m) | max (N·m) |\n|---|---:|---:|---:|---:|---:|---:|"
    );
    let cell = |stats: Option<&JointTorqueStatsJson>, k: usize, rms: bool| {
        stats.map_or_else(
            || "–".to_owned(),
            |s| format!("{:.4}", if rms { s.rms_nm[k] } else { s.max_nm[k] }),
        )
    };
    let (target, currents, drive) = (
        dynamics.model_vs_target_moment.as_ref(),
        dynamics.model_vs_currents.as_ref(),
        dynamics.currents_vs_target_current.as_ref(),
    );
    for k in 0..6 {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} |",
            k + 1,
            cell(target, k, true),
            cell(target, k, false),
            cell(currents, k, true),
            cell(currents, k, false),
            cell(drive, k, true),
            cell(drive, k, false)
        );
    }
    let describe = |p: &PayloadJson| {
        let cog = p.cog_m.map_or_else(
            || "no centre of gravity".to_owned(),
            |c| {
                format!(
                    "centre of gravity ({:.4}, {:.4}, {:.4}) m",
                    c[0], c[1], c[2]
                )
            },
        );
        match p.mass_std_kg {
            Some(std) => format!("{:.3} ± {std:.3} kg, {cog} ({})", p.mass_kg, p.source),
            None => format!("{:.3} kg, {cog} ({})", p.mass_kg, p.source),
        }
    };
    let _ = writeln!(
        md,
        "\nPayload configured: {}. Identified: {}.",
        dynamics
            .payload
            .configured
            .as_ref()
            .map_or_else(|| "none".to_owned(), describe),
        dynamics.payload.identified.as_ref().map_or_else(
            || format!(
                "not identifiable from this motion ({})",
                dynamics
                    .payload
                    .not_identifiable
                    .unwrap_or("no rows at rest")
            ),
            describe
        )
    );
    md
}

/// A few sentences a reviewer would write under the table.
fn reading(validation: &Validation, report: &ReportJson) -> String {
    let mut text = String::new();
    if report.paired == 0 {
        let _ = writeln!(
            text,
            "No row carried a usable measured pose, so only twin poses were computed (see `rows.csv`)."
        );
    } else {
        let position = statistic(validation, "position");
        let worst = validation
            .rows
            .iter()
            .filter_map(|r| r.paired.map(|(_, d)| (r, d.position_m)))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        let _ = write!(
            text,
            "The twin is on average {:.3} mm from the measured TCP (RMSE {:.3} mm)",
            position.mae * 1e3,
            position.rmse * 1e3
        );
        if let Some((row, value)) = worst {
            let _ = write!(
                text,
                "; the largest error, {:.3} mm, is at line {} (t = {} s)",
                value * 1e3,
                row.line,
                row.stamp_s
            );
        }
        text.push_str(".\n");
        // Share of the mean squared error explained by a constant offset: near 1 means a
        // systematic error (tool, calibration, frame), near 0 means noise or motion lag.
        let offset = report.mean_offset_m;
        let offset_sq = offset.iter().map(|v| v * v).sum::<f64>();
        let mse = position.rmse * position.rmse;
        if mse > 0.0 {
            let share = (offset_sq / mse).min(1.0);
            let _ = writeln!(
                text,
                "A constant offset of ({:.3}, {:.3}, {:.3}) mm (twin − measured) accounts for {:.0} % of the mean squared error: {}",
                offset[0] * 1e3,
                offset[1] * 1e3,
                offset[2] * 1e3,
                share * 100.0,
                if share > 0.8 {
                    "the error is mostly systematic — check the tool offset, the calibration and the frame."
                } else if share > 0.3 {
                    "part systematic, part varying with the pose or time."
                } else {
                    "the error varies with the pose or time rather than being a fixed offset (timing, joint readings, unmodelled elasticity)."
                }
            );
        }
        let angle = statistic(validation, "angle");
        let _ = writeln!(
            text,
            "Orientation agrees to {:.3} mrad on average ({:.4}°), at most {:.3} mrad.",
            angle.mae * 1e3,
            angle.mae.to_degrees(),
            angle.max * 1e3
        );
    }
    if report.rejected > 0 {
        let causes: Vec<String> = report
            .rejected_by_cause
            .iter()
            .map(|(cause, count)| format!("{count} × `{cause}`"))
            .collect();
        let lines: Vec<String> = report
            .rejections
            .iter()
            .take(10)
            .map(|r| r.line.to_string())
            .collect();
        let _ = writeln!(
            text,
            "{} inputs were rejected ({}), at lines {}{}; each is listed in `report.json`.",
            report.rejected,
            causes.join(", "),
            lines.join(", "),
            if report.rejections.len() > 10 {
                ", …"
            } else {
                ""
            }
        );
    }
    if report.gate.max_position_error_m.is_some() || report.gate.max_angle_error_rad.is_some() {
        if report.gate.passed {
            text.push_str("The gate passed: every given limit held.\n");
        } else {
            let _ = writeln!(
                text,
                "The gate FAILED: {}.",
                report.gate.failures.join("; ")
            );
        }
    }
    text
}

/// Writes every file into `dir` (created if needed); returns the paths written.
pub fn write_all(
    dir: &Path,
    validation: &Validation,
    context: &Context<'_>,
) -> io::Result<(ReportJson, Vec<PathBuf>)> {
    let report = report_json(validation, context);
    let json = serde_json::to_vec_pretty(&report).map_err(io::Error::other)?;
    let mut csv = Vec::new();
    write_rows_csv(validation, &mut csv)?;
    let mut files = vec![
        ("report.json", json),
        ("report.md", report_md(validation, &report).into_bytes()),
        ("rows.csv", csv),
    ];
    if let Some(dynamics) = context.dynamics {
        let mut csv = Vec::new();
        write_dynamics_csv(dynamics, &mut csv)?;
        files.push(("dynamics.csv", csv));
        files.extend(
            dynamics_plots(dynamics)
                .into_iter()
                .map(|(name, text)| (name, text.into_bytes())),
        );
    }
    files.extend(
        plots(validation)
            .into_iter()
            .map(|(name, text)| (name, text.into_bytes())),
    );
    Ok((report, write_files(dir, &files)?))
}

/// Writes each `(file name, bytes)` into `dir` (created if needed); returns the paths written.
/// Shared by the commands that leave a report folder (`validate`, `calibrate`).
pub fn write_files(dir: &Path, files: &[(&str, Vec<u8>)]) -> io::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir)?;
    files
        .iter()
        .map(|(name, bytes)| {
            let path = dir.join(name);
            std::fs::write(&path, bytes)?;
            Ok(path)
        })
        .collect()
}
