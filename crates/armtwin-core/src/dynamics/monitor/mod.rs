//! One arm's effort, live: the model's joint torques beside the measured ones, a momentum
//! observer for collisions, the payload identified while the arm rests, and each joint's friction
//! followed against temperature.
//!
//! Owns the per-sample step and the state it keeps (observer, payload identifier, friction fits,
//! residual statistics, alarm states). Must not allocate per sample, know where samples come
//! from, or publish: [`EffortMonitor::step`] returns a readout and hands alarm changes to a
//! callback; the twin turns them into events.
//!
//! Sign convention: every torque here is one the drives apply. `measured − model` is what the
//! drives spend beyond the model (friction, a payload heavier than configured, a contact); the
//! observer estimates the same quantity without differentiating anything. With `p = M(q) q̇`,
//! `ṗ = τ_drives − τ_f(q̇) − τ_e + C(q, q̇)ᵀ q̇ − g(q)` where `τ_e` is what the drives spend
//! beyond the model, so `r = K (p − ∫ (τ_drives − τ_f + Cᵀq̇ − g − r) dt)` settles on `−τ_e`
//! with time constant `1/K`; the readout gives `−r`, in the residual's sign.
//!
//! Here: the monitor, its step and its summary; `types` (settings, readouts, alarms),
//! `observer` (the momentum observer, or the target-current residual, and collisions),
//! `thresholds` (collision thresholds learnt from normal motion), `friction` (the friction fits
//! and their baselines), `payload` (the payload modelled and identified) and `window` (the
//! residual statistics).
//!
//! Where the controller sends its target current beside the measured one (UR RTDE), collisions
//! are watched on their difference: the controller's own model, friction feed-forward included,
//! leaves far less unexplained than ours (docs/load-twin.md).

mod friction;
mod observer;
mod payload;
mod thresholds;
mod types;
mod window;

pub use thresholds::ThresholdSource;
pub use types::{
    DetectionSource, EffortAlarm, EffortConfig, EffortError, EffortReadout, EffortSummary,
    FrictionReadout, JointValues, MAX_EFFORT_JOINTS, PayloadReadout, PayloadSource, ResidualStats,
    StateSource,
};

use super::payload::{
    AT_REST_RAD_S, AT_REST_RAD_S2, PayloadEstimate, PayloadIdentification, PayloadIdentifier,
};
use super::{ArmDynamics, ControllerMode, JointFriction, Payload, ur};
use crate::metrics::SlicedWindow;
use crate::model::ArmDescription;
use crate::sample::{JointQuantity, JointState};
use friction::{FrictionFit, TEMPERATURE_BINS, temperature_bin};
use observer::Observer;
use thresholds::Thresholds;
use window::{Block, WINDOW_SLICES, residual_stats};

/// The fewest joints an effort monitor watches: five-joint arms (an SO-101, a small
/// palletizer); every arm whose dynamics the catalog publishes has six.
pub const MIN_EFFORT_JOINTS: usize = 5;

/// Longest step (s) the observer integrates across: a longer silence starts it afresh.
const MAX_STEP_S: f64 = 0.1;

/// The previous sample, for differences.
#[derive(Debug, Clone, Copy)]
struct Previous<const N: usize> {
    stamp_s: f64,
    q_rad: [f64; N],
    qd_rad_s: [f64; N],
}

/// One robot's effort monitor for an arm of `N` joints.
#[derive(Debug, Clone)]
struct Monitor<const N: usize> {
    config: EffortConfig,
    arm_only: ArmDynamics<N>,
    loaded: ArmDynamics<N>,
    in_use: (Payload, PayloadSource),
    controller_payload: Option<Payload>,
    applied: Option<Payload>,
    thresholds: Thresholds<N>,
    current_to_torque: Option<[f64; N]>,
    previous: Option<Previous<N>>,
    observer: Observer<N>,
    identifier: PayloadIdentifier,
    rest_since_estimate: u32,
    estimate: Option<PayloadEstimate>,
    identification: Option<PayloadIdentification>,
    friction: [FrictionFit; N],
    /// Each fit's estimate after the latest sample (what the residual and observer subtract).
    fitted: [Option<JointFriction>; N],
    /// Per joint and temperature bin (the last: no temperature), the friction first fitted there.
    baselines: [[Option<f64>; TEMPERATURE_BINS + 1]; N],
    temperature_c: [Option<f64>; N],
    cumulative: Block<N>,
    /// Residual magnitudes over the last `window_s`.
    window: SlicedWindow<N>,
    latest: Option<EffortReadout>,
    collision: [bool; N],
    collisions: u64,
    payload_mismatch: bool,
}

impl<const N: usize> Monitor<N> {
    /// The monitor of `arm` (an arm of `N` joints with inertial parameters: a catalog arm, a
    /// custom arm's `[dynamics]`, a URDF's chain), its residual window `window_s` long.
    fn new(
        arm: &ArmDescription,
        config: &EffortConfig,
        window_s: f64,
    ) -> Result<Self, EffortError> {
        check_settings(config, window_s)?;
        // First: an arm of another joint count is refused for that, not for its thresholds.
        let mut arm_only = ArmDynamics::<N>::from_arm(arm)?;
        if let Some(rotor_kg_m2) = per_joint::<N>(
            "reflected_rotor_inertia_kg_m2",
            config.reflected_rotor_inertia_kg_m2,
            true,
        )? {
            arm_only = arm_only.with_reflected_rotor_inertia_kg_m2(rotor_kg_m2)?;
        }
        // The catalog's drive data are a Universal Robots arm's, never a URDF's of the same name.
        let catalog_name = Some(arm.name.as_str()).filter(|_| arm.joint_origins.is_none());
        let catalog =
            |values: Option<[f64; 6]>| values.and_then(|v| <[f64; N]>::try_from(v.as_slice()).ok());
        let floor_nm = per_joint::<N>("rated_torque_nm", config.rated_torque_nm, false)?
            .or_else(|| {
                let max_nm = arm.inertials.as_ref()?.max_torque_nm.as_deref()?;
                <[f64; N]>::try_from(max_nm).ok()
            })
            .map(|rated| rated.map(|nm| nm * ur::DEFAULT_COLLISION_SHARE))
            .or_else(|| catalog(catalog_name.and_then(ur::default_collision_threshold_nm)));
        let configured_nm = per_joint::<N>(
            "collision_threshold_nm",
            config.collision_threshold_nm,
            false,
        )?;
        let current_to_torque = per_joint::<N>(
            "current_to_torque_nm_per_a",
            config.current_to_torque_nm_per_a,
            false,
        )?
        .or_else(|| catalog(catalog_name.and_then(ur::current_to_torque_nm_per_a)));
        let thresholds = match (configured_nm, floor_nm) {
            (Some(configured), _) => Thresholds::new(Some(configured), configured, 1.0, 0.0),
            (None, Some(floor)) => Thresholds::new(
                None,
                floor,
                config.threshold_factor,
                config.threshold_learning_s,
            ),
            (None, None) => {
                return Err(EffortError::NoThresholds {
                    model: arm.name.clone(),
                });
            }
        };
        for value in thresholds.nm {
            if !(value.is_finite() && value > 0.0) {
                return Err(EffortError::Setting {
                    field: "collision_threshold_nm",
                    value,
                });
            }
        }
        let in_use = match config.payload {
            Some(payload) => (payload, PayloadSource::Config),
            None => (Payload::NONE, PayloadSource::None),
        };
        let loaded = arm_only.clone().with_payload(in_use.0)?;
        Ok(Self {
            config: *config,
            arm_only,
            loaded,
            in_use,
            controller_payload: None,
            applied: None,
            thresholds,
            current_to_torque,
            previous: None,
            observer: Observer::default(),
            identifier: PayloadIdentifier::new(),
            rest_since_estimate: 0,
            estimate: None,
            identification: None,
            friction: [FrictionFit::default(); N],
            fitted: [None; N],
            baselines: [[None; TEMPERATURE_BINS + 1]; N],
            temperature_c: [None; N],
            cumulative: Block::default(),
            window: SlicedWindow::new(window_s, WINDOW_SLICES),
            latest: None,
            collision: [false; N],
            collisions: 0,
            payload_mismatch: false,
        })
    }

    /// Steps the monitor with a joint sample: `q_rad` the actual joint angles, `state` what came
    /// beside them. Alarm changes go to `on_alarm`. `None` when the sample has no velocity and
    /// none can be differenced yet.
    fn step(
        &mut self,
        stamp_s: f64,
        q_rad: &[f64],
        state: &JointState,
        mut on_alarm: impl FnMut(EffortAlarm),
    ) -> Option<EffortReadout> {
        let q: [f64; N] = q_rad.try_into().ok()?;
        let get = |quantity: JointQuantity| joint_values(state, quantity);
        let step_s = self
            .previous
            .map(|previous| stamp_s - previous.stamp_s)
            .filter(|dt| *dt > 0.0 && *dt <= MAX_STEP_S);
        let qd = match (get(JointQuantity::Velocity), step_s, self.previous) {
            (Some(qd), _, _) => qd,
            (None, Some(dt), Some(previous)) => {
                std::array::from_fn(|k| (q[k] - previous.q_rad[k]) / dt)
            }
            _ => {
                self.previous = Some(Previous {
                    stamp_s,
                    q_rad: q,
                    qd_rad_s: [0.0; N],
                });
                return None;
            }
        };
        if let Some(payload) = state.payload {
            self.controller_payload = Some(Payload {
                mass_kg: payload.mass_kg,
                cog_flange_m: payload.cog_m,
                inertia_cog_kg_m2: payload.inertia_kg_m2.unwrap_or([0.0; 6]),
            });
            self.update_payload_in_use();
        }
        let mode = state.status.map_or(ControllerMode::Program, |status| {
            ControllerMode::from_robot_status_bits(status.status_bits)
        });
        let (state_source, model_q, model_qd, model_qdd) = self.model_state(state, &q, &qd, step_s);
        let model_nm = self
            .loaded
            .controller_moment_nm(mode, &model_q, &model_qd, &model_qdd);
        // Reported torques, else currents through the arm's torque factors.
        let measured_nm = get(JointQuantity::Torque).or_else(|| {
            let (factors, current) = (self.current_to_torque?, get(JointQuantity::Current)?);
            Some(std::array::from_fn(|k| current[k] * factors[k]))
        });
        if let Some(temperatures) = get(JointQuantity::Temperature) {
            self.temperature_c = temperatures.map(Some);
        }
        let keep = |window_s: f64| step_s.map_or(1.0, |dt| (-dt / window_s).exp());

        let program = mode == ControllerMode::Program;
        if let Some(measured) = measured_nm {
            self.learn_friction(
                keep(self.config.friction_window_s),
                program,
                &qd,
                &measured,
                &model_nm,
            );
        }
        let friction_nm: [f64; N] = std::array::from_fn(|k| {
            self.fitted[k].map_or(0.0, |friction| friction.torque_nm(qd[k]))
        });
        let residual_nm = measured_nm
            .map(|measured| std::array::from_fn(|k| measured[k] - model_nm[k] - friction_nm[k]));
        if let (Some(residual), true) = (residual_nm, program) {
            self.add_residual(stamp_s, &residual);
        }

        // Payload: identified from program-mode samples at rest (in freedrive the currents follow
        // the configured payload and tell nothing).
        self.identifier.forget(keep(self.config.payload_window_s));
        let at_rest = qd.iter().all(|v| v.abs() < AT_REST_RAD_S)
            && model_qd.iter().all(|v| v.abs() < AT_REST_RAD_S)
            && model_qdd.iter().all(|v| v.abs() < AT_REST_RAD_S2);
        if let (Some(measured), true, true) = (measured_nm, program, at_rest) {
            self.identify_at_rest(&q, &measured, &mut on_alarm);
        }

        let drive_residual_nm = self.drive_residual_nm(state);
        let observer_nm = measured_nm.map(|measured| {
            self.observe(
                stamp_s,
                step_s,
                mode,
                &q,
                &qd,
                &measured,
                &friction_nm,
                drive_residual_nm.as_ref(),
                &mut on_alarm,
            )
        });
        self.previous = Some(Previous {
            stamp_s,
            q_rad: q,
            qd_rad_s: qd,
        });
        let readout = EffortReadout {
            stamp_s,
            mode,
            state_source,
            model_nm: JointValues::from_array(model_nm),
            measured_nm: measured_nm.map(JointValues::from_array),
            residual_nm: residual_nm.map(JointValues::from_array),
            observer_nm: observer_nm.map(JointValues::from_array),
        };
        // The window follows source time, so it empties when program-mode residuals stop.
        self.window.advance_to(stamp_s);
        self.latest = Some(readout);
        Some(readout)
    }

    /// The state the model runs on: the controller's target when it sends one whole, else the
    /// actual state with q̈ from differences of q̇.
    fn model_state(
        &self,
        state: &JointState,
        q: &[f64; N],
        qd: &[f64; N],
        step_s: Option<f64>,
    ) -> (StateSource, [f64; N], [f64; N], [f64; N]) {
        if let (Some(tq), Some(tqd), Some(tqdd)) = (
            joint_values(state, JointQuantity::TargetPosition),
            joint_values(state, JointQuantity::TargetVelocity),
            joint_values(state, JointQuantity::TargetAcceleration),
        ) {
            return (StateSource::Target, tq, tqd, tqdd);
        }
        let qdd = match (step_s, self.previous) {
            (Some(dt), Some(previous)) => {
                std::array::from_fn(|k| (qd[k] - previous.qd_rad_s[k]) / dt)
            }
            _ => [0.0; N],
        };
        (StateSource::Actual, *q, *qd, qdd)
    }

    /// Measured less target current through the drives' torque factors (N·m), where the
    /// controller sends its target current beside the measured one.
    fn drive_residual_nm(&self, state: &JointState) -> Option<[f64; N]> {
        let factors = self.current_to_torque?;
        let current: [f64; N] = joint_values(state, JointQuantity::Current)?;
        let target: [f64; N] = joint_values(state, JointQuantity::TargetCurrent)?;
        Some(std::array::from_fn(|k| {
            (current[k] - target[k]) * factors[k]
        }))
    }

    /// The stamp went back (a restarted clock): differences and the observer start afresh.
    fn restart_clock(&mut self) {
        self.previous = None;
        self.observer.last_s = None;
        self.window.reset();
    }

    /// Residual statistics start afresh (a reset); fits and alarms stay.
    fn reset_statistics(&mut self) {
        self.cumulative = Block::default();
        self.window.reset();
    }

    /// What the monitor shows now.
    #[must_use]
    fn summary(&self) -> EffortSummary {
        let window = self.window.totals();
        let friction: [Option<FrictionReadout>; N] = std::array::from_fn(|k| {
            let JointFriction {
                coulomb_nm,
                viscous_nm_s_rad,
            } = self.fitted[k]?;
            let temperature_c = self.temperature_c[k];
            let baseline_coulomb_nm = self.baselines[k][temperature_bin(temperature_c)];
            Some(FrictionReadout {
                coulomb_nm,
                viscous_nm_s_rad,
                temperature_c,
                baseline_coulomb_nm,
                drift_nm: baseline_coulomb_nm.map(|baseline| coulomb_nm - baseline),
            })
        });
        let configured = self
            .controller_payload
            .map(|payload| (payload, PayloadSource::Controller))
            .or_else(|| {
                self.config
                    .payload
                    .map(|payload| (payload, PayloadSource::Config))
            });
        EffortSummary {
            latest: self.latest,
            cumulative: self.cumulative.stats(),
            window: residual_stats(window.n, &window.sums_of_squares, window.maxima),
            window_s: self.window.window_s(),
            friction: JointValues::from_array(friction),
            payload: PayloadReadout {
                configured,
                estimate: self.estimate,
                identification: self.identification,
                applied: self.applied,
                in_use: self.in_use,
            },
            collision_threshold_nm: JointValues::from_array(self.thresholds.nm),
            threshold_source: self.thresholds.source,
            detection: self.observer.source,
            collision: JointValues::from_array(self.collision),
            collisions: self.collisions,
            payload_mismatch: self.payload_mismatch,
        }
    }
}

/// One robot's effort monitor: for an arm of five, six or seven joints.
#[derive(Debug, Clone)]
pub struct EffortMonitor(Watched);

/// The monitor of the arm's joint count (boxed: a robot pays for its own arm's only).
#[derive(Debug, Clone)]
enum Watched {
    Five(Box<Monitor<5>>),
    Six(Box<Monitor<6>>),
    Seven(Box<Monitor<7>>),
}

/// `$body` with `$monitor` bound to the monitor, whichever joint count it has.
macro_rules! each {
    ($watched:expr, $monitor:ident => $body:expr) => {
        match $watched {
            Watched::Five($monitor) => $body,
            Watched::Six($monitor) => $body,
            Watched::Seven($monitor) => $body,
        }
    };
}

impl EffortMonitor {
    /// The monitor of `arm` (an arm of [`MIN_EFFORT_JOINTS`] to [`MAX_EFFORT_JOINTS`] joints with
    /// inertial parameters: a catalog arm, a custom arm's `[dynamics]`, a URDF's chain), its
    /// residual window `window_s` long.
    pub fn new(
        arm: &ArmDescription,
        config: &EffortConfig,
        window_s: f64,
    ) -> Result<Self, EffortError> {
        let joints = arm.joint_count();
        Ok(Self(match joints {
            5 => Watched::Five(Box::new(Monitor::new(arm, config, window_s)?)),
            6 => Watched::Six(Box::new(Monitor::new(arm, config, window_s)?)),
            7 => Watched::Seven(Box::new(Monitor::new(arm, config, window_s)?)),
            joints => return Err(EffortError::JointCount { joints }),
        }))
    }

    /// Steps the monitor with a joint sample: `q_rad` the actual joint angles, `state` what came
    /// beside them. Alarm changes go to `on_alarm`. `None` when the sample has no velocity and
    /// none can be differenced yet, or not one angle per joint.
    pub fn step(
        &mut self,
        stamp_s: f64,
        q_rad: &[f64],
        state: &JointState,
        on_alarm: impl FnMut(EffortAlarm),
    ) -> Option<EffortReadout> {
        each!(&mut self.0, monitor => monitor.step(stamp_s, q_rad, state, on_alarm))
    }

    /// The stamp went back (a restarted clock): differences and the observer start afresh.
    pub fn restart_clock(&mut self) {
        each!(&mut self.0, monitor => monitor.restart_clock());
    }

    /// Residual statistics start afresh (a reset); fits and alarms stay.
    pub fn reset_statistics(&mut self) {
        each!(&mut self.0, monitor => monitor.reset_statistics());
    }

    /// What the monitor shows now.
    #[must_use]
    pub fn summary(&self) -> EffortSummary {
        each!(&self.0, monitor => monitor.summary())
    }

    /// Applies the latest identified payload: the model uses it from the next sample on. The
    /// payload applied, or `None` when there is no estimate.
    pub fn apply_estimate(&mut self) -> Option<Payload> {
        each!(&mut self.0, monitor => monitor.apply_estimate())
    }

    /// Stops using an applied payload: back to the controller's or the configured one.
    pub fn discard_applied(&mut self) {
        each!(&mut self.0, monitor => monitor.discard_applied());
    }
}

/// Every scalar setting in its range: the times and gains positive, the learning time not
/// negative (the per-joint ones are checked against the arm by `per_joint`).
fn check_settings(config: &EffortConfig, window_s: f64) -> Result<(), EffortError> {
    for (field, value) in [
        ("observer_gain_per_s", config.observer_gain_per_s),
        ("payload_tolerance_kg", config.payload_tolerance_kg),
        ("payload_window_s", config.payload_window_s),
        ("friction_window_s", config.friction_window_s),
        ("collision_baseline_s", config.collision_baseline_s),
        ("threshold_factor", config.threshold_factor),
        ("payload_reach_m", config.payload_reach_m),
        ("window_s", window_s),
    ] {
        if !(value.is_finite() && value > 0.0) {
            return Err(EffortError::Setting { field, value });
        }
    }
    if !(config.threshold_learning_s.is_finite() && config.threshold_learning_s >= 0.0) {
        return Err(EffortError::Setting {
            field: "threshold_learning_s",
            value: config.threshold_learning_s,
        });
    }
    Ok(())
}

/// A per-joint setting as the arm's `N` values, each positive (or zero, with `zero_allowed`);
/// refused with another count.
fn per_joint<const N: usize>(
    field: &'static str,
    values: Option<JointValues<f64>>,
    zero_allowed: bool,
) -> Result<Option<[f64; N]>, EffortError> {
    let Some(values) = values else {
        return Ok(None);
    };
    let in_range = |v: f64| v.is_finite() && (v > 0.0 || (zero_allowed && v == 0.0));
    if let Some(value) = values.iter().find(|v| !in_range(**v)) {
        return Err(EffortError::Setting {
            field,
            value: *value,
        });
    }
    values
        .to_array::<N>()
        .map(Some)
        .ok_or(EffortError::JointValues {
            field,
            expected: N,
            got: values.len(),
        })
}

/// One value per joint of `quantity`, if `state` has it for each of the arm's `N` joints.
fn joint_values<const N: usize>(state: &JointState, quantity: JointQuantity) -> Option<[f64; N]> {
    state
        .get(quantity)
        .and_then(|values| values.try_into().ok())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::catalog;
    use crate::sample::ControllerStatus;
    use approx::assert_relative_eq;

    /// The test arms' joints (a UR10e's, a Z1's).
    const J: usize = 6;
    const DT_S: f64 = 0.002;
    const COULOMB_NM: [f64; J] = [6.0, 6.0, 4.0, 1.5, 1.5, 1.5];
    const VISCOUS_NM_S_RAD: [f64; J] = [3.0, 3.0, 2.0, 0.5, 0.5, 0.5];

    /// A contact: onset (s), joint, torque the drives must add (N·m), duration (s).
    type Contact = (f64, usize, f64, f64);

    /// A UR10e run: motion with rests every 4 s, friction, a carried payload; the drives'
    /// torques as the controller's currents would give them. Returns the alarms and the last
    /// summary.
    fn run(
        seconds: f64,
        configured_kg: f64,
        carried_kg: f64,
        contacts: &[Contact],
    ) -> (Vec<(f64, EffortAlarm)>, EffortMonitor) {
        let arm = catalog::arm("ur10e").expect("catalog arm");
        let cog = [0.0, 0.0, 0.05];
        let config = EffortConfig {
            payload: Some(Payload::point_mass(configured_kg, cog)),
            payload_window_s: 30.0,
            // The rated-torque share, as on a new arm before its normal motion is learnt.
            threshold_learning_s: 0.0,
            ..EffortConfig::default()
        };
        let mut monitor = EffortMonitor::new(&arm, &config, 10.0).expect("monitor");
        let truth = ArmDynamics::<J>::from_arm(&arm)
            .and_then(|d| d.with_payload(Payload::point_mass(carried_kg, cog)))
            .and_then(|d| {
                d.with_friction(std::array::from_fn(|k| JointFriction {
                    coulomb_nm: COULOMB_NM[k],
                    viscous_nm_s_rad: VISCOUS_NM_S_RAD[k],
                }))
            })
            .expect("dynamics");
        let centre = [0.0, -1.2, 1.3, -1.6, -1.5, 0.0];
        let omega = [1.1, 0.7, 0.9, 1.3, 1.7, 2.1];
        let mut alarms = Vec::new();
        let mut rest_q = centre;
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            reason = "a test's sample count"
        )]
        let samples = (seconds / DT_S) as usize;
        for i in 0..samples {
            #[allow(clippy::cast_precision_loss, reason = "a test's sample index")]
            let t = i as f64 * DT_S;
            // Every 4 s: 3 s of motion, then 1 s at rest where the motion stopped.
            let phase = t % 4.0;
            let (q, qd, qdd) = if phase < 3.0 {
                let s = |k: usize| (omega[k] * t).sin();
                let c = |k: usize| (omega[k] * t).cos();
                // Smooth start and stop: the amplitude envelope sin²(π·phase/3).
                let e = (std::f64::consts::PI * phase / 3.0).sin().powi(2);
                let de =
                    std::f64::consts::PI / 3.0 * (2.0 * std::f64::consts::PI * phase / 3.0).sin();
                let dde = 2.0
                    * (std::f64::consts::PI / 3.0).powi(2)
                    * (2.0 * std::f64::consts::PI * phase / 3.0).cos();
                let q: [f64; J] = std::array::from_fn(|k| rest_q[k] + 0.6 * e * s(k));
                let qd: [f64; J] = std::array::from_fn(|k| 0.6 * (de * s(k) + e * omega[k] * c(k)));
                let qdd: [f64; J] = std::array::from_fn(|k| {
                    0.6 * (dde * s(k) + 2.0 * de * omega[k] * c(k) - e * omega[k] * omega[k] * s(k))
                });
                (q, qd, qdd)
            } else {
                if phase - DT_S < 3.0 {
                    // A new rest pose for the next motion to start from.
                    let k = (t / 4.0).floor();
                    rest_q = std::array::from_fn(|j| {
                        centre[j] + 0.8 * ((k + 1.0) * (j as f64 + 1.3)).sin()
                    });
                }
                (rest_q, [0.0; J], [0.0; J])
            };
            let mut tau = truth.inverse_dynamics_nm(&q, &qd, &qdd);
            for &(onset, joint, torque, duration) in contacts {
                if t >= onset && t < onset + duration {
                    tau[joint] += torque * ((t - onset) / 0.01).min(1.0);
                }
            }
            let mut state = JointState::new(J);
            state.set(JointQuantity::Velocity, &qd);
            state.set(JointQuantity::TargetPosition, &q);
            state.set(JointQuantity::TargetVelocity, &qd);
            state.set(JointQuantity::TargetAcceleration, &qdd);
            state.set(JointQuantity::Torque, &tau);
            state.status = Some(ControllerStatus {
                robot_mode: 7,
                safety_mode: 1,
                status_bits: 3,
                speed_scaling: 1.0,
            });
            monitor.step(t, &q, &state, |alarm| alarms.push((t, alarm)));
        }
        (alarms, monitor)
    }

    /// The collisions raised: when, and on which joint (from 0).
    fn collisions_raised(alarms: &[(f64, EffortAlarm)]) -> Vec<(f64, usize)> {
        alarms
            .iter()
            .filter_map(|(t, alarm)| match alarm {
                EffortAlarm::Collision {
                    joint, on: true, ..
                } => Some((*t, *joint)),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn a_clean_run_raises_nothing_and_learns_friction() {
        let (alarms, monitor) = run(60.0, 2.0, 2.0, &[]);
        let summary = monitor.summary();
        assert!(alarms.is_empty(), "{alarms:?}");
        for k in 0..J {
            let friction = summary.friction[k].expect("fitted");
            assert!(
                (friction.coulomb_nm - COULOMB_NM[k]).abs() < 0.05,
                "{k}: {friction:?}"
            );
            assert!(
                (friction.viscous_nm_s_rad - VISCOUS_NM_S_RAD[k]).abs() < 0.05,
                "{k}: {friction:?}"
            );
        }
        let estimate = summary.payload.estimate.expect("identified");
        // Not exact: the first samples of each motion are slow enough to pass for rest.
        assert!((estimate.mass_kg - 2.0).abs() < 1e-3, "{estimate:?}");
    }

    #[test]
    fn contacts_raise_collisions_on_their_joint_within_milliseconds() {
        let contacts = [
            (21.0, 1, 60.0, 0.3),
            (25.5, 2, -30.0, 0.2),
            (30.2, 4, 12.0, 0.2),
        ];
        let (alarms, monitor) = run(40.0, 2.0, 2.0, &contacts);
        let summary = monitor.summary();
        let raised = collisions_raised(&alarms);
        assert_eq!(raised.len(), contacts.len(), "{alarms:?}");
        for ((t, joint), (onset, contact_joint, ..)) in raised.iter().zip(contacts) {
            assert_eq!(*joint, contact_joint);
            let latency_s = t - onset;
            assert!((0.0..0.03).contains(&latency_s), "latency {latency_s} s");
        }
        assert_eq!(summary.collisions, 3);
        assert_eq!(*summary.collision, [false; J]);
    }

    #[test]
    fn a_heavier_payload_is_identified_reported_and_applied() {
        let (alarms, mut monitor) = run(40.0, 2.0, 3.5, &[]);
        let summary = monitor.summary();
        let payload = alarms.iter().find_map(|(_, alarm)| match alarm {
            EffortAlarm::Payload {
                estimated_kg,
                on: true,
                ..
            } => Some(*estimated_kg),
            _ => None,
        });
        // Raised on the first estimate, from the first few rests.
        let estimated = payload.expect("a payload alarm");
        assert!((estimated - 3.5).abs() < 0.1, "{estimated}");
        assert!(summary.payload_mismatch);
        assert!(
            !alarms
                .iter()
                .any(|(_, a)| matches!(a, EffortAlarm::Collision { .. })),
            "{alarms:?}"
        );
        let estimate = summary.payload.estimate.expect("estimate");
        assert!((estimate.mass_kg - 3.5).abs() < 1e-3, "{estimate:?}");
        let cog = estimate.cog_flange_m.expect("cog");
        assert!((cog[2] - 0.05).abs() < 1e-3, "{cog:?}");
        let applied = monitor.apply_estimate().expect("applied");
        assert_eq!(applied.mass_kg.to_bits(), estimate.mass_kg.to_bits());
        let payload = monitor.summary().payload;
        assert_eq!(payload.in_use, (applied, PayloadSource::Applied));
        monitor.discard_applied();
        assert_eq!(monitor.summary().payload.in_use.1, PayloadSource::Config);
    }

    #[test]
    fn friction_growing_at_one_temperature_shows_as_drift() {
        let arm = catalog::arm("ur10e").expect("catalog arm");
        let config = EffortConfig {
            friction_window_s: 10.0,
            ..EffortConfig::default()
        };
        let mut monitor = EffortMonitor::new(&arm, &config, 10.0).expect("monitor");
        let rigid = ArmDynamics::<J>::from_arm(&arm).expect("dynamics");
        let omega = [1.1, 0.7, 0.9, 1.3, 1.7, 2.1];
        let seconds = 120.0;
        let mut drift_at = Vec::new();
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            reason = "a test's sample count"
        )]
        for i in 0..(seconds / DT_S) as usize {
            #[allow(clippy::cast_precision_loss, reason = "a test's sample index")]
            let t = i as f64 * DT_S;
            // Joint 2's Coulomb friction wears from 6 to 7.5 N·m at a steady 35 °C.
            let coulomb_2 = 6.0 + 1.5 * t / seconds;
            let q: [f64; J] = std::array::from_fn(|k| -0.8 + 0.6 * (omega[k] * t).sin());
            let qd: [f64; J] = std::array::from_fn(|k| 0.6 * omega[k] * (omega[k] * t).cos());
            let qdd: [f64; J] =
                std::array::from_fn(|k| -0.6 * omega[k] * omega[k] * (omega[k] * t).sin());
            let mut tau = rigid.inverse_dynamics_nm(&q, &qd, &qdd);
            for k in 0..J {
                let friction = JointFriction {
                    coulomb_nm: if k == 1 { coulomb_2 } else { COULOMB_NM[k] },
                    viscous_nm_s_rad: VISCOUS_NM_S_RAD[k],
                };
                tau[k] += friction.torque_nm(qd[k]);
            }
            let mut state = JointState::new(J);
            state.set(JointQuantity::Velocity, &qd);
            state.set(JointQuantity::TargetPosition, &q);
            state.set(JointQuantity::TargetVelocity, &qd);
            state.set(JointQuantity::TargetAcceleration, &qdd);
            state.set(JointQuantity::Torque, &tau);
            state.set(JointQuantity::Temperature, &[35.0; J]);
            monitor.step(t, &q, &state, |_| {});
            if i % 5000 == 4999 {
                drift_at.push(monitor.summary().friction[1].and_then(|f| f.drift_nm));
            }
        }
        let last = monitor.summary().friction;
        let joint_2 = last[1].expect("fitted");
        // The fit lags the wear by about its window: 1.5 N·m over 120 s, 10 s behind.
        assert!((joint_2.coulomb_nm - 7.5).abs() < 0.2, "{joint_2:?}");
        let drift = joint_2.drift_nm.expect("a baseline at 35 °C");
        assert!((1.1..1.6).contains(&drift), "{drift} N·m; {drift_at:?}");
        // Joints that do not wear do not drift.
        let steady = last[0].and_then(|f| f.drift_nm).expect("joint 1");
        assert!(steady.abs() < 0.1, "{steady}");
    }

    #[test]
    fn an_error_present_from_the_start_is_no_collision() {
        // 3 kg more than modelled from the first sample: joint 3's observer settles near 20 N·m,
        // beyond its 15 N·m threshold, while the observer is not yet armed.
        let (alarms, _) = run(12.0, 0.0, 3.0, &[]);
        assert!(
            !alarms
                .iter()
                .any(|(_, a)| matches!(a, EffortAlarm::Collision { .. })),
            "{alarms:?}"
        );
    }

    /// A URDF's arm (Unitree Z1, six joints) reporting joint torques, or motor currents through
    /// configured factors: its thresholds are the share of its `<limit effort>`s, and a contact
    /// computed by the whole tree's recursion is caught on its joint.
    #[test]
    fn a_urdf_arm_is_watched_with_its_own_effort_limits() {
        use crate::model::urdf::{UrdfDynamics, UrdfRobot};
        let text = include_str!("../../../../../tests/data/urdf/z1.urdf");
        let robot = UrdfRobot::parse(text).expect("URDF");
        let chain = robot.chain(None, Some("link06")).expect("chain");
        let arm = chain.arm_description(&robot).expect("arm");
        let tree = UrdfDynamics::new(&robot, &chain).expect("tree dynamics");
        let effort_nm: Vec<f64> = chain.joints.iter().filter_map(|j| j.max_effort).collect();
        let factors = [2.0, 2.5, 2.0, 1.5, 1.0, 0.5];
        for currents in [false, true] {
            let config = EffortConfig {
                threshold_learning_s: 0.0,
                current_to_torque_nm_per_a: currents.then_some(JointValues::from_array(factors)),
                ..EffortConfig::default()
            };
            let mut monitor = EffortMonitor::new(&arm, &config, 10.0).expect("monitor");
            let summary = monitor.summary();
            assert_eq!(summary.threshold_source, ThresholdSource::Rated);
            for (threshold, effort) in summary.collision_threshold_nm.iter().zip(&effort_nm) {
                assert_relative_eq!(*threshold, effort * ur::DEFAULT_COLLISION_SHARE);
            }
            let mut alarms = Vec::new();
            let mut largest_nm = 0.0_f64;
            for i in 0..3000 {
                #[allow(clippy::cast_precision_loss, reason = "a test's sample index")]
                let t = f64::from(i) * DT_S;
                let q: [f64; J] = std::array::from_fn(|k| 0.4 * (0.9 * t + k as f64).sin() + 0.3);
                let qd: [f64; J] = std::array::from_fn(|k| 0.36 * (0.9 * t + k as f64).cos());
                let qdd: [f64; J] = std::array::from_fn(|k| -0.324 * (0.9 * t + k as f64).sin());
                let mut tau = tree.inverse_dynamics(&q, &qd, &qdd).expect("torques");
                // Joint 2 pushed for 0.2 s from t = 4 s, beyond its rated-torque share.
                if (4.0..4.2).contains(&t) {
                    tau[1] += 10.0;
                }
                let mut state = JointState::new(J);
                state.set(JointQuantity::Velocity, &qd);
                state.set(JointQuantity::TargetPosition, &q);
                state.set(JointQuantity::TargetVelocity, &qd);
                state.set(JointQuantity::TargetAcceleration, &qdd);
                if currents {
                    let current: Vec<f64> = tau.iter().zip(factors).map(|(t, f)| t / f).collect();
                    state.set(JointQuantity::Current, &current);
                } else {
                    state.set(JointQuantity::Torque, &tau);
                }
                let readout = monitor
                    .step(t, &q, &state, |alarm| alarms.push((t, alarm)))
                    .expect("a readout");
                if t < 4.0 {
                    let residual = readout.residual_nm.expect("a residual");
                    largest_nm = residual.iter().fold(largest_nm, |m, r| m.max(r.abs()));
                }
            }
            assert!(
                largest_nm < 1e-9,
                "model against the tree: {largest_nm:e} N·m"
            );
            let raised = collisions_raised(&alarms);
            assert_eq!(raised.len(), 1, "{alarms:?}");
            assert_eq!(raised[0].1, 1, "{alarms:?}");
            assert!((4.0..4.03).contains(&raised[0].0), "{raised:?}");
        }
    }

    #[test]
    fn bad_settings_are_refused() {
        let arm = catalog::arm("ur10e").expect("catalog arm");
        let config = EffortConfig {
            observer_gain_per_s: 0.0,
            ..EffortConfig::default()
        };
        assert!(matches!(
            EffortMonitor::new(&arm, &config, 10.0),
            Err(EffortError::Setting {
                field: "observer_gain_per_s",
                ..
            })
        ));
        // A Panda: seven joints, so six thresholds are refused; to its fourth link, four joints.
        let panda = crate::model::urdf::UrdfRobot::parse(include_str!(
            "../../../../../tests/data/urdf/panda.urdf"
        ))
        .expect("URDF");
        let arm_to = |tip: &str| {
            let chain = panda.chain(None, Some(tip)).expect("chain");
            chain.arm_description(&panda).expect("arm")
        };
        let six_thresholds = EffortConfig {
            collision_threshold_nm: Some(JointValues::from_array([5.0; 6])),
            ..EffortConfig::default()
        };
        assert!(matches!(
            EffortMonitor::new(&arm_to("panda_hand_tcp"), &six_thresholds, 10.0),
            Err(EffortError::JointValues {
                field: "collision_threshold_nm",
                expected: 7,
                got: 6
            })
        ));
        assert!(matches!(
            EffortMonitor::new(&arm_to("panda_link4"), &EffortConfig::default(), 10.0),
            Err(EffortError::JointCount { joints: 4 })
        ));
        let ur20 = catalog::arm("ur20").expect("catalog arm");
        assert!(matches!(
            EffortMonitor::new(&ur20, &EffortConfig::default(), 10.0),
            Err(EffortError::NoThresholds { .. })
        ));
    }
}
