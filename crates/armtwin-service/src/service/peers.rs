//! The rest of the fleet, read through the mesh for the fleet page: the other instances' shard
//! claims (`get <prefix>/shards/**`) and their robots' states (`get <prefix>/state/**`), both
//! asked of remote queryables only, each bounded in time, in replies and in bytes per reply; a
//! read cut by either bound says so.
//!
//! Runs on a blocking thread when a fleet page asks (at most once a second, whatever the pages
//! open): it costs the other instances one state answer per robot then, and the twins nothing
//! per sample. Must not touch the fleet.

use std::sync::Arc;
use std::time::{Duration, Instant};

use serde_json::Value;
use tracing::debug;
use zenoh::Wait;
use zenoh::key_expr::KeyExpr;
use zenoh::sample::Locality;
use zenoh::session::Session;

use armtwin_mesh::keys::{KeySpace, Stream};
use armtwin_view::{PeerFleet, PeerRow};

/// How long a read waits for the other instances' answers.
const PEER_WAIT: Duration = Duration::from_secs(2);
/// The most robots of other instances a read keeps: beyond, the page says the list is cut.
pub(super) const MAX_PEER_ROBOTS: usize = 10_000;
/// The most shard claims a read keeps.
const MAX_CLAIMS: usize = 256;
/// The largest answer read (a state answer is a few KiB).
const MAX_REPLY_BYTES: usize = 64 * 1024;

/// What the fleet page asks of the mesh.
pub(super) struct Peers {
    session: Session,
    keys: KeySpace,
}

impl Peers {
    pub(super) fn new(session: Session, keys: KeySpace) -> Self {
        Self { session, keys }
    }

    /// The other instances' robots, in id order, each with its owner's shard.
    pub(super) fn read(&self) -> PeerFleet {
        let claims: Vec<(KeyExpr<'static>, Arc<str>)> = self
            .ask(&self.keys.every_shard_claim(), MAX_CLAIMS)
            .0
            .into_iter()
            .filter_map(|(_, claim)| {
                let robots = claim.get("robots")?.as_str()?;
                let key = KeyExpr::try_from(robots.to_owned()).ok()?;
                Some((key, Arc::from(robots)))
            })
            .collect();
        let (answers, timed_out) =
            self.ask(&self.keys.every_robot(Stream::State), MAX_PEER_ROBOTS + 1);
        let truncated = timed_out || answers.len() > MAX_PEER_ROBOTS;
        let mut rows: Vec<PeerRow> = answers
            .into_iter()
            .take(MAX_PEER_ROBOTS)
            .filter_map(|(key, state)| {
                let id = self.keys.robot_of(Stream::State, key.as_str()).ok()?;
                let robot = KeyExpr::try_from(id).ok()?;
                let shard = claims
                    .iter()
                    .find(|(robots, _)| robots.intersects(&robot))
                    .map(|(_, text)| Arc::clone(text));
                Some(row_of(id, shard, &state))
            })
            .collect();
        rows.sort_by(|a, b| a.id.cmp(&b.id));
        rows.dedup_by(|a, b| a.id == b.id);
        PeerFleet { rows, truncated }
    }

    /// The JSON answers of remote queryables on `selector`, at most `limit`, within
    /// [`PEER_WAIT`], and whether the wait ran out (some may not have answered).
    fn ask(&self, selector: &str, limit: usize) -> (Vec<(KeyExpr<'static>, Value)>, bool) {
        let start = Instant::now();
        let replies = match self
            .session
            .get(selector)
            .allowed_destination(Locality::Remote)
            .timeout(PEER_WAIT)
            .wait()
        {
            Ok(replies) => replies,
            Err(e) => {
                debug!(error = %e, selector, "the fleet's other instances could not be asked");
                return (Vec::new(), false);
            }
        };
        let mut answers = Vec::new();
        while let Ok(reply) = replies.recv() {
            let Ok(sample) = reply.result() else { continue };
            if sample.payload().len() > MAX_REPLY_BYTES {
                continue;
            }
            let Ok(value) = serde_json::from_slice::<Value>(&sample.payload().to_bytes()) else {
                continue;
            };
            answers.push((sample.key_expr().clone().into_owned(), value));
            if answers.len() >= limit {
                // Dropping the receiver drops the replies still to come.
                break;
            }
        }
        let took = start.elapsed();
        debug!(
            selector,
            answers = answers.len(),
            took_ms = took.as_millis(),
            "the fleet's other instances answered"
        );
        (answers, took >= PEER_WAIT)
    }
}

/// The fleet page's row of robot `id` from its state answer (`metrics`, `alarms`); a field
/// missing reads as zero.
fn row_of(id: &str, shard: Option<Arc<str>>, state: &Value) -> PeerRow {
    let metrics = &state["metrics"];
    let window = &metrics["window"];
    let count = |value: &Value| value.as_u64().unwrap_or(0);
    PeerRow {
        id: Arc::from(id),
        shard,
        position_m: window["position"]["mae"].as_f64().unwrap_or(0.0),
        angle_rad: window["angle"]["mae"].as_f64().unwrap_or(0.0),
        window_n: count(&window["n"]),
        paired: count(&metrics["paired"]),
        unpaired: count(&metrics["unpaired"]),
        rejected: count(&metrics["rejected"]),
        alarm_position: state["alarms"]["position"].as_bool().unwrap_or(false),
        alarm_angle: state["alarms"]["angle"].as_bool().unwrap_or(false),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_state_answer_becomes_a_row() {
        let state = serde_json::json!({
            "robot": "site-b/r1",
            "alarms": {"position": true, "angle": false},
            "metrics": {"paired": 10, "unpaired": 2, "rejected": 1,
                        "window": {"n": 7, "position": {"mae": 0.01}, "angle": {"mae": 0.002}}},
        });
        let row = row_of("site-b/r1", Some(Arc::from("site-b/**")), &state);
        assert_eq!(&*row.id, "site-b/r1");
        assert_eq!(row.shard.as_deref(), Some("site-b/**"));
        assert_eq!(
            (row.paired, row.unpaired, row.rejected, row.window_n),
            (10, 2, 1, 7)
        );
        assert!((row.position_m - 0.01).abs() < f64::EPSILON);
        assert!((row.angle_rad - 0.002).abs() < f64::EPSILON);
        assert!(row.alarm_position && !row.alarm_angle);
        let empty = row_of("x", None, &Value::Null);
        assert_eq!((empty.paired, empty.window_n), (0, 0));
    }
}
