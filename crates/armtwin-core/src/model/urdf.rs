//! A robot's kinematics from its URDF (ROS' Unified Robot Description Format): the serial chain
//! between two of its links, with revolute, continuous and prismatic joints, fixed joints folded
//! into the links, and the limits the file states.
//!
//! Reads the XML text only (no file, no mesh): the caller reads the file. The document is
//! untrusted input: its size and element count are bounded, DTDs (entity expansion) refused, and
//! every error names the link or joint it is about.

use std::collections::{HashMap, HashSet};
use std::f64::consts::PI;

use nalgebra::{IsometryMatrix3, Matrix3, Rotation3, Translation3, Unit, Vector3};
use thiserror::Error;

use super::inertia::{ArmInertials, LinkInertial};
use super::{ArmDescription, JointLimits, JointOrigins};
use crate::kinematics::{DhConvention, Pose};
use crate::orientation::{self, Rpy};

/// The largest URDF document taken (bytes): whole humanoids' descriptions, with every collision
/// and visual element, fit well within it.
pub const MAX_URDF_BYTES: usize = 4 << 20;
/// The largest number of XML nodes in a document (elements, attributes' text, comments).
const MAX_XML_NODES: u32 = 200_000;
/// The largest number of joints (and of links) in a description.
pub const MAX_URDF_JOINTS: usize = 4096;

/// Why a URDF description or a chain of it cannot be used.
#[derive(Debug, Error, PartialEq)]
pub enum UrdfError {
    /// The document is larger than [`MAX_URDF_BYTES`].
    #[error("the URDF is {bytes} bytes, above the {MAX_URDF_BYTES}-byte limit")]
    TooLarge {
        /// Its size.
        bytes: usize,
    },
    /// Not well-formed XML, or past the node limit, or with a DTD.
    #[error("the URDF is not readable XML: {0}")]
    Xml(String),
    /// The root element is not `<robot>`.
    #[error("the URDF's root element is <{0}>, not <robot>")]
    NotARobot(String),
    /// Xacro macros or expressions left in the document.
    #[error(
        "the file is a xacro template ({0}), not a URDF: expand it first, e.g. `xacro robot.urdf.xacro > robot.urdf` (or `ros2 run xacro xacro …`)"
    )]
    Xacro(String),
    /// More joints or links than [`MAX_URDF_JOINTS`].
    #[error("the URDF has more than {MAX_URDF_JOINTS} joints or links")]
    TooManyElements,
    /// A joint or link without a name, or a name used twice.
    #[error("{0}")]
    Naming(String),
    /// A joint's attribute or child element is missing or malformed.
    #[error("joint '{joint}': {reason}")]
    Joint {
        /// The joint's name.
        joint: String,
        /// What is wrong.
        reason: String,
    },
    /// A link's `<inertial>` is missing a value or malformed.
    #[error("link '{link}': {reason}")]
    Link {
        /// The link's name.
        link: String,
        /// What is wrong.
        reason: String,
    },
    /// The links do not form one tree.
    #[error("{0}")]
    Tree(String),
    /// The chain's base or tip cannot be chosen or is not in the tree.
    #[error("{0}")]
    Chain(String),
    /// A joint configuration of the wrong length, or not finite.
    #[error("the chain has {expected} joints, got {got} values")]
    JointCount {
        /// Joints on the chain.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// A joint value that is NaN or infinite.
    #[error("joint '{0}' has a value that is not finite")]
    NotFinite(String),
}

/// How a joint of the chain moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    /// A rotation about the axis (rad), within limits.
    Revolute,
    /// A rotation about the axis (rad), without limits.
    Continuous,
    /// A translation along the axis (m), within limits.
    Prismatic,
}

impl JointKind {
    /// The URDF's name of the kind.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Revolute => "revolute",
            Self::Continuous => "continuous",
            Self::Prismatic => "prismatic",
        }
    }
}

/// One moving joint of a chain.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainJoint {
    /// The joint's name in the URDF.
    pub name: String,
    /// How it moves.
    pub kind: JointKind,
    /// `parent_from_joint`: the fixed transforms before it (fixed joints folded in), then its own
    /// `<origin>`.
    pub parent_from_joint: IsometryMatrix3<f64>,
    /// Its `<axis>`, normalised, in the joint frame.
    pub axis: Unit<Vector3<f64>>,
    /// Its position limits (rad, or m for a prismatic joint); unlimited for a continuous joint.
    pub limits: JointLimits,
    /// Its velocity limit (rad/s or m/s), if the file gives one.
    pub max_velocity: Option<f64>,
    /// Its effort limit (N·m or N), if the file gives one.
    pub max_effort: Option<f64>,
}

/// The serial chain from a base link to a tip link.
#[derive(Debug, Clone, PartialEq)]
pub struct UrdfChain {
    /// The base link's name: poses are in its frame.
    pub base_link: String,
    /// The tip link's name: the pose is its frame's.
    pub tip_link: String,
    /// The moving joints, base to tip.
    pub joints: Vec<ChainJoint>,
    /// The fixed transform from the last moving joint's frame (or the base, without one) to the
    /// tip link.
    pub last_from_tip: IsometryMatrix3<f64>,
}

/// A joint as the file states it.
#[derive(Debug, Clone)]
struct RawJoint {
    name: String,
    /// `None` for a fixed joint.
    kind: Option<JointKind>,
    parent: String,
    child: String,
    origin: IsometryMatrix3<f64>,
    axis: Unit<Vector3<f64>>,
    limits: JointLimits,
    max_velocity: Option<f64>,
    max_effort: Option<f64>,
    mimic: bool,
}

/// A link's mass properties, in its own frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Inertial {
    /// Mass (kg).
    pub mass_kg: f64,
    /// Centre of mass in the link frame (m).
    pub com_m: Vector3<f64>,
    /// Inertia about the centre of mass, in the link frame's axes (kg·m²).
    pub inertia_kg_m2: Matrix3<f64>,
}

impl Inertial {
    /// No mass.
    pub const MASSLESS: Self = Self {
        mass_kg: 0.0,
        com_m: Vector3::new(0.0, 0.0, 0.0),
        inertia_kg_m2: Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    };
}

/// A URDF description: its name, links and joints, checked to form one tree.
#[derive(Debug, Clone)]
pub struct UrdfRobot {
    /// The `<robot name>`.
    pub name: String,
    links: Vec<String>,
    /// Per link (as `links`), its `<inertial>`; massless without one.
    inertials: Vec<Inertial>,
    joints: Vec<RawJoint>,
    /// The joint whose child is each link.
    joint_to: HashMap<String, usize>,
    root: String,
}

/// The xacro namespace, as files declare it (with or without `www.`): elements in it are macros a
/// URDF must not contain.
const XACRO_NAMESPACES: [&str; 2] = ["http://ros.org/wiki/xacro", "http://www.ros.org/wiki/xacro"];

fn number(text: &str, what: &str, joint: &str) -> Result<f64, UrdfError> {
    let value: f64 = text.trim().parse().map_err(|_| UrdfError::Joint {
        joint: joint.to_owned(),
        reason: format!("{what} '{text}' is not a number"),
    })?;
    if value.is_finite() {
        Ok(value)
    } else {
        Err(UrdfError::Joint {
            joint: joint.to_owned(),
            reason: format!("{what} '{text}' is not finite"),
        })
    }
}

fn triple(text: &str, what: &str, joint: &str) -> Result<Vector3<f64>, UrdfError> {
    let values: Vec<&str> = text.split_whitespace().collect();
    let [x, y, z] = values.as_slice() else {
        return Err(UrdfError::Joint {
            joint: joint.to_owned(),
            reason: format!("{what} '{text}' is not three finite numbers"),
        });
    };
    let value = |item: &str| {
        number(item, what, joint).map_err(|_| UrdfError::Joint {
            joint: joint.to_owned(),
            reason: format!("{what} '{text}' is not three finite numbers"),
        })
    };
    Ok(Vector3::new(value(x)?, value(y)?, value(z)?))
}

fn child<'a, 'input>(
    node: roxmltree::Node<'a, 'input>,
    name: &str,
) -> Option<roxmltree::Node<'a, 'input>> {
    node.children()
        .find(|c| c.is_element() && c.tag_name().name() == name)
}

/// `<origin xyz rpy>`: `Trans(xyz) · Rz(yaw) · Ry(pitch) · Rx(roll)`; identity when absent.
fn origin_of(joint: roxmltree::Node, name: &str) -> Result<IsometryMatrix3<f64>, UrdfError> {
    let Some(origin) = child(joint, "origin") else {
        return Ok(IsometryMatrix3::identity());
    };
    let xyz = origin
        .attribute("xyz")
        .map_or(Ok(Vector3::zeros()), |t| triple(t, "origin xyz", name))?;
    let rpy = origin
        .attribute("rpy")
        .map_or(Ok(Vector3::zeros()), |t| triple(t, "origin rpy", name))?;
    Ok(IsometryMatrix3::from_parts(
        Translation3::from(xyz),
        Rotation3::from_matrix_unchecked(orientation::matrix_from_rpy(Rpy {
            roll_rad: rpy.x,
            pitch_rad: rpy.y,
            yaw_rad: rpy.z,
        })),
    ))
}

fn parse_joint(node: roxmltree::Node) -> Result<RawJoint, UrdfError> {
    let name = node
        .attribute("name")
        .ok_or_else(|| UrdfError::Naming("a <joint> has no name".to_owned()))?
        .to_owned();
    let fail = |reason: String| UrdfError::Joint {
        joint: name.clone(),
        reason,
    };
    let kind = match node.attribute("type") {
        Some("revolute") => Some(JointKind::Revolute),
        Some("continuous") => Some(JointKind::Continuous),
        Some("prismatic") => Some(JointKind::Prismatic),
        Some("fixed") => None,
        Some(other @ ("floating" | "planar")) => {
            return Err(fail(format!(
                "type '{other}' is not a joint of a serial arm (revolute, continuous, prismatic or fixed)"
            )));
        }
        Some(other) => return Err(fail(format!("unknown joint type '{other}'"))),
        None => return Err(fail("no type".to_owned())),
    };
    let link_of = |element: &str| {
        child(node, element)
            .and_then(|c| c.attribute("link"))
            .map(str::to_owned)
            .ok_or_else(|| fail(format!("no <{element} link=…>")))
    };
    let parent = link_of("parent")?;
    let child_link = link_of("child")?;
    let origin = origin_of(node, &name)?;
    let axis_vector = match child(node, "axis").and_then(|a| a.attribute("xyz")) {
        Some(text) => triple(text, "axis xyz", &name)?,
        None => Vector3::x(),
    };
    // A fixed joint's axis is unused, and real files write `0 0 0` there.
    let axis = match Unit::try_new(axis_vector, 1e-12) {
        Some(axis) => axis,
        None if kind.is_none() => Vector3::x_axis(),
        None => return Err(fail("its axis has no length".to_owned())),
    };
    let limit = child(node, "limit");
    let limit_value = |attribute: &str| -> Result<Option<f64>, UrdfError> {
        limit
            .and_then(|l| l.attribute(attribute))
            .map(|t| number(t, &format!("limit {attribute}"), &name))
            .transpose()
    };
    let (lower, upper) = (limit_value("lower")?, limit_value("upper")?);
    let limits = match kind {
        Some(JointKind::Revolute | JointKind::Prismatic) => {
            if limit.is_none() {
                return Err(fail(format!(
                    "a {} joint needs a <limit>",
                    kind.map_or("", JointKind::as_str)
                )));
            }
            // The URDF's defaults for an absent lower or upper are 0.
            let (min, max) = (lower.unwrap_or(0.0), upper.unwrap_or(0.0));
            if min > max {
                return Err(fail(format!("limit lower {min} is above upper {max}")));
            }
            JointLimits {
                min_rad: Some(min),
                max_rad: Some(max),
            }
        }
        _ => JointLimits::UNLIMITED,
    };
    Ok(RawJoint {
        kind,
        parent,
        child: child_link,
        origin,
        axis,
        limits,
        max_velocity: limit_value("velocity")?,
        max_effort: limit_value("effort")?,
        mimic: child(node, "mimic").is_some(),
        name,
    })
}

/// A link's `<inertial>`: `<origin>` (the centre of mass and the inertia's axes), `<mass value>`
/// and `<inertia ixx ixy ixz iyy iyz izz>`; massless when absent.
fn parse_inertial(link: roxmltree::Node, name: &str) -> Result<Inertial, UrdfError> {
    let Some(inertial) = child(link, "inertial") else {
        return Ok(Inertial::MASSLESS);
    };
    let fail = |reason: String| UrdfError::Link {
        link: name.to_owned(),
        reason,
    };
    // The same readers as a joint's, their errors re-labelled with the link.
    let relabel = |error: UrdfError| match error {
        UrdfError::Joint { reason, .. } => fail(format!("inertial {reason}")),
        other => other,
    };
    let origin = origin_of(inertial, name).map_err(relabel)?;
    let mass_kg = child(inertial, "mass")
        .and_then(|m| m.attribute("value"))
        .ok_or_else(|| fail("<inertial> has no <mass value=…>".to_owned()))
        .and_then(|t| number(t, "mass", name).map_err(relabel))?;
    if mass_kg < 0.0 {
        return Err(fail(format!("mass {mass_kg} is negative")));
    }
    let inertia =
        child(inertial, "inertia").ok_or_else(|| fail("<inertial> has no <inertia>".to_owned()))?;
    let mut moments = [0.0; 6];
    for (value, key) in moments
        .iter_mut()
        .zip(["ixx", "ixy", "ixz", "iyy", "iyz", "izz"])
    {
        let text = inertia
            .attribute(key)
            .ok_or_else(|| fail(format!("<inertia> has no {key}")))?;
        *value = number(text, key, name).map_err(relabel)?;
    }
    let [ixx, ixy, ixz, iyy, iyz, izz] = moments;
    let in_origin_axes = Matrix3::new(ixx, ixy, ixz, ixy, iyy, iyz, ixz, iyz, izz);
    let rotation = origin.rotation.matrix();
    Ok(Inertial {
        mass_kg,
        com_m: origin.translation.vector,
        inertia_kg_m2: rotation * in_origin_axes * rotation.transpose(),
    })
}

/// The first xacro element, or attribute with a `${…}` expression, in the document.
fn xacro_left(document: &roxmltree::Document) -> Option<String> {
    document.descendants().find_map(|node| {
        if node.is_element()
            && node
                .tag_name()
                .namespace()
                .is_some_and(|n| XACRO_NAMESPACES.contains(&n))
        {
            return Some(format!("<xacro:{}>", node.tag_name().name()));
        }
        node.attributes()
            .find(|a| a.value().contains("${") || a.value().contains("$("))
            .map(|a| format!("{}=\"{}\"", a.name(), a.value()))
    })
}

impl UrdfRobot {
    /// Reads a URDF document; fails, naming the element, on anything that is not a tree of links
    /// joined by joints.
    pub fn parse(text: &str) -> Result<Self, UrdfError> {
        if text.len() > MAX_URDF_BYTES {
            return Err(UrdfError::TooLarge { bytes: text.len() });
        }
        let options = roxmltree::ParsingOptions {
            allow_dtd: false,
            nodes_limit: MAX_XML_NODES,
            ..roxmltree::ParsingOptions::default()
        };
        let document = roxmltree::Document::parse_with_options(text, options)
            .map_err(|e| UrdfError::Xml(e.to_string()))?;
        if let Some(found) = xacro_left(&document) {
            return Err(UrdfError::Xacro(found));
        }
        let root = document.root_element();
        if root.tag_name().name() != "robot" {
            return Err(UrdfError::NotARobot(root.tag_name().name().to_owned()));
        }
        let name = root.attribute("name").unwrap_or_default().to_owned();
        let mut links = Vec::new();
        let mut inertials = Vec::new();
        let mut joints = Vec::new();
        for node in root.children().filter(roxmltree::Node::is_element) {
            if links.len() >= MAX_URDF_JOINTS || joints.len() >= MAX_URDF_JOINTS {
                return Err(UrdfError::TooManyElements);
            }
            match node.tag_name().name() {
                "link" => {
                    let link = node
                        .attribute("name")
                        .ok_or_else(|| UrdfError::Naming("a <link> has no name".to_owned()))?;
                    inertials.push(parse_inertial(node, link)?);
                    links.push(link.to_owned());
                }
                "joint" => joints.push(parse_joint(node)?),
                _ => {}
            }
        }
        Self::checked(name, links, inertials, joints)
    }

    /// Checks that the links and joints form one tree, and indexes it.
    fn checked(
        name: String,
        links: Vec<String>,
        inertials: Vec<Inertial>,
        joints: Vec<RawJoint>,
    ) -> Result<Self, UrdfError> {
        let mut known = HashSet::with_capacity(links.len());
        for link in &links {
            if !known.insert(link.as_str()) {
                return Err(UrdfError::Naming(format!("link '{link}' is defined twice")));
            }
        }
        let mut joint_names = HashSet::with_capacity(joints.len());
        let mut joint_to = HashMap::with_capacity(joints.len());
        for (index, joint) in joints.iter().enumerate() {
            if !joint_names.insert(joint.name.as_str()) {
                return Err(UrdfError::Naming(format!(
                    "joint '{}' is defined twice",
                    joint.name
                )));
            }
            for link in [&joint.parent, &joint.child] {
                if !known.contains(link.as_str()) {
                    return Err(UrdfError::Joint {
                        joint: joint.name.clone(),
                        reason: format!("link '{link}' is not defined"),
                    });
                }
            }
            if let Some(other) = joint_to.insert(joint.child.clone(), index) {
                return Err(UrdfError::Tree(format!(
                    "link '{}' is the child of two joints, '{}' and '{}'",
                    joint.child, joints[other].name, joint.name
                )));
            }
        }
        let roots: Vec<&String> = links
            .iter()
            .filter(|l| !joint_to.contains_key(*l))
            .collect();
        let root = match roots.as_slice() {
            [root] => (*root).clone(),
            [] => {
                return Err(UrdfError::Tree(
                    "the links form a loop: no root link".to_owned(),
                ));
            }
            more => {
                return Err(UrdfError::Tree(format!(
                    "the links form {} trees, not one: roots {}",
                    more.len(),
                    quoted(more.iter().map(|s| s.as_str()))
                )));
            }
        };
        let robot = Self {
            name,
            links,
            inertials,
            joints,
            joint_to,
            root,
        };
        // Every link reaches the root: with one root and one parent each, only a loop apart from
        // the root could fail that. One walk down from the root finds it, in the tree's size.
        let reached: HashSet<&str> = robot.links_from_root().into_iter().collect();
        if let Some(on_loop) = robot.links.iter().find(|l| !reached.contains(l.as_str())) {
            return Err(UrdfError::Tree(format!("link '{on_loop}' is on a loop")));
        }
        Ok(robot)
    }

    /// Every link reachable from the root, parents before children (breadth first).
    fn links_from_root(&self) -> Vec<&str> {
        let mut children: HashMap<&str, Vec<&str>> = HashMap::new();
        for joint in &self.joints {
            children
                .entry(joint.parent.as_str())
                .or_default()
                .push(joint.child.as_str());
        }
        let mut order = vec![self.root.as_str()];
        let mut next = 0;
        while let Some(&link) = order.get(next) {
            next += 1;
            order.extend(children.get(link).map_or(&[][..], Vec::as_slice));
        }
        order
    }

    /// Each link's index by its name.
    fn link_indices(&self) -> HashMap<&str, usize> {
        self.links
            .iter()
            .enumerate()
            .map(|(index, link)| (link.as_str(), index))
            .collect()
    }

    /// The joints from the root to `link`, root first.
    fn path_to_root(&self, link: &str) -> Result<Vec<usize>, UrdfError> {
        let mut path = Vec::new();
        let mut at = link;
        while let Some(&index) = self.joint_to.get(at) {
            if path.len() > self.joints.len() {
                return Err(UrdfError::Tree(format!("link '{link}' is on a loop")));
            }
            path.push(index);
            at = &self.joints[index].parent;
        }
        path.reverse();
        Ok(path)
    }

    /// The root link: the one no joint has as its child.
    #[must_use]
    pub fn root_link(&self) -> &str {
        &self.root
    }

    /// The links no joint has as its parent, in the file's order.
    #[must_use]
    pub fn leaf_links(&self) -> Vec<&str> {
        let parents: HashSet<&str> = self.joints.iter().map(|j| j.parent.as_str()).collect();
        self.links
            .iter()
            .map(String::as_str)
            .filter(|l| !parents.contains(l))
            .collect()
    }

    /// The serial chain from `base_link` (default: the root) to `tip_link` (default: the one
    /// leaf; an error names the leaves when there are several).
    pub fn chain(
        &self,
        base_link: Option<&str>,
        tip_link: Option<&str>,
    ) -> Result<UrdfChain, UrdfError> {
        let base = base_link.unwrap_or(&self.root);
        let tip = match tip_link {
            Some(tip) => tip,
            None => match self.leaf_links().as_slice() {
                [leaf] => leaf,
                leaves => {
                    return Err(UrdfError::Chain(format!(
                        "the URDF has {} leaf links ({}): name the tip link",
                        leaves.len(),
                        quoted(leaves.iter().copied())
                    )));
                }
            },
        };
        for link in [base, tip] {
            if !self.links.iter().any(|l| l == link) {
                return Err(UrdfError::Chain(format!(
                    "link '{link}' is not in the URDF"
                )));
            }
        }
        let to_tip = self.path_to_root(tip)?;
        let to_base = self.path_to_root(base)?;
        if !to_tip.starts_with(&to_base) {
            return Err(UrdfError::Chain(format!(
                "link '{base}' is not between the root and '{tip}': no chain from it to '{tip}'"
            )));
        }
        let mut joints = Vec::new();
        let mut pending = IsometryMatrix3::identity();
        for &index in &to_tip[to_base.len()..] {
            let joint = &self.joints[index];
            let parent_from_joint = pending * joint.origin;
            match joint.kind {
                None => pending = parent_from_joint,
                Some(kind) => {
                    if joint.mimic {
                        return Err(UrdfError::Joint {
                            joint: joint.name.clone(),
                            reason:
                                "mimics another joint: mimic joints on the chain are not supported"
                                    .to_owned(),
                        });
                    }
                    joints.push(ChainJoint {
                        name: joint.name.clone(),
                        kind,
                        parent_from_joint,
                        axis: joint.axis,
                        limits: joint.limits,
                        max_velocity: joint.max_velocity,
                        max_effort: joint.max_effort,
                    });
                    pending = IsometryMatrix3::identity();
                }
            }
        }
        Ok(UrdfChain {
            base_link: base.to_owned(),
            tip_link: tip.to_owned(),
            joints,
            last_from_tip: pending,
        })
    }
}

/// The arm of the chain from `base_link` to `tip_link` (defaults as [`UrdfRobot::chain`]) of the
/// URDF `text`, read from `source_name`: named after the `<robot>`.
pub fn arm_from_urdf(
    text: &str,
    source_name: &str,
    base_link: Option<&str>,
    tip_link: Option<&str>,
) -> Result<ArmDescription, super::ModelError> {
    let arm = UrdfRobot::parse(text).and_then(|robot| {
        let chain = robot.chain(base_link, tip_link)?;
        chain.arm_description(&robot)
    });
    arm.map_err(|error| super::ModelError::Urdf {
        source_name: source_name.to_owned(),
        reason: error.to_string(),
    })
}

/// The inertials of `chain`'s arm, whose joint frames are `parent_from_joint` (each in the
/// previous one, the first in the base link; z along the joint's axis): per joint, every body it
/// carries that no later joint of the chain carries, lumped into one body in its frame. That
/// takes in links past the tip and side branches (a hand's fingers, a head), their own joints
/// held at zero: the torques are then the whole tree's with those joints at zero and at rest.
/// `None` when the chain carries no mass (a description for kinematics only). The drives' largest
/// torques are the joints' `<limit effort>` where every joint states one; gravity is standard
/// gravity along the root link's −z, in the base link's frame.
fn lumped_inertials(
    robot: &UrdfRobot,
    chain: &UrdfChain,
    parent_from_joint: &[IsometryMatrix3<f64>],
) -> Option<ArmInertials> {
    let chain_index = chain.joint_indices();
    let link_index = robot.link_indices();
    // Every link's pose in the root at zero, and the last joint of the chain on its way there.
    let mut placed: HashMap<&str, (IsometryMatrix3<f64>, Option<usize>)> =
        HashMap::with_capacity(robot.links.len());
    let mut carried: Vec<Vec<(IsometryMatrix3<f64>, Inertial)>> =
        vec![Vec::new(); chain.joints.len()];
    for link in robot.links_from_root() {
        let (root_from_link, owner) = match robot.joint_to.get(link) {
            None => (IsometryMatrix3::identity(), None),
            Some(&joint_index) => {
                let joint = &robot.joints[joint_index];
                let (root_from_parent, parent_owner) = placed[joint.parent.as_str()];
                (
                    root_from_parent * joint.origin,
                    chain_index
                        .get(joint.name.as_str())
                        .copied()
                        .or(parent_owner),
                )
            }
        };
        placed.insert(link, (root_from_link, owner));
        if let Some(owner) = owner {
            carried[owner].push((root_from_link, robot.inertials[link_index[link]]));
        }
    }
    let root_from_base = placed
        .get(chain.base_link.as_str())
        .map_or_else(IsometryMatrix3::identity, |(pose, _)| *pose);
    let mut root_from_joint = root_from_base;
    let mut links = Vec::with_capacity(chain.joints.len());
    for (bodies, joint_origin) in carried.iter().zip(parent_from_joint) {
        root_from_joint *= joint_origin;
        let joint_from_root = root_from_joint.inverse();
        links.push(lumped(bodies.iter().map(|(root_from_link, inertial)| {
            let joint_from_link = joint_from_root * root_from_link;
            let rotation = joint_from_link.rotation.matrix();
            PlacedBody {
                mass_kg: inertial.mass_kg,
                com_m: joint_from_link * nalgebra::Point3::from(inertial.com_m),
                inertia_kg_m2: rotation * inertial.inertia_kg_m2 * rotation.transpose(),
            }
        })));
    }
    if links
        .iter()
        .all(|link| link.mass_kg <= 0.0 && link.inertia_com_kg_m2.iter().all(|v| *v == 0.0))
    {
        return None;
    }
    let max_torque_nm: Option<Vec<f64>> = chain
        .joints
        .iter()
        .map(|joint| joint.max_effort.filter(|effort| *effort > 0.0))
        .collect();
    let gravity =
        root_from_base.rotation.inverse() * Vector3::new(0.0, 0.0, -STANDARD_GRAVITY_M_S2);
    Some(ArmInertials {
        links,
        reflected_rotor_inertia_kg_m2: vec![0.0; chain.joints.len()],
        max_torque_nm,
        gravity_base_m_s2: Some(gravity.into()),
    })
}

/// A body by its centre of mass (a point in some frame) and its inertia about it in that frame's
/// axes.
struct PlacedBody {
    mass_kg: f64,
    com_m: nalgebra::Point3<f64>,
    inertia_kg_m2: Matrix3<f64>,
}

/// Bodies fixed to one another as one: their total mass, its centre, and the inertia about it
/// (parallel axis theorem).
fn lumped(bodies: impl Iterator<Item = PlacedBody>) -> LinkInertial {
    let bodies: Vec<PlacedBody> = bodies.collect();
    let mass_kg: f64 = bodies.iter().map(|b| b.mass_kg).sum();
    // Massless bodies may still state an inertia (a rotor's): it adds, wherever its centre.
    let com = if mass_kg > 0.0 {
        bodies
            .iter()
            .fold(Vector3::zeros(), |sum, b| sum + b.com_m.coords * b.mass_kg)
            / mass_kg
    } else {
        Vector3::zeros()
    };
    let inertia = bodies.iter().fold(Matrix3::zeros(), |sum, b| {
        let offset = b.com_m.coords - com;
        sum + b.inertia_kg_m2
            + (Matrix3::identity() * offset.norm_squared() - offset * offset.transpose())
                * b.mass_kg
    });
    LinkInertial {
        mass_kg,
        com_link_m: com.into(),
        inertia_com_kg_m2: [
            inertia[(0, 0)],
            inertia[(1, 1)],
            inertia[(2, 2)],
            inertia[(0, 1)],
            inertia[(0, 2)],
            inertia[(1, 2)],
        ],
    }
}

fn quoted<'a>(names: impl Iterator<Item = &'a str>) -> String {
    names
        .map(|n| format!("'{n}'"))
        .collect::<Vec<_>>()
        .join(", ")
}

impl UrdfChain {
    /// The chain as an arm the twin runs, named after `robot` (the URDF it is a chain of), with no
    /// DH table: each joint's axis turned onto its frame's z by a fixed rotation folded into its
    /// origin and undone in the next one. Its inertials are every body each joint carries, lumped
    /// into that joint's link (see [`lumped_inertials`]). Prismatic joints are refused: the
    /// twin's joints turn.
    pub fn arm_description(&self, robot: &UrdfRobot) -> Result<ArmDescription, UrdfError> {
        let mut parent_from_joint = Vec::with_capacity(self.joints.len());
        let mut undo_previous = Rotation3::identity();
        for joint in &self.joints {
            if joint.kind == JointKind::Prismatic {
                return Err(UrdfError::Joint {
                    joint: joint.name.clone(),
                    reason: "is prismatic: the live twin takes chains of revolute and continuous joints (`armtwin fk` and `armtwin torques` take prismatic ones)".to_owned(),
                });
            }
            // The rotation taking z onto the axis; a half turn about x for −z.
            let onto_axis = Rotation3::rotation_between(&Vector3::z(), &joint.axis)
                .unwrap_or_else(|| Rotation3::from_axis_angle(&Vector3::x_axis(), PI));
            parent_from_joint.push(undo_previous * joint.parent_from_joint * onto_axis);
            undo_previous = onto_axis.inverse();
        }
        let inertials = lumped_inertials(robot, self, &parent_from_joint);
        Ok(ArmDescription {
            name: robot.name.clone(),
            convention: DhConvention::Standard,
            dh: Vec::new(),
            joint_limits: self.joints.iter().map(|j| j.limits).collect(),
            inertials,
            joint_origins: Some(JointOrigins {
                parent_from_joint,
                last_from_flange: undo_previous * self.last_from_tip,
            }),
        })
    }

    /// Each moving joint's index (base to tip) by its name.
    fn joint_indices(&self) -> HashMap<&str, usize> {
        self.joints
            .iter()
            .enumerate()
            .map(|(index, joint)| (joint.name.as_str(), index))
            .collect()
    }

    /// The number of moving joints.
    #[must_use]
    pub fn joint_count(&self) -> usize {
        self.joints.len()
    }

    /// The tip link's pose in the base link's frame at `q` (rad, or m for prismatic joints),
    /// base to tip. Limits are not checked: a twin follows the robot wherever it reports.
    pub fn pose(&self, q: &[f64]) -> Result<Pose, UrdfError> {
        if q.len() != self.joints.len() {
            return Err(UrdfError::JointCount {
                expected: self.joints.len(),
                got: q.len(),
            });
        }
        let mut base_from = IsometryMatrix3::identity();
        for (joint, &value) in self.joints.iter().zip(q) {
            if !value.is_finite() {
                return Err(UrdfError::NotFinite(joint.name.clone()));
            }
            let motion = match joint.kind {
                JointKind::Revolute | JointKind::Continuous => IsometryMatrix3::from_parts(
                    Translation3::identity(),
                    Rotation3::from_axis_angle(&joint.axis, value),
                ),
                JointKind::Prismatic => IsometryMatrix3::from_parts(
                    Translation3::from(joint.axis.into_inner() * value),
                    Rotation3::identity(),
                ),
            };
            base_from = base_from * joint.parent_from_joint * motion;
        }
        let base_from_tip = base_from * self.last_from_tip;
        Ok(Pose {
            position_m: base_from_tip.translation.vector,
            rotation: *base_from_tip.rotation.matrix(),
        })
    }
}

mod dynamics;
mod export;
pub use dynamics::{STANDARD_GRAVITY_M_S2, UrdfDynamics};
pub use export::{ModelFrames, model_urdf};

#[cfg(test)]
mod tests;
