//! What a running fleet shows its doors: the contract between the service and its HTTP side.
//!
//! - [`FleetSource`]: read access to a running fleet, which the service implements, and the rows
//!   it returns.
//! - [`HttpDoor`]: how the service opens and closes an HTTP server it does not know, which the
//!   dashboard implements.
//!
//! Must not serve HTTP, read the network, or name the service or the dashboard: the command line
//! hands one to the other, so a change in the dashboard recompiles neither this crate nor the
//! service.

use std::collections::VecDeque;
use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Instant;

use armtwin_codec::json;
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::{Alarms, MetricsReadout, RejectCause};
use armtwin_core::sample::JointState;

/// An HTTP server the service opens on a listener it has bound (so that an address in use fails
/// the start before anything joins the mesh), over a fleet it runs.
pub trait HttpDoor: Send + Sync {
    /// Starts serving `fleet` on `listener`, until [`OpenHttpDoor::close`].
    fn open(
        &self,
        listener: tokio::net::TcpListener,
        fleet: Arc<dyn FleetSource>,
    ) -> Box<dyn OpenHttpDoor>;
}

/// A running HTTP server, as [`HttpDoor::open`] started it.
pub trait OpenHttpDoor: Send {
    /// Ends every stream, stops accepting connections and waits (bounded) for the server.
    fn close(self: Box<Self>) -> Pin<Box<dyn Future<Output = ()> + Send>>;
}

/// Read access to a running fleet: each call copies what it needs out and holds nothing
/// afterwards, so the dashboard keeps no second copy of the state that could drift from it.
pub trait FleetSource: Send + Sync + 'static {
    /// Every tracked robot's row, in id order, and the service's totals.
    fn fleet(&self) -> (ServiceTotals, Vec<FleetRow>);
    /// Robot `id`'s state, model and recent events, if it is tracked.
    fn robot(&self, id: &str) -> Option<RobotDetail>;
    /// Robot `id`'s per-second history: every completed second it keeps, if it is tracked.
    fn history(&self, id: &str) -> Option<json::HistoryMessage>;
    /// Robot `id`'s incident and recording files, oldest first (`None` if it is neither tracked
    /// nor has files).
    fn recordings(&self, id: &str) -> Option<Vec<RecordingFile>>;
    /// Where robot `id`'s file `name` (as [`recordings`](Self::recordings) lists it) is on disk,
    /// and its size.
    fn recording_file(&self, id: &str, name: &str) -> Option<(std::path::PathBuf, u64)>;
    /// Robot `id`'s twin pose count (`None` if it is not tracked): changes whenever it moves.
    fn poses_of(&self, id: &str) -> Option<u64>;
    /// The robots whose gateway holds a liveliness token, or held one while the robot is
    /// configured or tracked, in id order, with whether the gateway streams (its `streaming`
    /// token is declared).
    fn gateways(&self) -> Vec<(Arc<str>, bool)>;
    /// The robots the configuration names (`[robots."<id>"]`), in id order: expected from the
    /// start, whether they have spoken since or not.
    fn expected(&self) -> Arc<[Arc<str>]>;
    /// The key expression of the robots this instance twins (`[service] robots`).
    fn own_shard(&self) -> Arc<str>;
    /// The robots the fleet's other instances twin, read through the mesh (blocks for up to a
    /// few seconds).
    fn peers(&self) -> PeerFleet;
}

/// One file the flight recorder wrote for a robot.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct RecordingFile {
    /// Its name in the robot's directory: `<UTC time>-<trigger>.mcap`.
    pub name: String,
    /// Its size (bytes).
    pub bytes: u64,
}

/// The robots of the fleet's other instances, as their state answers gave them.
#[derive(Debug, Clone, Default)]
pub struct PeerFleet {
    /// In id order.
    pub rows: Vec<PeerRow>,
    /// Robots may be missing: more answered than a read keeps, or not every instance answered
    /// in time.
    pub truncated: bool,
}

/// One robot another instance twins.
#[derive(Debug, Clone)]
pub struct PeerRow {
    /// The robot id.
    pub id: Arc<str>,
    /// The key expression of the instance that twins it (`[service] robots`), if its claim
    /// answered.
    pub shard: Option<Arc<str>>,
    /// Window MAE of the position distance (m).
    pub position_m: f64,
    /// Window MAE of the rotation angle (rad).
    pub angle_rad: f64,
    /// Pairs in the window.
    pub window_n: u64,
    /// Counters of the current metrics epoch.
    pub paired: u64,
    /// Measured poses that could not be paired.
    pub unpaired: u64,
    /// Inputs rejected.
    pub rejected: u64,
    /// Whether its position alarm is active.
    pub alarm_position: bool,
    /// Whether its angle alarm is active.
    pub alarm_angle: bool,
}

/// One tracked robot as the fleet page and `/metrics` read it.
#[derive(Debug, Clone)]
pub struct FleetRow {
    /// The robot id.
    pub id: Arc<str>,
    /// Its metrics at the read (counters and statistics of the current epoch).
    pub metrics: MetricsReadout,
    /// Position and angle alarms.
    pub alarms_active: Alarms,
    /// The latest joint state sent beside the angles, if any (temperatures, currents, modes).
    pub joint_state: Option<JointState>,
    /// Its totals over the service's life (no recent events: the fleet does not show them).
    pub counts: RobotCounts,
    /// Seconds since the robot's last input arrived, at the read.
    pub last_sample_age_s: f64,
}

/// The service's own totals.
#[derive(Debug, Clone, Copy, Default)]
pub struct ServiceTotals {
    /// Inputs (samples and queries) processed.
    pub inputs: u64,
    /// Twin poses published.
    pub poses: u64,
    /// Outputs Zenoh refused to send.
    pub publish_errors: u64,
    /// Robots tracked.
    pub robots: usize,
    /// `[service] max_robots`.
    pub max_robots: usize,
    /// Samples of new robots refused because the fleet was full.
    pub robots_refused: u64,
    /// Robots retired after `[service] forget_after_s` without input.
    pub robots_retired: u64,
    /// Seconds since the snapshot was last written, once it has been (with `state_dir`).
    pub snapshot_age_s: Option<f64>,
    /// Snapshot writes that failed (a full or read-only disk); each is tried again next period.
    pub snapshot_failures: u64,
    /// Robots' descriptions refused: unreadable, too large or too frequent, of another joint
    /// count, or disagreeing with the robot's own model.
    pub descriptions_refused: u64,
    /// The flight recorder's files and memory.
    pub recorder: RecorderTotals,
    /// The log of the histories' closed minutes of seconds.
    pub history_log: HistoryLogTotals,
}

/// The log of the histories' closed minutes of seconds (`[recorder] history_bytes`).
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct HistoryLogTotals {
    /// Bytes it holds.
    pub bytes: u64,
    /// Minutes not kept because the disk was behind: their seconds are not answered (their
    /// minute is).
    pub dropped: u64,
    /// Writes to its file that failed (it went on in memory after the first).
    pub write_failures: u64,
}

/// The flight recorder's totals.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct RecorderTotals {
    /// Incident files written.
    pub files: u64,
    /// Their bytes.
    pub bytes: u64,
    /// Incident files that could not be written (a full disk), or were dropped for a full queue.
    pub failures: u64,
    /// Bytes every robot's recent streams hold.
    pub ring_bytes: u64,
}

/// One robot as its page reads it.
pub struct RobotDetail {
    /// What `get <prefix>/state/<robot>` answers.
    pub state: json::StateMessage,
    /// The model the twin runs and the last valid joints, for the link frames.
    pub model: Arc<RobotModel>,
    /// Its totals and recent events.
    pub counts: RobotCounts,
}

/// A robot's totals over the service's life (reset and model replacement do not touch them) and
/// its last published events.
#[derive(Debug, Default, Clone)]
pub struct RobotCounts {
    /// Twin poses published.
    pub poses: u64,
    /// Rejected inputs by cause (a handful of causes at most: a short list beats a map).
    pub rejected_by_cause: Vec<(RejectCause, u64)>,
    /// The last recent published events, oldest first, as published (JSON).
    pub recent_events: VecDeque<Arc<[u8]>>,
    /// When the control thread last found results of the robot it had not published (to its
    /// metrics period).
    pub last_active: Option<Instant>,
}
