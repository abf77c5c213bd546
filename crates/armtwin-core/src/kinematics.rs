//! Forward kinematics of serial arms with revolute joints: a pure function of a compiled chain and
//! the joint angles.
//!
//! Owns: Denavit–Hartenberg tables (standard and modified), URDF-style joint origins, the tool
//! (TCP) offset, the output frame, and the chain they compile into. No caches, no I/O: the same
//! inputs always give the same pose.
//!
//! Every chain, whatever its source, compiles to one form,
//! `frame_from_tcp = F₀ · Rz(q₁ + θ₁) · F₁ · Rz(q₂ + θ₂) · … · Rz(qₙ + θₙ) · Fₙ`, with fixed rigid
//! transforms `Fₖ`, so the per-sample cost is n `sin_cos` and 2n small matrix products. The output
//! frame is folded into `F₀` and the tool into `Fₙ` once, when the chain is built. A standard-DH
//! table with exactly the Universal Robots structure (every nominal catalog arm) is evaluated in
//! closed form instead, equal to the link-by-link result to rounding ([`Chain::uses_closed_form`]).

use std::f64::consts::FRAC_PI_2;

use nalgebra::{
    IsometryMatrix3, Matrix3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3,
};
use thiserror::Error;

use crate::orientation::{self, Rpy};
use crate::trig;

/// One row of a Denavit–Hartenberg table. Lengths in metres, angles in radians.
///
/// - Standard DH (Denavit–Hartenberg, as Universal Robots publish it): joint i contributes
///   `Rz(qᵢ + θᵢ) · Tz(dᵢ) · Tx(aᵢ) · Rx(αᵢ)`.
/// - Modified DH (Craig): row i holds `(aᵢ₋₁, αᵢ₋₁, dᵢ, θᵢ)` and joint i contributes
///   `Rx(αᵢ₋₁) · Tx(aᵢ₋₁) · Rz(qᵢ + θᵢ) · Tz(dᵢ)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DhParameters {
    /// Link length `a` (m).
    pub a_m: f64,
    /// Link twist `α` (rad).
    pub alpha_rad: f64,
    /// Link offset `d` (m).
    pub d_m: f64,
    /// Joint angle offset `θ` (rad), added to the joint angle.
    pub theta_offset_rad: f64,
}

/// Which Denavit–Hartenberg convention a table is written in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DhConvention {
    /// `Rz(θ) · Tz(d) · Tx(a) · Rx(α)` per joint.
    Standard,
    /// Craig's `Rx(α) · Tx(a) · Rz(θ) · Tz(d)` per joint.
    Modified,
}

impl DhConvention {
    /// The name used in config files and listings: `standard` or `modified`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Standard => "standard",
            Self::Modified => "modified",
        }
    }
}

/// The frame poses are expressed in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OutputFrame {
    /// The controller's `base` frame, in which RTDE reports `actual_TCP_pose` (DH frame 0).
    #[default]
    Base,
    /// ROS `base_link`: `base` rotated by π about z (x and y negated).
    BaseLink,
}

impl OutputFrame {
    /// The name used on the wire and on the command line: `base` or `base_link`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Base => "base",
            Self::BaseLink => "base_link",
        }
    }

    /// The frame called `name` (`base` or `base_link`, as [`Self::as_str`] writes them).
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "base" => Some(Self::Base),
            "base_link" => Some(Self::BaseLink),
            _ => None,
        }
    }

    /// `frame_from_base`: exact (no `sin(π)` rounding) for `base_link`.
    #[must_use]
    pub fn frame_from_base(self) -> IsometryMatrix3<f64> {
        match self {
            Self::Base => IsometryMatrix3::identity(),
            Self::BaseLink => IsometryMatrix3::from_parts(
                Translation3::identity(),
                Rotation3::from_matrix_unchecked(Matrix3::from_diagonal(&Vector3::new(
                    -1.0, -1.0, 1.0,
                ))),
            ),
        }
    }
}

/// A tool (TCP) offset as entered on the UR pendant and reported by RTDE `tcp_offset`:
/// `[x, y, z, rx, ry, rz]`, metres and a rotation vector in radians, in the flange frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TcpOffset {
    /// `[x, y, z]` (m) of the TCP in the flange frame.
    pub position_m: [f64; 3],
    /// `[rx, ry, rz]` (rad): the TCP's orientation in the flange frame as a rotation vector.
    pub rotation_vector_rad: [f64; 3],
}

impl TcpOffset {
    /// No tool: the TCP is the flange.
    pub const FLANGE: Self = Self {
        position_m: [0.0; 3],
        rotation_vector_rad: [0.0; 3],
    };

    /// From the pendant's `[x, y, z, rx, ry, rz]`; `None` unless all six are finite.
    #[must_use]
    pub fn from_ur_pose(pose: [f64; 6]) -> Option<Self> {
        pose.iter().all(|v| v.is_finite()).then(|| Self {
            position_m: [pose[0], pose[1], pose[2]],
            rotation_vector_rad: [pose[3], pose[4], pose[5]],
        })
    }

    /// `[x, y, z, rx, ry, rz]`.
    #[must_use]
    pub fn to_ur_pose(&self) -> [f64; 6] {
        let [x, y, z] = self.position_m;
        let [rx, ry, rz] = self.rotation_vector_rad;
        [x, y, z, rx, ry, rz]
    }

    /// `flange_from_tcp` as a rigid transform.
    #[must_use]
    pub fn flange_from_tcp(&self) -> IsometryMatrix3<f64> {
        let rotation =
            orientation::matrix_from_rotation_vector(&Vector3::from(self.rotation_vector_rad));
        IsometryMatrix3::from_parts(
            Translation3::from(Vector3::from(self.position_m)),
            Rotation3::from_matrix_unchecked(rotation),
        )
    }
}

/// Why a set of joint angles cannot be evaluated.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum KinematicsError {
    /// The number of joint angles differs from the arm's joint count.
    #[error("expected {expected} joint angles, got {got}")]
    JointCount {
        /// The arm's joint count.
        expected: usize,
        /// How many were given.
        got: usize,
    },
    /// A joint angle is NaN or infinite.
    #[error("joint q{joint} is not a finite number ({value})")]
    NonFinite {
        /// 1-based joint number.
        joint: usize,
        /// The offending value.
        value: f64,
    },
    /// A joint angle lies outside the joint's position limits.
    #[error("joint q{joint} = {value_rad} rad is outside its limits [{min_rad}, {max_rad}] rad")]
    OutOfLimits {
        /// 1-based joint number.
        joint: usize,
        /// The offending angle (rad).
        value_rad: f64,
        /// Lower limit (rad), −∞ if none.
        min_rad: f64,
        /// Upper limit (rad), +∞ if none.
        max_rad: f64,
    },
}

/// A kinematic chain compiled to `F₀ · Π (Rz(qₖ + θₖ) · Fₖ)`, including output frame and tool.
///
/// A standard-DH table with exactly the Universal Robots structure (every nominal catalog arm) is
/// also evaluated in closed form, see [`Chain::uses_closed_form`]; any other chain (calibrated,
/// custom, modified DH, joint origins) link by link.
#[derive(Debug, Clone, PartialEq)]
pub struct Chain {
    /// `F₀`: output frame from joint 1's frame; the starting state of every evaluation.
    first: IsometryMatrix3<f64>,
    /// Per joint: its angle offset θ and the fixed transform `Fₖ` that follows its rotation.
    joints: Vec<CompiledJoint>,
    /// The same chain in closed form, when its table has the UR structure.
    closed_form: Option<UrClosedForm>,
}

/// The closed form of a standard-DH table with the Universal Robots structure:
/// `α = [π/2, 0, 0, π/2, −π/2, 0]` exactly, `a₁ = a₄ = a₅ = a₆ = 0`, `d₂ = d₃ = 0`, `θ = 0`.
///
/// Joints 2, 3 and 4 turn about parallel axes, so the pose needs only the sines and cosines of
/// `q₁, q₂, q₂ + q₃, q₂ + q₃ + q₄, q₅, q₆` (as in `ur_kinematics`' `forward()`): about 70 flops
/// instead of six dependent link updates. The sums enter the trig as unrounded two-sums, so the
/// result matches the link-by-link evaluation to rounding (tests: ≤ 1e-15).
#[derive(Debug, Clone, Copy, PartialEq)]
struct UrClosedForm {
    /// `[d1, a2, a3, d4, d5, d6]` (m).
    d1_a2_a3_d4_d5_d6_m: [f64; 6],
    /// Output frame `base_link` (x and y negated) rather than `base`.
    negate_xy: bool,
    /// The tool, `flange_from_tcp`, unless the TCP is the flange.
    flange_from_tcp: Option<IsometryMatrix3<f64>>,
}

/// `a + b` as a rounded sum and its exact rounding error (Knuth's two-sum).
#[inline]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let sum = a + b;
    let b_part = sum - a;
    let a_part = sum - b_part;
    (sum, (a - a_part) + (b - b_part))
}

/// `[d1, a2, a3, d4, d5, d6]` (m) of a standard-DH table with exactly the Universal Robots
/// structure (`α = [π/2, 0, 0, π/2, −π/2, 0]`, `a₁ = a₄ = a₅ = a₆ = 0`, `d₂ = d₃ = 0`, `θ = 0`,
/// compared bit for bit) and finite lengths, else `None`. The closed forms of FK and IK both rest
/// on it.
#[must_use]
#[allow(
    clippy::float_cmp,
    reason = "only an exact match has the structure the closed forms assume"
)]
pub fn ur_lengths_m(rows: &[DhParameters]) -> Option<[f64; 6]> {
    const ALPHA_RAD: [f64; 6] = [FRAC_PI_2, 0.0, 0.0, FRAC_PI_2, -FRAC_PI_2, 0.0];
    let [r1, r2, r3, r4, r5, r6] = rows else {
        return None;
    };
    let structure = rows
        .iter()
        .zip(ALPHA_RAD)
        .all(|(row, alpha)| row.alpha_rad == alpha && row.theta_offset_rad == 0.0)
        && [r1.a_m, r4.a_m, r5.a_m, r6.a_m, r2.d_m, r3.d_m]
            .iter()
            .all(|&v| v == 0.0);
    let lengths = [r1.d_m, r2.a_m, r3.a_m, r4.d_m, r5.d_m, r6.d_m];
    (structure && lengths.iter().all(|v| v.is_finite())).then_some(lengths)
}

impl UrClosedForm {
    /// The closed form of `rows` if they have the UR structure exactly, else `None`.
    fn detect(rows: &[DhParameters]) -> Option<Self> {
        ur_lengths_m(rows).map(|lengths| Self {
            d1_a2_a3_d4_d5_d6_m: lengths,
            negate_xy: false,
            flange_from_tcp: None,
        })
    }

    /// `frame_from_tcp` as rotation columns `[x, y, z]` and translation, for `q_rad[..6]`.
    #[inline]
    fn pose(&self, q_rad: &[f64; 6]) -> ([[f64; 3]; 3], [f64; 3]) {
        let [q1, q2, q3, q4, q5, q6] = *q_rad;
        let (q23, q23_lo) = two_sum(q2, q3);
        let (q234, q234_lo) = two_sum(q23, q4);
        let (sin, cos) = trig::sin_cos_batch_split(
            &[q1, q2, q23, q234, q5, q6],
            &[0.0, 0.0, q23_lo, q23_lo + q234_lo, 0.0, 0.0],
        );
        let [s1, s2, s23, s234, s5, s6] = sin;
        let [c1, c2, c23, c234, c5, c6] = cos;
        let [d1, a2, a3, d4, d5, d6] = self.d1_a2_a3_d4_d5_d6_m;
        // Frame 1: x₁ = (c1, s1, 0), y₁ = (0, 0, 1), z₁ = (s1, −c1, 0). Joints 2–4 turn in the
        // x₁y₁ plane; frame 4 has x₄ = c234·x₁ + s234·y₁, y₄ = z₁, z₄ = s234·x₁ − c234·y₁.
        let x4 = [c234 * c1, c234 * s1, s234];
        let y4 = [s1, -c1, 0.0];
        let z4 = [s234 * c1, s234 * s1, -c234];
        // Frame 5: x₅ = c5·x₄ + s5·y₄, y₅ = −z₄, z₅ = c5·y₄ − s5·x₄.
        let x5 = [c5 * x4[0] + s5 * y4[0], c5 * x4[1] + s5 * y4[1], c5 * x4[2]];
        let z5 = [
            c5 * y4[0] - s5 * x4[0],
            c5 * y4[1] - s5 * x4[1],
            -s5 * x4[2],
        ];
        // Frame 6: x₆ = c6·x₅ + s6·y₅, y₆ = c6·y₅ − s6·x₅, z₆ = z₅.
        let x6 = [
            c6 * x5[0] - s6 * z4[0],
            c6 * x5[1] - s6 * z4[1],
            c6 * x5[2] - s6 * z4[2],
        ];
        let y6 = [
            -c6 * z4[0] - s6 * x5[0],
            -c6 * z4[1] - s6 * x5[1],
            -c6 * z4[2] - s6 * x5[2],
        ];
        // Reach in the x₁y₁ plane: along x₁ and along y₁ (= base z).
        let reach = a2 * c2 + a3 * c23;
        let height = a2 * s2 + a3 * s23;
        let mut t = [
            reach * c1 + d4 * y4[0] + d5 * z4[0] + d6 * z5[0],
            reach * s1 + d4 * y4[1] + d5 * z4[1] + d6 * z5[1],
            d1 + height + d5 * z4[2] + d6 * z5[2],
        ];
        let mut axes = [x6, y6, z5];
        if let Some(tool) = &self.flange_from_tcp {
            let r = tool.rotation.matrix();
            let v = &tool.translation.vector;
            for i in 0..3 {
                t[i] += axes[0][i] * v.x + axes[1][i] * v.y + axes[2][i] * v.z;
            }
            let flange = axes;
            for (j, axis) in axes.iter_mut().enumerate() {
                *axis = std::array::from_fn(|i| {
                    flange[0][i] * r[(0, j)] + flange[1][i] * r[(1, j)] + flange[2][i] * r[(2, j)]
                });
            }
        }
        if self.negate_xy {
            for axis in &mut axes {
                axis[0] = -axis[0];
                axis[1] = -axis[1];
            }
            t[0] = -t[0];
            t[1] = -t[1];
        }
        (axes, t)
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct CompiledJoint {
    theta_offset_rad: f64,
    after: Link,
}

/// The fixed transform after a joint's rotation.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Link {
    /// `Tz(d) · Tx(a) · Rx(α)`: every link of a standard or modified DH table, applied in 48 flops.
    Dh {
        d_m: f64,
        a_m: f64,
        cos_alpha: f64,
        sin_alpha: f64,
    },
    /// Any rigid transform (URDF joint origins, a link with the tool folded in).
    General(IsometryMatrix3<f64>),
}

impl Link {
    fn dh(d_m: f64, a_m: f64, alpha_rad: f64) -> Self {
        let rotation = tx_rx(0.0, alpha_rad).rotation;
        Self::Dh {
            d_m,
            a_m,
            cos_alpha: rotation[(1, 1)],
            sin_alpha: rotation[(2, 1)],
        }
    }

    fn to_isometry(self) -> IsometryMatrix3<f64> {
        match self {
            Self::Dh {
                d_m,
                a_m,
                cos_alpha,
                sin_alpha,
            } => IsometryMatrix3::from_parts(
                Translation3::new(a_m, 0.0, d_m),
                Rotation3::from_matrix_unchecked(Matrix3::new(
                    1.0, 0.0, 0.0, 0.0, cos_alpha, -sin_alpha, 0.0, sin_alpha, cos_alpha,
                )),
            ),
            Self::General(isometry) => isometry,
        }
    }
}

/// `Tx(a) · Rx(α)`, with `Rx(±π/2)` built exactly (UR tables use ±π/2, whose cosine rounds to
/// 6e-17 otherwise).
#[allow(clippy::float_cmp, reason = "exactly ±π/2 is what nominal tables hold")]
fn tx_rx(a_m: f64, alpha_rad: f64) -> IsometryMatrix3<f64> {
    let (sin_alpha, cos_alpha) = if alpha_rad == FRAC_PI_2 {
        (1.0, 0.0)
    } else if alpha_rad == -FRAC_PI_2 {
        (-1.0, 0.0)
    } else {
        alpha_rad.sin_cos()
    };
    IsometryMatrix3::from_parts(
        Translation3::new(a_m, 0.0, 0.0),
        Rotation3::from_matrix_unchecked(Matrix3::new(
            1.0, 0.0, 0.0, 0.0, cos_alpha, -sin_alpha, 0.0, sin_alpha, cos_alpha,
        )),
    )
}

/// `state · Rz(θ) · link`, the state being the columns `[x, y, z]` of a rotation and a
/// translation `t`, both in the output frame.
#[inline]
fn advance(
    axes: &mut [[f64; 3]; 3],
    t: &mut [f64; 3],
    sin_theta: f64,
    cos_theta: f64,
    link: &Link,
) {
    let [x, y, z] = *axes;
    // Rz(θ) mixes the first two columns only. Written out per component: three-element array
    // closures compiled to shuffles that cost more than the arithmetic.
    let x1 = [
        cos_theta * x[0] + sin_theta * y[0],
        cos_theta * x[1] + sin_theta * y[1],
        cos_theta * x[2] + sin_theta * y[2],
    ];
    let y1 = [
        cos_theta * y[0] - sin_theta * x[0],
        cos_theta * y[1] - sin_theta * x[1],
        cos_theta * y[2] - sin_theta * x[2],
    ];
    match *link {
        Link::Dh {
            d_m,
            a_m,
            cos_alpha,
            sin_alpha,
        } => {
            t[0] += d_m * z[0] + a_m * x1[0];
            t[1] += d_m * z[1] + a_m * x1[1];
            t[2] += d_m * z[2] + a_m * x1[2];
            axes[0] = x1;
            axes[1] = [
                cos_alpha * y1[0] + sin_alpha * z[0],
                cos_alpha * y1[1] + sin_alpha * z[1],
                cos_alpha * y1[2] + sin_alpha * z[2],
            ];
            axes[2] = [
                cos_alpha * z[0] - sin_alpha * y1[0],
                cos_alpha * z[1] - sin_alpha * y1[1],
                cos_alpha * z[2] - sin_alpha * y1[2],
            ];
        }
        Link::General(ref isometry) => {
            let r = isometry.rotation.matrix();
            let v = &isometry.translation.vector;
            let columns = [x1, y1, z];
            for i in 0..3 {
                t[i] += columns[0][i] * v.x + columns[1][i] * v.y + columns[2][i] * v.z;
            }
            for (j, axis) in axes.iter_mut().enumerate() {
                *axis = std::array::from_fn(|i| {
                    columns[0][i] * r[(0, j)]
                        + columns[1][i] * r[(1, j)]
                        + columns[2][i] * r[(2, j)]
                });
            }
        }
    }
}

impl Chain {
    /// A chain from a DH table in the given convention; the flange is the last DH frame.
    #[must_use]
    pub fn from_dh(convention: DhConvention, rows: &[DhParameters]) -> Self {
        match convention {
            DhConvention::Standard => Self::from_standard_dh(rows),
            DhConvention::Modified => Self::from_modified_dh(rows),
        }
    }

    fn from_standard_dh(rows: &[DhParameters]) -> Self {
        Self {
            closed_form: UrClosedForm::detect(rows),
            first: IsometryMatrix3::identity(),
            joints: rows
                .iter()
                .map(|row| CompiledJoint {
                    theta_offset_rad: row.theta_offset_rad,
                    after: Link::dh(row.d_m, row.a_m, row.alpha_rad),
                })
                .collect(),
        }
    }

    fn from_modified_dh(rows: &[DhParameters]) -> Self {
        // Joint k's `Tz(dₖ)` and joint k+1's `Rx(αₖ) · Tx(aₖ)` (== `Tx(aₖ) · Rx(αₖ)`: both act
        // along or about x) form one `Tz · Tx · Rx` link.
        let first = rows.first().map_or_else(IsometryMatrix3::identity, |row| {
            tx_rx(row.a_m, row.alpha_rad)
        });
        let joints = rows
            .iter()
            .enumerate()
            .map(|(k, row)| {
                let (a_m, alpha_rad) = rows
                    .get(k + 1)
                    .map_or((0.0, 0.0), |next| (next.a_m, next.alpha_rad));
                CompiledJoint {
                    theta_offset_rad: row.theta_offset_rad,
                    after: Link::dh(row.d_m, a_m, alpha_rad),
                }
            })
            .collect();
        Self {
            first,
            joints,
            closed_form: None,
        }
    }

    /// A chain from URDF-style joint origins: `O₁ · Rz(q₁) · O₂ · Rz(q₂) · … · Oₙ · Rz(qₙ)`, each
    /// origin being the fixed transform from the parent link to the joint frame (as written by ROS
    /// `ur_calibration`); the flange is the last joint frame.
    #[must_use]
    pub fn from_joint_origins(parent_from_joint: &[IsometryMatrix3<f64>]) -> Self {
        Self::from_origins(parent_from_joint, IsometryMatrix3::identity())
    }

    /// A chain `O₁ · Rz(q₁) · … · Oₙ · Rz(qₙ) · L` from its joint origins `Oₖ` and the fixed
    /// `last_from_flange` `L` after the last joint (a URDF chain's tip link).
    #[must_use]
    pub fn from_origins(
        parent_from_joint: &[IsometryMatrix3<f64>],
        last_from_flange: IsometryMatrix3<f64>,
    ) -> Self {
        let first = parent_from_joint
            .first()
            .copied()
            .unwrap_or_else(IsometryMatrix3::identity);
        let joints = (0..parent_from_joint.len())
            .map(|k| CompiledJoint {
                theta_offset_rad: 0.0,
                after: Link::General(
                    parent_from_joint
                        .get(k + 1)
                        .copied()
                        .unwrap_or(last_from_flange),
                ),
            })
            .collect();
        Self {
            first,
            joints,
            closed_form: None,
        }
    }

    /// This chain expressed in `frame` with `tool` attached:
    /// `frame_from_base · chain · flange_from_tcp`.
    #[must_use]
    #[allow(clippy::float_cmp, reason = "output frames are exact sign flips")]
    pub fn with_frame_and_tool(mut self, frame: OutputFrame, tool: &TcpOffset) -> Self {
        self.first = frame.frame_from_base() * self.first;
        if *tool != TcpOffset::FLANGE {
            let flange_from_tcp = tool.flange_from_tcp();
            match self.joints.last_mut() {
                Some(last) => {
                    last.after = Link::General(last.after.to_isometry() * flange_from_tcp);
                }
                None => self.first *= flange_from_tcp,
            }
            if let Some(closed_form) = &mut self.closed_form {
                closed_form.flange_from_tcp = Some(
                    closed_form
                        .flange_from_tcp
                        .map_or(flange_from_tcp, |earlier| earlier * flange_from_tcp),
                );
            }
        }
        // The closed form starts in `base`; it follows `base` and `base_link` only.
        let base_link = OutputFrame::BaseLink.frame_from_base();
        let negate_xy = if self.first == IsometryMatrix3::identity() {
            Some(false)
        } else if self.first == base_link {
            Some(true)
        } else {
            None
        };
        self.closed_form = match (self.closed_form, negate_xy) {
            (Some(closed_form), Some(negate_xy)) => Some(UrClosedForm {
                negate_xy,
                ..closed_form
            }),
            _ => None,
        };
        self
    }

    /// Whether poses are evaluated in closed form: for a standard-DH table with exactly the
    /// Universal Robots structure (`α = [π/2, 0, 0, π/2, −π/2, 0]`, `a₁ = a₄ = a₅ = a₆ = 0`,
    /// `d₂ = d₃ = 0`, `θ = 0`: every nominal catalog arm) in frame `base` or `base_link`, with or
    /// without a tool. Results equal the link-by-link evaluation to rounding.
    #[must_use]
    pub fn uses_closed_form(&self) -> bool {
        self.closed_form.is_some()
    }

    /// The same chain, always evaluated link by link (never in closed form): the reference the
    /// closed form is tested against, and a benchmark baseline.
    #[must_use]
    pub fn to_link_by_link(&self) -> Self {
        Self {
            closed_form: None,
            ..self.clone()
        }
    }

    /// The chain as URDF-style joint origins: per joint, `parent_from_joint = Fₖ₋₁ · Rz(θₖ)`
    /// (`F₀` the first transform: output frame and mounting), each joint turning about its
    /// frame's z; then the fixed `last_from_tip = Fₙ` (the flange, and the tool when attached).
    /// `Π (parent_from_jointₖ · Rz(qₖ)) · last_from_tip` is this chain's pose.
    #[must_use]
    pub fn joint_origins(&self) -> (Vec<IsometryMatrix3<f64>>, IsometryMatrix3<f64>) {
        let mut before = self.first;
        let mut origins = Vec::with_capacity(self.joints.len());
        for joint in &self.joints {
            origins.push(
                before * Rotation3::from_axis_angle(&Vector3::z_axis(), joint.theta_offset_rad),
            );
            before = joint.after.to_isometry();
        }
        (origins, before)
    }

    /// Number of revolute joints.
    #[must_use]
    pub fn joint_count(&self) -> usize {
        self.joints.len()
    }

    /// `frame_from_tcp` for joint angles `q_rad` (rad), after checking their count and finiteness
    /// (joint limits are the model's: [`RobotModel::pose`](crate::model::RobotModel::pose)).
    ///
    /// The position is in metres in the chain's output frame; the rotation's columns are the TCP's
    /// axes in that frame. [`Pose::readout`] gives the quaternion in wire order `[x, y, z, w]` with
    /// `w ≥ 0`, and roll, pitch, yaw with `R = Rz(yaw) · Ry(pitch) · Rx(roll)`.
    ///
    /// The `ur10e`'s flange at `q = 0` in the controller's `base` frame (DH frame 0) is at
    /// `(a₂ + a₃, −(d₄ + d₆), d₁ − d₅)` with its z axis along base −y, i.e. `R = Rx(π/2)`:
    ///
    /// ```
    /// use approx::assert_abs_diff_eq;
    /// use armtwin_core::kinematics::Chain;
    /// use armtwin_core::model::catalog;
    /// use nalgebra::{Matrix3, Vector3};
    /// use std::f64::consts::{FRAC_1_SQRT_2, FRAC_PI_2};
    ///
    /// let ur10e = catalog::arm("ur10e")?;
    /// let chain = Chain::from_dh(ur10e.convention, &ur10e.dh);
    /// let pose = chain.pose(&[0.0; 6])?;
    /// // d₁ = 0.1807, a₂ = −0.6127, a₃ = −0.57155, d₄ = 0.17415, d₅ = 0.11985, d₆ = 0.11655 (m)
    /// let position_m = Vector3::new(-1.18425, -0.2907, 0.06085);
    /// assert_abs_diff_eq!(pose.position_m, position_m, epsilon = 1e-12);
    /// let rx_quarter_turn = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0);
    /// assert_abs_diff_eq!(pose.rotation, rx_quarter_turn, epsilon = 1e-15);
    ///
    /// let readout = pose.readout();
    /// let [qx, qy, qz, qw] = readout.quaternion_xyzw;
    /// assert_abs_diff_eq!(qx, FRAC_1_SQRT_2, epsilon = 1e-15);
    /// assert_abs_diff_eq!(qy.abs() + qz.abs(), 0.0, epsilon = 1e-15);
    /// assert_abs_diff_eq!(qw, FRAC_1_SQRT_2, epsilon = 1e-15);
    /// assert_abs_diff_eq!(readout.rpy.roll_rad, FRAC_PI_2, epsilon = 1e-15);
    /// assert_abs_diff_eq!(readout.rpy.pitch_rad, 0.0, epsilon = 1e-15);
    /// assert_abs_diff_eq!(readout.rpy.yaw_rad, 0.0, epsilon = 1e-15);
    ///
    /// assert!(chain.pose(&[0.0; 5]).is_err(), "one angle per joint");
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn pose(&self, q_rad: &[f64]) -> Result<Pose, KinematicsError> {
        if q_rad.len() != self.joints.len() {
            return Err(KinematicsError::JointCount {
                expected: self.joints.len(),
                got: q_rad.len(),
            });
        }
        if let Some((index, &value)) = q_rad.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(KinematicsError::NonFinite {
                joint: index + 1,
                value,
            });
        }
        Ok(self.pose_unchecked(q_rad))
    }

    /// The chain's link frames for joint angles `q_rad` (rad): `frame_from_link k` for
    /// `k = 0 ..= n`, the chain's first frame (the output frame's view of joint 1's frame) to
    /// the TCP, each after the joints before it. The last is [`Chain::pose`]'s pose; a viewer
    /// draws the arm as the segments between consecutive positions.
    ///
    /// ```
    /// use approx::assert_abs_diff_eq;
    /// use armtwin_core::kinematics::Chain;
    /// use armtwin_core::model::catalog;
    ///
    /// let ur10e = catalog::arm("ur10e")?;
    /// let chain = Chain::from_dh(ur10e.convention, &ur10e.dh);
    /// let q_rad = [0.3, -1.2, 1.1, -0.4, 1.5, 0.2];
    /// let frames = chain.link_frames(&q_rad)?;
    /// assert_eq!(frames.len(), 7);
    /// assert_abs_diff_eq!(frames[0].position_m.norm(), 0.0, epsilon = 1e-15);
    /// let tcp = chain.pose(&q_rad)?;
    /// assert_abs_diff_eq!(frames[6].position_m, tcp.position_m, epsilon = 1e-12);
    /// assert_abs_diff_eq!(frames[6].rotation, tcp.rotation, epsilon = 1e-12);
    /// // Joint 2 sits d₁ = 0.1807 m above the base, whatever q₁ is.
    /// assert_abs_diff_eq!(frames[1].position_m.z, 0.1807, epsilon = 1e-12);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn link_frames(&self, q_rad: &[f64]) -> Result<Vec<Pose>, KinematicsError> {
        // Checks the count and finiteness once, for every prefix below.
        let tcp = self.pose(q_rad)?;
        let link_by_link = Self {
            closed_form: None,
            ..self.clone()
        };
        let mut frames: Vec<Pose> = (0..q_rad.len())
            .map(|k| link_by_link.pose_unchecked(&q_rad[..k]))
            .collect();
        frames.push(tcp);
        Ok(frames)
    }

    /// `frame_from_tcp` for joint angles the caller has already validated (count and
    /// finiteness). Angles beyond the joint count are ignored; a short slice ends the chain early.
    #[must_use]
    pub fn pose_unchecked(&self, q_rad: &[f64]) -> Pose {
        if let (Some(closed_form), Some(q6)) = (&self.closed_form, q_rad.first_chunk::<6>()) {
            let ([x, y, z], t) = closed_form.pose(q6);
            return Pose {
                position_m: Vector3::from(t),
                rotation: Matrix3::new(x[0], y[0], z[0], x[1], y[1], z[1], x[2], y[2], z[2]),
            };
        }
        let r0 = self.first.rotation.matrix();
        let mut axes: [[f64; 3]; 3] = std::array::from_fn(|j| [r0[(0, j)], r0[(1, j)], r0[(2, j)]]);
        let mut t: [f64; 3] = self.first.translation.vector.into();
        for (joints, q_batch) in self
            .joints
            .chunks(trig::BATCH)
            .zip(q_rad.chunks(trig::BATCH))
        {
            let mut angles = [0.0; trig::BATCH];
            for ((angle, joint), q) in angles.iter_mut().zip(joints).zip(q_batch) {
                *angle = q + joint.theta_offset_rad;
            }
            let (sin, cos) = trig::sin_cos_batch(&angles);
            // Only as many joints as angles were given.
            for ((joint, s), c) in joints.iter().take(q_batch.len()).zip(sin).zip(cos) {
                advance(&mut axes, &mut t, s, c, &joint.after);
            }
        }
        let [x, y, z] = axes;
        Pose {
            position_m: Vector3::from(t),
            rotation: Matrix3::new(x[0], y[0], z[0], x[1], y[1], z[1], x[2], y[2], z[2]),
        }
    }
}

/// A rigid pose: the TCP's position and orientation in the output frame (`frame_from_tcp`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// TCP position (m).
    pub position_m: Vector3<f64>,
    /// TCP orientation as a rotation matrix (columns: the TCP's axes in the output frame).
    pub rotation: Matrix3<f64>,
}

/// A pose in every representation armtwin reports, with the `UR10e` FMU report's names.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseReadout {
    /// `[x, y, z]` (m).
    pub position_m: [f64; 3],
    /// Roll, pitch, yaw (rad), `R = Rz(yaw) · Ry(pitch) · Rx(roll)`.
    pub rpy: Rpy,
    /// Unit quaternion `[qx, qy, qz, qw]`, `qw ≥ 0`.
    pub quaternion_xyzw: [f64; 4],
}

impl PoseReadout {
    /// The readout of a position (m) and an orientation quaternion (canonicalised here).
    #[must_use]
    pub fn from_position_quaternion(
        position_m: [f64; 3],
        orientation: &UnitQuaternion<f64>,
    ) -> Self {
        let orientation = orientation::canonical(*orientation);
        Self {
            position_m,
            rpy: orientation::rpy_from_matrix(&orientation::matrix_from_quaternion(&orientation)),
            quaternion_xyzw: orientation::quaternion_to_xyzw(&orientation),
        }
    }

    /// The orientation as a unit quaternion.
    #[must_use]
    pub fn quaternion(&self) -> UnitQuaternion<f64> {
        let [x, y, z, w] = self.quaternion_xyzw;
        UnitQuaternion::new_unchecked(Quaternion::new(w, x, y, z))
    }
}

impl Pose {
    /// Position, roll/pitch/yaw and canonical quaternion of this pose.
    #[must_use]
    pub fn readout(&self) -> PoseReadout {
        PoseReadout {
            position_m: self.position_m.into(),
            rpy: orientation::rpy_from_matrix(&self.rotation),
            quaternion_xyzw: orientation::quaternion_to_xyzw(&orientation::quaternion_from_matrix(
                &self.rotation,
            )),
        }
    }

    /// The 4×4 homogeneous matrix, row-major.
    #[must_use]
    pub fn homogeneous_rows(&self) -> [[f64; 4]; 4] {
        let r = &self.rotation;
        let t = &self.position_m;
        [
            [r[(0, 0)], r[(0, 1)], r[(0, 2)], t.x],
            [r[(1, 0)], r[(1, 1)], r[(1, 2)], t.y],
            [r[(2, 0)], r[(2, 1)], r[(2, 2)], t.z],
            [0.0, 0.0, 0.0, 1.0],
        ]
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "exact results are expected where tested")]
mod tests {
    use super::*;

    fn dh(a_m: f64, alpha_rad: f64, d_m: f64) -> DhParameters {
        DhParameters {
            a_m,
            alpha_rad,
            d_m,
            theta_offset_rad: 0.0,
        }
    }

    #[test]
    fn modified_and_standard_tables_of_one_planar_arm_agree() {
        // A planar 2R arm: standard rows (a1, 0, 0), (a2, 0, 0); modified rows (0, 0), (a1, 0),
        // and the last link length a2 as a tool offset along x.
        let standard = Chain::from_dh(
            DhConvention::Standard,
            &[dh(0.4, 0.0, 0.0), dh(0.3, 0.0, 0.0)],
        );
        let tool = TcpOffset::from_ur_pose([0.3, 0.0, 0.0, 0.0, 0.0, 0.0]).expect("finite");
        let modified = Chain::from_dh(
            DhConvention::Modified,
            &[dh(0.0, 0.0, 0.0), dh(0.4, 0.0, 0.0)],
        )
        .with_frame_and_tool(OutputFrame::Base, &tool);
        for q in [[0.0, 0.0], [0.5, -1.0], [2.0, 3.0]] {
            let a = standard.pose(&q).expect("valid");
            let b = modified.pose(&q).expect("valid");
            assert!((a.position_m - b.position_m).norm() < 1e-15);
            assert!((a.rotation - b.rotation).norm() < 1e-15);
        }
    }

    #[test]
    fn base_link_negates_x_and_y() {
        let chain = Chain::from_dh(DhConvention::Standard, &[dh(0.5, 0.0, 0.2)]);
        let base = chain.pose(&[0.3]).expect("valid");
        let link = chain
            .clone()
            .with_frame_and_tool(OutputFrame::BaseLink, &TcpOffset::FLANGE)
            .pose(&[0.3])
            .expect("valid");
        assert_eq!(link.position_m.x, -base.position_m.x);
        assert_eq!(link.position_m.y, -base.position_m.y);
        assert_eq!(link.position_m.z, base.position_m.z);
    }

    #[test]
    fn joint_errors_name_count_and_joint() {
        let chain = Chain::from_dh(DhConvention::Standard, &[dh(0.5, 0.0, 0.2); 2]);
        assert_eq!(
            chain.pose(&[0.0]),
            Err(KinematicsError::JointCount {
                expected: 2,
                got: 1
            })
        );
        let err = chain.pose(&[0.0, f64::NAN]).expect_err("NaN");
        assert!(matches!(err, KinematicsError::NonFinite { joint: 2, .. }));
        assert_eq!(
            chain
                .pose(&[f64::INFINITY, 0.0])
                .expect_err("inf")
                .to_string(),
            "joint q1 is not a finite number (inf)"
        );
    }
}
