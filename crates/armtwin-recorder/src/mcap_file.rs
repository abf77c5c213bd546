//! An armtwin MCAP file being written ([`McapFile`]): its schemas and channels, one per stream,
//! its messages in CDR stamped with their source time, and its metadata record. Incident files
//! ([`super::incident`]) and `armtwin record`'s ([`super::live`]) are both written through it, so
//! a reader sees the same topics, schemas and encodings in either.
//!
//! Must not know what the messages mean or where the file goes: callers hand it values and a
//! writer.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use super::ros2_messages::{self as msg, MessageType};
use armtwin_codec::cdr::JointNames;
use armtwin_core::kinematics::PoseReadout;
use armtwin_core::model::catalog::UR_JOINT_NAMES;

/// Topics of an armtwin file, and what each carries.
pub mod topics {
    /// `sensor_msgs/msg/JointState`: the joints and their state, as they came in.
    pub const JOINT_STATES: &str = "/joint_states";
    /// `geometry_msgs/msg/PoseStamped`: the twin pose of each joint sample.
    pub const TWIN_POSE: &str = "/twin/pose";
    /// `geometry_msgs/msg/PoseStamped`: the measured pose of each pair (the UR driver's topic,
    /// so the file reads back as a bag of the robot).
    pub const MEASURED_POSE: &str = "/tcp_pose_broadcaster/pose";
    /// `armtwin_msgs/msg/Deviation`: twin minus measured, per pair.
    pub const DEVIATION: &str = "/twin/deviation";
    /// `armtwin_msgs/msg/Effort`: torques per joint sample of a robot whose effort is watched.
    pub const EFFORT: &str = "/twin/effort";
    /// `rcl_interfaces/msg/Log`: the trigger, and every trigger folded into the incident.
    pub const ROSOUT: &str = "/rosout";
    /// `std_msgs/msg/String`: the robot's URDF, once, at the file's start (files that know the
    /// robot's model: incidents).
    pub const ROBOT_DESCRIPTION: &str = "/robot_description";
    /// `tf2_msgs/msg/TFMessage`: the twin's link frames of each joint sample, named as the
    /// URDF's links (the same files).
    pub const TF: &str = "/tf";
}

/// The name of the MCAP metadata record an armtwin file carries.
pub const METADATA_NAME: &str = "armtwin";

/// Why a file was not written.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    /// The MCAP writer failed (its I/O among the causes).
    #[error("MCAP")]
    Mcap(#[from] mcap::McapError),
}

/// The joint names a `JointState` carries for `joint_count` joints: the UR driver's for six (so
/// the file reads back as a bag of the robot), else `joint_1`, `joint_2`, ….
#[must_use]
pub fn joint_names(joint_count: usize) -> Vec<String> {
    if joint_count == UR_JOINT_NAMES.len() {
        JointNames::ur("").as_slice().to_vec()
    } else {
        (1..=joint_count).map(|i| format!("joint_{i}")).collect()
    }
}

/// Which pose topic a pose goes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseTopic {
    /// [`topics::TWIN_POSE`].
    Twin,
    /// [`topics::MEASURED_POSE`].
    Measured,
}

/// Channels of one file, by stream.
struct Channels {
    joint_states: u16,
    twin_pose: u16,
    measured_pose: u16,
    deviation: u16,
    effort: u16,
    rosout: u16,
    /// The robot's description and link frames, when the file draws the robot.
    robot_description: Option<u16>,
    tf: Option<u16>,
}

/// An armtwin MCAP file being written: uncompressed, profile `ros2`, every channel declared up
/// front (a reader sees the same topics whatever the file holds; [`topics::ROBOT_DESCRIPTION`]
/// and [`topics::TF`] in the files that draw the robot).
pub struct McapFile<W: Write + Seek> {
    writer: mcap::Writer<W>,
    channels: Channels,
    sequence: u32,
    written: u64,
}

impl<W: Write + Seek> McapFile<W> {
    /// Starts a file on `out`: header, schemas and channels; those of the robot's description
    /// and link frames with `robot_frames`.
    pub fn create(out: W, robot_frames: bool) -> Result<Self, WriteError> {
        let mut writer = mcap::WriteOptions::new()
            .compression(None)
            .profile("ros2")
            .library(concat!("armtwin ", env!("CARGO_PKG_VERSION")))
            .create(out)?;
        let channels = channels(&mut writer, robot_frames)?;
        Ok(Self {
            writer,
            channels,
            sequence: 0,
            written: 0,
        })
    }

    /// Messages written so far.
    #[must_use]
    pub fn written(&self) -> u64 {
        self.written
    }

    fn put(&mut self, channel_id: u16, stamp_s: f64, data: &[u8]) -> Result<(), WriteError> {
        self.sequence = self.sequence.wrapping_add(1);
        self.written += 1;
        let time = msg::stamp_ns(stamp_s);
        self.writer.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id,
                sequence: self.sequence,
                log_time: time,
                publish_time: time,
            },
            data,
        )?;
        Ok(())
    }

    /// A `sensor_msgs/msg/JointState` on [`topics::JOINT_STATES`]; `velocity` and `effort`
    /// empty when absent.
    pub fn joint_state(
        &mut self,
        stamp_s: f64,
        frame_id: &str,
        joint_names: &[String],
        position: &[f64],
        velocity: &[f64],
        effort: &[f64],
    ) -> Result<(), WriteError> {
        let payload = msg::joint_state(stamp_s, frame_id, joint_names, position, velocity, effort);
        self.put(self.channels.joint_states, stamp_s, &payload)
    }

    /// A `geometry_msgs/msg/PoseStamped` on `topic`.
    pub fn pose(
        &mut self,
        topic: PoseTopic,
        stamp_s: f64,
        frame_id: &str,
        pose: &PoseReadout,
    ) -> Result<(), WriteError> {
        let payload = armtwin_codec::cdr::encode_pose_stamped(stamp_s, frame_id, pose);
        let channel = match topic {
            PoseTopic::Twin => self.channels.twin_pose,
            PoseTopic::Measured => self.channels.measured_pose,
        };
        self.put(channel, stamp_s, &payload)
    }

    /// An `armtwin_msgs/msg/Deviation` of the nine values in [`msg::DEVIATION`]'s order.
    pub fn deviation(
        &mut self,
        stamp_s: f64,
        frame_id: &str,
        values: &[f64],
    ) -> Result<(), WriteError> {
        let payload = msg::deviation(stamp_s, frame_id, values);
        self.put(self.channels.deviation, stamp_s, &payload)
    }

    /// An `armtwin_msgs/msg/Effort`: each array empty when absent.
    pub fn effort(&mut self, stamp_s: f64, arrays: [&[f64]; 4]) -> Result<(), WriteError> {
        let payload = msg::effort(stamp_s, arrays);
        self.put(self.channels.effort, stamp_s, &payload)
    }

    /// An `rcl_interfaces/msg/Log` from the `armtwin` logger.
    pub fn log(&mut self, stamp_s: f64, level: u8, text: &str) -> Result<(), WriteError> {
        let payload = msg::log(stamp_s, level, "armtwin", text);
        self.put(self.channels.rosout, stamp_s, &payload)
    }

    /// A `std_msgs/msg/String` on [`topics::ROBOT_DESCRIPTION`]; nothing in a file without
    /// that channel.
    pub fn robot_description(&mut self, stamp_s: f64, urdf: &str) -> Result<(), WriteError> {
        match self.channels.robot_description {
            Some(channel) => self.put(channel, stamp_s, &msg::string(urdf)),
            None => Ok(()),
        }
    }

    /// A `tf2_msgs/msg/TFMessage` on [`topics::TF`]; nothing in a file without that channel.
    pub fn tf(
        &mut self,
        stamp_s: f64,
        transforms: &[msg::Transform<'_>],
    ) -> Result<(), WriteError> {
        match self.channels.tf {
            Some(channel) => self.put(channel, stamp_s, &msg::tf_message(stamp_s, transforms)),
            None => Ok(()),
        }
    }

    /// Writes the metadata record [`METADATA_NAME`] and the file's summary; the messages
    /// written and the writer.
    pub fn finish(mut self, metadata: BTreeMap<String, String>) -> Result<u64, WriteError> {
        self.writer.write_metadata(&mcap::records::Metadata {
            name: METADATA_NAME.to_owned(),
            metadata,
        })?;
        self.writer.finish()?;
        Ok(self.written)
    }
}

/// Declares the file's schemas and channels.
fn channels<W: Write + Seek>(
    writer: &mut mcap::Writer<W>,
    robot_frames: bool,
) -> Result<Channels, WriteError> {
    let mut schema = |message: MessageType| {
        writer.add_schema(message.name, "ros2msg", message.definition.as_bytes())
    };
    let schemas = [
        schema(msg::JOINT_STATE)?,
        schema(msg::POSE_STAMPED)?,
        schema(msg::DEVIATION)?,
        schema(msg::EFFORT)?,
        schema(msg::LOG)?,
    ];
    // Declared after the others: a file without them keeps the same schema and channel ids.
    let frame_schemas = if robot_frames {
        Some((schema(msg::STRING)?, schema(msg::TF_MESSAGE)?))
    } else {
        None
    };
    let none = BTreeMap::new();
    let mut channel =
        |schema_id: u16, topic: &str| writer.add_channel(schema_id, topic, "cdr", &none);
    let mut channels = Channels {
        joint_states: channel(schemas[0], topics::JOINT_STATES)?,
        twin_pose: channel(schemas[1], topics::TWIN_POSE)?,
        measured_pose: channel(schemas[1], topics::MEASURED_POSE)?,
        deviation: channel(schemas[2], topics::DEVIATION)?,
        effort: channel(schemas[3], topics::EFFORT)?,
        rosout: channel(schemas[4], topics::ROSOUT)?,
        robot_description: None,
        tf: None,
    };
    if let Some((string, tf_message)) = frame_schemas {
        channels.robot_description = Some(channel(string, topics::ROBOT_DESCRIPTION)?);
        channels.tf = Some(channel(tf_message, topics::TF)?);
    }
    Ok(channels)
}

/// A pose from `[x, y, z, qx, qy, qz, qw]` as given (a canonical quaternion): the components
/// kept as they are, not renormalised, so the file holds what it was handed.
#[must_use]
pub fn pose_of(values: &[f64]) -> PoseReadout {
    let quaternion = nalgebra::UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(
        values[6], values[3], values[4], values[5],
    ));
    let mut pose =
        PoseReadout::from_position_quaternion([values[0], values[1], values[2]], &quaternion);
    pose.quaternion_xyzw.copy_from_slice(&values[3..7]);
    pose
}
