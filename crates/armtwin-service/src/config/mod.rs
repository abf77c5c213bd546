//! The service's configuration file (TOML) and the command-line overrides in Zenoh's own style.
//!
//! Owns parsing and validating the file, resolving paths relative to it, and loading every
//! robot's model, calibration and tool, so that a bad file fails at start with the file, the
//! field and the problem named, never later. The embedded default is `config/armtwin.toml`.
//!
//! A user's file is layered over the embedded default (`layers`): a key it leaves out keeps the
//! default's value. The file's sections as written are in `file`; robots in `robots`;
//! `[[sources]]` in `sources`; `[zenoh]` and the command line's Zenoh flags are the mesh crate's
//! (`armtwin_mesh::zenoh_section`), read here as one section of the file.
//! Must not open a session: the service does, with what this module checked.

#[cfg(test)]
mod documented_keys;
mod file;
mod http;
mod layers;
mod recorder;
mod robots;
mod sources;
#[cfg(test)]
mod zenoh_tests;

use std::collections::HashMap;
use std::fmt::Write as _;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;
use thiserror::Error;

use self::file::{AlignSection, File, SelfCalibrationSection, ServiceSection};
pub use self::recorder::RecorderConfig;
pub use self::robots::{ChainEnds, ConfiguredTools, DescriptionRules, RtdeLink};
use self::robots::{
    SharedSettings, load_pose_outputs, load_robots, load_rtde_links, models_from_controller,
};
pub use self::sources::{Ros2Source, SourceConfig, SourceRobot, SourceStream};
use self::sources::{SourceContext, load_sources};
use armtwin_core::align::AlignConfig;
use armtwin_core::identify::IdentifyOptions;
use armtwin_core::model::ModelError;
use armtwin_core::pipeline::{PipelineConfig, RobotSettings};
use armtwin_core::self_calibration::ReservoirConfig;
use armtwin_mesh::keys::KeySpace;
use armtwin_mesh::ros2::PoseOutputs;
use armtwin_mesh::zenoh_file::zenoh_file_keys;
pub use armtwin_mesh::zenoh_section::{
    Origin, Overrides, WrittenKeys, ZenohInsert, ZenohInsertError, ZenohMode, ZenohSection,
    without_source_location,
};

/// The embedded default configuration (`config/armtwin.toml`).
pub const DEFAULT_CONFIG_TOML: &str = include_str!("../../../../config/armtwin.toml");

/// Most slices `[service] window_slices` may ask for: a slice of the metrics window is 224
/// bytes per streaming robot, so this bounds a robot's window at 2.2 MB.
const MAX_WINDOW_SLICES: usize = 10_000;

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

/// Who may use the admin queries (`<prefix>/admin/**`), `[service] admin`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum AdminAccess {
    /// Answered while no other host can reach the instance (loopback listeners only, no
    /// connect, no multicast scouting), or when its own session's access control judges them.
    #[default]
    Loopback,
    /// Answered for whoever reaches the instance: a router's ACL guards the mesh.
    Mesh,
    /// Never answered.
    Off,
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

/// How a robot's twin poses and deviations go out (`[service] outputs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum OutputShape {
    /// Each on its own stream: `<prefix>/pose/<robot>` and `<prefix>/deviation/<robot>`.
    #[default]
    Separate,
    /// One message per joint sample on `<prefix>/paired/<robot>`: its twin pose, with the
    /// deviation of the measured pose paired at its stamp. One routed message per paired sample
    /// instead of two: Zenoh's routing, not the twin, is most of the service's CPU per sample.
    Paired,
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

/// Everything `armtwin serve` needs, loaded and checked.
#[derive(Debug, Clone)]
pub struct ServiceConfig {
    /// Where the configuration came from (a path, or `embedded default`).
    pub source_name: String,
    /// `[zenoh]`, after command-line overrides.
    pub zenoh: ZenohSection,
    /// Every key of armtwin's, under `[service] key_prefix` (`twin`).
    pub keys: KeySpace,
    /// Period of metrics publication while data flows.
    pub metrics_period: Duration,
    /// The format of the pose and deviation outputs.
    pub encoding: OutputEncoding,
    /// Whether poses and deviations go out on their own streams or paired in one.
    pub outputs: OutputShape,
    /// Congestion policy of the pose and deviation outputs (metrics and events block).
    pub pose_congestion: Congestion,
    /// Who may use the admin queries (`[service] admin`).
    pub admin: AdminAccess,
    /// The robots of each prefix a gateway is granted in the fleet description
    /// (`[service] fleet`), admitted up to the grant's own limit.
    pub robot_groups: Vec<armtwin_core::pipeline::RobotGroup>,
    /// How many events per robot are published.
    pub event_budget: EventBudget,
    /// Reject robots that are not configured (else they get `[robots.default]`).
    pub reject_unknown: bool,
    /// `[service] max_robots`: the most robots tracked; configured robots always fit.
    pub max_robots: usize,
    /// `[service] forget_after_s`: how long a robot admitted under the default may send nothing
    /// before it is retired; `None` (0 in the file): never.
    pub forget_after: Option<Duration>,
    /// The pipeline's shared settings.
    pub pipeline: PipelineConfig,
    /// `[robots.default]`, unless unknown robots are rejected.
    pub default_robot: Option<RobotSettings>,
    /// Every `[robots."<id>"]`.
    pub robots: HashMap<String, RobotSettings>,
    /// Which robots' TCP the configuration sets; the others take their controller's.
    pub configured_tools: ConfiguredTools,
    /// What the robots' own descriptions do to their twins.
    pub descriptions: DescriptionRules,
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
    /// `[http]`'s TLS and tokens (none of either on the embedded default).
    pub http_access: armtwin_access::http_access::HttpAccess,
    /// `[recorder]`: the flight recorder.
    pub recorder: RecorderConfig,
    /// `[opcua]` (or `--opcua`): the OPC UA server; `None`, none.
    pub opcua: Option<armtwin_opcua::OpcUaSettings>,
    /// `[robots."<id>"] rtde`: the UR controllers `serve` streams itself, in robot id order.
    pub rtde_links: Vec<RtdeLink>,
    /// The robots that take the model their controller says (`rtde`, and no `model` or
    /// `calibration` of their own).
    pub models_from_controller: std::collections::HashSet<String>,
}

/// The text of the configuration at `path` (none when `None`: the embedded default alone), its
/// name for messages, and the folder its relative paths start from.
fn read_source(path: Option<&Path>) -> Result<(String, String, PathBuf), ConfigError> {
    Ok(match path {
        Some(path) => (
            std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
                path: path.display().to_string(),
                source,
            })?,
            path.display().to_string(),
            path.parent().map(Path::to_path_buf).unwrap_or_default(),
        ),
        // Nothing over the default: the default's own values are not the user's, so that
        // `serve -m client` alone does not listen where the default's peer would.
        None => (
            String::new(),
            "embedded default config".to_owned(),
            PathBuf::new(),
        ),
    })
}

/// `text` layered over the embedded default: the table the sections are read from, and which of
/// `[zenoh]`'s mode and endpoints `text` writes itself.
fn effective_table(
    text: &str,
    source_name: &str,
) -> Result<(toml::Table, WrittenKeys), ConfigError> {
    let syntax = |name: &str, e: &toml::de::Error| ConfigError::Syntax {
        source_name: name.to_owned(),
        message: e.to_string(),
    };
    // The user's text on its own first, so that its errors name its own lines and fields.
    toml::from_str::<File>(text).map_err(|e| syntax(source_name, &e))?;
    let user: toml::Table = toml::from_str(text).map_err(|e| syntax(source_name, &e))?;
    let default: toml::Table =
        toml::from_str(DEFAULT_CONFIG_TOML).map_err(|e| syntax("embedded default config", &e))?;
    Ok(layers::effective(default, user))
}

/// The effective configuration of the file at `path` (the embedded default when `None`) as
/// TOML: the file layered over the default, each robot completed from `[robots.default]`,
/// checked as `armtwin serve` checks it. Paths in it are relative to the file, as written. It
/// opens with a comment line per `[zenoh]` mode, listen and connect: the value and where it came
/// from; a list the `[zenoh] file` sets itself is left out of `[zenoh]`, as it is left in the
/// file.
pub fn effective_toml(path: Option<&Path>) -> Result<String, ConfigError> {
    let (text, source_name, base_dir) = read_source(path)?;
    let config = ServiceConfig::parse(&text, &source_name, &base_dir, &Overrides::default())?;
    let (table, _) = effective_table(&text, &source_name)?;
    let mut table = layers::with_robots_completed(table);
    let zenoh_said = &config.zenoh;
    let mut origins = String::new();
    for (key, value, origin) in zenoh_said.with_origins() {
        // Writing to a String cannot fail.
        let _ = writeln!(origins, "# [zenoh] {key} = {value}: {origin}");
    }
    if let Some(toml::Value::Table(zenoh)) = table.get_mut("zenoh") {
        zenoh.insert("mode".to_owned(), zenoh_said.mode.as_str().into());
        let lists = [
            ("listen", &zenoh_said.listen, &zenoh_said.origins.listen),
            ("connect", &zenoh_said.connect, &zenoh_said.origins.connect),
        ];
        for (key, list, origin) in lists {
            if let Origin::ZenohFile { .. } = origin {
                zenoh.remove(key);
            } else {
                zenoh.insert(key.to_owned(), list.clone().into());
            }
        }
    }
    let text = toml::to_string(&table).map_err(|e| ConfigError::Syntax {
        source_name,
        message: e.to_string(),
    })?;
    Ok(origins + &text)
}

impl ServiceConfig {
    /// Loads `path`, or the embedded default when `None`, and applies `overrides`.
    pub fn load(path: Option<&Path>, overrides: &Overrides) -> Result<Self, ConfigError> {
        let (text, source_name, base_dir) = read_source(path)?;
        Self::parse(&text, &source_name, &base_dir, overrides)
    }

    /// Parses configuration text layered over the embedded default (a key it leaves out keeps
    /// the default's value); relative paths in it are taken from `base_dir`.
    pub fn parse(
        text: &str,
        source_name: &str,
        base_dir: &Path,
        overrides: &Overrides,
    ) -> Result<Self, ConfigError> {
        let (table, written) = effective_table(text, source_name)?;
        let file =
            File::deserialize(toml::Value::Table(table)).map_err(|e| ConfigError::Syntax {
                source_name: source_name.to_owned(),
                message: e.to_string(),
            })?;
        let zenoh = load_zenoh(file.zenoh, written, (source_name, base_dir), overrides)?;
        let service = file.service;
        let keys = KeySpace::new(&service.key_prefix).map_err(|_| ConfigError::Invalid {
            source_name: source_name.to_owned(),
            field: "service.key_prefix".to_owned(),
            problem: format!(
                "'{}' is not a plain key (no wildcards, no leading or trailing '/')",
                service.key_prefix
            ),
        })?;
        let align = check_service_and_align(&service, &file.align, source_name)?;
        let self_calibration = check_self_calibration(&file.self_calibration, source_name)?;
        let (default_robot, robots) = load_robots(
            &file.robots,
            (source_name, base_dir),
            &SharedSettings {
                reservoir: self_calibration.reservoir,
                effort: file.effort.config(),
                window_s: service.window_s,
            },
        )?;
        let ros2_pose = load_pose_outputs(&file.robots, source_name, &keys)?;
        let rtde_links = load_rtde_links(&file.robots, (source_name, base_dir))?;
        let (shard, snapshots) = check_deployment(&service, &robots, (source_name, base_dir))?;
        let (http_listen, http_access) =
            http::load_http(&file.http, overrides.http_listen, (source_name, base_dir))?;
        let recorder =
            recorder::load_recorder(&file.recorder, &file.robots, (source_name, base_dir))?;
        let opcua = armtwin_opcua::OpcUaSettings::from_section(
            &file.opcua,
            overrides.opcua_endpoint.as_deref(),
            base_dir,
        )
        .map_err(|e| ConfigError::Invalid {
            source_name: source_name.to_owned(),
            field: format!("opcua.{}", e.field),
            problem: e.problem,
        })?;
        let sources = load_sources(
            &file.sources,
            &SourceContext {
                source_name,
                keys: &keys,
                robots: &robots,
                default_robot: (!service.reject_unknown).then_some(&default_robot),
                ros2_pose: &ros2_pose,
                shard: &shard,
            },
        )?;
        Ok(Self {
            source_name: source_name.to_owned(),
            zenoh,
            keys,
            metrics_period: Duration::from_millis(service.metrics_period_ms),
            encoding: service.encoding,
            outputs: service.outputs,
            pose_congestion: service.pose_congestion,
            admin: service.admin,
            robot_groups: robot_groups(&service, (source_name, base_dir))?,
            event_budget: EventBudget {
                per_s: service.events_per_s,
                burst: service.events_burst,
            },
            reject_unknown: service.reject_unknown,
            max_robots: service.max_robots,
            forget_after: (service.forget_after_s > 0.0)
                .then(|| Duration::from_secs_f64(service.forget_after_s)),
            pipeline: PipelineConfig {
                window_s: service.window_s,
                window_slices: service.window_slices,
                history_s: file.recorder.history_s,
                align,
            },
            default_robot: if service.reject_unknown {
                None
            } else {
                Some(default_robot)
            },
            robots,
            configured_tools: ConfiguredTools::of(&file.robots),
            descriptions: DescriptionRules::of(&file.robots),
            self_calibration,
            sources,
            ros2_pose,
            shard,
            snapshots,
            http_listen,
            http_access,
            rtde_links,
            models_from_controller: models_from_controller(&file.robots),
            recorder,
            opcua,
        })
    }

    /// Whether robot `id` belongs to this instance (`[service] robots`).
    #[must_use]
    pub fn owns(&self, id: &str) -> bool {
        owns(&self.shard, id)
    }
}

/// `[zenoh]` as the session gets it: the section (of which the user's file wrote `written`), its
/// `[zenoh] file`'s own mode and endpoints, then the command line's flags
/// ([`ZenohSection::layered`]). A `[zenoh] file` that cannot be read as Zenoh's is refused here.
fn load_zenoh(
    section: ZenohSection,
    written: WrittenKeys,
    (source_name, base_dir): (&str, &Path),
    overrides: &Overrides,
) -> Result<ZenohSection, ConfigError> {
    let zenoh_file = section.file.as_ref().map(|f| base_dir.join(f));
    let file_keys = zenoh_file
        .as_deref()
        .map(zenoh_file_keys)
        .transpose()
        .map_err(|e| ConfigError::Invalid {
            source_name: source_name.to_owned(),
            field: "zenoh.file".to_owned(),
            problem: e.to_string(),
        })?;
    Ok(ZenohSection {
        file: zenoh_file,
        ..section
    }
    .layered(written, file_keys.as_ref(), overrides))
}

/// Whether robot `id` is one of `shard`'s: a robot id is a plain key, so it belongs to a shard
/// when the shard's key expression includes it.
#[must_use]
pub fn owns(shard: &zenoh::key_expr::KeyExpr<'_>, id: &str) -> bool {
    zenoh::key_expr::KeyExpr::try_from(id).is_ok_and(|key| shard.includes(&key))
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
    let min_held_out = armtwin_core::self_calibration::MIN_HELD_OUT;
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
        if service.window_max_samples.is_some() {
            return Err(invalid(
                "service.window_max_samples",
                "is no longer used: the window is kept in `window_slices` time slices, so its \
                 memory does not depend on the rate; remove the key"
                    .to_owned(),
            ));
        }
        if !(1..=MAX_WINDOW_SLICES).contains(&service.window_slices) {
            return Err(invalid(
                "service.window_slices",
                format!("must be 1 to {MAX_WINDOW_SLICES}"),
            ));
        }
        if service.max_robots == 0 {
            return Err(invalid(
                "service.max_robots",
                "must be at least 1".to_owned(),
            ));
        }
        // Up to a year: beyond it, `Duration` arithmetic on the service's clock is the limit,
        // not the fleet.
        if !(service.forget_after_s.is_finite()
            && (0.0..=365.0 * 24.0 * 3600.0).contains(&service.forget_after_s))
        {
            return Err(invalid(
                "service.forget_after_s",
                format!(
                    "{} must be 0 (never) or a number of seconds up to a year",
                    service.forget_after_s
                ),
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

/// The prefix grants of the fleet description `[service] fleet` names, each a group of robots
/// with the grant's `max_robots`; none without one. Their limits together must leave room under
/// `max_robots` for the robots outside them (the ids granted by name, the configured ones).
fn robot_groups(
    service: &ServiceSection,
    (source_name, base_dir): (&str, &Path),
) -> Result<Vec<armtwin_core::pipeline::RobotGroup>, ConfigError> {
    let Some(path) = &service.fleet else {
        return Ok(Vec::new());
    };
    let path = base_dir.join(path);
    let text = std::fs::read_to_string(&path).map_err(|source| ConfigError::Read {
        path: path.display().to_string(),
        source,
    })?;
    let invalid = |problem: String| ConfigError::Invalid {
        source_name: source_name.to_owned(),
        field: "service.fleet".to_owned(),
        problem,
    };
    let fleet = armtwin_access::acl::Fleet::parse(&text)
        .map_err(|e| invalid(format!("{}: {e}", path.display())))?;
    let groups: Vec<armtwin_core::pipeline::RobotGroup> = fleet
        .robot_groups()
        .iter()
        .map(|(prefix, max_robots)| armtwin_core::pipeline::RobotGroup {
            prefix: prefix.clone(),
            max_robots: *max_robots,
        })
        .collect();
    let granted: usize = groups.iter().map(|group| group.max_robots).sum();
    if granted >= service.max_robots {
        return Err(invalid(format!(
            "the grants' max_robots add up to {granted}, which leaves no room under \
             service.max_robots ({}) for the robots granted by name: raise max_robots or lower \
             the grants' limits",
            service.max_robots
        )));
    }
    Ok(groups)
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;

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
    fn the_history_is_an_hour_unless_set_and_at_most_a_day() {
        let parse =
            |text: &str| ServiceConfig::parse(text, "test", Path::new(""), &Overrides::default());
        assert_eq!(parse("").expect("valid").pipeline.history_s, 3600);
        for seconds in [0, 86_400] {
            let text = format!("[recorder]\nhistory_s = {seconds}\n");
            assert_eq!(parse(&text).expect("valid").pipeline.history_s, seconds);
        }
        let error = parse("[recorder]\nhistory_s = 86401\n")
            .expect_err("over a day")
            .to_string();
        assert!(
            error.contains("recorder.history_s: 86401 is over a day"),
            "{error}"
        );
    }

    #[test]
    fn the_window_is_set_in_slices_and_its_old_cap_is_refused_with_why() {
        let parse =
            |text: &str| ServiceConfig::parse(text, "test", Path::new(""), &Overrides::default());
        let config = parse("[service]\nwindow_s = 5.0\nwindow_slices = 50\n").expect("valid");
        assert_eq!(
            (config.pipeline.window_s, config.pipeline.window_slices),
            (5.0, 50)
        );
        assert_eq!(
            parse("").expect("valid").pipeline.window_slices,
            armtwin_core::metrics::DEFAULT_WINDOW_SLICES
        );
        for (text, expected) in [
            (
                "[service]\nwindow_max_samples = 100000\n",
                "service.window_max_samples: is no longer used: the window is kept in \
                 `window_slices` time slices",
            ),
            (
                "[service]\nwindow_slices = 0\n",
                "service.window_slices: must be 1 to 10000",
            ),
            (
                "[service]\nwindow_slices = 10001\n",
                "service.window_slices: must be 1 to 10000",
            ),
        ] {
            let error = parse(text).expect_err(text).to_string();
            assert!(error.contains(expected), "{error}");
        }
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

    fn parse(text: &str) -> Result<ServiceConfig, ConfigError> {
        ServiceConfig::parse(text, "test", Path::new(""), &Overrides::default())
    }

    #[test]
    fn a_file_is_layered_over_the_embedded_default() {
        let default = ServiceConfig::load(None, &Overrides::default()).expect("embedded");
        let config = parse("[robots.\"r1\"]\nmodel = \"ur5e\"\n").expect("valid");
        assert_eq!(config.zenoh, default.zenoh);
        assert_eq!(config.zenoh.listen, ["tcp/127.0.0.1:7447"]);
        assert!(config.zenoh.reaches_anyone());
        assert_eq!(config.pipeline, default.pipeline);
        assert_eq!(config.robots["r1"].model.arm().name, "ur5e");
        // One key of a section replaces that key alone.
        let config = parse("[align]\nmax_gap_s = 0.1\n").expect("valid");
        assert_eq!(
            config.pipeline.align,
            AlignConfig {
                max_gap_s: 0.1,
                ..default.pipeline.align
            }
        );
        // A client listens only where its own file or -l says.
        let client = parse("[zenoh]\nmode = \"client\"\n").expect("valid");
        assert!(client.zenoh.listen.is_empty() && !client.zenoh.reaches_anyone());
        let by_flag = ServiceConfig::parse(
            "",
            "test",
            Path::new(""),
            &Overrides {
                mode: Some(ZenohMode::Client),
                connect: vec!["tcp/127.0.0.1:7000".to_owned()],
                ..Overrides::default()
            },
        )
        .expect("valid");
        assert!(by_flag.zenoh.listen.is_empty() && by_flag.zenoh.reaches_anyone());
        // The user's own errors still name the user's line.
        let error = parse("[service]\nwindow_s = \"ten\"\n").expect_err("mistyped");
        assert!(error.to_string().contains("line 2"), "{error}");
    }

    #[test]
    fn a_robot_without_a_configured_tcp_takes_its_controllers() {
        let tools = |text: &str| parse(text).unwrap().configured_tools;
        let own = tools("[robots.\"a\"]\ntcp = [0, 0, 0.1, 0, 0, 0]\n[robots.\"b\"]\n");
        assert!(own.sets("a") && !own.sets("b") && !own.sets("unknown"));
        let default = tools("[robots.default]\ntcp = [0, 0, 0.1, 0, 0, 0]\n[robots.\"b\"]\n");
        assert!(default.sets("b") && default.sets("unknown"));
        assert!(!tools("").sets("anyone"));
    }

    /// The error's text, which must name the file, the field and the key.
    fn refusal(text: &str) -> String {
        let error = parse(text).expect_err(text);
        assert!(matches!(error, ConfigError::Invalid { .. }), "{error:?}");
        error.to_string()
    }

    #[test]
    fn sensors_sources_and_ros_outputs_on_armtwins_own_keys_are_refused_naming_the_field() {
        let sensor = |key: &str| {
            format!("[robots.\"lab/r7\"]\n[[robots.\"lab/r7\".sensors]]\nkey_expr = \"{key}\"\n")
        };
        let source = |key: &str| {
            format!(
                "[[sources]]\nkey = \"{key}\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"r1\"\n"
            )
        };
        for (text, expected) in [
            // An input stream: every sample would be taken twice.
            (
                sensor("twin/joints/**"),
                "test: robots.\"lab/r7\".sensors[0].key_expr: 'twin/joints/**' intersects \
                 armtwin's own 'twin/joints/**'",
            ),
            (
                sensor("twin/measured/lab/r7"),
                "robots.\"lab/r7\".sensors[0].key_expr: 'twin/measured/lab/r7' intersects \
                 armtwin's own 'twin/measured/**'",
            ),
            // Outputs: armtwin would read its own puts (refused when the service started, before).
            (
                sensor("twin/*/lab/**"),
                "robots.\"lab/r7\".sensors[0].key_expr: 'twin/*/lab/**' intersects armtwin's \
                 own 'twin/pose/**'",
            ),
            (
                sensor("twin/calibration/lab/r7"),
                "'twin/calibration/lab/r7' intersects armtwin's own 'twin/calibration/**'",
            ),
            (
                sensor("lab/r*"),
                "robots.\"lab/r7\".sensors[0].key_expr: 'lab/r*' is not a key expression",
            ),
            (
                source("twin/calibration/**"),
                "test: sources[0].key: 'twin/calibration/**' intersects armtwin's own \
                 'twin/calibration/**'",
            ),
            (
                source("twin/state/r1"),
                "sources[0].key: 'twin/state/r1' intersects armtwin's own 'twin/state/**'",
            ),
            (
                "[service]\nkey_prefix = \"plant/twin\"\n[robots.r1]\n\
                 ros2_pose = { scheme = \"bridge\", namespace = \"plant\", topic = \"twin/pose/x\" }\n"
                    .to_owned(),
                "robots.\"r1\".ros2_pose: key 'plant/twin/pose/x' intersects armtwin's own \
                 'plant/twin/pose/**'",
            ),
            (
                "[robots.default]\nros2_pose = { scheme = \"bridge\", topic = \"events/x\" }\n\
                 [service]\nkey_prefix = \"fleet\"\n"
                    .to_owned(),
                "robots.default.ros2_pose: key '*/events/x' intersects armtwin's own \
                 'fleet/events/**'",
            ),
        ] {
            let error = refusal(&text);
            assert!(error.contains(expected), "{text}\n{error}");
            assert!(!error.contains(".rs:"), "no source location: {error}");
        }
        // Clear of armtwin's keys: accepted.
        let config = parse(&format!(
            "{}{}[robots.r1]\nros2_pose = {{ scheme = \"bridge\" }}\n",
            sensor("lab/r7/tracker"),
            source("plc/r1/joints")
        ))
        .expect("valid");
        assert_eq!(config.keys.prefix(), "twin");
        assert_eq!(config.sources[0].key_expr, "plc/r1/joints");
    }

    #[test]
    fn robot_ids_follow_the_one_grammar_in_robot_sections_and_sources() {
        let long = "r".repeat(armtwin_mesh::keys::MAX_ROBOT_ID_BYTES);
        for id in [
            "r1",
            "demo/ur10e",
            "plant-a/cell-3/ur10e-07",
            "ur_ns/arm_1",
            "ur 10",
            &long,
        ] {
            let section = format!("[robots.\"{id}\"]\n");
            let config = parse(&section).unwrap_or_else(|e| panic!("{id}: {e}"));
            assert!(config.robots.contains_key(id));
            let source = format!(
                "[[sources]]\nkey = \"plc/x\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"{id}\"\n"
            );
            parse(&source).unwrap_or_else(|e| panic!("{id}: {e}"));
        }
        let too_long = "r".repeat(armtwin_mesh::keys::MAX_ROBOT_ID_BYTES + 1);
        for id in [
            "a/*",
            "a/**",
            "$*",
            "a#1",
            "a?b",
            "/a",
            "a/",
            "a//b",
            too_long.as_str(),
        ] {
            let error = refusal(&format!("[robots.\"{id}\"]\n"));
            assert!(error.contains(&format!("robots.\"{id}\": ")), "{error}");
            assert!(error.contains(" robot id "), "{error}");
            let error = refusal(&format!(
                "[[sources]]\nkey = \"plc/x\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"{id}\"\n"
            ));
            assert!(
                error.contains(&format!("sources[0].robot: '{id}' is not a robot id")),
                "{error}"
            );
        }
        let error = refusal(&format!("[robots.\"{too_long}\"]\n"));
        assert!(
            error.ends_with(
                "the robot id is 257 bytes long, over the 256 bytes a robot id may have"
            ),
            "{error}"
        );
        for prefix in ["", "a//b", "twin/", "/twin", "tw*n", "t#"] {
            let error = refusal(&format!("[service]\nkey_prefix = \"{prefix}\"\n"));
            assert!(
                error.contains(&format!(
                    "service.key_prefix: '{prefix}' is not a plain key"
                )),
                "{error}"
            );
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(32))]

        /// Any id of plain chunks within the bound is a robot the configuration takes.
        #[test]
        fn plain_ids_are_accepted(chunks in proptest::collection::vec("[A-Za-z0-9_.@-]{1,8}", 1..6)) {
            let id = chunks.join("/");
            // Zenoh's `**` never matches a verbatim chunk (`@…`): such a robot is only in a
            // shard that names it.
            let shard = if chunks.iter().any(|chunk| chunk.starts_with('@')) { id.clone() } else { "**".to_owned() };
            let text = format!("[service]\nrobots = \"{shard}\"\n[robots.\"{id}\"]\n");
            let config = parse(&text);
            proptest::prop_assert!(config.is_ok(), "{}: {:?}", id, config.err());
        }
    }
}
