//! Decoded input samples, as the pipeline receives them from any source (Zenoh, CSV, FMU).

use crate::kinematics::PoseReadout;

/// One joint-angle sample of one robot.
#[derive(Debug, Clone, PartialEq)]
pub struct JointSample {
    /// Source time (s); `None` when the message had none (the transport supplies one).
    pub stamp_s: Option<f64>,
    /// The gateway's own sequence number, if it sent one.
    pub seq: Option<u64>,
    /// Joint angles (rad), already converted from degrees where the message said so.
    pub q_rad: Vec<f64>,
    /// The controller's measured TCP pose from the same packet (RTDE sends both together); its
    /// stamp is the joint sample's.
    pub measured: Option<PoseReadout>,
}

/// One measured TCP pose of one robot, in the frame its source reports (the robot's `base` frame
/// for `…/measured/<robot>`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasuredSample {
    /// Source time (s); `None` when the message had none.
    pub stamp_s: Option<f64>,
    /// The pose: position, normalised canonical quaternion, and roll/pitch/yaw derived from it.
    pub pose: PoseReadout,
}
