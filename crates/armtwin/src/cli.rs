//! The `armtwin` command line: argument definitions and the commands behind them.
//!
//! The outer ring: reads files, prints, and turns every error into one message with context
//! (`anyhow`). All computing is delegated to the core.
#![allow(
    clippy::print_stderr,
    reason = "the command line reports progress and problems to its user"
)]

use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use std::sync::Arc;

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use serde::Serialize;

use crate::codec::PoseFields;
use crate::codec::ik::{IkAnswerJson, IkRequest};
use crate::codec::joint_csv::{JointCsvReader, PoseCsvWriter};
use crate::codec::recording::{self, ColumnMap, PoseForm, Recording};
use crate::config::{Overrides, ServiceConfig, ZenohInsert, ZenohMode, ZenohSection};
use crate::fmi::FmuSettings;
use crate::fmu_package::{self, FmuContents, FmuPackageError};
use crate::kinematics::{OutputFrame, TcpOffset};
use crate::model::{Calibration, ModelRef, RobotModel, catalog, custom};
use crate::pipeline::RobotSettings;
use crate::replay::{self, ReplaySettings};
use crate::rosbag::{self, BagOptions, BagTopics};
use crate::service;
use crate::validate;

/// armtwin: live digital twin for robot arms.
#[derive(Debug, Parser)]
#[command(name = "armtwin", version, about, propagate_version = true)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// armtwin's commands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Forward kinematics: TCP pose of one joint configuration (JSON), or of every row of a CSV.
    Fk(FkArgs),
    /// List the built-in robot models with their DH parameters and joint limits.
    Models(ModelsArgs),
    /// Run the live twin service on Zenoh (peer on tcp/127.0.0.1:7447 by default).
    Serve(ServeArgs),
    /// Publish a recording (CSV) to the mesh as a gateway would, for `armtwin serve` to twin.
    Replay(ReplayArgs),
    /// Run a recording through the twin offline: report (JSON, Markdown), per-row CSV and plots;
    /// exits 3 when --max-position-error or --max-angle-error is exceeded.
    Validate(ValidateArgs),
    /// FMI 2.0 co-simulation FMU of the forward kinematics.
    Fmu(FmuArgs),
    /// Inverse kinematics: every joint configuration reaching a TCP pose (JSON), nearest the
    /// seed first; exits 1 with the reason when the pose is unreachable.
    Ik(IkArgs),
    /// Identify the robot's kinematics (calibration.conf deltas, optionally the tool) from a
    /// recording with measured poses; writes calibration.conf, report.json, report.md and a plot.
    Calibrate(CalibrateArgs),
}

/// `armtwin fmu` arguments.
#[derive(Debug, Args)]
pub struct FmuArgs {
    /// What to do.
    #[command(subcommand)]
    pub command: FmuCommand,
}

/// `armtwin fmu` commands.
#[derive(Debug, Subcommand)]
pub enum FmuCommand {
    /// Package one robot (catalog model, calibration, tool, frame) as an FMU file.
    Build(FmuBuildArgs),
}

/// `armtwin fmu build` arguments.
#[derive(Debug, Args)]
pub struct FmuBuildArgs {
    /// The robot (catalog models only; the tool becomes the `tcp_*` parameters' start values).
    #[command(flatten)]
    pub robot: RobotArgs,
    /// The FMU file to write, e.g. `UR10e_FK.fmu`; its name without `.fmu` is the model
    /// identifier.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// The FMU library (`libarmtwin_fmu.so`); by default the one next to this executable, built
    /// by `cargo build --release -p armtwin-fmu`.
    #[arg(long, value_name = "PATH")]
    pub library: Option<PathBuf>,
}

/// Which recording and how to read it; shared by `replay` and `validate`.
#[derive(Debug, Args)]
pub struct RecordingArgs {
    /// The recording: the UR10e FMU report's CSV form, a ROS 2 export or a UR RTDE recording
    /// (recognised from the header), any CSV with --joint-columns, or a rosbag2 recording (a bag
    /// directory, or its `.mcap` / `.db3` file).
    pub recording: PathBuf,
    /// Seconds between rows, ignoring the recording's time column (e.g. 0.1 for the report's
    /// `fmpy_inputs.csv`, whose time column is a row index).
    #[arg(long, value_name = "SECONDS")]
    pub period: Option<f64>,
    /// Joint angle columns, in joint order, for a header armtwin does not recognise (or to
    /// override what it recognises): `--joint-columns j1,j2,j3,j4,j5,j6`.
    #[arg(long, value_name = "NAMES", value_delimiter = ',')]
    pub joint_columns: Vec<String>,
    /// With --joint-columns: the time column.
    #[arg(long, value_name = "NAME", requires = "joint_columns")]
    pub time_column: Option<String>,
    /// With --time-column: its unit.
    #[arg(long, value_enum, default_value_t = TimeUnit::S)]
    pub time_unit: TimeUnit,
    /// With --joint-columns: the measured pose columns, `x,y,z` then the orientation columns of
    /// --pose-form.
    #[arg(
        long,
        value_name = "NAMES",
        value_delimiter = ',',
        requires = "joint_columns"
    )]
    pub pose_columns: Vec<String>,
    /// With --pose-columns: the orientation form.
    #[arg(long, value_enum, default_value_t = PoseFormArg::Quaternion)]
    pub pose_form: PoseFormArg,
    /// For a rosbag2 recording: the `sensor_msgs/msg/JointState` topic.
    #[arg(long, value_name = "TOPIC", default_value = "/joint_states")]
    pub joint_topic: String,
    /// For a rosbag2 recording: the `geometry_msgs/msg/PoseStamped` topic of the measured pose,
    /// in the robot's `base` frame.
    #[arg(
        long,
        value_name = "TOPIC",
        default_value = "/tcp_pose_broadcaster/pose"
    )]
    pub pose_topic: String,
    /// For a rosbag2 recording: the robot's `tf_prefix`, of its joint names and of its `base`
    /// frame.
    #[arg(long, value_name = "PREFIX", default_value = "")]
    pub tf_prefix: String,
}

/// `--time-unit` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum TimeUnit {
    /// Seconds.
    S,
    /// Milliseconds.
    Ms,
    /// Microseconds.
    Us,
    /// Nanoseconds.
    Ns,
}

/// `--pose-form` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PoseFormArg {
    /// `qx,qy,qz,qw`.
    Quaternion,
    /// `roll,pitch,yaw` (rad).
    Rpy,
    /// A UR rotation vector `rx,ry,rz` (rad).
    Rotvec,
}

/// `armtwin replay` arguments.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// The recording.
    #[command(flatten)]
    pub input: RecordingArgs,
    /// Robot id to publish as (may span several key chunks, e.g. plant-a/cell-3/ur10e-07).
    #[arg(long)]
    pub robot: String,
    /// Playback speed relative to the recording's time (2.0 = twice as fast).
    #[arg(long, default_value_t = 1.0, conflicts_with = "max_rate")]
    pub speed: f64,
    /// Publish as fast as the transport takes it.
    #[arg(long)]
    pub max_rate: bool,
    /// Key prefix of the service.
    #[arg(long, default_value = "twin")]
    pub prefix: String,
    /// How to join the mesh; without flags, as the default `armtwin serve` configuration says
    /// (a peer, multicast scouting off), connecting to where it listens (tcp/127.0.0.1:7447).
    #[command(flatten)]
    pub zenoh: ZenohArgs,
}

/// `armtwin validate` arguments.
#[derive(Debug, Args)]
pub struct ValidateArgs {
    /// The recording.
    #[command(flatten)]
    pub input: RecordingArgs,
    /// The robot the recording is of.
    #[command(flatten)]
    pub robot: RobotArgs,
    /// A service configuration whose alignment, window and default alarm settings to use
    /// (default: the built-in one, as `armtwin serve`).
    #[arg(short = 'c', long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Directory for the report (default: `<recording name>-validation`).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Fail (exit 3) if the largest position error exceeds this many metres.
    #[arg(long, value_name = "METRES")]
    pub max_position_error: Option<f64>,
    /// Fail (exit 3) if the largest rotation angle between twin and measured exceeds this many
    /// radians.
    #[arg(long, value_name = "RADIANS")]
    pub max_angle_error: Option<f64>,
}

/// `armtwin serve` arguments.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// The configuration file (TOML); without it, the built-in `config/armtwin.toml`.
    #[arg(short = 'c', long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// How to join the mesh; the flags override the configuration's `[zenoh]`.
    #[command(flatten)]
    pub zenoh: ZenohArgs,
    /// Serve the dashboard and `/metrics` on this address, e.g. 127.0.0.1:8080 (replaces the
    /// configuration's `[http] listen`).
    #[arg(long = "http", value_name = "ADDRESS")]
    pub http_listen: Option<std::net::SocketAddr>,
}

/// How a command joins the Zenoh mesh, in Zenoh's own style (as `zenohd`): the same flags, with
/// the same meaning, for every command that opens a session. Each flag overrides the command's
/// `[zenoh]` settings ([`ZenohSection::overridden`]); what is not given stays as they say.
#[derive(Debug, Clone, Default, Args)]
pub struct ZenohArgs {
    /// Zenoh mode [default: the configuration's, peer].
    #[arg(short = 'm', long, value_enum, value_name = "MODE")]
    pub mode: Option<ZenohMode>,
    /// Endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable; replaces the configuration's
    /// list).
    #[arg(short = 'l', long = "listen", value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// Endpoint to connect to, e.g. tcp/10.0.0.5:7447 (repeatable; replaces the configuration's
    /// list).
    #[arg(short = 'e', long = "connect", value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// Any Zenoh configuration value, as `zenohd --cfg`: a JSON5 VALUE at the configuration path
    /// KEY, e.g. `--cfg transport/shared_memory/enabled:false` or
    /// `--cfg scouting/multicast/enabled:true` (repeatable; applied last, so it wins).
    #[arg(long = "cfg", value_name = "KEY:VALUE")]
    pub cfg: Vec<ZenohInsert>,
}

impl ZenohArgs {
    /// The flags as configuration overrides.
    #[must_use]
    pub fn overrides(&self) -> Overrides {
        Overrides {
            mode: self.mode,
            listen: self.listen.clone(),
            connect: self.connect.clone(),
            cfg: self.cfg.clone(),
            http_listen: None,
        }
    }
}

/// Which robot: model, its calibration, its tool, and the output frame. Shared by every command
/// that computes poses.
#[derive(Debug, Args)]
pub struct RobotArgs {
    /// Catalog model (see `armtwin models`) or a custom arm's TOML file.
    #[arg(long, default_value = "ur10e")]
    pub model: String,
    /// The robot's factory calibration: the controller's `calibration.conf` or the YAML written by
    /// ROS `ur_calibration`.
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
    /// Tool (TCP) offset `x,y,z,rx,ry,rz` as on the UR pendant: metres and a rotation vector in
    /// radians. Write `--tcp=-0.1,...` when the first value is negative.
    #[arg(long, value_name = "X,Y,Z,RX,RY,RZ", value_parser = parse_tcp)]
    pub tcp: Option<TcpOffset>,
    /// Frame of the output pose: the controller's `base` (as RTDE `actual_TCP_pose`) or ROS
    /// `base_link` (base rotated π about z).
    #[arg(long, value_enum, default_value_t = FrameArg::Base)]
    pub frame: FrameArg,
}

/// `--frame` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FrameArg {
    /// The controller's base frame.
    Base,
    /// ROS `base_link`.
    #[value(name = "base_link")]
    BaseLink,
}

impl From<FrameArg> for OutputFrame {
    fn from(frame: FrameArg) -> Self {
        match frame {
            FrameArg::Base => Self::Base,
            FrameArg::BaseLink => Self::BaseLink,
        }
    }
}

/// `armtwin fk` arguments.
#[derive(Debug, Args)]
pub struct FkArgs {
    /// The robot.
    #[command(flatten)]
    pub robot: RobotArgs,
    /// Joint angles are in degrees (outputs stay in metres and radians).
    #[arg(long)]
    pub deg: bool,
    /// Also print the 4×4 homogeneous matrix (row-major) of the pose.
    #[arg(long)]
    pub matrix: bool,
    /// Read joint angles from a CSV (`q1..qn` or `time,q1..qn` columns; `-` for stdin) and write
    /// the pose CSV `time,x,y,z,roll,pitch,yaw,qx,qy,qz,qw` to stdout.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["joints", "matrix"])]
    pub csv: Option<PathBuf>,
    /// Joint angles q1 … qn (radians unless --deg).
    #[arg(allow_negative_numbers = true, value_name = "Q")]
    pub joints: Vec<f64>,
}

/// `armtwin models` arguments.
#[derive(Debug, Args)]
pub struct ModelsArgs {
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Runs one parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Fk(args) => run_fk(&args),
        Command::Models(args) => run_models(&args),
        Command::Serve(args) => run_serve(&args),
        Command::Replay(args) => run_replay(&args),
        Command::Validate(args) => run_validate(&args),
        Command::Fmu(FmuArgs {
            command: FmuCommand::Build(args),
        }) => run_fmu_build(&args),
        Command::Ik(args) => run_ik(&args),
        Command::Calibrate(args) => run_calibrate(&args),
    }
}

impl RecordingArgs {
    /// Reads the recording and its source times, and says on stderr what was recognised.
    fn load(&self) -> Result<(Recording, Vec<f64>)> {
        if let Some(period) = self.period
            && !(period.is_finite() && period > 0.0)
        {
            bail!("--period must be a positive number of seconds, got {period}");
        }
        let map = (!self.joint_columns.is_empty()).then(|| ColumnMap {
            time: self.time_column.clone(),
            time_scale_s: match self.time_unit {
                TimeUnit::S => 1.0,
                TimeUnit::Ms => 1e-3,
                TimeUnit::Us => 1e-6,
                TimeUnit::Ns => 1e-9,
            },
            joints: self.joint_columns.clone(),
            pose: (!self.pose_columns.is_empty()).then(|| {
                let form = match self.pose_form {
                    PoseFormArg::Quaternion => PoseForm::Quaternion,
                    PoseFormArg::Rpy => PoseForm::Rpy,
                    PoseFormArg::Rotvec => PoseForm::RotationVector,
                };
                (form, self.pose_columns.clone())
            }),
        });
        let recording = if rosbag::is_bag(&self.recording) {
            self.read_bag()?
        } else {
            let text = read_text(&self.recording)?;
            recording::read_with(&text, map.as_ref())
                .with_context(|| self.recording.display().to_string())?
        };
        let times = recording::source_times(&recording, self.period);
        let malformed: Vec<_> = recording
            .entries
            .iter()
            .filter_map(|e| e.as_ref().err())
            .collect();
        eprintln!(
            "{}: {} ({} rows{}, {} malformed lines)",
            self.recording.display(),
            recording.format.describe(),
            recording.entries.len(),
            if recording.has_pose {
                " with measured pose"
            } else {
                ", joints only"
            },
            malformed.len()
        );
        for line in malformed.iter().take(5) {
            eprintln!("  line {}: {}", line.line, line.problem);
        }
        if malformed.len() > 5 {
            eprintln!("  … and {} more", malformed.len() - 5);
        }
        Ok((recording, times))
    }

    /// Reads a rosbag2 recording into rows, and says on stderr what its topics held.
    fn read_bag(&self) -> Result<Recording> {
        let options = BagOptions {
            topics: BagTopics {
                joint_states: self.joint_topic.clone(),
                pose: self.pose_topic.clone(),
            },
            tf_prefix: self.tf_prefix.clone(),
        };
        let bag = rosbag::read(&self.recording, &options)
            .with_context(|| self.recording.display().to_string())?;
        eprintln!(
            "{}: {:?} storage, {}",
            self.recording.display(),
            bag.storage,
            bag.summary
        );
        for (number, reason) in bag.summary.pose_errors.iter().take(5) {
            eprintln!("  {} message {number}: {reason}", self.pose_topic);
        }
        Ok(bag.recording)
    }
}

/// A progress bar on stderr for `total` steps; hidden when stderr is not a terminal.
fn progress_bar(total: usize, what: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(total as u64), ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{what} {{bar:40}} {{pos}}/{{len}} rows ({{per_sec}}, {{eta}} left)"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}

fn run_fmu_build(args: &FmuBuildArgs) -> Result<()> {
    // The same checks and messages as `armtwin fk`.
    let model = args.robot.load()?;
    let calibration = args
        .robot
        .calibration
        .as_deref()
        .map(|path| -> Result<(String, String)> {
            let name = path
                .file_name()
                .and_then(|name| name.to_str())
                .with_context(|| format!("{}: not a file name in UTF-8", path.display()))?;
            Ok((name.to_owned(), read_text(path)?))
        })
        .transpose()?;
    let settings = FmuSettings {
        guid: String::new(),
        model: args.robot.model.to_ascii_lowercase(),
        calibration_file: calibration.as_ref().map(|(name, _)| name.clone()),
        frame: model.frame(),
        tool: *model.tool(),
    };
    let platform = fmu_package::host_platform().ok_or(FmuPackageError::Platform)?;
    let identifier = fmu_package::model_identifier(&args.out)?;
    let contents = FmuContents::new(
        &identifier,
        settings,
        calibration.as_ref().map(|(_, text)| text.as_str()),
    )?;
    let library_path = fmu_package::find_library(args.library.as_deref(), platform)?;
    let library = std::fs::read(&library_path)
        .with_context(|| format!("cannot read {}", library_path.display()))?;
    fmu_package::write_fmu(&args.out, &contents, &library, platform)?;
    let settings = &contents.settings;
    eprintln!(
        "wrote {}: {}, {}, frame {}, tcp {:?}; modelIdentifier {identifier}, GUID {} (library {})",
        args.out.display(),
        settings.model,
        settings.calibration_file.as_deref().map_or_else(
            || "nominal".to_owned(),
            |name| format!("calibration {name}")
        ),
        settings.frame.as_str(),
        settings.tool.to_ur_pose(),
        settings.guid,
        library_path.display()
    );
    Ok(())
}

fn run_replay(args: &ReplayArgs) -> Result<()> {
    if !(args.speed.is_finite() && args.speed > 0.0) {
        bail!("--speed must be a positive number, got {}", args.speed);
    }
    let (recording, times) = args.input.load()?;
    let settings = ReplaySettings {
        zenoh: ZenohSection::joining_default_service().overridden(&args.zenoh.overrides()),
        key_prefix: args.prefix.clone(),
        robot: args.robot.clone(),
        speed: (!args.max_rate).then_some(args.speed),
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let bar = progress_bar(recording.entries.len(), "replay");
    let report = runtime.block_on(replay::replay(
        &recording,
        &times,
        &settings,
        shutdown_signal(),
        |done| {
            if done % 256 == 0 {
                bar.set_position(done as u64);
            }
        },
    ))?;
    bar.finish_and_clear();
    eprintln!(
        "published {} messages ({} malformed lines as raw text){}",
        report.published,
        report.malformed,
        if report.interrupted {
            ", interrupted"
        } else {
            ""
        }
    );
    Ok(())
}

/// Exit status of `validate` when a gate limit is exceeded.
pub const EXIT_GATE_FAILED: u8 = 3;

/// `validate` ran, but a `--max-…-error` limit was exceeded.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct GateFailed(pub String);

fn run_validate(args: &ValidateArgs) -> Result<()> {
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
    };
    let bar = progress_bar(recording.entries.len(), "validate");
    let validation = validate::validate(&recording, &times, config.pipeline, settings, |done| {
        if done % 1024 == 0 {
            bar.set_position(done as u64);
        }
    });
    bar.finish_and_clear();
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
    eprintln!("wrote {} files into {}", written.len(), out.display());
    if !report.gate.passed {
        return Err(GateFailed(report.gate.failures.join("; ")).into());
    }
    Ok(())
}

fn run_serve(args: &ServeArgs) -> Result<()> {
    let overrides = Overrides {
        http_listen: args.http_listen,
        ..args.zenoh.overrides()
    };
    let config = ServiceConfig::load(args.config.as_deref(), &overrides)?;
    tracing::info!(config = %config.source_name, "configuration loaded");
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(async {
        service::serve(config, shutdown_signal()).await?;
        Ok(())
    })
}

/// Completes on Ctrl-C (SIGINT) or SIGTERM.
async fn shutdown_signal() {
    let interrupt = tokio::signal::ctrl_c();
    #[cfg(unix)]
    {
        let mut terminate =
            match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
                Ok(signal) => signal,
                Err(e) => {
                    tracing::warn!(error = %e, "cannot listen for SIGTERM; Ctrl-C still works");
                    let _ = interrupt.await;
                    return;
                }
            };
        tokio::select! {
            _ = interrupt => tracing::info!("SIGINT received"),
            _ = terminate.recv() => tracing::info!("SIGTERM received"),
        }
    }
    #[cfg(not(unix))]
    {
        let _ = interrupt.await;
    }
}

/// Parses `x,y,z,rx,ry,rz`; also accepts the pendant's `p[x, y, z, rx, ry, rz]` spelling.
fn parse_tcp(text: &str) -> Result<TcpOffset, String> {
    let inner = text.trim();
    let inner = inner.strip_prefix('p').unwrap_or(inner);
    let inner = inner
        .strip_prefix('[')
        .and_then(|t| t.strip_suffix(']'))
        .unwrap_or(inner);
    let values = inner
        .split(',')
        .map(|item| {
            item.trim()
                .parse::<f64>()
                .map_err(|_| format!("'{}' is not a number", item.trim()))
        })
        .collect::<Result<Vec<f64>, String>>()?;
    let values: [f64; 6] = values
        .try_into()
        .map_err(|v: Vec<f64>| format!("expected 6 values x,y,z,rx,ry,rz, got {}", v.len()))?;
    TcpOffset::from_ur_pose(values).ok_or_else(|| "every value must be finite".to_owned())
}

fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

impl RobotArgs {
    /// Loads the model, calibration and tool these arguments name.
    pub fn load(&self) -> Result<RobotModel> {
        let arm = match ModelRef::parse(&self.model) {
            ModelRef::CustomArm(path) => {
                custom::parse_arm(&read_text(path)?, &path.display().to_string())?
            }
            ModelRef::Catalog(name) => catalog::arm(name)?,
        };
        let calibration = self
            .calibration
            .as_deref()
            .map(|path| -> Result<Calibration> {
                Ok(Calibration::parse(
                    &read_text(path)?,
                    &path.display().to_string(),
                )?)
            })
            .transpose()?;
        Ok(RobotModel::new(
            arm,
            calibration,
            self.tcp.unwrap_or(TcpOffset::FLANGE),
            self.frame.into(),
        )?)
    }
}

#[derive(Serialize)]
struct FkOutput {
    #[serde(flatten)]
    pose: PoseFields,
    #[serde(skip_serializing_if = "Option::is_none")]
    matrix: Option<[[f64; 4]; 4]>,
}

fn to_radians(q: &mut [f64], degrees: bool) {
    if degrees {
        for angle in q {
            *angle = angle.to_radians();
        }
    }
}

fn run_fk(args: &FkArgs) -> Result<()> {
    let model = args.robot.load()?;
    if let Some(path) = &args.csv {
        return run_fk_csv(&model, path, args.deg);
    }
    if args.joints.is_empty() {
        bail!(
            "give {} joint angles (or --csv FILE); e.g. armtwin fk --model {} 0 -1.57 0 -1.57 0 0",
            model.joint_count(),
            model.arm().name
        );
    }
    let mut q = args.joints.clone();
    to_radians(&mut q, args.deg);
    let pose = model.pose(&q)?;
    let output = FkOutput {
        pose: PoseFields::from(&pose.readout()),
        matrix: args.matrix.then(|| pose.homogeneous_rows()),
    };
    let stdout = io::stdout();
    let mut out = stdout.lock();
    serde_json::to_writer(&mut out, &output)?;
    writeln!(out)?;
    Ok(())
}

fn run_fk_csv(model: &RobotModel, path: &Path, degrees: bool) -> Result<()> {
    let (input, name): (Box<dyn Read>, String) = if path == Path::new("-") {
        (Box::new(io::stdin().lock()), "stdin".to_owned())
    } else {
        let file = File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
        (Box::new(BufReader::new(file)), path.display().to_string())
    };
    let rows = JointCsvReader::new(input, model.joint_count()).with_context(|| name.clone())?;
    let mut writer = PoseCsvWriter::new(BufWriter::new(io::stdout().lock()))?;
    for row in rows {
        let mut row = row.with_context(|| name.clone())?;
        to_radians(&mut row.q, degrees);
        let pose = model
            .pose(&row.q)
            .with_context(|| format!("{name}: line {}", row.line))?;
        writer.write(row.time_s, &PoseFields::from(&pose.readout()))?;
    }
    writer.finish()?;
    Ok(())
}

#[derive(Serialize)]
struct ModelListing {
    name: &'static str,
    title: &'static str,
    convention: &'static str,
    joints: Vec<JointListing>,
}

#[derive(Serialize)]
struct JointListing {
    name: &'static str,
    a_m: f64,
    alpha_rad: f64,
    d_m: f64,
    theta_offset_rad: f64,
    min_rad: Option<f64>,
    max_rad: Option<f64>,
}

fn run_models(args: &ModelsArgs) -> Result<()> {
    let listings: Vec<ModelListing> = catalog::UNIVERSAL_ROBOTS
        .iter()
        .map(|entry| {
            let arm = entry.arm();
            ModelListing {
                name: entry.name,
                title: entry.title,
                convention: arm.convention.as_str(),
                joints: arm
                    .dh
                    .iter()
                    .zip(&arm.joint_limits)
                    .zip(catalog::UR_JOINT_NAMES)
                    .map(|((row, limits), name)| JointListing {
                        name,
                        a_m: row.a_m,
                        alpha_rad: row.alpha_rad,
                        d_m: row.d_m,
                        theta_offset_rad: row.theta_offset_rad,
                        min_rad: limits.min_rad,
                        max_rad: limits.max_rad,
                    })
                    .collect(),
            }
        })
        .collect();
    let stdout = io::stdout();
    let mut out = stdout.lock();
    if args.json {
        serde_json::to_writer_pretty(&mut out, &listings)?;
        writeln!(out)?;
        return Ok(());
    }
    writeln!(
        out,
        "Universal Robots, standard DH (alpha = [pi/2, 0, 0, pi/2, -pi/2, 0]), metres:"
    )?;
    writeln!(
        out,
        "{:<7} {:<17} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}  wrist 3",
        "model", "", "d1", "a2", "a3", "d4", "d5", "d6"
    )?;
    for entry in &catalog::UNIVERSAL_ROBOTS {
        let [d1, a2, a3, d4, d5, d6] = entry.d1_a2_a3_d4_d5_d6_m;
        writeln!(
            out,
            "{:<7} {:<17} {d1:>9} {a2:>9} {a3:>9} {d4:>9} {d5:>9} {d6:>9}  {}",
            entry.name,
            entry.title,
            if entry.wrist_3_unlimited {
                "unlimited"
            } else {
                "±360°"
            }
        )?;
    }
    writeln!(
        out,
        "Every other joint: ±360°. `armtwin models --json` for full tables."
    )?;
    Ok(())
}

/// `armtwin ik` arguments.
#[derive(Debug, Args)]
pub struct IkArgs {
    /// The robot.
    #[command(flatten)]
    pub robot: RobotArgs,
    /// The TCP pose `x,y,z,qx,qy,qz,qw` in the output frame (metres; quaternion in wire order,
    /// normalised here). Write `--pose=-0.4,...` when the first value is negative.
    #[arg(
        long,
        value_name = "X,Y,Z,QX,QY,QZ,QW",
        value_delimiter = ',',
        allow_negative_numbers = true,
        required = true
    )]
    pub pose: Vec<f64>,
    /// Joint angles q1,…,q6 (rad) to order the solutions by (nearest first) and to pick each
    /// joint's turn; also gives q6 where the wrist is singular.
    #[arg(
        long,
        value_name = "Q1,…,Q6",
        value_delimiter = ',',
        allow_negative_numbers = true
    )]
    pub seed: Vec<f64>,
}

fn run_ik(args: &IkArgs) -> Result<()> {
    let model = args.robot.load()?;
    let request = IkRequest::new(&args.pose, args.seed.clone()).context("--pose")?;
    let answer = crate::ik::solve(&model, &request.target, request.seed())?;
    let output = IkAnswerJson::from(&answer);
    let stdout = io::stdout();
    let mut out = stdout.lock();
    serde_json::to_writer(&mut out, &output)?;
    writeln!(out)?;
    Ok(())
}

/// `armtwin calibrate` arguments.
#[derive(Debug, Args)]
pub struct CalibrateArgs {
    /// The recording (any layout `validate` reads; it must carry measured poses).
    #[command(flatten)]
    pub input: RecordingArgs,
    /// The robot: the nominal model and the tool the recording was made with (`--calibration`
    /// is refused: the fit starts from the nominal arm).
    #[command(flatten)]
    pub robot: RobotArgs,
    /// Also fit the tool offset, starting from --tcp (or the flange).
    #[arg(long)]
    pub fit_tcp: bool,
    /// Fraction of the rows, taken from the end of the recording, held out from the fit.
    #[arg(long, default_value_t = 0.3, value_name = "FRACTION")]
    pub holdout: f64,
    /// Metres one radian of orientation error weighs as in the fit.
    #[arg(long, default_value_t = 1.0, value_name = "M_PER_RAD")]
    pub orientation_weight: f64,
    /// Directory for calibration.conf and the report.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

#[allow(
    clippy::too_many_lines,
    reason = "one command: pair, fit, evaluate, write"
)]
fn run_calibrate(args: &CalibrateArgs) -> Result<()> {
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
        alarm: crate::pipeline::AlarmConfig::default(),
        sensors: Vec::new(),
        self_calibration: None,
    };
    let validation = validate::validate(&recording, &times, config.pipeline, settings, |_| {});
    let (samples, lines) = crate::calibrate::paired_samples(&recording, &validation);
    let split = crate::identify::holdout_start(samples.len(), args.holdout);
    let options = crate::identify::IdentifyOptions {
        fit_tool: args.fit_tcp,
        orientation_weight_m_per_rad: args.orientation_weight,
        ..crate::identify::IdentifyOptions::default()
    };
    let fit = crate::identify::identify(
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
    let report = crate::calibrate::report(
        &recording_name,
        &model.arm().name,
        &fit,
        split,
        lines.get(split).copied(),
        crate::identify::pose_errors(&model, held_out),
        crate::identify::pose_errors(&identified, held_out),
        crate::identify::pose_errors(&identified, &samples[..split]),
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
        ("report.md", crate::calibrate::report_md(&report)),
        (
            "held_out_error.svg",
            crate::calibrate::held_out_plot(
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
