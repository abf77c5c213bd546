//! What the effort monitor is told and what it shows: its settings and errors, the readout of
//! one sample, the summary (residual statistics, friction, payload, alarm states) and the alarm
//! changes. Types only; the monitor and its parts fill them.

use super::ThresholdSource;
use crate::dynamics::payload::{PayloadEstimate, PayloadIdentification};
use crate::dynamics::{ControllerMode, DynamicsError, Payload};

/// How a robot's effort is watched.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EffortConfig {
    /// The momentum observer's gain `K` (1/s): its time constant is `1/K`.
    pub observer_gain_per_s: f64,
    /// Per joint, the observer output (N·m) beyond which a collision is reported; `None` to
    /// learn them from the arm's normal motion, never below a share
    /// ([`ur::DEFAULT_COLLISION_SHARE`](crate::dynamics::ur::DEFAULT_COLLISION_SHARE)) of its
    /// rated torques.
    pub collision_threshold_nm: Option<JointValues<f64>>,
    /// Per joint, the largest torque its drive gives (N·m), where the arm's description states
    /// none or states it otherwise: a URDF's `<limit effort>`, Universal Robots' joint sizes.
    pub rated_torque_nm: Option<JointValues<f64>>,
    /// Per joint, the factor from motor current to joint torque (N·m/A), for arms that report
    /// currents rather than torques and whose factors the catalog does not know (or to give a
    /// robot's own).
    pub current_to_torque_nm_per_a: Option<JointValues<f64>>,
    /// Per joint, the drive's rotor inertia seen at the joint (kg·m²), where the arm's
    /// description states none (a URDF) or states it otherwise.
    pub reflected_rotor_inertia_kg_m2: Option<JointValues<f64>>,
    /// Seconds of armed program-mode motion the thresholds are learnt from (0: the rated-torque
    /// share, unlearnt).
    pub threshold_learning_s: f64,
    /// Learnt thresholds are this times the 99.9th percentile of the normal motion's output.
    pub threshold_factor: f64,
    /// Distance (m) from the flange within which an identified payload's centre of gravity must
    /// lie to count.
    pub payload_reach_m: f64,
    /// Identified minus modelled payload mass (kg) beyond which a mismatch is reported.
    pub payload_tolerance_kg: f64,
    /// Time constant (s) of the payload identifier's forgetting.
    pub payload_window_s: f64,
    /// Time constant (s) of the friction fits' forgetting.
    pub friction_window_s: f64,
    /// Time constant (s) of each joint's observer baseline: a collision is the observer leaving
    /// its baseline, so that what changes slowly (a payload heavier than modelled, friction not
    /// yet learned) raises none while an impact, over in milliseconds, does.
    pub collision_baseline_s: f64,
    /// The payload modelled while the robot's own messages name none.
    pub payload: Option<Payload>,
}

impl Default for EffortConfig {
    fn default() -> Self {
        Self {
            observer_gain_per_s: 50.0,
            collision_threshold_nm: None,
            rated_torque_nm: None,
            current_to_torque_nm_per_a: None,
            reflected_rotor_inertia_kg_m2: None,
            threshold_learning_s: 60.0,
            threshold_factor: 2.0,
            payload_reach_m: crate::dynamics::payload::DEFAULT_REACH_M,
            payload_tolerance_kg: 0.5,
            payload_window_s: 300.0,
            friction_window_s: 600.0,
            collision_baseline_s: 1.0,
            payload: None,
        }
    }
}

/// Why an arm's effort cannot be watched.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EffortError {
    /// Its dynamics cannot be built.
    #[error(transparent)]
    Dynamics(#[from] DynamicsError),
    /// No collision thresholds are configured and the arm has no default.
    #[error(
        "arm '{model}' has no rated torques to derive collision thresholds from (no joint sizes \
         published, no effort limits in its URDF): set collision_threshold_nm or rated_torque_nm"
    )]
    NoThresholds {
        /// The arm.
        model: String,
    },
    /// The arm has a joint count the monitor is not built for.
    #[error(
        "the load twin watches arms of {min} to {max} joints; this one has {joints}",
        min = super::MIN_EFFORT_JOINTS,
        max = MAX_EFFORT_JOINTS
    )]
    JointCount {
        /// The arm's joints.
        joints: usize,
    },
    /// A per-joint setting has another length than the arm's joint count.
    #[error("{field} has {got} values; the arm has {expected} joints")]
    JointValues {
        /// The setting.
        field: &'static str,
        /// The arm's joint count.
        expected: usize,
        /// The setting's.
        got: usize,
    },
    /// A setting is out of range.
    #[error("{field} = {value} must be a positive number")]
    Setting {
        /// The setting.
        field: &'static str,
        /// Its value.
        value: f64,
    },
}

/// Which state the model's torques are computed for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StateSource {
    /// The controller's target state (q, q̇, q̈), as its own torque model uses.
    Target,
    /// The actual state, q̈ (and q̇ when absent) from differences.
    Actual,
}

impl StateSource {
    /// The wire name.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Target => "target",
            Self::Actual => "actual",
        }
    }
}

/// What the collision detector watches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DetectionSource {
    /// The momentum observer on measured torques less the model and the fitted friction.
    #[default]
    Observer,
    /// Measured less target motor current (the controller's own model, friction feed-forward
    /// included) through the drives' torque factors, low-passed like the observer.
    TargetCurrent,
}

impl DetectionSource {
    /// The wire name.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Observer => "observer",
            Self::TargetCurrent => "target_current",
        }
    }
}

/// Where the modelled payload comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PayloadSource {
    /// None is known: no payload.
    None,
    /// The robot's configuration.
    Config,
    /// The controller's own, sent with the joint state.
    Controller,
    /// An identified payload an operator applied.
    Applied,
}

impl PayloadSource {
    /// The wire name.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Config => "config",
            Self::Controller => "controller",
            Self::Applied => "applied",
        }
    }
}

/// One joint sample's effort.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EffortReadout {
    /// The sample's stamp (s).
    pub stamp_s: f64,
    /// What the controller's torque model contains now.
    pub mode: ControllerMode,
    /// The state the model ran on.
    pub state_source: StateSource,
    /// The model's torques (N·m): like the controller's own (rigid body and rotor inertia in a
    /// program, gravity in freedrive), with the payload in use.
    pub model_nm: JointValues<f64>,
    /// The drives' torques (N·m): reported torques, else currents times the arm's torque factors.
    pub measured_nm: Option<JointValues<f64>>,
    /// `measured − model − friction` (N·m), friction as fitted so far.
    pub residual_nm: Option<JointValues<f64>>,
    /// The momentum observer's estimate of the same (N·m), low-passed by `1/K`; `None` until it
    /// has a measured torque and a velocity.
    pub observer_nm: Option<JointValues<f64>>,
}

/// Residual statistics per joint.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ResidualStats {
    /// Samples counted.
    pub n: u64,
    /// Root mean square (N·m).
    pub rms_nm: JointValues<f64>,
    /// Largest magnitude (N·m).
    pub max_nm: JointValues<f64>,
}

/// One joint's friction as fitted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrictionReadout {
    /// Coulomb friction (N·m).
    pub coulomb_nm: f64,
    /// Viscous friction (N·m·s/rad).
    pub viscous_nm_s_rad: f64,
    /// The joint's latest temperature (°C).
    pub temperature_c: Option<f64>,
    /// The Coulomb friction first fitted at this temperature (N·m): the wear signal's reference.
    pub baseline_coulomb_nm: Option<f64>,
    /// `coulomb_nm − baseline_coulomb_nm`: friction grown at the same temperature.
    pub drift_nm: Option<f64>,
}

/// The payload: configured, identified, applied, in use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PayloadReadout {
    /// What the controller or the configuration says, and which.
    pub configured: Option<(Payload, PayloadSource)>,
    /// The latest physical estimate.
    pub estimate: Option<PayloadEstimate>,
    /// The latest identification: an estimate, or why the motion so far identifies none.
    pub identification: Option<PayloadIdentification>,
    /// An identified payload an operator applied.
    pub applied: Option<Payload>,
    /// The one the model uses, and where it comes from.
    pub in_use: (Payload, PayloadSource),
}

/// Everything the monitor shows of a robot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EffortSummary {
    /// The latest sample's readout.
    pub latest: Option<EffortReadout>,
    /// Residuals (program mode) since the start or the last reset.
    pub cumulative: ResidualStats,
    /// Residuals over the last window.
    pub window: ResidualStats,
    /// The window's length (s).
    pub window_s: f64,
    /// Per joint, its friction once fitted.
    pub friction: JointValues<Option<FrictionReadout>>,
    /// The payload.
    pub payload: PayloadReadout,
    /// Per joint, the collision threshold (N·m).
    pub collision_threshold_nm: JointValues<f64>,
    /// Where the thresholds come from.
    pub threshold_source: ThresholdSource,
    /// What the collision detector watches.
    pub detection: DetectionSource,
    /// Per joint, whether a collision alarm is on.
    pub collision: JointValues<bool>,
    /// Collisions reported since the start.
    pub collisions: u64,
    /// Whether a payload mismatch is reported.
    pub payload_mismatch: bool,
}

/// A change of an effort alarm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EffortAlarm {
    /// A joint's observer output left its baseline by more than its threshold (`on`), or came
    /// back within half of it.
    Collision {
        /// The joint, from 0.
        joint: usize,
        /// The observer's output less its baseline (N·m).
        value_nm: f64,
        /// The threshold (N·m).
        threshold_nm: f64,
        /// Raised or cleared.
        on: bool,
    },
    /// The identified payload left the modelled one by more than the tolerance (`on`), or came
    /// back within it.
    Payload {
        /// Identified mass (kg).
        estimated_kg: f64,
        /// Its standard deviation (kg).
        std_kg: f64,
        /// The mass the model uses (kg).
        modelled_kg: f64,
        /// The tolerance (kg).
        tolerance_kg: f64,
        /// Raised or cleared.
        on: bool,
    },
}

/// The most joints an effort monitor watches (seven-joint arms: a Panda, an iiwa, an xArm7).
pub const MAX_EFFORT_JOINTS: usize = 7;

/// One value per joint of an arm the monitor watches, without an allocation: a slice of up to
/// [`MAX_EFFORT_JOINTS`] (it dereferences to the arm's joints only).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointValues<T> {
    values: [T; MAX_EFFORT_JOINTS],
    len: u8,
}

impl<T: Copy + Default> JointValues<T> {
    /// The values of an arm of `N` joints (`N` at most [`MAX_EFFORT_JOINTS`]).
    #[must_use]
    pub fn from_array<const N: usize>(values: [T; N]) -> Self {
        const { assert!(N <= MAX_EFFORT_JOINTS) };
        let mut all = [T::default(); MAX_EFFORT_JOINTS];
        all[..N].copy_from_slice(&values);
        Self {
            values: all,
            #[allow(clippy::cast_possible_truncation, reason = "at most MAX_EFFORT_JOINTS")]
            len: N as u8,
        }
    }

    /// `values` if there are at most [`MAX_EFFORT_JOINTS`].
    #[must_use]
    pub fn from_slice(values: &[T]) -> Option<Self> {
        let len = u8::try_from(values.len())
            .ok()
            .filter(|n| usize::from(*n) <= MAX_EFFORT_JOINTS)?;
        let mut all = [T::default(); MAX_EFFORT_JOINTS];
        all[..values.len()].copy_from_slice(values);
        Some(Self { values: all, len })
    }

    /// The values as an arm of `N` joints' array, if there are `N`.
    #[must_use]
    pub fn to_array<const N: usize>(&self) -> Option<[T; N]> {
        <[T; N]>::try_from(&**self).ok()
    }
}

impl<T: Copy + Default> Default for JointValues<T> {
    fn default() -> Self {
        Self {
            values: [T::default(); MAX_EFFORT_JOINTS],
            len: 0,
        }
    }
}

impl<T> std::ops::Deref for JointValues<T> {
    type Target = [T];

    fn deref(&self) -> &[T] {
        &self.values[..usize::from(self.len)]
    }
}

impl<T: serde::Serialize> serde::Serialize for JointValues<T> {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        (**self).serialize(serializer)
    }
}

impl<'a, T> IntoIterator for &'a JointValues<T> {
    type Item = &'a T;
    type IntoIter = std::slice::Iter<'a, T>;

    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}
