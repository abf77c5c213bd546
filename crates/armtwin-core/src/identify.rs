//! Identification of a Universal Robots arm's kinematics from its own stream: paired (joint
//! angles, measured TCP pose) samples in, `calibration.conf` deltas (and optionally the tool)
//! out.
//!
//! Owns the damped least-squares fit (Levenberg–Marquardt with an analytic Jacobian of the
//! standard-DH chain), the choice of an identifiable subset of parameters (pivoted Cholesky of
//! the column-scaled normal matrix: the parallel axes of joints 2–4 make three `δd` one, and weak
//! excitation makes more parameters indistinguishable), the robust (Huber) weighting of rows, the
//! excitation check and the error figures of a model on samples. Pure and deterministic: the same
//! samples give the same estimate; no I/O, no clock.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use thiserror::Error;

use crate::ik::UrGeometry;
use crate::kinematics::{DhParameters, OutputFrame, Pose, TcpOffset};
use crate::model::calibration::MountingDeltas;
use crate::model::{ArmDescription, RobotModel};
use crate::orientation;

/// One paired sample: joint angles and the controller's measured TCP pose (in the output frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairedSample {
    /// Joint angles (rad).
    pub q_rad: [f64; 6],
    /// The measured `frame_from_tcp`.
    pub measured: Pose,
}

/// How to fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IdentifyOptions {
    /// Also fit the tool offset (position and orientation), starting from the given tool.
    pub fit_tool: bool,
    /// Metres one radian of orientation error counts as (the ratio of position noise to
    /// orientation noise: 1 mm against 1 mrad is 1 m/rad).
    pub orientation_weight_m_per_rad: f64,
    /// Parameters are added to the identified subset, best determined first, while the subset's
    /// condition number (column-scaled) stays below this; the rest stay fixed at zero.
    pub max_condition: f64,
    /// Joints whose angles vary less than this (standard deviation, rad) count as not moved.
    pub min_joint_spread_rad: f64,
    /// At least this many joints must have moved.
    pub min_moving_joints: usize,
    /// Levenberg–Marquardt iterations at most.
    pub max_iterations: usize,
    /// Huber threshold as a multiple of the median row residual: rows beyond it count
    /// linearly, so a packet one cycle out of step cannot pull the fit.
    pub huber_factor: f64,
}

impl Default for IdentifyOptions {
    fn default() -> Self {
        Self {
            fit_tool: false,
            orientation_weight_m_per_rad: 1.0,
            max_condition: 1e4,
            min_joint_spread_rad: 0.05,
            min_moving_joints: 4,
            max_iterations: 40,
            huber_factor: 3.0,
        }
    }
}

/// What kind of quantity a parameter is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParameterKind {
    /// `delta_theta` of a joint (rad).
    DeltaTheta,
    /// `delta_a` of a joint (m).
    DeltaA,
    /// `delta_d` of a joint (m).
    DeltaD,
    /// `delta_alpha` of a joint (rad).
    DeltaAlpha,
    /// Tool position along a flange axis (m).
    ToolPosition,
    /// Tool rotation about a flange axis (rad).
    ToolRotation,
}

/// One parameter's estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct ParameterEstimate {
    /// `delta_d[2]` (0-based joint, as in `calibration.conf`'s lists), `tool_x`, `tool_rz`.
    pub name: String,
    /// Its kind.
    pub kind: ParameterKind,
    /// Estimated value (m or rad); 0 when fixed.
    pub value: f64,
    /// One standard deviation (from the residual and the normal matrix); `None` when fixed.
    pub std_dev: Option<f64>,
    /// Whether it was identified (false: fixed at zero, not identifiable from these samples).
    pub identified: bool,
}

/// How well the samples excite the parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Excitation {
    /// Standard deviation of each joint's angle over the samples (rad).
    pub joint_spread_rad: [f64; 6],
    /// Condition number of the identified subset's column-scaled Jacobian.
    pub condition_number: f64,
    /// How many parameters were identified.
    pub identified: usize,
    /// How many were candidates.
    pub candidates: usize,
}

/// The result of a fit.
#[derive(Debug, Clone, PartialEq)]
pub struct Identification {
    /// The identified deltas, in `calibration.conf`'s form.
    pub deltas: MountingDeltas,
    /// The tool (fitted, or the one given).
    pub tool: TcpOffset,
    /// Every candidate parameter, identified or fixed.
    pub parameters: Vec<ParameterEstimate>,
    /// Excitation figures.
    pub excitation: Excitation,
    /// Levenberg–Marquardt iterations taken.
    pub iterations: usize,
    /// Rows whose Huber weight ended below 1 (outliers, counted linearly).
    pub downweighted_rows: usize,
    /// Weighted RMS residual per row (m) before and after.
    pub rms_before_m: f64,
    /// See `rms_before_m`.
    pub rms_after_m: f64,
}

/// Why a fit was refused.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum IdentifyError {
    /// The arm is not a Universal Robots standard-DH arm, which `calibration.conf` describes.
    #[error(
        "arm '{model}' does not have the Universal Robots geometry that calibration.conf describes"
    )]
    NotUrGeometry {
        /// The arm's name.
        model: String,
    },
    /// Too few samples for the parameters.
    #[error("{got} paired samples; identification needs at least {need}")]
    TooFewSamples {
        /// Samples given.
        got: usize,
        /// Samples needed.
        need: usize,
    },
    /// A sample holds a NaN or infinite value.
    #[error("sample {index} is not finite")]
    NonFinite {
        /// 0-based sample index.
        index: usize,
    },
    /// The samples do not move the arm enough to identify anything with confidence.
    #[error("too little motion to identify the kinematics: {reason}")]
    InsufficientExcitation {
        /// Which figure fails, with its value.
        reason: String,
        /// The figures.
        excitation: Box<Excitation>,
    },
}

const JOINT_KINDS: [ParameterKind; 4] = [
    ParameterKind::DeltaTheta,
    ParameterKind::DeltaA,
    ParameterKind::DeltaD,
    ParameterKind::DeltaAlpha,
];

/// Candidate parameters: per joint `δθ, δa, δd, δα` (index `4·joint + kind`), then the tool's
/// `x, y, z, rx, ry, rz` when fitted.
fn parameter_name(index: usize) -> (String, ParameterKind) {
    if index < 24 {
        let kind = JOINT_KINDS[index % 4];
        let key = ["delta_theta", "delta_a", "delta_d", "delta_alpha"][index % 4];
        (format!("{key}[{}]", index / 4), kind)
    } else {
        let k = index - 24;
        let name = [
            "tool_x", "tool_y", "tool_z", "tool_rx", "tool_ry", "tool_rz",
        ][k];
        let kind = if k < 3 {
            ParameterKind::ToolPosition
        } else {
            ParameterKind::ToolRotation
        };
        (name.to_owned(), kind)
    }
}

/// The state being fitted: the DH table and the tool.
#[derive(Debug, Clone)]
struct State {
    nominal: [DhParameters; 6],
    deltas: [f64; 24],
    tool_position_m: Vector3<f64>,
    tool_rotation: Matrix3<f64>,
}

impl State {
    fn table(&self) -> [DhParameters; 6] {
        std::array::from_fn(|i| DhParameters {
            theta_offset_rad: self.nominal[i].theta_offset_rad + self.deltas[4 * i],
            a_m: self.nominal[i].a_m + self.deltas[4 * i + 1],
            d_m: self.nominal[i].d_m + self.deltas[4 * i + 2],
            alpha_rad: self.nominal[i].alpha_rad + self.deltas[4 * i + 3],
        })
    }

    fn mounting_deltas(&self) -> MountingDeltas {
        MountingDeltas {
            delta_theta_rad: std::array::from_fn(|i| self.deltas[4 * i]),
            delta_a_m: std::array::from_fn(|i| self.deltas[4 * i + 1]),
            delta_d_m: std::array::from_fn(|i| self.deltas[4 * i + 2]),
            delta_alpha_rad: std::array::from_fn(|i| self.deltas[4 * i + 3]),
        }
    }

    fn tool(&self) -> TcpOffset {
        let rotation_vector = orientation::rotation_vector_from_matrix(&self.tool_rotation);
        TcpOffset {
            position_m: self.tool_position_m.into(),
            rotation_vector_rad: rotation_vector.into(),
        }
    }

    fn apply(&mut self, step: &[f64]) {
        for (delta, s) in self.deltas.iter_mut().zip(step) {
            *delta += s;
        }
        if step.len() == 30 {
            self.tool_position_m += Vector3::new(step[24], step[25], step[26]);
            let rotation = Vector3::new(step[27], step[28], step[29]);
            self.tool_rotation =
                orientation::matrix_from_rotation_vector(&rotation) * self.tool_rotation;
        }
    }
}

/// FK of `table` and tool for `q`, with the Jacobian columns of every parameter (position and
/// rotation rows, base frame): returns `(position, rotation, columns)`.
fn pose_and_jacobian(
    table: &[DhParameters; 6],
    tool_position_m: &Vector3<f64>,
    tool_rotation: &Matrix3<f64>,
    q_rad: &[f64; 6],
    columns: &mut [[f64; 6]],
) -> (Vector3<f64>, Matrix3<f64>) {
    // Frames 0..=6: origin and rotation.
    let mut origins = [Vector3::zeros(); 7];
    let mut rotations = [Matrix3::identity(); 7];
    // Frame i's x axis after joint i's Rz (before Rx(α)), and its origin: where δa and δα act.
    let mut x_axes = [Vector3::zeros(); 6];
    for (i, row) in table.iter().enumerate() {
        let (s, c) = (q_rad[i] + row.theta_offset_rad).sin_cos();
        let (sa, ca) = row.alpha_rad.sin_cos();
        let r = rotations[i];
        let x = r.column(0) * c + r.column(1) * s;
        let y = r.column(1) * c - r.column(0) * s;
        let z = r.column(2).into_owned();
        origins[i + 1] = origins[i] + z * row.d_m + x * row.a_m;
        x_axes[i] = x;
        rotations[i + 1] = Matrix3::from_columns(&[x, y * ca + z * sa, z * ca - y * sa]);
    }
    let flange = rotations[6];
    let position = origins[6] + flange * tool_position_m;
    let rotation = flange * tool_rotation;
    if columns.len() < 24 {
        return (position, rotation);
    }
    for i in 0..6 {
        let z = rotations[i].column(2).into_owned();
        let x = x_axes[i];
        let dtheta_p = z.cross(&(position - origins[i]));
        let dalpha_p = x.cross(&(position - origins[i + 1]));
        columns[4 * i] = [dtheta_p.x, dtheta_p.y, dtheta_p.z, z.x, z.y, z.z];
        columns[4 * i + 1] = [x.x, x.y, x.z, 0.0, 0.0, 0.0];
        columns[4 * i + 2] = [z.x, z.y, z.z, 0.0, 0.0, 0.0];
        columns[4 * i + 3] = [dalpha_p.x, dalpha_p.y, dalpha_p.z, x.x, x.y, x.z];
    }
    if columns.len() == 30 {
        for k in 0..3 {
            let axis = flange.column(k);
            columns[24 + k] = [axis.x, axis.y, axis.z, 0.0, 0.0, 0.0];
            columns[27 + k] = [0.0, 0.0, 0.0, axis.x, axis.y, axis.z];
        }
    }
    (position, rotation)
}

/// The normal equations of one pass over the samples, in base-frame residuals.
struct Normal {
    /// `JᵀWJ`.
    matrix: DMatrix<f64>,
    /// `JᵀWr` (r = measured − model).
    gradient: DVector<f64>,
    /// `Σ ρ(r)`, the robust cost.
    cost: f64,
    /// Rows whose weight is below 1.
    downweighted: usize,
    /// `Σ w‖r‖²` and the row count, for the RMS.
    weighted_squares: f64,
}

/// Residual of each row (base frame, orientation weighted), without Jacobian.
fn row_residual(
    state: &State,
    table: &[DhParameters; 6],
    sample: &BaseSample,
    weight: f64,
) -> [f64; 6] {
    let mut none: [[f64; 6]; 0] = [];
    let (p, r) = pose_and_jacobian(
        table,
        &state.tool_position_m,
        &state.tool_rotation,
        &sample.q_rad,
        &mut none,
    );
    residual(&p, &r, sample, weight)
}

fn residual(p: &Vector3<f64>, r: &Matrix3<f64>, sample: &BaseSample, weight: f64) -> [f64; 6] {
    let dp = sample.position_m - p;
    let dr = orientation::rotation_vector_from_matrix(&(sample.rotation * r.transpose())) * weight;
    [dp.x, dp.y, dp.z, dr.x, dr.y, dr.z]
}

/// A sample with its measured pose taken back to the `base` frame.
#[derive(Debug, Clone, Copy)]
struct BaseSample {
    q_rad: [f64; 6],
    position_m: Vector3<f64>,
    rotation: Matrix3<f64>,
}

fn huber_weight(norm: f64, threshold: f64) -> f64 {
    if norm <= threshold {
        1.0
    } else {
        threshold / norm
    }
}

fn huber_cost(norm: f64, threshold: f64) -> f64 {
    if norm <= threshold {
        norm * norm
    } else {
        2.0 * threshold * norm - threshold * threshold
    }
}

fn median(mut values: Vec<f64>) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn normal_equations(
    state: &State,
    samples: &[BaseSample],
    weight: f64,
    threshold: f64,
    count: usize,
) -> Normal {
    let table = state.table();
    let mut matrix = DMatrix::zeros(count, count);
    let mut gradient = DVector::zeros(count);
    let mut columns = vec![[0.0; 6]; count];
    let (mut cost, mut downweighted, mut weighted_squares) = (0.0, 0, 0.0);
    for sample in samples {
        let (p, r) = pose_and_jacobian(
            &table,
            &state.tool_position_m,
            &state.tool_rotation,
            &sample.q_rad,
            &mut columns,
        );
        let res = residual(&p, &r, sample, weight);
        let norm = res.iter().map(|v| v * v).sum::<f64>().sqrt();
        let w = huber_weight(norm, threshold);
        if w < 1.0 {
            downweighted += 1;
        }
        cost += huber_cost(norm, threshold);
        weighted_squares += w * norm * norm;
        for column in &mut columns {
            for value in &mut column[3..] {
                *value *= weight;
            }
        }
        for a in 0..count {
            let ca = &columns[a];
            gradient[a] += w * (0..6).map(|k| ca[k] * res[k]).sum::<f64>();
            for b in a..count {
                let cb = &columns[b];
                matrix[(a, b)] += w * (0..6).map(|k| ca[k] * cb[k]).sum::<f64>();
            }
        }
    }
    for a in 0..count {
        for b in 0..a {
            matrix[(a, b)] = matrix[(b, a)];
        }
    }
    Normal {
        matrix,
        gradient,
        cost,
        downweighted,
        weighted_squares,
    }
}

/// Robust threshold of the current residuals: `factor × median`, never below a micrometre.
fn threshold_of(state: &State, samples: &[BaseSample], weight: f64, factor: f64) -> f64 {
    let table = state.table();
    let norms = samples
        .iter()
        .map(|s| {
            row_residual(state, &table, s, weight)
                .iter()
                .map(|v| v * v)
                .sum::<f64>()
                .sqrt()
        })
        .collect();
    (factor * median(norms)).max(1e-6)
}

/// Greedy pivoted Cholesky of the scaled normal matrix: parameters in the order they are best
/// determined, stopping where the next one's remaining part falls below `1 / max_condition²`
/// of the first (it is then nearly a combination of those chosen).
fn identifiable_subset(scaled: &DMatrix<f64>, max_condition: f64) -> Vec<usize> {
    let n = scaled.nrows();
    let mut residual = scaled.clone();
    let mut chosen = Vec::new();
    let mut first = 0.0;
    let limit = 1.0 / (max_condition * max_condition);
    loop {
        let best = (0..n).filter(|k| !chosen.contains(k)).max_by(|&a, &b| {
            residual[(a, a)]
                .total_cmp(&residual[(b, b)])
                .then(b.cmp(&a))
        });
        let Some(k) = best else { break };
        let pivot = residual[(k, k)];
        if chosen.is_empty() {
            first = pivot;
        }
        if !(pivot > first * limit && pivot > 0.0) {
            break;
        }
        chosen.push(k);
        let column: Vec<f64> = (0..n).map(|i| residual[(i, k)]).collect();
        for i in 0..n {
            for j in 0..n {
                residual[(i, j)] -= column[i] * column[j] / pivot;
            }
        }
    }
    chosen.sort_unstable();
    chosen
}

fn joint_spread(samples: &[PairedSample]) -> [f64; 6] {
    let n = samples.len().max(1) as f64;
    std::array::from_fn(|j| {
        let mean = samples.iter().map(|s| s.q_rad[j]).sum::<f64>() / n;
        (samples
            .iter()
            .map(|s| (s.q_rad[j] - mean).powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
    })
}

fn condition_number(matrix: &DMatrix<f64>) -> f64 {
    let eigen = matrix.clone().symmetric_eigen();
    let max = eigen.eigenvalues.max();
    let min = eigen.eigenvalues.min();
    if min <= 0.0 {
        f64::INFINITY
    } else {
        (max / min).sqrt()
    }
}

fn submatrix(matrix: &DMatrix<f64>, chosen: &[usize]) -> DMatrix<f64> {
    DMatrix::from_fn(chosen.len(), chosen.len(), |i, j| {
        matrix[(chosen[i], chosen[j])]
    })
}

/// Fits `arm`'s kinematic deltas (and the tool, with [`IdentifyOptions::fit_tool`]) to
/// `samples`, whose measured poses are in `frame`; `tool` is the known tool or the fit's start.
#[allow(
    clippy::too_many_lines,
    reason = "one fit: checks, subset, iterations, uncertainty"
)]
pub fn identify(
    arm: &ArmDescription,
    frame: OutputFrame,
    tool: &TcpOffset,
    samples: &[PairedSample],
    options: &IdentifyOptions,
) -> Result<Identification, IdentifyError> {
    let geometry = UrGeometry::from_arm(arm).ok_or_else(|| IdentifyError::NotUrGeometry {
        model: arm.name.clone(),
    })?;
    let count = if options.fit_tool { 30 } else { 24 };
    if samples.len() < 2 * count {
        return Err(IdentifyError::TooFewSamples {
            got: samples.len(),
            need: 2 * count,
        });
    }
    if let Some(index) = samples.iter().position(|s| {
        !(s.q_rad.iter().all(|v| v.is_finite())
            && s.measured.position_m.iter().all(|v| v.is_finite())
            && s.measured.rotation.iter().all(|v| v.is_finite()))
    }) {
        return Err(IdentifyError::NonFinite { index });
    }
    let base_from_frame = frame.frame_from_base().inverse();
    let base_samples: Vec<BaseSample> = samples
        .iter()
        .map(|s| BaseSample {
            q_rad: s.q_rad,
            position_m: base_from_frame.rotation * s.measured.position_m,
            rotation: base_from_frame.rotation.matrix()
                * orientation::matrix_from_quaternion(&orientation::quaternion_from_matrix(
                    &s.measured.rotation,
                )),
        })
        .collect();
    let mut state = State {
        nominal: geometry.dh(),
        deltas: [0.0; 24],
        tool_position_m: Vector3::from(tool.position_m),
        tool_rotation: *tool.flange_from_tcp().rotation.matrix(),
    };
    let weight = options.orientation_weight_m_per_rad;
    let spread = joint_spread(samples);
    let moving = spread
        .iter()
        .filter(|s| **s >= options.min_joint_spread_rad)
        .count();

    // The subset is chosen once, at the start, from the column-scaled normal matrix.
    let threshold = threshold_of(&state, &base_samples, weight, options.huber_factor);
    let start = normal_equations(&state, &base_samples, weight, threshold, count);
    let scales: Vec<f64> = (0..count)
        .map(|k| {
            let d = start.matrix[(k, k)].sqrt();
            if d > 0.0 { 1.0 / d } else { 0.0 }
        })
        .collect();
    let scaled = DMatrix::from_fn(count, count, |i, j| {
        start.matrix[(i, j)] * scales[i] * scales[j]
    });
    let chosen = identifiable_subset(&scaled, options.max_condition);
    let excitation = Excitation {
        joint_spread_rad: spread,
        condition_number: condition_number(&submatrix(&scaled, &chosen)),
        identified: chosen.len(),
        candidates: count,
    };
    if moving < options.min_moving_joints {
        return Err(IdentifyError::InsufficientExcitation {
            reason: format!(
                "{moving} joints moved by at least {} rad (standard deviation), {} needed",
                options.min_joint_spread_rad, options.min_moving_joints
            ),
            excitation: Box::new(excitation),
        });
    }
    if chosen.len() < count / 2 {
        return Err(IdentifyError::InsufficientExcitation {
            reason: format!(
                "only {} of {count} parameters are distinguishable within condition number {}",
                chosen.len(),
                options.max_condition
            ),
            excitation: Box::new(excitation),
        });
    }
    let rms_before_m = (start.weighted_squares / samples.len() as f64).sqrt();

    let mut damping = 1e-3;
    let mut iterations = 0;
    let mut normal = start;
    let mut threshold = threshold;
    for _ in 0..options.max_iterations {
        iterations += 1;
        let a = submatrix(&normal.matrix, &chosen);
        let g = DVector::from_iterator(chosen.len(), chosen.iter().map(|&k| normal.gradient[k]));
        let mut improved = false;
        while damping < 1e10 {
            let mut damped = a.clone();
            for i in 0..chosen.len() {
                damped[(i, i)] += damping * a[(i, i)].max(1e-30);
            }
            let Some(step) = damped.cholesky().map(|c| c.solve(&g)) else {
                damping *= 10.0;
                continue;
            };
            let mut full = vec![0.0; count];
            for (i, &k) in chosen.iter().enumerate() {
                full[k] = step[i];
            }
            let mut candidate = state.clone();
            candidate.apply(&full);
            let candidate_normal =
                normal_equations(&candidate, &base_samples, weight, threshold, count);
            if candidate_normal.cost < normal.cost {
                let relative = (normal.cost - candidate_normal.cost) / normal.cost.max(1e-300);
                state = candidate;
                normal = candidate_normal;
                damping = (damping * 0.1).max(1e-12);
                improved = relative > 1e-12;
                break;
            }
            damping *= 10.0;
        }
        if !improved {
            break;
        }
        // The robust scale follows the shrinking residuals.
        let next = threshold_of(&state, &base_samples, weight, options.huber_factor);
        if (next - threshold).abs() > 1e-3 * threshold {
            threshold = next;
            normal = normal_equations(&state, &base_samples, weight, threshold, count);
        }
    }

    let dof = (6 * samples.len()).saturating_sub(chosen.len()).max(1) as f64;
    let variance = normal.weighted_squares / dof;
    let covariance = submatrix(&normal.matrix, &chosen).try_inverse();
    let mut std_devs = vec![None; count];
    if let Some(covariance) = covariance {
        for (i, &k) in chosen.iter().enumerate() {
            std_devs[k] = Some((covariance[(i, i)] * variance).max(0.0).sqrt());
        }
    }
    let tool_values = {
        let t = state.tool();
        let mut v = t.position_m.to_vec();
        v.extend(t.rotation_vector_rad);
        v
    };
    let parameters = (0..count)
        .map(|k| {
            let (name, kind) = parameter_name(k);
            ParameterEstimate {
                name,
                kind,
                value: if k < 24 {
                    state.deltas[k]
                } else {
                    tool_values[k - 24]
                },
                std_dev: std_devs[k],
                identified: chosen.contains(&k),
            }
        })
        .collect();
    Ok(Identification {
        deltas: state.mounting_deltas(),
        tool: state.tool(),
        parameters,
        excitation,
        iterations,
        downweighted_rows: normal.downweighted,
        rms_before_m,
        rms_after_m: (normal.weighted_squares / samples.len() as f64).sqrt(),
    })
}

/// Error figures of a model on samples: position (m) and rotation angle (rad).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PoseErrors {
    /// Samples evaluated.
    pub count: usize,
    /// Mean absolute position error (m).
    pub position_mae_m: f64,
    /// RMS position error (m).
    pub position_rmse_m: f64,
    /// Largest position error (m).
    pub position_max_m: f64,
    /// Mean rotation angle (rad).
    pub angle_mae_rad: f64,
    /// RMS rotation angle (rad).
    pub angle_rmse_rad: f64,
    /// Largest rotation angle (rad).
    pub angle_max_rad: f64,
}

/// The errors of `model`'s FK against the measured poses of `samples` (rows whose joints the
/// model refuses are skipped).
#[must_use]
pub fn pose_errors(model: &RobotModel, samples: &[PairedSample]) -> PoseErrors {
    let mut errors = PoseErrors::default();
    let (mut position_squares, mut angle_squares) = (0.0, 0.0);
    for sample in samples {
        let Ok(pose) = model.pose(&sample.q_rad) else {
            continue;
        };
        let position = (pose.position_m - sample.measured.position_m).norm();
        let angle = orientation::rotation_angle_between(
            &orientation::quaternion_from_matrix(&pose.rotation),
            &orientation::quaternion_from_matrix(&sample.measured.rotation),
        );
        errors.count += 1;
        errors.position_mae_m += position;
        errors.angle_mae_rad += angle;
        position_squares += position * position;
        angle_squares += angle * angle;
        errors.position_max_m = errors.position_max_m.max(position);
        errors.angle_max_rad = errors.angle_max_rad.max(angle);
    }
    if errors.count > 0 {
        let n = errors.count as f64;
        errors.position_mae_m /= n;
        errors.angle_mae_rad /= n;
        errors.position_rmse_m = (position_squares / n).sqrt();
        errors.angle_rmse_rad = (angle_squares / n).sqrt();
    }
    errors
}

/// Splits `len` time-ordered samples into a training block and the held-out later block of
/// `holdout_fraction` (clamped to [0, 0.9]): returns the index where the held-out block begins.
#[must_use]
pub fn holdout_start(len: usize, holdout_fraction: f64) -> usize {
    let fraction = if holdout_fraction.is_finite() {
        holdout_fraction.clamp(0.0, 0.9)
    } else {
        0.0
    };
    #[allow(
        clippy::cast_sign_loss,
        reason = "the fraction is clamped to [0, 0.9], so the product is non-negative"
    )]
    let held_out = (len as f64 * fraction).round() as usize;
    len - held_out.min(len)
}
