//! A payload's mass and centre of gravity identified from joint torques at rest or in slow
//! motion: gravity torques are linear in the payload's mass and first moment, so many poses give a
//! linear least-squares problem.
//!
//! Owns the gravity regressor's accumulation and the estimate with its standard deviation. Must
//! not choose samples: the caller hands in only quasi-static, position-controlled ones (in
//! freedrive a UR's currents follow the *configured* payload, so they identify nothing), and the
//! torque left once the arm's own model is subtracted. Streaming, fixed-size, no allocation: the
//! same accumulator serves a recording and a live robot.

use nalgebra::{Matrix4, Vector4};

use super::ArmDynamics;

/// Joint speed (rad/s) below which every joint must be for a sample to count as at rest: at
/// rest a position-controlled arm's torques are gravity's alone.
pub const AT_REST_RAD_S: f64 = 0.01;

/// Joint acceleration (rad/s²) below which every joint must be, where the source gives one, for
/// a sample to count as at rest: a motion starting or stopping passes through zero speed with
/// its full acceleration, whose inertial torques are no payload's gravity.
pub const AT_REST_RAD_S2: f64 = 0.1;

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

    /// The least-squares payload, or `None` while the poses do not determine it (too few, or all
    /// alike: the normal equations are singular).
    #[must_use]
    pub fn estimate(&self) -> Option<PayloadEstimate> {
        if self.equations <= 4.0 {
            return None;
        }
        // Poses that leave a parameter undetermined (all alike, or a joint never turned) make the
        // normal matrix singular to rounding: refuse rather than invert noise.
        let eigenvalues = self.normal.symmetric_eigen().eigenvalues;
        if eigenvalues.min() <= 1e-10 * eigenvalues.max() {
            return None;
        }
        let inverse = self.normal.try_inverse()?;
        let x = inverse * self.projected;
        let residual_sum_squares = (self.torque_sum_squares - x.dot(&self.projected)).max(0.0);
        let variance = residual_sum_squares / (self.equations - 4.0);
        let mass_kg = x[0];
        let cog_flange_m =
            (mass_kg > 0.0).then(|| [x[1] / mass_kg, x[2] / mass_kg, x[3] / mass_kg]);
        Some(PayloadEstimate {
            mass_kg,
            cog_flange_m,
            mass_std_kg: (variance * inverse[(0, 0)]).sqrt(),
            samples: self.samples,
        })
    }
}
