use std::f64::consts::FRAC_PI_2;

use approx::assert_relative_eq;
use nalgebra::Vector3;

use super::*;

/// A base, a fixed mount 0.1 m up, a revolute joint about z, a 0.5-m link, a prismatic joint
/// along its x, and two leaves: the tool and a camera on the mount.
const ARM: &str = r#"<?xml version="1.0"?>
<robot name="two">
  <link name="base"/><link name="mount"/><link name="upper"/><link name="tool"/><link name="camera"/>
  <joint name="mount_fixed" type="fixed">
    <parent link="base"/><child link="mount"/><origin xyz="0 0 0.1"/>
  </joint>
  <joint name="shoulder" type="revolute">
    <parent link="mount"/><child link="upper"/><axis xyz="0 0 2"/>
    <limit lower="-3" upper="3" effort="150" velocity="2.5"/>
  </joint>
  <joint name="slide" type="prismatic">
    <parent link="upper"/><child link="tool"/><origin xyz="0.5 0 0" rpy="0 0 1.5707963267948966"/>
    <axis xyz="1 0 0"/><limit lower="0" upper="0.2" effort="50" velocity="0.1"/>
  </joint>
  <joint name="camera_fixed" type="fixed">
    <parent link="mount"/><child link="camera"/><origin xyz="0 0.05 0"/>
  </joint>
</robot>"#;

fn error_of(text: &str) -> UrdfError {
    UrdfRobot::parse(text)
        .and_then(|r| r.chain(None, Some("tool")))
        .unwrap_err()
}

#[test]
fn a_chain_folds_fixed_joints_and_moves_revolute_and_prismatic_joints() {
    let robot = UrdfRobot::parse(ARM).unwrap();
    assert_eq!(robot.name, "two");
    assert_eq!(robot.root_link(), "base");
    assert_eq!(robot.leaf_links(), ["tool", "camera"]);
    let chain = robot.chain(None, Some("tool")).unwrap();
    let names: Vec<_> = chain.joints.iter().map(|j| j.name.as_str()).collect();
    assert_eq!(names, ["shoulder", "slide"]);
    assert_eq!(chain.joints[0].kind, JointKind::Revolute);
    assert_eq!(chain.joints[0].limits.max_rad, Some(3.0));
    assert_eq!(chain.joints[0].max_effort, Some(150.0));
    assert_eq!(chain.joints[1].kind, JointKind::Prismatic);
    // Shoulder at 90°: the upper link points along y; the slide (turned 90° more) along −x.
    let pose = chain.pose(&[FRAC_PI_2, 0.2]).unwrap();
    assert_relative_eq!(
        pose.position_m,
        Vector3::new(-0.2, 0.5, 0.1),
        epsilon = 1e-15
    );
    assert_relative_eq!(pose.rotation * Vector3::x(), -Vector3::x(), epsilon = 1e-15);
    // From the mount, without the fixed joint before it; to the camera, no moving joint at all.
    let from_mount = robot.chain(Some("mount"), Some("tool")).unwrap();
    assert_relative_eq!(
        from_mount.pose(&[0.0, 0.0]).unwrap().position_m,
        Vector3::new(0.5, 0.0, 0.0),
        epsilon = 1e-15
    );
    let camera = robot.chain(None, Some("camera")).unwrap();
    assert_eq!(camera.joint_count(), 0);
    assert_relative_eq!(
        camera.pose(&[]).unwrap().position_m,
        Vector3::new(0.0, 0.05, 0.1)
    );
}

#[test]
fn a_chain_needs_its_tip_named_among_several_leaves_and_a_base_on_its_way() {
    let robot = UrdfRobot::parse(ARM).unwrap();
    let leaves = robot.chain(None, None).unwrap_err().to_string();
    assert!(leaves.contains("'tool', 'camera'"), "{leaves}");
    let off = robot
        .chain(Some("camera"), Some("tool"))
        .unwrap_err()
        .to_string();
    assert!(off.contains("'camera' is not between"), "{off}");
    let missing = robot.chain(None, Some("gripper")).unwrap_err().to_string();
    assert!(
        missing.contains("'gripper' is not in the URDF"),
        "{missing}"
    );
    let chain = robot.chain(None, Some("tool")).unwrap();
    assert_eq!(
        chain.pose(&[0.0]).unwrap_err(),
        UrdfError::JointCount {
            expected: 2,
            got: 1
        }
    );
    assert_eq!(
        chain.pose(&[f64::NAN, 0.0]).unwrap_err(),
        UrdfError::NotFinite("shoulder".to_owned())
    );
}

#[test]
fn bad_descriptions_are_refused_naming_what_is_wrong() {
    let cases: &[(&str, &str, &str)] = &[
        (
            r#"type="prismatic""#,
            r#"type="floating""#,
            "joint 'slide': type 'floating'",
        ),
        (
            r#"<axis xyz="1 0 0"/>"#,
            r#"<axis xyz="0 0 0"/>"#,
            "joint 'slide': its axis has no length",
        ),
        (
            r#"xyz="0.5 0 0""#,
            r#"xyz="0.5 zero 0""#,
            "joint 'slide': origin xyz '0.5 zero 0' is not three finite numbers",
        ),
        (
            r#"lower="0" upper="0.2""#,
            r#"lower="0.3" upper="0.2""#,
            "joint 'slide': limit lower 0.3 is above upper 0.2",
        ),
        (
            r#"<child link="tool"/>"#,
            r#"<child link="toll"/>"#,
            "joint 'slide': link 'toll' is not defined",
        ),
        (
            r#"<child link="camera"/>"#,
            r#"<child link="tool"/>"#,
            "link 'tool' is the child of two joints",
        ),
        (
            r#"<link name="camera"/>"#,
            r#"<link name="camera"/><link name="spare"/>"#,
            "2 trees, not one: roots 'base', 'spare'",
        ),
        (
            r#"<axis xyz="1 0 0"/>"#,
            r#"<axis xyz="1 0 0"/><mimic joint="shoulder"/>"#,
            "joint 'slide': mimics another joint",
        ),
        (
            r#"<robot name="two">"#,
            r#"<robot name="two" xmlns:xacro="http://ros.org/wiki/xacro"><xacro:property name="l" value="1"/>"#,
            "xacro template (<xacro:property>)",
        ),
        (
            r#"xyz="0.5 0 0""#,
            r#"xyz="${l} 0 0""#,
            "xacro template (xyz=\"${l} 0 0\")",
        ),
    ];
    for (from, to, expected) in cases {
        assert!(ARM.contains(from), "{from}");
        let error = error_of(&ARM.replacen(from, to, 1)).to_string();
        assert!(error.contains(expected), "{to}: {error}");
    }
    let looped = r#"<robot name="l"><link name="base"/><link name="a"/><link name="b"/>
        <joint name="ab" type="fixed"><parent link="a"/><child link="b"/></joint>
        <joint name="ba" type="fixed"><parent link="b"/><child link="a"/></joint></robot>"#;
    assert_eq!(
        UrdfRobot::parse(looped).unwrap_err(),
        UrdfError::Tree("link 'a' is on a loop".to_owned())
    );
    assert!(matches!(error_of("<robot"), UrdfError::Xml(_)));
    assert!(matches!(
        error_of(r#"<!DOCTYPE robot [<!ENTITY a "aaaa">]><robot name="x"/>"#),
        UrdfError::Xml(_)
    ));
    assert_eq!(
        error_of("<model/>"),
        UrdfError::NotARobot("model".to_owned())
    );
    let huge = " ".repeat(MAX_URDF_BYTES + 1);
    assert_eq!(
        error_of(&huge),
        UrdfError::TooLarge {
            bytes: MAX_URDF_BYTES + 1
        }
    );
}

/// A 2-kg point mass 0.5 m out on a link that turns about y, hung from a fixed base.
const PENDULUM: &str = r#"<robot name="pendulum">
  <link name="base"/>
  <link name="arm"><inertial><origin xyz="0.5 0 0"/><mass value="2"/>
    <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial></link>
  <joint name="hinge" type="continuous"><parent link="base"/><child link="arm"/><axis xyz="0 1 0"/></joint>
</robot>"#;

#[test]
fn a_pendulum_needs_the_torque_of_its_weight_and_its_acceleration() {
    let robot = UrdfRobot::parse(PENDULUM).unwrap();
    let chain = robot.chain(None, None).unwrap();
    let dynamics = UrdfDynamics::new(&robot, &chain).unwrap();
    // Horizontal (q = 0): gravity (−z) on the mass at +x turns it by +m g l about y (r × F), so
    // the joint holds it with −m g l.
    let hold = dynamics.inverse_dynamics(&[0.0], &[0.0], &[0.0]).unwrap();
    assert_relative_eq!(hold[0], -2.0 * STANDARD_GRAVITY_M_S2 * 0.5, epsilon = 1e-12);
    // Hanging straight down, at rest: no torque; accelerating: m l² q̈.
    let hanging = dynamics
        .inverse_dynamics(&[FRAC_PI_2], &[3.0], &[4.0])
        .unwrap();
    assert_relative_eq!(hanging[0], 2.0 * 0.25 * 4.0, epsilon = 1e-12);
    assert_eq!(
        dynamics.inverse_dynamics(&[0.0], &[], &[0.0]).unwrap_err(),
        UrdfError::JointCount {
            expected: 1,
            got: 0
        }
    );
    let negative = UrdfRobot::parse(&PENDULUM.replace(r#"value="2""#, r#"value="-2""#));
    assert_eq!(
        negative.unwrap_err().to_string(),
        "link 'arm': mass -2 is negative"
    );
    let missing = UrdfRobot::parse(&PENDULUM.replace(r#" izz="0""#, ""));
    assert_eq!(
        missing.unwrap_err().to_string(),
        "link 'arm': <inertia> has no izz"
    );
}

#[test]
fn a_models_urdf_reads_back_to_its_poses() {
    let model = crate::model::RobotModel::nominal("ur5e").unwrap();
    let text = model_urdf(&model, "base", "tool0");
    let chain = UrdfRobot::parse(&text).unwrap().chain(None, None).unwrap();
    assert_eq!(chain.joints[1].name, "shoulder_lift_joint");
    let q = [0.3, -1.2, 1.1, -0.4, 0.9, 2.0];
    let expected = model.pose(&q).unwrap();
    let got = chain.pose(&q).unwrap();
    assert_relative_eq!(got.position_m, expected.position_m, epsilon = 1e-14);
    assert_relative_eq!(got.rotation, expected.rotation, epsilon = 1e-14);
}

#[test]
fn a_models_link_transforms_compose_to_its_pose_and_name_its_urdfs_links() {
    let model = crate::model::RobotModel::nominal("ur10e").unwrap();
    let frames = ModelFrames::of(&model);
    assert_eq!(frames.root_link(), "base");
    let children: Vec<&str> = frames.child_links().collect();
    assert_eq!(children.first(), Some(&"link_1"));
    assert_eq!(children.last(), Some(&"tool0"));
    let q = [0.3, -1.2, 1.1, -0.4, 0.9, 2.0];
    let mut transforms = Vec::new();
    frames.transforms(&q, &mut transforms);
    assert_eq!(transforms.len(), children.len());
    let composed = transforms
        .iter()
        .fold(nalgebra::IsometryMatrix3::identity(), |acc, t| acc * t);
    let expected = model.pose(&q).unwrap();
    assert_relative_eq!(
        composed.translation.vector,
        expected.position_m,
        epsilon = 1e-14
    );
    assert_relative_eq!(
        *composed.rotation.matrix(),
        expected.rotation,
        epsilon = 1e-14
    );
    // Every frame is a link of the URDF, whose parents are the transforms' parents.
    let text = frames.urdf(&model);
    let robot = UrdfRobot::parse(&text).unwrap();
    let chain = robot.chain(None, None).unwrap();
    assert_eq!(chain.joints.len(), 6);
    for (k, child) in children.iter().enumerate() {
        let parent = frames.parent_link(k);
        assert!(
            text.contains(&format!(
                r#"<parent link="{parent}"/><child link="{child}"/>"#
            )),
            "{parent} → {child}"
        );
    }
    // A cylinder per link that reaches a next origin: the base's first joint is at its origin.
    assert_eq!(text.matches("<cylinder").count(), 6, "{text}");
}
