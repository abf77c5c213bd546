//! Self-calibration in the service: each self-calibrating robot's fits scheduled from its pair
//! reservoir and run on a thread of their own; each result goes to the robot's
//! [`CalibrationSlot`](super::calibration_slot::CalibrationSlot), held for `apply` or `discard`.
//!
//! Must not fit under a robot's lock: the batch is copied out, fitted, and the result put back.

use std::sync::Arc;
use std::sync::mpsc::{Receiver, Sender};

use tracing::info;

use super::error::ServiceError;
use super::fleet::Fleet;
use crate::config::SelfCalibrationConfig;
use armtwin_codec::json::{self, EstimateMessage};
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::Robot;
use armtwin_core::self_calibration::{self, CalibrationBatch};
use armtwin_mesh::keys::Stream;

/// One robot's pairs to fit, taken from its reservoir under its lock and fitted without it.
pub(super) struct FitJob {
    robot: Robot,
    model: Arc<RobotModel>,
    epoch: u64,
    batch: CalibrationBatch,
}

/// Hands the pairs of every self-calibrating robot with pairs new since its last fit to the
/// fitting thread: each robot's batch copied under its own lock (a few thousand pairs).
pub(super) fn schedule_fits(fleet: &Fleet, jobs: &Sender<FitJob>) {
    for cell in fleet.cells() {
        if cell.robot().settings().self_calibration.is_none() {
            continue;
        }
        let job = {
            let mut state = cell.lock();
            let Some(tracked) = state.twin() else {
                continue;
            };
            let Some(reservoir) = tracked.reservoir() else {
                continue;
            };
            if !state.calibration().wants_fit(reservoir.offered()) {
                continue;
            }
            let job = FitJob {
                batch: reservoir.batch(),
                model: Arc::clone(tracked.model()),
                epoch: tracked.state().metrics.epoch,
                robot: cell.robot().clone(),
            };
            state.calibration_mut().fit_started(job.batch.offered);
            job
        };
        if jobs.send(job).is_err() {
            return;
        }
    }
}

/// Starts the thread that fits self-calibrating robots' pairs, one after another, off the
/// sample path and off the control thread (a fit of thousands of pairs takes longer than many
/// metrics periods); it ends when `jobs` closes.
pub(super) fn fitting_thread(
    fleet: Arc<Fleet>,
    jobs: Receiver<FitJob>,
    config: SelfCalibrationConfig,
) -> Result<std::thread::JoinHandle<()>, ServiceError> {
    std::thread::Builder::new()
        .name("armtwin-calibrate".to_owned())
        .spawn(move || {
            for job in jobs {
                let FitJob {
                    robot,
                    model,
                    epoch,
                    batch,
                } = job;
                let fit = self_calibration::fit(&model, &batch, &config.options);
                let message = match &fit {
                    Ok(estimate) => EstimateMessage::estimate(robot.id(), epoch, estimate),
                    Err(e) => EstimateMessage::refused(robot.id(), epoch, &batch, e),
                };
                let payload = json::to_json_bytes(&message);
                let (message_status, message_improvement) = (message.status, message.improvement);
                {
                    // A robot retired meanwhile: its fit goes nowhere.
                    let Some(cell) = fleet.live_cell(&robot) else {
                        continue;
                    };
                    let mut state = cell.lock();
                    // Judged against a model the twin no longer runs: fit again next period.
                    let current = state
                        .twin()
                        .is_some_and(|now| Arc::ptr_eq(now.model(), &model));
                    let slot = state.calibration_mut();
                    if !current {
                        slot.fit_outdated();
                        continue;
                    }
                    slot.fit_done(message, fit.ok());
                }
                info!(
                    robot = robot.id(),
                    status = message_status,
                    improvement = message_improvement,
                    offered = batch.offered,
                    "self-calibration fit"
                );
                fleet
                    .outlet()
                    .publish(None, robot.id(), Stream::Calibration, payload);
            }
        })
        .map_err(|e| ServiceError::Worker(e.to_string()))
}
