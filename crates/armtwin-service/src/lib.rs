//! `armtwin serve`: the fleet of twins on a Zenoh mesh.
//!
//! - [`config`]: the service's TOML configuration and command-line overrides, validated.
//! - [`service`]: the service itself, one file per concern (intake, fleet, publish, queries,
//!   control, snapshots, the [`armtwin_view::FleetSource`] it implements for its HTTP door, the
//!   OPC UA view).
//! - [`exposure`]: who may reach each door of a configuration, without opening one.
//! - [`snapshot`]: the snapshot file, each twin's cumulative state across restarts.
//!
//! Must not depend on the dashboard, an offline mode or the RTDE gateway: the HTTP side is handed
//! in as an [`armtwin_view::HttpDoor`].

pub mod config;
pub mod exposure;
pub mod service;
pub mod snapshot;
