//! `[[sources]]`: inputs on keys of the robots' own (ROS 2 topics, JSON elsewhere), and the
//! check that no source or sensor key reaches into armtwin's own keys or its ROS outputs.
//!
//! Owns refusing, at load, every combination that could not work, naming the field. Must not
//! subscribe or decode: the service does.

use std::collections::HashMap;

use serde::Deserialize;
use zenoh::key_expr::KeyExpr;

use super::ConfigError;
use super::file::{RobotFromKey, SourceSection};
use armtwin_codec::cdr::{EffortMeaning, JointNames};
use armtwin_core::pipeline::RobotSettings;
use armtwin_mesh::ingest::SourceCodec;
use armtwin_mesh::keys::{self, KeySpace};
use armtwin_mesh::ros2::{self, KeyScheme, NamespaceRule, PoseOutputs};
use armtwin_mesh::zenoh_section::without_source_location;

/// Which stream of its robot a source feeds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SourceStream {
    /// Joint samples (`JointState` for ROS 2).
    Joints,
    /// Measured TCP poses in the robot's `base` frame (`PoseStamped` for ROS 2).
    Measured,
    /// The robot's own description, a URDF (`std_msgs/String` for ROS 2, as
    /// `robot_state_publisher` publishes `/robot_description`; the text itself for JSON).
    Description,
}

impl SourceStream {
    /// The configuration's name.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Joints => "joints",
            Self::Measured => "measured",
            Self::Description => "description",
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
    /// What `JointState.effort` holds (`None`: not read).
    pub effort: Option<EffortMeaning>,
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

/// What `[[sources]]` are checked against.
pub(super) struct SourceContext<'a> {
    pub(super) source_name: &'a str,
    /// armtwin's own keys, which no source or sensor may reach into.
    pub(super) keys: &'a KeySpace,
    pub(super) robots: &'a HashMap<String, RobotSettings>,
    /// `None` when unknown robots are rejected.
    pub(super) default_robot: Option<&'a RobotSettings>,
    pub(super) ros2_pose: &'a PoseOutputs,
    /// `[service] robots`.
    pub(super) shard: &'a KeyExpr<'static>,
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
pub(super) fn load_sources(
    sections: &[SourceSection],
    context: &SourceContext<'_>,
) -> Result<Vec<SourceConfig>, ConfigError> {
    let mut sources: Vec<SourceConfig> = Vec::with_capacity(sections.len());
    let mut keys: Vec<KeyExpr<'static>> = Vec::new();
    for (index, section) in sections.iter().enumerate() {
        let source = load_source(index, section, context)?;
        let key = check_source_key(index, &source, &keys, context)?;
        keys.push(key);
        sources.push(source);
    }
    check_sensor_keys(&keys, context)?;
    Ok(sources)
}

/// Checks every configured robot's sensor keys (the service subscribes to those alone): valid,
/// clear of armtwin's own keys and twin pose outputs, and of every source's key. A sensor on an
/// input stream would take its samples twice; on an output, armtwin would read its own puts,
/// delivered in the publishing thread, which holds the robot's lock.
fn check_sensor_keys(
    source_keys: &[KeyExpr<'static>],
    context: &SourceContext<'_>,
) -> Result<(), ConfigError> {
    // In id order, so that of several bad sensors the same one is named every time.
    let mut robots: Vec<(&String, &RobotSettings)> = context.robots.iter().collect();
    robots.sort_unstable_by_key(|(id, _)| *id);
    for (id, settings) in robots {
        for (index, sensor) in settings.sensors.iter().enumerate() {
            let invalid = |problem: String| ConfigError::Invalid {
                source_name: context.source_name.to_owned(),
                field: format!("robots.\"{id}\".sensors[{index}].key_expr"),
                problem: format!("'{}' {problem}", sensor.key_expr),
            };
            let sensor_key = KeyExpr::try_from(sensor.key_expr.as_str()).map_err(|e| {
                invalid(format!(
                    "is not a key expression: {}",
                    without_source_location(&e.to_string())
                ))
            })?;
            let clash = context
                .keys
                .own_subtree_of(&sensor_key)
                .map(|own| {
                    format!(
                        "intersects armtwin's own '{own}' (its inputs and outputs are not \
                         sensors)"
                    )
                })
                .or_else(|| {
                    source_keys
                        .iter()
                        .position(|key| key.intersects(&sensor_key))
                        .map(|source| format!("intersects sources[{source}].key"))
                })
                .or_else(|| own_pose_output(&sensor_key, context.ros2_pose));
            if let Some(problem) = clash {
                return Err(invalid(problem));
            }
        }
    }
    Ok(())
}

/// Why `key` would receive armtwin's own twin pose output, if it would.
fn own_pose_output(key: &KeyExpr<'_>, outputs: &PoseOutputs) -> Option<String> {
    outputs.key_patterns().into_iter().find_map(|pattern| {
        let output = KeyExpr::try_from(pattern.as_str()).ok()?;
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
        ("effort", section.effort.is_some()),
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
            if section.effort.is_some() && section.stream != SourceStream::Joints {
                return Err(invalid(
                    "effort",
                    "is read only with stream = \"joints\" (it says what JointState.effort holds)"
                        .to_owned(),
                ));
            }
            let tf_prefix = section.tf_prefix.clone().unwrap_or_default();
            let joint_names = match (&section.joint_names, section.stream) {
                (None, _) => JointNames::ur(&tf_prefix),
                (Some(_), SourceStream::Measured | SourceStream::Description) => {
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
                effort: section.effort,
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
    if section.stream == SourceStream::Description && section.codec == SourceCodec::ZenohSerialized
    {
        return Err(invalid(
            "codec",
            "stream = \"description\" reads codec = \"ros2\" (std_msgs/String) or \"json\" \
             (the URDF's text as it is)"
                .to_owned(),
        ));
    }
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
                SourceStream::Description => (ros2::DESCRIPTION_TOPIC, ros2::STRING_DDS_TYPE),
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

/// Why `id` is not a robot id, as a source's `robot` field reports it.
fn robot_id_problem(id: &str, problem: keys::PlainKeyError) -> String {
    match problem {
        keys::PlainKeyError::TooLong { .. } => format!("'{id}' is not a robot id: it {problem}"),
        _ => format!("'{id}' is not a robot id (one or more key chunks without wildcards)"),
    }
}

/// The settings of a source's fixed robot, if it may be tracked at all.
fn fixed_robot<'a>(
    index: usize,
    id: &str,
    context: &SourceContext<'a>,
) -> Result<&'a RobotSettings, ConfigError> {
    if let Err(problem) = keys::robot_id(id) {
        return Err(context.invalid(index, "robot", robot_id_problem(id, problem)));
    }
    if !super::owns(context.shard, id) {
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
    earlier: &[KeyExpr<'static>],
    context: &SourceContext<'_>,
) -> Result<KeyExpr<'static>, ConfigError> {
    let invalid = |problem: String| context.invalid(index, "key", problem);
    let text = &source.key_expr;
    let key = KeyExpr::try_from(text.clone())
        .map_err(|e| invalid(format!("'{text}' is not a key expression: {e}")))?;
    // Outputs would feed back into the twin; the built-in inputs would be taken twice.
    if let Some(own) = context.keys.own_subtree_of(&key) {
        return Err(invalid(format!(
            "'{text}' intersects armtwin's own '{own}' (its inputs and outputs are not \
             sources)"
        )));
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
