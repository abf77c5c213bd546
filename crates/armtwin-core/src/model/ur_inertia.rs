//! Published inertial parameters of the Universal Robots catalog arms: link masses, centres of
//! mass and inertia tensors in the standard-DH link frames, and the reflected rotor inertia of
//! each joint's drive.
//!
//! Owns these tables only; the recursion that uses them is in [`crate::dynamics`] (which names
//! this module `dynamics::ur`). Values are copied digit for digit from the sources named on each
//! table; nothing here is fitted or estimated.
//!
//! Sources (checked against each other):
//! - **P**: Universal Robots, "DH Parameters for calculations of kinematics and dynamics"
//!   (universal-robots.com article).
//! - **C**: the link and joint sections of e-Series controller configuration files
//!   (`urcontrol.conf.UR5` etc., `joint_size*_G5_rev1.conf`).
//! - **R**: `UniversalRobots/Universal_Robots_ROS2_Description`,
//!   `config/<model>/physical_parameters.yaml` (URDF link frames mapped back to DH frames).
//!
//! Every centre of mass and tensor is in the standard-DH frame of its link, the frame at the
//! link's distal joint (frame 6 is the flange), as the catalog's kinematics use them. Tensors are
//! about the centre of mass; where a source publishes none the tensor is zero (a point mass), as
//! in the controller's own model of the small arms.

use super::inertia::{ArmInertials, LinkInertial};

/// Gear ratio of every e-Series joint (C).
pub const E_SERIES_GEAR_RATIO: f64 = 101.0;

/// Rotor inertia (kg·m², motor side) of e-Series joint sizes 0 to 4 (C,
/// `joint_size*_G5_rev1.conf`).
pub const E_SERIES_ROTOR_INERTIA_KG_M2: [f64; 5] =
    [7.0e-6, 2.0767e-5, 6.0e-5, 1.8774e-4, 5.90109e-4];

/// Nominal torque constant (N·m/A, motor side) of e-Series joint sizes 0 to 4 (C). Each robot's
/// own constants are measured at the factory and differ by about 1 %.
pub const E_SERIES_TORQUE_CONSTANT_NM_PER_A: [f64; 5] =
    [0.035685, 0.07695, 0.10756, 0.098322, 0.11968];

/// Largest joint torque (N·m) of e-Series joint sizes 0 to 4 (C).
pub const E_SERIES_MAX_TORQUE_NM: [f64; 5] = [9.0, 28.0, 54.0, 150.0, 330.0];

/// Share of a joint's largest torque that a collision must reach unless configured otherwise:
/// above the model errors that are left once friction is learned (payload mismatches of a kilo
/// or two, the ~1 % spread of torque constants), below the force of a real impact.
pub const DEFAULT_COLLISION_SHARE: f64 = 0.1;

/// Per joint, the default collision threshold (N·m) of an e-Series arm whose joint sizes are
/// public ([`DEFAULT_COLLISION_SHARE`] of each joint's largest torque); `None` otherwise.
#[must_use]
pub fn default_collision_threshold_nm(name: &str) -> Option<[f64; 6]> {
    let sizes = table(name)?.joint_sizes?;
    Some(sizes.map(|size| E_SERIES_MAX_TORQUE_NM[size] * DEFAULT_COLLISION_SHARE))
}

/// Per joint, the nominal factor from motor current to joint torque, `K_τ · 101` (N·m/A), of an
/// e-Series arm whose joint sizes are public (UR3e, UR5e, UR10e, UR16e); `None` otherwise. Joint
/// torque ≈ current × this factor, friction and rotor inertia included in that torque.
#[must_use]
pub fn current_to_torque_nm_per_a(name: &str) -> Option<[f64; 6]> {
    let sizes = table(name)?.joint_sizes?;
    Some(sizes.map(|size| E_SERIES_TORQUE_CONSTANT_NM_PER_A[size] * E_SERIES_GEAR_RATIO))
}

/// One arm's table: per link mass (kg), centre of mass (m) and diagonal inertia about it
/// (`[Ixx, Iyy, Izz]`, kg·m²), and the e-Series joint sizes where they are public.
struct UrTable {
    mass_kg: [f64; 6],
    com_link_m: [[f64; 3]; 6],
    inertia_diagonal_kg_m2: [[f64; 3]; 6],
    joint_sizes: Option<[usize; 6]>,
}

const NO_INERTIA: [[f64; 3]; 6] = [[0.0; 3]; 6];

/// UR3 and UR3e centres of mass (P, R; C for the UR3e).
const UR3_COM_M: [[f64; 3]; 6] = [
    [0.0, -0.02, 0.0],
    [0.13, 0.0, 0.1157],
    [0.05, 0.0, 0.0238],
    [0.0, 0.0, 0.01],
    [0.0, 0.0, 0.01],
    [0.0, 0.0, -0.02],
];

/// UR5 and UR5e centres of mass (P, R; C for the UR5e).
const UR5_COM_M: [[f64; 3]; 6] = [
    [0.0, -0.02561, 0.00193],
    [0.2125, 0.0, 0.11336],
    [0.15, 0.0, 0.0265],
    [0.0, -0.0018, 0.01634],
    [0.0, 0.0018, 0.01634],
    [0.0, 0.0, -0.001159],
];

/// UR10 and UR10e centres of mass (P, R; C for the UR10e).
const UR10_COM_M: [[f64; 3]; 6] = [
    [0.021, 0.0, 0.027],
    [0.38, 0.0, 0.158],
    [0.24, 0.0, 0.068],
    [0.0, 0.007, 0.018],
    [0.0, 0.007, 0.018],
    [0.0, 0.0, -0.026],
];

/// UR3 (CB3), P and R: masses only; no tensors or joint sizes are published.
const UR3: UrTable = UrTable {
    mass_kg: [2.0, 3.42, 1.26, 0.8, 0.8, 0.35],
    com_link_m: UR3_COM_M,
    inertia_diagonal_kg_m2: NO_INERTIA,
    joint_sizes: None,
};

/// UR5 (CB3), P and R.
const UR5: UrTable = UrTable {
    mass_kg: [3.7, 8.393, 2.33, 1.219, 1.219, 0.1879],
    com_link_m: UR5_COM_M,
    inertia_diagonal_kg_m2: NO_INERTIA,
    joint_sizes: None,
};

/// UR10 (CB3), P and R.
const UR10: UrTable = UrTable {
    mass_kg: [7.1, 12.7, 4.27, 2.0, 2.0, 0.365],
    com_link_m: UR10_COM_M,
    inertia_diagonal_kg_m2: NO_INERTIA,
    joint_sizes: None,
};

/// UR3e, C = P = R. The controller's tensors are zero except wrist 3's Izz (C; P calls them
/// negligible below the UR10e).
const UR3E: UrTable = UrTable {
    mass_kg: [1.98, 3.4445, 1.437, 0.871, 0.805, 0.261],
    com_link_m: UR3_COM_M,
    inertia_diagonal_kg_m2: [
        [0.0; 3],
        [0.0; 3],
        [0.0; 3],
        [0.0; 3],
        [0.0; 3],
        [0.0, 0.0, 0.000144],
    ],
    joint_sizes: Some([2, 2, 1, 0, 0, 0]),
};

/// UR5e, C = P = R; tensors as the UR3e's (C). R's cylinder approximations are not used: they are
/// not the controller's model.
const UR5E: UrTable = UrTable {
    mass_kg: [3.761, 8.058, 2.846, 1.37, 1.30, 0.365],
    com_link_m: UR5_COM_M,
    inertia_diagonal_kg_m2: [
        [0.0; 3],
        [0.0; 3],
        [0.0; 3],
        [0.0; 3],
        [0.0; 3],
        [0.0, 0.0, 0.0002],
    ],
    joint_sizes: Some([3, 3, 3, 1, 1, 1]),
};

/// UR10e, C = P = R (tensors C = R).
const UR10E: UrTable = UrTable {
    mass_kg: [7.369, 13.051, 3.989, 2.10, 1.98, 0.615],
    com_link_m: UR10_COM_M,
    inertia_diagonal_kg_m2: [
        [0.03408, 0.03529, 0.02156],
        [0.02814, 0.77068, 0.76943],
        [0.01014, 0.30928, 0.30646],
        [0.00296, 0.00222, 0.00258],
        [0.00296, 0.00222, 0.00258],
        [0.00040, 0.00041, 0.00034],
    ],
    joint_sizes: Some([4, 4, 3, 2, 2, 2]),
};

/// UR16e, C = R.
const UR16E: UrTable = UrTable {
    mass_kg: [7.369, 10.45, 4.321, 2.18, 2.033, 0.907],
    com_link_m: [
        [0.0, -0.016, 0.030],
        [0.302, 0.0, 0.160],
        [0.194, 0.0, 0.065],
        [0.0, -0.009, 0.011],
        [0.0, 0.018, 0.012],
        [0.0, 0.0, -0.044],
    ],
    inertia_diagonal_kg_m2: [
        [0.03351, 0.03374, 0.02100],
        [0.02796, 0.47558, 0.47635],
        [0.01091, 0.12060, 0.11714],
        [0.00609, 0.00245, 0.00579],
        [0.00389, 0.00219, 0.00363],
        [0.00117, 0.00118, 0.00084],
    ],
    joint_sizes: Some([4, 4, 3, 2, 2, 2]),
};

/// UR20, P (R agrees except wrist 3, where R has 0.926 kg at `[0, 0, −0.0293]`; P is UR's own
/// article). Joint sizes are not public.
const UR20: UrTable = UrTable {
    mass_kg: [16.343, 29.632, 7.879, 3.054, 3.126, 0.846],
    com_link_m: [
        [0.0, -0.061, 0.0062],
        [0.5226, 0.0, 0.2098],
        [0.3234, 0.0, 0.0604],
        [0.0, -0.0026, 0.0393],
        [0.0, 0.0024, 0.0379],
        [0.0, -0.0003, -0.0318],
    ],
    inertia_diagonal_kg_m2: [
        [0.0887, 0.0763, 0.0842],
        [0.1467, 4.6659, 4.6348],
        [0.0261, 0.7576, 0.7533],
        [0.0056, 0.0054, 0.0040],
        [0.0059, 0.0058, 0.0043],
        [0.0009, 0.0009, 0.0012],
    ],
    joint_sizes: None,
};

/// UR30, R only. Its tensors are R's, which are an exact copy of the UR16e's and so suspect
/// (an upper arm of 28.5 kg with the UR16e's 10.45 kg tensor); no other source publishes any.
const UR30: UrTable = UrTable {
    mass_kg: [16.343, 28.542, 7.156, 3.054, 3.126, 0.926],
    com_link_m: [
        [-0.0001, -0.060, 0.0069],
        [0.3894, 0.0, 0.2103],
        [0.2257, 0.0, 0.0629],
        [0.0, -0.0048, 0.0353],
        [0.0, 0.0046, 0.0341],
        [0.0, 0.0, -0.0293],
    ],
    inertia_diagonal_kg_m2: UR16E.inertia_diagonal_kg_m2,
    joint_sizes: None,
};

/// The table of catalog arm `name` (case-insensitive).
fn table(name: &str) -> Option<UrTable> {
    Some(match name.to_ascii_lowercase().as_str() {
        "ur3" => UR3,
        "ur5" => UR5,
        "ur10" => UR10,
        "ur3e" => UR3E,
        "ur5e" => UR5E,
        "ur10e" => UR10E,
        "ur16e" => UR16E,
        "ur20" => UR20,
        "ur30" => UR30,
        _ => return None,
    })
}

/// The inertial parameters of catalog arm `name` (case-insensitive), `None` for a name the
/// catalog does not hold.
#[must_use]
pub fn inertials(name: &str) -> Option<ArmInertials> {
    let table = table(name)?;
    let links = (0..6)
        .map(|k| {
            let [ixx, iyy, izz] = table.inertia_diagonal_kg_m2[k];
            LinkInertial {
                mass_kg: table.mass_kg[k],
                com_link_m: table.com_link_m[k],
                inertia_com_kg_m2: [ixx, iyy, izz, 0.0, 0.0, 0.0],
            }
        })
        .collect();
    let reflected_rotor_inertia_kg_m2 = table.joint_sizes.map_or_else(
        || vec![0.0; 6],
        |sizes| {
            sizes
                .iter()
                .map(|&size| {
                    E_SERIES_ROTOR_INERTIA_KG_M2[size] * E_SERIES_GEAR_RATIO * E_SERIES_GEAR_RATIO
                })
                .collect()
        },
    );
    Some(ArmInertials {
        links,
        reflected_rotor_inertia_kg_m2,
        max_torque_nm: None,
        gravity_base_m_s2: None,
    })
}
