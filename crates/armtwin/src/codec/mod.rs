//! Codecs: the core's types to and from the formats armtwin reads and writes (JSON field sets,
//! CSV). They know the core types, never the network or the filesystem: callers hand in readers
//! and writers.

mod flat_json;
pub mod joint_csv;
pub mod recording;
pub mod wire;

pub use armtwin_core::pose_fields::PoseFields;
