//! Inverse kinematics: FK(IK(pose)) = pose for every catalog arm, all eight branches, calibrated
//! and tool models, singular and unreachable poses.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]

use std::f64::consts::PI;

use armtwin_core::ik::{self, IkError};
use armtwin_core::kinematics::{OutputFrame, Pose, TcpOffset};
use armtwin_core::model::{Calibration, RobotModel, catalog};
use armtwin_core::orientation;

mod common;

use common::Rng;

fn errors(model: &RobotModel, q: &[f64; 6], target: &Pose) -> (f64, f64) {
    let pose = model.pose(q).unwrap();
    let position = (pose.position_m - target.position_m).norm();
    let angle =
        orientation::rotation_vector_from_matrix(&(pose.rotation * target.rotation.transpose()))
            .norm();
    (position, angle)
}

fn same_angles(a: &[f64; 6], b: &[f64; 6], tolerance: f64) -> bool {
    a.iter()
        .zip(b)
        .all(|(x, y)| orientation::wrap_angle(x - y).abs() < tolerance)
}

/// Away from every singularity by `margin`: wrist not aligned, elbow not stretched or folded.
fn generic(q: &[f64; 6], margin: f64) -> bool {
    q[4].sin().abs() > margin && q[2].sin().abs() > margin
}

fn check_round_trips(model: &RobotModel, rng: &mut Rng, poses: usize, margin: f64) {
    let mut checked = 0;
    let mut with_eight = 0;
    let flange = RobotModel::new(
        model.arm().clone(),
        None,
        TcpOffset::FLANGE,
        OutputFrame::Base,
    )
    .unwrap();
    let geometry = ik::UrGeometry::from_arm(model.arm()).unwrap();
    let [_, _, _, d4, _, d6] = geometry.d1_a2_a3_d4_d5_d6_m;
    while checked < poses {
        let q = rng.joints();
        // The shoulder branches meet where the wrist centre is d4 from base z.
        let pose = flange.pose(&q).unwrap();
        let wrist = pose.position_m - pose.rotation.column(2) * d6;
        let shoulder_generic = d4 / wrist.x.hypot(wrist.y) < 1.0 - margin;
        if !(generic(&q, margin) && shoulder_generic) {
            continue;
        }
        checked += 1;
        let target = model.pose(&q).unwrap();
        let answer = ik::solve(model, &target, None)
            .unwrap_or_else(|e| panic!("{}: q = {q:?}: {e}", model.arm().name));
        for solution in &answer.solutions {
            let (position, angle) = errors(model, &solution.q_rad, &target);
            assert!(
                position <= 1e-9 && angle <= 1e-9,
                "{}: q = {q:?} → {:?}: {position:e} m, {angle:e} rad",
                model.arm().name,
                solution.q_rad
            );
        }
        assert!(
            answer
                .solutions
                .iter()
                .any(|s| same_angles(&s.q_rad, &q, 1e-7)),
            "{}: the generating configuration {q:?} is not among {:?}",
            model.arm().name,
            answer.solutions
        );
        // Each branch appears once: merged branches are one solution.
        let mut configurations: Vec<_> = answer
            .solutions
            .iter()
            .map(|s| {
                (
                    s.configuration.shoulder.as_str(),
                    s.configuration.elbow.as_str(),
                    s.configuration.wrist.as_str(),
                )
            })
            .collect();
        configurations.sort_unstable();
        configurations.dedup();
        // (On a calibrated chain a label comes from the nominal start's branch, and the elbow's
        // up or down can change on the way where the wrist is over the shoulder.)
        if model.chain().uses_closed_form() {
            assert_eq!(configurations.len(), answer.solutions.len());
        }
        if answer.solutions.len() == 8 {
            with_eight += 1;
        }
    }
    // The generating configuration is drawn from all branches alike, so finding it every time
    // shows no branch is missed; a pose has 8 solutions unless the other shoulder or wrist
    // branch puts the wrist beyond reach, which random joint angles often do.
    assert!(
        with_eight * 4 >= poses,
        "{}: only {with_eight} of {poses} poses had 8 solutions",
        model.arm().name
    );
}

#[test]
fn every_catalog_arm_round_trips_with_all_eight_solutions() {
    let mut rng = Rng(7);
    for entry in &catalog::UNIVERSAL_ROBOTS {
        let model = RobotModel::nominal(entry.name).unwrap();
        check_round_trips(&model, &mut rng, 2000, 0.05);
    }
}

#[test]
fn tool_and_base_link_round_trip() {
    let mut rng = Rng(11);
    let tool = TcpOffset::from_ur_pose([0.01, -0.02, 0.15, 0.3, -0.2, 1.0]).unwrap();
    for entry in &catalog::UNIVERSAL_ROBOTS {
        let model = RobotModel::new(
            catalog::arm(entry.name).unwrap(),
            None,
            tool,
            OutputFrame::BaseLink,
        )
        .unwrap();
        check_round_trips(&model, &mut rng, 300, 0.05);
    }
}

fn conf(theta: [f64; 6], a: [f64; 6], d: [f64; 6], alpha: [f64; 6]) -> Calibration {
    let list = |v: [f64; 6]| {
        v.iter()
            .map(|x| format!("{x:?}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let text = format!(
        "[mounting]\ndelta_theta = [ {} ]\ndelta_a = [ {} ]\ndelta_d = [ {} ]\ndelta_alpha = [ {} ]\n",
        list(theta),
        list(a),
        list(d),
        list(alpha)
    );
    Calibration::parse(&text, "realistic.conf").unwrap()
}

#[test]
fn a_realistically_calibrated_model_round_trips_with_every_branch() {
    // Deltas of the size real e-Series arms carry: the TCP moves by millimetres.
    let calibration = conf(
        [2e-4, -1.1e-3, 8e-4, 3e-4, -6e-4, 2e-4],
        [1e-4, -1.3e-3, 9e-4, 2e-4, 1e-4, 0.0],
        [3e-4, 1.2e-3, -2e-3, 8e-4, -3e-4, 2e-4],
        [-4e-4, 7e-4, 1.1e-3, 5e-4, -3e-4, 0.0],
    );
    let model = RobotModel::new(
        catalog::arm("ur5e").unwrap(),
        Some(calibration),
        TcpOffset::from_ur_pose([0.0, 0.0, 0.2, 0.0, 0.0, 0.0]).unwrap(),
        OutputFrame::Base,
    )
    .unwrap();
    check_round_trips(&model, &mut Rng(13), 1000, 0.1);
}

#[test]
fn the_example_calibrations_round_trip_where_the_nominal_arm_reaches() {
    // The example files move the TCP by ~9 cm on average from the nominal arm (synthetic values,
    // far beyond a real arm's millimetres): every solution returned must still reproduce the
    // target, the generating configuration is found where the nominal closed form gives that
    // branch a start, and a pose the nominal arm cannot reach is refused, never NaN.
    let mut rng = Rng(17);
    for (text, name) in [
        (
            include_str!("../../../config/examples/calibration.conf"),
            "calibration.conf",
        ),
        (
            include_str!("../../../config/examples/ur_calibration.yaml"),
            "ur_calibration.yaml",
        ),
    ] {
        let model = RobotModel::new(
            catalog::arm("ur10e").unwrap(),
            Some(Calibration::parse(text, name).unwrap()),
            TcpOffset::FLANGE,
            OutputFrame::Base,
        )
        .unwrap();
        let (mut found, mut answered, mut refused) = (0, 0, 0);
        for _ in 0..200 {
            let q = rng.joints();
            if !generic(&q, 0.3) {
                continue;
            }
            let target = model.pose(&q).unwrap();
            match ik::solve(&model, &target, None) {
                Ok(answer) => {
                    answered += 1;
                    for solution in &answer.solutions {
                        let (position, angle) = errors(&model, &solution.q_rad, &target);
                        assert!(position <= 1e-9 && angle <= 1e-9, "{name}: {q:?}");
                    }
                    if answer
                        .solutions
                        .iter()
                        .any(|s| same_angles(&s.q_rad, &q, 1e-7))
                    {
                        found += 1;
                    }
                }
                Err(IkError::Unreachable { .. }) => refused += 1,
                Err(other) => panic!("{name}: {q:?}: {other}"),
            }
        }
        println!("{name}: {answered} answered ({found} with the generating q), {refused} refused");
        assert!(found * 10 >= answered * 9, "{name}: {found} of {answered}");
        assert!(refused * 10 <= answered, "{name}: {refused} refused");
    }
}

#[test]
fn the_seed_orders_the_solutions() {
    let model = RobotModel::nominal("ur5e").unwrap();
    let q = [0.4, -1.2, 1.4, -1.7, -1.5, 0.3];
    let target = model.pose(&q).unwrap();
    let answer = ik::solve(&model, &target, Some(&q)).unwrap();
    assert!(same_angles(&answer.solutions[0].q_rad, &q, 1e-9));
    assert!(answer.solutions[0].distance_from_seed_rad < 1e-9);
    // A seed a full turn away on joint 6 gets its solution on that turn (limits are ±2π).
    let turned = [q[0], q[1], q[2], q[3], q[4], q[5] - 2.0 * PI];
    let answer = ik::solve(&model, &target, Some(&turned)).unwrap();
    assert!((answer.solutions[0].q_rad[5] - turned[5]).abs() < 1e-9);
    for pair in answer.solutions.windows(2) {
        assert!(pair[0].distance_from_seed_rad <= pair[1].distance_from_seed_rad);
    }
}

#[test]
fn a_singular_wrist_gives_solutions_with_the_seeds_q6() {
    let model = RobotModel::nominal("ur10e").unwrap();
    let q = [0.3, -1.0, 1.2, -0.4, 0.0, 0.7];
    let target = model.pose(&q).unwrap();
    let seed = [0.3, -1.0, 1.2, -0.4, 0.0, 0.5];
    let answer = ik::solve(&model, &target, Some(&seed)).unwrap();
    assert!(answer.wrist_singular);
    assert!(!answer.solutions.is_empty());
    for solution in &answer.solutions {
        let (position, angle) = errors(&model, &solution.q_rad, &target);
        assert!(position <= 1e-9 && angle <= 1e-9);
        assert!(solution.q_rad.iter().all(|v| v.is_finite()));
    }
    assert!((answer.solutions[0].q_rad[5] - 0.5).abs() < 1e-9);
}

#[test]
fn a_stretched_elbow_is_reached() {
    let model = RobotModel::nominal("ur10e").unwrap();
    let q = [0.3, -1.0, 0.0, -0.4, 1.0, 0.7];
    let target = model.pose(&q).unwrap();
    let answer = ik::solve(&model, &target, Some(&q)).unwrap();
    assert!(same_angles(&answer.solutions[0].q_rad, &q, 1e-6));
}

#[test]
fn unreachable_poses_are_refused_with_a_reason() {
    let model = RobotModel::nominal("ur10e").unwrap();
    let far = Pose {
        position_m: nalgebra::Vector3::new(3.0, 0.0, 0.5),
        rotation: nalgebra::Matrix3::identity(),
    };
    let err = ik::solve(&model, &far, None).unwrap_err();
    assert!(matches!(err, IkError::Unreachable { .. }), "{err}");
    assert!(err.to_string().contains("reach"), "{err}");
    // Inside the shoulder offset: the wrist centre on the base axis.
    let inside = Pose {
        position_m: nalgebra::Vector3::new(0.0, 0.0, 0.5 - 0.11655),
        rotation: nalgebra::Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0),
    };
    let err = ik::solve(&model, &inside, None).unwrap_err();
    assert!(matches!(err, IkError::Unreachable { .. }), "{err}");
    let nan = Pose {
        position_m: nalgebra::Vector3::new(f64::NAN, 0.0, 0.0),
        rotation: nalgebra::Matrix3::identity(),
    };
    assert!(matches!(
        ik::solve(&model, &nan, None),
        Err(IkError::NonFinite { .. })
    ));
}

#[test]
fn an_arm_without_the_ur_geometry_is_refused() {
    let text = include_str!("../../../config/examples/franka-panda.toml");
    let arm = armtwin_core::model::custom::parse_arm(text, "franka-panda.toml").unwrap();
    let model = RobotModel::new(arm, None, TcpOffset::FLANGE, OutputFrame::Base).unwrap();
    let middle: Vec<f64> = model
        .arm()
        .joint_limits
        .iter()
        .map(|l| 0.5 * (l.min_rad.unwrap_or(0.0) + l.max_rad.unwrap_or(0.0)))
        .collect();
    let target = model.pose(&middle).unwrap();
    assert!(matches!(
        ik::solve(&model, &target, None),
        Err(IkError::NotUrGeometry { .. })
    ));
}
