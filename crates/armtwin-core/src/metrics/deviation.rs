//! The deviation of one paired sample: the twin's pose minus the measured one, and its nine
//! non-negative magnitudes in [`METRIC_NAMES`](super::METRIC_NAMES) order.

use super::METRIC_COUNT;
use crate::kinematics::PoseReadout;
use crate::orientation;

/// Twin minus measured for one paired sample: both poses in the same frame, at the same time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Deviation {
    /// `x_twin − x_measured` (m).
    pub dx_m: f64,
    /// `y_twin − y_measured` (m).
    pub dy_m: f64,
    /// `z_twin − z_measured` (m).
    pub dz_m: f64,
    /// Euclidean distance between the two positions (m), ≥ 0.
    pub position_m: f64,
    /// Quaternion distance `1 − |⟨q_twin, q_measured⟩|`, in [0, 1]
    /// ([`orientation::quaternion_distance`]).
    pub quat_distance: f64,
    /// Angle of the rotation between the two orientations (rad), in [0, π]
    /// ([`orientation::rotation_angle_between`]).
    pub angle_rad: f64,
    /// `roll_twin − roll_measured` (rad), wrapped to (−π, π].
    pub droll_rad: f64,
    /// `pitch_twin − pitch_measured` (rad), wrapped to (−π, π].
    pub dpitch_rad: f64,
    /// `yaw_twin − yaw_measured` (rad), wrapped to (−π, π].
    pub dyaw_rad: f64,
}

impl Deviation {
    /// The deviation of the twin's pose from the measured one (`twin − measured`).
    ///
    /// ```
    /// use armtwin_core::kinematics::PoseReadout;
    /// use armtwin_core::metrics::Deviation;
    /// use nalgebra::{UnitQuaternion, Vector3};
    /// let twin = PoseReadout::from_position_quaternion([3.0, 4.0, 12.0], &UnitQuaternion::identity());
    /// let turned = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.5));
    /// let measured = PoseReadout::from_position_quaternion([0.0; 3], &turned);
    /// let d = Deviation::between(&twin, &measured);
    /// assert!((d.position_m - 13.0).abs() < 1e-12 && (d.angle_rad - 0.5).abs() < 1e-12);
    /// assert!((d.dyaw_rad + 0.5).abs() < 1e-12);
    /// ```
    #[must_use]
    pub fn between(twin: &PoseReadout, measured: &PoseReadout) -> Self {
        let [dx_m, dy_m, dz_m] =
            std::array::from_fn(|axis| twin.position_m[axis] - measured.position_m[axis]);
        let angle_rad =
            orientation::rotation_angle_between(&twin.quaternion(), &measured.quaternion());
        let rpy = orientation::rpy_difference(twin.rpy, measured.rpy);
        Self {
            dx_m,
            dy_m,
            dz_m,
            position_m: (dx_m * dx_m + dy_m * dy_m + dz_m * dz_m).sqrt(),
            quat_distance: orientation::quaternion_distance_of_angle(angle_rad),
            angle_rad,
            droll_rad: rpy.roll_rad,
            dpitch_rad: rpy.pitch_rad,
            dyaw_rad: rpy.yaw_rad,
        }
    }

    /// The nine fields, signed, in their declared order: dx, dy, dz, position, quaternion
    /// distance, angle, droll, dpitch, dyaw (the deviation columns of a validation CSV and the
    /// fields of a recorded `Deviation` message).
    #[must_use]
    pub fn fields(&self) -> [f64; 9] {
        [
            self.dx_m,
            self.dy_m,
            self.dz_m,
            self.position_m,
            self.quat_distance,
            self.angle_rad,
            self.droll_rad,
            self.dpitch_rad,
            self.dyaw_rad,
        ]
    }

    /// The nine non-negative error magnitudes, in [`METRIC_NAMES`] order: position, |dx|, |dy|,
    /// |dz|, quaternion distance, angle, |droll|, |dpitch|, |dyaw|.
    #[must_use]
    pub fn magnitudes(&self) -> [f64; METRIC_COUNT] {
        [
            self.position_m,
            self.dx_m.abs(),
            self.dy_m.abs(),
            self.dz_m.abs(),
            self.quat_distance,
            self.angle_rad,
            self.droll_rad.abs(),
            self.dpitch_rad.abs(),
            self.dyaw_rad.abs(),
        ]
    }
}
