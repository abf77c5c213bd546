//! An incident's content, copied out of a robot's rings ([`Incident`]), the fixed-size records
//! the rings hold ([`JointRecord`], [`MEASURED_STRIDE`], [`EFFORT_STRIDE`]) and the MCAP file
//! it becomes ([`write_mcap`]): one channel per stream, ROS 2 schemas, CDR messages.
//!
//! Must not know where the file goes or who asked for it: [`super::store`] names, writes and
//! prunes files; the service fills the rings.

use std::collections::BTreeMap;
use std::io::{Seek, Write};
use std::sync::Arc;
use std::time::SystemTime;

use super::mcap_file::{self, McapFile, PoseTopic, pose_of};
use super::ros2_messages::Transform;
use armtwin_core::dynamics::monitor::{EffortReadout, MAX_EFFORT_JOINTS};
use armtwin_core::kinematics::PoseReadout;
use armtwin_core::metrics::Deviation;
use armtwin_core::model::RobotModel;
use armtwin_core::model::urdf::ModelFrames;
use armtwin_core::orientation;
use armtwin_core::sample::{JointQuantity, JointSample};

pub use super::mcap_file::{METADATA_NAME, WriteError, topics};

/// Joint samples as records: `[stamp_s, present, q…, velocity…, effort…, x, y, z, qx, qy, qz, qw]`
/// with `joint_count` values per joint quantity; `present` says which of velocity (bit 0) and
/// effort (bit 1) the sample had.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JointRecord {
    /// Joints per sample.
    pub joint_count: usize,
}

const HAS_VELOCITY: u32 = 1;
const HAS_EFFORT: u32 = 2;

impl JointRecord {
    /// Values per record.
    #[must_use]
    pub fn stride(self) -> usize {
        2 + 3 * self.joint_count + 7
    }

    /// Writes the record of `sample` (its joints checked, `joint_count` of them) and its twin
    /// pose into `out` (`stride` long).
    pub fn fill(self, out: &mut [f64], stamp_s: f64, sample: &JointSample, twin: &PoseReadout) {
        let n = self.joint_count;
        out[0] = stamp_s;
        let mut present = 0;
        out[2..2 + n].copy_from_slice(&sample.q_rad[..n]);
        let state = sample.state.as_deref();
        let velocity = state.and_then(|s| s.get(JointQuantity::Velocity));
        let effort = state.and_then(|s| s.get(JointQuantity::Torque));
        for (bit, values, at) in [
            (HAS_VELOCITY, velocity, 2 + n),
            (HAS_EFFORT, effort, 2 + 2 * n),
        ] {
            let slot = &mut out[at..at + n];
            match values.filter(|v| v.len() == n) {
                Some(values) => {
                    slot.copy_from_slice(values);
                    present |= bit;
                }
                None => slot.fill(0.0),
            }
        }
        out[1] = f64::from(present);
        let pose = &mut out[2 + 3 * n..];
        pose[..3].copy_from_slice(&twin.position_m);
        pose[3..7].copy_from_slice(&twin.quaternion_xyzw);
    }
}

/// Values of a measured-pose record: `[stamp_s, x, y, z, qx, qy, qz, qw]` and the deviation's
/// nine values in [`super::ros2_messages::DEVIATION`]'s order.
pub const MEASURED_STRIDE: usize = 1 + 7 + 9;

/// Writes a measured pose's record into `out` (`MEASURED_STRIDE` long).
pub fn fill_measured(out: &mut [f64], stamp_s: f64, measured: &PoseReadout, d: &Deviation) {
    out[0] = stamp_s;
    out[1..4].copy_from_slice(&measured.position_m);
    out[4..8].copy_from_slice(&measured.quaternion_xyzw);
    out[8..].copy_from_slice(&d.fields());
}

/// Joints of an effort record: room for the most the effort monitor watches.
const EFFORT_JOINTS: usize = MAX_EFFORT_JOINTS;

/// Values of an effort record: `[stamp_s, present, model…, measured…, residual…, observer…]`,
/// [`MAX_EFFORT_JOINTS`] per array, the arm's joints first; `present` has bit `i` set when
/// array `i` is, and the arm's joint count from bit 4 on.
pub const EFFORT_STRIDE: usize = 2 + 4 * EFFORT_JOINTS;

/// Where an effort record's joint count starts in its `present` value.
const JOINTS_SHIFT: u32 = 4;

/// Writes an effort readout's record into `out` (`EFFORT_STRIDE` long).
pub fn fill_effort(out: &mut [f64], readout: &EffortReadout) {
    out[0] = readout.stamp_s;
    let arrays = [
        Some(readout.model_nm),
        readout.measured_nm,
        readout.residual_nm,
        readout.observer_nm,
    ];
    let joints = readout.model_nm.len();
    let mut present = 0_u32;
    for (i, values) in arrays.iter().enumerate() {
        let slot = &mut out[2 + i * EFFORT_JOINTS..2 + (i + 1) * EFFORT_JOINTS];
        slot.fill(0.0);
        if let Some(values) = values {
            slot[..joints].copy_from_slice(values);
            present |= 1 << i;
        }
    }
    #[allow(clippy::cast_possible_truncation, reason = "at most MAX_EFFORT_JOINTS")]
    let joints_bits = (joints as u32) << JOINTS_SHIFT;
    out[1] = f64::from(present | joints_bits);
}

/// An effort record's arrays (model, measured, residual, observer), each the arm's joints long,
/// empty where absent.
fn effort_arrays(record: &[f64]) -> [&[f64]; 4] {
    let present = present_bits(record[1]);
    let joints = ((present >> JOINTS_SHIFT) as usize).min(EFFORT_JOINTS);
    std::array::from_fn(|i| {
        if present & (1 << i) == 0 {
            &[][..]
        } else {
            &record[2 + i * EFFORT_JOINTS..2 + i * EFFORT_JOINTS + joints]
        }
    })
}

/// What set an incident off.
#[derive(Debug, Clone, PartialEq)]
pub struct Trigger {
    /// A word for the file name and the metadata: `alarm`, `collision`, `payload`, `restart`,
    /// `gap`, `operator`.
    pub kind: &'static str,
    /// Its source time (s).
    pub stamp_s: f64,
    /// When it happened (wall clock): the file's name.
    pub at: SystemTime,
    /// The event as published (JSON), or the operator's request.
    pub event_json: String,
}

/// A line of the incident's log.
#[derive(Debug, Clone, PartialEq)]
pub struct LogLine {
    /// Source time (s).
    pub stamp_s: f64,
    /// `rcl_interfaces/msg/Log` level.
    pub level: u8,
    /// The text.
    pub text: String,
}

/// What an incident file holds, copied out of a robot's rings.
#[derive(Debug, Clone)]
pub struct Incident {
    /// Robot id.
    pub robot: String,
    /// The model's name.
    pub model: String,
    /// Where the robot's calibration came from (`nominal` without one).
    pub calibration_source: String,
    /// The frame of the poses (`base`, `base_link`).
    pub frame_id: String,
    /// What set it off.
    pub trigger: Trigger,
    /// Source time (s) the file starts at: the trigger's less `pre_s`.
    pub from_s: f64,
    /// Source time (s) it ends at: the trigger's plus `post_s`.
    pub until_s: f64,
    /// The layout of `joints`.
    pub joint_record: JointRecord,
    /// Joint records in `[from_s, until_s]`.
    pub joints: Vec<f64>,
    /// Measured-pose records ([`MEASURED_STRIDE`]).
    pub measured: Vec<f64>,
    /// Effort records ([`EFFORT_STRIDE`]).
    pub efforts: Vec<f64>,
    /// The trigger's line and those of triggers folded in.
    pub log: Vec<LogLine>,
    /// The model the file draws the robot with, on `/robot_description` and `/tf` (its link
    /// frames at each joint sample); `None` draws nothing.
    pub drawn: Option<Arc<RobotModel>>,
}

impl Incident {
    /// Messages the file holds.
    #[must_use]
    pub fn message_count(&self) -> usize {
        let joints = self.joints.len() / self.joint_record.stride();
        let drawn = usize::from(self.drawn.is_some());
        (2 + drawn) * joints
            + drawn
            + 2 * (self.measured.len() / MEASURED_STRIDE)
            + self.efforts.len() / EFFORT_STRIDE
            + self.log.len()
    }

    /// The joint names a `JointState` carries ([`mcap_file::joint_names`]).
    #[must_use]
    pub fn joint_names(&self) -> Vec<String> {
        mcap_file::joint_names(self.joint_record.joint_count)
    }
}

/// Writes `incident` as an MCAP file (uncompressed: a few MB at most, written once) to `out`;
/// the messages written.
pub fn write_mcap<W: Write + Seek>(out: W, incident: &Incident) -> Result<u64, WriteError> {
    let mut file = McapFile::create(out, incident.drawn.is_some())?;
    let frame = incident.frame_id.as_str();
    let names = incident.joint_names();
    let n = incident.joint_record.joint_count;
    let mut drawing = incident.drawn.as_deref().map(|model| {
        let frames = ModelFrames::of(model);
        (frames.urdf(model), frames, Vec::new())
    });
    if let Some((urdf, _, _)) = &drawing {
        file.robot_description(incident.from_s, urdf)?;
    }
    for record in incident.joints.chunks_exact(incident.joint_record.stride()) {
        let stamp_s = record[0];
        let present = present_bits(record[1]);
        let part = |bit: u32, at: usize| {
            if present & bit == 0 {
                &[][..]
            } else {
                &record[at..at + n]
            }
        };
        file.joint_state(
            stamp_s,
            frame,
            &names,
            &record[2..2 + n],
            part(HAS_VELOCITY, 2 + n),
            part(HAS_EFFORT, 2 + 2 * n),
        )?;
        file.pose(
            PoseTopic::Twin,
            stamp_s,
            frame,
            &pose_of(&record[2 + 3 * n..]),
        )?;
        if let Some((_, frames, scratch)) = &mut drawing {
            write_tf(&mut file, stamp_s, frames, &record[2..2 + n], scratch)?;
        }
    }
    for record in incident.measured.chunks_exact(MEASURED_STRIDE) {
        let stamp_s = record[0];
        file.pose(PoseTopic::Measured, stamp_s, frame, &pose_of(&record[1..8]))?;
        file.deviation(stamp_s, frame, &record[8..])?;
    }
    for record in incident.efforts.chunks_exact(EFFORT_STRIDE) {
        file.effort(record[0], effort_arrays(record))?;
    }
    for line in &incident.log {
        file.log(line.stamp_s, line.level, &line.text)?;
    }
    file.finish(metadata(incident))
}

/// The link frames of `frames` at joints `q_rad` as one `/tf` message.
fn write_tf<W: Write + Seek>(
    file: &mut McapFile<W>,
    stamp_s: f64,
    frames: &ModelFrames,
    q_rad: &[f64],
    scratch: &mut Vec<nalgebra::IsometryMatrix3<f64>>,
) -> Result<(), mcap_file::WriteError> {
    frames.transforms(q_rad, scratch);
    let transforms: Vec<Transform<'_>> = scratch
        .iter()
        .zip(frames.child_links())
        .enumerate()
        .map(|(k, (parent_from_child, child))| {
            let t = parent_from_child.translation.vector;
            let q = orientation::quaternion_from_matrix(parent_from_child.rotation.matrix());
            Transform {
                parent: frames.parent_link(k),
                child,
                translation_m: [t.x, t.y, t.z],
                rotation_xyzw: orientation::quaternion_to_xyzw(&q),
            }
        })
        .collect();
    file.tf(stamp_s, &transforms)
}

/// The metadata record: who, what model, why, and the span.
fn metadata(incident: &Incident) -> BTreeMap<String, String> {
    let trigger = &incident.trigger;
    [
        ("robot", incident.robot.clone()),
        ("model", incident.model.clone()),
        ("calibration_source", incident.calibration_source.clone()),
        ("armtwin_version", env!("CARGO_PKG_VERSION").to_owned()),
        ("trigger", trigger.kind.to_owned()),
        ("trigger_event", trigger.event_json.clone()),
        ("trigger_stamp_s", trigger.stamp_s.to_string()),
        ("from_s", incident.from_s.to_string()),
        ("until_s", incident.until_s.to_string()),
        ("frame_id", incident.frame_id.clone()),
    ]
    .into_iter()
    .map(|(key, value)| (key.to_owned(), value))
    .collect()
}

/// The `present` bits of a record, written from a `u32` by the record's `fill`.
#[allow(
    clippy::cast_sign_loss,
    reason = "a small non-negative integer, written as f64 from a u32"
)]
fn present_bits(value: f64) -> u32 {
    value as u32
}

#[cfg(test)]
mod tests {
    use armtwin_core::dynamics::ControllerMode;
    use armtwin_core::dynamics::monitor::{JointValues, StateSource};

    use super::*;

    #[test]
    fn an_effort_record_keeps_every_watched_arms_arrays_whole() {
        for joints in [5, 6, 7] {
            let values = |offset: f64| {
                let all: Vec<f64> = (0..joints).map(|k| offset + f64::from(k)).collect();
                JointValues::from_slice(&all).expect("at most seven")
            };
            let readout = EffortReadout {
                stamp_s: 1.5,
                mode: ControllerMode::Program,
                state_source: StateSource::Target,
                model_nm: values(10.0),
                measured_nm: Some(values(20.0)),
                residual_nm: None,
                observer_nm: Some(values(40.0)),
            };
            let mut record = [f64::NAN; EFFORT_STRIDE];
            fill_effort(&mut record, &readout);
            let [model, measured, residual, observer] = effort_arrays(&record);
            assert_eq!(record[0].to_bits(), 1.5_f64.to_bits());
            assert_eq!(model, &*readout.model_nm);
            assert_eq!(measured, &*values(20.0));
            assert!(residual.is_empty());
            assert_eq!(observer, &*values(40.0));
        }
    }
}
