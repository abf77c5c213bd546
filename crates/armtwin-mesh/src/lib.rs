//! armtwin on a Zenoh mesh, apart from the twin: the plumbing every door shares (the service,
//! `replay`, `record`, the gateway, the benchmarks).
//!
//! Layout:
//! - [`beside`]: work a process runs on the service's session beside the twin.
//! - [`keys`]: armtwin's key space: every key built and read, the robot-id grammar.
//! - [`ros2`]: ROS 2 on Zenoh: `rmw_zenoh` and bridge key layouts, the twin pose output's key.
//! - [`ingest`]: the codec a Zenoh sample's encoding selects.
//! - [`controller`]: what a gateway learns of a controller beyond its samples.
//! - [`zenoh_section`]: `[zenoh]` and the command line's Zenoh flags, and where each setting
//!   came from.
//! - [`zenoh_file`]: what a `[zenoh] file` sets itself of mode and endpoints.
//! - [`session`] (re-exported here): a session's Zenoh configuration, publisher aggregation and
//!   bounded teardown.
//!
//! Must not know the twin, the fleet, the service's configuration or any HTTP: it is the plumbing
//! they share.

pub mod beside;
pub mod controller;
pub mod ingest;
pub mod keys;
pub mod ros2;
pub mod session;
pub mod zenoh_file;
pub mod zenoh_section;

pub use session::{
    MeshError, TEARDOWN_STEP, aggregate_publishers, bounded, close_session, transport_stamp_s,
    zenoh_config_of,
};
