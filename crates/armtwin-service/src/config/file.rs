//! The configuration file's sections as written (serde), before any check.
//!
//! Owns the TOML shape: names, types, defaults and `deny_unknown_fields`. Must not check values
//! or load anything: `super` turns these into the validated [`super::ServiceConfig`].

use std::collections::HashMap;
use std::path::PathBuf;

use serde::Deserialize;

use super::{
    AdminAccess, Congestion, EventBudget, OutputEncoding, OutputShape, SourceStream, ZenohSection,
};
use armtwin_core::metrics::DEFAULT_HISTORY_S;

use armtwin_codec::cdr::EffortMeaning;
use armtwin_core::align::AlignConfig;
use armtwin_core::dynamics::monitor::EffortConfig;
use armtwin_core::identify::IdentifyOptions;
use armtwin_core::pipeline::PipelineConfig;
use armtwin_core::self_calibration::ReservoirConfig;
use armtwin_mesh::ingest::SourceCodec;
use armtwin_mesh::ros2::KeyScheme;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct File {
    #[serde(default)]
    pub(super) zenoh: ZenohSection,
    #[serde(default)]
    pub(super) service: ServiceSection,
    #[serde(default)]
    pub(super) align: AlignSection,
    #[serde(default)]
    pub(super) self_calibration: SelfCalibrationSection,
    #[serde(default)]
    pub(super) effort: EffortSection,
    #[serde(default)]
    pub(super) robots: HashMap<String, RobotSection>,
    #[serde(default)]
    pub(super) sources: Vec<SourceSection>,
    #[serde(default)]
    pub(super) http: HttpSection,
    #[serde(default)]
    pub(super) recorder: RecorderSection,
    #[serde(default)]
    pub(super) opcua: armtwin_opcua::OpcUaSection,
}

/// `[http]`: the dashboard and `/metrics` (off unless `listen` is set), its TLS and tokens.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct HttpSection {
    pub(super) listen: Option<String>,
    pub(super) tls_certificate: Option<PathBuf>,
    pub(super) tls_private_key: Option<PathBuf>,
    #[serde(default)]
    pub(super) anonymous: bool,
    #[serde(default)]
    pub(super) tokens: Vec<TokenSection>,
}

/// `[[http.tokens]]`: one token the dashboard accepts.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct TokenSection {
    pub(super) name: String,
    pub(super) role: String,
    pub(super) hash: String,
}

/// `[self_calibration]`: how robots with `self_calibrate = true` keep their pairs and re-fit.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct SelfCalibrationSection {
    pub(super) refit_period_s: f64,
    pub(super) train_capacity: usize,
    pub(super) held_out_capacity: usize,
    pub(super) block_s: f64,
    pub(super) holdout_every: u64,
    pub(super) min_spacing_s: f64,
    pub(super) fit_tool: bool,
    pub(super) orientation_weight_m_per_rad: f64,
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

/// `[effort]`: how robots with `effort = true` are watched.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct EffortSection {
    pub(super) observer_gain_per_s: f64,
    pub(super) payload_tolerance_kg: f64,
    pub(super) payload_window_s: f64,
    pub(super) friction_window_s: f64,
    pub(super) collision_baseline_s: f64,
    pub(super) threshold_learning_s: f64,
    pub(super) threshold_factor: f64,
    pub(super) payload_reach_m: f64,
}

impl Default for EffortSection {
    fn default() -> Self {
        let defaults = EffortConfig::default();
        Self {
            observer_gain_per_s: defaults.observer_gain_per_s,
            payload_tolerance_kg: defaults.payload_tolerance_kg,
            payload_window_s: defaults.payload_window_s,
            friction_window_s: defaults.friction_window_s,
            collision_baseline_s: defaults.collision_baseline_s,
            threshold_learning_s: defaults.threshold_learning_s,
            threshold_factor: defaults.threshold_factor,
            payload_reach_m: defaults.payload_reach_m,
        }
    }
}

impl EffortSection {
    /// The settings every watched robot starts from (checked with each robot's arm).
    pub(super) fn config(&self) -> EffortConfig {
        EffortConfig {
            observer_gain_per_s: self.observer_gain_per_s,
            payload_tolerance_kg: self.payload_tolerance_kg,
            payload_window_s: self.payload_window_s,
            friction_window_s: self.friction_window_s,
            collision_baseline_s: self.collision_baseline_s,
            threshold_learning_s: self.threshold_learning_s,
            threshold_factor: self.threshold_factor,
            payload_reach_m: self.payload_reach_m,
            ..EffortConfig::default()
        }
    }
}

/// `[service] max_robots` unless set: the fleet a 2-core machine holds with room to spare
/// (BENCHMARKS.md: a few kilobytes per quiet robot, tens per streaming one), and far more robots
/// than one site has.
pub(super) const DEFAULT_MAX_ROBOTS: usize = 20_000;

/// `[service] forget_after_s` unless set: a week. Longer than a weekend or a maintenance stop, so
/// a robot that comes back keeps its cumulative metrics; short enough that the ids of robots
/// replaced, renamed or made up do not hold `max_robots` places for good.
pub(super) const DEFAULT_FORGET_AFTER_S: f64 = 7.0 * 24.0 * 3600.0;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct ServiceSection {
    pub(super) key_prefix: String,
    pub(super) metrics_period_ms: u64,
    pub(super) window_s: f64,
    pub(super) window_slices: usize,
    /// No longer read: the window keeps `window_slices` slices whatever the rate. Kept so that a
    /// file still setting it is told why, rather than that the key is unknown.
    pub(super) window_max_samples: Option<toml::Value>,
    pub(super) reject_unknown: bool,
    pub(super) encoding: OutputEncoding,
    pub(super) outputs: OutputShape,
    pub(super) pose_congestion: Congestion,
    pub(super) admin: AdminAccess,
    /// The fleet description whose prefix grants bound their robots (`max_robots` per grant).
    pub(super) fleet: Option<PathBuf>,
    pub(super) events_per_s: f64,
    pub(super) events_burst: u32,
    pub(super) robots: String,
    pub(super) state_dir: Option<PathBuf>,
    pub(super) snapshot_period_s: f64,
    pub(super) max_robots: usize,
    pub(super) forget_after_s: f64,
}

impl Default for ServiceSection {
    fn default() -> Self {
        let pipeline = PipelineConfig::default();
        Self {
            key_prefix: armtwin_mesh::keys::DEFAULT_PREFIX.to_owned(),
            metrics_period_ms: 100,
            window_s: pipeline.window_s,
            window_slices: pipeline.window_slices,
            window_max_samples: None,
            reject_unknown: false,
            encoding: OutputEncoding::Json,
            outputs: OutputShape::Separate,
            pose_congestion: Congestion::Drop,
            admin: AdminAccess::Loopback,
            fleet: None,
            events_per_s: EventBudget::default().per_s,
            events_burst: EventBudget::default().burst,
            robots: "**".to_owned(),
            state_dir: None,
            snapshot_period_s: 10.0,
            max_robots: DEFAULT_MAX_ROBOTS,
            forget_after_s: DEFAULT_FORGET_AFTER_S,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct AlignSection {
    pub(super) max_gap_s: f64,
    pub(super) max_wait_s: f64,
    pub(super) history_s: f64,
    pub(super) max_history: usize,
    pub(super) max_pending: usize,
    pub(super) restart_s: f64,
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
pub(super) struct RobotSection {
    pub(super) model: Option<String>,
    /// With a URDF `model`: the chain's base link (default: the root link).
    pub(super) base_link: Option<String>,
    /// With a URDF `model`: the chain's tip link (default: the one leaf link).
    pub(super) tip_link: Option<String>,
    pub(super) calibration: Option<PathBuf>,
    pub(super) tcp: Option<[f64; 6]>,
    pub(super) frame: Option<String>,
    pub(super) alarm_position_m: Option<f64>,
    pub(super) alarm_angle_rad: Option<f64>,
    pub(super) alarm_hold_s: Option<f64>,
    pub(super) self_calibrate: Option<bool>,
    pub(super) effort: Option<bool>,
    pub(super) collision_threshold_nm: Option<Vec<f64>>,
    /// Per joint, the drive's largest torque (N·m), over what the arm's description states.
    pub(super) rated_torque_nm: Option<Vec<f64>>,
    /// Per joint, motor current to joint torque (N·m/A) where the catalog has none.
    pub(super) current_to_torque_nm_per_a: Option<Vec<f64>>,
    /// Per joint, the drive's rotor inertia at the joint (kg·m²), over the description's.
    pub(super) reflected_rotor_inertia_kg_m2: Option<Vec<f64>>,
    pub(super) payload_kg: Option<f64>,
    pub(super) payload_cog_m: Option<[f64; 3]>,
    #[serde(default)]
    pub(super) sensors: Vec<SensorSection>,
    pub(super) ros2_pose: Option<Ros2PoseSection>,
    /// The flight recorder's ring for this robot (`[recorder] enabled` when unset).
    pub(super) record: Option<bool>,
    /// The robot's UR controller, `HOST[:PORT]`, which `serve` streams over RTDE itself.
    pub(super) rtde: Option<String>,
    pub(super) rtde_dashboard_port: Option<u16>,
    pub(super) rtde_frequency_hz: Option<f64>,
    /// Every data package to this CSV, as `armtwin gateway rtde --record` writes it.
    pub(super) rtde_record: Option<PathBuf>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SensorSection {
    pub(super) key_expr: String,
    /// `[x, y, z, rx, ry, rz]`: the sensor frame in the robot's base frame (m, rotation vector).
    #[serde(default)]
    pub(super) base_from_sensor: [f64; 6],
}

/// How `robot_from_key` reads a robot id.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum RobotFromKey {
    /// The ROS namespace of the key's topic.
    Ros2Namespace,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SourceSection {
    pub(super) key: String,
    pub(super) codec: SourceCodec,
    pub(super) stream: SourceStream,
    pub(super) robot: Option<String>,
    pub(super) robot_from_key: Option<RobotFromKey>,
    pub(super) scheme: Option<KeyScheme>,
    pub(super) topic: Option<String>,
    pub(super) tf_prefix: Option<String>,
    pub(super) joint_names: Option<Vec<String>>,
    pub(super) effort: Option<EffortMeaning>,
}

/// `ros2_pose` of a robot section (fields the robot's own leaves out come from
/// `[robots.default.ros2_pose]`).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct Ros2PoseSection {
    pub(super) enabled: Option<bool>,
    pub(super) scheme: Option<KeyScheme>,
    pub(super) domain_id: Option<u32>,
    pub(super) namespace: Option<String>,
    pub(super) topic: Option<String>,
    pub(super) tf_prefix: Option<String>,
    pub(super) type_hash: Option<String>,
}

/// `[recorder]` as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct RecorderSection {
    pub(super) enabled: bool,
    pub(super) pre_s: f64,
    pub(super) post_s: f64,
    pub(super) gap_s: f64,
    pub(super) dir: PathBuf,
    pub(super) max_files: usize,
    pub(super) max_bytes: u64,
    pub(super) robot_max_files: usize,
    pub(super) robot_max_bytes: u64,
    pub(super) robot_bytes: usize,
    pub(super) fleet_bytes: usize,
    pub(super) history_s: usize,
    pub(super) history_bytes: u64,
    pub(super) draw_robot: bool,
}

impl Default for RecorderSection {
    fn default() -> Self {
        Self {
            enabled: true,
            pre_s: 10.0,
            post_s: 5.0,
            gap_s: 1.0,
            dir: PathBuf::from("recordings"),
            max_files: 1000,
            max_bytes: 1 << 30,
            robot_max_files: 100,
            robot_max_bytes: 100 << 20,
            robot_bytes: 8 << 20,
            fleet_bytes: 1 << 30,
            history_s: DEFAULT_HISTORY_S,
            history_bytes: 512 << 20,
            draw_robot: true,
        }
    }
}
