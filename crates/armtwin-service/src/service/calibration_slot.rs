//! A self-calibrating robot's fits as its cell keeps them (the estimate waiting for `apply` or
//! `discard`, the last fit's message, the counts), and the `status` answered from them.
//!
//! Must not fit or schedule anything: `self_calibration` does, and hands its results here.

use armtwin_codec::json::EstimateMessage;
use armtwin_core::pipeline::{Robot, Twin};
use armtwin_core::self_calibration::{Estimate, PairReservoir};

/// A self-calibrating robot's fits.
#[derive(Debug, Default)]
pub(super) struct CalibrationSlot {
    /// The estimate waiting to be applied or discarded.
    pending: Option<Pending>,
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
struct Pending {
    estimate: Estimate,
    message: EstimateMessage,
}

impl CalibrationSlot {
    /// Whether a fit is due for a reservoir that has been offered `offered` pairs: some are new
    /// since the last fit, and none is running.
    pub(super) fn wants_fit(&self, offered: u64) -> bool {
        offered > self.fitted_offered && !self.in_flight
    }

    /// Notes a fit of the pairs up to `offered` running.
    pub(super) fn fit_started(&mut self, offered: u64) {
        self.in_flight = true;
        self.fitted_offered = offered;
    }

    /// Notes the running fit judged against a model the twin no longer runs: it counts for
    /// nothing, and the next period fits again.
    pub(super) fn fit_outdated(&mut self) {
        self.in_flight = false;
        self.fitted_offered = 0;
    }

    /// Notes the running fit done with `message`, and its `estimate`, if it made one, waiting
    /// for `apply` or `discard`.
    pub(super) fn fit_done(&mut self, message: EstimateMessage, estimate: Option<Estimate>) {
        self.in_flight = false;
        self.fits += 1;
        self.last = Some(message.clone());
        if let Some(estimate) = estimate {
            self.pending = Some(Pending { estimate, message });
        }
    }

    /// The estimate waiting to be applied, taken out.
    pub(super) fn take_estimate(&mut self) -> Option<Estimate> {
        self.pending.take().map(|pending| pending.estimate)
    }

    /// Drops the estimate waiting to be applied; whether there was one.
    pub(super) fn discard(&mut self) -> bool {
        self.pending.take().is_some()
    }
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

impl CalibrationStatus {
    /// What `status` answers for a self-calibrating robot, from its twin and its fits, once it
    /// has them.
    pub(super) fn of(robot: &Robot, twin: Option<&Twin>, slot: Option<&CalibrationSlot>) -> Self {
        let reservoir = twin.and_then(Twin::reservoir);
        let (train, held_out) = reservoir.map_or((0, 0), PairReservoir::kept);
        let view = twin.map(Twin::state);
        Self {
            robot: robot.id().to_owned(),
            epoch: view.as_ref().map_or(0, |view| view.metrics.epoch),
            calibration: view
                .as_ref()
                .and_then(|view| view.model.calibration())
                .map(|c| c.source_name.clone()),
            offered: reservoir.map_or(0, PairReservoir::offered),
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
}
