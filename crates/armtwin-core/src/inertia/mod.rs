//! An arm's inertial parameters: each link's mass distribution ([`LinkInertial`]) and the
//! drives' reflected rotor inertia ([`ArmInertials`]), as a model describes its arm; the
//! published Universal Robots tables and drive data in [`ur`].
//!
//! Owns these data only, which the model ([`crate::model`]) carries and the dynamics
//! ([`crate::dynamics`]) compute with. Must not compute: the recursions are the dynamics'.
//! Frames are the dynamics' (the DH link frame of each link).

pub mod ur;

/// One link's mass distribution, in its DH link frame (see the module doc for which frame).
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
    /// Per link, in its DH link frame.
    pub links: Vec<LinkInertial>,
    /// Per joint: the drive's rotor inertia seen at the joint, `J_rotor · ratio²` (kg·m²); 0 where
    /// unknown.
    pub reflected_rotor_inertia_kg_m2: Vec<f64>,
}
