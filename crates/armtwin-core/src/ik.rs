//! Inverse kinematics of Universal Robots arms: every joint configuration that puts the TCP at a
//! given pose.
//!
//! Owns the analytic closed form of the UR geometry (standard DH with
//! `α = [π/2, 0, 0, π/2, −π/2, 0]`, `a₁ = a₄ = a₅ = a₆ = 0`, `d₂ = d₃ = 0`: up to 8 solutions, two
//! per shoulder, elbow and wrist choice) and the Newton refinement that carries those solutions
//! onto a calibrated chain, whose geometry has no closed form. Pure: a function of the model and
//! the target pose, no state, no I/O.
//!
//! The closed form works in frame 1 of the arm (`x₁ = (c₁, s₁, 0)`, `y₁ = base z`,
//! `z₁ = (s₁, −c₁, 0)`): joints 2–4 turn about axes parallel to `z₁`, so the wrist centre's `z₁`
//! component is `d₄` whatever they do (this fixes `q₁`), the flange's `z` axis has `z₁`
//! component `cos q₅` (this fixes `q₅`), the flange axes' `z₁` components fix `q₆`, and what is
//! left is a planar two-link problem for `q₂, q₃` with `q₄` closing the sum `q₂ + q₃ + q₄`.

use std::f64::consts::{PI, TAU};

use nalgebra::{IsometryMatrix3, Matrix3, Matrix6, Rotation3, Translation3, Vector3, Vector6};
use thiserror::Error;

use crate::kinematics::{self, DhConvention, DhParameters, Pose};
use crate::model::{ArmDescription, JointLimits, RobotModel};
use crate::orientation;

/// Tolerance on a cosine or sine beyond ±1 that is still taken as a boundary (rounding), not as
/// an unreachable pose.
const BOUNDARY_TOLERANCE: f64 = 1e-10;
/// `|sin q₅|` below which the wrist is singular (axes 4 and 6 aligned): only `q₄ + q₆` is fixed.
const WRIST_SINGULAR_SIN: f64 = 1e-10;
/// A solution is accepted when FK reproduces the target to this (m and rad).
pub const SOLUTION_TOLERANCE: f64 = 1e-10;
/// Newton iterations per solution at most; a converging solve takes 3–5.
const NEWTON_ITERATIONS: usize = 60;
/// Solutions closer than this in every joint (rad) are one solution (merged branches).
const SAME_SOLUTION_RAD: f64 = 1e-7;

/// `[d1, a2, a3, d4, d5, d6]` (m) of an arm with exactly the Universal Robots structure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UrGeometry {
    /// `[d1, a2, a3, d4, d5, d6]` (m).
    pub d1_a2_a3_d4_d5_d6_m: [f64; 6],
}

impl UrGeometry {
    /// The geometry of `arm` if it is a standard-DH table with the UR structure
    /// ([`kinematics::ur_lengths_m`]) and the lengths the closed form divides by are not zero.
    #[must_use]
    pub fn from_arm(arm: &ArmDescription) -> Option<Self> {
        if arm.convention != DhConvention::Standard {
            return None;
        }
        let lengths = kinematics::ur_lengths_m(&arm.dh)?;
        let [_, a2, a3, _, _, d6] = lengths;
        (a2 != 0.0 && a3 != 0.0 && d6 != 0.0).then_some(Self {
            d1_a2_a3_d4_d5_d6_m: lengths,
        })
    }

    /// The standard-DH table of this geometry.
    #[must_use]
    pub fn dh(&self) -> [DhParameters; 6] {
        let [d1, a2, a3, d4, d5, d6] = self.d1_a2_a3_d4_d5_d6_m;
        let row = |a_m: f64, alpha_rad: f64, d_m: f64| DhParameters {
            a_m,
            alpha_rad,
            d_m,
            theta_offset_rad: 0.0,
        };
        [
            row(0.0, PI / 2.0, d1),
            row(a2, 0.0, 0.0),
            row(a3, 0.0, 0.0),
            row(0.0, PI / 2.0, d4),
            row(0.0, -PI / 2.0, d5),
            row(0.0, 0.0, d6),
        ]
    }
}

/// Which side of the base the arm reaches from: the two solutions for `q₁`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shoulder {
    /// `q₁ = ψ + asin(d₄ / r)`, `ψ` the wrist centre's azimuth, `r` its distance from base z.
    Left,
    /// `q₁ = ψ + π − asin(d₄ / r)`.
    Right,
}

/// Where the elbow sits relative to the line from the shoulder to the wrist.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Elbow {
    /// The elbow is above that line (along base z).
    Up,
    /// The elbow is below it.
    Down,
}

/// The two solutions for `q₅`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wrist {
    /// `sin q₅ ≥ 0`.
    NotFlipped,
    /// `sin q₅ < 0`.
    Flipped,
}

impl Shoulder {
    /// `left` or `right`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Left => "left",
            Self::Right => "right",
        }
    }
}

impl Elbow {
    /// `up` or `down`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Up => "up",
            Self::Down => "down",
        }
    }
}

impl Wrist {
    /// `not_flipped` or `flipped`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::NotFlipped => "not_flipped",
            Self::Flipped => "flipped",
        }
    }
}

/// A solution's shoulder, elbow and wrist choice.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Configuration {
    /// The `q₁` branch.
    pub shoulder: Shoulder,
    /// The `q₃` branch.
    pub elbow: Elbow,
    /// The `q₅` branch.
    pub wrist: Wrist,
}

/// One joint configuration reaching the target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkSolution {
    /// Joint angles (rad), within the joint limits, each the turn nearest the seed's.
    pub q_rad: [f64; 6],
    /// Its shoulder, elbow and wrist branch.
    pub configuration: Configuration,
    /// Distance between FK of `q_rad` and the target (m).
    pub position_error_m: f64,
    /// Rotation angle between FK of `q_rad` and the target (rad).
    pub angle_error_rad: f64,
    /// Distance from the seed, `‖q − seed‖` (rad); from zero when no seed was given.
    pub distance_from_seed_rad: f64,
}

/// Every solution for one target, nearest the seed first.
#[derive(Debug, Clone, PartialEq)]
pub struct IkAnswer {
    /// Distinct solutions within the joint limits, ordered by distance from the seed.
    pub solutions: Vec<IkSolution>,
    /// The wrist is singular (`sin q₅ ≈ 0`): only `q₄ + q₆` is determined, and `q₆` was taken
    /// from the seed (0 without one).
    pub wrist_singular: bool,
    /// Solutions that exist but fall outside the joint limits at every turn.
    pub outside_limits: usize,
}

/// Why no configuration reaches a target.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum IkError {
    /// The arm does not have the Universal Robots structure, so there is no closed form to start
    /// from.
    #[error(
        "arm '{model}' does not have the Universal Robots geometry; inverse kinematics needs it"
    )]
    NotUrGeometry {
        /// The arm's name.
        model: String,
    },
    /// A value of the target or the seed is NaN or infinite.
    #[error("the {what} is not finite")]
    NonFinite {
        /// `target position`, `target orientation` or `seed`.
        what: &'static str,
    },
    /// The seed does not have one angle per joint.
    #[error("the seed has {got} joint angles, the arm {expected}")]
    SeedLength {
        /// The arm's joint count.
        expected: usize,
        /// The seed's length.
        got: usize,
    },
    /// The target orientation is not a rotation.
    #[error("the target orientation is not a rotation (‖RᵀR − I‖ = {deviation:.3e})")]
    NotARotation {
        /// How far from orthonormal.
        deviation: f64,
    },
    /// No configuration reaches the pose.
    #[error("pose unreachable: {reason}")]
    Unreachable {
        /// Which constraint fails, with its figures.
        reason: String,
    },
    /// Configurations reach the pose, but none within the joint limits.
    #[error("pose reachable by {count} configurations, none of them within the joint limits")]
    OutsideLimits {
        /// How many configurations there were.
        count: usize,
    },
}

/// One closed-form solution before joint limits: principal angles and branch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClosedFormSolution {
    /// Joint angles in (−π, π] (rad).
    pub q_rad: [f64; 6],
    /// Its branch.
    pub configuration: Configuration,
    /// The branch as the closed form counts it, `0..8`: shoulder, wrist, then the sign of `q₃`
    /// (stable along a branch, unlike the elbow's up or down, which flips where the wrist
    /// passes over the shoulder).
    pub branch: usize,
}

/// The closed-form solutions of `geometry` for `base_from_flange`; `q6_singular_rad` is the
/// `q₆` taken where the wrist is singular. Returns the solutions and whether the wrist is
/// singular; fails only when no branch reaches the pose.
pub fn closed_form(
    geometry: &UrGeometry,
    base_from_flange: &Pose,
    q6_singular_rad: f64,
) -> Result<(Vec<ClosedFormSolution>, bool), IkError> {
    closed_form_within(
        geometry,
        base_from_flange,
        q6_singular_rad,
        BOUNDARY_TOLERANCE,
    )
}

/// [`closed_form`], taking a pose up to `margin` beyond the shoulder or elbow boundary (as a
/// cosine or sine beyond ±1) as on it: the start for a calibrated chain, which reaches a little
/// further or less far than its nominal arm.
fn closed_form_within(
    geometry: &UrGeometry,
    base_from_flange: &Pose,
    q6_singular_rad: f64,
    margin: f64,
) -> Result<(Vec<ClosedFormSolution>, bool), IkError> {
    let [d1, a2, a3, d4, d5, d6] = geometry.d1_a2_a3_d4_d5_d6_m;
    let p = base_from_flange.position_m;
    let r = base_from_flange.rotation;
    let (x6, y6, z6) = (
        r.column(0).into_owned(),
        r.column(1).into_owned(),
        r.column(2).into_owned(),
    );
    // Wrist centre: the origin of frame 5 (and 4), d6 back along the flange z axis.
    let wrist = p - z6 * d6;
    let radius = wrist.x.hypot(wrist.y);
    let ratio = d4 / radius;
    if ratio.is_nan() || ratio.abs() > 1.0 + margin {
        return Err(IkError::Unreachable {
            reason: format!(
                "the wrist centre is {radius:.6} m from the base z axis, closer than the shoulder offset d4 = {:.6} m",
                d4.abs()
            ),
        });
    }
    let azimuth = wrist.y.atan2(wrist.x);
    let lean = ratio.clamp(-1.0, 1.0).asin();
    let mut solutions = Vec::with_capacity(8);
    let mut wrist_singular = false;
    let mut elbow_failure = None;
    for (shoulder_index, shoulder) in [Shoulder::Left, Shoulder::Right].into_iter().enumerate() {
        let q1 = match shoulder {
            Shoulder::Left => azimuth + lean,
            Shoulder::Right => azimuth + PI - lean,
        };
        let (s1, c1) = q1.sin_cos();
        let x1 = Vector3::new(c1, s1, 0.0);
        let z1 = Vector3::new(s1, -c1, 0.0);
        let c5 = z6.dot(&z1).clamp(-1.0, 1.0);
        for (wrist_index, wrist_branch) in
            [Wrist::NotFlipped, Wrist::Flipped].into_iter().enumerate()
        {
            let q5 = match wrist_branch {
                Wrist::NotFlipped => c5.acos(),
                Wrist::Flipped => -c5.acos(),
            };
            let (s5, c5) = q5.sin_cos();
            let q6 = if s5.abs() < WRIST_SINGULAR_SIN {
                wrist_singular = true;
                q6_singular_rad
            } else {
                (-y6.dot(&z1) / s5).atan2(x6.dot(&z1) / s5)
            };
            let (s6, c6) = q6.sin_cos();
            // Undo joint 6, then joint 5: frame 5's x and z, frame 4's x and z.
            let x5 = x6 * c6 - y6 * s6;
            let y5 = x6 * s6 + y6 * c6;
            let z4 = -y5;
            let x4 = x5 * c5 - z6 * s5;
            let q234 = x4.z.atan2(x4.dot(&x1));
            let o4 = wrist - z4 * d5;
            let reach = (o4 - z1 * d4).dot(&x1);
            let height = o4.z - d1;
            let c3 = (reach * reach + height * height - a2 * a2 - a3 * a3) / (2.0 * a2 * a3);
            if c3.is_nan() || c3.abs() > 1.0 + margin {
                elbow_failure = Some(reach.hypot(height));
                continue;
            }
            for (elbow_index, elbow_sign) in [1.0, -1.0].into_iter().enumerate() {
                let q3 = elbow_sign * c3.clamp(-1.0, 1.0).acos();
                let (s3, c3) = q3.sin_cos();
                let q2 = height.atan2(reach) - (a3 * s3).atan2(a2 + a3 * c3);
                let q4 = q234 - q2 - q3;
                // Elbow above the shoulder–wrist line: the cross product of the line and the
                // elbow, signed by the direction the line points along x₁.
                let (s2, c2) = q2.sin_cos();
                let cross = reach * (a2 * s2) - height * (a2 * c2);
                let elbow = if cross * reach >= 0.0 {
                    Elbow::Up
                } else {
                    Elbow::Down
                };
                solutions.push(ClosedFormSolution {
                    q_rad: [q1, q2, q3, q4, q5, q6].map(orientation::wrap_angle),
                    configuration: Configuration {
                        shoulder,
                        elbow,
                        wrist: wrist_branch,
                    },
                    branch: 4 * shoulder_index + 2 * wrist_index + elbow_index,
                });
            }
        }
    }
    if solutions.is_empty() {
        let reach = elbow_failure.unwrap_or(f64::NAN);
        return Err(IkError::Unreachable {
            reason: format!(
                "the wrist is {reach:.6} m from the shoulder, outside the arm's reach [{:.6}, {:.6}] m",
                (a2.abs() - a3.abs()).abs(),
                a2.abs() + a3.abs()
            ),
        });
    }
    Ok((solutions, wrist_singular))
}

/// Position error (m) and rotation error vector (rad) of `pose` against `target`, in the output
/// frame: `target − pose` and `log(R_target · Rᵀ)`.
fn pose_error(target: &Pose, pose: &Pose) -> Vector6<f64> {
    let dp = target.position_m - pose.position_m;
    let dr =
        orientation::rotation_vector_from_matrix(&(target.rotation * pose.rotation.transpose()));
    Vector6::new(dp.x, dp.y, dp.z, dr.x, dr.y, dr.z)
}

/// Damped Newton (Levenberg–Marquardt) on `model`'s chain from `start`: `q ← q + (JᵀJ + μI)⁻¹Jᵀe`
/// with a forward-difference Jacobian; a step is taken only if it shrinks the error, and `μ`
/// grows until one does, so a start far from the solution (a large calibration) or near a
/// singularity does not jump to another branch. Returns the best angles found.
fn refine(model: &RobotModel, target: &Pose, start: [f64; 6]) -> [f64; 6] {
    const STEP_RAD: f64 = 1e-7;
    /// Largest joint step (rad) of one iteration.
    const MAX_STEP_RAD: f64 = 0.3;
    let chain = model.chain();
    let mut q = start;
    let mut pose = chain.pose_unchecked(&q);
    let mut error = pose_error(target, &pose);
    let mut damping = 1e-12;
    for _ in 0..NEWTON_ITERATIONS {
        if error.norm() < 1e-15 {
            break;
        }
        let mut jacobian = Matrix6::zeros();
        for j in 0..6 {
            let mut moved = q;
            moved[j] += STEP_RAD;
            let column = pose_error(&chain.pose_unchecked(&moved), &pose) / STEP_RAD;
            jacobian.set_column(j, &column);
        }
        let svd = jacobian.svd(true, true);
        let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
            break;
        };
        let projected = u.transpose() * error;
        let mut improved = false;
        while damping < 1e6 {
            let mut scaled = Vector6::zeros();
            for k in 0..6 {
                let sigma = svd.singular_values[k];
                scaled[k] = projected[k] * sigma / (sigma * sigma + damping);
            }
            let mut step = v_t.transpose() * scaled;
            let largest = step.amax();
            if largest > MAX_STEP_RAD {
                step *= MAX_STEP_RAD / largest;
            }
            let mut candidate = q;
            for (angle, delta) in candidate.iter_mut().zip(step.iter()) {
                *angle += delta;
            }
            let candidate_pose = chain.pose_unchecked(&candidate);
            let candidate_error = pose_error(target, &candidate_pose);
            if candidate_error.norm() < error.norm() {
                (q, pose, error) = (candidate, candidate_pose, candidate_error);
                damping = (damping * 0.1).max(1e-15);
                improved = true;
                break;
            }
            damping *= 10.0;
        }
        // Rounding bounds how small the error gets; stop once no step shrinks it.
        if !improved {
            break;
        }
    }
    q.map(orientation::wrap_angle)
}

/// The turn of `angle_rad` (`angle + 2πk`) within `limits` nearest `reference_rad`, if any.
fn nearest_turn(angle_rad: f64, reference_rad: f64, limits: &JointLimits) -> Option<f64> {
    let base = angle_rad + TAU * ((reference_rad - angle_rad) / TAU).round();
    [base, base - TAU, base + TAU]
        .into_iter()
        .filter(|candidate| limits.contains(*candidate))
        .min_by(|a, b| {
            (a - reference_rad)
                .abs()
                .total_cmp(&(b - reference_rad).abs())
        })
}

fn check_rotation(rotation: &Matrix3<f64>) -> Result<(), IkError> {
    let deviation = (rotation.transpose() * rotation - Matrix3::identity()).norm();
    if deviation > 1e-6 || (rotation.determinant() - 1.0).abs() > 1e-6 {
        return Err(IkError::NotARotation { deviation });
    }
    Ok(())
}

/// The closed form of a model's nominal arm, for targets in the model's output frame with its
/// tool.
struct NominalSolver {
    geometry: UrGeometry,
    frame_from_base: IsometryMatrix3<f64>,
    tcp_from_flange: IsometryMatrix3<f64>,
    q6_singular_rad: f64,
    /// How far beyond a boundary a target may lie and still give starts (see
    /// [`closed_form_within`]).
    boundary_margin: f64,
}

/// Boundary margin for a chain that is not its nominal arm.
const CALIBRATED_BOUNDARY_MARGIN: f64 = 0.05;

/// Iterations of the branch-keeping correction in [`NominalSolver::carry`].
const CARRY_ITERATIONS: usize = 12;

impl NominalSolver {
    /// The closed-form solutions for `frame_from_tcp`.
    fn solve(&self, frame_from_tcp: &Pose) -> Result<(Vec<ClosedFormSolution>, bool), IkError> {
        let base_from_flange =
            self.frame_from_base.inverse() * isometry(frame_from_tcp) * self.tcp_from_flange;
        closed_form_within(
            &self.geometry,
            &to_pose(&base_from_flange),
            self.q6_singular_rad,
            self.boundary_margin,
        )
    }

    /// A start for Newton on `model`'s chain on the branch of `start`: the closed form is solved
    /// again for a target corrected by the chain's own deviation from the nominal arm,
    /// `T ← T · FK(q)⁻¹ · T_nominal`, keeping the branch, until the deviation stops shrinking.
    /// A calibration moves the TCP by millimetres to centimetres, so near an elbow or shoulder
    /// boundary Newton from the nominal solution may cross to the neighbouring branch; the
    /// corrected closed form does not.
    fn carry(&self, model: &RobotModel, target: &Pose, start: ClosedFormSolution) -> [f64; 6] {
        let goal = isometry(target);
        let mut nominal_target = goal;
        let mut q = start.q_rad;
        let mut best = (f64::INFINITY, q);
        for _ in 0..CARRY_ITERATIONS {
            let reached = model.chain().pose_unchecked(&q);
            let size = pose_error(target, &reached).norm();
            if size.is_nan() || size >= best.0 {
                break;
            }
            best = (size, q);
            if size < 1e-13 {
                break;
            }
            nominal_target = goal * isometry(&reached).inverse() * nominal_target;
            let Ok((solutions, _)) = self.solve(&to_pose(&nominal_target)) else {
                break;
            };
            let Some(same_branch) = solutions.iter().find(|s| s.branch == start.branch) else {
                break;
            };
            q = same_branch.q_rad;
        }
        best.1
    }
}

fn isometry(pose: &Pose) -> IsometryMatrix3<f64> {
    IsometryMatrix3::from_parts(
        Translation3::from(pose.position_m),
        Rotation3::from_matrix_unchecked(pose.rotation),
    )
}

fn to_pose(isometry: &IsometryMatrix3<f64>) -> Pose {
    Pose {
        position_m: isometry.translation.vector,
        rotation: *isometry.rotation.matrix(),
    }
}

/// Every configuration of `model` whose TCP is at `target` (`frame_from_tcp`, in the model's
/// output frame), within the joint limits, nearest `seed_rad` first.
///
/// The closed form of the nominal arm gives the starting solutions; each is refined by Newton's
/// method on the model's own chain (calibration, tool and frame included) and kept only if FK
/// reproduces the target to [`SOLUTION_TOLERANCE`]. The target's rotation is re-orthonormalised
/// first, so a quaternion read from text rounds to a rotation.
#[allow(
    clippy::too_many_lines,
    reason = "one pass: checks, starts, refinement, limits, order"
)]
pub fn solve(
    model: &RobotModel,
    target: &Pose,
    seed_rad: Option<&[f64]>,
) -> Result<IkAnswer, IkError> {
    let geometry = UrGeometry::from_arm(model.arm()).ok_or_else(|| IkError::NotUrGeometry {
        model: model.arm().name.clone(),
    })?;
    if !target.position_m.iter().all(|v| v.is_finite()) {
        return Err(IkError::NonFinite {
            what: "target position",
        });
    }
    if !target.rotation.iter().all(|v| v.is_finite()) {
        return Err(IkError::NonFinite {
            what: "target orientation",
        });
    }
    check_rotation(&target.rotation)?;
    let seed: [f64; 6] = match seed_rad {
        None => [0.0; 6],
        Some(seed) => {
            let seed: [f64; 6] = seed.try_into().map_err(|_| IkError::SeedLength {
                expected: 6,
                got: seed.len(),
            })?;
            if !seed.iter().all(|v| v.is_finite()) {
                return Err(IkError::NonFinite { what: "seed" });
            }
            seed
        }
    };
    let target = Pose {
        position_m: target.position_m,
        rotation: orientation::matrix_from_quaternion(&orientation::quaternion_from_matrix(
            &target.rotation,
        )),
    };
    let nominal = NominalSolver {
        geometry,
        frame_from_base: model.frame().frame_from_base(),
        tcp_from_flange: model.tool().flange_from_tcp().inverse(),
        q6_singular_rad: seed[5],
        boundary_margin: if model.chain().uses_closed_form() {
            BOUNDARY_TOLERANCE
        } else {
            CALIBRATED_BOUNDARY_MARGIN
        },
    };
    let (starts, wrist_singular) = nominal.solve(&target)?;
    let limits = &model.arm().joint_limits;
    let mut solutions: Vec<IkSolution> = Vec::with_capacity(starts.len());
    let mut reaching = 0;
    let mut outside_limits = 0;
    for start in starts {
        // From the branch-keeping correction first; from the plain nominal solution if that
        // does not converge.
        let converged = [nominal.carry(model, &target, start), start.q_rad]
            .into_iter()
            .find_map(|from| {
                let q = refine(model, &target, from);
                let error = pose_error(&target, &model.chain().pose_unchecked(&q));
                let position_error_m = error.fixed_rows::<3>(0).norm();
                let angle_error_rad = error.fixed_rows::<3>(3).norm();
                (position_error_m <= SOLUTION_TOLERANCE && angle_error_rad <= SOLUTION_TOLERANCE)
                    .then_some((q, position_error_m, angle_error_rad))
            });
        let Some((q, position_error_m, angle_error_rad)) = converged else {
            continue;
        };
        let duplicate = solutions.iter().any(|known| {
            known
                .q_rad
                .iter()
                .zip(&q)
                .all(|(a, b)| orientation::wrap_angle(a - b).abs() < SAME_SOLUTION_RAD)
        });
        if duplicate {
            continue;
        }
        reaching += 1;
        let mut within = [0.0; 6];
        let mut fits = true;
        for (j, slot) in within.iter_mut().enumerate() {
            let joint_limits = limits.get(j).copied().unwrap_or(JointLimits::UNLIMITED);
            match nearest_turn(q[j], seed[j], &joint_limits) {
                Some(angle) => *slot = angle,
                None => fits = false,
            }
        }
        if !fits {
            outside_limits += 1;
            continue;
        }
        let distance_from_seed_rad = within
            .iter()
            .zip(&seed)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt();
        solutions.push(IkSolution {
            q_rad: within,
            configuration: start.configuration,
            position_error_m,
            angle_error_rad,
            distance_from_seed_rad,
        });
    }
    if solutions.is_empty() {
        if outside_limits > 0 {
            return Err(IkError::OutsideLimits {
                count: outside_limits,
            });
        }
        return Err(IkError::Unreachable {
            reason: format!(
                "no closed-form branch converged onto the model's chain within {SOLUTION_TOLERANCE:e} (reaching: {reaching})"
            ),
        });
    }
    solutions.sort_by(|a, b| {
        a.distance_from_seed_rad
            .total_cmp(&b.distance_from_seed_rad)
    });
    Ok(IkAnswer {
        solutions,
        wrist_singular,
        outside_limits,
    })
}
