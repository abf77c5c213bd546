//! The FMI 2.0 FMU's interface contract, shared by the packager (`armtwin fmu build`) and the FMU
//! library (the `armtwin-fmu` crate): its scalar variables (names, value references, units,
//! descriptions) and the resource file that tells the model-agnostic library which robot it is.
//!
//! Pure: parses and writes text and builds the [`RobotModel`]; never opens a file. The packager
//! and the library both build the robot through [`FmuSettings::robot_model`], so what was
//! validated at build time is exactly what the FMU computes.

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::kinematics::{OutputFrame, TcpOffset};
use crate::model::{Calibration, ModelError, ModelRef, RobotModel, catalog};
use crate::pose_fields::PoseFields;

/// Name of the robot description inside the FMU's `resources/` folder.
pub const RESOURCE_FILE: &str = "armtwin-fmu.toml";

/// Number of joint inputs `q1..q6` (the `UR10e` FMU report's 6-joint interface).
pub const JOINT_COUNT: usize = 6;

/// Number of pose outputs, in the order of [`PoseFields::NAMES`].
pub const OUTPUT_COUNT: usize = PoseFields::NAMES.len();

/// Number of tool parameters `tcp_x..tcp_rz`.
pub const TOOL_COUNT: usize = 6;

/// Number of payload parameters: `payload_mass` and `payload_cog_x..z`.
pub const PAYLOAD_COUNT: usize = 4;

const FIRST_OUTPUT_VR: u32 = JOINT_COUNT as u32;
const FIRST_TOOL_VR: u32 = FIRST_OUTPUT_VR + OUTPUT_COUNT as u32;
const FIRST_VELOCITY_VR: u32 = FIRST_TOOL_VR + TOOL_COUNT as u32;
const FIRST_ACCELERATION_VR: u32 = FIRST_VELOCITY_VR + JOINT_COUNT as u32;
const FIRST_TORQUE_VR: u32 = FIRST_ACCELERATION_VR + JOINT_COUNT as u32;
const FIRST_PAYLOAD_VR: u32 = FIRST_TORQUE_VR + JOINT_COUNT as u32;
const VARIABLE_COUNT: u32 = FIRST_PAYLOAD_VR + PAYLOAD_COUNT as u32;

/// What a value reference addresses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Variable {
    /// Joint angle `q{index + 1}` (rad): an input, value references 0–5.
    Joint(usize),
    /// Pose output `PoseFields::NAMES[index]`: value references 6–15.
    Output(usize),
    /// Tool offset component `index` of `[x, y, z, rx, ry, rz]`: a tunable parameter, value
    /// references 16–21.
    Tool(usize),
    /// Joint velocity `qd{index + 1}` (rad/s): an input, value references 22–27.
    Velocity(usize),
    /// Joint acceleration `qdd{index + 1}` (rad/s²): an input, value references 28–33.
    Acceleration(usize),
    /// Joint torque `tau{index + 1}` (N·m) of the inverse dynamics: an output, value references
    /// 34–39.
    Torque(usize),
    /// Payload parameter `index` of `[mass, cog x, cog y, cog z]` (kg, m in the flange frame):
    /// a tunable parameter, value references 40–43.
    Payload(usize),
}

impl Variable {
    /// The variable with value reference `value_reference`, if there is one.
    #[must_use]
    pub fn from_value_reference(value_reference: u32) -> Option<Self> {
        let index = |first: u32| (value_reference - first) as usize;
        match value_reference {
            vr if vr < FIRST_OUTPUT_VR => Some(Self::Joint(index(0))),
            vr if vr < FIRST_TOOL_VR => Some(Self::Output(index(FIRST_OUTPUT_VR))),
            vr if vr < FIRST_VELOCITY_VR => Some(Self::Tool(index(FIRST_TOOL_VR))),
            vr if vr < FIRST_ACCELERATION_VR => Some(Self::Velocity(index(FIRST_VELOCITY_VR))),
            vr if vr < FIRST_TORQUE_VR => Some(Self::Acceleration(index(FIRST_ACCELERATION_VR))),
            vr if vr < FIRST_PAYLOAD_VR => Some(Self::Torque(index(FIRST_TORQUE_VR))),
            vr if vr < VARIABLE_COUNT => Some(Self::Payload(index(FIRST_PAYLOAD_VR))),
            _ => None,
        }
    }

    /// Its value reference.
    #[must_use]
    pub fn value_reference(self) -> u32 {
        match self {
            Self::Joint(index) => index as u32,
            Self::Output(index) => FIRST_OUTPUT_VR + index as u32,
            Self::Tool(index) => FIRST_TOOL_VR + index as u32,
            Self::Velocity(index) => FIRST_VELOCITY_VR + index as u32,
            Self::Acceleration(index) => FIRST_ACCELERATION_VR + index as u32,
            Self::Torque(index) => FIRST_TORQUE_VR + index as u32,
            Self::Payload(index) => FIRST_PAYLOAD_VR + index as u32,
        }
    }

    /// Its FMI causality: `input`, `output` or `parameter`.
    #[must_use]
    pub fn causality(self) -> &'static str {
        match self {
            Self::Joint(_) | Self::Velocity(_) | Self::Acceleration(_) => "input",
            Self::Output(_) | Self::Torque(_) => "output",
            Self::Tool(_) | Self::Payload(_) => "parameter",
        }
    }
}

/// Unit of a variable, as declared in the model description's `UnitDefinitions`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unit {
    /// Metre.
    Metre,
    /// Radian.
    Radian,
    /// Radian per second.
    RadianPerSecond,
    /// Radian per second squared.
    RadianPerSecondSquared,
    /// Newton metre.
    NewtonMetre,
    /// Kilogram.
    Kilogram,
}

impl Unit {
    /// Every unit, in the model description's order.
    pub const ALL: [Self; 6] = [
        Self::Metre,
        Self::Radian,
        Self::RadianPerSecond,
        Self::RadianPerSecondSquared,
        Self::NewtonMetre,
        Self::Kilogram,
    ];

    /// The unit's name in the model description.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Metre => "m",
            Self::Radian => "rad",
            Self::RadianPerSecond => "rad/s",
            Self::RadianPerSecondSquared => "rad/s2",
            Self::NewtonMetre => "N.m",
            Self::Kilogram => "kg",
        }
    }

    /// Its SI base units with their exponents, as `<BaseUnit>` attributes.
    #[must_use]
    pub fn base_units(self) -> &'static [(&'static str, i32)] {
        match self {
            Self::Metre => &[("m", 1)],
            Self::Radian => &[("rad", 1)],
            Self::RadianPerSecond => &[("s", -1), ("rad", 1)],
            Self::RadianPerSecondSquared => &[("s", -2), ("rad", 1)],
            Self::NewtonMetre => &[("kg", 1), ("m", 2), ("s", -2)],
            Self::Kilogram => &[("kg", 1)],
        }
    }
}

/// One scalar variable of the FMU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScalarVariable {
    /// Its name (the `UR10e` FMU report's names for inputs and outputs).
    pub name: &'static str,
    /// What it addresses (and so its value reference and causality).
    pub variable: Variable,
    /// Its unit; `None` for the dimensionless quaternion.
    pub unit: Option<Unit>,
    /// One line for the model description.
    pub description: &'static str,
}

const fn scalar(
    name: &'static str,
    variable: Variable,
    unit: Option<Unit>,
    description: &'static str,
) -> ScalarVariable {
    ScalarVariable {
        name,
        variable,
        unit,
        description,
    }
}

const M: Option<Unit> = Some(Unit::Metre);
const RAD: Option<Unit> = Some(Unit::Radian);
const RAD_S: Option<Unit> = Some(Unit::RadianPerSecond);
const RAD_S2: Option<Unit> = Some(Unit::RadianPerSecondSquared);
const NM: Option<Unit> = Some(Unit::NewtonMetre);
const KG: Option<Unit> = Some(Unit::Kilogram);

/// Every variable, ordered by value reference (so a variable's 1-based index in the model
/// description's `ModelVariables` is its value reference plus one).
pub const VARIABLES: [ScalarVariable; VARIABLE_COUNT as usize] = {
    use Variable::{Acceleration, Joint, Output, Payload, Tool, Torque, Velocity};
    [
        scalar("q1", Joint(0), RAD, "Joint 1 (shoulder pan) angle"),
        scalar("q2", Joint(1), RAD, "Joint 2 (shoulder lift) angle"),
        scalar("q3", Joint(2), RAD, "Joint 3 (elbow) angle"),
        scalar("q4", Joint(3), RAD, "Joint 4 (wrist 1) angle"),
        scalar("q5", Joint(4), RAD, "Joint 5 (wrist 2) angle"),
        scalar("q6", Joint(5), RAD, "Joint 6 (wrist 3) angle"),
        scalar("x", Output(0), M, "TCP position x in the output frame"),
        scalar("y", Output(1), M, "TCP position y in the output frame"),
        scalar("z", Output(2), M, "TCP position z in the output frame"),
        scalar(
            "roll",
            Output(3),
            RAD,
            "TCP roll, R = Rz(yaw) Ry(pitch) Rx(roll), in (-pi, pi]",
        ),
        scalar(
            "pitch",
            Output(4),
            RAD,
            "TCP pitch, R = Rz(yaw) Ry(pitch) Rx(roll), in [-pi/2, pi/2]",
        ),
        scalar(
            "yaw",
            Output(5),
            RAD,
            "TCP yaw, R = Rz(yaw) Ry(pitch) Rx(roll), in (-pi, pi]",
        ),
        scalar("qx", Output(6), None, "TCP orientation, unit quaternion x"),
        scalar("qy", Output(7), None, "TCP orientation, unit quaternion y"),
        scalar("qz", Output(8), None, "TCP orientation, unit quaternion z"),
        scalar(
            "qw",
            Output(9),
            None,
            "TCP orientation, unit quaternion w (>= 0)",
        ),
        scalar(
            "tcp_x",
            Tool(0),
            M,
            "Tool (TCP) offset x in the flange frame",
        ),
        scalar(
            "tcp_y",
            Tool(1),
            M,
            "Tool (TCP) offset y in the flange frame",
        ),
        scalar(
            "tcp_z",
            Tool(2),
            M,
            "Tool (TCP) offset z in the flange frame",
        ),
        scalar(
            "tcp_rx",
            Tool(3),
            RAD,
            "Tool (TCP) orientation in the flange frame, rotation vector x",
        ),
        scalar(
            "tcp_ry",
            Tool(4),
            RAD,
            "Tool (TCP) orientation in the flange frame, rotation vector y",
        ),
        scalar(
            "tcp_rz",
            Tool(5),
            RAD,
            "Tool (TCP) orientation in the flange frame, rotation vector z",
        ),
        scalar("qd1", Velocity(0), RAD_S, "Joint 1 velocity"),
        scalar("qd2", Velocity(1), RAD_S, "Joint 2 velocity"),
        scalar("qd3", Velocity(2), RAD_S, "Joint 3 velocity"),
        scalar("qd4", Velocity(3), RAD_S, "Joint 4 velocity"),
        scalar("qd5", Velocity(4), RAD_S, "Joint 5 velocity"),
        scalar("qd6", Velocity(5), RAD_S, "Joint 6 velocity"),
        scalar("qdd1", Acceleration(0), RAD_S2, "Joint 1 acceleration"),
        scalar("qdd2", Acceleration(1), RAD_S2, "Joint 2 acceleration"),
        scalar("qdd3", Acceleration(2), RAD_S2, "Joint 3 acceleration"),
        scalar("qdd4", Acceleration(3), RAD_S2, "Joint 4 acceleration"),
        scalar("qdd5", Acceleration(4), RAD_S2, "Joint 5 acceleration"),
        scalar("qdd6", Acceleration(5), RAD_S2, "Joint 6 acceleration"),
        scalar("tau1", Torque(0), NM, TORQUE_DESCRIPTION),
        scalar("tau2", Torque(1), NM, TORQUE_DESCRIPTION),
        scalar("tau3", Torque(2), NM, TORQUE_DESCRIPTION),
        scalar("tau4", Torque(3), NM, TORQUE_DESCRIPTION),
        scalar("tau5", Torque(4), NM, TORQUE_DESCRIPTION),
        scalar("tau6", Torque(5), NM, TORQUE_DESCRIPTION),
        scalar("payload_mass", Payload(0), KG, "Payload mass"),
        scalar(
            "payload_cog_x",
            Payload(1),
            M,
            "Payload centre of gravity x in the flange frame",
        ),
        scalar(
            "payload_cog_y",
            Payload(2),
            M,
            "Payload centre of gravity y in the flange frame",
        ),
        scalar(
            "payload_cog_z",
            Payload(3),
            M,
            "Payload centre of gravity z in the flange frame",
        ),
    ]
};

/// What every torque output is.
const TORQUE_DESCRIPTION: &str = "Joint torque of the inverse dynamics (rigid body, payload, \
     reflected rotor inertia; gravity 9.82 m/s2 along the base's -z; no friction), as the UR \
     controller's target_moment in a program";

/// The FMU's log categories (`LogCategories` in the model description, `fmi2SetDebugLogging`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogCategory {
    /// A call failed (`fmi2Error`, `fmi2Fatal`); always logged.
    StatusError,
    /// A call was discarded (`fmi2Discard`); always logged.
    StatusDiscard,
    /// Lifecycle and step calls; logged with debug logging on.
    Calls,
}

impl LogCategory {
    /// Every category, in model-description order.
    pub const ALL: [Self; 3] = [Self::StatusError, Self::StatusDiscard, Self::Calls];

    /// The category's name in the model description and in log messages.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::StatusError => "logStatusError",
            Self::StatusDiscard => "logStatusDiscard",
            Self::Calls => "logCalls",
        }
    }

    /// One line for the model description.
    #[must_use]
    pub fn description(self) -> &'static str {
        match self {
            Self::StatusError => "Calls that returned fmi2Error or fmi2Fatal (always logged)",
            Self::StatusDiscard => "Calls that returned fmi2Discard (always logged)",
            Self::Calls => "Lifecycle and step calls (with debug logging on)",
        }
    }

    /// The category called `name`.
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|category| category.name() == name)
    }
}

/// Why the robot description of an FMU is unusable.
#[derive(Debug, Error)]
pub enum FmuSettingsError {
    /// The file is not valid TOML or lacks a field.
    #[error("{RESOURCE_FILE}: {message}")]
    Syntax {
        /// The TOML parser's message.
        message: String,
    },
    /// `frame` is not a known frame.
    #[error("{RESOURCE_FILE}: frame: '{frame}' is not base or base_link")]
    Frame {
        /// The value found.
        frame: String,
    },
    /// A `tcp` value is not finite.
    #[error("{RESOURCE_FILE}: tcp: every value must be finite")]
    Tool,
    /// `calibration` is not a plain file name inside `resources/`.
    #[error("{RESOURCE_FILE}: calibration: '{name}' is not a plain file name")]
    CalibrationName {
        /// The value found.
        name: String,
    },
    /// The calibration's text was given where none is configured, or is missing.
    #[error(
        "{RESOURCE_FILE}: calibration: the text of the calibration must be given exactly when one is configured"
    )]
    CalibrationText,
    /// The FMU's interface has six joints; this arm has another count.
    #[error("model '{model}' has {joints} joints; the FMU's interface has {JOINT_COUNT} (q1..q6)")]
    JointCount {
        /// The model.
        model: String,
        /// Its joint count.
        joints: usize,
    },
    /// Only catalog models are packaged.
    #[error("model '{model}': the FMU supports catalog models only, not custom arm or URDF files")]
    CustomArm {
        /// The model value.
        model: String,
    },
    /// The model or its calibration is invalid.
    #[error(transparent)]
    Model(#[from] ModelError),
}

/// The robot an FMU computes: the content of its `resources/armtwin-fmu.toml`.
#[derive(Debug, Clone, PartialEq)]
pub struct FmuSettings {
    /// The FMU's GUID, as in its model description (checked against `fmuGUID`).
    pub guid: String,
    /// Catalog model name (`ur10e`).
    pub model: String,
    /// File name of the calibration inside `resources/`, if the robot has one.
    pub calibration_file: Option<String>,
    /// Frame of the output pose.
    pub frame: OutputFrame,
    /// Tool offset the FMU starts with (the `tcp_*` parameters' start values).
    pub tool: TcpOffset,
}

/// The file's form on disk.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SettingsFile {
    guid: String,
    model: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    calibration: Option<String>,
    frame: String,
    tcp: [f64; 6],
}

impl FmuSettings {
    /// Parses and checks the resource file's text (the calibration's file name included; its
    /// content is checked by [`Self::robot_model`]).
    pub fn from_toml(text: &str) -> Result<Self, FmuSettingsError> {
        let file: SettingsFile = toml::from_str(text).map_err(|e| FmuSettingsError::Syntax {
            message: e.message().to_owned(),
        })?;
        let frame = OutputFrame::from_name(&file.frame)
            .ok_or(FmuSettingsError::Frame { frame: file.frame })?;
        let tool = TcpOffset::from_ur_pose(file.tcp).ok_or(FmuSettingsError::Tool)?;
        if let Some(name) = &file.calibration
            && !is_plain_file_name(name)
        {
            return Err(FmuSettingsError::CalibrationName { name: name.clone() });
        }
        Ok(Self {
            guid: file.guid,
            model: file.model,
            calibration_file: file.calibration,
            frame,
            tool,
        })
    }

    /// The resource file's text, with a comment saying who writes and reads it.
    #[must_use]
    pub fn to_toml(&self) -> String {
        let file = SettingsFile {
            guid: self.guid.clone(),
            model: self.model.clone(),
            calibration: self.calibration_file.clone(),
            frame: self.frame.as_str().to_owned(),
            tcp: self.tool.to_ur_pose(),
        };
        let body = toml::to_string(&file).unwrap_or_else(|e| {
            unreachable!("strings, a finite float array and an optional string serialize: {e}")
        });
        let newline = if body.ends_with('\n') { "" } else { "\n" };
        format!(
            "# The robot this FMU computes: written by `armtwin fmu build`, read by the FMU at \
             fmi2Instantiate.\n{body}{newline}"
        )
    }

    /// The robot model these settings describe; `calibration_text` is the content of
    /// [`Self::calibration_file`] (and must be `None` when there is none).
    pub fn robot_model(
        &self,
        calibration_text: Option<&str>,
    ) -> Result<RobotModel, FmuSettingsError> {
        let arm = match ModelRef::parse(&self.model) {
            ModelRef::Catalog(name) => catalog::arm(name)?,
            ModelRef::CustomArm(_) | ModelRef::Urdf(_) => {
                return Err(FmuSettingsError::CustomArm {
                    model: self.model.clone(),
                });
            }
        };
        let calibration = match (&self.calibration_file, calibration_text) {
            (Some(name), Some(text)) => {
                Some(Calibration::parse(text, name).map_err(ModelError::from)?)
            }
            (None, None) => None,
            _ => return Err(FmuSettingsError::CalibrationText),
        };
        let model = RobotModel::new(arm, calibration, self.tool, self.frame)?;
        if model.joint_count() != JOINT_COUNT {
            return Err(FmuSettingsError::JointCount {
                model: self.model.clone(),
                joints: model.joint_count(),
            });
        }
        Ok(model)
    }
}

/// Whether `name` names a file directly inside a folder: no separators, not `.` or `..`.
fn is_plain_file_name(name: &str) -> bool {
    !name.is_empty()
        && name != "."
        && name != ".."
        && !name.contains(['/', '\\', '\0'])
        && name != RESOURCE_FILE
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variables_are_ordered_by_value_reference_and_round_trip() {
        for (index, scalar) in VARIABLES.iter().enumerate() {
            let vr = scalar.variable.value_reference();
            assert_eq!(vr as usize, index, "{}", scalar.name);
            assert_eq!(Variable::from_value_reference(vr), Some(scalar.variable));
        }
        assert_eq!(Variable::from_value_reference(VARIABLES.len() as u32), None);
        assert_eq!(Variable::from_value_reference(u32::MAX), None);
    }

    #[test]
    fn names_are_the_reports_and_the_codecs() {
        let names: Vec<_> = VARIABLES.iter().map(|v| v.name).collect();
        assert_eq!(names[..6], ["q1", "q2", "q3", "q4", "q5", "q6"]);
        assert_eq!(names[6..16], PoseFields::NAMES);
        assert_eq!(
            names[16..22],
            ["tcp_x", "tcp_y", "tcp_z", "tcp_rx", "tcp_ry", "tcp_rz"]
        );
        assert_eq!(names[22..28], ["qd1", "qd2", "qd3", "qd4", "qd5", "qd6"]);
        assert_eq!(
            names[34..40],
            ["tau1", "tau2", "tau3", "tau4", "tau5", "tau6"]
        );
        assert_eq!(
            names[40..],
            [
                "payload_mass",
                "payload_cog_x",
                "payload_cog_y",
                "payload_cog_z"
            ]
        );
    }

    fn settings() -> FmuSettings {
        FmuSettings {
            guid: "{6f1c0c52-0000-5000-8000-000000000001}".to_owned(),
            model: "ur10e".to_owned(),
            calibration_file: Some("calibration.conf".to_owned()),
            frame: OutputFrame::BaseLink,
            tool: TcpOffset::from_ur_pose([0.1, -0.2, 0.15, 0.3, -1e-17, 2.5]).expect("finite"),
        }
    }

    #[test]
    fn settings_round_trip_through_toml_exactly() {
        let settings = settings();
        let text = settings.to_toml();
        assert_eq!(FmuSettings::from_toml(&text).expect("valid"), settings);
        let without = FmuSettings {
            calibration_file: None,
            ..settings
        };
        assert_eq!(
            FmuSettings::from_toml(&without.to_toml()).expect("valid"),
            without
        );
    }

    #[test]
    fn bad_settings_name_the_field() {
        let text = settings().to_toml();
        let error = |text: &str| {
            FmuSettings::from_toml(text)
                .expect_err("invalid")
                .to_string()
        };
        assert_eq!(
            error(&text.replace("base_link", "world")),
            "armtwin-fmu.toml: frame: 'world' is not base or base_link"
        );
        assert_eq!(
            error(&text.replace("\"calibration.conf\"", "\"../etc/passwd\"")),
            "armtwin-fmu.toml: calibration: '../etc/passwd' is not a plain file name"
        );
        assert!(error(&text.replace("model =", "modell =")).contains("modell"));
        assert!(error("guid = 1").starts_with("armtwin-fmu.toml: "));
    }

    #[test]
    fn robot_model_checks_model_and_calibration() {
        let mut settings = settings();
        settings.calibration_file = None;
        let model = settings.robot_model(None).expect("catalog model");
        assert_eq!(model.arm().name, "ur10e");
        assert_eq!(model.frame(), OutputFrame::BaseLink);
        assert!(matches!(
            settings.robot_model(Some("[mounting]")),
            Err(FmuSettingsError::CalibrationText)
        ));
        settings.model = "ur11".to_owned();
        assert!(matches!(
            settings.robot_model(None),
            Err(FmuSettingsError::Model(ModelError::UnknownModel { .. }))
        ));
        settings.model = "arm.toml".to_owned();
        assert!(matches!(
            settings.robot_model(None),
            Err(FmuSettingsError::CustomArm { .. })
        ));
    }
}
