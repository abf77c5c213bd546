//! `armtwin validate --dynamics`: a UR RTDE recording's joint torques against the core's
//! inverse dynamics, row by row.
//!
//! Owns which state and payload each row is modelled with, the controller mode it is compared in,
//! the torque the motor currents imply, and the payload identified from them. Must not do I/O or
//! compute the dynamics itself: it reads a [`ColumnTable`] and calls [`armtwin_core::dynamics`], the code
//! the service would run.
//!
//! Like with like: RTDE `target_moment` is the controller's own model of the *target* state, in
//! the mode the status bits give (program: rigid body and rotor inertia; freedrive: gravity), so
//! the model is evaluated on the target state in that mode. Without target columns the actual
//! state is used, with accelerations from central differences of `actual_qd`.

use thiserror::Error;

use armtwin_codec::recording::ColumnTable;
pub use armtwin_core::dynamics::monitor::StateSource;
use armtwin_core::dynamics::payload::{DEFAULT_REACH_M, PayloadIdentification, PayloadIdentifier};
use armtwin_core::dynamics::{ArmDynamics, ControllerMode, DynamicsError, Payload, ur};
use armtwin_core::model::ArmDescription;

pub use armtwin_core::dynamics::payload::AT_REST_RAD_S;

/// Why the dynamics of a recording cannot be compared.
#[derive(Debug, Error)]
pub enum DynamicsValidationError {
    /// The arm has no inertial parameters, or they are invalid.
    #[error(transparent)]
    Dynamics(#[from] DynamicsError),
    /// Neither target nor actual joint angles are in the recording.
    #[error("the recording has neither target_q_0..5 nor actual_q_0..5 with actual_qd_0..5")]
    NoState,
}

/// Where the payload came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PayloadSource {
    /// The recording's `payload` and `payload_cog_0..2` columns.
    Recording,
    /// `--payload` on the command line.
    CommandLine,
    /// Neither: no payload.
    None,
}

/// One modelled row.
#[derive(Debug, Clone, PartialEq)]
pub struct DynamicsRow {
    /// 1-based line in the file.
    pub line: u64,
    /// The recording's `timestamp` (s), if any.
    pub t_s: Option<f64>,
    /// The controller mode of the row.
    pub mode: ControllerMode,
    /// The model's torques (N·m) in that mode.
    pub tau_model_nm: [f64; 6],
    /// The torques the currents imply (N·m), for arms whose drive data is public.
    pub tau_measured_nm: Option<[f64; 6]>,
    /// The controller's `target_moment` (N·m), if recorded.
    pub target_moment_nm: Option<[f64; 6]>,
    /// Measured less target current through the drives' torque factors (N·m), if both are
    /// recorded: what the live monitor watches for collisions then.
    pub current_vs_target_nm: Option<[f64; 6]>,
}

/// The dynamics of a whole recording.
#[derive(Debug, Clone, PartialEq)]
pub struct DynamicsValidation {
    /// Which state the model used.
    pub state_source: StateSource,
    /// Rows modelled, in file order.
    pub rows: Vec<DynamicsRow>,
    /// Data lines without a complete state, not modelled.
    pub skipped_lines: Vec<u64>,
    /// The payload of the first modelled row and where it came from (the recording's may change
    /// from row to row; each row is modelled with its own).
    pub payload_configured: Option<Payload>,
    /// Where the payload came from.
    pub payload_source: PayloadSource,
    /// The payload the currents of program-mode rows at rest identify, or why they identify none.
    pub payload_identification: PayloadIdentification,
}

const JOINTS: usize = 6;

/// The names [`compare`] needs from [`armtwin_codec::recording::read_columns`], in this order:
/// `timestamp`, six each of the joint groups, then the payload and the status bits.
#[must_use]
pub fn wanted_columns() -> Vec<String> {
    let mut names = vec!["timestamp".to_owned()];
    for group in [
        "target_q",
        "target_qd",
        "target_qdd",
        "actual_q",
        "actual_qd",
        "actual_current",
        "target_moment",
    ] {
        names.extend((0..JOINTS).map(|k| format!("{group}_{k}")));
    }
    names.extend(
        [
            "payload",
            "payload_cog_0",
            "payload_cog_1",
            "payload_cog_2",
            "robot_status_bits",
        ]
        .map(str::to_owned),
    );
    names.extend((0..JOINTS).map(|k| format!("target_current_{k}")));
    names
}

/// Column offsets in [`wanted_columns`].
const TIMESTAMP: usize = 0;
const TARGET_Q: usize = 1;
const TARGET_QD: usize = 7;
const TARGET_QDD: usize = 13;
const ACTUAL_Q: usize = 19;
const ACTUAL_QD: usize = 25;
const ACTUAL_CURRENT: usize = 31;
const TARGET_MOMENT: usize = 37;
const PAYLOAD: usize = 43;
const STATUS_BITS: usize = 47;
const TARGET_CURRENT: usize = 48;

fn group(values: &[Option<f64>], start: usize) -> Option<[f64; JOINTS]> {
    let mut out = [0.0; JOINTS];
    for (k, slot) in out.iter_mut().enumerate() {
        *slot = values[start + k].filter(|v| v.is_finite())?;
    }
    Some(out)
}

/// Models every row of `table` (read with [`wanted_columns`]) for `arm`, with the recording's
/// payload where it has one, else `payload_flag`.
pub fn compare(
    table: &ColumnTable,
    arm: &ArmDescription,
    payload_flag: Option<Payload>,
) -> Result<DynamicsValidation, DynamicsValidationError> {
    let arm_only = ArmDynamics::<JOINTS>::from_arm(arm)?;
    let current_to_torque = ur::current_to_torque_nm_per_a(&arm.name);
    let has = |start: usize| (start..start + JOINTS).all(|i| table.found[i]);
    let state_source = if has(TARGET_Q) && has(TARGET_QD) && has(TARGET_QDD) {
        StateSource::Target
    } else if has(ACTUAL_Q) && has(ACTUAL_QD) {
        StateSource::Actual
    } else {
        return Err(DynamicsValidationError::NoState);
    };
    let recorded_payload = (PAYLOAD..PAYLOAD + 4).all(|i| table.found[i]);
    let payload_source = if recorded_payload {
        PayloadSource::Recording
    } else if payload_flag.is_some() {
        PayloadSource::CommandLine
    } else {
        PayloadSource::None
    };

    // The state of each line that has one: (index in table, q, qd, qdd if recorded).
    let mut states = Vec::with_capacity(table.rows.len());
    let mut skipped_lines = Vec::new();
    for (index, (line, values)) in table.rows.iter().enumerate() {
        let state = match state_source {
            StateSource::Target => group(values, TARGET_Q)
                .zip(group(values, TARGET_QD))
                .zip(group(values, TARGET_QDD))
                .map(|((q, qd), qdd)| (q, qd, Some(qdd))),
            StateSource::Actual => group(values, ACTUAL_Q)
                .zip(group(values, ACTUAL_QD))
                .map(|(q, qd)| (q, qd, None)),
        };
        match state {
            Some((q, qd, qdd)) => states.push(RowState { index, q, qd, qdd }),
            None => skipped_lines.push(*line),
        }
    }

    let mut rows = Vec::with_capacity(states.len());
    let mut identifier = PayloadIdentifier::new();
    let mut payload_configured = None;
    let mut loaded = arm_only.clone();
    for (position, state) in states.iter().enumerate() {
        let (q, qd) = (state.q, state.qd);
        let (line, values) = &table.rows[state.index];
        let qdd = state
            .qdd
            .unwrap_or_else(|| differentiated(table, &states, position));
        let payload = row_payload(values, recorded_payload, payload_flag);
        if let Some(payload) = payload
            && loaded.payload() != &payload
        {
            // An invalid recorded payload (negative mass) is modelled as none, not guessed at.
            loaded = arm_only
                .clone()
                .with_payload(payload)
                .unwrap_or_else(|_| arm_only.clone());
        }
        payload_configured = payload_configured.or(payload);
        let mode = values[STATUS_BITS].and_then(status_bits).map_or(
            ControllerMode::Program,
            ControllerMode::from_robot_status_bits,
        );
        let tau_model_nm = loaded.controller_moment_nm(mode, &q, &qd, &qdd);
        let tau_measured_nm = current_torque_nm(values, None, current_to_torque);
        let current_vs_target_nm =
            current_torque_nm(values, Some(TARGET_CURRENT), current_to_torque);
        // Payload identification: program mode, at rest by the actual velocities.
        if let (ControllerMode::Program, Some(measured), Some(actual_q), Some(actual_qd)) = (
            mode,
            tau_measured_nm,
            group(values, ACTUAL_Q),
            group(values, ACTUAL_QD),
        ) && actual_qd.iter().all(|v| v.abs() < AT_REST_RAD_S)
        {
            let arm_torque = arm_only.gravity_nm(&actual_q);
            let beyond: [f64; JOINTS] = std::array::from_fn(|k| measured[k] - arm_torque[k]);
            identifier.add_static_sample(&arm_only, &actual_q, &beyond);
        }
        rows.push(DynamicsRow {
            line: *line,
            t_s: values[TIMESTAMP],
            mode,
            tau_model_nm,
            tau_measured_nm,
            target_moment_nm: group(values, TARGET_MOMENT),
            current_vs_target_nm,
        });
    }
    Ok(DynamicsValidation {
        state_source,
        rows,
        skipped_lines,
        payload_configured,
        payload_source,
        // A centre of gravity the poses cannot place is taken as configured.
        payload_identification: identifier.identify(
            DEFAULT_REACH_M,
            payload_configured.map_or([0.0; 3], |p| p.cog_flange_m),
        ),
    })
}

/// The actual currents (less the group at `less`, if given) through the drives' torque factors.
fn current_torque_nm(
    values: &[Option<f64>],
    less: Option<usize>,
    factors: Option<[f64; JOINTS]>,
) -> Option<[f64; JOINTS]> {
    let (factors, current) = (factors?, group(values, ACTUAL_CURRENT)?);
    let subtracted = match less {
        Some(less) => group(values, less)?,
        None => [0.0; JOINTS],
    };
    Some(std::array::from_fn(|k| {
        (current[k] - subtracted[k]) * factors[k]
    }))
}

/// A row's payload: its own columns in a recording that has them, else `payload_flag`.
fn row_payload(
    values: &[Option<f64>],
    recorded_payload: bool,
    payload_flag: Option<Payload>,
) -> Option<Payload> {
    if !recorded_payload {
        return payload_flag;
    }
    match values[PAYLOAD..PAYLOAD + 4] {
        [Some(mass_kg), Some(x), Some(y), Some(z)] => Some(Payload::point_mass(mass_kg, [x, y, z])),
        _ => None,
    }
}

/// RTDE's `robot_status_bits` as written in a recording (a whole number), if it is one.
#[allow(
    clippy::cast_sign_loss,
    clippy::cast_possible_truncation,
    reason = "a whole number in u32's range, checked first"
)]
fn status_bits(value: f64) -> Option<u32> {
    (value >= 0.0 && value <= f64::from(u32::MAX) && value.fract() == 0.0).then_some(value as u32)
}

/// A line's state: its index in the table, `q`, `q̇` and `q̈` when recorded.
struct RowState {
    index: usize,
    q: [f64; JOINTS],
    qd: [f64; JOINTS],
    qdd: Option<[f64; JOINTS]>,
}

/// `q̈` of state `position` by central differences of `q̇` over the timestamps of its neighbours
/// (one-sided at the ends, zero when there are no usable timestamps).
fn differentiated(table: &ColumnTable, states: &[RowState], position: usize) -> [f64; JOINTS] {
    let before = position.saturating_sub(1);
    let after = (position + 1).min(states.len() - 1);
    let time = |p: usize| table.rows[states[p].index].1[TIMESTAMP];
    match (time(before), time(after)) {
        (Some(t0), Some(t1)) if t1 > t0 => {
            std::array::from_fn(|k| (states[after].qd[k] - states[before].qd[k]) / (t1 - t0))
        }
        _ => [0.0; JOINTS],
    }
}
