//! A robot model written as a URDF: its chain (the robot's own calibration, output frame and tool
//! folded in) as revolute joints about z at their origins, so that `robot_state_publisher`,
//! Pinocchio or `MoveIt` load it to the poses armtwin computes.

use std::fmt::Write as _;

use nalgebra::IsometryMatrix3;

use crate::model::{RobotModel, catalog};
use crate::orientation;

/// `<origin xyz rpy>` of `transform`; numbers in Rust's shortest form that reads back to the same
/// bits.
fn origin(transform: &IsometryMatrix3<f64>) -> String {
    let t = transform.translation.vector;
    let rpy = orientation::rpy_from_matrix(transform.rotation.matrix());
    format!(
        r#"<origin xyz="{} {} {}" rpy="{} {} {}"/>"#,
        t.x, t.y, t.z, rpy.roll_rad, rpy.pitch_rad, rpy.yaw_rad
    )
}

/// XML text with `&`, `<`, `>` and `"` escaped.
fn escaped(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The URDF of `model`: links `<root_link>`, `link_1` … `link_n`, and `<tip_link>`; a catalog
/// arm's joints keep Universal Robots' ROS names (`shoulder_pan_joint` …), others are `joint_k`.
/// Limits are the model's; an unlimited joint is `continuous`. Without inertials: kinematics.
#[must_use]
pub fn model_urdf(model: &RobotModel, root_link: &str, tip_link: &str) -> String {
    let (origins, last_from_tip) = model.chain().joint_origins();
    let arm = model.arm();
    let ur_names = origins.len() == catalog::UR_JOINT_NAMES.len()
        && catalog::UNIVERSAL_ROBOTS.iter().any(|e| e.name == arm.name);
    let mut text = String::new();
    let _ = writeln!(text, r#"<?xml version="1.0"?>"#);
    let _ = writeln!(
        text,
        "<!-- armtwin's model of {}: calibration {}, tool {:?} -->",
        escaped(&arm.name).replace("--", "- -"),
        model
            .calibration()
            .map_or("none".to_owned(), |c| escaped(&c.source_name)
                .replace("--", "- -")),
        model.tool().to_ur_pose()
    );
    let _ = writeln!(text, r#"<robot name="{}">"#, escaped(&arm.name));
    let _ = writeln!(text, r#"  <link name="{}"/>"#, escaped(root_link));
    let mut parent = escaped(root_link);
    for (k, joint_origin) in origins.iter().enumerate() {
        let joint = if ur_names {
            format!("{}_joint", catalog::UR_JOINT_NAMES[k])
        } else {
            format!("joint_{}", k + 1)
        };
        let child = format!("link_{}", k + 1);
        let limits = arm.joint_limits.get(k);
        let (kind, limit) = match limits.and_then(|l| l.min_rad.zip(l.max_rad)) {
            Some((min, max)) => (
                "revolute",
                format!(r#"<limit lower="{min}" upper="{max}" effort="0" velocity="0"/>"#),
            ),
            None => ("continuous", String::new()),
        };
        let _ = writeln!(text, r#"  <link name="{child}"/>"#);
        let _ = writeln!(
            text,
            r#"  <joint name="{joint}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>{}<axis xyz="0 0 1"/>{limit}</joint>"#,
            origin(joint_origin)
        );
        parent = child;
    }
    let _ = writeln!(text, r#"  <link name="{}"/>"#, escaped(tip_link));
    let _ = writeln!(
        text,
        r#"  <joint name="{}_fixed" type="fixed"><parent link="{parent}"/><child link="{}"/>{}</joint>"#,
        escaped(tip_link),
        escaped(tip_link),
        origin(&last_from_tip)
    );
    let _ = writeln!(text, "</robot>");
    text
}
