//! A pose as named fields (`x, y, z, roll, pitch, yaw, qx, qy, qz, qw`): the output names of the
//! service's messages, `validate`'s CSV and the FMU's variables, defined once.

use serde::Serialize;

use crate::kinematics::PoseReadout;

/// A pose with the `UR10e` FMU report's output names (`x, y, z, roll, pitch, yaw, qx, qy, qz, qw`):
/// metres, radians, quaternion `qw ≥ 0`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PoseFields {
    /// TCP x (m).
    pub x: f64,
    /// TCP y (m).
    pub y: f64,
    /// TCP z (m).
    pub z: f64,
    /// Roll (rad), `R = Rz(yaw) · Ry(pitch) · Rx(roll)`.
    pub roll: f64,
    /// Pitch (rad).
    pub pitch: f64,
    /// Yaw (rad).
    pub yaw: f64,
    /// Quaternion x.
    pub qx: f64,
    /// Quaternion y.
    pub qy: f64,
    /// Quaternion z.
    pub qz: f64,
    /// Quaternion w (≥ 0).
    pub qw: f64,
}

impl From<&PoseReadout> for PoseFields {
    fn from(readout: &PoseReadout) -> Self {
        let [x, y, z] = readout.position_m;
        let [qx, qy, qz, qw] = readout.quaternion_xyzw;
        Self {
            x,
            y,
            z,
            roll: readout.rpy.roll_rad,
            pitch: readout.rpy.pitch_rad,
            yaw: readout.rpy.yaw_rad,
            qx,
            qy,
            qz,
            qw,
        }
    }
}

impl PoseFields {
    /// Column names in output order.
    pub const NAMES: [&'static str; 10] = [
        "x", "y", "z", "roll", "pitch", "yaw", "qx", "qy", "qz", "qw",
    ];

    /// Values in the order of [`Self::NAMES`].
    #[must_use]
    pub fn values(&self) -> [f64; 10] {
        [
            self.x, self.y, self.z, self.roll, self.pitch, self.yaw, self.qx, self.qy, self.qz,
            self.qw,
        ]
    }
}
