//! A robot's URDF description, as a user or a robot's `/robot_description` hands it in: every
//! chain from the root to a leaf that parses gives a finite pose with a rotation, and torques, at
//! zero joint values; anything else is an error, never a panic.

use armtwin_core::model::urdf::{UrdfDynamics, UrdfRobot};

/// Leaves tried per description: a generated tree may have thousands.
const MAX_LEAVES: usize = 16;

/// Runs every check of this decoder on one input; panics on a broken invariant.
pub fn check(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    let robot = match UrdfRobot::parse(text) {
        Ok(robot) => robot,
        Err(error) => {
            assert!(!error.to_string().is_empty());
            return;
        }
    };
    for leaf in robot.leaf_links().into_iter().take(MAX_LEAVES) {
        let chain = match robot.chain(None, Some(leaf)) {
            Ok(chain) => chain,
            Err(error) => {
                assert!(!error.to_string().is_empty());
                continue;
            }
        };
        let pose = chain
            .pose(&vec![0.0; chain.joint_count()])
            .expect("zeros fit the chain");
        assert!(pose.position_m.iter().all(|v| v.is_finite()), "{pose:?}");
        let zeros = vec![0.0; chain.joint_count()];
        let dynamics = UrdfDynamics::new(&robot, &chain).expect("a chain of this robot");
        let torques = dynamics
            .inverse_dynamics(&zeros, &zeros, &zeros)
            .expect("zeros fit the chain");
        assert!(torques.iter().all(|t| t.is_finite()), "{torques:?}");
        let gram = pose.rotation.transpose() * pose.rotation;
        for (i, j) in (0..3).flat_map(|i| (0..3).map(move |j| (i, j))) {
            let identity = if i == j { 1.0 } else { 0.0 };
            assert!(
                (gram[(i, j)] - identity).abs() < 1e-9,
                "not a rotation: {pose:?}"
            );
        }
    }
}
