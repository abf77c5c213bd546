//! Custom arms from a TOML description: a standard or modified (Craig) DH table with any number
//! of revolute joints.
//!
//! ```toml
//! name = "my-arm"
//! convention = "standard"   # or "modified" (Craig: row i holds a(i-1), alpha(i-1), d(i), theta(i))
//! angle_unit = "rad"        # or "deg": applies to alpha, theta_offset, min and max
//!
//! [[joints]]
//! a = 0.0                   # metres
//! alpha = 1.5707963267948966
//! d = 0.1807                # metres
//! theta_offset = 0.0        # optional, default 0
//! min = -6.283185307179586  # optional, default unlimited
//! max = 6.283185307179586   # optional, default unlimited
//!
//! # Optional, for inverse dynamics: one entry per joint, base to flange, in the DH link frame of
//! # `convention` (standard: the frame at the link's distal joint, the last one the flange;
//! # modified: the frame at the link's own joint). Lengths in metres whatever `angle_unit` says.
//! [[dynamics.links]]
//! mass = 7.369                      # kg
//! com = [0.021, 0.0, 0.027]         # centre of mass (m)
//! inertia = [0.034, 0.035, 0.022]   # optional, about the centre of mass (kg·m²): Ixx, Iyy, Izz
//!                                   # or Ixx, Iyy, Izz, Ixy, Ixz, Iyz; default 0 (a point mass)
//! rotor_inertia = 6.02              # optional: the drive's rotor inertia × gear ratio² (kg·m²)
//! ```

use serde::Deserialize;

use super::inertia::{ArmInertials, LinkInertial};
use super::{ArmDescription, JointLimits, ModelError};
use crate::kinematics::{DhConvention, DhParameters};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ArmFile {
    name: String,
    convention: ConventionName,
    #[serde(default)]
    angle_unit: AngleUnit,
    joints: Vec<JointRow>,
    dynamics: Option<DynamicsSection>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct DynamicsSection {
    links: Vec<LinkRow>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LinkRow {
    mass: f64,
    com: [f64; 3],
    #[serde(default)]
    inertia: Vec<f64>,
    #[serde(default)]
    rotor_inertia: f64,
}

#[derive(Debug, Deserialize)]
#[serde(rename_all = "lowercase")]
enum ConventionName {
    Standard,
    Modified,
}

#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
enum AngleUnit {
    #[default]
    Rad,
    Deg,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct JointRow {
    a: f64,
    alpha: f64,
    d: f64,
    #[serde(default)]
    theta_offset: f64,
    min: Option<f64>,
    max: Option<f64>,
}

/// Parses a custom arm description (TOML text) named `source_name` in messages.
pub fn parse_arm(text: &str, source_name: &str) -> Result<ArmDescription, ModelError> {
    let invalid = |reason: String| ModelError::CustomArm {
        source_name: source_name.to_owned(),
        reason,
    };
    let file: ArmFile = toml::from_str(text).map_err(|e| invalid(e.to_string()))?;
    if file.joints.is_empty() {
        return Err(invalid(
            "joints: an arm needs at least one joint".to_owned(),
        ));
    }
    let to_rad = |angle: f64| match file.angle_unit {
        AngleUnit::Rad => angle,
        AngleUnit::Deg => angle.to_radians(),
    };
    let mut dh = Vec::with_capacity(file.joints.len());
    let mut joint_limits = Vec::with_capacity(file.joints.len());
    for (index, row) in file.joints.iter().enumerate() {
        let joint = index + 1;
        let fields = [
            ("a", Some(row.a)),
            ("alpha", Some(row.alpha)),
            ("d", Some(row.d)),
            ("theta_offset", Some(row.theta_offset)),
            ("min", row.min),
            ("max", row.max),
        ];
        if let Some((field, value)) = fields
            .iter()
            .find_map(|(field, value)| value.filter(|v| !v.is_finite()).map(|v| (field, v)))
        {
            return Err(invalid(format!(
                "joints[{joint}].{field}: {value} is not finite"
            )));
        }
        if let (Some(min), Some(max)) = (row.min, row.max)
            && min > max
        {
            return Err(invalid(format!(
                "joints[{joint}]: min {min} is above max {max}"
            )));
        }
        dh.push(DhParameters {
            a_m: row.a,
            alpha_rad: to_rad(row.alpha),
            d_m: row.d,
            theta_offset_rad: to_rad(row.theta_offset),
        });
        joint_limits.push(JointLimits {
            min_rad: row.min.map(to_rad),
            max_rad: row.max.map(to_rad),
        });
    }
    let inertials = file
        .dynamics
        .as_ref()
        .map(|section| parse_inertials(section, file.joints.len()))
        .transpose()
        .map_err(invalid)?;
    Ok(ArmDescription {
        name: file.name,
        convention: match file.convention {
            ConventionName::Standard => DhConvention::Standard,
            ConventionName::Modified => DhConvention::Modified,
        },
        dh,
        joint_limits,
        inertials,
        joint_origins: None,
    })
}

/// The `[dynamics]` section of an arm with `joint_count` joints, or what is wrong with it.
fn parse_inertials(section: &DynamicsSection, joint_count: usize) -> Result<ArmInertials, String> {
    if section.links.len() != joint_count {
        return Err(format!(
            "dynamics.links: {} entries for {joint_count} joints",
            section.links.len()
        ));
    }
    let mut links = Vec::with_capacity(joint_count);
    let mut reflected_rotor_inertia_kg_m2 = Vec::with_capacity(joint_count);
    for (index, row) in section.links.iter().enumerate() {
        let link = index + 1;
        let inertia_com_kg_m2 = match row.inertia[..] {
            [] => [0.0; 6],
            [ixx, iyy, izz] => [ixx, iyy, izz, 0.0, 0.0, 0.0],
            [ixx, iyy, izz, ixy, ixz, iyz] => [ixx, iyy, izz, ixy, ixz, iyz],
            _ => {
                return Err(format!(
                    "dynamics.links[{link}].inertia: {} values; give 3 (Ixx, Iyy, Izz) or 6 \
                     (Ixx, Iyy, Izz, Ixy, Ixz, Iyz)",
                    row.inertia.len()
                ));
            }
        };
        let mut values = [row.mass, row.rotor_inertia]
            .into_iter()
            .chain(row.com)
            .chain(inertia_com_kg_m2);
        if let Some(value) = values.find(|v| !v.is_finite()) {
            return Err(format!("dynamics.links[{link}]: {value} is not finite"));
        }
        let must_be_non_negative = [
            ("mass", row.mass),
            ("rotor_inertia", row.rotor_inertia),
            ("inertia[1]", inertia_com_kg_m2[0]),
            ("inertia[2]", inertia_com_kg_m2[1]),
            ("inertia[3]", inertia_com_kg_m2[2]),
        ];
        if let Some((field, value)) = must_be_non_negative.iter().find(|(_, v)| *v < 0.0) {
            return Err(format!(
                "dynamics.links[{link}].{field}: {value} is negative"
            ));
        }
        links.push(LinkInertial {
            mass_kg: row.mass,
            com_link_m: row.com,
            inertia_com_kg_m2,
        });
        reflected_rotor_inertia_kg_m2.push(row.rotor_inertia);
    }
    Ok(ArmInertials {
        links,
        reflected_rotor_inertia_kg_m2,
        max_torque_nm: None,
        gravity_base_m_s2: None,
    })
}
