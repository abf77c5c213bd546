//! `[robots.default]` and `[robots."<id>"]`: each robot's model, calibration, tool, alarms,
//! sensors and twin pose output for ROS tools.
//!
//! Owns loading and checking them, sharing one model among robots that agree on it. Must not
//! decide what the service subscribes to: sensor keys are checked against the other keys in
//! `sources`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use nalgebra::{IsometryMatrix3, Rotation3, Translation3, Vector3};

use zenoh::key_expr::KeyExpr;

use super::ConfigError;
use super::file::{RobotSection, Ros2PoseSection};
use armtwin_core::dynamics::Payload;
use armtwin_core::dynamics::monitor::{
    EffortConfig, EffortMonitor, JointValues, MAX_EFFORT_JOINTS,
};
use armtwin_core::kinematics::{OutputFrame, TcpOffset};
use armtwin_core::model::{Calibration, ModelError, ModelRef, RobotModel, catalog, custom, urdf};
use armtwin_core::orientation;
use armtwin_core::pipeline::{AlarmConfig, RobotSettings, SensorStream};
use armtwin_core::self_calibration::ReservoirConfig;
use armtwin_mesh::keys::{self, KeySpace};
use armtwin_mesh::ros2::{self, PoseOutput, PoseOutputs};
use armtwin_mesh::zenoh_section::without_source_location;

/// What every robot's settings start from: the sections shared by all robots.
pub(super) struct SharedSettings {
    /// `[self_calibration]`'s reservoir, for robots with `self_calibrate = true`.
    pub(super) reservoir: ReservoirConfig,
    /// `[effort]`, for robots with `effort = true`.
    pub(super) effort: EffortConfig,
    /// `[service] window_s`: the effort monitor's residual window.
    pub(super) window_s: f64,
}

/// The two ends of the chain taken from a URDF: `base_link` and `tip_link` (unset: the root
/// link, and the one leaf).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ChainEnds {
    /// `base_link`.
    pub base_link: Option<String>,
    /// `tip_link`.
    pub tip_link: Option<String>,
}

/// What a robot's own description (a URDF on `<prefix>/description/<robot>` or from a
/// `stream = "description"` source) does to its twin: a robot whose own section sets `model`
/// or `calibration` has it checked against that model; any other (its model the default's)
/// computes with it. The chain is picked with the robot's `base_link` and `tip_link`, else
/// `[robots.default]`'s.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DescriptionRules {
    own_model: std::collections::HashSet<String>,
    ends: HashMap<String, ChainEnds>,
    default_ends: ChainEnds,
}

impl DescriptionRules {
    /// Reads them off the `[robots]` sections.
    pub(super) fn of(sections: &HashMap<String, RobotSection>) -> Self {
        let default = sections.get("default");
        let default_ends = ChainEnds {
            base_link: default.and_then(|s| s.base_link.clone()),
            tip_link: default.and_then(|s| s.tip_link.clone()),
        };
        let mut rules = Self {
            default_ends: default_ends.clone(),
            ..Self::default()
        };
        for (id, section) in sections.iter().filter(|(id, _)| *id != "default") {
            if section.model.is_some() || section.calibration.is_some() {
                rules.own_model.insert(id.clone());
            }
            rules.ends.insert(
                id.clone(),
                ChainEnds {
                    base_link: section
                        .base_link
                        .clone()
                        .or_else(|| default_ends.base_link.clone()),
                    tip_link: section
                        .tip_link
                        .clone()
                        .or_else(|| default_ends.tip_link.clone()),
                },
            );
        }
        rules
    }

    /// Whether robot `id`'s own section sets its model: its description is then checked, not
    /// taken.
    #[must_use]
    pub fn has_own_model(&self, id: &str) -> bool {
        self.own_model.contains(id)
    }

    /// The chain ends of robot `id`'s description.
    #[must_use]
    pub fn ends(&self, id: &str) -> &ChainEnds {
        self.ends.get(id).unwrap_or(&self.default_ends)
    }
}

/// Which robots' TCP the configuration sets (`tcp` in their own section or in
/// `[robots.default]`): the others take the one their controller reports, when a gateway reads
/// it (`tcp_offset`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ConfiguredTools {
    /// `[robots.default]` sets `tcp`.
    default: bool,
    /// Robots with a section of their own whose TCP is set.
    robots: std::collections::HashSet<String>,
    /// Robots with a section of their own whose TCP is not.
    unset: std::collections::HashSet<String>,
}

impl ConfiguredTools {
    /// Reads them off the `[robots]` sections.
    pub(super) fn of(sections: &HashMap<String, RobotSection>) -> Self {
        let default = sections.get("default").is_some_and(|s| s.tcp.is_some());
        let mut tools = Self {
            default,
            ..Self::default()
        };
        for (id, section) in sections.iter().filter(|(id, _)| *id != "default") {
            if section.tcp.is_some() || default {
                tools.robots.insert(id.clone());
            } else {
                tools.unset.insert(id.clone());
            }
        }
        tools
    }

    /// Whether robot `id`'s TCP is configured (its own section's, else the default's).
    #[must_use]
    pub fn sets(&self, id: &str) -> bool {
        self.robots.contains(id) || (self.default && !self.unset.contains(id))
    }
}

/// `[robots.default]` (built in when absent: the `ur10e`, no tool) and every robot's own section.
pub(super) fn load_robots(
    sections: &HashMap<String, RobotSection>,
    (source_name, base_dir): (&str, &Path),
    shared: &SharedSettings,
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
            shared,
            &mut models,
        )?;
        if id == "default" {
            default_robot = Some(settings);
            continue;
        }
        if let Err(problem) = keys::robot_id(id) {
            return Err(ConfigError::Invalid {
                source_name: source_name.to_owned(),
                field: format!("robots.\"{id}\""),
                problem: match problem {
                    keys::PlainKeyError::TooLong { .. } => format!("the robot id {problem}"),
                    _ => "a robot id is one or more key chunks without wildcards".to_owned(),
                },
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
            shared,
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
            ModelRef::Urdf(relative) => {
                let (text, path) = self.read(relative)?;
                urdf::arm_from_urdf(
                    &text,
                    &path,
                    self.pick(|s| s.base_link.clone()).as_deref(),
                    self.pick(|s| s.tip_link.clone()).as_deref(),
                )
                .map_err(|e| self.model_error(e))?
            }
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

    /// The effort settings of a robot with `effort = true` (its thresholds and payload over
    /// `[effort]`'s), checked against its arm: one that cannot be watched is refused here, not
    /// at its first sample.
    fn effort(
        &self,
        model: &RobotModel,
        shared: &SharedSettings,
    ) -> Result<Option<EffortConfig>, ConfigError> {
        if !self.pick(|s| s.effort).unwrap_or(false) {
            return Ok(None);
        }
        let mut config = shared.effort;
        // One value per joint: their count is checked against the arm's by the monitor below.
        let per_joint = |name: &str, values: Option<Vec<f64>>| {
            values
                .map(|values| {
                    JointValues::from_slice(&values).ok_or_else(|| {
                        self.invalid(
                            name,
                            format!(
                                "has {} values; the load twin watches at most {MAX_EFFORT_JOINTS} joints",
                                values.len()
                            ),
                        )
                    })
                })
                .transpose()
        };
        if let Some(thresholds) = per_joint(
            "collision_threshold_nm",
            self.pick(|s| s.collision_threshold_nm.clone()),
        )? {
            config.collision_threshold_nm = Some(thresholds);
        }
        if let Some(rated) = per_joint("rated_torque_nm", self.pick(|s| s.rated_torque_nm.clone()))?
        {
            config.rated_torque_nm = Some(rated);
        }
        if let Some(factors) = per_joint(
            "current_to_torque_nm_per_a",
            self.pick(|s| s.current_to_torque_nm_per_a.clone()),
        )? {
            config.current_to_torque_nm_per_a = Some(factors);
        }
        if let Some(rotor) = per_joint(
            "reflected_rotor_inertia_kg_m2",
            self.pick(|s| s.reflected_rotor_inertia_kg_m2.clone()),
        )? {
            config.reflected_rotor_inertia_kg_m2 = Some(rotor);
        }
        match (self.pick(|s| s.payload_kg), self.pick(|s| s.payload_cog_m)) {
            (Some(mass_kg), cog) => {
                config.payload = Some(Payload::point_mass(mass_kg, cog.unwrap_or([0.0; 3])));
            }
            (None, Some(_)) => {
                return Err(self.invalid("payload_cog_m", "is set without payload_kg".to_owned()));
            }
            (None, None) => {}
        }
        if let Some(payload) = config.payload
            && !(payload.mass_kg.is_finite()
                && payload.mass_kg >= 0.0
                && payload.cog_flange_m.iter().all(|v| v.is_finite()))
        {
            return Err(self.invalid(
                "payload_kg",
                "the payload's mass must be a non-negative number and its centre of gravity finite"
                    .to_owned(),
            ));
        }
        EffortMonitor::new(model.arm(), &config, shared.window_s)
            .map_err(|e| self.invalid("effort", e.to_string()))?;
        Ok(Some(config))
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
    shared: &SharedSettings,
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
    let effort = source.effort(&model, shared)?;
    Ok(RobotSettings {
        model,
        alarm: source.alarm()?,
        sensors: source.sensors()?,
        self_calibration: source
            .pick(|s| s.self_calibrate)
            .unwrap_or(false)
            .then_some(shared.reservoir),
        effort,
    })
}

/// The robots that take their controller's model: those whose controller `serve` streams
/// (`rtde`) and whose own section names neither a `model` nor a `calibration` (a calibration is
/// one arm's, so it names the model too).
pub(super) fn models_from_controller(
    sections: &HashMap<String, RobotSection>,
) -> std::collections::HashSet<String> {
    sections
        .iter()
        .filter(|(id, section)| {
            *id != "default"
                && section.rtde.is_some()
                && section.model.is_none()
                && section.calibration.is_none()
        })
        .map(|(id, _)| id.clone())
        .collect()
}

/// `[robots."<id>"] rtde`: a UR controller `serve` streams itself over RTDE, on its own session.
/// What is not set here takes `armtwin gateway rtde`'s defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct RtdeLink {
    /// The robot the controller's samples are published as.
    pub robot: String,
    /// `HOST`, `HOST:PORT` or `[IPv6]:PORT`, as written.
    pub address: String,
    /// `rtde_dashboard_port`: the controller's dashboard server, read for its model and serial.
    pub dashboard_port: Option<u16>,
    /// `rtde_frequency_hz`: the output frequency to ask for.
    pub frequency_hz: Option<f64>,
    /// `rtde_record`: a CSV of every data package, relative to the configuration's folder.
    pub record: Option<PathBuf>,
}

/// The RTDE links of the robot sections, in robot id order; `[robots.default]` may set none of
/// their keys (every robot would stream one controller).
pub(super) fn load_rtde_links(
    sections: &HashMap<String, RobotSection>,
    (source_name, base_dir): (&str, &Path),
) -> Result<Vec<RtdeLink>, ConfigError> {
    if let Some(default) = sections.get("default") {
        let keys = [
            ("rtde", default.rtde.is_some()),
            ("rtde_dashboard_port", default.rtde_dashboard_port.is_some()),
            ("rtde_frequency_hz", default.rtde_frequency_hz.is_some()),
            ("rtde_record", default.rtde_record.is_some()),
        ];
        if let Some((key, _)) = keys.iter().find(|(_, set)| *set) {
            return Err(ConfigError::Invalid {
                source_name: source_name.to_owned(),
                field: format!("robots.default.{key}"),
                problem: "a controller is one robot's: set it in that robot's section".to_owned(),
            });
        }
    }
    let mut links = Vec::new();
    for (id, section) in sections {
        let Some(address) = &section.rtde else {
            let stray = section.rtde_dashboard_port.is_some()
                || section.rtde_frequency_hz.is_some()
                || section.rtde_record.is_some();
            if stray && id != "default" {
                return Err(ConfigError::Invalid {
                    source_name: source_name.to_owned(),
                    field: format!("robots.\"{id}\".rtde"),
                    problem: "missing: the other rtde_ keys describe the link to that controller"
                        .to_owned(),
                });
            }
            continue;
        };
        links.push(RtdeLink {
            robot: id.clone(),
            address: address.clone(),
            dashboard_port: section.rtde_dashboard_port,
            frequency_hz: section.rtde_frequency_hz,
            record: section.rtde_record.as_ref().map(|path| base_dir.join(path)),
        });
    }
    links.sort_by(|a, b| a.robot.cmp(&b.robot));
    Ok(links)
}

/// The twin pose outputs of `[robots.default]` and of every robot section.
/// Each output's key is checked to stay out of armtwin's own keys (`keys`).
pub(super) fn load_pose_outputs(
    sections: &HashMap<String, RobotSection>,
    source_name: &str,
    keys: &KeySpace,
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
            if let Some(output) = &output {
                let field = format!("robots.\"{id}\".ros2_pose");
                check_pose_output_key(keys, (source_name, &field), &output.key(id))?;
            }
            outputs.robots.insert(id.clone(), output);
        }
    }
    if let Some(output) = &outputs.default {
        // A robot without a section of its own has its id for namespace: checked here for a
        // one-chunk id, as the robots that come are not known yet.
        let field = "robots.default.ros2_pose";
        check_pose_output_key(keys, (source_name, field), &output.key("*"))?;
    }
    Ok(outputs)
}

/// Refuses a twin pose output key that reaches into armtwin's own keys: CDR poses there would
/// meet armtwin's own messages, or feed back into it.
fn check_pose_output_key(
    keys: &KeySpace,
    (source_name, field): (&str, &str),
    key: &str,
) -> Result<(), ConfigError> {
    let invalid = |problem: String| ConfigError::Invalid {
        source_name: source_name.to_owned(),
        field: field.to_owned(),
        problem: format!("key '{key}' {problem}"),
    };
    let key_expr = KeyExpr::try_from(key).map_err(|e| {
        invalid(format!(
            "is not a key expression: {}",
            without_source_location(&e.to_string())
        ))
    })?;
    match keys.own_subtree_of(&key_expr) {
        Some(own) => Err(invalid(format!(
            "intersects armtwin's own '{own}' (set ros2_pose.namespace or topic)"
        ))),
        None => Ok(()),
    }
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
