//! What the echo, the load generator and the orchestrator agree on: armtwin's keys (its default
//! prefix), robot ids, streams, and how each process joins the mesh (a Zenoh peer on TCP loopback, multicast
//! scouting off, so every run is isolated on its own free port).
//!
//! Must not know what a process does with the mesh: no publishing or counting here.

use std::sync::LazyLock;

use armtwin_cli::flags::ZenohArgs;
use armtwin_mesh::keys::{KeySpace, Stream};
use armtwin_mesh::zenoh_section::ZenohSection;
use armtwin_mesh::{MeshError, aggregate_publishers, zenoh_config_of};

/// Joint samples, gateway → twin.
pub const JOINTS: Stream = Stream::Joints;
/// Measured poses, gateway → twin.
pub const MEASURED: Stream = Stream::Measured;
/// Twin poses (the echo republishes joint samples here).
pub const POSE: Stream = Stream::Pose;
/// Deviations (the echo republishes measured poses here).
pub const DEVIATION: Stream = Stream::Deviation;
/// Twin poses with their deviations in one message (armtwin with `[service] outputs =
/// "paired"`; the echo with `--paired` republishes joint samples here).
pub const PAIRED: Stream = Stream::Paired;
/// Running metrics (armtwin only).
pub const METRICS: Stream = Stream::Metrics;
/// Events (armtwin only; none expected in a benchmark).
pub const EVENTS: Stream = Stream::Events;
/// Liveliness tokens, one per tracked robot (armtwin only).
pub const ALIVE: Stream = Stream::Alive;

pub use crate::fleet::robot_id;

/// armtwin's keys under its default prefix, built once: the echo reads a robot id per sample.
static KEYS: LazyLock<KeySpace> = LazyLock::new(KeySpace::default);

/// `<prefix>/<stream>/<robot>`, under armtwin's default `[service] key_prefix`.
#[must_use]
pub fn key(stream: Stream, robot: &str) -> String {
    KEYS.key(stream, robot)
}

/// `<prefix>/<stream>/**`: every robot's key of a stream.
#[must_use]
pub fn every_robot(stream: Stream) -> String {
    KEYS.every_robot(stream)
}

/// The robot id of a `<prefix>/<stream>/<robot>` key.
#[must_use]
pub fn robot_of(key: &str, stream: Stream) -> Option<&str> {
    KEYS.robot_of(stream, key).ok()
}

/// The Zenoh configuration of armtwin's `-m/-l/-e/--cfg` flags over Zenoh's and armtwin's
/// defaults (a peer, multicast scouting off), built as `armtwin serve` builds its own, with the
/// publishers of every stream aggregated as docs/fleet.md advises a gateway of many robots (the
/// load publishes inputs, the echo outputs), unless `--cfg` says otherwise.
pub fn config_of(zenoh: &ZenohArgs) -> Result<zenoh::Config, MeshError> {
    let mut config = zenoh_config_of(&ZenohSection::default().overridden(&zenoh.overrides()))?;
    let streams = [JOINTS, MEASURED, POSE, DEVIATION, PAIRED].map(every_robot);
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
