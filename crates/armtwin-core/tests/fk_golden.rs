//! Golden poses of every catalog model at two closed-form configurations, from UR's published DH
//! values typed here independently of the catalog.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]

use std::f64::consts::FRAC_PI_2;

use armtwin_core::kinematics::{OutputFrame, TcpOffset};
use armtwin_core::model::{RobotModel, catalog};

/// `(name, [d1, a2, a3, d4, d5, d6])` as Universal Robots publish them.
const PUBLISHED: [(&str, [f64; 6]); 9] = [
    (
        "ur3",
        [0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819],
    ),
    (
        "ur5",
        [0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823],
    ),
    ("ur10", [0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922]),
    (
        "ur3e",
        [0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921],
    ),
    ("ur5e", [0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996]),
    (
        "ur10e",
        [0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655],
    ),
    ("ur16e", [0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655]),
    ("ur20", [0.2363, -0.862, -0.7287, 0.201, 0.1593, 0.1543]),
    ("ur30", [0.2363, -0.637, -0.5037, 0.201, 0.1593, 0.1543]),
];

fn assert_close(actual: [f64; 3], expected: [f64; 3], what: &str) {
    for (axis, (a, e)) in actual.iter().zip(expected).enumerate() {
        assert!(
            (a - e).abs() < 1e-12,
            "{what}: axis {axis}: got {a}, expected {e}"
        );
    }
}

#[test]
fn catalog_lists_exactly_the_published_models() {
    let names: Vec<&str> = catalog::UNIVERSAL_ROBOTS.iter().map(|e| e.name).collect();
    let published: Vec<&str> = PUBLISHED.iter().map(|(n, _)| *n).collect();
    assert_eq!(names, published);
}

#[test]
fn flange_at_zero_is_closed_form() {
    for (name, [d1, a2, a3, d4, d5, d6]) in PUBLISHED {
        let model = RobotModel::nominal(name).expect("catalog model");
        let pose = model.pose(&[0.0; 6]).expect("valid");
        assert_close(pose.position_m.into(), [a2 + a3, -(d4 + d6), d1 - d5], name);
        // Flange z points along base −y, flange x along base x: R = Rx(π/2).
        let q = pose.readout().quaternion_xyzw;
        let half_sqrt2 = 0.5_f64.sqrt();
        let expected = [half_sqrt2, 0.0, 0.0, half_sqrt2];
        for (a, e) in q.iter().zip(expected) {
            assert!((a - e).abs() < 1e-15, "{name}: quaternion {q:?}");
        }
    }
}

#[test]
fn flange_upright_is_closed_form() {
    // Shoulder lift and wrist 1 at −π/2: the arm stands straight up.
    let q = [0.0, -FRAC_PI_2, 0.0, -FRAC_PI_2, 0.0, 0.0];
    for (name, [d1, a2, a3, d4, d5, d6]) in PUBLISHED {
        let model = RobotModel::nominal(name).expect("catalog model");
        let pose = model.pose(&q).expect("valid");
        assert_close(
            pose.position_m.into(),
            [0.0, -(d4 + d6), d1 - a2 - a3 + d5],
            name,
        );
        let expected = [[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]];
        for (row, expected_row) in expected.iter().enumerate() {
            for (col, e) in expected_row.iter().enumerate() {
                let a = pose.rotation[(row, col)];
                assert!((a - e).abs() < 1e-15, "{name}: R[{row}][{col}] = {a}");
            }
        }
    }
}

#[test]
fn base_link_frame_and_tool_compose() {
    // A 0.2 m tool along the flange z axis, turned π/2 about it.
    let tool = TcpOffset::from_ur_pose([0.0, 0.0, 0.2, 0.0, 0.0, FRAC_PI_2]).expect("finite");
    let arm = catalog::arm("ur10e").expect("catalog");
    let model = RobotModel::new(arm, None, tool, OutputFrame::BaseLink).expect("model");
    let pose = model.pose(&[0.0; 6]).expect("valid");
    // At q = 0 the flange z axis is base −y; base_link negates x and y.
    let [d1, a2, a3, d4, d5, d6] = PUBLISHED[5].1;
    assert_close(
        pose.position_m.into(),
        [-(a2 + a3), d4 + d6 + 0.2, d1 - d5],
        "ur10e tool in base_link",
    );
}

#[test]
fn joint_limits_are_enforced_with_the_joint_named() {
    let model = RobotModel::nominal("ur10e").expect("catalog model");
    let err = model
        .pose(&[0.0, 0.0, 7.0, 0.0, 0.0, 0.0])
        .expect_err("outside ±2π");
    assert!(err.to_string().contains("q3"), "{err}");
    // UR3e's tool joint turns without limit.
    let ur3e = RobotModel::nominal("ur3e").expect("catalog model");
    assert!(ur3e.pose(&[0.0, 0.0, 0.0, 0.0, 0.0, 100.0]).is_ok());
    assert!(ur3e.pose(&[0.0, 0.0, 0.0, 0.0, 0.0, f64::NAN]).is_err());
}
