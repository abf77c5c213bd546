//! The measured pose's fields and orientation forms, and the pose of a position and one form's
//! values, with the checks every codec applies to it (a quaternion's norm, a rotation vector's
//! overflow). Knows no JSON: the slots decoder, the fast path and the binary codecs all call it.

use armtwin_core::kinematics::PoseReadout;
use armtwin_core::orientation::{self, Rpy};
use nalgebra::{UnitQuaternion, Vector3};

use super::WireError;

/// How far a quaternion's norm may be from 1 before it is rejected rather than normalised
/// (gateways round their components; a larger error means a wrong field, not rounding).
const QUATERNION_NORM_TOLERANCE: f64 = 0.05;

/// The fields of a measured pose: position, then the orientation forms in
/// [`OrientationForm::ALL`] order, each in wire order.
pub(super) const POSE_KEYS: [&str; 13] = [
    "x", "y", "z", "qx", "qy", "qz", "qw", "roll", "pitch", "yaw", "rx", "ry", "rz",
];

/// The orientation forms a measured pose may carry.
#[derive(Debug, Clone, Copy)]
pub(super) enum OrientationForm {
    /// `qx, qy, qz, qw`.
    Quaternion,
    /// `roll, pitch, yaw` (rad), `R = Rz(yaw) · Ry(pitch) · Rx(roll)`.
    RollPitchYaw,
    /// UR rotation vector `rx, ry, rz` (rad).
    RotationVector,
}
impl OrientationForm {
    pub(super) const ALL: [Self; 3] = [Self::Quaternion, Self::RollPitchYaw, Self::RotationVector];

    /// Where the form's fields are in [`POSE_KEYS`], in wire order.
    pub(super) fn slots(self) -> std::ops::Range<usize> {
        match self {
            Self::Quaternion => 3..7,
            Self::RollPitchYaw => 7..10,
            Self::RotationVector => 10..13,
        }
    }

    /// The form's fields, in wire order.
    pub(super) fn keys(self) -> &'static [&'static str] {
        &POSE_KEYS[self.slots()]
    }
}

/// The pose of a position (m) and the values of one orientation form (in the form's wire order;
/// unused trailing values ignored).
pub(super) fn pose_of(
    prefix: &str,
    position_m: [f64; 3],
    form: OrientationForm,
    values: [f64; 4],
) -> Result<PoseReadout, WireError> {
    let orientation = match form {
        OrientationForm::Quaternion => quaternion(prefix, values)?,
        OrientationForm::RollPitchYaw => {
            let [roll_rad, pitch_rad, yaw_rad, _] = values;
            orientation::quaternion_from_matrix(&orientation::matrix_from_rpy(Rpy {
                roll_rad,
                pitch_rad,
                yaw_rad,
            }))
        }
        OrientationForm::RotationVector => {
            let [rx, ry, rz, _] = values;
            rotation_vector(prefix, [rx, ry, rz])?
        }
    };
    Ok(PoseReadout::from_position_quaternion(
        position_m,
        &orientation,
    ))
}

/// A measured pose of a position (m) and a quaternion in wire order `[x, y, z, w]`, with this
/// decoder's checks (norm within 5 % of 1, then normalised and canonicalised to `qw ≥ 0`): for
/// the binary codecs that carry the same pose.
pub(crate) fn pose_from_quaternion(
    position_m: [f64; 3],
    xyzw: [f64; 4],
) -> Result<PoseReadout, WireError> {
    pose_of("", position_m, OrientationForm::Quaternion, xyzw)
}

/// A quaternion in wire order `[x, y, z, w]`, normalised if its norm is within 5 % of 1.
fn quaternion(prefix: &str, xyzw: [f64; 4]) -> Result<UnitQuaternion<f64>, WireError> {
    let norm = xyzw.iter().map(|c| c * c).sum::<f64>().sqrt();
    let error = || WireError::QuaternionNorm {
        fields: format!("{prefix}qx..qw"),
        norm,
    };
    // Also false for an infinite norm (components beyond ~1e154) and for zero.
    if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE || !norm.is_finite() {
        return Err(error());
    }
    orientation::quaternion_from_xyzw(xyzw).ok_or_else(error)
}

/// A UR rotation vector `[rx, ry, rz]` (rad); rejected if its angle overflows.
fn rotation_vector(prefix: &str, rxyz: [f64; 3]) -> Result<UnitQuaternion<f64>, WireError> {
    let q = orientation::quaternion_from_rotation_vector(&Vector3::from(rxyz));
    if q.coords.iter().all(|c| c.is_finite()) {
        return Ok(q);
    }
    // Only a norm beyond ~1e154 overflows; blame the largest component.
    let largest = (0..3)
        .max_by(|&a, &b| rxyz[a].abs().total_cmp(&rxyz[b].abs()))
        .unwrap_or(0);
    Err(WireError::NonFinite {
        field: format!(
            "{prefix}{}",
            OrientationForm::RotationVector.keys()[largest]
        ),
    })
}
