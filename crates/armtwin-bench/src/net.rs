//! What the echo, the load generator and the orchestrator agree on: the key prefix, robot ids,
//! stream names, and how each process joins the mesh (a Zenoh peer on TCP loopback, multicast
//! scouting off, so every run is isolated on its own free port).
//!
//! Must not know what a process does with the mesh: no publishing or counting here.

use armtwin::cli::ZenohArgs;
use armtwin::config::ZenohSection;
use armtwin::mesh::{MeshError, aggregate_publishers, zenoh_config_of};

/// Key prefix of every stream (armtwin's default `[service] key_prefix`).
pub const PREFIX: &str = "twin";

/// Joint samples, gateway → twin.
pub const JOINTS: &str = "joints";
/// Measured poses, gateway → twin.
pub const MEASURED: &str = "measured";
/// Twin poses (the echo republishes joint samples here).
pub const POSE: &str = "pose";
/// Deviations (the echo republishes measured poses here).
pub const DEVIATION: &str = "deviation";
/// Running metrics (armtwin only).
pub const METRICS: &str = "metrics";
/// Events (armtwin only; none expected in a benchmark).
pub const EVENTS: &str = "events";
/// Liveliness tokens, one per tracked robot (armtwin only).
pub const ALIVE: &str = "alive";

pub use crate::fleet::robot_id;

/// `<prefix>/<stream>/<robot>`.
#[must_use]
pub fn key(stream: &str, robot: &str) -> String {
    format!("{PREFIX}/{stream}/{robot}")
}

/// `<prefix>/<stream>/**`: every robot's key of a stream.
#[must_use]
pub fn every_robot(stream: &str) -> String {
    format!("{PREFIX}/{stream}/**")
}

/// The robot id of a `<prefix>/<stream>/<robot>` key.
#[must_use]
pub fn robot_of<'k>(key: &'k str, stream: &str) -> Option<&'k str> {
    key.strip_prefix(PREFIX)?
        .strip_prefix('/')?
        .strip_prefix(stream)?
        .strip_prefix('/')
}

/// The Zenoh configuration of armtwin's `-m/-l/-e/--cfg` flags over Zenoh's and armtwin's
/// defaults (a peer, multicast scouting off), built as `armtwin serve` builds its own, with the
/// publishers of every stream aggregated as the README advises a gateway of many robots (the
/// load publishes inputs, the echo outputs), unless `--cfg` says otherwise.
pub fn config_of(zenoh: &ZenohArgs) -> Result<zenoh::Config, MeshError> {
    let mut config = zenoh_config_of(&ZenohSection::default().overridden(&zenoh.overrides()))?;
    let streams = [JOINTS, MEASURED, POSE, DEVIATION].map(every_robot);
    aggregate_publishers(&mut config, &streams)?;
    Ok(config)
}

/// `tcp/127.0.0.1:<port>`.
#[must_use]
pub fn loopback_endpoint(port: u16) -> String {
    format!("tcp/127.0.0.1:{port}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robot_ids_round_trip_through_keys() {
        let robot = robot_id(42);
        assert_eq!(robot, "fleet/r00042");
        assert_eq!(robot_of(&key(JOINTS, &robot), JOINTS), Some(robot.as_str()));
        assert_eq!(robot_of(&key(POSE, &robot), JOINTS), None);
        assert_eq!(robot_of("other/joints/r1", JOINTS), None);
    }
}
