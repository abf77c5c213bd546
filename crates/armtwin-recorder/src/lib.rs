//! The flight recorder: a robot's recent streams kept at full rate, and an incident's seconds
//! before and after written as an MCAP file that Foxglove and the `ros2 bag` tools read.
//!
//! - [`ring`]: the fixed-size records of a robot's recent streams, bounded per robot; an open
//!   block in memory, the closed ones in the fleet's [`spool`].
//! - [`block`]: a closed block's lossless compression.
//! - [`spool`]: the fleet's log of closed blocks, bounded in bytes, on an unnamed file.
//! - [`incident`]: the records' layout, an incident copied out of the rings, and its MCAP file.
//! - [`mcap_file`]: an armtwin MCAP file's channels, messages and metadata, for incident files
//!   and `armtwin record`'s alike.
//! - [`live`]: live messages (armtwin's gateway and output messages) decoded and written to a
//!   robot's file, for `armtwin record`.
//! - [`ros2_messages`]: the ROS 2 schemas (`ros2msg`) and CDR encoders of the file's messages.
//! - [`store`]: the writer thread, the files' names and their retention.
//!
//! Knows nothing of Zenoh or of the service: the service fills the rings, decides when an
//! incident is due and hands it to the store; `armtwin record` hands live messages to
//! [`live`].

pub mod block;
pub mod incident;
pub mod live;
pub mod mcap_file;
pub mod ring;
pub mod ros2_messages;
pub mod spool;
pub mod store;

pub use incident::{Incident, JointRecord, LogLine, Trigger};
pub use ring::RecordRing;
pub use spool::Spool;
pub use store::{IncidentSender, Outcome, StoreCounters, StoreSettings};
