//! The control thread: declares newly tracked robots' liveliness tokens and, once a robot
//! streams, the publishers that cache its routes; publishes the periodic metrics, schedules
//! self-calibration fits and writes snapshots; at the end finishes every twin and undeclares.
//!
//! Must not run on Zenoh's threads, and never holds a robot's cell across a declaration.

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, channel};
use std::time::{Duration, Instant};

use tracing::{debug, info, warn};

use super::fleet::Fleet;
use super::publish::RobotPublishers;
use super::self_calibration::{FitJob, fitting_thread, schedule_fits};
use super::sink::ZenohSink;
use super::snapshot::save_snapshot;
use super::{ServeReport, ServiceError};
use crate::codec::json;
use crate::config::SelfCalibrationConfig;
use crate::keys::Stream;
use crate::pipeline::{Robot, Twin};
use crate::snapshot::SnapshotStore;

/// Publishes the metrics of every robot with new results: each robot's snapshot taken under
/// its own lock, then encoded and sent after it is released, so a robot's samples wait at most
/// for its own snapshot, never for a metrics message's encoding and sending.
fn publish_due_metrics(fleet: &Fleet) {
    for cell in fleet.cells() {
        let snapshot = {
            let mut guard = cell.lock();
            let state = &mut *guard;
            let Some(snapshot) = state.twin.as_mut().and_then(Twin::take_due_metrics) else {
                continue;
            };
            state.outputs.counts.last_active = Some(Instant::now());
            snapshot
        };
        let payload = json::MetricsMessage::new(&snapshot).to_json_bytes();
        fleet
            .outputs
            .publish(None, &snapshot.robot, Stream::Metrics, payload);
    }
}

/// Twin poses a robot publishes on plain keys before the control thread declares the
/// publishers (and input keys) that cache its routes. Zenoh computes the route of a put on an
/// undeclared key anew every time; a declaration is paid once, costs in proportion to the keys
/// beside it and holds memory for as long as the robot is tracked: a robot that streams repays
/// it within a few dozen messages, while one that sends now and then never would, so a fleet of
/// mostly quiet robots holds route caches only for the few that stream.
pub(super) const ROUTE_CACHE_AFTER_POSES: u64 = 64;

/// What the control thread is asked to do.
pub(super) enum Control {
    /// Declare a newly tracked robot's liveliness token.
    Track(Robot),
    /// Declare the publishers and input keys that cache a streaming robot's routes.
    CacheRoutes(Robot),
    /// Finish the pipeline, undeclare everything and stop.
    Stop,
}

/// When the control thread's periodic duties fall due. Pure: the thread passes the time in.
#[derive(Debug, Clone, Copy)]
struct Schedule {
    metrics_period: Duration,
    refit_period: Duration,
    snapshot_period: Option<Duration>,
    next_metrics: Instant,
    next_refit: Instant,
    next_snapshot: Option<Instant>,
}

/// The duties due at one turn of the control loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Due {
    metrics: bool,
    refit: bool,
    snapshot: bool,
}

impl Schedule {
    /// Each duty first due one period after `now`; snapshots only with a period.
    fn new(
        now: Instant,
        metrics_period: Duration,
        refit_period: Duration,
        snapshot_period: Option<Duration>,
    ) -> Self {
        Self {
            metrics_period,
            refit_period,
            snapshot_period,
            next_metrics: now + metrics_period,
            next_refit: now + refit_period,
            next_snapshot: snapshot_period.map(|period| now + period),
        }
    }

    /// How long the thread may wait for a request at `now`: until the next duty, or not at all
    /// while route caches wait to be declared (one is declared per turn, so that every new
    /// robot's token, asked for meanwhile, goes first).
    fn wait(&self, now: Instant, declarations_waiting: bool) -> Duration {
        if declarations_waiting {
            return Duration::ZERO;
        }
        let next = self.next_metrics.min(self.next_refit);
        self.next_snapshot
            .map_or(next, |snapshot| next.min(snapshot))
            .saturating_duration_since(now)
    }

    /// The duties due at `now`, each due again one period after `now` (a late turn skips the
    /// periods it missed instead of running them back to back).
    fn take_due(&mut self, now: Instant) -> Due {
        let metrics = now >= self.next_metrics;
        if metrics {
            self.next_metrics = now + self.metrics_period;
        }
        let refit = now >= self.next_refit;
        if refit {
            self.next_refit = now + self.refit_period;
        }
        let snapshot = self.next_snapshot.is_some_and(|due| now >= due);
        if snapshot {
            self.next_snapshot = self.snapshot_period.map(|period| now + period);
        }
        Due {
            metrics,
            refit,
            snapshot,
        }
    }
}

impl Control {
    /// Starts the thread that declares robots' Zenoh entities (never on Zenoh's own threads),
    /// publishes the periodic metrics, and finishes the pipeline at the end.
    pub(super) fn thread(
        fleet: Arc<Fleet>,
        rx: Receiver<Self>,
        (metrics_period, self_calibration): (Duration, SelfCalibrationConfig),
        snapshots: Option<(SnapshotStore, Duration)>,
    ) -> Result<std::thread::JoinHandle<ServeReport>, ServiceError> {
        let (jobs_tx, jobs_rx) = channel::<FitJob>();
        let fitting = fitting_thread(Arc::clone(&fleet), jobs_rx, self_calibration)?;
        std::thread::Builder::new()
            .name("armtwin-control".to_owned())
            .spawn(move || {
                let schedule = Schedule::new(
                    Instant::now(),
                    metrics_period,
                    self_calibration.refit_period,
                    snapshots.as_ref().map(|(_, period)| *period),
                );
                let store = snapshots.as_ref().map(|(store, _)| store);
                let report = Self::run(&fleet, &rx, schedule, &jobs_tx, store);
                // Closing the queue ends the fitting thread after its current fit.
                drop(jobs_tx);
                if fitting.join().is_err() {
                    warn!("the self-calibration thread panicked");
                }
                report
            })
            .map_err(|e| ServiceError::Worker(e.to_string()))
    }

    fn run(
        fleet: &Fleet,
        rx: &Receiver<Self>,
        mut schedule: Schedule,
        jobs: &Sender<FitJob>,
        store: Option<&SnapshotStore>,
    ) -> ServeReport {
        let outputs = &fleet.outputs;
        let mut tokens = Vec::new();
        // Streaming robots whose route caches are asked for and not yet declared.
        let mut undeclared = VecDeque::new();
        loop {
            // Every new robot's token before any robot's publishers: each Zenoh declaration
            // costs in proportion to the keys beside it, and a fleet is tracked once its tokens
            // are.
            let wait = schedule.wait(Instant::now(), !undeclared.is_empty());
            // Declared without the lock: samples keep flowing meanwhile (their outputs go out
            // with an undeclared key until the publishers exist).
            match rx.recv_timeout(wait) {
                Ok(Self::Stop) | Err(RecvTimeoutError::Disconnected) => break,
                Ok(Self::Track(robot)) => match outputs.declare_token(robot.id()) {
                    Ok(token) => {
                        info!(robot = robot.id(), "tracking robot");
                        tokens.push((Arc::clone(robot.shared_id()), token));
                    }
                    Err(e) => {
                        warn!(robot = robot.id(), error = %e, "cannot declare the robot's liveliness token");
                    }
                },
                Ok(Self::CacheRoutes(robot)) => undeclared.push_back(robot),
                Err(RecvTimeoutError::Timeout) => {
                    if let Some(robot) = undeclared.pop_front() {
                        match outputs.declare(robot.id()) {
                            Ok(publishers) => {
                                fleet.cell(&robot).lock().outputs.declared = Some(publishers);
                            }
                            Err(e) => {
                                warn!(robot = robot.id(), error = %e, "cannot declare the robot's publishers");
                            }
                        }
                        if undeclared.is_empty() {
                            debug!("every tracked robot's publishers are declared");
                        }
                    }
                }
            }
            let due = schedule.take_due(Instant::now());
            if due.metrics {
                publish_due_metrics(fleet);
            }
            if due.refit {
                schedule_fits(fleet, jobs);
            }
            if let (true, Some(store)) = (due.snapshot, store) {
                save_snapshot(fleet, store);
            }
        }
        // Set before any twin is finished: an input that takes a robot's lock after the control
        // thread finished that robot's twin sees it and is ignored.
        fleet.stop();
        let mut robots = 0;
        let mut declared: Vec<(Arc<str>, RobotPublishers)> = Vec::new();
        for cell in fleet.cells() {
            let mut guard = cell.lock();
            let state = &mut *guard;
            if let Some(tracked) = &mut state.twin {
                tracked.finish(&mut ZenohSink::of(outputs, &mut state.outputs));
                robots += 1;
            }
            if let Some(publishers) = state.outputs.declared.take() {
                declared.push((Arc::clone(cell.robot.shared_id()), publishers));
            }
        }
        let report = ServeReport {
            inputs: fleet.inputs.load(Ordering::Relaxed),
            poses: outputs.poses.load(Ordering::Relaxed),
            robots,
            publish_errors: outputs.publish_errors.load(Ordering::Relaxed),
        };
        if let Some(store) = store {
            save_snapshot(fleet, store);
            info!(path = %store.path().display(), "final snapshot written");
        }
        outputs.undeclare_all(declared, tokens);
        report
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use super::{Due, Schedule};

    const NONE_DUE: Due = Due {
        metrics: false,
        refit: false,
        snapshot: false,
    };

    fn ms(ms: u64) -> Duration {
        Duration::from_millis(ms)
    }

    #[test]
    fn waits_for_the_earliest_duty_and_not_at_all_while_declarations_wait() {
        let start = Instant::now();
        let schedule = Schedule::new(start, ms(1000), ms(5000), Some(ms(300)));
        assert_eq!(schedule.wait(start, false), ms(300));
        assert_eq!(schedule.wait(start + ms(100), false), ms(200));
        assert_eq!(schedule.wait(start, true), Duration::ZERO);
        // Past a deadline the wait is zero, not negative.
        assert_eq!(schedule.wait(start + ms(400), false), Duration::ZERO);
        let without_snapshots = Schedule::new(start, ms(1000), ms(5000), None);
        assert_eq!(without_snapshots.wait(start, false), ms(1000));
    }

    #[test]
    fn each_duty_falls_due_at_its_period_and_is_rescheduled_from_the_turn() {
        let start = Instant::now();
        let mut schedule = Schedule::new(start, ms(1000), ms(2500), Some(ms(1500)));
        assert_eq!(schedule.take_due(start + ms(999)), NONE_DUE);
        assert_eq!(
            schedule.take_due(start + ms(1000)),
            Due {
                metrics: true,
                ..NONE_DUE
            }
        );
        assert_eq!(schedule.take_due(start + ms(1001)), NONE_DUE);
        assert_eq!(
            schedule.take_due(start + ms(1600)),
            Due {
                snapshot: true,
                ..NONE_DUE
            }
        );
        // A late turn runs each due duty once and skips the periods it missed.
        assert_eq!(
            schedule.take_due(start + ms(9000)),
            Due {
                metrics: true,
                refit: true,
                snapshot: true,
            }
        );
        assert_eq!(schedule.take_due(start + ms(9999)), NONE_DUE);
        assert_eq!(schedule.wait(start + ms(9000), false), ms(1000));
    }

    #[test]
    fn without_a_snapshot_period_no_snapshot_is_ever_due() {
        let start = Instant::now();
        let mut schedule = Schedule::new(start, ms(10), ms(10), None);
        for turn in 1..100 {
            assert!(!schedule.take_due(start + ms(turn * 7)).snapshot);
        }
    }
}
