//! Identification of a Universal Robots arm's kinematics from its own stream: paired (joint
//! angles, measured TCP pose) samples in, `calibration.conf` deltas (and optionally the tool)
//! out.
//!
//! Owns the damped least-squares fit (Levenberg–Marquardt with an analytic Jacobian), the choice
//! of an identifiable subset of parameters (pivoted Cholesky of the column-scaled normal matrix:
//! weak excitation makes parameters indistinguishable), the robust (Huber) weighting of rows, the
//! excitation check, the exact conversion of the fitted chain to `calibration.conf`'s deltas and
//! the error figures of a model on samples. Pure and deterministic: the same samples give the
//! same estimate; no I/O, no clock.
//!
//! The fit is not done in `calibration.conf`'s own form. Axes 2–4 of a UR arm are nominally
//! parallel; a real arm's are slightly skew, and standard DH puts the common normal of two
//! nearly parallel axes hundreds of metres away (the controller's files carry `δd` of that size,
//! cancelling along the three axes). Small steps from the nominal table cannot reach that point,
//! and at nominal the three `δd` are one translation. So joints whose axis is nominally parallel
//! to the next (joints 2 and 3) are fitted in Hayati's form, `Rz(q + θ) · Tx(a) · Rx(α) · Ry(β)`:
//! a tilt `β` about the link's y axis in place of `δd`, well conditioned for parallel and skew
//! axes alike. The fitted chain is then rewritten in standard DH: for each pair of consecutive
//! axes their common normal gives `θ`, `d`, `a` and `α`; base and flange stay what UR defines
//! (frame 0 is the base, whose z axis is joint 1's; the flange is the last DH frame). FK with
//! the written deltas equals the fitted chain's to rounding.

use std::f64::consts::TAU;

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
    /// Hayati's `β` of a joint whose axis is nominally parallel to the next: the link's tilt
    /// about its own y axis (rad), fitted in place of `delta_d`.
    Tilt,
    /// Tool position along a flange axis (m).
    ToolPosition,
    /// Tool rotation about a flange axis (rad).
    ToolRotation,
}

/// One parameter's estimate, in the fit's own form (the module doc): small deltas to the nominal
/// table, with a tilt `beta[j]` in place of `delta_d[j]` at joints whose axis is nominally
/// parallel to the next. [`Identification::deltas`] holds the same chain in `calibration.conf`'s
/// form, whose `δθ` and `δd` at skew axes can be far larger than these.
#[derive(Debug, Clone, PartialEq)]
pub struct ParameterEstimate {
    /// `delta_theta[1]`, `beta[2]` (0-based joint, as in `calibration.conf`'s lists), `tool_x`,
    /// `tool_rz`.
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
    /// The identified chain as `calibration.conf` deltas to the nominal table: FK with them is
    /// the fitted chain's FK (skew axes give `δd` of up to hundreds of metres, as the
    /// controller's own files have).
    pub deltas: MountingDeltas,
    /// The tool (fitted, or the one given).
    pub tool: TcpOffset,
    /// Every candidate parameter of the fit, identified or fixed.
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

/// `|sin α|` of a nominal link below which its joint's axis counts as parallel to the next.
const NOMINALLY_PARALLEL_SIN: f64 = 1e-9;

/// `|sin|` of the angle between two consecutive axes below which the conversion to DH takes them
/// as parallel (the common normal through the frame's origin, `d = 0`). Below it, the tilt left
/// out moves the flange by at most this times the arm's reach; above it, the common normal lies
/// `offset / sin` away and FK through that `d` rounds to about `1e-16 · offset / sin`. Both are
/// tens of nanometres at the threshold; at real skews (~1e-3) the rounding is ~1e-13 m.
const PARALLEL_SIN: f64 = 1e-8;

/// Candidate parameters: per joint `δθ, δa, δd (or β where tilted), δα` (index
/// `4·joint + kind`), then the tool's `x, y, z, rx, ry, rz` when fitted.
fn parameter_name(index: usize, tilted: [bool; 6]) -> (String, ParameterKind) {
    if index < 24 {
        let joint = index / 4;
        let (key, kind) = if index % 4 == 2 && tilted[joint] {
            ("beta", ParameterKind::Tilt)
        } else {
            (
                ["delta_theta", "delta_a", "delta_d", "delta_alpha"][index % 4],
                JOINT_KINDS[index % 4],
            )
        };
        (format!("{key}[{joint}]"), kind)
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

/// One link of the fitted chain: `Rz(q + θ) · Tz(d) · Tx(a) · Rx(α)`, followed by `Ry(β)` when
/// `tilt_rad` is given (Hayati's form; `d` then stays at its nominal value).
#[derive(Debug, Clone, Copy, PartialEq)]
struct FitLink {
    dh: DhParameters,
    tilt_rad: Option<f64>,
}

/// The state being fitted: the chain's deltas and the tool.
#[derive(Debug, Clone)]
struct State {
    nominal: [DhParameters; 6],
    /// Joints fitted in Hayati's form (their axis is nominally parallel to the next).
    tilted: [bool; 6],
    /// Per joint `δθ, δa, δd (or β where tilted), δα`.
    deltas: [f64; 24],
    tool_position_m: Vector3<f64>,
    tool_rotation: Matrix3<f64>,
}

impl State {
    fn links(&self) -> [FitLink; 6] {
        std::array::from_fn(|i| {
            let nominal = self.nominal[i];
            let third = self.deltas[4 * i + 2];
            FitLink {
                dh: DhParameters {
                    theta_offset_rad: nominal.theta_offset_rad + self.deltas[4 * i],
                    a_m: nominal.a_m + self.deltas[4 * i + 1],
                    d_m: nominal.d_m + if self.tilted[i] { 0.0 } else { third },
                    alpha_rad: nominal.alpha_rad + self.deltas[4 * i + 3],
                },
                tilt_rad: self.tilted[i].then_some(third),
            }
        })
    }

    fn mounting_deltas(&self) -> MountingDeltas {
        mounting_deltas_of(&self.links(), &self.nominal)
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

/// The frames of a fitted chain at `q_rad`, base frame: origins and rotations of frames 0..=6
/// (6: the flange), and each joint's x axis after its `Rz` (where `δa` and `δα` act).
struct Frames {
    origins: [Vector3<f64>; 7],
    rotations: [Matrix3<f64>; 7],
    x_axes: [Vector3<f64>; 6],
}

fn frames(links: &[FitLink; 6], q_rad: &[f64; 6]) -> Frames {
    let mut origins = [Vector3::zeros(); 7];
    let mut rotations = [Matrix3::identity(); 7];
    let mut x_axes = [Vector3::zeros(); 6];
    for (i, link) in links.iter().enumerate() {
        (origins[i + 1], rotations[i + 1], x_axes[i]) =
            through_link(&origins[i], &rotations[i], link, q_rad[i]);
    }
    Frames {
        origins,
        rotations,
        x_axes,
    }
}

/// The frame after `link` turned by `q_rad` from the frame at `origin` with `rotation`:
/// `(origin, rotation, x axis after Rz)`.
fn through_link(
    origin: &Vector3<f64>,
    rotation: &Matrix3<f64>,
    link: &FitLink,
    q_rad: f64,
) -> (Vector3<f64>, Matrix3<f64>, Vector3<f64>) {
    let row = &link.dh;
    let (s, c) = (q_rad + row.theta_offset_rad).sin_cos();
    let (sa, ca) = row.alpha_rad.sin_cos();
    let x = rotation.column(0) * c + rotation.column(1) * s;
    let y = rotation.column(1) * c - rotation.column(0) * s;
    let z = rotation.column(2).into_owned();
    let next_origin = origin + z * row.d_m + x * row.a_m;
    let y_alpha = y * ca + z * sa;
    let z_alpha = z * ca - y * sa;
    let next_rotation = match link.tilt_rad {
        Some(beta) => {
            let (sb, cb) = beta.sin_cos();
            Matrix3::from_columns(&[x * cb - z_alpha * sb, y_alpha, x * sb + z_alpha * cb])
        }
        None => Matrix3::from_columns(&[x, y_alpha, z_alpha]),
    };
    (next_origin, next_rotation, x)
}

/// FK of `links` and tool for `q`, with the Jacobian columns of every parameter (position and
/// rotation rows, base frame) when `columns` has room for them: returns `(position, rotation)`.
fn pose_and_jacobian(
    links: &[FitLink; 6],
    tool_position_m: &Vector3<f64>,
    tool_rotation: &Matrix3<f64>,
    q_rad: &[f64; 6],
    columns: &mut [[f64; 6]],
) -> (Vector3<f64>, Matrix3<f64>) {
    let Frames {
        origins,
        rotations,
        x_axes,
    } = frames(links, q_rad);
    let flange = rotations[6];
    let position = origins[6] + flange * tool_position_m;
    let rotation = flange * tool_rotation;
    if columns.len() < 24 {
        return (position, rotation);
    }
    for (i, link) in links.iter().enumerate() {
        let z = rotations[i].column(2).into_owned();
        let x = x_axes[i];
        let dtheta_p = z.cross(&(position - origins[i]));
        let dalpha_p = x.cross(&(position - origins[i + 1]));
        columns[4 * i] = [dtheta_p.x, dtheta_p.y, dtheta_p.z, z.x, z.y, z.z];
        columns[4 * i + 1] = [x.x, x.y, x.z, 0.0, 0.0, 0.0];
        columns[4 * i + 2] = if link.tilt_rad.is_some() {
            // `Ry(β)` turns everything after it about the link's y axis (after `Rx(α)`, which
            // `Ry` leaves in place) through the link's origin.
            let y = rotations[i + 1].column(1).into_owned();
            let dbeta_p = y.cross(&(position - origins[i + 1]));
            [dbeta_p.x, dbeta_p.y, dbeta_p.z, y.x, y.y, y.z]
        } else {
            [z.x, z.y, z.z, 0.0, 0.0, 0.0]
        };
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

/// `angle` taken into (−π, π].
fn wrapped(angle_rad: f64) -> f64 {
    angle_rad - TAU * (angle_rad / TAU).round()
}

/// The standard-DH table with the FK of `links` (any mix of DH and Hayati links).
///
/// Walks the fitted chain's axes at `q = 0`: frame 0 is the base (joint 1's axis is its z axis in
/// both forms); for joints 1–5 the common normal of axis `i` and axis `i + 1` is frame `i`'s x
/// axis, its foot on axis `i + 1` frame `i`'s origin, which fixes `θ`, `d`, `a` and `α`; the
/// flange row takes the fitted flange frame as it is (its x axis is normal to axis 6 and its origin
/// on a normal of it, as in every DH row). Each DH frame is advanced from the row just found, as
/// FK does, so rounding does not accumulate along the chain. The sign of each common normal
/// follows the fitted frame's x axis, so the table stays near the nominal one wherever the axes
/// allow it.
fn dh_table_of(links: &[FitLink; 6]) -> [DhParameters; 6] {
    let fitted = frames(links, &[0.0; 6]);
    let mut origin = Vector3::zeros();
    let mut rotation = Matrix3::identity();
    let mut rows = [DhParameters {
        a_m: 0.0,
        alpha_rad: 0.0,
        d_m: 0.0,
        theta_offset_rad: 0.0,
    }; 6];
    for (i, row) in rows.iter_mut().enumerate() {
        let x = rotation.column(0).into_owned();
        let z = rotation.column(2).into_owned();
        let next = fitted.rotations[i + 1];
        let z_next = next.column(2).into_owned();
        let (d_m, x_next, a_m) = if i + 1 < links.len() {
            let (d_m, mut x_next, mut a_m) =
                common_normal(&origin, &x, &z, &fitted.origins[i + 1], &z_next);
            if x_next.dot(&next.column(0)) < 0.0 {
                x_next = -x_next;
                a_m = -a_m;
            }
            (d_m, x_next, a_m)
        } else {
            let offset = fitted.origins[i + 1] - origin;
            let x_flange = next.column(0);
            let x_next = (x_flange - z * z.dot(&x_flange)).normalize();
            (offset.dot(&z), x_next, offset.dot(&x_next))
        };
        *row = DhParameters {
            theta_offset_rad: x.cross(&x_next).dot(&z).atan2(x.dot(&x_next)),
            d_m,
            a_m,
            alpha_rad: z.cross(&z_next).dot(&x_next).atan2(z.dot(&z_next)),
        };
        let dh_link = FitLink {
            dh: *row,
            tilt_rad: None,
        };
        (origin, rotation, _) = through_link(&origin, &rotation, &dh_link, 0.0);
    }
    rows
}

/// The common normal of the axis of the frame at `origin` (axes `x`, `z`) and the axis through
/// `point` along `direction` (unit vectors): `(d, normal, a)`, its foot on the first axis at
/// `origin + d·z`, its direction and its signed length `a` along it to the second axis. Parallel
/// axes (within [`PARALLEL_SIN`]) take the normal through `origin`; coincident ones the frame's
/// own `x`.
fn common_normal(
    origin: &Vector3<f64>,
    x: &Vector3<f64>,
    z: &Vector3<f64>,
    point: &Vector3<f64>,
    direction: &Vector3<f64>,
) -> (f64, Vector3<f64>, f64) {
    let offset = point - origin;
    let normal = z.cross(direction);
    let sin_squared = normal.norm_squared();
    if sin_squared > PARALLEL_SIN * PARALLEL_SIN {
        // The closest points of the two lines, from `normal` itself rather than `1 − cos²`,
        // which cancels for nearly parallel axes.
        let d_m = offset.cross(direction).dot(&normal) / sin_squared;
        let along_m = offset.cross(z).dot(&normal) / sin_squared;
        let unit_normal = normal / sin_squared.sqrt();
        let a_m = (offset + direction * along_m - z * d_m).dot(&unit_normal);
        (d_m, unit_normal, a_m)
    } else {
        // Where the second axis crosses the plane normal to the first through `origin`.
        let in_plane = offset - direction * (offset.dot(z) / direction.dot(z));
        let a_m = in_plane.norm();
        let unit_normal = if a_m > 0.0 { in_plane / a_m } else { *x };
        (0.0, unit_normal, a_m)
    }
}

/// `links` as `calibration.conf` deltas to `nominal`, angles taken within π of the nominal.
fn mounting_deltas_of(links: &[FitLink; 6], nominal: &[DhParameters; 6]) -> MountingDeltas {
    let rows = dh_table_of(links);
    MountingDeltas {
        delta_theta_rad: std::array::from_fn(|i| {
            wrapped(rows[i].theta_offset_rad - nominal[i].theta_offset_rad)
        }),
        delta_a_m: std::array::from_fn(|i| rows[i].a_m - nominal[i].a_m),
        delta_d_m: std::array::from_fn(|i| rows[i].d_m - nominal[i].d_m),
        delta_alpha_rad: std::array::from_fn(|i| wrapped(rows[i].alpha_rad - nominal[i].alpha_rad)),
    }
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
fn row_residual(state: &State, links: &[FitLink; 6], sample: &BaseSample, weight: f64) -> [f64; 6] {
    let mut none: [[f64; 6]; 0] = [];
    let (p, r) = pose_and_jacobian(
        links,
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
    let links = state.links();
    let mut matrix = DMatrix::zeros(count, count);
    let mut gradient = DVector::zeros(count);
    let mut columns = vec![[0.0; 6]; count];
    let (mut cost, mut downweighted, mut weighted_squares) = (0.0, 0, 0.0);
    for sample in samples {
        let (p, r) = pose_and_jacobian(
            &links,
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
    let links = state.links();
    let norms = samples
        .iter()
        .map(|s| {
            row_residual(state, &links, s, weight)
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
    let nominal = geometry.dh();
    let mut state = State {
        nominal,
        tilted: std::array::from_fn(|i| {
            i + 1 < nominal.len() && nominal[i].alpha_rad.sin().abs() < NOMINALLY_PARALLEL_SIN
        }),
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
            let (name, kind) = parameter_name(k, state.tilted);
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

#[cfg(test)]
#[allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a test that fails an expectation fails the test"
)]
mod tests {
    use super::*;
    use crate::kinematics::{Chain, DhConvention};
    use crate::model::calibration::{Calibration, CalibrationForm};
    use crate::model::catalog;
    use std::f64::consts::PI;

    fn ur10e() -> [DhParameters; 6] {
        UrGeometry::from_arm(&catalog::arm("ur10e").unwrap())
            .unwrap()
            .dh()
    }

    /// Element `k` of a Weyl sequence in [−1, 1): evenly spread, deterministic test inputs.
    fn spread(k: usize, stride: f64) -> f64 {
        2.0 * (k as f64 * stride).fract() - 1.0
    }

    fn configurations(count: usize) -> impl Iterator<Item = [f64; 6]> {
        const STRIDES: [f64; 6] = [
            0.618_033_988_7,
            0.414_213_562_4,
            0.732_050_807_6,
            0.236_067_977_5,
            0.645_751_311_1,
            0.162_277_660_2,
        ];
        (1..=count).map(|k| std::array::from_fn(|j| PI * spread(k, STRIDES[j])))
    }

    /// The UR10e's fitted chain with deltas of the given sizes; `skew_rad` the tilts (`α` and
    /// `β`) of the nominally parallel axes.
    fn state_with(seed: usize, skew_rad: f64) -> State {
        let nominal = ur10e();
        let tilted = [false, true, true, false, false, false];
        let deltas = std::array::from_fn(|k| {
            let v = spread(seed * 24 + k + 1, 0.754_877_666_2);
            match (k % 4, tilted[k / 4]) {
                (0, _) => 0.2 * v,
                (1, _) | (2, false) => 0.02 * v,
                (2 | 3, true) => skew_rad * v.signum() * (0.5 + 0.5 * v.abs()),
                _ => 3e-3 * v,
            }
        });
        State {
            nominal,
            tilted,
            deltas,
            tool_position_m: Vector3::zeros(),
            tool_rotation: Matrix3::identity(),
        }
    }

    fn fitted_pose(links: &[FitLink; 6], q: &[f64; 6]) -> (Vector3<f64>, Matrix3<f64>) {
        pose_and_jacobian(links, &Vector3::zeros(), &Matrix3::identity(), q, &mut [])
    }

    /// The largest position (m) and rotation (Frobenius) difference between the chain of
    /// `links` and FK with `deltas` on `nominal`.
    fn largest_difference(
        links: &[FitLink; 6],
        nominal: &[DhParameters; 6],
        deltas: &MountingDeltas,
    ) -> (f64, f64) {
        let chain = Chain::from_dh(DhConvention::Standard, &deltas.apply(nominal));
        configurations(500).fold((0.0, 0.0), |(position, rotation), q| {
            let (p, r) = fitted_pose(links, &q);
            let pose = chain.pose_unchecked(&q);
            (
                f64::max(position, (pose.position_m - p).norm()),
                f64::max(rotation, (pose.rotation - r).norm()),
            )
        })
    }

    #[test]
    fn the_written_deltas_reproduce_the_fitted_chain_whatever_the_skew() {
        // Real skews (~1e-3) put the common normals hundreds of metres away; 1e-12 and 0 take
        // the parallel branch.
        for skew_rad in [3e-3, 1e-4, 1e-6, 1e-12, 0.0] {
            for seed in 0..4 {
                let state = state_with(seed, skew_rad);
                let links = state.links();
                let deltas = mounting_deltas_of(&links, &state.nominal);
                let (position_m, rotation) = largest_difference(&links, &state.nominal, &deltas);
                assert!(
                    position_m < 1e-9 && rotation < 1e-9,
                    "skew {skew_rad:e}, seed {seed}: {position_m:e} m, {rotation:e}; {deltas:?}"
                );
                if skew_rad >= 1e-4 {
                    let far = deltas.delta_d_m[1..4].iter().any(|d| d.abs() > 10.0);
                    assert!(far, "skew {skew_rad:e}: {deltas:?}");
                }
            }
        }
    }

    #[test]
    fn a_standard_dh_chain_is_written_as_its_own_table() {
        // The example file's chain, given link by link in DH, comes back as the file's deltas:
        // the common normals (and their signs) are the ones the controller writes.
        let Calibration {
            form: CalibrationForm::MountingDeltas(example),
            ..
        } = Calibration::parse(
            include_str!("../../../config/examples/calibration.conf"),
            "calibration.conf",
        )
        .unwrap()
        else {
            panic!("conf form");
        };
        let nominal = ur10e();
        let rows = example.apply(&nominal);
        let links: [FitLink; 6] = std::array::from_fn(|i| FitLink {
            dh: rows[i],
            tilt_rad: None,
        });
        let written = mounting_deltas_of(&links, &nominal);
        for i in 0..6 {
            let pairs = [
                (
                    written.delta_theta_rad[i],
                    example.delta_theta_rad[i],
                    1e-12,
                ),
                (written.delta_a_m[i], example.delta_a_m[i], 1e-12),
                (written.delta_d_m[i], example.delta_d_m[i], 1e-9),
                (
                    written.delta_alpha_rad[i],
                    example.delta_alpha_rad[i],
                    1e-12,
                ),
            ];
            for (got, want, tolerance) in pairs {
                assert!(
                    (got - want).abs() < tolerance,
                    "joint {i}: {got} against {want}"
                );
            }
        }
    }

    #[test]
    fn the_jacobian_columns_are_the_derivatives_of_the_pose() {
        let mut state = state_with(2, 2e-3);
        state.tool_position_m = Vector3::new(0.01, -0.02, 0.15);
        state.tool_rotation =
            orientation::matrix_from_rotation_vector(&Vector3::new(0.1, 0.2, -0.3));
        let pose_of = |state: &State, q: &[f64; 6]| {
            pose_and_jacobian(
                &state.links(),
                &state.tool_position_m,
                &state.tool_rotation,
                q,
                &mut [],
            )
        };
        for q in configurations(20) {
            let mut columns = [[0.0; 6]; 30];
            pose_and_jacobian(
                &state.links(),
                &state.tool_position_m,
                &state.tool_rotation,
                &q,
                &mut columns,
            );
            for (k, column) in columns.iter().enumerate() {
                let h = 1e-6;
                let mut step = [0.0; 30];
                step[k] = h;
                let mut plus = state.clone();
                plus.apply(&step);
                step[k] = -h;
                let mut minus = state.clone();
                minus.apply(&step);
                let (p_plus, r_plus) = pose_of(&plus, &q);
                let (p_minus, r_minus) = pose_of(&minus, &q);
                let dp = (p_plus - p_minus) / (2.0 * h);
                let dr = orientation::rotation_vector_from_matrix(&(r_plus * r_minus.transpose()))
                    / (2.0 * h);
                let numeric = [dp.x, dp.y, dp.z, dr.x, dr.y, dr.z];
                let error = (0..6)
                    .map(|i| (numeric[i] - column[i]).abs())
                    .fold(0.0, f64::max);
                assert!(
                    error < 1e-7,
                    "{}: {column:?} against {numeric:?}",
                    parameter_name(k, state.tilted).0
                );
            }
        }
    }
}
