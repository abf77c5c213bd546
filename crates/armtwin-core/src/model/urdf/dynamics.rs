//! Inverse dynamics of a URDF chain by the recursive Newton–Euler algorithm over the whole tree:
//! the torques a chain's joints apply include every body they carry, links past the tip and side
//! branches (a head beside an arm, the fingers of a hand), whose own joints are held at zero and
//! at rest.

use std::collections::HashMap;

use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

use super::{Inertial, JointKind, UrdfChain, UrdfError, UrdfRobot};

/// Standard gravity (m/s²), along the root link's −z: the URDF's convention, and Pinocchio's and
/// Gazebo's default.
pub const STANDARD_GRAVITY_M_S2: f64 = 9.81;

/// One link of the tree below the root, with the joint that carries it.
#[derive(Debug, Clone)]
struct TreeBody {
    /// The body its joint hangs from; `None` for the root link.
    parent: Option<usize>,
    /// The joint's `<origin>`: the parent link to the joint frame.
    origin: nalgebra::IsometryMatrix3<f64>,
    /// How it moves; `None` for a fixed joint (or the root).
    kind: Option<JointKind>,
    axis: Unit<Vector3<f64>>,
    /// Its index in the chain's joint values, if the chain moves it.
    chain_index: Option<usize>,
    inertial: Inertial,
}

/// The inverse dynamics of one chain of a URDF, with the whole tree's bodies.
#[derive(Debug, Clone)]
pub struct UrdfDynamics {
    /// Parents before children.
    bodies: Vec<TreeBody>,
    joint_count: usize,
    /// Gravity in the root link's frame (m/s²).
    gravity_root_m_s2: Vector3<f64>,
}

/// A link's motion in its own frame: angular velocity and acceleration, and its origin's linear
/// acceleration.
#[derive(Debug, Clone, Copy)]
struct Motion {
    omega: Vector3<f64>,
    omega_dot: Vector3<f64>,
    accel: Vector3<f64>,
}

impl UrdfDynamics {
    /// The dynamics of `chain`, a chain of `robot`, under standard gravity along the root link's
    /// −z.
    pub fn new(robot: &UrdfRobot, chain: &UrdfChain) -> Result<Self, UrdfError> {
        let chain_index = chain.joint_indices();
        let link_index = robot.link_indices();
        // Parents before children: each body's joint hangs from a body already placed.
        let mut bodies = Vec::with_capacity(robot.links.len());
        let mut body_of: HashMap<&str, usize> = HashMap::with_capacity(robot.links.len());
        for link in robot.links_from_root() {
            let inertial = robot.inertials[link_index[link]];
            let body = match robot.joint_to.get(link) {
                None => TreeBody {
                    parent: None,
                    origin: nalgebra::IsometryMatrix3::identity(),
                    kind: None,
                    axis: Vector3::z_axis(),
                    chain_index: None,
                    inertial,
                },
                Some(&joint_index) => {
                    let joint = &robot.joints[joint_index];
                    TreeBody {
                        parent: Some(body_of[joint.parent.as_str()]),
                        origin: joint.origin,
                        kind: joint.kind,
                        axis: joint.axis,
                        chain_index: chain_index.get(joint.name.as_str()).copied(),
                        inertial,
                    }
                }
            };
            body_of.insert(link, bodies.len());
            bodies.push(body);
        }
        if bodies.iter().filter(|b| b.chain_index.is_some()).count() != chain.joints.len() {
            return Err(UrdfError::Chain(
                "the chain is not a chain of this URDF".to_owned(),
            ));
        }
        Ok(Self {
            bodies,
            joint_count: chain.joints.len(),
            gravity_root_m_s2: Vector3::new(0.0, 0.0, -STANDARD_GRAVITY_M_S2),
        })
    }

    /// The number of the chain's moving joints.
    #[must_use]
    pub fn joint_count(&self) -> usize {
        self.joint_count
    }

    /// The torques (N·m, or N for a prismatic joint) the chain's joints apply for accelerations
    /// `qdd` at positions `q` and velocities `qd` (base to tip, as the chain's joints), gravity
    /// included; every joint off the chain held at zero and at rest.
    pub fn inverse_dynamics(
        &self,
        q: &[f64],
        qd: &[f64],
        qdd: &[f64],
    ) -> Result<Vec<f64>, UrdfError> {
        for values in [q, qd, qdd] {
            if values.len() != self.joint_count {
                return Err(UrdfError::JointCount {
                    expected: self.joint_count,
                    got: values.len(),
                });
            }
        }
        let value = |body: &TreeBody, values: &[f64]| body.chain_index.map_or(0.0, |i| values[i]);
        // Per body: the parent-to-body rotation and translation, and the body's motion. The
        // root's acceleration is gravity's opposite, which adds gravity to every body's load.
        let mut placements = Vec::with_capacity(self.bodies.len());
        let mut motions: Vec<Motion> = Vec::with_capacity(self.bodies.len());
        for body in &self.bodies {
            let Some(parent) = body.parent else {
                placements.push((Rotation3::identity(), Vector3::zeros()));
                motions.push(Motion {
                    omega: Vector3::zeros(),
                    omega_dot: Vector3::zeros(),
                    accel: -self.gravity_root_m_s2,
                });
                continue;
            };
            let (position, velocity, acceleration) =
                (value(body, q), value(body, qd), value(body, qdd));
            let axis = body.axis.into_inner();
            let (rotation, translation) = match body.kind {
                Some(JointKind::Revolute | JointKind::Continuous) => (
                    body.origin.rotation * Rotation3::from_axis_angle(&body.axis, position),
                    body.origin.translation.vector,
                ),
                Some(JointKind::Prismatic) => (
                    body.origin.rotation,
                    body.origin.translation.vector + body.origin.rotation * (axis * position),
                ),
                None => (body.origin.rotation, body.origin.translation.vector),
            };
            let from = motions[parent];
            let back = rotation.inverse();
            let omega_in = back * from.omega;
            let mut motion = Motion {
                omega: omega_in,
                omega_dot: back * from.omega_dot,
                accel: back
                    * (from.accel
                        + from.omega_dot.cross(&translation)
                        + from.omega.cross(&from.omega.cross(&translation))),
            };
            match body.kind {
                Some(JointKind::Revolute | JointKind::Continuous) => {
                    motion.omega = omega_in + axis * velocity;
                    motion.omega_dot += axis * acceleration + omega_in.cross(&(axis * velocity));
                }
                Some(JointKind::Prismatic) => {
                    motion.accel += axis * acceleration + 2.0 * omega_in.cross(&(axis * velocity));
                }
                None => {}
            }
            placements.push((rotation, translation));
            motions.push(motion);
        }
        // Backward: each body's force and moment about its origin, in its frame, handed to its
        // parent; a moving joint's torque is their part along its axis.
        let mut forces = vec![Vector3::zeros(); self.bodies.len()];
        let mut moments = vec![Vector3::zeros(); self.bodies.len()];
        let mut torques = vec![0.0; self.joint_count];
        for (index, body) in self.bodies.iter().enumerate().rev() {
            let Motion {
                omega,
                omega_dot,
                accel,
            } = motions[index];
            let Inertial {
                mass_kg,
                com_m,
                inertia_kg_m2,
            } = body.inertial;
            let com_accel = accel + omega_dot.cross(&com_m) + omega.cross(&omega.cross(&com_m));
            let force = mass_kg * com_accel;
            let inertia: &Matrix3<f64> = &inertia_kg_m2;
            forces[index] += force;
            moments[index] +=
                inertia * omega_dot + omega.cross(&(inertia * omega)) + com_m.cross(&force);
            if let Some(chain_index) = body.chain_index {
                let along = match body.kind {
                    Some(JointKind::Prismatic) => forces[index],
                    _ => moments[index],
                };
                torques[chain_index] = body.axis.dot(&along);
            }
            if let Some(parent) = body.parent {
                let (rotation, translation) = placements[index];
                let force_in_parent = rotation * forces[index];
                let moment_in_parent =
                    rotation * moments[index] + translation.cross(&force_in_parent);
                forces[parent] += force_in_parent;
                moments[parent] += moment_in_parent;
            }
        }
        Ok(torques)
    }
}
