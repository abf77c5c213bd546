//! What the server reads of the fleet ([`TwinSource`]): the twinned robots' ids when a client
//! browses them, one robot's [`RobotReading`] (plain values in SI units, angles in radians) when
//! a client reads or monitors its nodes, and every robot's alarms at each sampling interval.
//!
//! Defined here, implemented by the service: this crate knows no twin, and the service's
//! sample path knows no OPC UA.

use std::sync::Arc;

/// The fleet, as the OPC UA server reads it.
pub trait TwinSource: Send + Sync + 'static {
    /// Every twinned robot's id, in any order. `ids` is cleared first.
    fn robot_ids(&self, ids: &mut Vec<Arc<str>>);

    /// Robot `id`'s reading, copied out now (the robot locked only while it is copied), if it
    /// is twinned.
    fn read_robot(&self, id: &str) -> Option<RobotReading>;

    /// Every twinned robot's alarms, each robot locked only while its flags are read, handed to
    /// `visit` in any order.
    fn read_alarms(&self, visit: &mut dyn FnMut(&Arc<str>, AlarmReading));
}

/// Which of a robot's alarms are on.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[expect(
    clippy::struct_excessive_bools,
    reason = "independent alarms, any of them on"
)]
pub struct AlarmReading {
    /// The position deviation alarm.
    pub position: bool,
    /// The orientation deviation alarm.
    pub angle: bool,
    /// A collision alarm on any joint.
    pub collision: bool,
    /// The identified payload differs from the modelled one.
    pub payload: bool,
}

/// One robot's state at the moment it was read.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RobotReading {
    /// The robot's id: its node's name.
    pub id: Arc<str>,
    /// The arm's model name (`ur10e`, or a custom arm's own).
    pub model: String,
    /// The arm's serial number, as its controller reports it (UR: the dashboard server's
    /// `get serial number`), once a gateway said it.
    pub serial_number: Option<String>,
    /// The arm's joint count.
    pub joint_count: usize,
    /// The newest source time of the robot (s).
    pub stamp_s: f64,
    /// The last joint angles (rad).
    pub positions_rad: Option<Vec<f64>>,
    /// The last joint velocities (rad/s).
    pub velocities_rad_s: Option<Vec<f64>>,
    /// The last joint temperatures (°C).
    pub temperatures_c: Option<Vec<f64>>,
    /// The last motor currents (A).
    pub currents_a: Option<Vec<f64>>,
    /// The last joint torques (N·m).
    pub torques_nm: Option<Vec<f64>>,
    /// The controller's modes, when reported.
    pub controller: Option<ControllerReading>,
    /// The payload the controller or the configuration reports (the flange's load).
    pub configured_payload: Option<PayloadReading>,
    /// The payload an operator applied from an identification.
    pub applied_payload: Option<PayloadReading>,
    /// The latest identified payload.
    pub identified_payload: Option<IdentifiedPayload>,
    /// The twin's last pose.
    pub twin_pose: Option<PoseReading>,
    /// Twin-vs-robot deviation since the start or the last reset.
    pub cumulative: DeviationStats,
    /// Twin-vs-robot deviation over the last window.
    pub window: DeviationStats,
    /// The window's length (s).
    pub window_s: f64,
    /// The position deviation alarm is on.
    pub position_alarm: bool,
    /// The orientation deviation alarm is on.
    pub angle_alarm: bool,
    /// Per joint, whether a collision alarm is on (empty unless effort is watched).
    pub collision: Vec<bool>,
    /// Collisions reported since the start.
    pub collisions: u64,
    /// Where the calibration in use came from (`nominal` without one).
    pub calibration: String,
}

/// The controller's modes (UR RTDE's meanings).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ControllerReading {
    /// Robot mode (UR: 7 running).
    pub robot_mode: i32,
    /// Safety mode (UR: 1 normal, 2 reduced, 3 protective stop, 4 recovery, 5 safeguard stop,
    /// 6 system emergency stop, 7 robot emergency stop, 8 violation, 9 fault, …).
    pub safety_mode: i32,
    /// The speed scaling (fraction, 0 to 1).
    pub speed_scaling: f64,
    /// A program runs.
    pub program_running: bool,
    /// The teach button is held (freedrive).
    pub freedrive: bool,
}

/// A payload: mass and centre of gravity in the flange frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PayloadReading {
    /// Mass (kg).
    pub mass_kg: f64,
    /// Centre of gravity in the flange frame (m).
    pub cog_m: [f64; 3],
}

/// An identified payload and its uncertainty.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct IdentifiedPayload {
    /// Mass (kg), as fitted: may be negative or insignificant.
    pub mass_kg: f64,
    /// Standard deviation of `mass_kg` (kg).
    pub mass_std_kg: f64,
    /// Samples used.
    pub samples: usize,
}

/// A pose: position and orientation.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PoseReading {
    /// `[x, y, z]` (m).
    pub position_m: [f64; 3],
    /// Unit quaternion `[qx, qy, qz, qw]`.
    pub quaternion_xyzw: [f64; 4],
}

/// Deviation statistics over one set of samples.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DeviationStats {
    /// Samples.
    pub samples: u64,
    /// Root mean square of the position deviation (m).
    pub position_rmse_m: f64,
    /// The largest position deviation (m).
    pub position_max_m: f64,
    /// Root mean square of the orientation deviation (rad).
    pub angle_rmse_rad: f64,
    /// The largest orientation deviation (rad).
    pub angle_max_rad: f64,
}
