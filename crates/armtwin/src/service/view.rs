//! The dashboard's read of the fleet ([`FleetSource`]): copied out under each robot's own lock
//! in turn.
//!
//! Must not keep anything between reads.

use std::collections::VecDeque;
use std::sync::Arc;

use super::fleet::Fleet;
use crate::codec::json;
use crate::dashboard::{FleetRow, FleetSource, RobotCounts, RobotDetail, ServiceTotals};

/// The fleet as the dashboard reads it.
pub(super) struct FleetView {
    fleet: Arc<Fleet>,
}

impl FleetView {
    pub(super) fn new(fleet: Arc<Fleet>) -> Self {
        Self { fleet }
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
            recorder: fleet.recorder().totals(),
        };
        (totals, rows)
    }

    fn robot(&self, id: &str) -> Option<RobotDetail> {
        let cell = self.fleet.existing_cell_of(id)?;
        let guard = cell.lock();
        let twin = guard.twin()?;
        Some(RobotDetail {
            state: json::StateMessage::new(&twin.state()),
            model: Arc::clone(twin.model()),
            counts: guard.outputs().counts().clone(),
        })
    }

    fn poses_of(&self, id: &str) -> Option<u64> {
        let cell = self.fleet.existing_cell_of(id)?;
        let guard = cell.lock();
        guard.twin()?;
        Some(guard.outputs().counts().poses)
    }
}
