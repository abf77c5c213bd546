//! Each joint's friction, learnt live: a least-squares fit `coulomb · sign(q̇) + viscous · q̇`
//! with forgetting on moving program-mode samples, both coefficients constrained to be
//! non-negative (friction only ever opposes motion; an unconstrained fit on real drives trades a
//! negative viscous term against a large Coulomb one), and per temperature bin the first fit
//! good enough to be a wear baseline (the drift the summary shows is against it).
//!
//! Not modelled, because on real UR drives it did not pay (docs/load-twin.md): a separate fit per
//! direction and a Stribeck term each changed the residual by under 0.02 N·m RMS.

use super::Monitor;
use crate::dynamics::JointFriction;

/// Joint speed (rad/s) above which a sample tells the joint's friction apart from its sign.
const MOVING_RAD_S: f64 = 0.05;
/// Moving samples (weighted by forgetting) a joint's friction fit needs before it is used.
const MIN_FRICTION_WEIGHT: f64 = 200.0;
/// Moving samples (weighted) a joint's friction fit needs before it becomes a temperature bin's
/// baseline: a wear reference must not be a first rough fit.
const MIN_BASELINE_WEIGHT: f64 = 2000.0;
/// Temperature bins (°C) of the friction baselines: `[0, 5)`, `[5, 10)`, … `[95, 100)`, and one
/// for samples with no temperature.
const TEMPERATURE_BIN_C: f64 = 5.0;
pub(super) const TEMPERATURE_BINS: usize = 20;

/// A joint's friction fit `y = coulomb · sign(q̇) + viscous · q̇`, with forgetting.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct FrictionFit {
    /// Normal equations: Σ s·q̇, Σ q̇², Σ s·y, Σ q̇·y (s = sign(q̇)); Σ s² is `weight`, the
    /// samples taken (|s| = 1 on a moving sample), both forgotten alike.
    sv: f64,
    vv: f64,
    sy: f64,
    vy: f64,
    weight: f64,
}

impl FrictionFit {
    pub(super) fn forget(&mut self, keep: f64) {
        self.sv *= keep;
        self.vv *= keep;
        self.sy *= keep;
        self.vy *= keep;
        self.weight *= keep;
    }

    pub(super) fn add(&mut self, qd_rad_s: f64, torque_nm: f64) {
        let sign = qd_rad_s.signum();
        self.sv += sign * qd_rad_s;
        self.vv += qd_rad_s * qd_rad_s;
        self.sy += sign * torque_nm;
        self.vy += qd_rad_s * torque_nm;
        self.weight += 1.0;
    }

    /// The fitted friction, once enough motion in both directions and at several speeds is in:
    /// the non-negative least-squares solution of the 2×2 normal equations (the unconstrained
    /// one when it is physical, else the better of the two fits with one term at zero).
    pub(super) fn estimate(&self) -> Option<JointFriction> {
        if self.weight < MIN_FRICTION_WEIGHT {
            return None;
        }
        let det = self.weight * self.vv - self.sv * self.sv;
        if det <= 1e-9 * self.weight * self.vv {
            return None;
        }
        let free = JointFriction {
            coulomb_nm: (self.vv * self.sy - self.sv * self.vy) / det,
            viscous_nm_s_rad: (self.weight * self.vy - self.sv * self.sy) / det,
        };
        if free.coulomb_nm >= 0.0 && free.viscous_nm_s_rad >= 0.0 {
            return Some(free);
        }
        let coulomb_only = JointFriction {
            coulomb_nm: (self.sy / self.weight).max(0.0),
            viscous_nm_s_rad: 0.0,
        };
        let viscous_only = JointFriction {
            coulomb_nm: 0.0,
            viscous_nm_s_rad: (self.vy / self.vv).max(0.0),
        };
        Some(
            if self.squared_error(coulomb_only) <= self.squared_error(viscous_only) {
                coulomb_only
            } else {
                viscous_only
            },
        )
    }

    /// `Σ (y − f(q̇))²` up to the constant `Σ y²`, from the normal equations.
    fn squared_error(&self, friction: JointFriction) -> f64 {
        let (c, v) = (friction.coulomb_nm, friction.viscous_nm_s_rad);
        c * c * self.weight + 2.0 * c * v * self.sv + v * v * self.vv
            - 2.0 * (c * self.sy + v * self.vy)
    }
}

impl<const N: usize> Monitor<N> {
    /// Friction: fitted on moving program-mode samples (`measured − model`), used by the
    /// residual and the observer; `keep` is what forgetting leaves of the past.
    pub(super) fn learn_friction(
        &mut self,
        keep: f64,
        program: bool,
        qd: &[f64; N],
        measured_nm: &[f64; N],
        model_nm: &[f64; N],
    ) {
        for (k, fit) in self.friction.iter_mut().enumerate() {
            fit.forget(keep);
            if program && qd[k].abs() > MOVING_RAD_S {
                fit.add(qd[k], measured_nm[k] - model_nm[k]);
            }
            self.fitted[k] = fit.estimate();
        }
        self.update_baselines();
    }

    /// Keeps, per joint, the first friction fitted in each temperature bin.
    pub(super) fn update_baselines(&mut self) {
        for k in 0..N {
            if self.friction[k].weight < MIN_BASELINE_WEIGHT {
                continue;
            }
            let Some(JointFriction {
                coulomb_nm: coulomb,
                ..
            }) = self.fitted[k]
            else {
                continue;
            };
            let bin = temperature_bin(self.temperature_c[k]);
            let baseline = &mut self.baselines[k][bin];
            if baseline.is_none() {
                *baseline = Some(coulomb);
            }
        }
    }
}

#[allow(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    reason = "clamped to the bins first"
)]
pub(super) fn temperature_bin(temperature_c: Option<f64>) -> usize {
    match temperature_c {
        Some(t) if t.is_finite() => {
            ((t / TEMPERATURE_BIN_C)
                .floor()
                .clamp(0.0, (TEMPERATURE_BINS - 1) as f64)) as usize
        }
        _ => TEMPERATURE_BINS,
    }
}
