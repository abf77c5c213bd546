//! The service's configuration file (TOML) and the command-line overrides in Zenoh's own style.
//!
//! Owns parsing and validating the file, resolving paths relative to it, and loading every
//! robot's model, calibration and tool, so that a bad file fails at start with the file, the
//! field and the problem named, never later. The embedded default is `config/armtwin.toml`.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use nalgebra::{IsometryMatrix3, Rotation3, Translation3, Vector3};
use serde::Deserialize;
use thiserror::Error;

use crate::align::AlignConfig;
use crate::codec::cdr::JointNames;
use crate::identify::IdentifyOptions;
use crate::ingest::SourceCodec;
use crate::kinematics::{OutputFrame, TcpOffset};
use crate::model::{Calibration, ModelError, ModelRef, RobotModel, catalog, custom};
use crate::orientation;
use crate::pipeline::{AlarmConfig, PipelineConfig, RobotSettings, SensorStream};
use crate::ros2::{self, KeyScheme, NamespaceRule, PoseOutput, PoseOutputs};
use crate::self_calibration::ReservoirConfig;

/// The embedded default configuration (`config/armtwin.toml`).
pub const DEFAULT_CONFIG_TOML: &str = include_str!("../../../config/armtwin.toml");

/// Why a configuration cannot be used.
#[derive(Debug, Error)]
pub enum ConfigError {
    /// The file cannot be read.
    #[error("cannot read {path}")]
    Read {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The TOML is invalid or has unknown or mistyped fields.
    #[error("{source_name}: {message}")]
    Syntax {
        /// The file.
        source_name: String,
        /// The parser's message (with line and field).
        message: String,
    },
    /// A value is out of range or inconsistent.
    #[error("{source_name}: {field}: {problem}")]
    Invalid {
        /// The file.
        source_name: String,
        /// The field.
        field: String,
        /// What is wrong.
        problem: String,
    },
    /// A robot's model or calibration cannot be loaded.
    #[error("{source_name}: robot '{robot}'")]
    Model {
        /// The file.
        source_name: String,
        /// The robot id (`default` for the default).
        robot: String,
        /// The model error.
        source: Box<ModelError>,
    },
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default)]
    zenoh: ZenohSection,
    #[serde(default)]
    service: ServiceSection,
    #[serde(default)]
    align: AlignSection,
    #[serde(default)]
    self_calibration: SelfCalibrationSection,
    #[serde(default)]
    robots: HashMap<String, RobotSection>,
    #[serde(default)]
    sources: Vec<SourceSection>,
    #[serde(default)]
    http: HttpSection,
}

/// `[http]`: the dashboard and `/metrics` (off unless `listen` is set).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct HttpSection {
    listen: Option<String>,
}

/// `[self_calibration]`: how robots with `self_calibrate = true` keep their pairs and re-fit.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct SelfCalibrationSection {
    refit_period_s: f64,
    train_capacity: usize,
    held_out_capacity: usize,
    block_s: f64,
    holdout_every: u64,
    min_spacing_s: f64,
    fit_tool: bool,
    orientation_weight_m_per_rad: f64,
}

impl Default for SelfCalibrationSection {
    fn default() -> Self {
        let reservoir = ReservoirConfig::default();
        Self {
            refit_period_s: 10.0,
            train_capacity: reservoir.train_capacity,
            held_out_capacity: reservoir.held_out_capacity,
            block_s: reservoir.block_s,
            holdout_every: reservoir.holdout_every,
            min_spacing_s: reservoir.min_spacing_s,
            fit_tool: false,
            orientation_weight_m_per_rad: IdentifyOptions::default().orientation_weight_m_per_rad,
        }
    }
}

/// Self-calibration settings shared by the robots that opt in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SelfCalibrationConfig {
    /// How often each opted-in robot's pairs are fitted again (when new ones came in).
    pub refit_period: Duration,
    /// How pairs are kept.
    pub reservoir: ReservoirConfig,
    /// How they are fitted.
    pub options: IdentifyOptions,
}

/// `[zenoh]`: how armtwin joins the mesh.
#[derive(Debug, Clone, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ZenohSection {
    /// The session's role.
    #[serde(default)]
    pub mode: ZenohMode,
    /// Endpoints to listen on, e.g. `tcp/127.0.0.1:7447`.
    #[serde(default)]
    pub listen: Vec<String>,
    /// Endpoints to connect to.
    #[serde(default)]
    pub connect: Vec<String>,
    /// A complete Zenoh JSON5 configuration file; `mode`, `listen`, `connect` and
    /// `multicast_scouting` given here override it.
    pub file: Option<PathBuf>,
    /// Multicast scouting (off by default: peers are found through `listen`/`connect`).
    #[serde(default)]
    pub multicast_scouting: bool,
    /// Values set at a path of the Zenoh configuration (`zenohd --cfg` style), applied last so
    /// that they win over every key above.
    #[serde(default)]
    pub cfg: Vec<ZenohInsert>,
}

/// A Zenoh session's role (`-m/--mode`, `[zenoh] mode`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum ZenohMode {
    /// Talks to every session it reaches, directly.
    #[default]
    Peer,
    /// Talks through one router (or peer) it connects to.
    Client,
    /// Routes for clients and other routers.
    Router,
}

impl ZenohMode {
    /// The name Zenoh's configuration uses.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Peer => "peer",
            Self::Client => "client",
            Self::Router => "router",
        }
    }
}

impl std::fmt::Display for ZenohMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One `KEY:VALUE` setting of the Zenoh configuration: a JSON5 `value` at the path `key`, e.g.
/// `transport/shared_memory/enabled:false` (the key holds no `:`, the value may).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(try_from = "String")]
pub struct ZenohInsert {
    /// The configuration path, e.g. `transport/shared_memory/enabled`.
    pub key: String,
    /// The JSON5 value, e.g. `false`; Zenoh checks it against the key when the session's
    /// configuration is built.
    pub value: String,
}

/// A `--cfg` (or `[zenoh] cfg`) entry that is not `KEY:VALUE`.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error(
    "'{text}' is not KEY:VALUE (a Zenoh configuration path, a colon, a JSON5 value; e.g. transport/shared_memory/enabled:false)"
)]
pub struct ZenohInsertError {
    /// The entry as given.
    pub text: String,
}

impl std::str::FromStr for ZenohInsert {
    type Err = ZenohInsertError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text.split_once(':') {
            Some((key, value)) if !key.trim().is_empty() && !value.trim().is_empty() => Ok(Self {
                key: key.trim().to_owned(),
                value: value.trim().to_owned(),
            }),
            _ => Err(ZenohInsertError {
                text: text.to_owned(),
            }),
        }
    }
}

impl TryFrom<String> for ZenohInsert {
    type Error = ZenohInsertError;

    fn try_from(text: String) -> Result<Self, Self::Error> {
        text.parse()
    }
}

impl std::fmt::Display for ZenohInsert {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}", self.key, self.value)
    }
}

impl ZenohSection {
    /// How a session joins the service running on the embedded default configuration: its
    /// mode and multicast scouting, connecting to the endpoints it listens on
    /// (`tcp/127.0.0.1:7447`). What `armtwin replay` starts from, so that a bare `replay` reaches
    /// a bare `serve`.
    #[must_use]
    pub fn joining_default_service() -> Self {
        // The embedded file is checked by this module's tests; a broken one would fall back to
        // Zenoh's own defaults rather than stop `replay`.
        let service = toml::from_str::<File>(DEFAULT_CONFIG_TOML)
            .map(|file| file.zenoh)
            .unwrap_or_default();
        Self {
            mode: service.mode,
            connect: service.listen,
            multicast_scouting: service.multicast_scouting,
            ..Self::default()
        }
    }

    /// The section with the command line's flags applied: a mode replaces the section's, an
    /// endpoint list replaces the section's list, `--cfg` entries come after the section's own.
    #[must_use]
    pub fn overridden(mut self, overrides: &Overrides) -> Self {
        if let Some(mode) = overrides.mode {
            self.mode = mode;
        }
        if !overrides.listen.is_empty() {
            self.listen.clone_from(&overrides.listen);
        }
        if !overrides.connect.is_empty() {
            self.connect.clone_from(&overrides.connect);
        }
        self.cfg.extend(overrides.cfg.iter().cloned());
        self
    }
}

/// What to do when a pose or deviation cannot be sent to a subscriber as fast as it is produced
/// (metrics and events always wait: they are few, and must not be lost).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Congestion {
    /// Wait: nothing is lost, and a slow subscriber slows the twin and, through it, every
    /// gateway.
    Block,
    /// Drop the message for the congested subscriber only: the twin never waits for it, other
    /// subscribers get every message, and the congested one sees a gap in the pose `seq`.
    #[default]
    Drop,
}

/// The format of the pose and deviation outputs (metrics, events and query replies are JSON).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum OutputEncoding {
    /// JSON objects (`application/json`).
    #[default]
    Json,
    /// Zenoh's own serialization (`zenoh/serialized;armtwin/twin-pose/v1`,
    /// `zenoh/serialized;armtwin/deviation/v1`).
    ZenohSerialized,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct ServiceSection {
    key_prefix: String,
    metrics_period_ms: u64,
    window_s: f64,
    window_max_samples: usize,
    reject_unknown: bool,
    encoding: OutputEncoding,
    pose_congestion: Congestion,
    events_per_s: f64,
    events_burst: u32,
    robots: String,
    state_dir: Option<PathBuf>,
    snapshot_period_s: f64,
}

impl Default for ServiceSection {
    fn default() -> Self {
        let pipeline = PipelineConfig::default();
        Self {
            key_prefix: "twin".to_owned(),
            metrics_period_ms: 100,
            window_s: pipeline.window_s,
            window_max_samples: pipeline.window_max_samples,
            reject_unknown: false,
            encoding: OutputEncoding::Json,
            pose_congestion: Congestion::Drop,
            events_per_s: EventBudget::default().per_s,
            events_burst: EventBudget::default().burst,
            robots: "**".to_owned(),
            state_dir: None,
            snapshot_period_s: 10.0,
        }
    }
}

/// Where and how often the service writes its snapshot (`[service] state_dir`,
/// `snapshot_period_s`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SnapshotSettings {
    /// The folder of the snapshot file (relative paths are taken from the configuration's
    /// folder).
    pub state_dir: PathBuf,
    /// Time between two snapshots while the service runs (one more is written at shutdown).
    pub period: Duration,
}

/// How many events per robot the service publishes: a token bucket of `burst` events refilled at
/// `per_s`. Rejected, gap and unpaired events beyond it are counted, not published; alarms,
/// recoveries and restarts always go out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EventBudget {
    /// Sustained events per second per robot.
    pub per_s: f64,
    /// Events a robot may publish at once.
    pub burst: u32,
}

impl Default for EventBudget {
    fn default() -> Self {
        Self {
            per_s: 20.0,
            burst: 100,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct AlignSection {
    max_gap_s: f64,
    max_wait_s: f64,
    history_s: f64,
    max_history: usize,
    max_pending: usize,
    restart_s: f64,
}

impl Default for AlignSection {
    fn default() -> Self {
        let align = AlignConfig::default();
        Self {
            max_gap_s: align.max_gap_s,
            max_wait_s: align.max_wait_s,
            history_s: align.history_s,
            max_history: align.max_history,
            max_pending: align.max_pending,
            restart_s: align.restart_s,
        }
    }
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RobotSection {
    model: Option<String>,
    calibration: Option<PathBuf>,
    tcp: Option<[f64; 6]>,
    frame: Option<String>,
    alarm_position_m: Option<f64>,
    alarm_angle_rad: Option<f64>,
    alarm_hold_s: Option<f64>,
    self_calibrate: Option<bool>,
    #[serde(default)]
    sensors: Vec<SensorSection>,
    ros2_pose: Option<Ros2PoseSection>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SensorSection {
    key_expr: String,
    /// `[x, y, z, rx, ry, rz]`: the sensor frame in the robot's base frame (m, rotation vector).
    #[serde(default)]
    base_from_sensor: [f64; 6],
}

/// Everything `armtwin serve` needs, loaded and checked.
#[derive(Debug, Clone)]
pub struct ServiceConfig {
    /// Where the configuration came from (a path, or `embedded default`).
    pub source_name: String,
    /// `[zenoh]`, after command-line overrides.
    pub zenoh: ZenohSection,
    /// Key prefix (`twin`).
    pub key_prefix: String,
    /// Period of metrics publication while data flows.
    pub metrics_period: Duration,
    /// The format of the pose and deviation outputs.
    pub encoding: OutputEncoding,
    /// Congestion policy of the pose and deviation outputs (metrics and events block).
    pub pose_congestion: Congestion,
    /// How many events per robot are published.
    pub event_budget: EventBudget,
    /// Reject robots that are not configured (else they get `[robots.default]`).
    pub reject_unknown: bool,
    /// The pipeline's shared settings.
    pub pipeline: PipelineConfig,
    /// `[robots.default]`, unless unknown robots are rejected.
    pub default_robot: Option<RobotSettings>,
    /// Every `[robots."<id>"]`.
    pub robots: HashMap<String, RobotSettings>,
    /// `[self_calibration]`.
    pub self_calibration: SelfCalibrationConfig,
    /// `[[sources]]`: inputs on keys of the robots' own (ROS 2 topics, JSON elsewhere).
    pub sources: Vec<SourceConfig>,
    /// `ros2_pose` of `[robots.default]` and of each robot: the twin pose for ROS tools.
    pub ros2_pose: PoseOutputs,
    /// `[service] robots`: the robot ids this instance owns (`**`, every robot, by default);
    /// its subscriptions, queryables and tokens cover these alone.
    pub shard: zenoh::key_expr::KeyExpr<'static>,
    /// `[service] state_dir`: the snapshot of the twins' cumulative state, if kept.
    pub snapshots: Option<SnapshotSettings>,
    /// `[http] listen` (or `--http`): where the dashboard and `/metrics` listen; `None`, no HTTP.
    pub http_listen: Option<SocketAddr>,
}

/// Command-line overrides, Zenoh style (`-m`, `-l`, `-e`, `--cfg`).
#[derive(Debug, Clone, Default)]
pub struct Overrides {
    /// `-m/--mode`.
    pub mode: Option<ZenohMode>,
    /// `-l/--listen` (replaces the file's list when given).
    pub listen: Vec<String>,
    /// `-e/--connect` (replaces the file's list when given).
    pub connect: Vec<String>,
    /// `--cfg KEY:VALUE` (applied after the file's `cfg`, so they win).
    pub cfg: Vec<ZenohInsert>,
    /// `--http ADDRESS` (replaces `[http] listen`).
    pub http_listen: Option<SocketAddr>,
}

impl ServiceConfig {
    /// Loads `path`, or the embedded default when `None`, and applies `overrides`.
    pub fn load(path: Option<&Path>, overrides: &Overrides) -> Result<Self, ConfigError> {
        let (text, source_name, base_dir) = match path {
            Some(path) => (
                std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
                    path: path.display().to_string(),
                    source,
                })?,
                path.display().to_string(),
                path.parent().map(Path::to_path_buf).unwrap_or_default(),
            ),
            None => (
                DEFAULT_CONFIG_TOML.to_owned(),
                "embedded default config".to_owned(),
                PathBuf::new(),
            ),
        };
        Self::parse(&text, &source_name, &base_dir, overrides)
    }

    /// Parses configuration text; relative paths in it are taken from `base_dir`.
    pub fn parse(
        text: &str,
        source_name: &str,
        base_dir: &Path,
        overrides: &Overrides,
    ) -> Result<Self, ConfigError> {
        let file: File = toml::from_str(text).map_err(|e| ConfigError::Syntax {
            source_name: source_name.to_owned(),
            message: e.to_string(),
        })?;
        let mut zenoh = file.zenoh.overridden(overrides);
        zenoh.file = zenoh.file.map(|f| base_dir.join(f));
        let service = file.service;
        let align = check_service_and_align(&service, &file.align, source_name)?;
        let self_calibration = check_self_calibration(&file.self_calibration, source_name)?;
        let (default_robot, robots) = load_robots(
            &file.robots,
            (source_name, base_dir),
            self_calibration.reservoir,
        )?;
        let ros2_pose = load_pose_outputs(&file.robots, source_name)?;
        let (shard, snapshots) = check_deployment(&service, &robots, (source_name, base_dir))?;
        let http_listen = match (overrides.http_listen, &file.http.listen) {
            (Some(address), _) => Some(address),
            (None, None) => None,
            (None, Some(text)) => Some(text.parse().map_err(|e| ConfigError::Invalid {
                source_name: source_name.to_owned(),
                field: "http.listen".to_owned(),
                problem: format!("'{text}' is not an IP address and port: {e}"),
            })?),
        };
        let sources = load_sources(
            &file.sources,
            &SourceContext {
                source_name,
                key_prefix: &service.key_prefix,
                robots: &robots,
                default_robot: (!service.reject_unknown).then_some(&default_robot),
                ros2_pose: &ros2_pose,
                shard: &shard,
            },
        )?;
        Ok(Self {
            source_name: source_name.to_owned(),
            zenoh,
            key_prefix: service.key_prefix,
            metrics_period: Duration::from_millis(service.metrics_period_ms),
            encoding: service.encoding,
            pose_congestion: service.pose_congestion,
            event_budget: EventBudget {
                per_s: service.events_per_s,
                burst: service.events_burst,
            },
            reject_unknown: service.reject_unknown,
            pipeline: PipelineConfig {
                window_s: service.window_s,
                window_max_samples: service.window_max_samples,
                align,
            },
            default_robot: if service.reject_unknown {
                None
            } else {
                Some(default_robot)
            },
            robots,
            self_calibration,
            sources,
            ros2_pose,
            shard,
            snapshots,
            http_listen,
        })
    }

    /// Whether robot `id` belongs to this instance (`[service] robots`).
    #[must_use]
    pub fn owns(&self, id: &str) -> bool {
        owns(&self.shard, id)
    }
}

/// Whether robot `id` is one of `shard`'s: a robot id is a plain key, so it belongs to a shard
/// when the shard's key expression includes it.
#[must_use]
pub fn owns(shard: &zenoh::key_expr::KeyExpr<'_>, id: &str) -> bool {
    zenoh::key_expr::KeyExpr::try_from(id).is_ok_and(|key| shard.includes(&key))
}

/// Zenoh's error message without the source location it ends with (` at …/file.rs:line.`).
fn without_source_location(message: &str) -> &str {
    message
        .find(" at ")
        .filter(|&at| message[at..].contains(".rs:"))
        .map_or(message, |at| &message[..at])
}

/// Checks `[service] robots` (a key expression every configured robot is in), `state_dir` and
/// `snapshot_period_s`.
fn check_deployment(
    service: &ServiceSection,
    robots: &HashMap<String, RobotSettings>,
    (source_name, base_dir): (&str, &Path),
) -> Result<(zenoh::key_expr::KeyExpr<'static>, Option<SnapshotSettings>), ConfigError> {
    let invalid = |field: &str, problem: String| ConfigError::Invalid {
        source_name: source_name.to_owned(),
        field: format!("service.{field}"),
        problem,
    };
    let shard = zenoh::key_expr::KeyExpr::try_from(service.robots.clone()).map_err(|e| {
        invalid(
            "robots",
            format!(
                "'{}' is not a key expression of robot ids (e.g. \"site-a/**\"; a wildcard \
                 is a whole chunk, * or **, or $* inside one): {}",
                service.robots,
                without_source_location(&e.to_string())
            ),
        )
    })?;
    let mut outside: Vec<&str> = robots
        .keys()
        .map(String::as_str)
        .filter(|id| !owns(&shard, id))
        .collect();
    outside.sort_unstable();
    if let Some(id) = outside.first() {
        return Err(invalid(
            "robots",
            format!(
                "robot '{id}' is configured but outside '{shard}': its samples would never reach \
                 this instance"
            ),
        ));
    }
    if !(service.snapshot_period_s.is_finite() && service.snapshot_period_s >= 0.1) {
        return Err(invalid(
            "snapshot_period_s",
            format!("{} must be at least 0.1 (s)", service.snapshot_period_s),
        ));
    }
    let snapshots = service.state_dir.as_ref().map(|dir| SnapshotSettings {
        state_dir: base_dir.join(dir),
        period: Duration::from_secs_f64(service.snapshot_period_s),
    });
    Ok((shard, snapshots))
}

/// Checks `[self_calibration]`.
fn check_self_calibration(
    section: &SelfCalibrationSection,
    source_name: &str,
) -> Result<SelfCalibrationConfig, ConfigError> {
    let invalid = |field: &str, problem: String| ConfigError::Invalid {
        source_name: source_name.to_owned(),
        field: format!("self_calibration.{field}"),
        problem,
    };
    let positive = |field: &str, value: f64| {
        if value.is_finite() && value > 0.0 {
            Ok(value)
        } else {
            Err(invalid(field, format!("{value} must be a positive number")))
        }
    };
    let refit_period_s = positive("refit_period_s", section.refit_period_s)?;
    let block_s = positive("block_s", section.block_s)?;
    let orientation_weight = positive(
        "orientation_weight_m_per_rad",
        section.orientation_weight_m_per_rad,
    )?;
    if !(section.min_spacing_s.is_finite() && section.min_spacing_s >= 0.0) {
        return Err(invalid(
            "min_spacing_s",
            format!("{} must be a non-negative number", section.min_spacing_s),
        ));
    }
    // Identification needs twice its parameters in rows; judging needs `MIN_HELD_OUT`.
    let min_train = 60;
    if section.train_capacity < min_train || section.train_capacity > 100_000 {
        return Err(invalid(
            "train_capacity",
            format!(
                "{} must be in [{min_train}, 100000]",
                section.train_capacity
            ),
        ));
    }
    let min_held_out = crate::self_calibration::MIN_HELD_OUT;
    if section.held_out_capacity < min_held_out || section.held_out_capacity > 100_000 {
        return Err(invalid(
            "held_out_capacity",
            format!(
                "{} must be in [{min_held_out}, 100000]",
                section.held_out_capacity
            ),
        ));
    }
    if section.holdout_every < 2 {
        return Err(invalid(
            "holdout_every",
            format!("{} must be at least 2", section.holdout_every),
        ));
    }
    Ok(SelfCalibrationConfig {
        refit_period: Duration::from_secs_f64(refit_period_s),
        reservoir: ReservoirConfig {
            train_capacity: section.train_capacity,
            held_out_capacity: section.held_out_capacity,
            block_s,
            holdout_every: section.holdout_every,
            min_spacing_s: section.min_spacing_s,
        },
        options: IdentifyOptions {
            fit_tool: section.fit_tool,
            orientation_weight_m_per_rad: orientation_weight,
            ..IdentifyOptions::default()
        },
    })
}

/// Checks `[service]` and builds the alignment limits of `[align]`.
fn check_service_and_align(
    service: &ServiceSection,
    align: &AlignSection,
    source_name: &str,
) -> Result<AlignConfig, ConfigError> {
    let invalid = |field: &str, problem: String| ConfigError::Invalid {
        source_name: source_name.to_owned(),
        field: field.to_owned(),
        problem,
    };
    {
        if service.key_prefix.is_empty()
            || service.key_prefix.contains(['*', '$', '?', '#'])
            || service.key_prefix.starts_with('/')
            || service.key_prefix.ends_with('/')
        {
            return Err(invalid(
                "service.key_prefix",
                format!(
                    "'{}' is not a plain key (no wildcards, no leading or trailing '/')",
                    service.key_prefix
                ),
            ));
        }
        let positive = |field: &str, value: f64| {
            if value.is_finite() && value > 0.0 {
                Ok(value)
            } else {
                Err(invalid(field, format!("{value} must be a positive number")))
            }
        };
        positive("service.window_s", service.window_s)?;
        if service.metrics_period_ms == 0 {
            return Err(invalid(
                "service.metrics_period_ms",
                "must be at least 1".to_owned(),
            ));
        }
        positive("service.events_per_s", service.events_per_s)?;
        if service.events_burst == 0 {
            return Err(invalid(
                "service.events_burst",
                "must be at least 1".to_owned(),
            ));
        }
        if service.window_max_samples == 0 {
            return Err(invalid(
                "service.window_max_samples",
                "must be at least 1".to_owned(),
            ));
        }
        Ok(AlignConfig {
            max_gap_s: positive("align.max_gap_s", align.max_gap_s)?,
            max_wait_s: positive("align.max_wait_s", align.max_wait_s)?,
            history_s: positive("align.history_s", align.history_s)?,
            max_history: align.max_history.max(2),
            max_pending: align.max_pending.max(1),
            restart_s: positive("align.restart_s", align.restart_s)?,
        })
    }
}

/// `[robots.default]` (built in when absent: the `ur10e`, no tool) and every robot's own section.
fn load_robots(
    sections: &HashMap<String, RobotSection>,
    (source_name, base_dir): (&str, &Path),
    reservoir: ReservoirConfig,
) -> Result<(RobotSettings, HashMap<String, RobotSettings>), ConfigError> {
    let default_section = sections.get("default");
    let mut default_robot = None;
    let mut robots = HashMap::new();
    let mut models = HashMap::new();
    for (id, section) in sections {
        let settings = robot_settings(
            id,
            section,
            default_section,
            (source_name, base_dir),
            reservoir,
            &mut models,
        )?;
        if id == "default" {
            default_robot = Some(settings);
            continue;
        }
        if id.is_empty()
            || id.contains(['*', '$', '?', '#'])
            || id.starts_with('/')
            || id.ends_with('/')
        {
            return Err(ConfigError::Invalid {
                source_name: source_name.to_owned(),
                field: format!("robots.\"{id}\""),
                problem: "a robot id is one or more key chunks without wildcards".to_owned(),
            });
        }
        robots.insert(id.clone(), settings);
    }
    let default_robot = match default_robot {
        Some(settings) => settings,
        None => robot_settings(
            "default",
            &RobotSection::default(),
            None,
            (source_name, base_dir),
            reservoir,
            &mut models,
        )?,
    };
    Ok((default_robot, robots))
}

/// Where a robot's settings come from: the file, its own section and `[robots.default]`.
struct RobotSource<'a> {
    id: &'a str,
    section: &'a RobotSection,
    /// `[robots.default]`, for fields the robot's own section leaves out.
    fallback: Option<&'a RobotSection>,
    source_name: &'a str,
    base_dir: &'a Path,
}

impl RobotSource<'_> {
    fn invalid(&self, name: &str, problem: String) -> ConfigError {
        ConfigError::Invalid {
            source_name: self.source_name.to_owned(),
            field: format!("robots.\"{}\".{name}", self.id),
            problem,
        }
    }

    fn model_error(&self, source: ModelError) -> ConfigError {
        ConfigError::Model {
            source_name: self.source_name.to_owned(),
            robot: self.id.to_owned(),
            source: Box::new(source),
        }
    }

    /// The robot's own value of a field, else the default section's.
    fn pick<T: Clone>(&self, field: impl Fn(&RobotSection) -> Option<T>) -> Option<T> {
        field(self.section).or_else(|| self.fallback.and_then(&field))
    }

    fn read(&self, relative: &Path) -> Result<(String, String), ConfigError> {
        let path = self.base_dir.join(relative);
        let text = std::fs::read_to_string(&path).map_err(|source| ConfigError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Ok((text, path.display().to_string()))
    }

    fn model(&self) -> Result<RobotModel, ConfigError> {
        let model_name = self
            .pick(|s| s.model.clone())
            .unwrap_or_else(|| DEFAULT_MODEL.to_owned());
        let arm = match ModelRef::parse(&model_name) {
            ModelRef::CustomArm(relative) => {
                let (text, path) = self.read(relative)?;
                custom::parse_arm(&text, &path).map_err(|e| self.model_error(e))?
            }
            ModelRef::Catalog(name) => catalog::arm(name).map_err(|e| self.model_error(e))?,
        };
        let calibration = match self.pick(|s| s.calibration.clone()) {
            Some(relative) => {
                let (text, path) = self.read(&relative)?;
                Some(Calibration::parse(&text, &path).map_err(|e| self.model_error(e.into()))?)
            }
            None => None,
        };
        let tcp = match self.pick(|s| s.tcp) {
            Some(values) => TcpOffset::from_ur_pose(values)
                .ok_or_else(|| self.invalid("tcp", "every value must be finite".to_owned()))?,
            None => TcpOffset::FLANGE,
        };
        let frame = match self.pick(|s| s.frame.clone()) {
            None => OutputFrame::Base,
            Some(name) => OutputFrame::from_name(&name).ok_or_else(|| {
                self.invalid("frame", format!("'{name}' is not base or base_link"))
            })?,
        };
        RobotModel::new(arm, calibration, tcp, frame).map_err(|e| self.model_error(e))
    }

    fn alarm(&self) -> Result<AlarmConfig, ConfigError> {
        let non_negative = |name: &str, value: Option<f64>| match value {
            Some(v) if !(v.is_finite() && v >= 0.0) => {
                Err(self.invalid(name, format!("{v} must be a non-negative number")))
            }
            other => Ok(other),
        };
        Ok(AlarmConfig {
            position_m: non_negative("alarm_position_m", self.pick(|s| s.alarm_position_m))?,
            angle_rad: non_negative("alarm_angle_rad", self.pick(|s| s.alarm_angle_rad))?,
            hold_s: non_negative("alarm_hold_s", self.pick(|s| s.alarm_hold_s))?.unwrap_or(0.0),
        })
    }

    fn sensors(&self) -> Result<Vec<SensorStream>, ConfigError> {
        self.section
            .sensors
            .iter()
            .enumerate()
            .map(|(index, sensor)| {
                let [x, y, z, rx, ry, rz] = sensor.base_from_sensor;
                if !sensor.base_from_sensor.iter().all(|v| v.is_finite()) {
                    return Err(self.invalid(
                        &format!("sensors[{index}].base_from_sensor"),
                        "every value must be finite".to_owned(),
                    ));
                }
                if sensor.key_expr.is_empty() {
                    return Err(
                        self.invalid(&format!("sensors[{index}].key_expr"), "is empty".to_owned())
                    );
                }
                Ok(SensorStream {
                    key_expr: sensor.key_expr.clone(),
                    base_from_sensor: IsometryMatrix3::from_parts(
                        Translation3::new(x, y, z),
                        Rotation3::from_matrix_unchecked(orientation::matrix_from_rotation_vector(
                            &Vector3::new(rx, ry, rz),
                        )),
                    ),
                })
            })
            .collect()
    }
}

/// The arm of a robot whose sections name none.
const DEFAULT_MODEL: &str = "ur10e";

/// What a robot's model is built from, once its own section and `[robots.default]` are merged:
/// robots that agree on it share one model (a fleet of identical arms holds one, not thousands).
#[derive(Debug, PartialEq, Eq, Hash)]
struct ModelSource {
    /// The catalog name or custom arm file (the built-in default filled in).
    model: String,
    calibration: Option<PathBuf>,
    /// The `tcp` values' bits (doubles are not `Eq`).
    tcp_bits: Option<[u64; 6]>,
    frame: Option<String>,
}

/// A robot's settings: its own fields, else the default section's, else built-in defaults.
/// Models already built for an identical [`ModelSource`] (in `models`) are shared.
fn robot_settings(
    id: &str,
    section: &RobotSection,
    default_section: Option<&RobotSection>,
    (source_name, base_dir): (&str, &Path),
    reservoir: ReservoirConfig,
    models: &mut HashMap<ModelSource, Arc<RobotModel>>,
) -> Result<RobotSettings, ConfigError> {
    let source = RobotSource {
        id,
        section,
        fallback: if id == "default" {
            None
        } else {
            default_section
        },
        source_name,
        base_dir,
    };
    let model_source = ModelSource {
        model: source
            .pick(|s| s.model.clone())
            .unwrap_or_else(|| DEFAULT_MODEL.to_owned()),
        calibration: source.pick(|s| s.calibration.clone()),
        tcp_bits: source.pick(|s| s.tcp).map(|tcp| tcp.map(f64::to_bits)),
        frame: source.pick(|s| s.frame.clone()),
    };
    let model = if let Some(model) = models.get(&model_source) {
        Arc::clone(model)
    } else {
        let model = Arc::new(source.model()?);
        models.insert(model_source, Arc::clone(&model));
        model
    };
    Ok(RobotSettings {
        model,
        alarm: source.alarm()?,
        sensors: source.sensors()?,
        self_calibration: source
            .pick(|s| s.self_calibrate)
            .unwrap_or(false)
            .then_some(reservoir),
    })
}

/// Which stream of its robot a source feeds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SourceStream {
    /// Joint samples (`JointState` for ROS 2).
    Joints,
    /// Measured TCP poses in the robot's `base` frame (`PoseStamped` for ROS 2).
    Measured,
}

impl SourceStream {
    /// The configuration's name.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Joints => "joints",
            Self::Measured => "measured",
        }
    }
}

/// How a source finds the robot of a sample.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SourceRobot {
    /// Every sample is this robot's (`robot = "<id>"`).
    Fixed(String),
    /// The ROS namespace in the sample's key (`robot_from_key = "ros2_namespace"`).
    FromKey(NamespaceRule),
}

/// What a `codec = "ros2"` source reads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ros2Source {
    /// Whether samples carry `rmw_zenoh`'s attachment (and how keys are laid out).
    pub scheme: KeyScheme,
    /// The joints' names in `JointState` (`tf_prefix` included).
    pub joint_names: JointNames,
    /// The frame a `PoseStamped` must be in: `<tf_prefix>base`.
    pub base_frame: String,
}

/// One `[[sources]]` entry, checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SourceConfig {
    /// The key expression subscribed to.
    pub key_expr: String,
    /// How payloads are encoded.
    pub codec: SourceCodec,
    /// The stream fed.
    pub stream: SourceStream,
    /// The robot of each sample.
    pub robot: SourceRobot,
    /// `Some` exactly for `codec = "ros2"`.
    pub ros2: Option<Ros2Source>,
}

/// How `robot_from_key` reads a robot id.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
enum RobotFromKey {
    /// The ROS namespace of the key's topic.
    Ros2Namespace,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SourceSection {
    key: String,
    codec: SourceCodec,
    stream: SourceStream,
    robot: Option<String>,
    robot_from_key: Option<RobotFromKey>,
    scheme: Option<KeyScheme>,
    topic: Option<String>,
    tf_prefix: Option<String>,
    joint_names: Option<Vec<String>>,
}

/// `ros2_pose` of a robot section (fields the robot's own leaves out come from
/// `[robots.default.ros2_pose]`).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct Ros2PoseSection {
    enabled: Option<bool>,
    scheme: Option<KeyScheme>,
    domain_id: Option<u32>,
    namespace: Option<String>,
    topic: Option<String>,
    tf_prefix: Option<String>,
    type_hash: Option<String>,
}

/// The twin pose outputs of `[robots.default]` and of every robot section.
fn load_pose_outputs(
    sections: &HashMap<String, RobotSection>,
    source_name: &str,
) -> Result<PoseOutputs, ConfigError> {
    let fallback = sections.get("default").and_then(|s| s.ros2_pose.as_ref());
    let mut outputs = PoseOutputs {
        default: pose_output("default", fallback, None, source_name)?,
        robots: HashMap::new(),
    };
    if fallback.is_some_and(|section| section.namespace.is_some()) {
        return Err(ConfigError::Invalid {
            source_name: source_name.to_owned(),
            field: "robots.default.ros2_pose.namespace".to_owned(),
            problem: "would give every robot the same key: set it per robot (without it, a \
                      robot's namespace is its id)"
                .to_owned(),
        });
    }
    for (id, section) in sections {
        if id != "default" {
            let output = pose_output(id, section.ros2_pose.as_ref(), fallback, source_name)?;
            outputs.robots.insert(id.clone(), output);
        }
    }
    Ok(outputs)
}

/// One robot's twin pose output: its own `ros2_pose` fields, else the default section's.
fn pose_output(
    id: &str,
    own: Option<&Ros2PoseSection>,
    fallback: Option<&Ros2PoseSection>,
    source_name: &str,
) -> Result<Option<PoseOutput>, ConfigError> {
    if own.is_none() && fallback.is_none() {
        return Ok(None);
    }
    let invalid = |name: &str, problem: String| ConfigError::Invalid {
        source_name: source_name.to_owned(),
        field: format!("robots.\"{id}\".ros2_pose.{name}"),
        problem,
    };
    let pick = |field: fn(&Ros2PoseSection) -> Option<&str>| {
        own.and_then(field).or_else(|| fallback.and_then(field))
    };
    let enabled = own
        .and_then(|s| s.enabled)
        .or_else(|| fallback.and_then(|s| s.enabled))
        .unwrap_or(true);
    if !enabled {
        return Ok(None);
    }
    let scheme = own
        .and_then(|s| s.scheme)
        .or_else(|| fallback.and_then(|s| s.scheme))
        .ok_or_else(|| {
            invalid(
                "scheme",
                "is needed: \"rmw_zenoh\" (ROS 2 on Zenoh) or \"bridge\" (zenoh-bridge-ros2dds)"
                    .to_owned(),
            )
        })?;
    let namespace = own
        .and_then(|s| s.namespace.as_deref())
        .map(|namespace| {
            ros2::relative_ros_name(namespace, true)
                .map(str::to_owned)
                .map_err(|e| invalid("namespace", e.to_string()))
        })
        .transpose()?;
    let topic = pick(|s| s.topic.as_deref()).unwrap_or(ros2::DEFAULT_POSE_OUTPUT_TOPIC);
    let topic = ros2::relative_ros_name(topic, false)
        .map_err(|e| invalid("topic", e.to_string()))?
        .to_owned();
    let type_hash = pick(|s| s.type_hash.as_deref()).unwrap_or(ros2::POSE_STAMPED_TYPE_HASH);
    if type_hash.is_empty() || type_hash.contains(['/', '*', '$', '?', '#']) {
        return Err(invalid(
            "type_hash",
            format!("'{type_hash}' is not one key chunk"),
        ));
    }
    Ok(Some(PoseOutput {
        scheme,
        domain_id: own
            .and_then(|s| s.domain_id)
            .or_else(|| fallback.and_then(|s| s.domain_id))
            .unwrap_or(0),
        namespace,
        topic,
        tf_prefix: pick(|s| s.tf_prefix.as_deref()).unwrap_or("").to_owned(),
        type_hash: type_hash.to_owned(),
    }))
}

/// What `[[sources]]` are checked against.
struct SourceContext<'a> {
    source_name: &'a str,
    key_prefix: &'a str,
    robots: &'a HashMap<String, RobotSettings>,
    /// `None` when unknown robots are rejected.
    default_robot: Option<&'a RobotSettings>,
    ros2_pose: &'a PoseOutputs,
    /// `[service] robots`.
    shard: &'a zenoh::key_expr::KeyExpr<'static>,
}

impl SourceContext<'_> {
    fn invalid(&self, index: usize, name: &str, problem: String) -> ConfigError {
        ConfigError::Invalid {
            source_name: self.source_name.to_owned(),
            field: if name.is_empty() {
                format!("sources[{index}]")
            } else {
                format!("sources[{index}].{name}")
            },
            problem,
        }
    }
}

/// Checks every `[[sources]]` entry: a combination that cannot work is refused here, with the
/// field and the reason, rather than silently taking nothing at run time.
fn load_sources(
    sections: &[SourceSection],
    context: &SourceContext<'_>,
) -> Result<Vec<SourceConfig>, ConfigError> {
    let mut sources: Vec<SourceConfig> = Vec::with_capacity(sections.len());
    let mut keys: Vec<zenoh::key_expr::KeyExpr<'static>> = Vec::new();
    for (index, section) in sections.iter().enumerate() {
        let source = load_source(index, section, context)?;
        let key = check_source_key(index, &source, &keys, context)?;
        keys.push(key);
        sources.push(source);
    }
    for (id, settings) in context.robots {
        for (index, sensor) in settings.sensors.iter().enumerate() {
            let Ok(sensor_key) = zenoh::key_expr::KeyExpr::try_from(sensor.key_expr.as_str())
            else {
                // The service names a malformed sensor key when it declares it.
                continue;
            };
            let field = format!("robots.\"{id}\".sensors[{index}].key_expr");
            let clash = keys
                .iter()
                .enumerate()
                .find(|(_, key)| key.intersects(&sensor_key))
                .map(|(source, _)| format!("intersects sources[{source}].key"))
                .or_else(|| own_pose_output(&sensor_key, context.ros2_pose));
            if let Some(problem) = clash {
                return Err(ConfigError::Invalid {
                    source_name: context.source_name.to_owned(),
                    field,
                    problem: format!("'{}' {problem}", sensor.key_expr),
                });
            }
        }
    }
    Ok(sources)
}

/// Why `key` would receive armtwin's own twin pose output, if it would.
fn own_pose_output(key: &zenoh::key_expr::KeyExpr<'_>, outputs: &PoseOutputs) -> Option<String> {
    outputs.key_patterns().into_iter().find_map(|pattern| {
        let output = zenoh::key_expr::KeyExpr::try_from(pattern.as_str()).ok()?;
        key.intersects(&output).then(|| {
            format!("intersects the twin pose output '{pattern}': armtwin would read its own poses")
        })
    })
}

/// The ROS 2 settings of a source (`None` for JSON, which takes none of them).
fn ros2_source(
    index: usize,
    section: &SourceSection,
    context: &SourceContext<'_>,
) -> Result<Option<Ros2Source>, ConfigError> {
    let invalid = |name: &str, problem: String| context.invalid(index, name, problem);
    let ros2_only = [
        ("robot_from_key", section.robot_from_key.is_some()),
        ("scheme", section.scheme.is_some()),
        ("topic", section.topic.is_some()),
        ("tf_prefix", section.tf_prefix.is_some()),
        ("joint_names", section.joint_names.is_some()),
    ];
    match section.codec {
        SourceCodec::Json | SourceCodec::ZenohSerialized => {
            if let Some((name, _)) = ros2_only.iter().find(|(_, given)| *given) {
                return Err(invalid(
                    name,
                    "is read only with codec = \"ros2\" (a JSON source names its robot with \
                     robot = \"<id>\")"
                        .to_owned(),
                ));
            }
            Ok(None)
        }
        SourceCodec::Ros2 => {
            let scheme = section.scheme.ok_or_else(|| {
                invalid(
                    "scheme",
                    "codec = \"ros2\" needs scheme = \"rmw_zenoh\" (ROS 2 on Zenoh: keys \
                     <domain>/<namespace>/<topic>/<type>/<hash>, an attachment per sample) or \
                     \"bridge\" (zenoh-bridge-ros2dds: keys <namespace>/<topic>)"
                        .to_owned(),
                )
            })?;
            let tf_prefix = section.tf_prefix.clone().unwrap_or_default();
            let joint_names = match (&section.joint_names, section.stream) {
                (None, _) => JointNames::ur(&tf_prefix),
                (Some(_), SourceStream::Measured) => {
                    return Err(invalid(
                        "joint_names",
                        "is read only with stream = \"joints\"".to_owned(),
                    ));
                }
                (Some(names), SourceStream::Joints) => JointNames::new(
                    names
                        .iter()
                        .map(|name| format!("{tf_prefix}{name}"))
                        .collect(),
                )
                .ok_or_else(|| {
                    invalid(
                        "joint_names",
                        "needs 1 to 32 names, base to flange".to_owned(),
                    )
                })?,
            };
            Ok(Some(Ros2Source {
                scheme,
                base_frame: format!("{tf_prefix}base"),
                joint_names,
            }))
        }
    }
}

fn load_source(
    index: usize,
    section: &SourceSection,
    context: &SourceContext<'_>,
) -> Result<SourceConfig, ConfigError> {
    let invalid = |name: &str, problem: String| context.invalid(index, name, problem);
    let ros2 = ros2_source(index, section, context)?;
    let robot = match (&section.robot, section.robot_from_key) {
        (Some(_), Some(_)) => {
            return Err(invalid(
                "",
                "robot and robot_from_key exclude each other".to_owned(),
            ));
        }
        (None, None) => {
            return Err(invalid(
                "",
                "needs robot = \"<id>\" (every sample is that robot's) or, with codec = \
                 \"ros2\", robot_from_key = \"ros2_namespace\" (the robot is the topic's \
                 namespace)"
                    .to_owned(),
            ));
        }
        (Some(id), None) => {
            if section.topic.is_some() {
                return Err(invalid(
                    "topic",
                    "is read only with robot_from_key (it tells the namespace from the topic)"
                        .to_owned(),
                ));
            }
            let settings = fixed_robot(index, id, context)?;
            check_joint_count(index, id, settings, ros2.as_ref(), section.stream, context)?;
            SourceRobot::Fixed(id.clone())
        }
        (None, Some(RobotFromKey::Ros2Namespace)) => {
            // A JSON source with robot_from_key is refused above, with the field named.
            let Some(ros2) = &ros2 else {
                return Err(invalid(
                    "robot_from_key",
                    "is read only with codec = \"ros2\"".to_owned(),
                ));
            };
            let (default_topic, dds_type) = match section.stream {
                SourceStream::Joints => (ros2::UR_JOINT_TOPIC, ros2::JOINT_STATE_DDS_TYPE),
                SourceStream::Measured => (ros2::UR_POSE_TOPIC, ros2::POSE_STAMPED_DDS_TYPE),
            };
            let topic = section.topic.as_deref().unwrap_or(default_topic);
            let rule = NamespaceRule::new(ros2.scheme, topic, dds_type)
                .map_err(|e| invalid("topic", e.to_string()))?;
            SourceRobot::FromKey(rule)
        }
    };
    Ok(SourceConfig {
        key_expr: section.key.clone(),
        codec: section.codec,
        stream: section.stream,
        robot,
        ros2,
    })
}

/// The settings of a source's fixed robot, if it may be tracked at all.
fn fixed_robot<'a>(
    index: usize,
    id: &str,
    context: &SourceContext<'a>,
) -> Result<&'a RobotSettings, ConfigError> {
    if id.is_empty()
        || id.contains(['*', '$', '?', '#'])
        || id.starts_with('/')
        || id.ends_with('/')
    {
        return Err(context.invalid(
            index,
            "robot",
            format!("'{id}' is not a robot id (one or more key chunks without wildcards)"),
        ));
    }
    if !owns(context.shard, id) {
        return Err(context.invalid(
            index,
            "robot",
            format!(
                "robot '{id}' is outside service.robots '{}': this instance does not own it",
                context.shard
            ),
        ));
    }
    context
        .robots
        .get(id)
        .or(context.default_robot)
        .ok_or_else(|| {
            context.invalid(
                index,
                "robot",
                format!(
                    "robot '{id}' is not configured and service.reject_unknown is true: every \
                     sample would be rejected"
                ),
            )
        })
}

/// A ROS 2 joint source of a fixed robot must name as many joints as the robot's arm has.
fn check_joint_count(
    index: usize,
    id: &str,
    settings: &RobotSettings,
    ros2: Option<&Ros2Source>,
    stream: SourceStream,
    context: &SourceContext<'_>,
) -> Result<(), ConfigError> {
    let (Some(ros2), SourceStream::Joints) = (ros2, stream) else {
        return Ok(());
    };
    let names = ros2.joint_names.as_slice().len();
    let joints = settings.model.joint_count();
    if names == joints {
        Ok(())
    } else {
        Err(context.invalid(
            index,
            "joint_names",
            format!(
                "{names} joint names for robot '{id}', whose arm has {joints} joints (name them \
                 with joint_names = [...])"
            ),
        ))
    }
}

/// Checks a source's key expression: valid, clear of armtwin's own inputs and outputs and of
/// its twin pose outputs (a local put is delivered in the publishing thread, which holds the robot's lock),
/// disjoint from the sources before it, and able to name a robot under its rule.
fn check_source_key(
    index: usize,
    source: &SourceConfig,
    earlier: &[zenoh::key_expr::KeyExpr<'static>],
    context: &SourceContext<'_>,
) -> Result<zenoh::key_expr::KeyExpr<'static>, ConfigError> {
    use zenoh::key_expr::KeyExpr;
    let invalid = |problem: String| context.invalid(index, "key", problem);
    let text = &source.key_expr;
    let key = KeyExpr::try_from(text.clone())
        .map_err(|e| invalid(format!("'{text}' is not a key expression: {e}")))?;
    // Outputs would feed back into the twin; the built-in inputs would be taken twice.
    for stream in [
        "pose",
        "deviation",
        "metrics",
        "events",
        "joints",
        "measured",
    ] {
        let own = format!("{}/{stream}/**", context.key_prefix);
        if KeyExpr::try_from(own.as_str()).is_ok_and(|own_key| key.intersects(&own_key)) {
            return Err(invalid(format!(
                "'{text}' intersects armtwin's own '{own}' (its inputs and outputs are not \
                 sources)"
            )));
        }
    }
    if let Some(problem) = own_pose_output(&key, context.ros2_pose) {
        return Err(invalid(format!("'{text}' {problem}")));
    }
    if let Some(other) = earlier.iter().position(|other| other.intersects(&key)) {
        return Err(invalid(format!(
            "'{text}' intersects sources[{other}].key '{}': a sample would be taken twice",
            earlier[other]
        )));
    }
    if let SourceRobot::FromKey(rule) = &source.robot {
        let pattern = rule.key_pattern();
        let matches = KeyExpr::try_from(pattern.as_str()).is_ok_and(|p| key.intersects(&p));
        if !matches {
            let scheme = source.ros2.as_ref().map_or("", |ros2| ros2.scheme.as_str());
            return Err(invalid(format!(
                "'{text}' never carries topic '/{}' under a namespace in the {scheme} layout \
                 ('{pattern}'): no sample could name a robot (set topic, or robot = \"<id>\" \
                 for a robot without a namespace)",
                rule.topic()
            )));
        }
    }
    Ok(key)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zenoh_flags_override_the_file_and_cfg_entries_come_last() {
        let text = "[zenoh]\nmode = \"client\"\nlisten = [\"tcp/127.0.0.1:7000\"]\n\
                    connect = [\"tcp/10.0.0.1:7447\"]\ncfg = [\"transport/shared_memory/enabled:false\"]\n";
        let overrides = Overrides {
            mode: Some(ZenohMode::Router),
            listen: vec!["tcp/0.0.0.0:7447".to_owned()],
            connect: Vec::new(),
            cfg: vec![
                "connect/timeout_ms:{router: -1, peer: 2000}"
                    .parse()
                    .expect("KEY:VALUE"),
            ],
            http_listen: None,
        };
        let config = ServiceConfig::parse(text, "test", Path::new(""), &overrides).expect("valid");
        let zenoh = &config.zenoh;
        assert_eq!(zenoh.mode, ZenohMode::Router);
        assert_eq!(zenoh.listen, ["tcp/0.0.0.0:7447"]);
        assert_eq!(
            zenoh.connect,
            ["tcp/10.0.0.1:7447"],
            "no -e: the file's list stays"
        );
        let cfg: Vec<String> = zenoh.cfg.iter().map(ToString::to_string).collect();
        assert_eq!(
            cfg,
            [
                "transport/shared_memory/enabled:false",
                "connect/timeout_ms:{router: -1, peer: 2000}"
            ]
        );
        assert_eq!(zenoh.cfg[1].key, "connect/timeout_ms");
        // The default: a peer, multicast scouting off, no extra settings.
        let default = ServiceConfig::load(None, &Overrides::default()).expect("embedded");
        assert_eq!(default.zenoh.mode, ZenohMode::Peer);
        assert!(!default.zenoh.multicast_scouting && default.zenoh.cfg.is_empty());
        assert_eq!(
            ZenohSection::joining_default_service(),
            ZenohSection {
                connect: default.zenoh.listen,
                ..ZenohSection::default()
            }
        );
    }

    #[test]
    fn bad_zenoh_entries_are_named() {
        for bad in ["novalue", ":false", "key:", ""] {
            let error = bad.parse::<ZenohInsert>().expect_err(bad);
            assert!(
                error
                    .to_string()
                    .contains(&format!("'{bad}' is not KEY:VALUE")),
                "{error}"
            );
        }
        let error = ServiceConfig::parse(
            "[zenoh]\nmode = \"hub\"\n",
            "test",
            Path::new(""),
            &Overrides::default(),
        )
        .expect_err("unknown mode");
        assert!(error.to_string().contains("hub"), "{error}");
        let error = ServiceConfig::parse(
            "[zenoh]\ncfg = [\"oops\"]\n",
            "test",
            Path::new(""),
            &Overrides::default(),
        )
        .expect_err("not KEY:VALUE");
        assert!(
            error.to_string().contains("'oops' is not KEY:VALUE"),
            "{error}"
        );
    }

    #[test]
    fn robots_with_the_same_model_source_share_one_model() {
        let text = "[robots.default]\nmodel = \"ur10e\"\n\
                    [robots.a]\n[robots.b]\nmodel = \"ur10e\"\n\
                    [robots.c]\ntcp = [0.0, 0.0, 0.1, 0.0, 0.0, 0.0]\n\
                    [robots.d]\ntcp = [0.0, 0.0, 0.1, 0.0, 0.0, 0.0]\n\
                    [robots.e]\nmodel = \"ur5e\"\n";
        let config = ServiceConfig::parse(text, "test", Path::new(""), &Overrides::default())
            .expect("valid configuration");
        let model = |id: &str| Arc::clone(&config.robots[id].model);
        let default = Arc::clone(&config.default_robot.as_ref().expect("default").model);
        assert!(Arc::ptr_eq(&model("a"), &default) && Arc::ptr_eq(&model("b"), &default));
        assert!(Arc::ptr_eq(&model("c"), &model("d")));
        assert!(!Arc::ptr_eq(&model("c"), &default));
        assert!(!Arc::ptr_eq(&model("e"), &default));
        assert_eq!(model("e").arm().name, "ur5e");
    }

    #[test]
    fn shards_and_snapshots_are_checked_when_the_configuration_loads() {
        let parse = |text: &str| {
            ServiceConfig::parse(
                text,
                "test",
                Path::new("/etc/armtwin"),
                &Overrides::default(),
            )
        };
        let config = parse(
            "[service]\nrobots = \"site-a/**\"\nstate_dir = \"state\"\nsnapshot_period_s = 2.5\n",
        )
        .expect("valid");
        assert!(config.owns("site-a/r1") && config.owns("site-a/cell/r2"));
        // `**` also matches no chunk at all: a robot named `site-a` is the shard's too.
        assert!(config.owns("site-a") && !config.owns("site-b/r1") && !config.owns("site-ab/r1"));
        assert_eq!(
            config.snapshots,
            Some(SnapshotSettings {
                state_dir: PathBuf::from("/etc/armtwin/state"),
                period: Duration::from_millis(2500),
            })
        );
        let default = parse("").expect("valid");
        assert!(default.owns("any/robot") && default.snapshots.is_none());

        for (text, expected) in [
            (
                "[service]\nrobots = \"site-*/**\"\n",
                "service.robots: 'site-*/**' is not a key expression of robot ids",
            ),
            (
                "[service]\nrobots = \"site-a/**\"\n[robots.\"site-b/r1\"]\n",
                "robot 'site-b/r1' is configured but outside 'site-a/**'",
            ),
            (
                "[service]\nrobots = \"site-a/**\"\n[[sources]]\nkey = \"plc/r9\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"site-b/r9\"\n",
                "robot 'site-b/r9' is outside service.robots 'site-a/**'",
            ),
            (
                "[service]\nsnapshot_period_s = 0.0\n",
                "service.snapshot_period_s: 0 must be at least 0.1",
            ),
        ] {
            let error = parse(text).expect_err(text).to_string();
            assert!(error.contains(expected), "{error}");
            assert!(!error.contains(".rs:"), "no source location: {error}");
        }
    }
}
