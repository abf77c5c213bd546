//! An arm's mass distribution as its description carries it: per link, mass, centre of mass and
//! inertia tensor in the link's frame, and per joint the reflected rotor inertia of its drive.
//! The link frame is the DH frame of a DH arm (the frame at the link's distal joint; frame 6 is
//! the flange), and the joint's own frame (z along its axis) of an arm given by its joint
//! origins, a URDF's chain.
//!
//! Owns the types only; the catalog's values are in [`super::ur_inertia`], a custom arm's are
//! read by [`super::custom`], and the recursion that uses them is [`crate::dynamics`].

/// One link's mass distribution, in its link frame (see the module doc for which frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkInertial {
    /// Mass (kg).
    pub mass_kg: f64,
    /// Centre of mass (m) in the link frame.
    pub com_link_m: [f64; 3],
    /// Inertia tensor about the centre of mass, in the link frame's axes, as
    /// `[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]` (kg·m², the tensor's entries, not products of inertia
    /// with flipped sign; RTDE's `payload_inertia` order).
    pub inertia_com_kg_m2: [f64; 6],
}

/// An arm's inertial parameters: one [`LinkInertial`] and one reflected rotor inertia per joint,
/// base to flange.
#[derive(Debug, Clone, PartialEq)]
pub struct ArmInertials {
    /// Per link, in its link frame.
    pub links: Vec<LinkInertial>,
    /// Per joint: the drive's rotor inertia seen at the joint, `J_rotor · ratio²` (kg·m²); 0 where
    /// unknown.
    pub reflected_rotor_inertia_kg_m2: Vec<f64>,
    /// Per joint, the largest torque its drive gives (N·m), where the description states it for
    /// every joint (a URDF's `<limit effort>`).
    pub max_torque_nm: Option<Vec<f64>>,
    /// The gravity the description is stated under, in the base frame (m/s²): a URDF's standard
    /// gravity along its root link's −z. `None`: a controller's, 9.82 m/s² along the base's −z.
    pub gravity_base_m_s2: Option<[f64; 3]>,
}
