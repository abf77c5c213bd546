//! The output recipe: which variables a data package carries, in which order and with which
//! type, and one data package decoded into an [`RtdeSample`]. Must not know the handshake's
//! order or anything beyond one package.

use std::fmt;

use super::frame::PackageType;
use super::{ProtocolVersion, RtdeError};
use armtwin_core::sample::{ControllerStatus, JointQuantity, JointState, Payload};

/// An RTDE variable type, as the output setup answer names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VariableType {
    /// `f64`.
    Double,
    /// Six `f64`.
    Vector6D,
    /// Three `f64`.
    Vector3D,
    /// Six `i32`.
    Vector6Int32,
    /// Six `u32`.
    Vector6Uint32,
    /// `i32`.
    Int32,
    /// `u32`.
    Uint32,
    /// `u64`.
    Uint64,
    /// `u8`.
    Uint8,
    /// One byte, 0 or 1.
    Bool,
}

impl VariableType {
    /// The type's name in the output setup answer.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Double => "DOUBLE",
            Self::Vector6D => "VECTOR6D",
            Self::Vector3D => "VECTOR3D",
            Self::Vector6Int32 => "VECTOR6INT32",
            Self::Vector6Uint32 => "VECTOR6UINT32",
            Self::Int32 => "INT32",
            Self::Uint32 => "UINT32",
            Self::Uint64 => "UINT64",
            Self::Uint8 => "UINT8",
            Self::Bool => "BOOL",
        }
    }

    /// The type named `name`, if RTDE has one.
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "DOUBLE" => Self::Double,
            "VECTOR6D" => Self::Vector6D,
            "VECTOR3D" => Self::Vector3D,
            "VECTOR6INT32" => Self::Vector6Int32,
            "VECTOR6UINT32" => Self::Vector6Uint32,
            "INT32" => Self::Int32,
            "UINT32" => Self::Uint32,
            "UINT64" => Self::Uint64,
            "UINT8" => Self::Uint8,
            "BOOL" => Self::Bool,
            _ => return None,
        })
    }

    /// Bytes of one value in a data package.
    #[must_use]
    pub fn size_bytes(self) -> usize {
        match self {
            Self::Double | Self::Uint64 => 8,
            Self::Vector6D => 48,
            Self::Vector3D | Self::Vector6Int32 | Self::Vector6Uint32 => 24,
            Self::Int32 | Self::Uint32 => 4,
            Self::Uint8 | Self::Bool => 1,
        }
    }
}

impl fmt::Display for VariableType {
    fn fmt(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        formatter.write_str(self.as_str())
    }
}

/// The answer's word for a variable the controller does not have.
pub const NOT_FOUND: &str = "NOT_FOUND";

/// A variable the gateway requests: its RTDE name, type, and where it goes in an [`RtdeSample`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Variable {
    /// The RTDE name.
    pub name: &'static str,
    /// Its type in RTDE.
    pub kind: VariableType,
    /// The gateway cannot stream without it.
    pub required: bool,
    field: Field,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Field {
    Timestamp,
    ActualQ,
    ActualTcpPose,
    ActualQd,
    TargetQ,
    TargetQd,
    TargetQdd,
    ActualCurrent,
    TargetCurrent,
    TargetMoment,
    JointTemperatures,
    RobotMode,
    SafetyMode,
    RobotStatusBits,
    SpeedScaling,
    Payload,
    PayloadCog,
    TcpOffset,
}

const fn variable(name: &'static str, kind: VariableType, field: Field) -> Variable {
    Variable {
        name,
        kind,
        required: false,
        field,
    }
}

/// What the gateway requests, in order, with the types UR's RTDE guide gives them. `timestamp`
/// and `actual_q` are required; the others fill [`RtdeSample`]'s optional fields where the
/// controller has them (older firmware lacks some, e.g. `payload_cog` before 3.3 / 5.0).
pub const VARIABLES: [Variable; 18] = [
    Variable {
        required: true,
        ..variable("timestamp", VariableType::Double, Field::Timestamp)
    },
    Variable {
        required: true,
        ..variable("actual_q", VariableType::Vector6D, Field::ActualQ)
    },
    variable(
        "actual_TCP_pose",
        VariableType::Vector6D,
        Field::ActualTcpPose,
    ),
    variable("actual_qd", VariableType::Vector6D, Field::ActualQd),
    variable("target_q", VariableType::Vector6D, Field::TargetQ),
    variable("target_qd", VariableType::Vector6D, Field::TargetQd),
    variable("target_qdd", VariableType::Vector6D, Field::TargetQdd),
    variable(
        "actual_current",
        VariableType::Vector6D,
        Field::ActualCurrent,
    ),
    variable(
        "target_current",
        VariableType::Vector6D,
        Field::TargetCurrent,
    ),
    variable("target_moment", VariableType::Vector6D, Field::TargetMoment),
    variable(
        "joint_temperatures",
        VariableType::Vector6D,
        Field::JointTemperatures,
    ),
    variable("robot_mode", VariableType::Int32, Field::RobotMode),
    variable("safety_mode", VariableType::Int32, Field::SafetyMode),
    variable(
        "robot_status_bits",
        VariableType::Uint32,
        Field::RobotStatusBits,
    ),
    variable("speed_scaling", VariableType::Double, Field::SpeedScaling),
    variable("payload", VariableType::Double, Field::Payload),
    variable("payload_cog", VariableType::Vector3D, Field::PayloadCog),
    variable("tcp_offset", VariableType::Vector6D, Field::TcpOffset),
];

/// The variable named `name` among [`VARIABLES`].
#[must_use]
pub fn variable_named(name: &str) -> Option<&'static Variable> {
    VARIABLES.iter().find(|variable| variable.name == name)
}

/// One data package: what a UR controller reports each cycle. Units as RTDE gives them.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RtdeSample {
    /// Seconds since the controller started (its own clock).
    pub timestamp_s: f64,
    /// Joint positions (rad), base to wrist 3.
    pub actual_q_rad: [f64; 6],
    /// The TCP pose in the robot's `base` frame: `x, y, z` (m), then a rotation vector
    /// `rx, ry, rz` (axis · angle, rad).
    pub actual_tcp_pose: Option<[f64; 6]>,
    /// Joint velocities (rad/s).
    pub actual_qd_rad_s: Option<[f64; 6]>,
    /// Target joint positions (rad).
    pub target_q_rad: Option<[f64; 6]>,
    /// Target joint velocities (rad/s).
    pub target_qd_rad_s: Option<[f64; 6]>,
    /// Target joint accelerations (rad/s²).
    pub target_qdd_rad_s2: Option<[f64; 6]>,
    /// Joint currents (A).
    pub actual_current_a: Option<[f64; 6]>,
    /// Target joint currents (A).
    pub target_current_a: Option<[f64; 6]>,
    /// Target joint torques (Nm).
    pub target_moment_nm: Option<[f64; 6]>,
    /// Joint temperatures (°C).
    pub joint_temperatures_c: Option<[f64; 6]>,
    /// Robot mode (UR's `ROBOT_MODE_*`, -1 no controller … 7 running).
    pub robot_mode: Option<i32>,
    /// Safety mode (UR's `SAFETY_MODE_*`, 1 normal …).
    pub safety_mode: Option<i32>,
    /// Bits: 0 power on, 1 program running, 2 teach button, 3 power button.
    pub robot_status_bits: Option<u32>,
    /// Speed scaling of the trajectory limiter (0..1).
    pub speed_scaling: Option<f64>,
    /// The configured payload mass (kg).
    pub payload_kg: Option<f64>,
    /// The payload's centre of gravity (m, tool flange frame).
    pub payload_cog_m: Option<[f64; 3]>,
    /// The TCP the controller's `actual_TCP_pose` is of: `x, y, z` (m) and a rotation vector
    /// (rad) in the tool flange frame, as the robot's installation or `set_tcp` sets it.
    pub tcp_offset: Option<[f64; 6]>,
}

impl RtdeSample {
    /// What of the package the joint message carries beside the angles
    /// (`armtwin/joints/v2`): velocities, the target state, currents, the controller's model
    /// torques, temperatures, modes and the configured payload, each when the recipe has it.
    #[must_use]
    pub fn joint_state(&self) -> JointState {
        let mut state = JointState::new(self.actual_q_rad.len());
        let quantities = [
            (JointQuantity::Velocity, &self.actual_qd_rad_s),
            (JointQuantity::TargetPosition, &self.target_q_rad),
            (JointQuantity::TargetVelocity, &self.target_qd_rad_s),
            (JointQuantity::TargetAcceleration, &self.target_qdd_rad_s2),
            (JointQuantity::Current, &self.actual_current_a),
            (JointQuantity::TargetCurrent, &self.target_current_a),
            (JointQuantity::TargetTorque, &self.target_moment_nm),
            (JointQuantity::Temperature, &self.joint_temperatures_c),
        ];
        for (quantity, values) in quantities {
            // A controller's non-finite value would refuse the whole state downstream: left out.
            if let Some(values) = values.filter(|values| values.iter().all(|v| v.is_finite())) {
                state.set(quantity, &values);
            }
        }
        if let (Some(robot_mode), Some(safety_mode), Some(status_bits), Some(speed_scaling)) = (
            self.robot_mode,
            self.safety_mode,
            self.robot_status_bits,
            self.speed_scaling.filter(|value| value.is_finite()),
        ) {
            state.status = Some(ControllerStatus {
                robot_mode,
                safety_mode,
                status_bits,
                speed_scaling,
            });
        }
        if let (Some(mass_kg), Some(cog_m)) = (self.payload_kg, self.payload_cog_m)
            && mass_kg.is_finite()
            && mass_kg >= 0.0
            && cog_m.iter().all(|value| value.is_finite())
        {
            state.payload = Some(Payload {
                mass_kg,
                cog_m,
                inertia_kg_m2: None,
            });
        }
        state
    }
}

/// The output recipe the controller agreed to: an id (protocol 2) and the variables of each data
/// package in order, every one known and typed as RTDE defines it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Recipe {
    /// The recipe id data packages carry (protocol 2); `None` under protocol 1.
    pub id: Option<u8>,
    /// The variables, in package order.
    pub variables: Vec<&'static Variable>,
    /// Bytes of a data package's payload, the id byte included.
    pub payload_bytes: usize,
}

/// The controller's answer to an output setup: the recipe of the variables it knows, and the
/// names of those it answered [`NOT_FOUND`] for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SetupAnswer {
    /// The recipe of the known variables (its id is only valid if `not_found` is empty).
    pub recipe: Recipe,
    /// Variables the controller does not have.
    pub not_found: Vec<&'static str>,
}

impl SetupAnswer {
    /// Reads the answer to a setup of `requested`: (protocol 2: a recipe id byte, then) the
    /// comma-separated types, one per requested variable.
    pub fn parse(
        payload: &[u8],
        requested: &[&'static Variable],
        version: ProtocolVersion,
    ) -> Result<Self, RtdeError> {
        let package = PackageType::SetupOutputs;
        let (id, types) = match version {
            ProtocolVersion::V2 => {
                let Some((&id, types)) = payload.split_first() else {
                    return Err(RtdeError::Truncated {
                        package,
                        field: "recipe id",
                    });
                };
                (Some(id), types)
            }
            ProtocolVersion::V1 => (None, payload),
        };
        let types = std::str::from_utf8(types).map_err(|_| RtdeError::NotUtf8 {
            package,
            field: "variable types",
        })?;
        let answered = types.split(',').count();
        if answered != requested.len() {
            return Err(RtdeError::VariableCount {
                requested: requested.len(),
                answered,
            });
        }
        let mut variables = Vec::with_capacity(requested.len());
        let mut not_found = Vec::new();
        for (name, variable) in types.split(',').zip(requested) {
            if name == NOT_FOUND {
                not_found.push(variable.name);
                continue;
            }
            if name == "IN_USE" {
                return Err(RtdeError::SetupRefused {
                    reason: format!("'{}' is in use", variable.name),
                });
            }
            let Some(kind) = VariableType::from_name(name) else {
                return Err(RtdeError::UnknownType {
                    variable: variable.name.to_owned(),
                    name: name.chars().take(32).collect(),
                });
            };
            if kind != variable.kind {
                return Err(RtdeError::TypeMismatch {
                    variable: variable.name,
                    expected: variable.kind,
                    got: kind,
                });
            }
            variables.push(*variable);
        }
        if id == Some(0) && not_found.is_empty() {
            return Err(RtdeError::SetupRefused {
                reason: "recipe id 0".to_owned(),
            });
        }
        let payload_bytes = usize::from(id.is_some())
            + variables
                .iter()
                .map(|variable| variable.kind.size_bytes())
                .sum::<usize>();
        Ok(Self {
            recipe: Recipe {
                id,
                variables,
                payload_bytes,
            },
            not_found,
        })
    }
}

/// Reads big-endian values off a slice whose length was checked against the recipe.
struct Values<'a> {
    bytes: &'a [u8],
}

impl Values<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0; N];
        if let Some((head, rest)) = self.bytes.split_first_chunk::<N>() {
            out = *head;
            self.bytes = rest;
        }
        out
    }

    fn f64(&mut self) -> f64 {
        f64::from_be_bytes(self.take())
    }

    fn f64s<const N: usize>(&mut self) -> [f64; N] {
        std::array::from_fn(|_| self.f64())
    }
}

impl Recipe {
    /// Decodes a data package's payload: the recipe id (protocol 2) and every variable's value,
    /// the size checked against the recipe first.
    pub fn decode(&self, payload: &[u8]) -> Result<RtdeSample, RtdeError> {
        if payload.len() != self.payload_bytes {
            return Err(RtdeError::PayloadSize {
                package: PackageType::DataPackage,
                expected: self.payload_bytes,
                got: payload.len(),
            });
        }
        let mut values = Values { bytes: payload };
        if let Some(expected) = self.id {
            let [got] = values.take();
            if got != expected {
                return Err(RtdeError::RecipeId { expected, got });
            }
        }
        let mut sample = RtdeSample::default();
        for variable in &self.variables {
            match variable.field {
                Field::Timestamp => sample.timestamp_s = values.f64(),
                Field::ActualQ => sample.actual_q_rad = values.f64s(),
                Field::ActualTcpPose => sample.actual_tcp_pose = Some(values.f64s()),
                Field::ActualQd => sample.actual_qd_rad_s = Some(values.f64s()),
                Field::TargetQ => sample.target_q_rad = Some(values.f64s()),
                Field::TargetQd => sample.target_qd_rad_s = Some(values.f64s()),
                Field::TargetQdd => sample.target_qdd_rad_s2 = Some(values.f64s()),
                Field::ActualCurrent => sample.actual_current_a = Some(values.f64s()),
                Field::TargetCurrent => sample.target_current_a = Some(values.f64s()),
                Field::TargetMoment => sample.target_moment_nm = Some(values.f64s()),
                Field::JointTemperatures => sample.joint_temperatures_c = Some(values.f64s()),
                Field::RobotMode => sample.robot_mode = Some(i32::from_be_bytes(values.take())),
                Field::SafetyMode => sample.safety_mode = Some(i32::from_be_bytes(values.take())),
                Field::RobotStatusBits => {
                    sample.robot_status_bits = Some(u32::from_be_bytes(values.take()));
                }
                Field::SpeedScaling => sample.speed_scaling = Some(values.f64()),
                Field::Payload => sample.payload_kg = Some(values.f64()),
                Field::PayloadCog => sample.payload_cog_m = Some(values.f64s()),
                Field::TcpOffset => sample.tcp_offset = Some(values.f64s()),
            }
        }
        Ok(sample)
    }

    /// Whether the recipe carries `name`.
    #[must_use]
    pub fn has(&self, name: &str) -> bool {
        self.variables.iter().any(|variable| variable.name == name)
    }
}

/// The bytes of a data package's payload for `sample` under `recipe`: what a controller sends,
/// for tests and fuzzing's round trips. Absent optional values are sent as zeros.
#[must_use]
pub fn encode(recipe: &Recipe, sample: &RtdeSample) -> Vec<u8> {
    fn doubles(bytes: &mut Vec<u8>, values: &[f64]) {
        for value in values {
            bytes.extend_from_slice(&value.to_be_bytes());
        }
    }
    let mut bytes = Vec::with_capacity(recipe.payload_bytes);
    if let Some(id) = recipe.id {
        bytes.push(id);
    }
    let six = |values: Option<[f64; 6]>| values.unwrap_or_default();
    for variable in &recipe.variables {
        let out = &mut bytes;
        match variable.field {
            Field::Timestamp => doubles(out, &[sample.timestamp_s]),
            Field::ActualQ => doubles(out, &sample.actual_q_rad),
            Field::ActualTcpPose => doubles(out, &six(sample.actual_tcp_pose)),
            Field::ActualQd => doubles(out, &six(sample.actual_qd_rad_s)),
            Field::TargetQ => doubles(out, &six(sample.target_q_rad)),
            Field::TargetQd => doubles(out, &six(sample.target_qd_rad_s)),
            Field::TargetQdd => doubles(out, &six(sample.target_qdd_rad_s2)),
            Field::ActualCurrent => doubles(out, &six(sample.actual_current_a)),
            Field::TargetCurrent => doubles(out, &six(sample.target_current_a)),
            Field::TargetMoment => doubles(out, &six(sample.target_moment_nm)),
            Field::JointTemperatures => doubles(out, &six(sample.joint_temperatures_c)),
            Field::SpeedScaling => doubles(out, &[sample.speed_scaling.unwrap_or_default()]),
            Field::Payload => doubles(out, &[sample.payload_kg.unwrap_or_default()]),
            Field::PayloadCog => doubles(out, &sample.payload_cog_m.unwrap_or_default()),
            Field::TcpOffset => doubles(out, &six(sample.tcp_offset)),
            Field::RobotMode => {
                out.extend_from_slice(&sample.robot_mode.unwrap_or_default().to_be_bytes());
            }
            Field::SafetyMode => {
                out.extend_from_slice(&sample.safety_mode.unwrap_or_default().to_be_bytes());
            }
            Field::RobotStatusBits => {
                out.extend_from_slice(&sample.robot_status_bits.unwrap_or_default().to_be_bytes());
            }
        }
    }
    bytes
}

/// One value of a data package, as a recording writes it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Cell {
    Double(f64),
    Integer(i64),
}

impl Variable {
    /// How many values the variable has (6 for `VECTOR6D`, …).
    #[must_use]
    pub fn width(&self) -> usize {
        match self.kind {
            VariableType::Vector6D | VariableType::Vector6Int32 | VariableType::Vector6Uint32 => 6,
            VariableType::Vector3D => 3,
            _ => 1,
        }
    }

    /// The variable's values in `sample`, in order (zeros where the sample has none).
    pub(super) fn cells(&self, sample: &RtdeSample, mut cell: impl FnMut(Cell)) {
        let mut doubles = |values: &[f64]| values.iter().for_each(|v| cell(Cell::Double(*v)));
        let six = |values: Option<[f64; 6]>| values.unwrap_or_default();
        match self.field {
            Field::Timestamp => doubles(&[sample.timestamp_s]),
            Field::ActualQ => doubles(&sample.actual_q_rad),
            Field::ActualTcpPose => doubles(&six(sample.actual_tcp_pose)),
            Field::ActualQd => doubles(&six(sample.actual_qd_rad_s)),
            Field::TargetQ => doubles(&six(sample.target_q_rad)),
            Field::TargetQd => doubles(&six(sample.target_qd_rad_s)),
            Field::TargetQdd => doubles(&six(sample.target_qdd_rad_s2)),
            Field::ActualCurrent => doubles(&six(sample.actual_current_a)),
            Field::TargetCurrent => doubles(&six(sample.target_current_a)),
            Field::TargetMoment => doubles(&six(sample.target_moment_nm)),
            Field::JointTemperatures => doubles(&six(sample.joint_temperatures_c)),
            Field::SpeedScaling => doubles(&[sample.speed_scaling.unwrap_or_default()]),
            Field::Payload => doubles(&[sample.payload_kg.unwrap_or_default()]),
            Field::PayloadCog => doubles(&sample.payload_cog_m.unwrap_or_default()),
            Field::TcpOffset => doubles(&six(sample.tcp_offset)),
            Field::RobotMode => cell(Cell::Integer(sample.robot_mode.unwrap_or_default().into())),
            Field::SafetyMode => {
                cell(Cell::Integer(sample.safety_mode.unwrap_or_default().into()));
            }
            Field::RobotStatusBits => cell(Cell::Integer(
                sample.robot_status_bits.unwrap_or_default().into(),
            )),
        }
    }
}
