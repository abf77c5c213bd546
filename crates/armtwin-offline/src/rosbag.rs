//! rosbag2 recordings (MCAP, the default storage since Iron, and sqlite3 `.db3`) read into the
//! [`Recording`] a CSV becomes, so `validate` and `replay` run a bag through the one path they
//! run a CSV through.
//!
//! Each `sensor_msgs/msg/JointState` on the joint topic becomes a row (its joints matched by
//! name, [`cdr::decode_joint_state`]); the `geometry_msgs/msg/PoseStamped` on the pose topic with
//! the same `header.stamp` becomes that row's measured pose (the UR driver's broadcasters stamp
//! both with the controller cycle's time). A message that does not decode becomes a
//! [`Malformed`] entry whose text is the decoder's error, rejected and counted like a bad CSV
//! line. Owns finding a bag's storage files and reading them; decoding is [`cdr`]'s, the rest is
//! the recording's.

use std::collections::HashMap;
use std::fmt;
use std::path::{Path, PathBuf};

use rusqlite::OpenFlags;
use thiserror::Error;

use armtwin_codec::cdr::{self, CdrError, JointNames};
use armtwin_codec::recording::{Cell, Format, Malformed, PoseCells, Recording, RecordingRow};

/// The ROS type of joint messages.
pub const JOINT_STATE_TYPE: &str = "sensor_msgs/msg/JointState";
/// The ROS type of measured poses.
pub const POSE_STAMPED_TYPE: &str = "geometry_msgs/msg/PoseStamped";

/// Which topics of a bag to read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BagTopics {
    /// `sensor_msgs/msg/JointState` (`/joint_states`).
    pub joint_states: String,
    /// `geometry_msgs/msg/PoseStamped` in the robot's `base` frame
    /// (`/tcp_pose_broadcaster/pose`); absent from a bag, the rows carry no measured pose.
    pub pose: String,
}

impl Default for BagTopics {
    fn default() -> Self {
        Self {
            joint_states: "/joint_states".to_owned(),
            pose: "/tcp_pose_broadcaster/pose".to_owned(),
        }
    }
}

/// How to read a bag of one robot.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct BagOptions {
    /// The topics.
    pub topics: BagTopics,
    /// The robot's `tf_prefix` (`""`, or e.g. `alice_`): of its joint names and of the pose's
    /// expected frame `<tf_prefix>base`.
    pub tf_prefix: String,
}

/// Why a bag cannot be read at all.
#[derive(Debug, Error)]
pub enum BagError {
    /// A file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// A directory without `.mcap` or `.db3` files, or a file of another kind.
    #[error("{path}: not a rosbag2 recording (no .mcap or .db3 storage file)")]
    NoStorage {
        /// The path given.
        path: PathBuf,
    },
    /// An MCAP file is damaged.
    #[error("{path}: MCAP: {source}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The reader's error.
        source: mcap::McapError,
    },
    /// A sqlite3 storage file is damaged or not a rosbag2 database.
    #[error("{path}: sqlite3: {source}")]
    Sqlite {
        /// The file.
        path: PathBuf,
        /// The error.
        source: rusqlite::Error,
    },
    /// The joint topic is not in the bag.
    #[error("topic '{topic}' is not in the bag; it has: {found}")]
    NoTopic {
        /// The topic asked for.
        topic: String,
        /// The bag's topics, comma-separated.
        found: String,
    },
    /// A topic holds another type, or is not CDR.
    #[error("topic '{topic}' holds {got}, expected {expected} in CDR")]
    TopicType {
        /// The topic.
        topic: String,
        /// The type (and encoding) expected.
        expected: &'static str,
        /// What the bag says.
        got: String,
    },
}

/// The storage of a bag.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Storage {
    /// MCAP.
    Mcap,
    /// sqlite3 (`.db3`).
    Sqlite3,
}

/// What reading a bag found, for the command line to say.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BagSummary {
    /// Storage files read, in order.
    pub files: Vec<PathBuf>,
    /// Joint messages (rows).
    pub joint_messages: usize,
    /// Pose messages.
    pub pose_messages: usize,
    /// Poses given to a row (same stamp as a joint message).
    pub paired_poses: usize,
    /// Poses whose stamp no joint message has (not used).
    pub unmatched_poses: usize,
    /// Poses that did not decode or are in another frame (not used): message number and why.
    pub pose_errors: Vec<(u64, String)>,
}

impl fmt::Display for BagSummary {
    fn fmt(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            formatter,
            "{} joint messages, {} poses ({} given to a joint message, {} without one, {} unusable)",
            self.joint_messages,
            self.pose_messages,
            self.paired_poses,
            self.unmatched_poses,
            self.pose_errors.len()
        )
    }
}

/// A bag read as a recording.
#[derive(Debug, Clone)]
pub struct BagRecording {
    /// The rows, as a CSV's.
    pub recording: Recording,
    /// The storage read.
    pub storage: Storage,
    /// What was found.
    pub summary: BagSummary,
}

/// Whether `path` looks like a rosbag2 recording: a directory with `metadata.yaml` or storage
/// files, or an `.mcap` / `.db3` file.
#[must_use]
pub fn is_bag(path: &Path) -> bool {
    if path.is_dir() {
        return path.join("metadata.yaml").is_file() || storage_files(path).is_ok();
    }
    storage_of(path).is_some()
}

fn storage_of(path: &Path) -> Option<Storage> {
    match path.extension()?.to_str()? {
        "mcap" => Some(Storage::Mcap),
        "db3" => Some(Storage::Sqlite3),
        _ => None,
    }
}

/// The storage files of a bag directory (or the one file given), in name order, all of one
/// storage.
fn storage_files(path: &Path) -> Result<(Storage, Vec<PathBuf>), BagError> {
    let no_storage = || BagError::NoStorage {
        path: path.to_owned(),
    };
    if !path.is_dir() {
        let storage = storage_of(path).ok_or_else(no_storage)?;
        return Ok((storage, vec![path.to_owned()]));
    }
    let io = |source| BagError::Io {
        path: path.to_owned(),
        source,
    };
    let mut files = Vec::new();
    for entry in std::fs::read_dir(path).map_err(io)? {
        let file = entry.map_err(io)?.path();
        if let Some(storage) = storage_of(&file) {
            files.push((storage, file));
        }
    }
    files.sort_by(|a, b| a.1.cmp(&b.1));
    let storage = files
        .first()
        .map(|(storage, _)| *storage)
        .ok_or_else(no_storage)?;
    Ok((
        storage,
        files
            .into_iter()
            .filter(|(s, _)| *s == storage)
            .map(|(_, file)| file)
            .collect(),
    ))
}

/// Which of the two topics a message is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stream {
    Joints,
    Pose,
}

/// One message of a bag: its stream, log time (ns) and CDR bytes.
struct BagMessage {
    stream: Stream,
    log_time_ns: u64,
    data: Vec<u8>,
}

/// Reads the bag at `path` (a rosbag2 directory, or one `.mcap` / `.db3` file).
pub fn read(path: &Path, options: &BagOptions) -> Result<BagRecording, BagError> {
    let (storage, files) = storage_files(path)?;
    let mut topics_found = Vec::new();
    let mut messages = Vec::new();
    for file in &files {
        match storage {
            Storage::Mcap => read_mcap(file, &options.topics, &mut topics_found, &mut messages)?,
            Storage::Sqlite3 => {
                read_sqlite(file, &options.topics, &mut topics_found, &mut messages)?;
            }
        }
    }
    if !topics_found.contains(&options.topics.joint_states) {
        topics_found.sort();
        topics_found.dedup();
        return Err(BagError::NoTopic {
            topic: options.topics.joint_states.clone(),
            found: topics_found.join(", "),
        });
    }
    // Split files and chunks are each in time order, not necessarily all together.
    messages.sort_by_key(|message| message.log_time_ns);
    let (recording, mut summary) = to_recording(&messages, options);
    summary.files = files;
    Ok(BagRecording {
        recording,
        storage,
        summary,
    })
}

/// Checks a topic's type and encoding; `None` for a topic not read.
fn stream_of(
    topics: &BagTopics,
    topic: &str,
    type_name: &str,
    encoding: &str,
) -> Result<Option<Stream>, BagError> {
    let (stream, expected) = if topic == topics.joint_states {
        (Stream::Joints, JOINT_STATE_TYPE)
    } else if topic == topics.pose {
        (Stream::Pose, POSE_STAMPED_TYPE)
    } else {
        return Ok(None);
    };
    if type_name != expected || encoding != "cdr" {
        return Err(BagError::TopicType {
            topic: topic.to_owned(),
            expected,
            got: format!("{type_name} in {encoding:?}"),
        });
    }
    Ok(Some(stream))
}

fn read_mcap(
    file: &Path,
    topics: &BagTopics,
    topics_found: &mut Vec<String>,
    messages: &mut Vec<BagMessage>,
) -> Result<(), BagError> {
    let bytes = std::fs::read(file).map_err(|source| BagError::Io {
        path: file.to_owned(),
        source,
    })?;
    let mcap_error = |source| BagError::Mcap {
        path: file.to_owned(),
        source,
    };
    // Channels are checked once each.
    let mut streams: HashMap<u16, Option<Stream>> = HashMap::new();
    for message in mcap::MessageStream::new(&bytes).map_err(mcap_error)? {
        let message = message.map_err(mcap_error)?;
        let channel = &message.channel;
        let stream = if let Some(stream) = streams.get(&channel.id) {
            *stream
        } else {
            topics_found.push(channel.topic.clone());
            let type_name = channel.schema.as_ref().map_or("", |s| s.name.as_str());
            let stream = stream_of(topics, &channel.topic, type_name, &channel.message_encoding)?;
            streams.insert(channel.id, stream);
            stream
        };
        if let Some(stream) = stream {
            messages.push(BagMessage {
                stream,
                log_time_ns: message.log_time,
                data: message.data.into_owned(),
            });
        }
    }
    Ok(())
}

fn read_sqlite(
    file: &Path,
    topics: &BagTopics,
    topics_found: &mut Vec<String>,
    messages: &mut Vec<BagMessage>,
) -> Result<(), BagError> {
    let sqlite_error = |source| BagError::Sqlite {
        path: file.to_owned(),
        source,
    };
    let connection = rusqlite::Connection::open_with_flags(
        file,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(sqlite_error)?;
    let mut statement = connection
        .prepare("SELECT id, name, type, serialization_format FROM topics")
        .map_err(sqlite_error)?;
    let rows = statement
        .query_map([], |row| {
            Ok((
                row.get::<_, i64>(0)?,
                row.get::<_, String>(1)?,
                row.get::<_, String>(2)?,
                row.get::<_, String>(3)?,
            ))
        })
        .map_err(sqlite_error)?;
    let mut wanted = Vec::new();
    for row in rows {
        let (id, name, type_name, encoding) = row.map_err(sqlite_error)?;
        if let Some(stream) = stream_of(topics, &name, &type_name, &encoding)? {
            wanted.push((id, stream));
        }
        topics_found.push(name);
    }
    let mut statement = connection
        .prepare("SELECT timestamp, data FROM messages WHERE topic_id = ?1 ORDER BY timestamp")
        .map_err(sqlite_error)?;
    for (id, stream) in wanted {
        let rows = statement
            .query_map([id], |row| {
                Ok((row.get::<_, i64>(0)?, row.get::<_, Vec<u8>>(1)?))
            })
            .map_err(sqlite_error)?;
        for row in rows {
            let (timestamp, data) = row.map_err(sqlite_error)?;
            messages.push(BagMessage {
                stream,
                // rosbag2 writes nanoseconds since the epoch; none is negative.
                log_time_ns: u64::try_from(timestamp).unwrap_or(0),
                data,
            });
        }
    }
    Ok(())
}

/// The rows of a bag's messages (in log-time order).
fn to_recording(messages: &[BagMessage], options: &BagOptions) -> (Recording, BagSummary) {
    let joint_names = JointNames::ur(&options.tf_prefix);
    let base_frame = format!("{}base", options.tf_prefix);
    let mut summary = BagSummary::default();
    // Poses by stamp, to give each to the joint message of the same stamp.
    let mut poses: HashMap<u64, [f64; 7]> = HashMap::new();
    for (number, message) in (1_u64..).zip(messages.iter().filter(|m| m.stream == Stream::Pose)) {
        summary.pose_messages += 1;
        let pose = match cdr::decode_pose_stamped(&message.data) {
            Ok(pose) if pose.frame_id != base_frame => Err(format!(
                "frame '{}', expected '{base_frame}'",
                pose.frame_id
            )),
            Ok(pose) => Ok(pose),
            Err(error) => Err(error.to_string()),
        };
        match pose {
            Ok(pose) => {
                let stamp_s = pose
                    .sample
                    .stamp_s
                    .unwrap_or_else(|| log_time_s(message.log_time_ns));
                let [x, y, z] = pose.sample.pose.position_m;
                let [qx, qy, qz, qw] = pose.xyzw_as_sent;
                poses.insert(stamp_s.to_bits(), [x, y, z, qx, qy, qz, qw]);
            }
            Err(reason) => summary.pose_errors.push((number, reason)),
        }
    }
    let mut entries = Vec::new();
    for (number, message) in (1_u64..).zip(messages.iter().filter(|m| m.stream == Stream::Joints)) {
        summary.joint_messages += 1;
        entries.push(
            match cdr::decode_joint_state(&message.data, &joint_names, None) {
                Ok(sample) => {
                    let stamp_s = sample
                        .stamp_s
                        .unwrap_or_else(|| log_time_s(message.log_time_ns));
                    let pose = poses.remove(&stamp_s.to_bits()).map(|values| {
                        summary.paired_poses += 1;
                        PoseCells::Quaternion(values.map(Cell::Number))
                    });
                    Ok(RecordingRow {
                        line: number,
                        stamp_s: Some(stamp_s),
                        q: sample.q_rad.into_iter().map(Cell::Number).collect(),
                        pose,
                    })
                }
                Err(error) => Err(malformed(number, &options.topics.joint_states, &error)),
            },
        );
    }
    summary.unmatched_poses = poses.len();
    let recording = Recording {
        format: Format::Rosbag2,
        has_pose: summary.pose_messages > 0,
        entries,
    };
    (recording, summary)
}

/// A joint message that did not decode, as the recording's malformed entry: its text (what
/// `replay` publishes, and the service rejects) names the message and the decoder's error.
fn malformed(number: u64, topic: &str, error: &CdrError) -> Malformed {
    Malformed {
        line: number,
        text: format!("{topic} message {number}: {error}"),
        problem: format!("{}: {error}", error.kind()),
    }
}

fn log_time_s(log_time_ns: u64) -> f64 {
    (log_time_ns / 1_000_000_000) as f64 + (log_time_ns % 1_000_000_000) as f64 * 1e-9
}
