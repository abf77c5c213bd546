//! A robot model written as a URDF: its chain (the robot's own calibration, output frame and tool
//! folded in) as revolute joints about z at their origins, so that `robot_state_publisher`,
//! Pinocchio or `MoveIt` load it to the poses armtwin computes; and the transforms between its
//! links at given joint angles ([`ModelFrames::transforms`]), as `/tf` carries them.

use std::fmt::Write as _;

use nalgebra::{IsometryMatrix3, Rotation3, Translation3, Vector3};

use crate::model::{RobotModel, catalog};
use crate::orientation;

/// The radius (m) of the cylinders drawn between joint origins: a viewer's stand-in for the
/// link meshes, which a chain of joint origins does not have.
const LINK_RADIUS_M: f64 = 0.03;

/// A segment shorter than this (m) is not drawn.
const SHORTEST_SEGMENT_M: f64 = 1e-6;

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

/// A `<visual>` cylinder from a link's origin to `end` (m, in the link's frame), or nothing for
/// a point.
fn segment_visual(end: &Vector3<f64>) -> String {
    let length_m = end.norm();
    if length_m < SHORTEST_SEGMENT_M {
        return String::new();
    }
    // A URDF cylinder lies along its own z, centred on its origin.
    let along = Rotation3::rotation_between(&Vector3::z(), end)
        .unwrap_or_else(|| Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI));
    let placed = IsometryMatrix3::from_parts(Translation3::from(end / 2.0), along);
    format!(
        r#"<visual>{}<geometry><cylinder radius="{LINK_RADIUS_M}" length="{length_m}"/></geometry></visual>"#,
        origin(&placed)
    )
}

/// XML text with `&`, `<`, `>` and `"` escaped.
fn escaped(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A model's links and joints as its URDF names them: `<root_link>`, `link_1` … `link_n` and
/// `<tip_link>`; a catalog arm's joints keep Universal Robots' ROS names (`shoulder_pan_joint`
/// …), others are `joint_k`. The one naming of [`ModelFrames::urdf`] and
/// [`ModelFrames::transforms`], so a viewer's `/tf` moves the links of its `/robot_description`.
#[derive(Debug, Clone)]
pub struct ModelFrames {
    root_link: String,
    tip_link: String,
    links: Vec<String>,
    joints: Vec<String>,
    /// Per joint, `parent_from_joint` at zero ([`crate::kinematics::Chain::joint_origins`]).
    origins: Vec<IsometryMatrix3<f64>>,
    last_from_tip: IsometryMatrix3<f64>,
}

impl ModelFrames {
    /// The frames of `model`, from `root_link` to `tip_link`.
    #[must_use]
    pub fn new(model: &RobotModel, root_link: &str, tip_link: &str) -> Self {
        let (origins, last_from_tip) = model.chain().joint_origins();
        let ur_names = origins.len() == catalog::UR_JOINT_NAMES.len()
            && catalog::UNIVERSAL_ROBOTS
                .iter()
                .any(|e| e.name == model.arm().name);
        let joints = (0..origins.len())
            .map(|k| {
                if ur_names {
                    format!("{}_joint", catalog::UR_JOINT_NAMES[k])
                } else {
                    format!("joint_{}", k + 1)
                }
            })
            .collect();
        Self {
            root_link: root_link.to_owned(),
            tip_link: tip_link.to_owned(),
            links: (1..=origins.len()).map(|k| format!("link_{k}")).collect(),
            joints,
            origins,
            last_from_tip,
        }
    }

    /// The frames a running model is drawn with: rooted at its output frame's name (`base`,
    /// `base_link`, as its poses' `frame_id`), ending at `tcp` with a tool, else `tool0`.
    #[must_use]
    pub fn of(model: &RobotModel) -> Self {
        let has_tool = model.tool().flange_from_tcp() != IsometryMatrix3::identity();
        Self::new(
            model,
            model.frame().as_str(),
            if has_tool { "tcp" } else { "tool0" },
        )
    }

    /// The root link: the frame the transforms start from.
    #[must_use]
    pub fn root_link(&self) -> &str {
        &self.root_link
    }

    /// The link each joint moves, then the tip: the child frames of [`Self::transforms`].
    pub fn child_links(&self) -> impl Iterator<Item = &str> {
        self.links
            .iter()
            .map(String::as_str)
            .chain(std::iter::once(self.tip_link.as_str()))
    }

    /// The link before `child_links()`'s `k`-th.
    #[must_use]
    pub fn parent_link(&self, k: usize) -> &str {
        match k.checked_sub(1) {
            Some(before) => &self.links[before],
            None => &self.root_link,
        }
    }

    /// `parent_from_child` of each of [`Self::child_links`] at joint angles `q_rad` (one per
    /// joint; missing ones taken as zero), into `out` (cleared first). Their product is the
    /// model's pose.
    pub fn transforms(&self, q_rad: &[f64], out: &mut Vec<IsometryMatrix3<f64>>) {
        out.clear();
        for (k, joint_origin) in self.origins.iter().enumerate() {
            let q = q_rad.get(k).copied().unwrap_or(0.0);
            out.push(joint_origin * Rotation3::from_axis_angle(&Vector3::z_axis(), q));
        }
        out.push(self.last_from_tip);
    }

    /// The URDF text: limits are the model's, an unlimited joint is `continuous`; each link is
    /// drawn as a cylinder to the next joint's origin. Without inertials: kinematics.
    #[must_use]
    pub fn urdf(&self, model: &RobotModel) -> String {
        let arm = model.arm();
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
        let first = self
            .origins
            .first()
            .map_or(self.last_from_tip, |o| *o)
            .translation
            .vector;
        let _ = writeln!(
            text,
            r#"  <link name="{}">{}</link>"#,
            escaped(&self.root_link),
            segment_visual(&first)
        );
        for (k, joint_origin) in self.origins.iter().enumerate() {
            let parent = escaped(self.parent_link(k));
            let child = &self.links[k];
            let next = self
                .origins
                .get(k + 1)
                .unwrap_or(&self.last_from_tip)
                .translation
                .vector;
            let (kind, limit) = match arm
                .joint_limits
                .get(k)
                .and_then(|l| l.min_rad.zip(l.max_rad))
            {
                Some((min, max)) => (
                    "revolute",
                    format!(r#"<limit lower="{min}" upper="{max}" effort="0" velocity="0"/>"#),
                ),
                None => ("continuous", String::new()),
            };
            let _ = writeln!(
                text,
                r#"  <link name="{child}">{}</link>"#,
                segment_visual(&next)
            );
            let _ = writeln!(
                text,
                r#"  <joint name="{}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>{}<axis xyz="0 0 1"/>{limit}</joint>"#,
                self.joints[k],
                origin(joint_origin)
            );
        }
        let tip = escaped(&self.tip_link);
        let _ = writeln!(text, r#"  <link name="{tip}"/>"#);
        let _ = writeln!(
            text,
            r#"  <joint name="{tip}_fixed" type="fixed"><parent link="{}"/><child link="{tip}"/>{}</joint>"#,
            escaped(self.parent_link(self.origins.len())),
            origin(&self.last_from_tip)
        );
        let _ = writeln!(text, "</robot>");
        text
    }
}

/// The URDF of `model` from `root_link` to `tip_link` ([`ModelFrames`]).
#[must_use]
pub fn model_urdf(model: &RobotModel, root_link: &str, tip_link: &str) -> String {
    ModelFrames::new(model, root_link, tip_link).urdf(model)
}
