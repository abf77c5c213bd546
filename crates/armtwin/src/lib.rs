//! armtwin: a live digital twin for robot arms.
//!
//! Gateways stream joint angles (and the controller's measured tool pose); armtwin computes each
//! arm's calibrated forward kinematics and keeps running twin-vs-robot error metrics. The pure
//! core ([`armtwin_core`], re-exported here under its own module names) serves every mode: the
//! command line, the live service, offline validation and the FMU.
//!
//! This crate is the outer ring, around the core:
//! - [`codec`]: the codec crate ([`armtwin_codec`]): the core's types to and from CSV, the
//!   service's JSON and Zenoh-serialized messages, ROS 2 CDR messages and `rmw_zenoh`
//!   attachments, and the one decoded-message path into the pipeline.
//! - [`rosbag`]: rosbag2 recordings (MCAP, sqlite3) read into the rows a CSV becomes.
//! - [`ros2`]: ROS 2 on Zenoh: `rmw_zenoh` and bridge key layouts, the robot a key names, the
//!   twin pose output's key.
//! - [`ingest`]: the codec a Zenoh sample's encoding selects.
//! - [`acl`]: a fleet description (who speaks for which robots) as a router's access control.
//! - [`certs`]: a fleet's certificates by role: its CA, the router's, a client's per name.
//! - [`keys`]: armtwin's key space on Zenoh: every key built and read, the robot-id grammar,
//!   armtwin's own streams.
//! - [`config`]: the service's TOML configuration and command-line overrides.
//! - [`mesh`]: every armtwin session's Zenoh configuration, publisher aggregation and bounded
//!   teardown.
//! - [`service`]: `armtwin serve`, the fleet of twins on a Zenoh mesh, one file per concern.
//! - [`snapshot`]: the service's snapshot file, each twin's cumulative state across restarts.
//! - [`dashboard`]: the service's HTTP side: fleet and robot pages, live streams, `/metrics`.
//! - [`http_access`]: who may reach it: its TLS identity, tokens and their roles.
//! - [`recorder`]: the flight recorder: each robot's recent streams, incidents as MCAP files.
//! - [`replay`]: `armtwin replay`, a recording published as a gateway would.
//! - [`record`]: `armtwin record`, live streams of chosen robots written as MCAP files.
//! - [`gateway`]: `armtwin gateway rtde`, Universal Robots controllers streamed over RTDE.
//! - [`controller`]: what a gateway learns of a controller beyond its samples (its TCP, model
//!   and serial number), as the message the service reads.
//! - [`validate`]: `armtwin validate`, a recording through the pipeline offline, with its report
//!   and plots.
//! - [`calibrate`]: `armtwin calibrate`, a recording's kinematics identified, with its report.
//! - [`fmu_package`]: `armtwin fmu build`, the FMU archive.
//!
//! The `armtwin` command line is the `armtwin-cli` crate, on this one.

pub use armtwin_codec as codec;
// The mesh plumbing every door shares, under the module names the service's files use.
pub use armtwin_core::{
    align, dynamics, fmi, identify, ik, kinematics, metrics, model, orientation, pipeline,
    pose_fields, sample, self_calibration, trig,
};
pub use armtwin_mesh as mesh;
pub use armtwin_mesh::{controller, ingest, keys, ros2};

pub mod acl;
pub mod calibrate;
pub mod certs;
pub mod config;
pub mod dashboard;
#[cfg(test)]
mod file_sizes;
pub mod fmu_package;
pub mod gateway;
pub mod http_access;
#[cfg(test)]
mod module_graph;
pub mod record;
pub mod recorder;
pub mod replay;
pub mod rosbag;
pub mod service;
pub mod snapshot;
pub mod validate;
