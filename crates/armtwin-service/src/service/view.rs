//! The dashboard's read of the fleet ([`FleetSource`]): copied out under each robot's own lock
//! in turn.
//!
//! Must not keep anything between reads (the gateways' tokens are heard, and the other
//! instances' robots asked, in modules of their own).

use std::collections::VecDeque;
use std::sync::Arc;

use super::fleet::Fleet;
use super::gateways::GatewayTokens;
use super::peers::Peers;
use armtwin_codec::json;
use armtwin_recorder::store;
use armtwin_view::{
    FleetRow, FleetSource, PeerFleet, RecordingFile, RobotCounts, RobotDetail, ServiceTotals,
};

/// The fleet as the dashboard reads it.
pub(super) struct FleetView {
    fleet: Arc<Fleet>,
    gateways: Arc<GatewayTokens>,
    peers: Peers,
    shard: Arc<str>,
    expected: Arc<[Arc<str>]>,
}

impl FleetView {
    pub(super) fn new(
        fleet: Arc<Fleet>,
        gateways: Arc<GatewayTokens>,
        peers: Peers,
        shard: &str,
        configured: impl IntoIterator<Item = impl AsRef<str>>,
    ) -> Self {
        let mut expected: Vec<Arc<str>> = configured
            .into_iter()
            .map(|id| Arc::from(id.as_ref()))
            .collect();
        expected.sort();
        Self {
            fleet,
            gateways,
            peers,
            shard: Arc::from(shard),
            expected: expected.into(),
        }
    }
}

impl FleetSource for FleetView {
    fn fleet(&self) -> (ServiceTotals, Vec<FleetRow>) {
        let fleet = &self.fleet;
        let mut rows: Vec<FleetRow> = Vec::new();
        let counted = fleet.walk(|cell, guard| {
            let Some(twin) = guard.twin() else {
                return;
            };
            let state = twin.state();
            rows.push(FleetRow {
                id: Arc::clone(cell.robot().shared_id()),
                metrics: state.metrics,
                alarms_active: state.alarms_active,
                joint_state: state.last_state.map(|(_, joint_state)| joint_state.clone()),
                counts: RobotCounts {
                    recent_events: VecDeque::new(),
                    ..guard.outputs().counts().clone()
                },
                last_sample_age_s: fleet.since_last_input(guard).as_secs_f64(),
            });
        });
        rows.sort_by(|a, b| a.id.cmp(&b.id));
        let totals = ServiceTotals {
            inputs: counted.inputs,
            poses: counted.poses,
            publish_errors: fleet.outlet().publish_errors(),
            robots: rows.len(),
            max_robots: fleet.occupancy().1,
            robots_refused: fleet.robots_refused(),
            robots_retired: fleet.robots_retired(),
            snapshot_age_s: fleet.snapshot_age_s(),
            snapshot_failures: fleet.snapshot_failures(),
            descriptions_refused: fleet.descriptions_refused(),
            recorder: fleet.recorder().totals(),
            history_log: fleet.history_log_totals(),
        };
        (totals, rows)
    }

    fn robot(&self, id: &str) -> Option<RobotDetail> {
        let cell = self.fleet.existing_cell_of(id)?;
        let guard = cell.lock();
        let state = guard.state_message()?;
        Some(RobotDetail {
            state,
            model: Arc::clone(guard.twin()?.model()),
            counts: guard.outputs().counts().clone(),
        })
    }

    fn history(&self, id: &str) -> Option<json::HistoryMessage> {
        let cell = self.fleet.existing_cell_of(id)?;
        cell.lock().history_message(id, |_| i64::MIN..=i64::MAX)
    }

    fn recordings(&self, id: &str) -> Option<Vec<RecordingFile>> {
        let dir = &self.fleet.recorder().config().store.dir;
        let files = store::robot_files(dir, id);
        if files.is_empty() && self.fleet.existing_cell_of(id).is_none() {
            return None;
        }
        Some(
            files
                .into_iter()
                .map(|(name, bytes)| RecordingFile { name, bytes })
                .collect(),
        )
    }

    fn recording_file(&self, id: &str, name: &str) -> Option<(std::path::PathBuf, u64)> {
        store::robot_file(&self.fleet.recorder().config().store.dir, id, name)
    }

    fn poses_of(&self, id: &str) -> Option<u64> {
        let cell = self.fleet.existing_cell_of(id)?;
        let guard = cell.lock();
        guard.twin()?;
        Some(guard.outputs().counts().poses)
    }

    fn gateways(&self) -> Vec<(Arc<str>, bool)> {
        self.gateways.read(|id| self.fleet.find(id).is_some())
    }

    fn expected(&self) -> Arc<[Arc<str>]> {
        Arc::clone(&self.expected)
    }

    fn own_shard(&self) -> Arc<str> {
        Arc::clone(&self.shard)
    }

    fn peers(&self) -> PeerFleet {
        self.peers.read()
    }
}
