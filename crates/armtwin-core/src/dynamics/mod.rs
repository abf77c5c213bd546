//! Inverse dynamics of serial arms with revolute joints: joint torques from joint positions,
//! velocities and accelerations (recursive Newton–Euler), gravity torques, the joint-space mass
//! matrix, and the generalized momentum with the `C(q, q̇)ᵀ q̇` term a momentum observer needs.
//!
//! Owns: the payload, the friction of each joint, the gravity vector of the mounting, and the
//! recursions over them and the arm's own inertial parameters ([`LinkInertial`], [`ArmInertials`],
//! which its description carries: `crate::model::inertia`). Must not: read files, keep caches, allocate per call, or know where
//! the joint states come from (the service, a recording and the FMU hand them in alike). The
//! published Universal Robots tables and drive data are in [`ur`]; the payload's identification
//! from torques in [`payload`].
//!
//! Frames. Link i's inertial parameters are given in the DH frame of link i in the arm's
//! convention: standard DH (every catalog arm) puts it at the link's distal joint (frame 6 is the
//! flange), Craig's modified DH at the link's own joint. The recursion itself runs in *joint
//! frames*, the frame right after joint i's rotation `Rz(qᵢ + θᵢ)`, whose z axis is the joint axis
//! through its origin: the arm is compiled once to `F₀ · Rz(q₁ + θ₁) · F₁ · … · Rz(qₙ + θₙ)` with
//! fixed `Fₖ = Rx(α) · (a, 0, d)` (as the kinematics compile it), and each link's parameters are
//! moved into its joint frame once, so a call needs no per-link offset and the joint axis is
//! always `z`. An arm given by its joint origins (a URDF's chain) has its joint frames already,
//! each `Fₖ` a rotation and an origin, and its links' parameters in them. Gravity is a vector in
//! the base frame (DH frame 0, a URDF's base link); the payload's centre of gravity is in the
//! flange frame, as RTDE's `payload_cog` and the pendant give it.
//!
//! Torques `τ = M(q) q̈ + C(q, q̇) q̇ + g(q) + J_r q̈ + τ_f(q̇)`: rigid-body terms from the
//! recursion, `J_r` the reflected rotor inertia (rotor inertia × gear ratio², a diagonal constant
//! that [`ArmDynamics::mass_matrix_kg_m2`] includes), `τ_f` Coulomb plus viscous friction. Universal
//! Robots' controller reports `target_moment` as this without friction, with gravity 9.82 m/s²
//! and the payload as configured.

pub mod monitor;
pub mod payload;

use nalgebra::{Matrix3, SMatrix, Vector3};
use thiserror::Error;

use crate::kinematics::{DhConvention, DhParameters};
pub use crate::model::inertia::{ArmInertials, LinkInertial};
/// Published inertial and drive parameters of the Universal Robots catalog arms (kept with the
/// arms' descriptions, which carry them).
pub use crate::model::ur_inertia as ur;
use crate::model::{ArmDescription, JointOrigins};
use crate::trig;

/// Standard gravity as Universal Robots' controller uses it in its torque model (m/s²).
pub const UR_CONTROLLER_GRAVITY_M_S2: f64 = 9.82;

/// What a Universal Robots controller's torque model (RTDE `target_moment`) contains.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControllerMode {
    /// A program moves the arm: the full inverse dynamics of the target state plus rotor inertia,
    /// no friction.
    Program,
    /// Freedrive (teach button held, `target_qdd` ≡ 0): gravity only; velocity terms make the
    /// comparison worse.
    Freedrive,
}

impl ControllerMode {
    /// The bit of RTDE `robot_status_bits` set while the teach button is pressed.
    pub const TEACH_BUTTON_BIT: u32 = crate::sample::ControllerStatus::TEACH_BUTTON_BIT;

    /// The wire name: `program` or `freedrive`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Program => "program",
            Self::Freedrive => "freedrive",
        }
    }

    /// The mode RTDE's `robot_status_bits` report.
    #[must_use]
    pub fn from_robot_status_bits(bits: u32) -> Self {
        if bits & (1 << Self::TEACH_BUTTON_BIT) == 0 {
            Self::Program
        } else {
            Self::Freedrive
        }
    }
}

/// A payload rigidly attached to the flange.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Payload {
    /// Mass (kg).
    pub mass_kg: f64,
    /// Centre of gravity (m) in the flange frame.
    pub cog_flange_m: [f64; 3],
    /// Inertia tensor about the centre of gravity in the flange frame's axes,
    /// `[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]` (kg·m²); zeros for a point mass, as the controller models it.
    pub inertia_cog_kg_m2: [f64; 6],
}

impl Payload {
    /// No payload.
    pub const NONE: Self = Self {
        mass_kg: 0.0,
        cog_flange_m: [0.0; 3],
        inertia_cog_kg_m2: [0.0; 6],
    };

    /// A point mass of `mass_kg` at `cog_flange_m` (RTDE's `payload` and `payload_cog`).
    #[must_use]
    pub fn point_mass(mass_kg: f64, cog_flange_m: [f64; 3]) -> Self {
        Self {
            mass_kg,
            cog_flange_m,
            inertia_cog_kg_m2: [0.0; 6],
        }
    }
}

/// One joint's friction: `τ_f = coulomb · sign(q̇) + viscous · q̇`, with `sign(0) = 0`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct JointFriction {
    /// Coulomb friction (N·m), at least 0.
    pub coulomb_nm: f64,
    /// Viscous friction (N·m·s/rad), at least 0.
    pub viscous_nm_s_rad: f64,
}

impl JointFriction {
    /// The friction torque (N·m) at joint velocity `qd_rad_s`, opposing the motion as a torque
    /// the drive must add.
    #[must_use]
    pub fn torque_nm(&self, qd_rad_s: f64) -> f64 {
        let sign = if qd_rad_s > 0.0 {
            1.0
        } else if qd_rad_s < 0.0 {
            -1.0
        } else {
            0.0
        };
        self.coulomb_nm * sign + self.viscous_nm_s_rad * qd_rad_s
    }
}

/// Why an arm's dynamics cannot be built or changed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum DynamicsError {
    /// The arm's joint count differs from the dynamics' fixed joint count.
    #[error("the dynamics are built for {expected} joints; the arm has {got}")]
    JointCount {
        /// The dynamics' joint count.
        expected: usize,
        /// The arm's.
        got: usize,
    },
    /// The arm carries no inertial parameters.
    #[error("arm '{model}' has no inertial parameters (a custom arm gives them in [dynamics])")]
    NoInertials {
        /// The arm's name.
        model: String,
    },
    /// A parameter list has the wrong length.
    #[error("{what}: expected {expected} entries, got {got}")]
    ParameterCount {
        /// Which list.
        what: &'static str,
        /// The joint count.
        expected: usize,
        /// How many were given.
        got: usize,
    },
    /// A parameter is not finite, or negative where it must not be.
    #[error("{what} = {value} is invalid: {reason}")]
    InvalidParameter {
        /// Which parameter, e.g. `link 3 mass_kg`.
        what: String,
        /// The offending value.
        value: f64,
        /// Why.
        reason: &'static str,
    },
}

/// `value` if finite (and, with `non_negative`, at least 0), else the error naming it.
fn checked(
    what: impl FnOnce() -> String,
    value: f64,
    non_negative: bool,
) -> Result<f64, DynamicsError> {
    if !value.is_finite() {
        return Err(DynamicsError::InvalidParameter {
            what: what(),
            value,
            reason: "not a finite number",
        });
    }
    if non_negative && value < 0.0 {
        return Err(DynamicsError::InvalidParameter {
            what: what(),
            value,
            reason: "negative",
        });
    }
    Ok(value)
}

/// A rigid body's inertial parameters about a frame's origin, in that frame: what the recursion
/// needs, with the centre of mass folded in so a call never shifts an inertia.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Body {
    mass_kg: f64,
    /// `m · c` (kg·m), `c` the centre of mass.
    first_moment_kg_m: Vector3<f64>,
    /// Inertia about the frame's origin (kg·m²): `I_c + m (|c|² E − c cᵀ)`.
    inertia_origin_kg_m2: Matrix3<f64>,
}

impl Body {
    const NONE: Self = Self {
        mass_kg: 0.0,
        first_moment_kg_m: Vector3::new(0.0, 0.0, 0.0),
        inertia_origin_kg_m2: Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    };

    /// The body of mass `mass_kg` with its centre at `com_m` and tensor `[Ixx, Iyy, Izz, Ixy,
    /// Ixz, Iyz]` about it, all in a frame `source`, expressed in `target` where
    /// `target_from_source` is `(rotation, translation)`.
    fn from_com(
        mass_kg: f64,
        com_m: [f64; 3],
        inertia_com_kg_m2: [f64; 6],
        target_from_source: &RigidTransform,
    ) -> Self {
        let (rotation, translation) = target_from_source;
        let [ixx, iyy, izz, ixy, ixz, iyz] = inertia_com_kg_m2;
        let inertia_source = Matrix3::new(ixx, ixy, ixz, ixy, iyy, iyz, ixz, iyz, izz);
        let inertia_com = rotation * inertia_source * rotation.transpose();
        let com = rotation * Vector3::from(com_m) + translation;
        let shift = Matrix3::identity() * com.norm_squared() - com * com.transpose();
        Self {
            mass_kg,
            first_moment_kg_m: com * mass_kg,
            inertia_origin_kg_m2: inertia_com + shift * mass_kg,
        }
    }

    fn plus(&self, other: &Self) -> Self {
        Self {
            mass_kg: self.mass_kg + other.mass_kg,
            first_moment_kg_m: self.first_moment_kg_m + other.first_moment_kg_m,
            inertia_origin_kg_m2: self.inertia_origin_kg_m2 + other.inertia_origin_kg_m2,
        }
    }
}

/// A rigid transform `target_from_source` as `(rotation, translation)`.
type RigidTransform = (Matrix3<f64>, Vector3<f64>);

/// The fixed part of the transform from joint frame i−1 (or the base) to joint frame i:
/// `Rx(α) · Rz(qᵢ + θᵢ)` with the origin at `(a, 0, d)` for a DH arm; any fixed rotation and
/// origin, then `Rz(qᵢ)`, for an arm given by its joint origins.
#[derive(Debug, Clone, Copy, PartialEq)]
struct JointGeometry {
    twist: Twist,
    /// Joint i's origin in joint frame i−1 (m).
    origin_m: Vector3<f64>,
    theta_offset_rad: f64,
}

/// `(cos α, sin α)`, exact for ±π/2 and 0 as the kinematics build them (UR tables hold ±π/2,
/// whose cosine rounds to 6e-17).
#[allow(clippy::float_cmp, reason = "exactly ±π/2 is what nominal tables hold")]
fn cos_sin(alpha_rad: f64) -> (f64, f64) {
    use std::f64::consts::FRAC_PI_2;
    if alpha_rad == FRAC_PI_2 {
        (0.0, 1.0)
    } else if alpha_rad == -FRAC_PI_2 {
        (0.0, -1.0)
    } else {
        let (sin, cos) = alpha_rad.sin_cos();
        (cos, sin)
    }
}

/// A link twist `Rx(α)`, or any fixed rotation between two joint frames (a URDF's joint
/// origins). Every catalog arm's twists are 0 or ±π/2, where the rotation only swaps and negates
/// components: naming those cases saves the recursion a third of its multiplications (the branch
/// is the same on every call, so it predicts).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Twist {
    Zero,
    QuarterTurn,
    MinusQuarterTurn,
    Other { cos_alpha: f64, sin_alpha: f64 },
    Rotation(Matrix3<f64>),
}

impl Twist {
    #[allow(clippy::float_cmp, reason = "only exact 0 and ±π/2 take the shortcuts")]
    fn from_alpha(alpha_rad: f64) -> Self {
        use std::f64::consts::FRAC_PI_2;
        if alpha_rad == 0.0 {
            Self::Zero
        } else if alpha_rad == FRAC_PI_2 {
            Self::QuarterTurn
        } else if alpha_rad == -FRAC_PI_2 {
            Self::MinusQuarterTurn
        } else {
            let (sin_alpha, cos_alpha) = alpha_rad.sin_cos();
            Self::Other {
                cos_alpha,
                sin_alpha,
            }
        }
    }

    /// The twist of `parent_from_joint`: a named case where it is exactly one (an exact
    /// identity or quarter turn about x), else the rotation itself.
    #[allow(clippy::float_cmp, reason = "only exact rotations take the shortcuts")]
    fn from_rotation(parent_from_joint: &Matrix3<f64>) -> Self {
        [
            (Self::Zero, 1.0, 0.0),
            (Self::QuarterTurn, 0.0, 1.0),
            (Self::MinusQuarterTurn, 0.0, -1.0),
        ]
        .into_iter()
        .find(|(_, c, s)| {
            *parent_from_joint == Matrix3::new(1.0, 0.0, 0.0, 0.0, *c, -s, 0.0, *s, *c)
        })
        .map_or(Self::Rotation(*parent_from_joint), |(twist, ..)| twist)
    }

    /// `Rx(α) · v`.
    #[inline]
    fn rotate(&self, v: &Vector3<f64>) -> Vector3<f64> {
        match self {
            Self::Zero => *v,
            Self::QuarterTurn => Vector3::new(v.x, -v.z, v.y),
            Self::MinusQuarterTurn => Vector3::new(v.x, v.z, -v.y),
            Self::Other {
                cos_alpha: c,
                sin_alpha: s,
            } => Vector3::new(v.x, c * v.y - s * v.z, s * v.y + c * v.z),
            Self::Rotation(rotation) => rotation * v,
        }
    }

    /// `Rx(α)ᵀ · v`.
    #[inline]
    fn rotate_back(&self, v: &Vector3<f64>) -> Vector3<f64> {
        match self {
            Self::Zero => *v,
            Self::QuarterTurn => Vector3::new(v.x, v.z, -v.y),
            Self::MinusQuarterTurn => Vector3::new(v.x, -v.z, v.y),
            Self::Other {
                cos_alpha: c,
                sin_alpha: s,
            } => Vector3::new(v.x, c * v.y + s * v.z, c * v.z - s * v.y),
            Self::Rotation(rotation) => rotation.tr_mul(v),
        }
    }
}

/// The rotation `parent_from_child = Rx(α) · Rz(q + θ)` of one joint at one state.
#[derive(Debug, Clone, Copy)]
struct JointRotation<'a> {
    /// Borrowed: a general rotation is a whole 3×3 matrix, copied per joint and call otherwise.
    twist: &'a Twist,
    cos_q: f64,
    sin_q: f64,
}

impl JointRotation<'_> {
    /// `R · v`: a child-frame vector in the parent frame.
    #[inline]
    fn in_parent(&self, v: &Vector3<f64>) -> Vector3<f64> {
        let (c, s) = (self.cos_q, self.sin_q);
        self.twist
            .rotate(&Vector3::new(c * v.x - s * v.y, s * v.x + c * v.y, v.z))
    }

    /// `Rᵀ · v`: a parent-frame vector in the child frame.
    #[inline]
    fn in_child(&self, v: &Vector3<f64>) -> Vector3<f64> {
        let (c, s) = (self.cos_q, self.sin_q);
        let u = self.twist.rotate_back(v);
        Vector3::new(c * u.x + s * u.y, c * u.y - s * u.x, u.z)
    }
}

/// `Tz(d) · Tx(a) · Rx(α)` as `(rotation, translation)`.
fn tz_tx_rx(d_m: f64, a_m: f64, alpha_rad: f64) -> RigidTransform {
    let (c, s) = cos_sin(alpha_rad);
    (
        Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c),
        Vector3::new(a_m, 0.0, d_m),
    )
}

/// An arm's inverse dynamics for a fixed joint count `N` (6 for every catalog arm): the arm's
/// geometry and inertial parameters compiled into joint frames, with a mounting (gravity), a
/// payload, rotor inertia and friction. Immutable; `with_*` return a changed copy. Every method is
/// a pure function of its arguments and allocates nothing.
///
/// Inputs are not checked: a NaN in gives NaN out. Joint states from outside go through
/// [`RobotModel::check_joints`](crate::model::RobotModel::check_joints) first.
///
/// A UR5e holding 2 kg at rest: the torques are the gravity torques, and the shoulder (joint 2)
/// holds the most:
///
/// ```
/// use approx::assert_relative_eq;
/// use armtwin_core::dynamics::{ArmDynamics, Payload};
/// use armtwin_core::model::catalog;
///
/// let dynamics = ArmDynamics::<6>::from_arm(&catalog::arm("ur5e")?)?
///     .with_payload(Payload::point_mass(2.0, [0.0, 0.0, 0.05]))?;
/// let q_rad = [0.3, -1.2, 1.4, -0.9, 1.5707963267948966, 0.0];
/// let tau_nm = dynamics.inverse_dynamics_nm(&q_rad, &[0.0; 6], &[0.0; 6]);
/// let gravity_nm = dynamics.gravity_nm(&q_rad);
/// for (tau, gravity) in tau_nm.iter().zip(gravity_nm) {
///     assert_relative_eq!(*tau, gravity, epsilon = 1e-12);
/// }
/// // Joint 1 turns about the vertical: gravity does no work on it.
/// assert!(tau_nm[0].abs() < 1e-12);
/// assert!(tau_nm[1].abs() > tau_nm[2].abs() && tau_nm[1].abs() > 20.0);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct ArmDynamics<const N: usize = 6> {
    joints: [JointGeometry; N],
    /// Per link in its joint frame, the payload folded into the last.
    bodies: [Body; N],
    /// The last link without the payload.
    last_link: Body,
    /// `joint_n_from_flange` as `(rotation, translation)`.
    last_joint_from_flange: RigidTransform,
    reflected_rotor_inertia_kg_m2: [f64; N],
    friction: [JointFriction; N],
    gravity_base_m_s2: Vector3<f64>,
    payload: Payload,
}

/// The generalized momentum and the term its derivative needs (`ṗ = τ − g(q) + C(q, q̇)ᵀ q̇`,
/// with τ the torque the joints apply beyond friction).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MomentumTerms<const N: usize = 6> {
    /// `p = M(q) q̇`, rotor inertia included (N·m·s).
    pub momentum_nms: [f64; N],
    /// `C(q, q̇)ᵀ q̇` (N·m) for the `C` with `Ṁ = C + Cᵀ` (unique as this product).
    pub coriolis_transpose_qd_nm: [f64; N],
}

impl<const N: usize> ArmDynamics<N> {
    /// The dynamics of `arm` from its inertial parameters, with the gravity they are stated
    /// under (a URDF's: 9.81 m/s² along its root's −z), else 9.82 m/s² along the base's −z (a
    /// floor mounting, as UR's controller models it); no payload and no friction.
    pub fn from_arm(arm: &ArmDescription) -> Result<Self, DynamicsError> {
        let joint_count = arm.joint_count();
        if joint_count != N {
            return Err(DynamicsError::JointCount {
                expected: N,
                got: joint_count,
            });
        }
        let inertials = arm
            .inertials
            .as_ref()
            .ok_or_else(|| DynamicsError::NoInertials {
                model: arm.name.clone(),
            })?;
        for (what, got) in [
            ("links", inertials.links.len()),
            (
                "reflected_rotor_inertia_kg_m2",
                inertials.reflected_rotor_inertia_kg_m2.len(),
            ),
        ] {
            if got != N {
                return Err(DynamicsError::ParameterCount {
                    what,
                    expected: N,
                    got,
                });
            }
        }
        let (joints, joint_from_link, last_joint_from_flange) =
            if let Some(origins) = &arm.joint_origins {
                compile_origins::<N>(origins)
            } else {
                let (joints, joint_from_link) = compile_geometry::<N>(arm.convention, &arm.dh);
                // Standard DH: the last link frame is the flange; modified: the tool row's.
                let last = joint_from_link
                    .last()
                    .copied()
                    .unwrap_or((Matrix3::identity(), Vector3::zeros()));
                (joints, joint_from_link, last)
            };
        let mut bodies = [Body::NONE; N];
        let mut reflected_rotor_inertia_kg_m2 = [0.0; N];
        for k in 0..N {
            let link = &inertials.links[k];
            let joint = k + 1;
            checked(|| format!("link {joint} mass_kg"), link.mass_kg, true)?;
            for (axis, value) in link.com_link_m.iter().enumerate() {
                checked(|| format!("link {joint} com_link_m[{axis}]"), *value, false)?;
            }
            for (entry, value) in link.inertia_com_kg_m2.iter().enumerate() {
                checked(
                    || format!("link {joint} inertia_com_kg_m2[{entry}]"),
                    *value,
                    entry < 3,
                )?;
            }
            reflected_rotor_inertia_kg_m2[k] = checked(
                || format!("joint {joint} reflected_rotor_inertia_kg_m2"),
                inertials.reflected_rotor_inertia_kg_m2[k],
                true,
            )?;
            bodies[k] = Body::from_com(
                link.mass_kg,
                link.com_link_m,
                link.inertia_com_kg_m2,
                &joint_from_link[k],
            );
        }
        let last_link = bodies.last().copied().unwrap_or(Body::NONE);
        let gravity_base_m_s2 = inertials.gravity_base_m_s2.map_or(
            Vector3::new(0.0, 0.0, -UR_CONTROLLER_GRAVITY_M_S2),
            Vector3::from,
        );
        Ok(Self {
            joints,
            bodies,
            last_link,
            last_joint_from_flange,
            reflected_rotor_inertia_kg_m2,
            friction: [JointFriction::default(); N],
            gravity_base_m_s2,
            payload: Payload::NONE,
        })
    }

    /// The same arm with gravity `gravity_base_m_s2` (m/s², the acceleration of a falling body in
    /// the base frame: `[0, 0, −9.82]` on a floor, `[0, 0, 9.82]` on a ceiling).
    pub fn with_gravity_base_m_s2(
        mut self,
        gravity_base_m_s2: [f64; 3],
    ) -> Result<Self, DynamicsError> {
        for (axis, value) in gravity_base_m_s2.iter().enumerate() {
            checked(|| format!("gravity_base_m_s2[{axis}]"), *value, false)?;
        }
        self.gravity_base_m_s2 = Vector3::from(gravity_base_m_s2);
        Ok(self)
    }

    /// The same arm carrying `payload` (replacing any earlier one).
    pub fn with_payload(mut self, payload: Payload) -> Result<Self, DynamicsError> {
        checked(|| "payload mass_kg".to_owned(), payload.mass_kg, true)?;
        for (axis, value) in payload.cog_flange_m.iter().enumerate() {
            checked(|| format!("payload cog_flange_m[{axis}]"), *value, false)?;
        }
        for (entry, value) in payload.inertia_cog_kg_m2.iter().enumerate() {
            checked(
                || format!("payload inertia_cog_kg_m2[{entry}]"),
                *value,
                entry < 3,
            )?;
        }
        let payload_body = Body::from_com(
            payload.mass_kg,
            payload.cog_flange_m,
            payload.inertia_cog_kg_m2,
            &self.last_joint_from_flange,
        );
        if let Some(last) = self.bodies.last_mut() {
            *last = self.last_link.plus(&payload_body);
        }
        self.payload = payload;
        Ok(self)
    }

    /// The same arm with its drives' rotor inertias, seen at the joints, `J_rotor · ratio²`
    /// (kg·m²), replacing the description's.
    pub fn with_reflected_rotor_inertia_kg_m2(
        mut self,
        inertia_kg_m2: [f64; N],
    ) -> Result<Self, DynamicsError> {
        for (k, value) in inertia_kg_m2.iter().enumerate() {
            checked(
                || format!("joint {} reflected_rotor_inertia_kg_m2", k + 1),
                *value,
                true,
            )?;
        }
        self.reflected_rotor_inertia_kg_m2 = inertia_kg_m2;
        Ok(self)
    }

    /// The same arm with `friction` per joint.
    pub fn with_friction(mut self, friction: [JointFriction; N]) -> Result<Self, DynamicsError> {
        for (k, joint) in friction.iter().enumerate() {
            checked(
                || format!("joint {} coulomb_nm", k + 1),
                joint.coulomb_nm,
                true,
            )?;
            checked(
                || format!("joint {} viscous_nm_s_rad", k + 1),
                joint.viscous_nm_s_rad,
                true,
            )?;
        }
        self.friction = friction;
        Ok(self)
    }

    /// Gravity in the base frame (m/s²).
    #[must_use]
    pub fn gravity_base_m_s2(&self) -> [f64; 3] {
        self.gravity_base_m_s2.into()
    }

    /// The payload carried.
    #[must_use]
    pub fn payload(&self) -> &Payload {
        &self.payload
    }

    /// Per joint, the reflected rotor inertia (kg·m²).
    #[must_use]
    pub fn reflected_rotor_inertia_kg_m2(&self) -> &[f64; N] {
        &self.reflected_rotor_inertia_kg_m2
    }

    /// Joint torques (N·m) that produce accelerations `qdd_rad_s2` at `q_rad`, `qd_rad_s`: rigid
    /// body, payload, gravity, reflected rotor inertia and friction.
    #[must_use]
    pub fn inverse_dynamics_nm(
        &self,
        q_rad: &[f64; N],
        qd_rad_s: &[f64; N],
        qdd_rad_s2: &[f64; N],
    ) -> [f64; N] {
        let rotations = self.joint_rotations(q_rad);
        let mut tau_nm = self.rnea(&rotations, qd_rad_s, qdd_rad_s2, -self.gravity_base_m_s2);
        for k in 0..N {
            tau_nm[k] += self.reflected_rotor_inertia_kg_m2[k] * qdd_rad_s2[k]
                + self.friction[k].torque_nm(qd_rad_s[k]);
        }
        tau_nm
    }

    /// The torques a Universal Robots controller reports as `target_moment` in `mode`, for the
    /// target state: rigid body and rotor inertia in a program, gravity alone in freedrive;
    /// friction never (the controller models it in its currents only).
    #[must_use]
    pub fn controller_moment_nm(
        &self,
        mode: ControllerMode,
        q_rad: &[f64; N],
        qd_rad_s: &[f64; N],
        qdd_rad_s2: &[f64; N],
    ) -> [f64; N] {
        let rotations = self.joint_rotations(q_rad);
        match mode {
            ControllerMode::Program => {
                let mut tau_nm =
                    self.rnea(&rotations, qd_rad_s, qdd_rad_s2, -self.gravity_base_m_s2);
                for k in 0..N {
                    tau_nm[k] += self.reflected_rotor_inertia_kg_m2[k] * qdd_rad_s2[k];
                }
                tau_nm
            }
            ControllerMode::Freedrive => {
                self.rnea(&rotations, &[0.0; N], &[0.0; N], -self.gravity_base_m_s2)
            }
        }
    }

    /// Per joint, the gravity torques (N·m) of a payload at rest per unit of its parameters
    /// `[m, m·cx, m·cy, m·cz]` (kg, kg·m; `c` its centre of gravity in the flange frame): the
    /// payload's gravity torques are this row times those parameters, whatever the arm carries.
    #[must_use]
    pub fn payload_gravity_regressor(&self, q_rad: &[f64; N]) -> [[f64; 4]; N] {
        let rotations = self.joint_rotations(q_rad);
        // At rest every link frame accelerates at −g; in the last joint's frame:
        let mut acceleration = -self.gravity_base_m_s2;
        for rotation in &rotations {
            acceleration = rotation.in_child(&acceleration);
        }
        let (flange_rotation, flange_origin) = &self.last_joint_from_flange;
        // Wrenches (force, moment about the last joint's origin) per unit parameter: a unit mass
        // at the flange origin, then a unit first moment along each flange axis.
        let mut wrenches = [(Vector3::zeros(), Vector3::zeros()); 4];
        wrenches[0] = (acceleration, flange_origin.cross(&acceleration));
        for axis in 0..3 {
            wrenches[axis + 1].1 = flange_rotation.column(axis).cross(&acceleration);
        }
        let mut regressor = [[0.0; 4]; N];
        for (column, (mut force, mut moment)) in wrenches.into_iter().enumerate() {
            for k in (0..N).rev() {
                regressor[k][column] = moment.z;
                let rotation = &rotations[k];
                force = rotation.in_parent(&force);
                moment = rotation.in_parent(&moment) + self.joints[k].origin_m.cross(&force);
            }
        }
        regressor
    }

    /// Gravity torques `g(q)` (N·m): what holds the arm still at `q_rad`.
    #[must_use]
    pub fn gravity_nm(&self, q_rad: &[f64; N]) -> [f64; N] {
        let rotations = self.joint_rotations(q_rad);
        self.rnea(&rotations, &[0.0; N], &[0.0; N], -self.gravity_base_m_s2)
    }

    /// Coriolis and centrifugal torques `C(q, q̇) q̇` (N·m).
    #[must_use]
    pub fn coriolis_nm(&self, q_rad: &[f64; N], qd_rad_s: &[f64; N]) -> [f64; N] {
        let rotations = self.joint_rotations(q_rad);
        self.rnea(&rotations, qd_rad_s, &[0.0; N], Vector3::zeros())
    }

    /// Friction torques `τ_f(q̇)` (N·m).
    #[must_use]
    pub fn friction_nm(&self, qd_rad_s: &[f64; N]) -> [f64; N] {
        std::array::from_fn(|k| self.friction[k].torque_nm(qd_rad_s[k]))
    }

    /// The joint-space mass matrix `M(q)` (kg·m² for revolute joints), reflected rotor inertia on
    /// its diagonal: column j is the torque for a unit acceleration of joint j alone, at rest,
    /// without gravity (n recursions sharing one set of joint rotations).
    #[must_use]
    pub fn mass_matrix_kg_m2(&self, q_rad: &[f64; N]) -> SMatrix<f64, N, N> {
        let rotations = self.joint_rotations(q_rad);
        let mut mass = SMatrix::<f64, N, N>::zeros();
        for j in 0..N {
            let mut unit = [0.0; N];
            unit[j] = 1.0;
            let column = self.rnea(&rotations, &[0.0; N], &unit, Vector3::zeros());
            for (i, value) in column.iter().enumerate() {
                mass[(i, j)] = *value;
            }
            mass[(j, j)] += self.reflected_rotor_inertia_kg_m2[j];
        }
        mass
    }

    /// The generalized momentum `p = M(q) q̇` and `C(q, q̇)ᵀ q̇` in one outward and one inward pass.
    ///
    /// Why this form: with `hⱼ` the spatial momentum of the links from j outward, taken at joint
    /// j, `pⱼ = Sⱼ · hⱼ` (`Sⱼ` the joint's unit twist); differentiating at `q̈ = 0` gives
    /// `(Ṁ q̇)ⱼ = (vₚ × Sⱼ) · hⱼ + (C q̇)ⱼ`, `vₚ` the twist of joint j's parent, so
    /// `(Cᵀ q̇)ⱼ = (Ṁ q̇ − C q̇)ⱼ = (vₚ × Sⱼ) · hⱼ` with no derivative taken numerically.
    #[must_use]
    pub fn momentum(&self, q_rad: &[f64; N], qd_rad_s: &[f64; N]) -> MomentumTerms<N> {
        let rotations = self.joint_rotations(q_rad);
        let mut omega = Vector3::zeros();
        let mut velocity = Vector3::zeros();
        // Per joint, in its frame: the parent's angular velocity, the origin's velocity, and the
        // link's own momentum (linear; angular about the origin).
        let mut parent_omega = [Vector3::zeros(); N];
        let mut origin_velocity = [Vector3::zeros(); N];
        let mut linear = [Vector3::zeros(); N];
        let mut angular = [Vector3::zeros(); N];
        for k in 0..N {
            let r = &rotations[k];
            let origin = &self.joints[k].origin_m;
            let v = r.in_child(&(velocity + omega.cross(origin)));
            let w_parent = r.in_child(&omega);
            let w = w_parent + Vector3::z() * qd_rad_s[k];
            let body = &self.bodies[k];
            linear[k] = v * body.mass_kg + w.cross(&body.first_moment_kg_m);
            angular[k] = body.inertia_origin_kg_m2 * w + body.first_moment_kg_m.cross(&v);
            parent_omega[k] = w_parent;
            origin_velocity[k] = v;
            omega = w;
            velocity = v;
        }
        let mut momentum_nms = [0.0; N];
        let mut coriolis_transpose_qd_nm = [0.0; N];
        let mut subtree_linear = Vector3::zeros();
        let mut subtree_angular = Vector3::zeros();
        for k in (0..N).rev() {
            if k + 1 < N {
                let r = &rotations[k + 1];
                let carried = r.in_parent(&subtree_linear);
                subtree_angular = angular[k]
                    + r.in_parent(&subtree_angular)
                    + self.joints[k + 1].origin_m.cross(&carried);
                subtree_linear = linear[k] + carried;
            } else {
                subtree_linear = linear[k];
                subtree_angular = angular[k];
            }
            momentum_nms[k] =
                subtree_angular.z + self.reflected_rotor_inertia_kg_m2[k] * qd_rad_s[k];
            // vₚ × S with S = (z, 0): angular part ωₚ × z, linear part v × z.
            let z = Vector3::z();
            coriolis_transpose_qd_nm[k] = parent_omega[k].cross(&z).dot(&subtree_angular)
                + origin_velocity[k].cross(&z).dot(&subtree_linear);
        }
        MomentumTerms {
            momentum_nms,
            coriolis_transpose_qd_nm,
        }
    }

    /// Per joint, the rotation from joint frame i−1 (or the base) to joint frame i,
    /// `Rx(α) · Rz(qᵢ + θᵢ)`.
    #[inline]
    fn joint_rotations(&self, q_rad: &[f64; N]) -> [JointRotation<'_>; N] {
        let angles: [f64; N] = std::array::from_fn(|k| q_rad[k] + self.joints[k].theta_offset_rad);
        let (sin, cos) = sin_cos(&angles);
        std::array::from_fn(|k| JointRotation {
            twist: &self.joints[k].twist,
            cos_q: cos[k],
            sin_q: sin[k],
        })
    }

    /// Recursive Newton–Euler without rotor inertia or friction, in joint frames. The base
    /// accelerates at `base_acceleration_m_s2` (−gravity puts gravity on every link at no cost).
    #[inline]
    fn rnea(
        &self,
        rotations: &[JointRotation<'_>; N],
        qd_rad_s: &[f64; N],
        qdd_rad_s2: &[f64; N],
        base_acceleration_m_s2: Vector3<f64>,
    ) -> [f64; N] {
        let mut omega = Vector3::zeros();
        let mut omega_dot = Vector3::zeros();
        let mut acceleration = base_acceleration_m_s2;
        // Per link, the force and the moment about its joint's origin it needs, in its frame.
        let mut force = [Vector3::zeros(); N];
        let mut moment = [Vector3::zeros(); N];
        for k in 0..N {
            let r = &rotations[k];
            let origin = &self.joints[k].origin_m;
            let a = r.in_child(
                &(acceleration + omega_dot.cross(origin) + omega.cross(&omega.cross(origin))),
            );
            let w_parent = r.in_child(&omega);
            let w = Vector3::new(w_parent.x, w_parent.y, w_parent.z + qd_rad_s[k]);
            // ω̇ = Rᵀω̇ₚ + (Rᵀωₚ) × z q̇ + z q̈, with (x, y, z) × ẑ = (y, −x, 0).
            let wd_parent = r.in_child(&omega_dot);
            let wd = Vector3::new(
                wd_parent.x + w_parent.y * qd_rad_s[k],
                wd_parent.y - w_parent.x * qd_rad_s[k],
                wd_parent.z + qdd_rad_s2[k],
            );
            let body = &self.bodies[k];
            let h = &body.first_moment_kg_m;
            force[k] = a * body.mass_kg + wd.cross(h) + w.cross(&w.cross(h));
            let inertia = &body.inertia_origin_kg_m2;
            moment[k] = inertia * wd + w.cross(&(inertia * w)) + h.cross(&a);
            omega = w;
            omega_dot = wd;
            acceleration = a;
        }
        let mut tau_nm = [0.0; N];
        let mut f = Vector3::zeros();
        let mut n = Vector3::zeros();
        for k in (0..N).rev() {
            if k + 1 < N {
                let r = &rotations[k + 1];
                let carried = r.in_parent(&f);
                n = moment[k] + r.in_parent(&n) + self.joints[k + 1].origin_m.cross(&carried);
                f = force[k] + carried;
            } else {
                f = force[k];
                n = moment[k];
            }
            tau_nm[k] = n.z;
        }
        tau_nm
    }
}

/// `(sin, cos)` of each angle: batched for six joints, the platform's otherwise.
#[inline]
fn sin_cos<const N: usize>(angles_rad: &[f64; N]) -> ([f64; N], [f64; N]) {
    let mut sin = [0.0; N];
    let mut cos = [0.0; N];
    if let Ok(six) = <&[f64; trig::BATCH]>::try_from(angles_rad.as_slice()) {
        let (s, c) = trig::sin_cos_batch(six);
        sin.copy_from_slice(&s);
        cos.copy_from_slice(&c);
    } else {
        for k in 0..N {
            (sin[k], cos[k]) = angles_rad[k].sin_cos();
        }
    }
    (sin, cos)
}

/// The arm compiled to joint frames: per joint its [`JointGeometry`], and `joint_from_link` for
/// each link frame of `convention` (standard: `Tz(d) · Tx(a) · Rx(α)` of its own row, so the last
/// is the flange; modified: `Tz(d)`).
fn compile_geometry<const N: usize>(
    convention: DhConvention,
    rows: &[DhParameters],
) -> ([JointGeometry; N], [RigidTransform; N]) {
    let joint_from_link: [RigidTransform; N] = std::array::from_fn(|k| {
        let row = &rows[k];
        match convention {
            DhConvention::Standard => tz_tx_rx(row.d_m, row.a_m, row.alpha_rad),
            DhConvention::Modified => tz_tx_rx(row.d_m, 0.0, 0.0),
        }
    });
    let joints = std::array::from_fn(|k| {
        let row = &rows[k];
        // Standard: Fₖ₋₁ = row k−1's `Tz(d) · Tx(a) · Rx(α)`, nothing before joint 1.
        // Modified: Fₖ₋₁ = row k−1's `Tz(d)`, then row k's `Rx(α) · Tx(a)`.
        let (d_m, a_m, alpha_rad) = match convention {
            DhConvention::Standard => match k.checked_sub(1).map(|p| &rows[p]) {
                Some(previous) => (previous.d_m, previous.a_m, previous.alpha_rad),
                None => (0.0, 0.0, 0.0),
            },
            DhConvention::Modified => (
                k.checked_sub(1).map_or(0.0, |p| rows[p].d_m),
                row.a_m,
                row.alpha_rad,
            ),
        };
        JointGeometry {
            twist: Twist::from_alpha(alpha_rad),
            origin_m: Vector3::new(a_m, 0.0, d_m),
            theta_offset_rad: row.theta_offset_rad,
        }
    });
    (joints, joint_from_link)
}

/// An arm given by its joint origins compiled to joint frames: they are its joint frames already,
/// and its links' parameters are in them; the flange is the chain's tip.
fn compile_origins<const N: usize>(
    origins: &JointOrigins,
) -> ([JointGeometry; N], [RigidTransform; N], RigidTransform) {
    let joints = std::array::from_fn(|k| {
        let parent_from_joint = &origins.parent_from_joint[k];
        JointGeometry {
            twist: Twist::from_rotation(parent_from_joint.rotation.matrix()),
            origin_m: parent_from_joint.translation.vector,
            theta_offset_rad: 0.0,
        }
    });
    let flange = &origins.last_from_flange;
    (
        joints,
        [(Matrix3::identity(), Vector3::zeros()); N],
        (*flange.rotation.matrix(), flange.translation.vector),
    )
}

#[cfg(test)]
mod tests;
