//! The commands behind the flags, one file each, and what several of them share: the robot and
//! the recording a command names, read from their files; the progress bar; the shutdown signal.
//!
//! The command line's edge: reads the files named on it, prints to its user and turns every error
//! into one message with context (`anyhow`). Must not compute: every pose, metric and fit comes
//! from the `armtwin` library.
#![allow(
    clippy::print_stderr,
    reason = "the command line reports progress and problems to its user"
)]

mod acl;
mod calibrate;
mod certs;
mod config;
mod doctor;
mod fk;
mod fmu;
mod gateway;
mod http_token;
mod ik;
mod models;
mod opcua_user;
mod record;
mod replay;
mod serve;
mod torques;
mod validate;

pub use validate::{EXIT_GATE_FAILED, GateFailed};

use std::path::Path;

use anyhow::{Context, Result, bail};
use armtwin_codec::recording::{self, ColumnMap, PoseForm, Recording};
use armtwin_core::kinematics::TcpOffset;
use armtwin_core::model::{Calibration, ModelRef, RobotModel, catalog, custom, urdf};
use armtwin_offline::rosbag::{self, BagOptions, BagTopics};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use crate::flags::{
    ChainLinks, Cli, Command, ConfigArgs, ConfigCommand, FmuArgs, FmuCommand, GatewayArgs,
    GatewayCommand, PoseFormArg, RecordingArgs, RobotArgs, TimeUnit,
};

/// Runs one parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Fk(args) => fk::run(&args),
        Command::Models(args) => models::run(&args),
        Command::Torques(args) => torques::run(&args),
        Command::Serve(args) => serve::run(&args),
        Command::Replay(args) => replay::run(&args),
        Command::Record(args) => record::run(&args),
        Command::Validate(args) => validate::run(&args),
        Command::Fmu(FmuArgs {
            command: FmuCommand::Build(args),
        }) => fmu::build(&args),
        Command::Ik(args) => ik::run(&args),
        Command::Calibrate(args) => calibrate::run(&args),
        Command::Gateway(GatewayArgs {
            command: GatewayCommand::Rtde(args),
        }) => gateway::rtde(&args),
        Command::Acl(args) => acl::run(&args),
        Command::Certs(args) => certs::run(&args),
        Command::HttpToken(args) => http_token::run(&args),
        Command::OpcuaUser(args) => opcua_user::run(&args),
        Command::Config(ConfigArgs {
            command: ConfigCommand::Show(args),
        }) => config::show(&args),
        Command::Doctor(args) => doctor::run(&args),
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

pub(super) fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

impl ChainLinks {
    /// Refuses `--base-link` and `--tip-link` for a model that is not a URDF, rather than ignore
    /// them.
    pub(super) fn only_for(&self, model: &ModelRef) -> Result<()> {
        if !matches!(model, ModelRef::Urdf(_))
            && (self.base_link.is_some() || self.tip_link.is_some())
        {
            bail!("--base-link and --tip-link name links of a URDF --model");
        }
        Ok(())
    }
}

impl RobotArgs {
    /// Loads the model, calibration and tool these arguments name.
    pub fn load(&self) -> Result<RobotModel> {
        let model = ModelRef::parse(&self.model);
        self.links.only_for(&model)?;
        let arm = match model {
            ModelRef::CustomArm(path) => {
                custom::parse_arm(&read_text(path)?, &path.display().to_string())?
            }
            ModelRef::Catalog(name) => catalog::arm(name)?,
            ModelRef::Urdf(path) => urdf::arm_from_urdf(
                &read_text(path)?,
                &path.display().to_string(),
                self.links.base_link.as_deref(),
                self.links.tip_link.as_deref(),
            )?,
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
