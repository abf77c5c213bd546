//! Properties of the recursions that hold for any correct implementation: checked against the
//! kinematics (potential energy), against each other (momentum, mass matrix, passivity), and
//! against exact invariants. Pinocchio checks the numbers themselves (tests/python).

#![allow(
    clippy::float_cmp,
    reason = "zero torques and unchanged results are exact invariants, not approximations"
)]

use std::fmt::Write as _;

use nalgebra::{SMatrix, SVector, Vector3};

use super::*;
use crate::kinematics::Chain;
use crate::model::catalog;
use crate::model::urdf::{UrdfDynamics, UrdfRobot};

/// A small deterministic generator (xorshift64*), so failures reproduce.
struct Rng(u64);

impl Rng {
    fn uniform(&mut self, low: f64, high: f64) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let bits = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11;
        low + (high - low) * (bits as f64 / (1_u64 << 53) as f64)
    }

    fn joints(&mut self, limit: f64) -> [f64; 6] {
        std::array::from_fn(|_| self.uniform(-limit, limit))
    }
}

/// Every catalog arm's dynamics, and three six-joint URDF chains' (joint frames turned by any
/// rotation; the Z1's flange turned off its last joint's axes), for the properties every arm's
/// dynamics must have.
fn catalog_dynamics() -> Vec<(&'static str, ArmDynamics)> {
    let urdf = |text: &str, tip: &str| {
        let robot = UrdfRobot::parse(text).unwrap();
        let chain = robot.chain(None, Some(tip)).unwrap();
        ArmDynamics::from_arm(&chain.arm_description(&robot).unwrap()).unwrap()
    };
    catalog::UNIVERSAL_ROBOTS
        .iter()
        .map(|entry| {
            let arm = entry.arm();
            (entry.name, ArmDynamics::from_arm(&arm).unwrap())
        })
        .chain([
            (
                "z1.urdf",
                urdf(
                    include_str!("../../../../tests/data/urdf/z1.urdf"),
                    "link06",
                ),
            ),
            (
                "ur5_robot.urdf",
                urdf(
                    include_str!("../../../../tests/data/urdf/ur5_robot.urdf"),
                    "tool0",
                ),
            ),
            (
                "kinova.urdf",
                urdf(
                    include_str!("../../../../tests/data/urdf/kinova.urdf"),
                    "j2s6s200_end_effector",
                ),
            ),
        ])
        .collect()
}

fn some_payload() -> Payload {
    Payload {
        mass_kg: 2.7,
        cog_flange_m: [0.01, -0.02, 0.08],
        inertia_cog_kg_m2: [0.004, 0.005, 0.003, 0.0002, -0.0001, 0.0003],
    }
}

fn max_abs(values: impl IntoIterator<Item = f64>) -> f64 {
    values.into_iter().fold(0.0, |worst, v| worst.max(v.abs()))
}

#[test]
fn every_catalog_arm_has_six_links_and_rotor_inertia_only_where_sizes_are_public() {
    for (name, dynamics) in catalog_dynamics() {
        let with_rotor = dynamics
            .reflected_rotor_inertia_kg_m2()
            .iter()
            .all(|&j| j > 0.0);
        let expected = matches!(name, "ur3e" | "ur5e" | "ur10e" | "ur16e");
        assert_eq!(with_rotor, expected, "{name}");
    }
    // Size 4 (UR10e shoulder): 5.90109e-4 kg·m² × 101² = 6.020 kg·m² (research table).
    let ur10e = ArmDynamics::<6>::from_arm(&catalog::arm("ur10e").unwrap()).unwrap();
    assert!((ur10e.reflected_rotor_inertia_kg_m2()[0] - 6.020).abs() < 5e-4);
}

#[test]
fn gravity_torques_are_the_gradient_of_potential_energy_from_the_kinematics() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    // Against the DH kinematics: the catalog's arms.
    for (name, dynamics) in catalog_dynamics()
        .into_iter()
        .filter(|(name, _)| catalog::arm(name).is_ok())
    {
        let arm = catalog::arm(name).unwrap();
        let inertials = arm.inertials.clone().unwrap();
        let chain = Chain::from_dh(arm.convention, &arm.dh);
        let payload = some_payload();
        let dynamics = dynamics
            .with_payload(payload)
            .unwrap()
            .with_gravity_base_m_s2([0.4, -1.1, -9.7])
            .unwrap();
        let gravity = Vector3::from(dynamics.gravity_base_m_s2());
        // U(q) = −Σ mᵢ g·cᵢ(q), each centre placed by the kinematics' own link frames.
        let potential_j = |q: &[f64; 6]| {
            let frames = chain.link_frames(q).unwrap();
            let mut energy = 0.0;
            for (k, link) in inertials.links.iter().enumerate() {
                let frame = &frames[k + 1];
                let com = frame.rotation * Vector3::from(link.com_link_m) + frame.position_m;
                energy -= link.mass_kg * gravity.dot(&com);
            }
            let flange = &frames[6];
            let cog = flange.rotation * Vector3::from(payload.cog_flange_m) + flange.position_m;
            energy - payload.mass_kg * gravity.dot(&cog)
        };
        for _ in 0..20 {
            let q = rng.joints(6.2);
            let tau = dynamics.gravity_nm(&q);
            let step = 1e-6;
            for j in 0..6 {
                let (mut up, mut down) = (q, q);
                up[j] += step;
                down[j] -= step;
                let gradient = (potential_j(&up) - potential_j(&down)) / (2.0 * step);
                assert!(
                    (tau[j] - gradient).abs() < 1e-6 * (1.0 + gradient.abs()),
                    "{name} joint {}: {} vs {gradient}",
                    j + 1,
                    tau[j]
                );
            }
        }
    }
}

#[test]
fn mass_matrix_is_symmetric_positive_definite_and_gives_the_acceleration_torques() {
    let mut rng = Rng(7);
    for (name, dynamics) in catalog_dynamics() {
        let dynamics = dynamics.with_payload(some_payload()).unwrap();
        for _ in 0..50 {
            let (q, qd, qdd) = (rng.joints(6.2), rng.joints(3.0), rng.joints(10.0));
            let mass = dynamics.mass_matrix_kg_m2(&q);
            let asymmetry = max_abs((mass - mass.transpose()).iter().copied());
            assert!(asymmetry < 1e-12, "{name}: asymmetry {asymmetry}");
            let eigenvalues = mass.symmetric_eigen().eigenvalues;
            assert!(eigenvalues.min() > 0.0, "{name}: {eigenvalues}");
            // τ(q, q̇, q̈) = M q̈ + C q̇ + g, each piece from a different call.
            let tau = SVector::from(dynamics.inverse_dynamics_nm(&q, &qd, &qdd));
            let parts = mass * SVector::from(qdd)
                + SVector::from(dynamics.coriolis_nm(&q, &qd))
                + SVector::from(dynamics.gravity_nm(&q));
            assert!(max_abs((tau - parts).iter().copied()) < 1e-10, "{name}");
        }
    }
}

/// `Ṁ(q, q̇)` by central differences along `q̇`.
fn mass_matrix_rate(dynamics: &ArmDynamics, q: &[f64; 6], qd: &[f64; 6]) -> SMatrix<f64, 6, 6> {
    let step = 1e-6;
    let up: [f64; 6] = std::array::from_fn(|k| q[k] + step * qd[k]);
    let down: [f64; 6] = std::array::from_fn(|k| q[k] - step * qd[k]);
    (dynamics.mass_matrix_kg_m2(&up) - dynamics.mass_matrix_kg_m2(&down)) / (2.0 * step)
}

#[test]
fn coriolis_torques_are_passive_and_momentum_terms_match_the_mass_matrix() {
    let mut rng = Rng(0xdead_beef);
    for (name, dynamics) in catalog_dynamics() {
        let dynamics = dynamics.with_payload(some_payload()).unwrap();
        for _ in 0..30 {
            let (q, qd) = (rng.joints(6.2), rng.joints(3.0));
            let qd_vector = SVector::from(qd);
            let mass_rate = mass_matrix_rate(&dynamics, &q, &qd);
            let coriolis = SVector::from(dynamics.coriolis_nm(&q, &qd));
            // q̇ᵀ (Ṁ − 2C) q̇ = 0: the Coriolis torques do no work.
            let work = qd_vector.dot(&(mass_rate * qd_vector)) - 2.0 * qd_vector.dot(&coriolis);
            let scale = qd_vector.dot(&(mass_rate * qd_vector)).abs() + 1.0;
            assert!(work.abs() < 1e-6 * scale, "{name}: {work} (scale {scale})");

            let terms = dynamics.momentum(&q, &qd);
            let momentum = dynamics.mass_matrix_kg_m2(&q) * qd_vector;
            assert!(
                max_abs(
                    (SVector::from(terms.momentum_nms) - momentum)
                        .iter()
                        .copied()
                ) < 1e-11,
                "{name}: momentum"
            );
            // Cᵀ q̇ = Ṁ q̇ − C q̇.
            let expected = mass_rate * qd_vector - coriolis;
            let got = SVector::from(terms.coriolis_transpose_qd_nm);
            let error = max_abs((got - expected).iter().copied());
            assert!(
                error < 1e-6 * (1.0 + max_abs(expected.iter().copied())),
                "{name}: Cᵀq̇ {got} vs {expected}"
            );
        }
    }
}

#[test]
fn an_arm_at_rest_without_gravity_needs_no_torque_and_a_massless_payload_changes_nothing() {
    let mut rng = Rng(42);
    for (name, dynamics) in catalog_dynamics() {
        let weightless = dynamics
            .clone()
            .with_payload(some_payload())
            .unwrap()
            .with_gravity_base_m_s2([0.0; 3])
            .unwrap();
        let q = rng.joints(6.2);
        assert_eq!(
            weightless.inverse_dynamics_nm(&q, &[0.0; 6], &[0.0; 6]),
            [0.0; 6],
            "{name}"
        );
        let massless = Payload {
            mass_kg: 0.0,
            cog_flange_m: [0.3, -0.2, 0.5],
            inertia_cog_kg_m2: [0.0; 6],
        };
        let with_massless = dynamics.clone().with_payload(massless).unwrap();
        let (qd, qdd) = (rng.joints(3.0), rng.joints(10.0));
        assert_eq!(
            with_massless.inverse_dynamics_nm(&q, &qd, &qdd),
            dynamics.inverse_dynamics_nm(&q, &qd, &qdd),
            "{name}"
        );
        // A payload's torques scale with its mass at rest (the controller's point mass).
        let g1 = dynamics
            .clone()
            .with_payload(Payload::point_mass(1.0, [0.0, 0.0, 0.1]))
            .unwrap()
            .gravity_nm(&q);
        let g2 = dynamics
            .clone()
            .with_payload(Payload::point_mass(2.0, [0.0, 0.0, 0.1]))
            .unwrap()
            .gravity_nm(&q);
        let g0 = dynamics.gravity_nm(&q);
        for k in 0..6 {
            assert!(
                ((g2[k] - g0[k]) - 2.0 * (g1[k] - g0[k])).abs() < 1e-10,
                "{name}"
            );
        }
    }
}

#[test]
fn rotor_inertia_and_friction_add_to_the_rigid_body_torques() {
    let friction = [JointFriction {
        coulomb_nm: 3.0,
        viscous_nm_s_rad: 0.5,
    }; 6];
    let plain = ArmDynamics::<6>::from_arm(&catalog::arm("ur5e").unwrap()).unwrap();
    let rubbing = plain.clone().with_friction(friction).unwrap();
    let q = [0.1, -1.0, 1.2, -0.3, 1.4, 0.6];
    let qd = [0.5, -0.25, 0.0, 1.0, -2.0, 0.0];
    let qdd = [1.0, 2.0, -1.0, 0.0, 3.0, -2.0];
    let difference: Vec<f64> = rubbing
        .inverse_dynamics_nm(&q, &qd, &qdd)
        .iter()
        .zip(plain.inverse_dynamics_nm(&q, &qd, &qdd))
        .map(|(a, b)| a - b)
        .collect();
    let expected = [3.25, -3.125, 0.0, 3.5, -4.0, 0.0];
    assert!(max_abs(difference.iter().zip(expected).map(|(a, b)| a - b)) < 1e-12);
    assert_eq!(rubbing.friction_nm(&qd)[2], 0.0, "no Coulomb term at rest");

    // Rotor inertia enters as J·q̈ on its own joint only.
    let mut arm = catalog::arm("ur5e").unwrap();
    arm.inertials
        .as_mut()
        .unwrap()
        .reflected_rotor_inertia_kg_m2
        .fill(0.0);
    let rigid = ArmDynamics::<6>::from_arm(&arm).unwrap();
    let with_rotors = plain.inverse_dynamics_nm(&q, &qd, &qdd);
    let without = rigid.inverse_dynamics_nm(&q, &qd, &qdd);
    for k in 0..6 {
        let rotor = plain.reflected_rotor_inertia_kg_m2()[k] * qdd[k];
        assert!((with_rotors[k] - without[k] - rotor).abs() < 1e-12);
    }
    // UR5e wrist joints are size 1: 2.0767e-5 · 101² = 0.2118 kg·m².
    assert!((plain.reflected_rotor_inertia_kg_m2()[4] - 0.2118).abs() < 1e-4);
}

#[test]
fn bad_parameters_and_mismatched_arms_are_errors() {
    let arm = catalog::arm("ur10e").unwrap();
    assert_eq!(
        ArmDynamics::<7>::from_arm(&arm).unwrap_err(),
        DynamicsError::JointCount {
            expected: 7,
            got: 6
        }
    );
    let bare = ArmDescription {
        inertials: None,
        joint_origins: None,
        ..arm.clone()
    };
    assert!(matches!(
        ArmDynamics::<6>::from_arm(&bare),
        Err(DynamicsError::NoInertials { .. })
    ));
    let mut negative = arm.clone();
    negative.inertials.as_mut().unwrap().links[2].mass_kg = -1.0;
    let error = ArmDynamics::<6>::from_arm(&negative).unwrap_err();
    assert!(error.to_string().contains("link 3 mass_kg"), "{error}");
    let dynamics = ArmDynamics::<6>::from_arm(&arm).unwrap();
    assert!(
        dynamics
            .clone()
            .with_payload(Payload::point_mass(f64::NAN, [0.0; 3]))
            .is_err()
    );
    assert!(
        dynamics
            .with_gravity_base_m_s2([0.0, f64::INFINITY, 0.0])
            .is_err()
    );
}

#[test]
fn a_custom_arm_with_the_catalog_table_and_parameters_gives_the_catalog_torques() {
    let arm = catalog::arm("ur10e").unwrap();
    let inertials = arm.inertials.clone().unwrap();
    let mut text = String::from("name = \"copy\"\nconvention = \"standard\"\n");
    for row in &arm.dh {
        write!(
            text,
            "[[joints]]\na = {:?}\nalpha = {:?}\nd = {:?}\n",
            row.a_m, row.alpha_rad, row.d_m
        )
        .unwrap();
    }
    for (link, rotor) in inertials
        .links
        .iter()
        .zip(&inertials.reflected_rotor_inertia_kg_m2)
    {
        write!(
            text,
            "[[dynamics.links]]\nmass = {:?}\ncom = {:?}\ninertia = {:?}\nrotor_inertia = {:?}\n",
            link.mass_kg, link.com_link_m, link.inertia_com_kg_m2, rotor
        )
        .unwrap();
    }
    let custom = crate::model::custom::parse_arm(&text, "copy.toml").unwrap();
    let from_custom = ArmDynamics::<6>::from_arm(&custom).unwrap();
    let from_catalog = ArmDynamics::<6>::from_arm(&arm).unwrap();
    let (q, qd, qdd) = ([0.3, -1.0, 0.8, 2.0, -0.5, 1.0], [0.4; 6], [-1.5; 6]);
    assert_eq!(
        from_custom.inverse_dynamics_nm(&q, &qd, &qdd),
        from_catalog.inverse_dynamics_nm(&q, &qd, &qdd)
    );

    let five_links = &text[..text.rfind("[[dynamics.links]]").unwrap()];
    let error = crate::model::custom::parse_arm(five_links, "x.toml").unwrap_err();
    assert!(
        error.to_string().contains("5 entries for 6 joints"),
        "{error}"
    );
    let wrong_inertia = text.replacen("inertia = [", "inertia = [1.0, ", 1);
    let error = crate::model::custom::parse_arm(&wrong_inertia, "x.toml").unwrap_err();
    assert!(error.to_string().contains("inertia: 7 values"), "{error}");
}

#[test]
fn the_payload_regressor_reproduces_the_payload_gravity_torques() {
    let mut rng = Rng(0x5eed);
    for (name, dynamics) in catalog_dynamics() {
        let dynamics = dynamics.with_gravity_base_m_s2([1.0, -2.0, -9.5]).unwrap();
        for _ in 0..20 {
            let q = rng.joints(6.2);
            let mass_kg = rng.uniform(0.0, 20.0);
            let cog = [
                rng.uniform(-0.2, 0.2),
                rng.uniform(-0.2, 0.2),
                rng.uniform(0.0, 0.3),
            ];
            let loaded = dynamics
                .clone()
                .with_payload(Payload::point_mass(mass_kg, cog))
                .unwrap();
            let expected: Vec<f64> = loaded
                .gravity_nm(&q)
                .iter()
                .zip(dynamics.gravity_nm(&q))
                .map(|(a, b)| a - b)
                .collect();
            let parameters = [
                mass_kg,
                mass_kg * cog[0],
                mass_kg * cog[1],
                mass_kg * cog[2],
            ];
            for (row, expected) in dynamics.payload_gravity_regressor(&q).iter().zip(expected) {
                let got: f64 = row.iter().zip(parameters).map(|(y, p)| y * p).sum();
                assert!(
                    (got - expected).abs() < 1e-11,
                    "{name}: {got} vs {expected}"
                );
            }
        }
    }
}

#[test]
fn a_payload_is_identified_from_noisy_static_torques_within_its_stated_uncertainty() {
    let mut rng = Rng(0xfeed);
    let arm = ArmDynamics::<6>::from_arm(&catalog::arm("ur10e").unwrap()).unwrap();
    let truth = Payload::point_mass(4.2, [0.02, -0.01, 0.11]);
    let loaded = arm.clone().with_payload(truth).unwrap();
    let mut within_two_std = 0;
    let trials = 40;
    for _ in 0..trials {
        let mut identifier = payload::PayloadIdentifier::new();
        assert!(identifier.estimate().is_none());
        for _ in 0..100 {
            let q = rng.joints(3.0);
            // Measured: the loaded arm's gravity torques plus noise as currents show at rest
            // (uniform ±0.5 N·m, σ ≈ 0.29 N·m).
            let measured = loaded
                .gravity_nm(&q)
                .map(|tau| tau + rng.uniform(-0.5, 0.5));
            let model = arm.gravity_nm(&q);
            let beyond: [f64; 6] = std::array::from_fn(|k| measured[k] - model[k]);
            identifier.add_static_sample(&arm, &q, &beyond);
        }
        let estimate = identifier.estimate().unwrap();
        assert_eq!(estimate.samples, 100);
        assert!(
            estimate.mass_std_kg > 0.0 && estimate.mass_std_kg < 0.05,
            "{estimate:?}"
        );
        let error = estimate.mass_kg - truth.mass_kg;
        assert!(error.abs() < 5.0 * estimate.mass_std_kg, "{estimate:?}");
        if error.abs() < 2.0 * estimate.mass_std_kg {
            within_two_std += 1;
        }
        let cog = estimate.cog_flange_m.unwrap();
        for (got, want) in cog.iter().zip(truth.cog_flange_m) {
            assert!((got - want).abs() < 0.01, "{cog:?}");
        }
    }
    // A stated σ that is honest puts ~95 % of estimates within 2σ.
    assert!(
        within_two_std >= trials * 8 / 10,
        "{within_two_std} of {trials}"
    );
    // One pose repeated determines nothing.
    let mut identifier = payload::PayloadIdentifier::new();
    for _ in 0..10 {
        identifier.add_static_sample(&arm, &[0.1; 6], &[1.0; 6]);
    }
    assert!(identifier.estimate().is_none());
}

#[test]
fn the_controller_model_is_gravity_in_freedrive_and_never_friction() {
    let friction = [JointFriction {
        coulomb_nm: 3.0,
        viscous_nm_s_rad: 0.5,
    }; 6];
    let dynamics = ArmDynamics::<6>::from_arm(&catalog::arm("ur5e").unwrap())
        .unwrap()
        .with_friction(friction)
        .unwrap();
    let (q, qd, qdd) = ([0.2, -1.1, 1.3, -0.4, 1.2, 0.3], [0.5; 6], [1.0; 6]);
    assert_eq!(
        ControllerMode::from_robot_status_bits(0b011),
        ControllerMode::Program
    );
    assert_eq!(
        ControllerMode::from_robot_status_bits(0b111),
        ControllerMode::Freedrive
    );
    assert_eq!(
        dynamics.controller_moment_nm(ControllerMode::Freedrive, &q, &qd, &qdd),
        dynamics.gravity_nm(&q)
    );
    let program = dynamics.controller_moment_nm(ControllerMode::Program, &q, &qd, &qdd);
    let full = dynamics.inverse_dynamics_nm(&q, &qd, &qdd);
    let rubbing = dynamics.friction_nm(&qd);
    for k in 0..6 {
        assert!((program[k] + rubbing[k] - full[k]).abs() < 1e-12);
    }
    // Current to torque: a UR10e shoulder (size 4) 0.11968 N·m/A × 101.
    let factors = ur::current_to_torque_nm_per_a("ur10e").unwrap();
    assert!((factors[0] - 12.08768).abs() < 1e-9);
    assert!(ur::current_to_torque_nm_per_a("ur20").is_none());
}

/// `ArmDynamics` of a URDF's chain, the recursion the live twin runs with every carried body
/// lumped into its joint's link, equals the whole tree's recursion (`UrdfDynamics`) at spread
/// states: fingers, a head and links past the tip included.
fn lumped_dynamics_agree_with_the_tree<const N: usize>(
    text: &str,
    base_link: Option<&str>,
    tip_link: &str,
) {
    let robot = UrdfRobot::parse(text).unwrap();
    let chain = robot.chain(base_link, Some(tip_link)).unwrap();
    let arm = chain.arm_description(&robot).unwrap();
    let inertials = arm.inertials.as_ref().expect("the chain carries mass");
    assert_eq!(
        inertials.max_torque_nm.as_ref().map(Vec::len),
        Some(N),
        "{tip_link}: every joint states its effort"
    );
    let lumped = ArmDynamics::<N>::from_arm(&arm).unwrap();
    let tree = UrdfDynamics::new(&robot, &chain).unwrap();
    let mut largest = 0.0_f64;
    for sample in 0..20 {
        #[allow(clippy::cast_precision_loss, reason = "a test's sample index")]
        let value = |scale: f64, k: usize| {
            scale * ((f64::from(sample) + 1.0) * (k as f64 * 1.7 + 0.3)).sin()
        };
        let q: [f64; N] = std::array::from_fn(|k| value(2.5, k));
        let qd: [f64; N] = std::array::from_fn(|k| value(1.5, k + 11));
        let qdd: [f64; N] = std::array::from_fn(|k| value(4.0, k + 23));
        let expected = tree.inverse_dynamics(&q, &qd, &qdd).unwrap();
        let got = lumped.inverse_dynamics_nm(&q, &qd, &qdd);
        let scale = expected.iter().fold(1.0_f64, |m, v| m.max(v.abs()));
        for (g, e) in got.iter().zip(&expected) {
            largest = largest.max((g - e).abs() / scale);
        }
    }
    assert!(largest < 1e-12, "{tip_link}: {largest:e} relative");
}

#[test]
fn a_chains_lumped_dynamics_equal_the_whole_trees() {
    let data = |name: &str| match name {
        "ur5" => include_str!("../../../../tests/data/urdf/ur5_robot.urdf"),
        "z1" => include_str!("../../../../tests/data/urdf/z1.urdf"),
        "kinova" => include_str!("../../../../tests/data/urdf/kinova.urdf"),
        "panda" => include_str!("../../../../tests/data/urdf/panda.urdf"),
        _ => include_str!("../../../../tests/data/urdf/tiago_no_hand.urdf"),
    };
    lumped_dynamics_agree_with_the_tree::<6>(data("ur5"), None, "tool0");
    lumped_dynamics_agree_with_the_tree::<6>(data("z1"), None, "link06");
    lumped_dynamics_agree_with_the_tree::<6>(data("kinova"), None, "j2s6s200_end_effector");
    lumped_dynamics_agree_with_the_tree::<7>(data("panda"), None, "panda_hand_tcp");
    lumped_dynamics_agree_with_the_tree::<7>(
        data("tiago"),
        Some("torso_lift_link"),
        "wrist_ft_tool_link",
    );
}

#[test]
fn rotor_inertia_given_adds_its_torque_and_its_share_of_the_mass_matrix() {
    let mut rng = Rng(0x7070);
    let (_, dynamics) = catalog_dynamics()
        .into_iter()
        .find(|(name, _)| *name == "z1.urdf")
        .expect("a URDF arm");
    assert_eq!(dynamics.reflected_rotor_inertia_kg_m2(), &[0.0; 6]);
    let rotor_kg_m2 = [0.5, 0.4, 0.3, 0.2, 0.1, 0.05];
    let turning = dynamics
        .clone()
        .with_reflected_rotor_inertia_kg_m2(rotor_kg_m2)
        .unwrap();
    for _ in 0..10 {
        let (q, qd, qdd) = (rng.joints(2.0), rng.joints(2.0), rng.joints(5.0));
        let without = dynamics.inverse_dynamics_nm(&q, &qd, &qdd);
        let with = turning.inverse_dynamics_nm(&q, &qd, &qdd);
        let mass = turning.mass_matrix_kg_m2(&q) - dynamics.mass_matrix_kg_m2(&q);
        for k in 0..6 {
            assert!((with[k] - without[k] - rotor_kg_m2[k] * qdd[k]).abs() < 1e-12);
            assert!((mass[(k, k)] - rotor_kg_m2[k]).abs() < 1e-12);
        }
    }
    assert!(
        dynamics
            .with_reflected_rotor_inertia_kg_m2([0.1, -0.1, 0.0, 0.0, 0.0, 0.0])
            .is_err()
    );
}
