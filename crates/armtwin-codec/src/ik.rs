//! Inverse kinematics requests and answers as JSON: what `armtwin ik` prints and what the
//! `<prefix>/ik/<robot>` queryable answers, in one form.
//!
//! A request is `{"pose": [x, y, z, qx, qy, qz, qw], "seed": [q1, …]}` (`seed` optional; metres,
//! quaternion in wire order, normalised here; the pose in the robot's output frame).

use serde::{Deserialize, Serialize};
use thiserror::Error;

use armtwin_core::ik::{IkAnswer, IkError};
use armtwin_core::kinematics::Pose;
use armtwin_core::orientation;

/// Largest request accepted (bytes): a pose and a seed take under 1 KiB.
pub const MAX_REQUEST_BYTES: usize = 4096;

/// Why a request cannot be answered.
#[derive(Debug, Error)]
pub enum IkRequestError {
    /// Larger than [`MAX_REQUEST_BYTES`].
    #[error("request of {len} bytes exceeds the limit of {MAX_REQUEST_BYTES}")]
    TooLarge {
        /// Its size.
        len: usize,
    },
    /// Not the request's JSON.
    #[error("not an IK request ({{\"pose\": [x, y, z, qx, qy, qz, qw], \"seed\": [...]}}): {0}")]
    Json(String),
    /// The pose does not have 7 values.
    #[error("the pose takes 7 values x,y,z,qx,qy,qz,qw, got {got}")]
    PoseLength {
        /// How many it had.
        got: usize,
    },
    /// The quaternion is zero or not finite.
    #[error("the pose's quaternion must be finite and non-zero")]
    Quaternion,
    /// The solver found no answer.
    #[error(transparent)]
    Ik(#[from] IkError),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RequestJson {
    pose: Vec<f64>,
    #[serde(default)]
    seed: Vec<f64>,
}

/// A decoded request: the target `frame_from_tcp` and the seed (empty: none).
#[derive(Debug, Clone)]
pub struct IkRequest {
    /// The target pose.
    pub target: Pose,
    /// Joint angles (rad) to prefer solutions near; empty for none.
    pub seed_rad: Vec<f64>,
}

impl IkRequest {
    /// The request of a pose's seven values and a seed.
    pub fn new(pose: &[f64], seed_rad: Vec<f64>) -> Result<Self, IkRequestError> {
        let [x, y, z, qx, qy, qz, qw]: [f64; 7] = pose
            .try_into()
            .map_err(|_| IkRequestError::PoseLength { got: pose.len() })?;
        let orientation = orientation::quaternion_from_xyzw([qx, qy, qz, qw])
            .ok_or(IkRequestError::Quaternion)?;
        Ok(Self {
            target: Pose {
                position_m: nalgebra::Vector3::new(x, y, z),
                rotation: orientation::matrix_from_quaternion(&orientation),
            },
            seed_rad,
        })
    }

    /// A request's JSON bytes.
    pub fn decode(payload: &[u8]) -> Result<Self, IkRequestError> {
        if payload.len() > MAX_REQUEST_BYTES {
            return Err(IkRequestError::TooLarge { len: payload.len() });
        }
        let request: RequestJson =
            serde_json::from_slice(payload).map_err(|e| IkRequestError::Json(e.to_string()))?;
        Self::new(&request.pose, request.seed)
    }

    /// The seed, if there is one.
    #[must_use]
    pub fn seed(&self) -> Option<&[f64]> {
        (!self.seed_rad.is_empty()).then_some(self.seed_rad.as_slice())
    }
}

/// One solution as written.
#[derive(Debug, Clone, Serialize)]
pub struct IkSolutionJson {
    /// Joint angles (rad).
    pub q: [f64; 6],
    /// `left` / `right`.
    pub shoulder: &'static str,
    /// `up` / `down`.
    pub elbow: &'static str,
    /// `flip` / `no_flip`.
    pub wrist: &'static str,
    /// Distance of the solution's FK from the target (m).
    pub position_error_m: f64,
    /// Rotation angle between the solution's FK and the target (rad).
    pub angle_error_rad: f64,
    /// Distance from the seed (rad), 0 without one.
    pub distance_from_seed_rad: f64,
}

/// An answer as written: `{solutions, wrist_singular, outside_limits}`.
#[derive(Debug, Clone, Serialize)]
pub struct IkAnswerJson {
    /// Nearest to the seed first.
    pub solutions: Vec<IkSolutionJson>,
    /// The wrist is singular: `q₆` was taken from the seed.
    pub wrist_singular: bool,
    /// Configurations outside the joint limits.
    pub outside_limits: usize,
}

impl From<&IkAnswer> for IkAnswerJson {
    fn from(answer: &IkAnswer) -> Self {
        Self {
            solutions: answer
                .solutions
                .iter()
                .map(|solution| IkSolutionJson {
                    q: solution.q_rad,
                    shoulder: solution.configuration.shoulder.as_str(),
                    elbow: solution.configuration.elbow.as_str(),
                    wrist: solution.configuration.wrist.as_str(),
                    position_error_m: solution.position_error_m,
                    angle_error_rad: solution.angle_error_rad,
                    distance_from_seed_rad: solution.distance_from_seed_rad,
                })
                .collect(),
            wrist_singular: answer.wrist_singular,
            outside_limits: answer.outside_limits,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_are_checked_before_solving() {
        assert!(matches!(
            IkRequest::decode(br#"{"pose": [0.1, 0.2]}"#),
            Err(IkRequestError::PoseLength { got: 2 })
        ));
        assert!(matches!(
            IkRequest::decode(br#"{"pose": [0.1, 0.2, 0.3, 0, 0, 0, 0]}"#),
            Err(IkRequestError::Quaternion)
        ));
        assert!(matches!(
            IkRequest::decode(br#"{"pose": [0.1, 0.2, 0.3, 0, 0, 0, 1], "sed": []}"#),
            Err(IkRequestError::Json(_))
        ));
        assert!(matches!(
            IkRequest::decode(&vec![b' '; MAX_REQUEST_BYTES + 1]),
            Err(IkRequestError::TooLarge { .. })
        ));
        let request =
            IkRequest::decode(br#"{"pose": [0.1, 0.2, 0.3, 0, 0, 0, 2], "seed": [0,0,0,0,0,0]}"#)
                .expect("valid");
        assert_eq!(request.seed().map(<[f64]>::len), Some(6));
        assert!((request.target.rotation - nalgebra::Matrix3::identity()).norm() < 1e-15);
    }
}
