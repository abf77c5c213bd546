//! Self-calibration in the service: each self-calibrating robot's fits scheduled from its pair
//! reservoir, run on a thread of their own, and held for `apply` or `discard`.
//!
//! Must not fit under a robot's lock: the batch is copied out, fitted, and the result put back.

use std::sync::Arc;
use std::sync::mpsc::{Receiver, Sender};

use tracing::info;

use super::ServiceError;
use super::fleet::{Fleet, RobotState};
use crate::codec::json::{self, EstimateMessage};
use crate::config::SelfCalibrationConfig;
use crate::keys::Stream;
use crate::model::RobotModel;
use crate::pipeline::{Robot, Twin};
use crate::self_calibration::{self, CalibrationBatch, Estimate};

/// What `status` answers for a self-calibrating robot (`state`: its entry's, if it has one).
pub(super) fn calibration_status(robot: &Robot, state: Option<&RobotState>) -> CalibrationStatus {
    let slot = state.map(|state| &state.calibration);
    let twin = state.and_then(|state| state.twin.as_ref());
    let reservoir = twin.and_then(Twin::reservoir);
    let (train, held_out) = reservoir.map_or((0, 0), self_calibration::PairReservoir::kept);
    let view = twin.map(Twin::state);
    CalibrationStatus {
        robot: robot.id().to_owned(),
        epoch: view.as_ref().map_or(0, |view| view.metrics.epoch),
        calibration: view
            .as_ref()
            .and_then(|view| view.model.calibration())
            .map(|c| c.source_name.clone()),
        offered: reservoir.map_or(0, self_calibration::PairReservoir::offered),
        train_pairs: train,
        held_out_pairs: held_out,
        fits: slot.map_or(0, |slot| slot.fits),
        fitting: slot.is_some_and(|slot| slot.in_flight),
        pending: slot
            .and_then(|slot| slot.pending.as_ref())
            .map(|pending| pending.message.clone()),
        last: slot.and_then(|slot| slot.last.clone()),
    }
}

/// A self-calibrating robot's fits.
#[derive(Debug, Default)]
pub(super) struct CalibrationSlot {
    /// The estimate waiting to be applied or discarded.
    pub(super) pending: Option<Pending>,
    /// The last fit's message (an estimate or a refusal).
    last: Option<EstimateMessage>,
    /// Fits made.
    fits: u64,
    /// A fit is running.
    in_flight: bool,
    /// Pairs the reservoir had taken into account at the last fit: none new, no fit.
    fitted_offered: u64,
}

/// An estimate waiting for `apply` or `discard`.
#[derive(Debug)]
pub(super) struct Pending {
    pub(super) estimate: Estimate,
    message: EstimateMessage,
}

/// The `status` answer of `<prefix>/calibrate/<robot>`.
#[derive(Debug, serde::Serialize)]
pub(super) struct CalibrationStatus {
    robot: String,
    /// The metrics epoch.
    epoch: u64,
    /// The source of the calibration the twin runs (`self-calibration` once one was applied).
    calibration: Option<String>,
    offered: u64,
    train_pairs: usize,
    held_out_pairs: usize,
    fits: u64,
    fitting: bool,
    pending: Option<EstimateMessage>,
    last: Option<EstimateMessage>,
}

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
        if cell.robot.settings().self_calibration.is_none() {
            continue;
        }
        let job = {
            let mut guard = cell.lock();
            let state = &mut *guard;
            let Some(tracked) = &state.twin else {
                continue;
            };
            let Some(reservoir) = tracked.reservoir() else {
                continue;
            };
            let slot = &mut state.calibration;
            if reservoir.offered() <= slot.fitted_offered || slot.in_flight {
                continue;
            }
            let job = FitJob {
                batch: reservoir.batch(),
                model: Arc::clone(tracked.model()),
                epoch: tracked.state().metrics.epoch,
                robot: cell.robot.clone(),
            };
            slot.in_flight = true;
            slot.fitted_offered = job.batch.offered;
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
                    let mut guard = cell.lock();
                    let state = &mut *guard;
                    // Judged against a model the twin no longer runs: fit again next period.
                    let current = state
                        .twin
                        .as_ref()
                        .is_some_and(|now| Arc::ptr_eq(now.model(), &model));
                    let slot = &mut state.calibration;
                    slot.in_flight = false;
                    if !current {
                        slot.fitted_offered = 0;
                        continue;
                    }
                    slot.fits += 1;
                    slot.last = Some(message.clone());
                    if let Ok(estimate) = fit {
                        slot.pending = Some(Pending { estimate, message });
                    }
                }
                info!(
                    robot = robot.id(),
                    status = message_status,
                    improvement = message_improvement,
                    offered = batch.offered,
                    "self-calibration fit"
                );
                fleet
                    .outputs
                    .publish(None, robot.id(), Stream::Calibration, payload);
            }
        })
        .map_err(|e| ServiceError::Worker(e.to_string()))
}
