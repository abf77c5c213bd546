//! A payload's mass and centre of gravity identified from joint torques at rest or in slow
//! motion: gravity torques are linear in the payload's mass and first moment, so many poses give a
//! linear least-squares problem.
//!
//! Owns the gravity regressor's accumulation and the estimate with its standard deviation. Must
//! not choose samples: the caller hands in only quasi-static, position-controlled ones (in
//! freedrive a UR's currents follow the *configured* payload, so they identify nothing), and the
//! torque left once the arm's own model is subtracted. Streaming, fixed-size, no allocation: the
//! same accumulator serves a recording and a live robot.
//!
//! An answer is physical or it is none: the mass is never negative and the centre of gravity lies
//! within the tool's reach; poses that do not tell the parameters apart (the regressor's
//! condition number) give [`PayloadIdentification::NotIdentifiable`], an answer in its own right.

use nalgebra::{Matrix4, Vector4};

use super::ArmDynamics;

/// Joint speed (rad/s) below which every joint must be for a sample to count as at rest: at
/// rest a position-controlled arm's torques are gravity's alone.
pub const AT_REST_RAD_S: f64 = 0.01;

/// Joint acceleration (rad/s²) below which every joint must be, where the source gives one, for
/// a sample to count as at rest: a motion starting or stopping passes through zero speed with
/// its full acceleration, whose inertial torques are no payload's gravity.
pub const AT_REST_RAD_S2: f64 = 0.1;

/// Distance (m) from the flange within which a payload's centre of gravity must lie unless the
/// caller says otherwise: farther than any tool a 3–30 kg arm carries, so an estimate beyond it
/// is the fit trading mass against lever arm, not a payload.
pub const DEFAULT_REACH_M: f64 = 0.5;

/// Largest condition number of the column-scaled regressor the parameters are identified from:
/// beyond it, a torque error of 1 % moves some parameter by more than its whole size.
pub const MAX_CONDITION: f64 = 100.0;

/// Accumulates `Yᵀ Y` and `Yᵀ τ` of the gravity regressor
/// ([`ArmDynamics::payload_gravity_regressor`]) over samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PayloadIdentifier {
    normal: Matrix4<f64>,
    projected: Vector4<f64>,
    torque_sum_squares: f64,
    /// Equations taken, each weighted by what forgetting left of it.
    equations: f64,
    samples: usize,
}

/// An identified payload.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PayloadEstimate {
    /// Mass (kg).
    pub mass_kg: f64,
    /// Centre of gravity (m) in the flange frame; `None` unless the mass is positive.
    pub cog_flange_m: Option<[f64; 3]>,
    /// Standard deviation of `mass_kg` (kg), from the fit's residual and the poses' spread.
    pub mass_std_kg: f64,
    /// Samples used.
    pub samples: usize,
    /// Whether the centre of gravity was identified too; else the poses fixed the mass only, with
    /// the centre of gravity assumed (the configured one).
    pub cog_identified: bool,
    /// Condition number of the column-scaled regressor: how well the poses tell mass and centre
    /// of gravity apart (1 is ideal; above [`MAX_CONDITION`] there is no estimate).
    pub condition: f64,
}

/// Why the poses taken give no payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NotIdentifiableReason {
    /// Fewer equations than parameters, or a parameter no pose moves.
    TooFewPoses,
    /// The poses do not tell the parameters apart (condition number above [`MAX_CONDITION`]).
    PosesAlike,
    /// The least-squares answer is no payload: a mass significantly below zero, or a centre of
    /// gravity beyond the reach (torques the arm model misses, not a payload's).
    Unphysical,
}

impl NotIdentifiableReason {
    /// The wire name.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::TooFewPoses => "too_few_poses",
            Self::PosesAlike => "poses_alike",
            Self::Unphysical => "unphysical",
        }
    }
}

/// What the poses taken say of the payload.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PayloadIdentification {
    /// A physical estimate.
    Identified(PayloadEstimate),
    /// Not identifiable from this motion.
    NotIdentifiable {
        /// Why.
        reason: NotIdentifiableReason,
        /// The condition number of the column-scaled regressor (infinite when singular).
        condition: f64,
        /// Samples taken.
        samples: usize,
    },
}

impl PayloadIdentification {
    /// The estimate, if there is one.
    #[must_use]
    pub fn estimate(self) -> Option<PayloadEstimate> {
        match self {
            Self::Identified(estimate) => Some(estimate),
            Self::NotIdentifiable { .. } => None,
        }
    }
}

impl Default for PayloadIdentifier {
    fn default() -> Self {
        Self::new()
    }
}

impl PayloadIdentifier {
    /// No samples yet.
    #[must_use]
    pub fn new() -> Self {
        Self {
            normal: Matrix4::zeros(),
            projected: Vector4::zeros(),
            torque_sum_squares: 0.0,
            equations: 0.0,
            samples: 0,
        }
    }

    /// Adds one quasi-static sample: joint angles `q_rad` and `tau_payload_nm`, the joint torques
    /// beyond the arm's own model without payload (measured minus
    /// [`ArmDynamics::inverse_dynamics_nm`] of `dynamics` with [`super::Payload::NONE`]).
    pub fn add_static_sample<const N: usize>(
        &mut self,
        dynamics: &ArmDynamics<N>,
        q_rad: &[f64; N],
        tau_payload_nm: &[f64; N],
    ) {
        let regressor = dynamics.payload_gravity_regressor(q_rad);
        for (row, tau) in regressor.iter().zip(tau_payload_nm) {
            let row = Vector4::from(*row);
            self.normal += row * row.transpose();
            self.projected += row * *tau;
            self.torque_sum_squares += tau * tau;
        }
        self.equations += N as f64;
        self.samples += 1;
    }

    /// Scales everything taken so far by `keep` (in `(0, 1]`): exponential forgetting, so that a
    /// live estimate follows a payload that changed. `samples` still counts every sample.
    pub fn forget(&mut self, keep: f64) {
        self.normal *= keep;
        self.projected *= keep;
        self.torque_sum_squares *= keep;
        self.equations *= keep;
    }

    /// The payload, if the poses identify one within [`DEFAULT_REACH_M`] (a centre of gravity
    /// they cannot place is assumed at the flange).
    #[must_use]
    pub fn estimate(&self) -> Option<PayloadEstimate> {
        self.identify(DEFAULT_REACH_M, [0.0; 3]).estimate()
    }

    /// The least-squares payload constrained to physics: a mass below zero but within three
    /// standard deviations of it is no payload (0 kg); one significantly below zero is not
    /// identifiable. A centre of gravity farther than `reach_m` from the flange is the fit
    /// trading lever arm against torques the arm model misses (wrist friction at rest dwarfs a
    /// tool's few centimetres): the mass is then fitted alone with the centre of gravity at
    /// `assumed_cog_m` (the configured one), and reported so.
    #[must_use]
    pub fn identify(&self, reach_m: f64, assumed_cog_m: [f64; 3]) -> PayloadIdentification {
        let not_identifiable = |reason, condition| PayloadIdentification::NotIdentifiable {
            reason,
            condition,
            samples: self.samples,
        };
        let diagonal = self.normal.diagonal();
        if self.equations <= 4.0 || diagonal.iter().any(|d| *d <= 0.0) {
            return not_identifiable(NotIdentifiableReason::TooFewPoses, f64::INFINITY);
        }
        // The columns have different units (N·m per kg, per kg·m): scale them to unit norm so
        // that the condition number measures the poses, not the units.
        let scale = diagonal.map(|d| 1.0 / d.sqrt());
        let scaled = Matrix4::from_fn(|i, j| self.normal[(i, j)] * scale[i] * scale[j]);
        let eigenvalues = scaled.symmetric_eigen().eigenvalues;
        let condition = if eigenvalues.min() > 0.0 {
            (eigenvalues.max() / eigenvalues.min()).sqrt()
        } else {
            f64::INFINITY
        };
        if condition > MAX_CONDITION {
            return not_identifiable(NotIdentifiableReason::PosesAlike, condition);
        }
        let Some(inverse) = self.normal.try_inverse() else {
            return not_identifiable(NotIdentifiableReason::PosesAlike, condition);
        };
        let x = inverse * self.projected;
        let residual_sum_squares = (self.torque_sum_squares - x.dot(&self.projected)).max(0.0);
        let variance = residual_sum_squares / (self.equations - 4.0);
        let mass_std_kg = (variance * inverse[(0, 0)]).sqrt();
        let mass_kg = x[0];
        if mass_kg + 3.0 * mass_std_kg < 0.0 {
            return not_identifiable(NotIdentifiableReason::Unphysical, condition);
        }
        if mass_kg <= 3.0 * mass_std_kg {
            // A mass indistinguishable from none has no centre of gravity to speak of.
            return PayloadIdentification::Identified(PayloadEstimate {
                mass_kg: mass_kg.max(0.0),
                cog_flange_m: None,
                mass_std_kg,
                samples: self.samples,
                cog_identified: false,
                condition,
            });
        }
        let cog = [x[1] / mass_kg, x[2] / mass_kg, x[3] / mass_kg];
        if cog.iter().map(|c| c * c).sum::<f64>().sqrt() <= reach_m {
            return PayloadIdentification::Identified(PayloadEstimate {
                mass_kg,
                cog_flange_m: Some(cog),
                mass_std_kg,
                samples: self.samples,
                cog_identified: true,
                condition,
            });
        }
        // The mass alone: its regressor column is `a = [1, c]` against the parameters.
        let a = Vector4::new(1.0, assumed_cog_m[0], assumed_cog_m[1], assumed_cog_m[2]);
        let normal = a.dot(&(self.normal * a));
        if normal <= 0.0 {
            return not_identifiable(NotIdentifiableReason::Unphysical, condition);
        }
        let projected = a.dot(&self.projected);
        let mass_kg = projected / normal;
        let residual_sum_squares = (self.torque_sum_squares - mass_kg * projected).max(0.0);
        let mass_std_kg = (residual_sum_squares / (self.equations - 1.0) / normal).sqrt();
        if mass_kg + 3.0 * mass_std_kg < 0.0 {
            return not_identifiable(NotIdentifiableReason::Unphysical, condition);
        }
        PayloadIdentification::Identified(PayloadEstimate {
            mass_kg: mass_kg.max(0.0),
            cog_flange_m: (mass_kg > 3.0 * mass_std_kg).then_some(assumed_cog_m),
            mass_std_kg,
            samples: self.samples,
            cog_identified: false,
            condition,
        })
    }
}
