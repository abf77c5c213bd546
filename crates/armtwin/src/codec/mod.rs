//! Codecs: the core's types to and from the formats armtwin reads and writes (JSON field sets,
//! zenoh-ext serialized messages, CSV, ROS 2 CDR messages, IK requests and answers). They know the
//! core types, never the network or the filesystem: callers hand in bytes, readers and writers.

pub mod cdr;
mod flat_json;
pub mod ik;
pub mod joint_csv;
pub mod recording;
pub mod wire;
pub mod zser;

pub use armtwin_core::pose_fields::PoseFields;
