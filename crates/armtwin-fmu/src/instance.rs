//! One FMU instance as a state machine in safe Rust: the FMI 2.0 co-simulation states, the
//! variables' values, and the pose outputs, which are kept equal to the core's forward kinematics
//! of the current inputs and tool at every moment (so a get before the first `fmi2DoStep`, or
//! right after initialization, is already right).
//!
//! Knows nothing of C: the FFI module converts pointers and delegates here, then logs what comes
//! back. Every failed call moves the instance to the error state, as FMI 2.0 prescribes for
//! `fmi2Error`; only getters, `fmi2SetDebugLogging`, `fmi2Reset` and `fmi2FreeInstance` are allowed
//! there.

use std::fmt;

use armtwin_core::dynamics::{ArmDynamics, Payload};
use armtwin_core::fmi::{
    FmuSettingsError, JOINT_COUNT, LogCategory, OUTPUT_COUNT, PAYLOAD_COUNT, TOOL_COUNT, VARIABLES,
    Variable,
};
use armtwin_core::kinematics::{KinematicsError, TcpOffset};
use armtwin_core::model::RobotModel;
use armtwin_core::pose_fields::PoseFields;
use thiserror::Error;

use crate::resources::{self, ResourceError, Robot};

/// `fmi2Type` of a co-simulation instance.
pub const CO_SIMULATION: i32 = 1;

/// The FMI 2.0 co-simulation states this FMU can be in (`fmi2DoStep` completes synchronously, so
/// there is no step in progress, failed or cancelled).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// After `fmi2Instantiate` or `fmi2Reset`.
    Instantiated,
    /// Between `fmi2EnterInitializationMode` and `fmi2ExitInitializationMode`.
    InitializationMode,
    /// Ready for `fmi2DoStep`.
    StepComplete,
    /// After `fmi2Terminate`.
    Terminated,
    /// After a call returned `fmi2Error`.
    Error,
}

impl fmt::Display for State {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Instantiated => "instantiated",
            Self::InitializationMode => "initialization mode",
            Self::StepComplete => "step complete",
            Self::Terminated => "terminated",
            Self::Error => "error (an earlier call failed: call fmi2Reset or fmi2FreeInstance)",
        })
    }
}

/// Where getters are allowed.
const GETTABLE: &[State] = &[
    State::InitializationMode,
    State::StepComplete,
    State::Terminated,
    State::Error,
];
/// Where setters are allowed (inputs have start values; the tool parameters are tunable).
const SETTABLE: &[State] = &[
    State::Instantiated,
    State::InitializationMode,
    State::StepComplete,
];
/// Where `fmi2Get*Status` is allowed.
const STATUS: &[State] = &[State::StepComplete, State::Terminated];
/// Everywhere an instance can be.
const ANY: &[State] = &[
    State::Instantiated,
    State::InitializationMode,
    State::StepComplete,
    State::Terminated,
    State::Error,
];

/// Why a call on an instance failed (it returns `fmi2Error`).
#[derive(Debug, Error)]
pub enum CallError {
    /// The call is not allowed in the instance's state.
    #[error("{function}: not allowed in state {state}")]
    State {
        /// The FMI function.
        function: &'static str,
        /// The state the instance was in.
        state: State,
    },
    /// No variable of this type has the value reference.
    #[error("{function}: no {type_name} variable has value reference {value_reference}")]
    UnknownValueReference {
        /// The FMI function.
        function: &'static str,
        /// `Real`, `Integer`, `Boolean` or `String`.
        type_name: &'static str,
        /// The value reference asked for.
        value_reference: u32,
    },
    /// An output was written.
    #[error(
        "{function}: '{name}' (value reference {value_reference}) is an output and cannot be set"
    )]
    Output {
        /// The FMI function.
        function: &'static str,
        /// The output's name.
        name: &'static str,
        /// Its value reference.
        value_reference: u32,
    },
    /// A joint angle is not finite or outside its limits.
    #[error("{function}: {source}")]
    Joint {
        /// The FMI function.
        function: &'static str,
        /// What is wrong with which joint.
        source: KinematicsError,
    },
    /// A tool parameter, joint velocity or acceleration is not finite, or a payload parameter
    /// is out of range.
    #[error("{function}: '{name}' = {value} is not a finite number")]
    Tool {
        /// The FMI function.
        function: &'static str,
        /// The parameter's name.
        name: &'static str,
        /// The value given.
        value: f64,
    },
    /// The payload mass is negative.
    #[error("{function}: 'payload_mass' = {value} is negative")]
    PayloadMass {
        /// The FMI function.
        function: &'static str,
        /// The value given.
        value: f64,
    },
    /// A pointer argument is null.
    #[error("{function}: argument '{argument}' is a null pointer")]
    NullPointer {
        /// The FMI function.
        function: &'static str,
        /// The argument's name.
        argument: &'static str,
    },
    /// A string argument is not valid UTF-8.
    #[error("{function}: argument '{argument}' is not valid UTF-8")]
    Encoding {
        /// The FMI function.
        function: &'static str,
        /// The argument's name.
        argument: &'static str,
    },
    /// The function is declared unsupported in the model description.
    #[error("{function} is not supported by this FMU ({reason})")]
    Unsupported {
        /// The FMI function.
        function: &'static str,
        /// The capability flag or reason.
        reason: &'static str,
    },
    /// A time argument is not a finite number.
    #[error("{function}: {argument} = {value} is not a finite number")]
    Time {
        /// The FMI function.
        function: &'static str,
        /// The argument's name.
        argument: &'static str,
        /// The value given.
        value: f64,
    },
    /// `fmi2DoStep` was called at another time than where the last step ended.
    #[error(
        "fmi2DoStep: currentCommunicationPoint {given} is not the FMU's time {expected} (where the last step ended)"
    )]
    CommunicationPoint {
        /// The FMU's time.
        expected: f64,
        /// The master's.
        given: f64,
    },
    /// `fmi2DoStep` was called with a step size that is not positive.
    #[error("fmi2DoStep: communicationStepSize {value} must be a positive finite number")]
    StepSize {
        /// The value given.
        value: f64,
    },
    /// A bug in this FMU: a panic, caught at the boundary (the call returns `fmi2Fatal`).
    #[error("{function}: internal error: {message}")]
    Internal {
        /// The FMI function.
        function: &'static str,
        /// The panic's message.
        message: String,
    },
    /// `fmi2SetDebugLogging` named an unknown category.
    #[error("fmi2SetDebugLogging: unknown log category '{name}' (known: {known})")]
    LogCategory {
        /// The name given.
        name: String,
        /// The known names.
        known: String,
    },
    /// The robot model could not be rebuilt with a new tool.
    #[error("{function}: {source}")]
    Model {
        /// The FMI function.
        function: &'static str,
        /// Why.
        source: FmuSettingsError,
    },
}

/// Why `fmi2Instantiate` fails (it returns a null instance).
#[derive(Debug, Error)]
pub enum InstantiateError {
    /// A required argument is null.
    #[error("fmi2Instantiate: argument '{argument}' is a null pointer")]
    NullPointer {
        /// The argument's name.
        argument: &'static str,
    },
    /// A string argument is not valid UTF-8.
    #[error("fmi2Instantiate: argument '{argument}' is not valid UTF-8")]
    Encoding {
        /// The argument's name.
        argument: &'static str,
    },
    /// The instance name is empty.
    #[error("fmi2Instantiate: instanceName is empty")]
    EmptyName,
    /// Model exchange (or an unknown type) was asked for.
    #[error(
        "fmi2Instantiate: fmuType {fmu_type} is not supported; this FMU is co-simulation only (fmi2CoSimulation = 1)"
    )]
    FmuType {
        /// The type given.
        fmu_type: i32,
    },
    /// The GUID differs from the resources'.
    #[error(
        "fmi2Instantiate: fmuGUID {given} does not match this FMU's {expected} (modelDescription.xml and resources/armtwin-fmu.toml come from different builds)"
    )]
    Guid {
        /// The GUID the master passed.
        given: String,
        /// The GUID in the resources.
        expected: String,
    },
    /// The resources are unusable.
    #[error("fmi2Instantiate: {0}")]
    Resources(#[from] ResourceError),
}

/// Which log messages reach the master.
#[derive(Debug, Clone, PartialEq)]
struct LogFilter {
    debug: bool,
    /// `None`: every category.
    categories: Option<Vec<LogCategory>>,
}

impl LogFilter {
    fn logs(&self, category: LogCategory) -> bool {
        match category {
            LogCategory::StatusError | LogCategory::StatusDiscard => true,
            LogCategory::Calls => {
                self.debug
                    && self
                        .categories
                        .as_ref()
                        .is_none_or(|categories| categories.contains(&category))
            }
        }
    }
}

/// One FMU instance.
#[derive(Debug, Clone)]
pub struct Instance {
    name: String,
    robot: Robot,
    initial_logging: LogFilter,
    logging: LogFilter,
    state: State,
    time_s: f64,
    q_rad: [f64; JOINT_COUNT],
    tool: [f64; TOOL_COUNT],
    /// The model with the current tool.
    model: RobotModel,
    /// `PoseFields` values of the current inputs and tool.
    outputs: [f64; OUTPUT_COUNT],
    qd_rad_s: [f64; JOINT_COUNT],
    qdd_rad_s2: [f64; JOINT_COUNT],
    /// `[mass, cog x, cog y, cog z]`.
    payload: [f64; PAYLOAD_COUNT],
    /// The arm's dynamics with the current payload; `None` for an arm without inertial
    /// parameters (its torques are NaN).
    dynamics: Option<ArmDynamics<JOINT_COUNT>>,
    /// Joint torques of the current inputs.
    torques_nm: [f64; JOINT_COUNT],
}

/// Does what `fmi2Instantiate` does once its pointers are read: checks type and GUID, loads the
/// robot from the resource folder the URI names.
pub fn instantiate(
    name: &str,
    fmu_type: i32,
    guid: &str,
    resource_uri: &str,
    logging_on: bool,
) -> Result<Instance, InstantiateError> {
    if name.is_empty() {
        return Err(InstantiateError::EmptyName);
    }
    if fmu_type != CO_SIMULATION {
        return Err(InstantiateError::FmuType { fmu_type });
    }
    let robot = resources::load(&resources::folder_from_uri(resource_uri)?)?;
    if robot.settings.guid != guid {
        return Err(InstantiateError::Guid {
            given: guid.to_owned(),
            expected: robot.settings.guid,
        });
    }
    Ok(Instance::new(name, robot, logging_on))
}

impl Instance {
    /// A fresh instance of `robot`: inputs at their start value 0, the settings' tool.
    #[must_use]
    pub fn new(name: &str, robot: Robot, logging_on: bool) -> Self {
        let logging = LogFilter {
            debug: logging_on,
            categories: None,
        };
        let model = robot.model.clone();
        let mut instance = Self {
            name: name.to_owned(),
            initial_logging: logging.clone(),
            logging,
            state: State::Instantiated,
            time_s: 0.0,
            q_rad: [0.0; JOINT_COUNT],
            tool: robot.settings.tool.to_ur_pose(),
            dynamics: ArmDynamics::from_arm(model.arm()).ok(),
            model,
            outputs: [0.0; OUTPUT_COUNT],
            qd_rad_s: [0.0; JOINT_COUNT],
            qdd_rad_s2: [0.0; JOINT_COUNT],
            payload: [0.0; PAYLOAD_COUNT],
            torques_nm: [0.0; JOINT_COUNT],
            robot,
        };
        // Zero is inside every joint's limits.
        instance.outputs =
            pose_outputs(&instance.model, &instance.q_rad).unwrap_or([f64::NAN; OUTPUT_COUNT]);
        instance.torques_nm = torques(
            instance.dynamics.as_ref(),
            &instance.q_rad,
            &instance.qd_rad_s,
            &instance.qdd_rad_s2,
        );
        instance
    }

    /// The instance name given at instantiation.
    #[must_use]
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The robot in one line: model, calibration, frame and tool.
    #[must_use]
    pub fn describe(&self) -> String {
        let settings = &self.robot.settings;
        format!(
            "{}, {}, frame {}, tool {:?}",
            settings.model,
            settings.calibration_file.as_deref().map_or_else(
                || "nominal".to_owned(),
                |file| format!("calibration {file}")
            ),
            settings.frame.as_str(),
            self.tool
        )
    }

    /// The current state.
    #[must_use]
    pub fn state(&self) -> State {
        self.state
    }

    /// The time where the last step ended (the start time before the first).
    #[must_use]
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// Whether messages of `category` reach the master.
    #[must_use]
    pub fn logs(&self, category: LogCategory) -> bool {
        self.logging.logs(category)
    }

    /// Records a failure the FFI layer detected (a null pointer, say): the instance enters the
    /// error state. Returns the error for logging.
    pub fn reject(&mut self, error: CallError) -> CallError {
        self.state = State::Error;
        error
    }

    /// Runs `body` if the state allows `function`; any failure moves the instance to the error
    /// state.
    fn call<T>(
        &mut self,
        function: &'static str,
        allowed: &[State],
        body: impl FnOnce(&mut Self) -> Result<T, CallError>,
    ) -> Result<T, CallError> {
        let result = if allowed.contains(&self.state) {
            body(self)
        } else {
            Err(CallError::State {
                function,
                state: self.state,
            })
        };
        if result.is_err() {
            self.state = State::Error;
        }
        result
    }

    /// `fmi2SetDebugLogging`: debug logging on or off, for the named categories (all when none
    /// are named). Errors and discards are always logged.
    pub fn set_debug_logging(&mut self, on: bool, categories: &[&str]) -> Result<(), CallError> {
        self.call("fmi2SetDebugLogging", ANY, |this| {
            let categories = categories
                .iter()
                .map(|&name| {
                    LogCategory::from_name(name).ok_or_else(|| CallError::LogCategory {
                        name: name.to_owned(),
                        known: LogCategory::ALL.map(LogCategory::name).join(", "),
                    })
                })
                .collect::<Result<Vec<_>, _>>()?;
            this.logging = LogFilter {
                debug: on,
                categories: (!categories.is_empty()).then_some(categories),
            };
            Ok(())
        })
    }

    /// `fmi2SetupExperiment`: the start time (tolerance and stop time do not matter to an
    /// algebraic model).
    pub fn setup_experiment(&mut self, start_time_s: f64) -> Result<(), CallError> {
        self.call("fmi2SetupExperiment", &[State::Instantiated], |this| {
            if !start_time_s.is_finite() {
                return Err(CallError::Time {
                    function: "fmi2SetupExperiment",
                    argument: "startTime",
                    value: start_time_s,
                });
            }
            this.time_s = start_time_s;
            Ok(())
        })
    }

    /// `fmi2EnterInitializationMode`.
    pub fn enter_initialization_mode(&mut self) -> Result<(), CallError> {
        self.transition(
            "fmi2EnterInitializationMode",
            State::Instantiated,
            State::InitializationMode,
        )
    }

    /// `fmi2ExitInitializationMode`.
    pub fn exit_initialization_mode(&mut self) -> Result<(), CallError> {
        self.transition(
            "fmi2ExitInitializationMode",
            State::InitializationMode,
            State::StepComplete,
        )
    }

    /// `fmi2Terminate`.
    pub fn terminate(&mut self) -> Result<(), CallError> {
        self.transition("fmi2Terminate", State::StepComplete, State::Terminated)
    }

    fn transition(
        &mut self,
        function: &'static str,
        from: State,
        to: State,
    ) -> Result<(), CallError> {
        self.call(function, &[from], |this| {
            this.state = to;
            Ok(())
        })
    }

    /// `fmi2Reset`: back to the state after instantiation (start values, the settings' tool,
    /// time 0, the logging asked for at instantiation), from any state.
    pub fn reset(&mut self) {
        *self = Self::new(&self.name, self.robot.clone(), self.initial_logging.debug);
        self.logging = self.initial_logging.clone();
    }

    /// `fmi2GetReal`: the values of `value_references` into `values` (same length).
    pub fn get_real(
        &mut self,
        value_references: &[u32],
        values: &mut [f64],
    ) -> Result<(), CallError> {
        const FUNCTION: &str = "fmi2GetReal";
        self.call(FUNCTION, GETTABLE, |this| {
            for (&vr, value) in value_references.iter().zip(values.iter_mut()) {
                *value = match Variable::from_value_reference(vr) {
                    Some(Variable::Joint(index)) => this.q_rad[index],
                    Some(Variable::Output(index)) => this.outputs[index],
                    Some(Variable::Tool(index)) => this.tool[index],
                    Some(Variable::Velocity(index)) => this.qd_rad_s[index],
                    Some(Variable::Acceleration(index)) => this.qdd_rad_s2[index],
                    Some(Variable::Torque(index)) => this.torques_nm[index],
                    Some(Variable::Payload(index)) => this.payload[index],
                    None => return Err(unknown(FUNCTION, "Real", vr)),
                };
            }
            Ok(())
        })
    }

    /// `fmi2SetReal`: joint angles (finite, within the joint limits), velocities, accelerations
    /// and tool parameters (finite), payload parameters (finite, the mass at least 0). All or
    /// nothing: on error no value changes. The outputs follow at once.
    pub fn set_real(&mut self, value_references: &[u32], values: &[f64]) -> Result<(), CallError> {
        const FUNCTION: &str = "fmi2SetReal";
        self.call(FUNCTION, SETTABLE, |this| {
            let mut q_rad = this.q_rad;
            let mut tool = this.tool;
            let mut tool_set = false;
            let mut qd_rad_s = this.qd_rad_s;
            let mut qdd_rad_s2 = this.qdd_rad_s2;
            let mut payload = this.payload;
            let mut payload_set = false;
            let not_finite = |vr: u32, value: f64| CallError::Tool {
                function: FUNCTION,
                name: VARIABLES[vr as usize].name,
                value,
            };
            for (&vr, &value) in value_references.iter().zip(values) {
                match Variable::from_value_reference(vr) {
                    Some(Variable::Joint(index)) => q_rad[index] = value,
                    Some(
                        variable @ (Variable::Velocity(index) | Variable::Acceleration(index)),
                    ) => {
                        if !value.is_finite() {
                            return Err(not_finite(vr, value));
                        }
                        if matches!(variable, Variable::Velocity(_)) {
                            qd_rad_s[index] = value;
                        } else {
                            qdd_rad_s2[index] = value;
                        }
                    }
                    Some(Variable::Payload(index)) => {
                        if !value.is_finite() {
                            return Err(not_finite(vr, value));
                        }
                        if index == 0 && value < 0.0 {
                            return Err(CallError::PayloadMass {
                                function: FUNCTION,
                                value,
                            });
                        }
                        payload[index] = value;
                        payload_set = true;
                    }
                    Some(Variable::Tool(index)) => {
                        if !value.is_finite() {
                            return Err(CallError::Tool {
                                function: FUNCTION,
                                name: VARIABLES[vr as usize].name,
                                value,
                            });
                        }
                        tool[index] = value;
                        tool_set = true;
                    }
                    Some(Variable::Output(_) | Variable::Torque(_)) => {
                        return Err(CallError::Output {
                            function: FUNCTION,
                            name: VARIABLES[vr as usize].name,
                            value_reference: vr,
                        });
                    }
                    None => return Err(unknown(FUNCTION, "Real", vr)),
                }
            }
            let model = tool_set.then(|| this.model_with_tool(tool)).transpose()?;
            let outputs =
                pose_outputs(model.as_ref().unwrap_or(&this.model), &q_rad).map_err(|source| {
                    CallError::Joint {
                        function: FUNCTION,
                        source,
                    }
                })?;
            if let Some(model) = model {
                this.model = model;
            }
            if payload_set {
                let [mass_kg, x, y, z] = payload;
                // Checked above: a finite mass of at least 0 and a finite centre of gravity.
                // `with_payload` replaces the payload the dynamics carried.
                this.dynamics = this
                    .dynamics
                    .take()
                    .and_then(|d| d.with_payload(Payload::point_mass(mass_kg, [x, y, z])).ok());
                this.payload = payload;
            }
            this.q_rad = q_rad;
            this.tool = tool;
            this.outputs = outputs;
            this.qd_rad_s = qd_rad_s;
            this.qdd_rad_s2 = qdd_rad_s2;
            this.torques_nm = torques(this.dynamics.as_ref(), &q_rad, &qd_rad_s, &qdd_rad_s2);
            Ok(())
        })
    }

    /// The robot with tool `[x, y, z, rx, ry, rz]` (each value already checked finite).
    fn model_with_tool(&self, tool: [f64; TOOL_COUNT]) -> Result<RobotModel, CallError> {
        let start = &self.robot.model;
        RobotModel::new(
            start.arm().clone(),
            start.calibration().cloned(),
            TcpOffset::from_ur_pose(tool).unwrap_or(TcpOffset::FLANGE),
            start.frame(),
        )
        .map_err(|source| CallError::Model {
            function: "fmi2SetReal",
            source: source.into(),
        })
    }

    /// `fmi2Get`/`fmi2Set` of `Integer`, `Boolean` or `String` (`type_name`): this FMU has no
    /// such variables, so any value reference is unknown.
    pub fn untyped(
        &mut self,
        function: &'static str,
        type_name: &'static str,
        setter: bool,
        value_references: &[u32],
    ) -> Result<(), CallError> {
        self.call(function, if setter { SETTABLE } else { GETTABLE }, |_| {
            value_references
                .first()
                .map_or(Ok(()), |&vr| Err(unknown(function, type_name, vr)))
        })
    }

    /// `fmi2DoStep`: advances time from `current_s` by `step_s`. The outputs already hold the
    /// pose of the inputs set before the step: forward kinematics has no dynamics.
    pub fn do_step(&mut self, current_s: f64, step_s: f64) -> Result<(), CallError> {
        self.call("fmi2DoStep", &[State::StepComplete], |this| {
            if !current_s.is_finite() {
                return Err(CallError::Time {
                    function: "fmi2DoStep",
                    argument: "currentCommunicationPoint",
                    value: current_s,
                });
            }
            if !(step_s.is_finite() && step_s > 0.0) {
                return Err(CallError::StepSize { value: step_s });
            }
            // Masters compute communication points as start + n·h; a few ulps apart is the same.
            let tolerance = 1e-9 * this.time_s.abs().max(1.0);
            if (current_s - this.time_s).abs() > tolerance {
                return Err(CallError::CommunicationPoint {
                    expected: this.time_s,
                    given: current_s,
                });
            }
            this.time_s = current_s + step_s;
            Ok(())
        })
    }

    /// A function the model description declares unsupported: always an error.
    pub fn unsupported(&mut self, function: &'static str, reason: &'static str) -> CallError {
        self.reject(CallError::Unsupported { function, reason })
    }

    /// `fmi2GetRealStatus`: `fmi2LastSuccessfulTime` (kind 2) is the time; any other kind is not
    /// available (`Ok(None)`, the call returns `fmi2Discard`).
    pub fn real_status(&mut self, kind: i32) -> Result<Option<f64>, CallError> {
        const LAST_SUCCESSFUL_TIME: i32 = 2;
        self.call("fmi2GetRealStatus", STATUS, |this| {
            Ok((kind == LAST_SUCCESSFUL_TIME).then_some(this.time_s))
        })
    }

    /// `fmi2GetBooleanStatus`: `fmi2Terminated` (kind 3) is false (this FMU never asks to end
    /// the simulation); any other kind is not available.
    pub fn boolean_status(&mut self, kind: i32) -> Result<Option<bool>, CallError> {
        const TERMINATED: i32 = 3;
        self.call("fmi2GetBooleanStatus", STATUS, |_| {
            Ok((kind == TERMINATED).then_some(false))
        })
    }

    /// `fmi2GetStatus`, `fmi2GetIntegerStatus`, `fmi2GetStringStatus`: nothing to report, as
    /// `fmi2DoStep` never returns `fmi2Pending`; `Ok(())` means `fmi2Discard`.
    pub fn unavailable_status(&mut self, function: &'static str) -> Result<(), CallError> {
        self.call(function, STATUS, |_| Ok(()))
    }
}

fn unknown(function: &'static str, type_name: &'static str, value_reference: u32) -> CallError {
    CallError::UnknownValueReference {
        function,
        type_name,
        value_reference,
    }
}

/// The joint torques of the inverse dynamics (NaN without dynamics).
fn torques(
    dynamics: Option<&ArmDynamics<JOINT_COUNT>>,
    q_rad: &[f64; JOINT_COUNT],
    qd_rad_s: &[f64; JOINT_COUNT],
    qdd_rad_s2: &[f64; JOINT_COUNT],
) -> [f64; JOINT_COUNT] {
    dynamics.map_or([f64::NAN; JOINT_COUNT], |dynamics| {
        dynamics.inverse_dynamics_nm(q_rad, qd_rad_s, qdd_rad_s2)
    })
}

/// The outputs, in `PoseFields` order, for joint angles `q_rad`: the same readout as `armtwin fk`.
fn pose_outputs(
    model: &RobotModel,
    q_rad: &[f64; JOINT_COUNT],
) -> Result<[f64; OUTPUT_COUNT], KinematicsError> {
    let pose = model.pose(q_rad)?;
    Ok(PoseFields::from(&pose.readout()).values())
}

#[cfg(test)]
#[allow(
    clippy::float_cmp,
    reason = "the FMU must give the core's values exactly"
)]
mod tests {
    use armtwin_core::fmi::FmuSettings;
    use armtwin_core::kinematics::OutputFrame;

    use super::*;

    fn robot(tool: [f64; 6]) -> Robot {
        let settings = FmuSettings {
            guid: "{test}".to_owned(),
            model: "ur10e".to_owned(),
            calibration_file: None,
            frame: OutputFrame::Base,
            tool: TcpOffset::from_ur_pose(tool).expect("finite"),
        };
        let model = settings.robot_model(None).expect("catalog model");
        Robot { settings, model }
    }

    fn instance() -> Instance {
        Instance::new("arm", robot([0.0, 0.0, 0.1, 0.0, 0.0, 0.0]), false)
    }

    fn initialized() -> Instance {
        let mut instance = instance();
        instance.setup_experiment(0.0).expect("instantiated");
        instance.enter_initialization_mode().expect("instantiated");
        instance
            .exit_initialization_mode()
            .expect("initialization mode");
        instance
    }

    fn get(instance: &mut Instance, vrs: &[u32]) -> Vec<f64> {
        let mut values = vec![f64::NAN; vrs.len()];
        instance.get_real(vrs, &mut values).expect("gettable");
        values
    }

    const OUTPUT_VRS: [u32; 10] = [6, 7, 8, 9, 10, 11, 12, 13, 14, 15];

    #[test]
    fn lifecycle_follows_the_fmi_state_machine() {
        let mut instance = instance();
        assert_eq!(instance.state(), State::Instantiated);
        instance.setup_experiment(1.5).expect("instantiated");
        instance.enter_initialization_mode().expect("instantiated");
        assert_eq!(instance.state(), State::InitializationMode);
        instance
            .exit_initialization_mode()
            .expect("initialization mode");
        assert_eq!(instance.state(), State::StepComplete);
        instance.do_step(1.5, 0.1).expect("step complete");
        instance.do_step(1.6, 0.1).expect("step complete");
        assert!((instance.time_s() - 1.7).abs() < 1e-15);
        instance.terminate().expect("step complete");
        assert_eq!(instance.state(), State::Terminated);
        instance.reset();
        assert_eq!(instance.state(), State::Instantiated);
        assert_eq!(instance.time_s(), 0.0);
    }

    #[test]
    fn a_call_in_the_wrong_state_fails_and_enters_the_error_state() {
        let mut instance = instance();
        let error = instance.do_step(0.0, 0.1).expect_err("not initialized");
        assert_eq!(
            error.to_string(),
            "fmi2DoStep: not allowed in state instantiated"
        );
        assert_eq!(instance.state(), State::Error);
        // Getters still answer; everything else waits for a reset.
        assert_eq!(get(&mut instance, &[0]), [0.0]);
        assert!(matches!(
            instance.enter_initialization_mode(),
            Err(CallError::State {
                state: State::Error,
                ..
            })
        ));
        instance.reset();
        instance.enter_initialization_mode().expect("reset");
    }

    #[test]
    fn outputs_are_the_core_pose_from_instantiation_on_and_follow_every_set() {
        let mut instance = instance();
        instance.enter_initialization_mode().expect("instantiated");
        let model = robot([0.0, 0.0, 0.1, 0.0, 0.0, 0.0]).model;
        let at_zero = PoseFields::from(&model.pose(&[0.0; 6]).expect("valid").readout()).values();
        assert_eq!(get(&mut instance, &OUTPUT_VRS), at_zero);
        let q = [0.3, -1.2, 1.1, -0.4, 1.5, 2.9];
        instance.set_real(&[0, 1, 2, 3, 4, 5], &q).expect("inputs");
        let expected = PoseFields::from(&model.pose(&q).expect("valid").readout()).values();
        assert_eq!(get(&mut instance, &OUTPUT_VRS), expected);
        assert_ne!(expected, at_zero);
    }

    #[test]
    fn tool_parameters_rebuild_the_model() {
        let mut instance = initialized();
        let q = [0.1, -0.7, 0.9, 0.2, -1.3, 0.4];
        let tool = [0.05, -0.02, 0.2, 0.1, 0.2, -0.3];
        instance
            .set_real(
                &[16, 17, 18, 19, 20, 21, 0, 1, 2, 3, 4, 5],
                &[tool, q].concat(),
            )
            .expect("tunable parameters and inputs");
        let expected =
            PoseFields::from(&robot(tool).model.pose(&q).expect("valid").readout()).values();
        assert_eq!(get(&mut instance, &OUTPUT_VRS), expected);
        assert_eq!(get(&mut instance, &[16, 17, 18, 19, 20, 21]), tool);
    }

    #[test]
    fn torques_are_the_cores_inverse_dynamics_with_the_payload() {
        let mut instance = initialized();
        let q = [0.3, -1.2, 1.1, -0.4, 1.5, 0.2];
        let qd = [0.5, -0.3, 0.8, 1.0, -0.6, 0.4];
        let qdd = [1.0, 2.0, -1.5, 0.5, 3.0, -2.0];
        let payload = [3.5, 0.01, -0.02, 0.09];
        let vrs: Vec<u32> = (0..6).chain(22..34).chain(40..44).collect();
        instance
            .set_real(&vrs, &[&q[..], &qd, &qdd, &payload].concat())
            .expect("inputs and payload");
        let arm = robot([0.0; 6]).model.arm().clone();
        let expected = ArmDynamics::<JOINT_COUNT>::from_arm(&arm)
            .and_then(|d| d.with_payload(Payload::point_mass(3.5, [0.01, -0.02, 0.09])))
            .expect("dynamics")
            .inverse_dynamics_nm(&q, &qd, &qdd);
        let torque_vrs: Vec<u32> = (34..40).collect();
        assert_eq!(get(&mut instance, &torque_vrs), expected);
        assert_eq!(get(&mut instance, &[40, 41, 42, 43]), payload);
    }

    #[test]
    fn bad_sets_change_nothing_and_say_why() {
        let mut instance = initialized();
        let before = get(&mut instance, &[0, 6, 16, 23, 34, 40]);
        let cases: [(&[u32], &[f64], &str); 8] = [
            (
                &[0, 6],
                &[0.5, 1.0],
                "fmi2SetReal: 'x' (value reference 6) is an output and cannot be set",
            ),
            (
                &[0, 44],
                &[0.5, 1.0],
                "fmi2SetReal: no Real variable has value reference 44",
            ),
            (
                &[0, 34],
                &[0.5, 1.0],
                "fmi2SetReal: 'tau1' (value reference 34) is an output and cannot be set",
            ),
            (
                &[0, 23],
                &[0.5, f64::NAN],
                "fmi2SetReal: 'qd2' = NaN is not a finite number",
            ),
            (
                &[0, 40],
                &[0.5, -1.0],
                "fmi2SetReal: 'payload_mass' = -1 is negative",
            ),
            (
                &[0, 1],
                &[0.5, f64::NAN],
                "fmi2SetReal: joint q2 is not a finite number (NaN)",
            ),
            (
                &[2],
                &[7.0],
                "fmi2SetReal: joint q3 = 7 rad is outside its limits",
            ),
            (
                &[0, 18],
                &[0.5, f64::INFINITY],
                "fmi2SetReal: 'tcp_z' = inf is not a finite number",
            ),
        ];
        for (vrs, values, message) in cases {
            instance.reset();
            instance.enter_initialization_mode().expect("reset");
            let error = instance.set_real(vrs, values).expect_err(message);
            assert!(error.to_string().starts_with(message), "{error}");
            assert_eq!(instance.state(), State::Error);
            assert_eq!(
                get(&mut instance, &[0, 6, 16, 23, 34, 40]),
                before,
                "{message}"
            );
        }
    }

    #[test]
    fn untyped_variables_do_not_exist() {
        let mut instance = initialized();
        instance
            .untyped("fmi2GetInteger", "Integer", false, &[])
            .expect("nothing asked");
        let error = instance
            .untyped("fmi2GetBoolean", "Boolean", false, &[0])
            .expect_err("no Boolean");
        assert_eq!(
            error.to_string(),
            "fmi2GetBoolean: no Boolean variable has value reference 0"
        );
    }

    #[test]
    fn do_step_checks_time_and_step_size() {
        let mut instance = initialized();
        assert!(matches!(
            instance.do_step(0.0, 0.0),
            Err(CallError::StepSize { .. })
        ));
        let mut instance = initialized();
        assert!(matches!(
            instance.do_step(0.5, 0.1),
            Err(CallError::CommunicationPoint { .. })
        ));
        let mut instance = initialized();
        let mut t = 0.0;
        for n in 1..=1000 {
            instance.do_step(t, 0.1).expect("step");
            t = f64::from(n) * 0.1;
        }
        assert_eq!(
            instance.real_status(2).expect("status"),
            Some(999.0 * 0.1 + 0.1)
        );
        assert_eq!(instance.real_status(0).expect("status"), None);
        assert_eq!(instance.boolean_status(3).expect("status"), Some(false));
    }

    #[test]
    fn debug_logging_filters_calls_only() {
        let mut instance = instance();
        assert!(!instance.logs(LogCategory::Calls));
        assert!(instance.logs(LogCategory::StatusError));
        instance.set_debug_logging(true, &[]).expect("all");
        assert!(instance.logs(LogCategory::Calls));
        instance
            .set_debug_logging(true, &["logStatusError"])
            .expect("known");
        assert!(!instance.logs(LogCategory::Calls));
        let error = instance
            .set_debug_logging(true, &["logEverything"])
            .expect_err("unknown");
        assert!(
            error
                .to_string()
                .contains("logStatusError, logStatusDiscard, logCalls")
        );
    }
}
