//! Decoded input samples, as the pipeline receives them from any source (Zenoh, CSV, FMU), and
//! the joint state a controller reports beside the angles.

use smallvec::SmallVec;

use crate::kinematics::PoseReadout;

/// Joint angles (rad) of one sample: held inline up to eight joints (every catalog arm, and a
/// gripper beside it), so decoding a sample allocates nothing; longer chains spill to the heap.
pub type JointAngles = SmallVec<[f64; 8]>;

/// One joint-angle sample of one robot.
#[derive(Debug, Clone, PartialEq)]
pub struct JointSample {
    /// Source time (s); `None` when the message had none (the transport supplies one).
    pub stamp_s: Option<f64>,
    /// The gateway's own sequence number, if it sent one.
    pub seq: Option<u64>,
    /// Joint angles (rad), already converted from degrees where the message said so.
    pub q_rad: JointAngles,
    /// The controller's measured TCP pose from the same packet (RTDE sends both together); its
    /// stamp is the joint sample's.
    pub measured: Option<PoseReadout>,
    /// What else the source read of the joints in the same packet (velocities, currents,
    /// temperatures, modes, payload), if anything. Boxed: most sources send none, and a sample
    /// stays small on the path every message takes.
    pub state: Option<Box<JointState>>,
}

/// One measured TCP pose of one robot, in the frame its source reports (the robot's `base` frame
/// for `…/measured/<robot>`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasuredSample {
    /// Source time (s); `None` when the message had none.
    pub stamp_s: Option<f64>,
    /// The pose: position, normalised canonical quaternion, and roll/pitch/yaw derived from it.
    pub pose: PoseReadout,
}

/// A per-joint quantity a controller may report beside the angles, in the wire order of
/// [`JointState`] (JSON `state` fields, the binary `armtwin/joints/v2` sequences).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum JointQuantity {
    /// Actual joint velocity (rad/s).
    Velocity,
    /// The controller's target angle (rad).
    TargetPosition,
    /// Target velocity (rad/s).
    TargetVelocity,
    /// Target acceleration (rad/s²).
    TargetAcceleration,
    /// Actual motor current (A).
    Current,
    /// Target motor current (A).
    TargetCurrent,
    /// Measured joint torque (Nm): a torque sensor's, or currents the source converted.
    Torque,
    /// The controller's model torque for the target state (Nm; UR RTDE `target_moment`).
    TargetTorque,
    /// Joint temperature (°C).
    Temperature,
}

impl JointQuantity {
    /// Every quantity, in wire order.
    pub const ALL: [Self; 9] = [
        Self::Velocity,
        Self::TargetPosition,
        Self::TargetVelocity,
        Self::TargetAcceleration,
        Self::Current,
        Self::TargetCurrent,
        Self::Torque,
        Self::TargetTorque,
        Self::Temperature,
    ];

    /// The field's name on the wire (JSON and binary) and in the state answer.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Velocity => "qd",
            Self::TargetPosition => "target_q",
            Self::TargetVelocity => "target_qd",
            Self::TargetAcceleration => "target_qdd",
            Self::Current => "current_a",
            Self::TargetCurrent => "target_current_a",
            Self::Torque => "torque_nm",
            Self::TargetTorque => "target_torque_nm",
            Self::Temperature => "temperature_c",
        }
    }

    /// The quantity named `name` on the wire.
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|quantity| quantity.name() == name)
    }

    fn bit(self) -> u16 {
        1 << self as u16
    }
}

/// The controller's modes and status in the packet (UR RTDE `robot_mode`, `safety_mode`,
/// `robot_status_bits`, `speed_scaling`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControllerStatus {
    /// Robot mode (UR: −1 no controller … 7 running, 8 updating firmware).
    pub robot_mode: i32,
    /// Safety mode (UR: 1 normal, 2 reduced, 3 protective stop, … 11 automatic mode safeguard stop).
    pub safety_mode: i32,
    /// Status bits (UR: bit 0 power on, bit 1 program running, bit 2 teach button pressed,
    /// bit 3 power button pressed).
    pub status_bits: u32,
    /// The controller's speed scaling (fraction, 0 to 1).
    pub speed_scaling: f64,
}

impl ControllerStatus {
    /// The bit of RTDE `robot_status_bits` set while the teach button is pressed.
    pub const TEACH_BUTTON_BIT: u32 = 2;

    /// The arm is powered.
    #[must_use]
    pub fn power_on(&self) -> bool {
        self.status_bits & 1 != 0
    }

    /// A program is running.
    #[must_use]
    pub fn program_running(&self) -> bool {
        self.status_bits & 2 != 0
    }

    /// The teach button is held: the arm is in freedrive, moved by hand.
    #[must_use]
    pub fn freedrive(&self) -> bool {
        self.status_bits & (1 << Self::TEACH_BUTTON_BIT) != 0
    }
}

/// The payload the controller is configured with: mass, centre of gravity and optionally
/// inertia, in the flange frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Payload {
    /// Mass (kg).
    pub mass_kg: f64,
    /// Centre of gravity in the flange frame (m).
    pub cog_m: [f64; 3],
    /// Inertia about the centre of gravity, flange axes (kg·m²): `Ixx, Iyy, Izz, Ixy, Ixz, Iyz`.
    pub inertia_kg_m2: Option<[f64; 6]>,
}

/// What a controller reports of its joints beside their angles, read in the same packet. Every
/// part is optional: UR's RTDE gives all of it, a ROS 2 `JointState` velocity and effort, most
/// gateways nothing. Per-joint values are stored only for the quantities present, in one
/// allocation.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct JointState {
    joint_count: usize,
    /// Which quantities are present: bit `quantity as u16`.
    present: u16,
    /// `joint_count` values per present quantity, in [`JointQuantity::ALL`] order.
    values: Vec<f64>,
    /// Modes and status bits.
    pub status: Option<ControllerStatus>,
    /// The configured payload.
    pub payload: Option<Payload>,
}

impl JointState {
    /// An empty state of an arm with `joint_count` joints.
    #[must_use]
    pub fn new(joint_count: usize) -> Self {
        Self {
            joint_count,
            ..Self::default()
        }
    }

    /// The arm's joint count.
    #[must_use]
    pub fn joint_count(&self) -> usize {
        self.joint_count
    }

    /// Nothing is present.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.present == 0 && self.status.is_none() && self.payload.is_none()
    }

    /// Where `quantity`'s values start in `values`, present or not.
    fn offset(&self, quantity: JointQuantity) -> usize {
        (self.present & (quantity.bit() - 1)).count_ones() as usize * self.joint_count
    }

    /// One value per joint of `quantity`, if present.
    #[must_use]
    pub fn get(&self, quantity: JointQuantity) -> Option<&[f64]> {
        if self.present & quantity.bit() == 0 {
            return None;
        }
        let start = self.offset(quantity);
        self.values.get(start..start + self.joint_count)
    }

    /// Sets `quantity` to `values`; `false`, and nothing set, unless there is one value per joint.
    pub fn set(&mut self, quantity: JointQuantity, values: &[f64]) -> bool {
        if values.len() != self.joint_count {
            return false;
        }
        let start = self.offset(quantity);
        if self.present & quantity.bit() == 0 {
            self.values.splice(start..start, values.iter().copied());
            self.present |= quantity.bit();
        } else {
            self.values[start..start + self.joint_count].copy_from_slice(values);
        }
        true
    }

    /// The quantities present with their values, in wire order.
    pub fn quantities(&self) -> impl Iterator<Item = (JointQuantity, &[f64])> {
        JointQuantity::ALL
            .into_iter()
            .filter_map(|quantity| Some((quantity, self.get(quantity)?)))
    }

    /// Takes what `newer` has over what this holds, keeping the rest: the latest of each part.
    /// A state of another joint count replaces this one whole.
    pub fn update_from(&mut self, newer: &Self) {
        if newer.joint_count != self.joint_count {
            self.clone_from(newer);
            return;
        }
        if newer.present | self.present == self.present {
            // The usual case, the same parts as before: copied in place.
            for (quantity, values) in newer.quantities() {
                let start = self.offset(quantity);
                self.values[start..start + self.joint_count].copy_from_slice(values);
            }
        } else {
            for (quantity, values) in newer.quantities() {
                self.set(quantity, values);
            }
        }
        if newer.status.is_some() {
            self.status = newer.status;
        }
        if newer.payload.is_some() {
            self.payload = newer.payload;
        }
    }
}
