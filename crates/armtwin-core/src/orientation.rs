//! Orientation representations and the conversions between them, each with its convention stated.
//!
//! Owns: rotation matrix ↔ quaternion ↔ roll/pitch/yaw ↔ UR rotation vector, and the comparison
//! measures the metrics use (quaternion distance, rotation angle, wrapped Euler differences).
//! Must not know about robots, files or the network.
//!
//! Conventions, used everywhere in armtwin:
//! - rotation matrices act on column vectors: `p_target = target_from_source · p_source`;
//! - quaternions are unit quaternions, on the wire in order `[x, y, z, w]`, canonicalised to
//!   `w ≥ 0` (the `UR10e` FMU report's rule);
//! - roll, pitch, yaw: `R = Rz(yaw) · Ry(pitch) · Rx(roll)` (fixed axes x, then y, then z), with
//!   roll, yaw in (−π, π] and pitch in [−π/2, π/2];
//! - UR rotation vector `[rx, ry, rz]`: axis · angle in radians, angle in [0, π], as entered on the
//!   UR pendant and reported by RTDE `actual_TCP_pose` / `tcp_offset`.

use std::f64::consts::{PI, TAU};

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};

use crate::trig;

/// Below this value of `cos(pitch)` the roll/yaw split is ill-defined (gimbal lock) and
/// [`rpy_from_matrix`] sets yaw to zero; the rotation rebuilt from the angles then differs from the
/// original by at most about twice this value.
const GIMBAL_LOCK_COS_PITCH: f64 = 1e-12;

/// Roll, pitch, yaw in radians with `R = Rz(yaw) · Ry(pitch) · Rx(roll)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rpy {
    /// Rotation about x, applied first, in (−π, π].
    pub roll_rad: f64,
    /// Rotation about y, applied second, in [−π/2, π/2].
    pub pitch_rad: f64,
    /// Rotation about z, applied last, in (−π, π].
    pub yaw_rad: f64,
}

/// Rotation matrix `Rz(yaw) · Ry(pitch) · Rx(roll)`.
///
/// ```
/// use armtwin_core::orientation::{matrix_from_rpy, rpy_from_matrix, Rpy};
/// let rpy = Rpy { roll_rad: 0.3, pitch_rad: -1.2, yaw_rad: 2.9 };
/// let back = rpy_from_matrix(&matrix_from_rpy(rpy));
/// assert!((back.roll_rad - 0.3).abs() < 1e-12 && (back.pitch_rad + 1.2).abs() < 1e-12);
/// assert!((back.yaw_rad - 2.9).abs() < 1e-12);
/// ```
#[must_use]
pub fn matrix_from_rpy(rpy: Rpy) -> Matrix3<f64> {
    let (sr, cr) = rpy.roll_rad.sin_cos();
    let (sp, cp) = rpy.pitch_rad.sin_cos();
    let (sy, cy) = rpy.yaw_rad.sin_cos();
    Matrix3::new(
        cy * cp,
        cy * sp * sr - sy * cr,
        cy * sp * cr + sy * sr,
        sy * cp,
        sy * sp * sr + cy * cr,
        sy * sp * cr - cy * sr,
        -sp,
        cp * sr,
        cp * cr,
    )
}

/// Roll, pitch, yaw of a rotation matrix, `R = Rz(yaw) · Ry(pitch) · Rx(roll)` (the `UR10e`
/// FMU report's `matrix_to_rpy`).
///
/// At gimbal lock (`cos(pitch)` below 1e-12, pitch = ±π/2) only `roll ∓ yaw` is defined: yaw is
/// set to 0 and roll carries the whole rotation about the remaining axis.
///
/// Roll is taken after undoing yaw (from the first two rows rotated by −yaw), not from the nearly
/// vanishing third row, so `matrix_from_rpy(rpy_from_matrix(R)) == R` holds to rounding at every
/// distance from the lock.
#[must_use]
pub fn rpy_from_matrix(m: &Matrix3<f64>) -> Rpy {
    // Entries of a rotation are at most 1 in magnitude: no overflow without `hypot`.
    let cos_pitch_squared = m[(0, 0)] * m[(0, 0)] + m[(1, 0)] * m[(1, 0)];
    let cos_pitch = cos_pitch_squared.sqrt();
    // Decided on the square: roll and yaw then need not wait for the square root.
    let locked = cos_pitch_squared <= GIMBAL_LOCK_COS_PITCH * GIMBAL_LOCK_COS_PITCH;
    // Rz(−yaw) · R = Ry(pitch) · Rx(roll), whose row 1 is [0, cos(roll), −sin(roll)]; with
    // cos(yaw), sin(yaw) = m₀₀, m₁₀ over cos(pitch), and atan2 blind to a positive common factor,
    // roll = atan2(m₁₀·m₀₂ − m₀₀·m₁₂, m₀₀·m₁₁ − m₁₀·m₀₁): no division. At the lock, yaw = 0.
    let (roll_y, roll_x) = if locked {
        (-m[(1, 2)], m[(1, 1)])
    } else {
        (
            m[(1, 0)] * m[(0, 2)] - m[(0, 0)] * m[(1, 2)],
            m[(0, 0)] * m[(1, 1)] - m[(1, 0)] * m[(0, 1)],
        )
    };
    let (yaw_y, yaw_x) = if locked {
        (0.0, 1.0)
    } else {
        (m[(1, 0)], m[(0, 0)])
    };
    let [roll_rad, pitch_rad, yaw_rad] =
        trig::atan2_batch(&[roll_y, -m[(2, 0)], yaw_y], &[roll_x, cos_pitch, yaw_x]);
    Rpy {
        roll_rad: wrap_angle(roll_rad),
        // `+ 0.0` turns −0.0 into 0.0, so exact poses print without a stray sign.
        pitch_rad: pitch_rad + 0.0,
        yaw_rad: wrap_angle(yaw_rad),
    }
}

/// Unit quaternion of a rotation matrix, canonicalised to `w ≥ 0`.
///
/// The matrix must be orthonormal (it comes from the kinematics, never from outside).
#[must_use]
pub fn quaternion_from_matrix(m: &Matrix3<f64>) -> UnitQuaternion<f64> {
    canonical(UnitQuaternion::from_rotation_matrix(
        &Rotation3::from_matrix_unchecked(*m),
    ))
}

/// Rotation matrix of a unit quaternion.
#[must_use]
pub fn matrix_from_quaternion(q: &UnitQuaternion<f64>) -> Matrix3<f64> {
    q.to_rotation_matrix().into_inner()
}

/// The same rotation with `w ≥ 0` (`q` and `−q` are one rotation; the `UR10e` FMU report's rule
/// picks one).
///
/// At `w == 0` exactly (a half turn) both signs satisfy the rule and `q` is returned as is.
#[must_use]
pub fn canonical(q: UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    if q.w < 0.0 {
        UnitQuaternion::new_unchecked(-q.into_inner())
    } else {
        q
    }
}

/// Unit quaternion from components in wire order `[x, y, z, w]`; `None` unless all four are
/// finite and the norm is positive. The result is normalised and canonicalised to `w ≥ 0`.
#[must_use]
pub fn quaternion_from_xyzw(xyzw: [f64; 4]) -> Option<UnitQuaternion<f64>> {
    let [x, y, z, w] = xyzw;
    let raw = Quaternion::new(w, x, y, z);
    let norm = raw.norm();
    if !norm.is_finite() || norm <= 0.0 {
        return None;
    }
    Some(canonical(UnitQuaternion::new_unchecked(raw / norm)))
}

/// Components in wire order `[x, y, z, w]`.
#[must_use]
pub fn quaternion_to_xyzw(q: &UnitQuaternion<f64>) -> [f64; 4] {
    [q.i, q.j, q.k, q.w]
}

/// Unit quaternion of a UR rotation vector `[rx, ry, rz]` (axis · angle, radians).
///
/// Exact for any angle, including zero (series expansion below 1e-4 rad).
#[must_use]
pub fn quaternion_from_rotation_vector(rotation_vector_rad: &Vector3<f64>) -> UnitQuaternion<f64> {
    let angle_rad = rotation_vector_rad.norm();
    let half = 0.5 * angle_rad;
    // sin(θ/2)/θ, with its Taylor series where the division would lose precision.
    let scale = if angle_rad < 1e-4 {
        0.5 - angle_rad * angle_rad / 48.0
    } else {
        half.sin() / angle_rad
    };
    let v = rotation_vector_rad * scale;
    canonical(UnitQuaternion::new_unchecked(Quaternion::new(
        half.cos(),
        v.x,
        v.y,
        v.z,
    )))
}

/// UR rotation vector `[rx, ry, rz]` (axis · angle, radians) of a unit quaternion, angle in
/// [0, π]. At exactly π the axis sign is that of the quaternion's vector part.
///
/// ```
/// use armtwin_core::orientation::{quaternion_from_rotation_vector, rotation_vector_from_quaternion};
/// use nalgebra::Vector3;
/// let r = Vector3::new(0.1, -2.0, 1.2);
/// let back = rotation_vector_from_quaternion(&quaternion_from_rotation_vector(&r));
/// assert!((back - r).norm() < 1e-12);
/// ```
#[must_use]
pub fn rotation_vector_from_quaternion(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let q = canonical(*q);
    let v = q.imag();
    let sin_half = v.norm();
    if sin_half < 1e-12 {
        // θ ≈ 2·v/w to second order; w ≈ 1 here.
        return v * (2.0 / q.w);
    }
    let angle_rad = 2.0 * sin_half.atan2(q.w);
    v * (angle_rad / sin_half)
}

/// Rotation matrix of a UR rotation vector.
#[must_use]
pub fn matrix_from_rotation_vector(rotation_vector_rad: &Vector3<f64>) -> Matrix3<f64> {
    matrix_from_quaternion(&quaternion_from_rotation_vector(rotation_vector_rad))
}

/// UR rotation vector of a rotation matrix (angle in [0, π]).
#[must_use]
pub fn rotation_vector_from_matrix(m: &Matrix3<f64>) -> Vector3<f64> {
    rotation_vector_from_quaternion(&quaternion_from_matrix(m))
}

/// Angle wrapped to (−π, π].
///
/// ```
/// use armtwin_core::orientation::wrap_angle;
/// use std::f64::consts::PI;
/// assert_eq!(wrap_angle(-PI), PI);
/// assert!((wrap_angle(3.0 * PI / 2.0) + PI / 2.0).abs() < 1e-15);
/// ```
#[must_use]
pub fn wrap_angle(angle_rad: f64) -> f64 {
    if angle_rad > -PI && angle_rad <= PI {
        return angle_rad + 0.0;
    }
    let r = angle_rad.rem_euclid(TAU);
    if r > PI { r - TAU } else { r }
}

/// Angle of the rotation taking `a` to `b`, in [0, π]: `2·acos|⟨a, b⟩|`.
///
/// Computed as `2·atan2(|v|, |w|)` of the relative quaternion, which equals the acos form but
/// keeps full precision for small angles, where `acos` near 1 loses half the digits.
#[must_use]
pub fn rotation_angle_between(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
    let relative = a.inverse() * b;
    2.0 * relative.imag().norm().atan2(relative.w.abs())
}

/// Quaternion distance `1 − |⟨a, b⟩|` in [0, 1] (the `UR10e` FMU report's orientation error): 0
/// for the same rotation, 1 for a half turn. Sign-invariant, so `q` and `−q` are at distance 0.
///
/// Evaluated as `2·sin²(θ/4)` with θ from [`rotation_angle_between`], identical in exact arithmetic
/// and free of the cancellation in `1 − |⟨a, b⟩|` for nearby rotations.
#[must_use]
pub fn quaternion_distance(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
    quaternion_distance_of_angle(rotation_angle_between(a, b))
}

/// [`quaternion_distance`] of two rotations `angle_rad` apart (the [`rotation_angle_between`]
/// them): `2·sin²(θ/4)`, for a caller that has the angle already.
#[must_use]
pub fn quaternion_distance_of_angle(angle_rad: f64) -> f64 {
    let s = (0.25 * angle_rad).sin();
    2.0 * s * s
}

/// Per-angle differences `a − b` of two roll/pitch/yaw triples, each wrapped to (−π, π].
#[must_use]
pub fn rpy_difference(a: Rpy, b: Rpy) -> Rpy {
    Rpy {
        roll_rad: wrap_angle(a.roll_rad - b.roll_rad),
        pitch_rad: wrap_angle(a.pitch_rad - b.pitch_rad),
        yaw_rad: wrap_angle(a.yaw_rad - b.yaw_rad),
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "exact results are expected where tested")]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn wrap_angle_range_is_half_open_at_minus_pi() {
        assert_eq!(wrap_angle(PI), PI);
        assert_eq!(wrap_angle(-PI), PI);
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(-3.0 * PI) - PI).abs() < 1e-12);
        assert_eq!(wrap_angle(0.0), 0.0);
        assert!((wrap_angle(TAU + 0.5) - 0.5).abs() < 1e-12);
    }

    #[test]
    fn gimbal_lock_keeps_the_rotation() {
        for pitch in [FRAC_PI_2, -FRAC_PI_2] {
            let m = matrix_from_rpy(Rpy {
                roll_rad: 0.7,
                pitch_rad: pitch,
                yaw_rad: -0.4,
            });
            let rpy = rpy_from_matrix(&m);
            assert_eq!(rpy.yaw_rad, 0.0);
            assert!((rpy.pitch_rad - pitch).abs() < 1e-7);
            assert!((matrix_from_rpy(rpy) - m).norm() < 1e-12);
        }
    }

    #[test]
    fn half_turn_rotation_vector_has_angle_pi() {
        let r = Vector3::new(0.0, 0.0, PI);
        let back = rotation_vector_from_quaternion(&quaternion_from_rotation_vector(&r));
        assert!((back.norm() - PI).abs() < 1e-12);
        assert!(
            (matrix_from_rotation_vector(&back) - matrix_from_rotation_vector(&r)).norm() < 1e-12
        );
    }

    #[test]
    fn distance_and_angle_of_known_rotations() {
        let a = UnitQuaternion::identity();
        let b = quaternion_from_rotation_vector(&Vector3::new(0.0, 0.0, 0.5));
        assert!((rotation_angle_between(&a, &b) - 0.5).abs() < 1e-15);
        let expected = 1.0 - (0.25_f64).cos();
        assert!((quaternion_distance(&a, &b) - expected).abs() < 1e-15);
        let minus_b = UnitQuaternion::new_unchecked(-b.into_inner());
        assert!(quaternion_distance(&b, &minus_b) < 1e-16);
        // A tiny angle keeps its digits.
        let c = quaternion_from_rotation_vector(&Vector3::new(1e-9, 0.0, 0.0));
        assert!((rotation_angle_between(&a, &c) - 1e-9).abs() < 1e-22);
    }

    #[test]
    fn quaternion_parsing_rejects_degenerate_norms() {
        assert!(quaternion_from_xyzw([0.0; 4]).is_none());
        assert!(quaternion_from_xyzw([f64::NAN, 0.0, 0.0, 1.0]).is_none());
        assert!(quaternion_from_xyzw([f64::INFINITY, 0.0, 0.0, 1.0]).is_none());
        let q = quaternion_from_xyzw([0.0, 0.0, 0.0, -2.0]).expect("valid");
        assert_eq!(quaternion_to_xyzw(&q), [-0.0, -0.0, -0.0, 1.0]);
    }
}
