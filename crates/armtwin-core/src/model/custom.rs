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
//! ```

use serde::Deserialize;

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
    Ok(ArmDescription {
        name: file.name,
        convention: match file.convention {
            ConventionName::Standard => DhConvention::Standard,
            ConventionName::Modified => DhConvention::Modified,
        },
        dh,
        joint_limits,
    })
}
