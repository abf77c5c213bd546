//! The momentum observer: an estimate of what the drives spend beyond the model, without
//! differentiating anything (the sign convention is in the module's documentation), and the
//! collision alarms on it, armed once it has settled and measured against a slow baseline.
//! Where the controller sends its target current, the observer's place is taken by the
//! measured-minus-target torque low-passed with the same time constant `1/K`: the controller's
//! model already holds the dynamics the observer would integrate.

use super::{DetectionSource, EffortAlarm, Monitor};
use crate::dynamics::ControllerMode;

/// Observer time constants (`1/K`) of steady program-mode input before its alarms are armed:
/// it starts from zero and needs a few to settle.
const ARMING_TIME_CONSTANTS: f64 = 5.0;

/// The momentum observer's state.
#[derive(Debug, Clone, Copy)]
pub(super) struct Observer<const N: usize> {
    /// `p(0) + ∫ (…) dt`: what the momentum would be without external torques.
    pub(super) expected_nms: [f64; N],
    /// Its output `r`.
    pub(super) r_nm: [f64; N],
    /// Per joint, the output low-passed by `collision_baseline_s`, held while the joint's
    /// collision alarm is on (in the readout's sign).
    pub(super) baseline_nm: [f64; N],
    /// Stamp of the last step.
    pub(super) last_s: Option<f64>,
    /// Alarms are armed from this stamp on.
    pub(super) armed_from_s: f64,
    /// What it watches: a change starts it afresh.
    pub(super) source: DetectionSource,
}

impl<const N: usize> Default for Observer<N> {
    fn default() -> Self {
        Self {
            expected_nms: [0.0; N],
            r_nm: [0.0; N],
            baseline_nm: [0.0; N],
            last_s: None,
            armed_from_s: 0.0,
            source: DetectionSource::default(),
        }
    }
}

impl<const N: usize> Monitor<N> {
    /// One observer step; returns its output in the residual's sign.
    #[allow(clippy::too_many_arguments, reason = "one sample's parts, named")]
    pub(super) fn observe(
        &mut self,
        stamp_s: f64,
        step_s: Option<f64>,
        mode: ControllerMode,
        q: &[f64; N],
        qd: &[f64; N],
        measured_nm: &[f64; N],
        friction_nm: &[f64; N],
        drive_residual_nm: Option<&[f64; N]>,
        on_alarm: &mut impl FnMut(EffortAlarm),
    ) -> [f64; N] {
        let gain = self.config.observer_gain_per_s;
        let source = drive_residual_nm.map_or(DetectionSource::Observer, |_| {
            DetectionSource::TargetCurrent
        });
        let observer = &mut self.observer;
        let continues = observer.last_s.is_some() && step_s.is_some() && observer.source == source;
        observer.source = source;
        if continues && let Some(dt) = step_s {
            if let Some(drive_residual) = drive_residual_nm {
                // The same first-order lag the observer has, implicit: stable for any K·dt.
                let follow = gain * dt / (1.0 + gain * dt);
                for (r, residual) in observer.r_nm.iter_mut().zip(drive_residual) {
                    *r += follow * (-residual - *r);
                }
            } else {
                let terms = self.loaded.momentum(q, qd);
                let gravity_nm = self.loaded.gravity_nm(q);
                for k in 0..N {
                    let drive = measured_nm[k] - friction_nm[k];
                    let partial = observer.expected_nms[k]
                        + (drive + terms.coriolis_transpose_qd_nm[k] - gravity_nm[k]) * dt;
                    // Implicit in r: stable for any K·dt.
                    let r = gain * (terms.momentum_nms[k] - partial) / (1.0 + gain * dt);
                    observer.expected_nms[k] = partial + r * dt;
                    observer.r_nm[k] = r;
                }
            }
        } else {
            observer.expected_nms = self.loaded.momentum(q, qd).momentum_nms;
            observer.r_nm = [0.0; N];
            observer.baseline_nm = [0.0; N];
            observer.armed_from_s = stamp_s + ARMING_TIME_CONSTANTS / gain;
        }
        observer.last_s = Some(stamp_s);
        if mode == ControllerMode::Freedrive {
            // A person moves the arm: that is the point, not a collision.
            observer.armed_from_s = stamp_s + ARMING_TIME_CONSTANTS / gain;
        }
        let output: [f64; N] = observer.r_nm.map(|r| -r);
        let armed = stamp_s >= observer.armed_from_s;
        let follow = step_s.map_or(1.0, |dt| {
            1.0 - (-dt / self.config.collision_baseline_s).exp()
        });
        let mut above_baseline_nm = [0.0; N];
        for (k, output_nm) in output.iter().enumerate() {
            if !armed {
                // Settling (a start, a gap, freedrive): what the observer shows is the arm's
                // steady state, a payload or model error included, not an impact.
                observer.baseline_nm[k] = *output_nm;
            }
            let value_nm = output_nm - observer.baseline_nm[k];
            above_baseline_nm[k] = value_nm;
            if armed && !self.collision[k] {
                observer.baseline_nm[k] += follow * (output_nm - observer.baseline_nm[k]);
            }
            let threshold_nm = self.thresholds.nm[k];
            let on = if self.collision[k] {
                value_nm.abs() > threshold_nm / 2.0
            } else {
                armed && value_nm.abs() > threshold_nm
            };
            if on != self.collision[k] {
                self.collision[k] = on;
                if on {
                    self.collisions += 1;
                }
                on_alarm(EffortAlarm::Collision {
                    joint: k,
                    value_nm,
                    threshold_nm,
                    on,
                });
            }
        }
        // Normal motion teaches the thresholds: armed, in a program, nothing alarming.
        if let (true, Some(dt), ControllerMode::Program) = (armed, step_s, mode)
            && !self.collision.iter().any(|on| *on)
        {
            self.thresholds.learn(dt, &above_baseline_nm);
        }
        output
    }
}
