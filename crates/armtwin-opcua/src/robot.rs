//! One robot's nodes: an OPC 40010 `MotionDeviceSystem` under DI's `DeviceSet`, named by the
//! robot's id, holding its motion device (axes, power trains, flange load), its controller, its
//! safety state and armtwin's `Twin` object; and what each of their variables reads from a
//! [`RobotReading`].
//!
//! Node ids are strings in armtwin's namespace: the robot's id for its system, `<id>#<path>`
//! below it (`#` never occurs in a robot id, a Zenoh key): a node's id names its robot, so its
//! nodes can be made again from the robot's reading whenever a request names one. Builds into
//! the address space it is given (a request's own, dropped after it); must not touch
//! subscriptions.

use opcua::nodes::{ObjectBuilder, ReferenceDirection, VariableBuilder};
use opcua::server::address_space::{AccessLevel, AddressSpace, EventNotifier};
use opcua::types::{
    DataTypeId, EUInformation, LocalizedText, NodeId, ObjectTypeId, QualifiedName, ReferenceTypeId,
    StatusCode, UAString, VariableTypeId, Variant,
};

use crate::manager::Namespaces;
use crate::reading::{DeviationStats, RobotReading};

/// DI's `DeviceSet` object.
pub(crate) const DEVICE_SET: u32 = 5001;
/// Robotics' `MotionDeviceSystemType`, `MotionDeviceType`, `AxisType`, `PowerTrainType`,
/// `MotorType`, `ControllerType`, `SafetyStateType`, `LoadType` and `UserType`.
pub(crate) const MOTION_DEVICE_SYSTEM_TYPE: u32 = 1002;
const MOTION_DEVICE_TYPE: u32 = 1004;
const AXIS_TYPE: u32 = 16601;
const POWER_TRAIN_TYPE: u32 = 16794;
const MOTOR_TYPE: u32 = 1019;
const CONTROLLER_TYPE: u32 = 1003;
const SAFETY_STATE_TYPE: u32 = 1013;
const LOAD_TYPE: u32 = 1018;
const USER_TYPE: u32 = 18175;
/// Robotics' `Moves` reference (a power train moves an axis).
const MOVES: u32 = 18178;
/// Robotics' enumerations: `MotionDeviceCategoryEnumeration`, `AxisMotionProfileEnumeration`,
/// `OperationalModeEnumeration`.
const MOTION_DEVICE_CATEGORY: u32 = 18193;
const AXIS_MOTION_PROFILE: u32 = 3008;
const OPERATIONAL_MODE: u32 = 3006;
/// `ARTICULATED_ROBOT` and `ROTARY`, the values every arm armtwin models takes.
const ARTICULATED_ROBOT: i32 = 1;
const ROTARY: i32 = 1;

/// The engineering units published, as UNECE codes (OPC 10000-8's `EUInformation`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Unit {
    Degree,
    DegreePerSecond,
    Celsius,
    Ampere,
    NewtonMetre,
    Kilogram,
    Metre,
    Radian,
    Second,
}

impl Unit {
    /// UNECE common code and display name.
    fn code_and_symbol(self) -> (&'static str, &'static str) {
        match self {
            Self::Degree => ("DD", "°"),
            Self::DegreePerSecond => ("E96", "°/s"),
            Self::Celsius => ("CEL", "°C"),
            Self::Ampere => ("AMP", "A"),
            Self::NewtonMetre => ("NU", "N·m"),
            Self::Kilogram => ("KGM", "kg"),
            Self::Metre => ("MTR", "m"),
            Self::Radian => ("C81", "rad"),
            Self::Second => ("SEC", "s"),
        }
    }

    /// The unit's `EUInformation`: its `UnitId` packs the UNECE code's characters, as OPC 10000-8
    /// says.
    pub(crate) fn information(self) -> EUInformation {
        let (code, symbol) = self.code_and_symbol();
        let unit_id = code.bytes().fold(0_i32, |id, c| (id << 8) | i32::from(c));
        EUInformation {
            namespace_uri: UAString::from("http://www.opcfoundation.org/UA/units/un/cefact"),
            unit_id,
            display_name: LocalizedText::new("en", symbol),
            description: LocalizedText::new("en", code),
        }
    }
}

/// A statistic of the deviation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Stat {
    Samples,
    PositionRmse,
    PositionMax,
    AngleRmse,
    AngleMax,
}

/// What a variable of a robot shows: each reads its value from a [`RobotReading`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Quantity {
    AxisPosition(usize),
    AxisSpeed(usize),
    MotorTemperature(usize),
    MotorCurrent(usize),
    MotorTorque(usize),
    SpeedOverride,
    InControl,
    FlangeMass,
    OperationalMode,
    EmergencyStop,
    ProtectiveStop,
    SourceTime,
    TwinPosition,
    TwinOrientation,
    Window(Stat),
    Cumulative(Stat),
    WindowLength,
    PositionAlarm,
    AngleAlarm,
    Collision,
    Collisions,
    IdentifiedMass,
    IdentifiedMassStd,
    IdentifiedSamples,
    Calibration,
    SerialNumber,
}

/// A variable's value, or why there is none.
pub(crate) type Reading = (Variant, StatusCode);

fn good(value: impl Into<Variant>) -> Reading {
    (value.into(), StatusCode::Good)
}

fn missing() -> Reading {
    (Variant::Empty, StatusCode::BadWaitingForInitialData)
}

/// Per-joint `values[joint]` scaled, or missing.
fn joint(values: Option<&Vec<f64>>, joint: usize, scale: f64) -> Reading {
    values
        .and_then(|values| values.get(joint))
        .map_or_else(missing, |value| good(value * scale))
}

/// A mass a plant may read: physical, or no number at all.
fn physical_mass(mass_kg: f64) -> Reading {
    if mass_kg.is_finite() && mass_kg >= 0.0 {
        good(mass_kg)
    } else {
        (Variant::Empty, StatusCode::BadOutOfRange)
    }
}

/// How many standard deviations an identified mass must lie above zero to be published.
const SIGNIFICANT_SIGMAS: f64 = 2.0;

fn stat(stats: &DeviationStats, stat: Stat) -> Reading {
    match stat {
        Stat::Samples => good(stats.samples),
        Stat::PositionRmse => good(stats.position_rmse_m),
        Stat::PositionMax => good(stats.position_max_m),
        Stat::AngleRmse => good(stats.angle_rmse_rad),
        Stat::AngleMax => good(stats.angle_max_rad),
    }
}

impl Quantity {
    /// This quantity's value in `reading`.
    pub(crate) fn read(self, reading: &RobotReading) -> Reading {
        let controller = reading.controller.as_ref();
        match self {
            Self::AxisPosition(j) => joint(reading.positions_rad.as_ref(), j, f64::to_degrees(1.0)),
            Self::AxisSpeed(j) => joint(reading.velocities_rad_s.as_ref(), j, f64::to_degrees(1.0)),
            Self::MotorTemperature(j) => joint(reading.temperatures_c.as_ref(), j, 1.0),
            Self::MotorCurrent(j) => joint(reading.currents_a.as_ref(), j, 1.0),
            Self::MotorTorque(j) => joint(reading.torques_nm.as_ref(), j, 1.0),
            // 40010's SpeedOverride is a percentage of the programmed speed.
            Self::SpeedOverride => {
                controller.map_or_else(missing, |c| good(c.speed_scaling * 100.0))
            }
            // UR's robot mode 7 is RUNNING: powered, brakes released, under control.
            Self::InControl => controller.map_or_else(missing, |c| good(c.robot_mode == 7)),
            Self::FlangeMass => reading
                .applied_payload
                .or(reading.configured_payload)
                .map_or_else(missing, |payload| physical_mass(payload.mass_kg)),
            // The controller reports no operational mode; freedrive is hand-guided, reduced speed.
            Self::OperationalMode => {
                controller.map_or_else(missing, |c| good(i32::from(c.freedrive)))
            }
            Self::EmergencyStop => {
                controller.map_or_else(missing, |c| good(matches!(c.safety_mode, 6 | 7)))
            }
            Self::ProtectiveStop => {
                controller.map_or_else(missing, |c| good(matches!(c.safety_mode, 3 | 5)))
            }
            Self::SourceTime => good(reading.stamp_s),
            Self::TwinPosition => reading
                .twin_pose
                .map_or_else(missing, |pose| good(pose.position_m.to_vec())),
            Self::TwinOrientation => reading
                .twin_pose
                .map_or_else(missing, |pose| good(pose.quaternion_xyzw.to_vec())),
            Self::Window(s) => stat(&reading.window, s),
            Self::Cumulative(s) => stat(&reading.cumulative, s),
            Self::WindowLength => good(reading.window_s),
            Self::PositionAlarm => good(reading.position_alarm),
            Self::AngleAlarm => good(reading.angle_alarm),
            Self::Collision => good(reading.collision.iter().any(|&on| on)),
            Self::Collisions => good(reading.collisions),
            Self::IdentifiedMass => reading.identified_payload.map_or_else(missing, |fit| {
                // A fit the data cannot tell from zero, or below it, is "unknown", not a number.
                if fit.mass_kg > SIGNIFICANT_SIGMAS * fit.mass_std_kg {
                    physical_mass(fit.mass_kg)
                } else {
                    (Variant::Empty, StatusCode::BadOutOfRange)
                }
            }),
            Self::IdentifiedMassStd => reading
                .identified_payload
                .map_or_else(missing, |fit| good(fit.mass_std_kg)),
            Self::IdentifiedSamples => reading
                .identified_payload
                .map_or_else(missing, |fit| good(fit.samples as u64)),
            Self::Calibration => good(reading.calibration.as_str()),
            // DI's nameplate property is mandatory: empty until the controller's is known.
            Self::SerialNumber => good(reading.serial_number.as_deref().unwrap_or("")),
        }
    }
}

/// A variable that changes, and what it shows.
pub(crate) struct Slot {
    pub(crate) node: NodeId,
    pub(crate) quantity: Quantity,
}

/// A robot's nodes as built.
pub(crate) struct RobotNodes {
    /// Its variables that change.
    pub(crate) slots: Vec<Slot>,
}

/// Adds a robot's nodes to `space` under `DeviceSet`.
struct Tree<'a> {
    space: &'a mut AddressSpace,
    ns: Namespaces,
    robot: &'a str,
    slots: Vec<Slot>,
}

impl Tree<'_> {
    fn id(&self, path: &str) -> NodeId {
        NodeId::new(self.ns.armtwin, format!("{}#{path}", self.robot))
    }

    fn object(
        &mut self,
        id: NodeId,
        browse_name: QualifiedName,
        type_definition: NodeId,
        (parent, reference): (&NodeId, ReferenceTypeId),
    ) -> NodeId {
        let display = browse_name.name.to_string();
        ObjectBuilder::new(&id, browse_name, display)
            .has_type_definition(type_definition)
            .reference(parent.clone(), reference, ReferenceDirection::Inverse)
            .insert(self.space);
        id
    }

    /// An object at `path`, a component of `parent`.
    fn component(
        &mut self,
        path: &str,
        browse_name: QualifiedName,
        type_definition: NodeId,
        parent: &NodeId,
    ) -> NodeId {
        let id = self.id(path);
        self.object(
            id,
            browse_name,
            type_definition,
            (parent, ReferenceTypeId::HasComponent),
        )
    }

    fn folder(&mut self, path: &str, browse_name: QualifiedName, parent: &NodeId) -> NodeId {
        let id = self.id(path);
        self.object(
            id,
            browse_name,
            ObjectTypeId::FolderType.into(),
            (parent, ReferenceTypeId::HasComponent),
        )
    }

    /// `ParameterSet` (DI's) under `parent`.
    fn parameter_set(&mut self, path: &str, parent: &NodeId) -> NodeId {
        let id = self.id(&format!("{path}/ParameterSet"));
        self.object(
            id,
            QualifiedName::new(self.ns.di, "ParameterSet"),
            ObjectTypeId::BaseObjectType.into(),
            (parent, ReferenceTypeId::HasComponent),
        )
    }

    fn variable(
        &mut self,
        path: &str,
        browse_name: QualifiedName,
        (data_type, type_definition): (NodeId, NodeId),
        (parent, reference): (&NodeId, ReferenceTypeId),
        value: Variant,
    ) -> NodeId {
        let id = self.id(path);
        let display = browse_name.name.to_string();
        let rank = if matches!(value, Variant::Array(_)) {
            1
        } else {
            -1
        };
        VariableBuilder::new(&id, browse_name, display)
            .data_type(data_type)
            .value_rank(rank)
            .value(value)
            .access_level(AccessLevel::CURRENT_READ)
            .user_access_level(AccessLevel::CURRENT_READ)
            .has_type_definition(type_definition)
            .reference(parent.clone(), reference, ReferenceDirection::Inverse)
            .insert(self.space);
        id
    }

    fn property(
        &mut self,
        path: &str,
        browse_name: QualifiedName,
        data_type: NodeId,
        value: Variant,
        parent: &NodeId,
    ) -> NodeId {
        self.variable(
            path,
            browse_name,
            (data_type, VariableTypeId::PropertyType.into()),
            (parent, ReferenceTypeId::HasProperty),
            value,
        )
    }

    /// A variable that changes: `quantity` of the robot.
    fn live(
        &mut self,
        path: &str,
        browse_name: QualifiedName,
        data_type: DataTypeId,
        parent: &NodeId,
        quantity: Quantity,
    ) -> NodeId {
        let id = self.variable(
            path,
            browse_name,
            (
                data_type.into(),
                VariableTypeId::BaseDataVariableType.into(),
            ),
            (parent, ReferenceTypeId::HasComponent),
            Variant::Empty,
        );
        self.keep_up(&id, quantity);
        id
    }

    /// Keeps variable `node` showing `quantity` of the robot.
    fn keep_up(&mut self, node: &NodeId, quantity: Quantity) {
        self.slots.push(Slot {
            node: node.clone(),
            quantity,
        });
    }

    /// An `AnalogUnitType` variable of `quantity` in `unit`, with its `EngineeringUnits`.
    fn analog(
        &mut self,
        path: &str,
        browse_name: QualifiedName,
        parent: &NodeId,
        unit: Unit,
        quantity: Quantity,
    ) -> NodeId {
        let id = self.variable(
            path,
            browse_name,
            (
                DataTypeId::Double.into(),
                VariableTypeId::AnalogUnitType.into(),
            ),
            (parent, ReferenceTypeId::HasComponent),
            Variant::Empty,
        );
        self.property(
            &format!("{path}/EngineeringUnits"),
            QualifiedName::new(0, "EngineeringUnits"),
            DataTypeId::EUInformation.into(),
            Variant::from(unit.information()),
            &id,
        );
        self.slots.push(Slot {
            node: id.clone(),
            quantity,
        });
        id
    }

    /// DI's nameplate properties, mandatory on 40010's components; `serial`, where the
    /// component's serial number can become known, keeps that property up to date.
    fn nameplate(
        &mut self,
        path: &str,
        parent: &NodeId,
        (manufacturer, model): (&str, &str),
        serial: Option<Quantity>,
    ) {
        let di = self.ns.di;
        for (name, data_type, value) in [
            (
                "Manufacturer",
                DataTypeId::LocalizedText,
                Variant::from(LocalizedText::new("", manufacturer)),
            ),
            (
                "Model",
                DataTypeId::LocalizedText,
                Variant::from(LocalizedText::new("", model)),
            ),
            ("ProductCode", DataTypeId::String, Variant::from(model)),
            ("SerialNumber", DataTypeId::String, Variant::from("")),
        ] {
            let id = self.property(
                &format!("{path}/{name}"),
                QualifiedName::new(di, name),
                data_type.into(),
                value,
                parent,
            );
            if name == "SerialNumber"
                && let Some(quantity) = serial
            {
                self.keep_up(&id, quantity);
            }
        }
    }
}

/// The manufacturer of a catalogue model, where its name tells it.
fn manufacturer_of(model: &str) -> &'static str {
    if model.to_ascii_lowercase().starts_with("ur") {
        "Universal Robots"
    } else {
        ""
    }
}

/// Builds `reading`'s robot's nodes in `space` under `DeviceSet`.
pub(crate) fn build(
    space: &mut AddressSpace,
    ns: Namespaces,
    reading: &RobotReading,
) -> RobotNodes {
    let robot = &*reading.id;
    let mut tree = Tree {
        space,
        ns,
        robot,
        slots: Vec::new(),
    };
    let root = NodeId::new(ns.armtwin, robot.to_owned());
    ObjectBuilder::new(&root, QualifiedName::new(ns.armtwin, robot), robot)
        .has_type_definition(NodeId::new(ns.robotics, MOTION_DEVICE_SYSTEM_TYPE))
        .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
        .reference(
            NodeId::new(ns.di, DEVICE_SET),
            ReferenceTypeId::HasComponent,
            ReferenceDirection::Inverse,
        )
        .insert(tree.space);
    let identity = (manufacturer_of(&reading.model), reading.model.as_str());
    tree.motion_device(&root, identity);
    for j in 0..reading.joint_count {
        tree.joint(j, identity);
    }
    tree.controller(&root, identity.0);
    tree.safety_state(&root);
    tree.twin(&root);
    RobotNodes { slots: tree.slots }
}

/// Where a robot's motion device's nodes are, below its system.
const DEVICE: &str = "MotionDevices/Arm";

impl Tree<'_> {
    /// `MotionDevices/<model>`: its nameplate, category, parameters, folders and flange load.
    fn motion_device(&mut self, root: &NodeId, identity: (&str, &str)) {
        let (r, a) = (self.ns.robotics, self.ns.armtwin);
        let devices = self.folder(
            "MotionDevices",
            QualifiedName::new(r, "MotionDevices"),
            root,
        );
        let device = self.component(
            DEVICE,
            QualifiedName::new(a, identity.1),
            NodeId::new(r, MOTION_DEVICE_TYPE),
            &devices,
        );
        // UR's dashboard server gives the arm's serial number (the controller's is its own).
        self.nameplate(DEVICE, &device, identity, Some(Quantity::SerialNumber));
        self.property(
            &format!("{DEVICE}/MotionDeviceCategory"),
            QualifiedName::new(r, "MotionDeviceCategory"),
            NodeId::new(r, MOTION_DEVICE_CATEGORY),
            Variant::from(ARTICULATED_ROBOT),
            &device,
        );
        let parameters = self.parameter_set(DEVICE, &device);
        for (name, data_type, quantity) in [
            ("SpeedOverride", DataTypeId::Double, Quantity::SpeedOverride),
            ("InControl", DataTypeId::Boolean, Quantity::InControl),
        ] {
            self.live(
                &format!("{DEVICE}/ParameterSet/{name}"),
                QualifiedName::new(r, name),
                data_type,
                &parameters,
                quantity,
            );
        }
        self.folder(
            &format!("{DEVICE}/Axes"),
            QualifiedName::new(r, "Axes"),
            &device,
        );
        self.folder(
            &format!("{DEVICE}/PowerTrains"),
            QualifiedName::new(r, "PowerTrains"),
            &device,
        );
        let load = self.component(
            &format!("{DEVICE}/FlangeLoad"),
            QualifiedName::new(r, "FlangeLoad"),
            NodeId::new(r, LOAD_TYPE),
            &device,
        );
        self.analog(
            &format!("{DEVICE}/FlangeLoad/Mass"),
            QualifiedName::new(r, "Mass"),
            &load,
            Unit::Kilogram,
            Quantity::FlangeMass,
        );
    }

    /// Joint `j`: its axis and the power train (motor) that moves it.
    fn joint(&mut self, j: usize, identity: (&str, &str)) {
        let (r, a) = (self.ns.robotics, self.ns.armtwin);
        let name = format!("Axis{}", j + 1);
        let path = format!("{DEVICE}/Axes/{name}");
        let axes = self.id(&format!("{DEVICE}/Axes"));
        let axis = self.component(
            &path,
            QualifiedName::new(a, name.as_str()),
            NodeId::new(r, AXIS_TYPE),
            &axes,
        );
        self.property(
            &format!("{path}/MotionProfile"),
            QualifiedName::new(r, "MotionProfile"),
            NodeId::new(r, AXIS_MOTION_PROFILE),
            Variant::from(ROTARY),
            &axis,
        );
        let parameters = self.parameter_set(&path, &axis);
        for (name, unit, quantity) in [
            ("ActualPosition", Unit::Degree, Quantity::AxisPosition(j)),
            ("ActualSpeed", Unit::DegreePerSecond, Quantity::AxisSpeed(j)),
        ] {
            self.analog(
                &format!("{path}/ParameterSet/{name}"),
                QualifiedName::new(r, name),
                &parameters,
                unit,
                quantity,
            );
        }

        let train_name = format!("PowerTrain{}", j + 1);
        let train_path = format!("{DEVICE}/PowerTrains/{train_name}");
        let trains = self.id(&format!("{DEVICE}/PowerTrains"));
        let train = self.component(
            &train_path,
            QualifiedName::new(a, train_name.as_str()),
            NodeId::new(r, POWER_TRAIN_TYPE),
            &trains,
        );
        self.space
            .insert_reference(&train, &axis, NodeId::new(r, MOVES));
        let motor_path = format!("{train_path}/Motor");
        let motor = self.component(
            &motor_path,
            QualifiedName::new(a, "Motor"),
            NodeId::new(r, MOTOR_TYPE),
            &train,
        );
        self.nameplate(&motor_path, &motor, identity, None);
        let parameters = self.parameter_set(&motor_path, &motor);
        // Current and torque are not in 40010 1.01: armtwin's, beside the motor's temperature.
        for (name, namespace, unit, quantity) in [
            (
                "MotorTemperature",
                r,
                Unit::Celsius,
                Quantity::MotorTemperature(j),
            ),
            ("ActualCurrent", a, Unit::Ampere, Quantity::MotorCurrent(j)),
            (
                "ActualTorque",
                a,
                Unit::NewtonMetre,
                Quantity::MotorTorque(j),
            ),
        ] {
            self.analog(
                &format!("{motor_path}/ParameterSet/{name}"),
                QualifiedName::new(namespace, name),
                &parameters,
                unit,
                quantity,
            );
        }
    }

    /// `Controllers/Controller`: what 40010 makes mandatory, with the manufacturer where known.
    fn controller(&mut self, root: &NodeId, manufacturer: &str) {
        let (r, a) = (self.ns.robotics, self.ns.armtwin);
        let controllers = self.folder("Controllers", QualifiedName::new(r, "Controllers"), root);
        let path = "Controllers/Controller";
        let controller = self.component(
            path,
            QualifiedName::new(a, "Controller"),
            NodeId::new(r, CONTROLLER_TYPE),
            &controllers,
        );
        self.nameplate(path, &controller, (manufacturer, ""), None);
        let user = self.component(
            &format!("{path}/CurrentUser"),
            QualifiedName::new(r, "CurrentUser"),
            NodeId::new(r, USER_TYPE),
            &controller,
        );
        self.property(
            &format!("{path}/CurrentUser/Level"),
            QualifiedName::new(r, "Level"),
            DataTypeId::String.into(),
            Variant::from(""),
            &user,
        );
        for name in ["Software", "TaskControls"] {
            self.folder(
                &format!("{path}/{name}"),
                QualifiedName::new(r, name),
                &controller,
            );
        }
    }

    /// `SafetyStates/SafetyState`, from the controller's safety mode.
    fn safety_state(&mut self, root: &NodeId) {
        let (r, a) = (self.ns.robotics, self.ns.armtwin);
        let states = self.folder("SafetyStates", QualifiedName::new(r, "SafetyStates"), root);
        let path = "SafetyStates/SafetyState";
        let safety = self.component(
            path,
            QualifiedName::new(a, "SafetyState"),
            NodeId::new(r, SAFETY_STATE_TYPE),
            &states,
        );
        let parameters = self.parameter_set(path, &safety);
        for (name, quantity) in [
            ("EmergencyStop", Quantity::EmergencyStop),
            ("ProtectiveStop", Quantity::ProtectiveStop),
        ] {
            self.live(
                &format!("{path}/ParameterSet/{name}"),
                QualifiedName::new(r, name),
                DataTypeId::Boolean,
                &parameters,
                quantity,
            );
        }
        let mode = self.variable(
            &format!("{path}/ParameterSet/OperationalMode"),
            QualifiedName::new(r, "OperationalMode"),
            (
                NodeId::new(r, OPERATIONAL_MODE),
                VariableTypeId::BaseDataVariableType.into(),
            ),
            (&parameters, ReferenceTypeId::HasComponent),
            Variant::Empty,
        );
        self.slots.push(Slot {
            node: mode,
            quantity: Quantity::OperationalMode,
        });
    }

    /// armtwin's own object of the robot: what no controller offers.
    fn twin(&mut self, root: &NodeId) {
        let a = self.ns.armtwin;
        let twin = self.component(
            "Twin",
            QualifiedName::new(a, "Twin"),
            ObjectTypeId::BaseObjectType.into(),
            root,
        );
        for (name, unit, quantity) in [
            ("SourceTime", Unit::Second, Quantity::SourceTime),
            ("WindowLength", Unit::Second, Quantity::WindowLength),
        ] {
            self.analog(
                &format!("Twin/{name}"),
                QualifiedName::new(a, name),
                &twin,
                unit,
                quantity,
            );
        }
        for (name, data_type, quantity) in [
            ("Position", DataTypeId::Double, Quantity::TwinPosition),
            (
                "OrientationXYZW",
                DataTypeId::Double,
                Quantity::TwinOrientation,
            ),
            (
                "PositionAlarm",
                DataTypeId::Boolean,
                Quantity::PositionAlarm,
            ),
            ("AngleAlarm", DataTypeId::Boolean, Quantity::AngleAlarm),
            ("Collision", DataTypeId::Boolean, Quantity::Collision),
            ("Collisions", DataTypeId::UInt64, Quantity::Collisions),
            ("Calibration", DataTypeId::String, Quantity::Calibration),
        ] {
            self.live(
                &format!("Twin/{name}"),
                QualifiedName::new(a, name),
                data_type,
                &twin,
                quantity,
            );
        }
        self.deviation_stats(&twin, "Window", Quantity::Window);
        self.deviation_stats(&twin, "Cumulative", Quantity::Cumulative);
        let payload = self.folder(
            "Twin/IdentifiedPayload",
            QualifiedName::new(a, "IdentifiedPayload"),
            &twin,
        );
        for (name, quantity) in [
            ("Mass", Quantity::IdentifiedMass),
            ("MassStd", Quantity::IdentifiedMassStd),
        ] {
            self.analog(
                &format!("Twin/IdentifiedPayload/{name}"),
                QualifiedName::new(a, name),
                &payload,
                Unit::Kilogram,
                quantity,
            );
        }
        self.live(
            "Twin/IdentifiedPayload/Samples",
            QualifiedName::new(a, "Samples"),
            DataTypeId::UInt64,
            &payload,
            Quantity::IdentifiedSamples,
        );
    }

    /// `Twin/<set>`: one set of deviation statistics.
    fn deviation_stats(&mut self, twin: &NodeId, set: &str, of: fn(Stat) -> Quantity) {
        let a = self.ns.armtwin;
        let path = format!("Twin/{set}");
        let folder = self.folder(&path, QualifiedName::new(a, set), twin);
        self.live(
            &format!("{path}/Samples"),
            QualifiedName::new(a, "Samples"),
            DataTypeId::UInt64,
            &folder,
            of(Stat::Samples),
        );
        for (name, unit, stat) in [
            ("PositionRmse", Unit::Metre, Stat::PositionRmse),
            ("PositionMax", Unit::Metre, Stat::PositionMax),
            ("AngleRmse", Unit::Radian, Stat::AngleRmse),
            ("AngleMax", Unit::Radian, Stat::AngleMax),
        ] {
            self.analog(
                &format!("{path}/{name}"),
                QualifiedName::new(a, name),
                &folder,
                unit,
                of(stat),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reading::{IdentifiedPayload, PayloadReading};

    #[test]
    fn unit_ids_pack_the_unece_codes() {
        // OPC 10000-8's examples: degree Celsius is 4408652, metre 5067858.
        assert_eq!(Unit::Celsius.information().unit_id, 4408652);
        assert_eq!(Unit::Metre.information().unit_id, 5067858);
        assert_eq!(Unit::Degree.information().unit_id, 17476);
    }

    #[test]
    fn axis_positions_are_degrees_of_the_joints_in_radians() {
        let reading = RobotReading {
            positions_rad: Some(vec![std::f64::consts::FRAC_PI_2, -1.0]),
            ..RobotReading::default()
        };
        let (value, status) = Quantity::AxisPosition(0).read(&reading);
        assert_eq!(status, StatusCode::Good);
        assert_eq!(value, Variant::from(90.0));
        assert_eq!(
            Quantity::AxisPosition(1).read(&reading).0,
            Variant::from(-1.0_f64.to_degrees())
        );
        assert_eq!(
            Quantity::AxisPosition(2).read(&reading).1,
            StatusCode::BadWaitingForInitialData
        );
        assert_eq!(
            Quantity::AxisSpeed(0).read(&reading).1,
            StatusCode::BadWaitingForInitialData
        );
    }

    #[test]
    fn a_mass_is_published_only_when_physical_and_significant() {
        let fit = |mass_kg, mass_std_kg| RobotReading {
            identified_payload: Some(IdentifiedPayload {
                mass_kg,
                mass_std_kg,
                samples: 100,
            }),
            ..RobotReading::default()
        };
        assert_eq!(
            Quantity::IdentifiedMass.read(&fit(1.2, 0.05)),
            (Variant::from(1.2), StatusCode::Good)
        );
        // The held-out UR5e recording's −0.17 kg: no number.
        assert_eq!(
            Quantity::IdentifiedMass.read(&fit(-0.17, 0.05)).1,
            StatusCode::BadOutOfRange
        );
        // Within two standard deviations of zero: unknown.
        assert_eq!(
            Quantity::IdentifiedMass.read(&fit(0.08, 0.05)),
            (Variant::Empty, StatusCode::BadOutOfRange)
        );
        assert_eq!(
            Quantity::IdentifiedMassStd.read(&fit(0.08, 0.05)).0,
            Variant::from(0.05)
        );
        let configured = RobotReading {
            configured_payload: Some(PayloadReading {
                mass_kg: -1.0,
                cog_m: [0.0; 3],
            }),
            ..RobotReading::default()
        };
        assert_eq!(
            Quantity::FlangeMass.read(&configured).1,
            StatusCode::BadOutOfRange
        );
    }

    #[test]
    fn the_serial_number_is_empty_until_a_gateway_reports_it() {
        assert_eq!(
            Quantity::SerialNumber.read(&RobotReading::default()),
            (Variant::from(""), StatusCode::Good)
        );
        let reported = RobotReading {
            serial_number: Some("20235500001".to_owned()),
            ..RobotReading::default()
        };
        assert_eq!(
            Quantity::SerialNumber.read(&reported).0,
            Variant::from("20235500001")
        );
    }

    #[test]
    fn an_applied_payload_wins_over_the_configured_one() {
        let reading = RobotReading {
            configured_payload: Some(PayloadReading {
                mass_kg: 1.0,
                cog_m: [0.0; 3],
            }),
            applied_payload: Some(PayloadReading {
                mass_kg: 2.5,
                cog_m: [0.0; 3],
            }),
            ..RobotReading::default()
        };
        assert_eq!(Quantity::FlangeMass.read(&reading).0, Variant::from(2.5));
    }
}
