//! A robot's own factory kinematic calibration, in the two forms Universal Robots users have, and
//! how it turns a nominal arm into that robot's chain.
//!
//! 1. The controller's `calibration.conf` (from `/root/.urcontrol/` on the robot): INI-like, whose
//!    `[mounting]` section carries `delta_theta`, `delta_a`, `delta_d`, `delta_alpha`, six values
//!    each in SI units, applied to the nominal standard-DH table as `θᵢ = qᵢ + δθᵢ`,
//!    `dᵢ = dᵢ + δdᵢ`, `aᵢ = aᵢ + δaᵢ`, `αᵢ = αᵢ + δαᵢ`. Real files carry δd of hundreds of metres
//!    on joints 2–4 (nearly parallel axes put the DH common normals far away); they cancel, and
//!    f64 keeps the pose accurate far below a micrometre.
//! 2. The YAML written by ROS `ur_calibration`: `kinematics:` with `shoulder`, `upper_arm`,
//!    `forearm`, `wrist_1`, `wrist_2`, `wrist_3`, each `x y z roll pitch yaw` (the URDF joint
//!    origin, `Trans(x, y, z) · Rz(yaw) · Ry(pitch) · Rx(roll)`), and `hash`. The pose is
//!    `O₁ · Rz(q₁) · … · O₆ · Rz(q₆)`; the URDF's fixed `wrist_3_link → flange → tool0` transforms
//!    compose to the identity, so the flange is the last joint frame, as in DH.
//!
//! Parses text handed in by the caller; errors name the source, the field and the problem.

use std::fmt;

use nalgebra::{IsometryMatrix3, Rotation3, Translation3, Vector3};
use thiserror::Error;
use yaml_rust2::{Yaml, YamlLoader};

use super::{ArmDescription, ModelError};
use crate::kinematics::{Chain, DhConvention, DhParameters};
use crate::orientation::{Rpy, matrix_from_rpy};

/// Segment names of the `ur_calibration` YAML, base to flange.
pub const YAML_SEGMENTS: [&str; 6] = [
    "shoulder",
    "upper_arm",
    "forearm",
    "wrist_1",
    "wrist_2",
    "wrist_3",
];

/// Keys of each YAML segment.
const YAML_SEGMENT_KEYS: [&str; 6] = ["x", "y", "z", "roll", "pitch", "yaw"];

/// Keys of the `[mounting]` section that armtwin reads.
const CONF_KEYS: [&str; 4] = ["delta_theta", "delta_a", "delta_d", "delta_alpha"];

/// A calibration with the name of the file it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// Where it came from (a file path), for messages and the service's state.
    pub source_name: String,
    /// The calibration itself.
    pub form: CalibrationForm,
}

/// The two forms of a UR calibration.
#[derive(Debug, Clone, PartialEq)]
pub enum CalibrationForm {
    /// `calibration.conf` `[mounting]` deltas to the nominal standard-DH table.
    MountingDeltas(MountingDeltas),
    /// `ur_calibration` YAML: one URDF joint origin per joint (replaces the nominal geometry).
    JointOrigins {
        /// `parent_from_joint` for each of the six joints.
        parent_from_joint: Vec<IsometryMatrix3<f64>>,
        /// The file's `hash` entry, if present.
        hash: Option<String>,
    },
}

/// The four delta vectors of `calibration.conf`, one value per joint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MountingDeltas {
    /// `delta_theta` (rad).
    pub delta_theta_rad: [f64; 6],
    /// `delta_a` (m).
    pub delta_a_m: [f64; 6],
    /// `delta_d` (m).
    pub delta_d_m: [f64; 6],
    /// `delta_alpha` (rad).
    pub delta_alpha_rad: [f64; 6],
}

impl MountingDeltas {
    /// All deltas zero: the nominal arm.
    pub const ZERO: Self = Self {
        delta_theta_rad: [0.0; 6],
        delta_a_m: [0.0; 6],
        delta_d_m: [0.0; 6],
        delta_alpha_rad: [0.0; 6],
    };

    /// The text of a `calibration.conf` holding these deltas in its `[mounting]` section, with
    /// `comment` lines (each prefixed `# `) above. Values are written with the shortest digits
    /// that read back to the same `f64`, so [`Calibration::parse_conf`] returns these deltas
    /// exactly.
    #[must_use]
    pub fn to_conf_text(&self, comment: &str) -> String {
        let list = |values: &[f64; 6]| {
            let items: Vec<String> = values.iter().map(|v| format!("{v:?}")).collect();
            format!("[ {} ]", items.join(", "))
        };
        let mut text = String::new();
        for line in comment.lines() {
            text.push_str("# ");
            text.push_str(line);
            text.push('\n');
        }
        text.push_str("[mounting]\n");
        for (key, values) in CONF_KEYS.iter().zip([
            &self.delta_theta_rad,
            &self.delta_a_m,
            &self.delta_d_m,
            &self.delta_alpha_rad,
        ]) {
            text.push_str(key);
            text.push_str(" = ");
            text.push_str(&list(values));
            text.push('\n');
        }
        text
    }

    /// The nominal table with these deltas added.
    #[must_use]
    pub fn apply(&self, nominal: &[DhParameters]) -> Vec<DhParameters> {
        nominal
            .iter()
            .enumerate()
            .map(|(i, row)| DhParameters {
                a_m: row.a_m + self.delta_a_m[i],
                alpha_rad: row.alpha_rad + self.delta_alpha_rad[i],
                d_m: row.d_m + self.delta_d_m[i],
                theta_offset_rad: row.theta_offset_rad + self.delta_theta_rad[i],
            })
            .collect()
    }
}

/// Why a calibration file cannot be used: `source: field: problem`.
#[derive(Debug, Clone, PartialEq, Error)]
#[error("{source_name}: {field}: {problem}")]
pub struct CalibrationError {
    /// The file.
    pub source_name: String,
    /// The field (`[mounting] delta_d`, `kinematics.wrist_2.roll`, or `file` for the whole file).
    pub field: String,
    /// What is wrong.
    pub problem: CalibrationProblem,
}

/// What is wrong with a calibration field.
#[derive(Debug, Clone, PartialEq)]
pub enum CalibrationProblem {
    /// The field is absent.
    Missing,
    /// The field appears twice.
    Duplicate {
        /// 1-based line of the second occurrence.
        line: usize,
    },
    /// A list has the wrong number of values.
    WrongCount {
        /// Values required.
        expected: usize,
        /// Values found.
        got: usize,
    },
    /// A value does not parse as a number.
    NotANumber {
        /// The text found.
        text: String,
    },
    /// A value is NaN or infinite.
    NonFinite,
    /// The text is not in the expected syntax.
    Syntax {
        /// What was expected or found.
        detail: String,
    },
}

impl fmt::Display for CalibrationProblem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Missing => write!(f, "missing"),
            Self::Duplicate { line } => write!(f, "given a second time on line {line}"),
            Self::WrongCount { expected, got } => {
                write!(f, "expected {expected} values (one per joint), got {got}")
            }
            Self::NotANumber { text } => write!(f, "'{text}' is not a number"),
            Self::NonFinite => write!(f, "value is not finite"),
            Self::Syntax { detail } => write!(f, "{detail}"),
        }
    }
}

fn error(
    source_name: &str,
    field: impl Into<String>,
    problem: CalibrationProblem,
) -> CalibrationError {
    CalibrationError {
        source_name: source_name.to_owned(),
        field: field.into(),
        problem,
    }
}

impl Calibration {
    /// Parses either form: YAML when the text has a top-level `kinematics:` key, otherwise
    /// `calibration.conf`.
    pub fn parse(text: &str, source_name: &str) -> Result<Self, CalibrationError> {
        let looks_like_yaml = text
            .lines()
            .any(|line| line.trim_end().starts_with("kinematics:"));
        if looks_like_yaml {
            Self::parse_yaml(text, source_name)
        } else {
            Self::parse_conf(text, source_name)
        }
    }

    /// Parses the controller's `calibration.conf`.
    pub fn parse_conf(text: &str, source_name: &str) -> Result<Self, CalibrationError> {
        let mut section = String::new();
        let mut found: [Option<[f64; 6]>; 4] = [None; 4];
        let mut saw_mounting = false;
        let mut lines = text.lines().enumerate();
        while let Some((index, raw)) = lines.next() {
            let line = raw.trim();
            if line.is_empty() || line.starts_with('#') || line.starts_with(';') {
                continue;
            }
            if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
                name.trim().clone_into(&mut section);
                saw_mounting |= section == "mounting";
                continue;
            }
            let Some((key, value)) = line.split_once('=') else {
                return Err(error(
                    source_name,
                    format!("line {}", index + 1),
                    CalibrationProblem::Syntax {
                        detail: format!("expected 'name = value' or '[section]', found '{line}'"),
                    },
                ));
            };
            let key = key.trim();
            let Some(slot) = CONF_KEYS.iter().position(|k| *k == key) else {
                continue;
            };
            if section != "mounting" {
                continue;
            }
            // A list may continue over several lines until its closing bracket.
            let mut value = value.trim().to_owned();
            while value.starts_with('[') && !value.contains(']') {
                match lines.next() {
                    Some((_, more)) => value.push_str(more.trim()),
                    None => break,
                }
            }
            let field = format!("[mounting] {key}");
            if found[slot].is_some() {
                return Err(error(
                    source_name,
                    field,
                    CalibrationProblem::Duplicate { line: index + 1 },
                ));
            }
            found[slot] = Some(parse_list(&value, source_name, &field)?);
        }
        if !saw_mounting {
            return Err(error(
                source_name,
                "[mounting]",
                CalibrationProblem::Missing,
            ));
        }
        let take = |slot: usize| {
            found[slot].ok_or_else(|| {
                error(
                    source_name,
                    format!("[mounting] {}", CONF_KEYS[slot]),
                    CalibrationProblem::Missing,
                )
            })
        };
        Ok(Self {
            source_name: source_name.to_owned(),
            form: CalibrationForm::MountingDeltas(MountingDeltas {
                delta_theta_rad: take(0)?,
                delta_a_m: take(1)?,
                delta_d_m: take(2)?,
                delta_alpha_rad: take(3)?,
            }),
        })
    }

    /// Parses the YAML written by ROS `ur_calibration`.
    pub fn parse_yaml(text: &str, source_name: &str) -> Result<Self, CalibrationError> {
        let documents = YamlLoader::load_from_str(text).map_err(|scan| {
            error(
                source_name,
                "file",
                CalibrationProblem::Syntax {
                    detail: format!("not valid YAML: {scan}"),
                },
            )
        })?;
        let root = documents.first().unwrap_or(&Yaml::BadValue);
        let kinematics = &root["kinematics"];
        if kinematics.as_hash().is_none() {
            return Err(error(
                source_name,
                "kinematics",
                CalibrationProblem::Missing,
            ));
        }
        let mut parent_from_joint = Vec::with_capacity(YAML_SEGMENTS.len());
        for segment in YAML_SEGMENTS {
            let node = &kinematics[segment];
            if node.as_hash().is_none() {
                return Err(error(
                    source_name,
                    format!("kinematics.{segment}"),
                    CalibrationProblem::Missing,
                ));
            }
            let mut values = [0.0; 6];
            for (value, key) in values.iter_mut().zip(YAML_SEGMENT_KEYS) {
                let field = format!("kinematics.{segment}.{key}");
                *value = yaml_number(&node[key])
                    .map_err(|problem| error(source_name, field.clone(), problem))?;
            }
            let [x, y, z, roll, pitch, yaw] = values;
            let rotation = matrix_from_rpy(Rpy {
                roll_rad: roll,
                pitch_rad: pitch,
                yaw_rad: yaw,
            });
            parent_from_joint.push(IsometryMatrix3::from_parts(
                Translation3::from(Vector3::new(x, y, z)),
                Rotation3::from_matrix_unchecked(rotation),
            ));
        }
        let hash = match &kinematics["hash"] {
            Yaml::String(hash) => Some(hash.clone()),
            _ => None,
        };
        Ok(Self {
            source_name: source_name.to_owned(),
            form: CalibrationForm::JointOrigins {
                parent_from_joint,
                hash,
            },
        })
    }

    /// Which form this is: `calibration.conf` or `ur_calibration yaml`.
    #[must_use]
    pub fn form_name(&self) -> &'static str {
        match self.form {
            CalibrationForm::MountingDeltas(_) => "calibration.conf",
            CalibrationForm::JointOrigins { .. } => "ur_calibration yaml",
        }
    }

    /// The calibrated flange chain of `arm` (output frame and tool not yet attached).
    pub fn chain_for(&self, arm: &ArmDescription) -> Result<Chain, ModelError> {
        let mismatch = |reason: String| ModelError::CalibrationMismatch {
            source_name: self.source_name.clone(),
            reason,
        };
        if arm.dh.len() != 6 {
            return Err(mismatch(format!(
                "a UR calibration has 6 joints, but arm '{}' has {}",
                arm.name,
                arm.dh.len()
            )));
        }
        match &self.form {
            CalibrationForm::MountingDeltas(deltas) => {
                if arm.convention != DhConvention::Standard {
                    return Err(mismatch(format!(
                        "calibration.conf deltas apply to a standard-DH table, but arm '{}' is {}",
                        arm.name,
                        arm.convention.as_str()
                    )));
                }
                Ok(Chain::from_dh(
                    DhConvention::Standard,
                    &deltas.apply(&arm.dh),
                ))
            }
            CalibrationForm::JointOrigins {
                parent_from_joint, ..
            } => Ok(Chain::from_joint_origins(parent_from_joint)),
        }
    }
}

/// `[ v1, v2, … ]` with exactly six finite numbers.
fn parse_list(value: &str, source_name: &str, field: &str) -> Result<[f64; 6], CalibrationError> {
    let inner = value
        .strip_prefix('[')
        .and_then(|v| v.strip_suffix(']'))
        .ok_or_else(|| {
            error(
                source_name,
                field,
                CalibrationProblem::Syntax {
                    detail: format!("expected a list '[ v1, v2, ... ]', found '{value}'"),
                },
            )
        })?;
    let items: Vec<&str> = inner
        .split(',')
        .map(str::trim)
        .filter(|item| !item.is_empty())
        .collect();
    if items.len() != 6 {
        return Err(error(
            source_name,
            field,
            CalibrationProblem::WrongCount {
                expected: 6,
                got: items.len(),
            },
        ));
    }
    let mut values = [0.0; 6];
    for (slot, item) in values.iter_mut().zip(&items) {
        let number: f64 = item.parse().map_err(|_| {
            error(
                source_name,
                field,
                CalibrationProblem::NotANumber {
                    text: (*item).to_owned(),
                },
            )
        })?;
        if !number.is_finite() {
            return Err(error(source_name, field, CalibrationProblem::NonFinite));
        }
        *slot = number;
    }
    Ok(values)
}

fn yaml_number(node: &Yaml) -> Result<f64, CalibrationProblem> {
    let number = match node {
        // `as_f64` also reads YAML's `.nan` and `.inf` spellings, rejected just below.
        Yaml::Real(text) => node
            .as_f64()
            .ok_or_else(|| CalibrationProblem::NotANumber { text: text.clone() })?,
        Yaml::Integer(i) => *i as f64,
        Yaml::BadValue | Yaml::Null => return Err(CalibrationProblem::Missing),
        Yaml::String(text) => {
            return Err(CalibrationProblem::NotANumber { text: text.clone() });
        }
        other => {
            return Err(CalibrationProblem::NotANumber {
                text: format!("{other:?}"),
            });
        }
    };
    if number.is_finite() {
        Ok(number)
    } else {
        Err(CalibrationProblem::NonFinite)
    }
}
