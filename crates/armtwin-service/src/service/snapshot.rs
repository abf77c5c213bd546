//! The service's snapshots: every twin restored before the first input (whole or not at all)
//! and written each period and at the end.
//!
//! Must not hold more than one robot's cell at a time; the file format is [`crate::snapshot`]'s.

use tracing::{debug, info, warn};

use super::fleet::Fleet;
use crate::config::ServiceConfig;
use crate::snapshot::{SnapshotError, SnapshotStore};
use armtwin_core::pipeline::{RestoreError, Robot, Twin, TwinRecord, Untracked};

/// Restores the twins of the snapshot in `store`, if there is one, before any input arrives.
/// The file is taken whole or not at all: when it is damaged, of another format or service, or
/// names a robot this instance may not track, it is set aside with a warning naming why, and
/// the service starts fresh. A robot whose record is of another arm than its configured model
/// (it computed with its own description, or its controller's model) starts afresh alone.
pub(super) fn restore_snapshot(store: &SnapshotStore, fleet: &Fleet, config: &ServiceConfig) {
    let path = store.path().display().to_string();
    let refuse = |error: &SnapshotError| match store.set_aside() {
        Ok(aside) => warn!(
            %error,
            kept_as = %aside.display(),
            "snapshot refused: starting fresh"
        ),
        Err(e) => warn!(%error, set_aside_error = %e, "snapshot refused: starting fresh"),
    };
    let records = match store.load() {
        Ok(Some(records)) => records,
        Ok(None) => {
            info!(%path, "no snapshot yet: starting fresh");
            return;
        }
        Err(e) => {
            refuse(&e);
            return;
        }
    };
    let foreign = |problem: String| SnapshotError::Foreign {
        path: path.clone(),
        problem,
    };
    let mut robots: Vec<(Robot, &TwinRecord)> = Vec::with_capacity(records.len());
    for record in &records {
        let id = record.robot.as_str();
        if !config.owns(id) {
            refuse(&foreign(format!(
                "robot '{id}' is outside service.robots '{}'",
                config.shard
            )));
            return;
        }
        match fleet.admit(id) {
            Ok(robot) => robots.push((robot, record)),
            Err(Untracked::Unknown) => {
                refuse(&foreign(format!(
                    "robot '{id}' is not configured and service.reject_unknown is true"
                )));
                return;
            }
            // The limit was lowered since the file was written: the robots beyond it start
            // afresh when they send (refused while the fleet stays full), the others keep theirs.
            Err(Untracked::Full { max_robots }) => {
                warn!(
                    robot = id,
                    max_robots, "twin not restored: the fleet is full (service.max_robots)"
                );
            }
            Err(Untracked::GroupFull { max_robots, .. }) => {
                warn!(
                    robot = id,
                    max_robots,
                    "twin not restored: its group is full (its gateway's grant's max_robots)"
                );
            }
        }
    }
    // Every twin is built before any is installed: one foreign record (or a robot recorded
    // twice) refuses the whole file, before any twin exists.
    let mut restored: Vec<Twin> = Vec::with_capacity(robots.len());
    for (robot, record) in robots {
        if restored
            .iter()
            .any(|twin| twin.robot().index() == robot.index())
        {
            let twice = RestoreError::AlreadyTracked {
                robot: robot.id().to_owned(),
            };
            refuse(&foreign(twice.to_string()));
            return;
        }
        match Twin::restored(robot, &config.pipeline, record) {
            Ok(twin) => restored.push(twin),
            // It computed with another arm than its configured one (its own description, its
            // controller's model): that robot starts afresh, the others keep theirs.
            Err(e @ RestoreError::Arm { .. }) => {
                warn!(error = %e, "twin not restored: it starts afresh");
            }
            Err(e) => {
                refuse(&foreign(e.to_string()));
                return;
            }
        }
    }
    let count = restored.len();
    for restored in restored {
        let Some(cell) = fleet.live_cell(restored.robot()) else {
            continue;
        };
        let robot = cell.robot();
        if !fleet.install_twin(robot, &mut cell.lock(), restored) {
            let error = RestoreError::AlreadyTracked {
                robot: robot.id().to_owned(),
            };
            warn!(robot = robot.id(), %error, "twin not restored");
        }
    }
    info!(%path, robots = count, "twins restored from the snapshot");
}

/// Writes the snapshot of every tracked twin: each robot's record taken under its own lock,
/// one robot at a time, and the file written after. Whether it was written.
pub(super) fn save_snapshot(fleet: &Fleet, store: &SnapshotStore) -> bool {
    let records: Vec<TwinRecord> = fleet
        .cells()
        .iter()
        .filter_map(|cell| cell.lock().twin().map(Twin::record))
        .collect();
    match store.save(&records) {
        Ok(()) => {
            let failed = fleet.snapshot_saved();
            if failed > 0 {
                info!(
                    robots = records.len(),
                    failed_periods = failed,
                    "snapshot written again"
                );
            }
            debug!(robots = records.len(), "snapshot written");
            true
        }
        Err(e) => {
            if fleet.snapshot_failed() {
                warn!(error = %e, "snapshot not written: twinning goes on, tried again every period");
            } else {
                debug!(error = %e, "snapshot not written again");
            }
            false
        }
    }
}

/// Writes the snapshot once more as the service stops, saying whether it was.
pub(super) fn save_final_snapshot(fleet: &Fleet, store: &SnapshotStore) {
    if save_snapshot(fleet, store) {
        info!(path = %store.path().display(), "final snapshot written");
    } else {
        warn!(path = %store.path().display(), "final snapshot not written");
    }
}
