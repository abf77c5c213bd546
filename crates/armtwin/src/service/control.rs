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
use zenoh::liveliness::LivelinessToken;

use super::fleet::{Fleet, Retired, RobotState};
use super::memory::give_back_freed_memory;
use super::publish::{Outputs, RobotPublishers};
use super::self_calibration::{FitJob, fitting_thread, schedule_fits};
use super::sink::ZenohSink;
use super::snapshot::{save_final_snapshot, save_snapshot};
use super::{ServeReport, ServiceError};
use crate::codec::json;
use crate::config::SelfCalibrationConfig;
use crate::keys::Stream;
use crate::pipeline::{Robot, Twin};
use crate::snapshot::SnapshotStore;

/// Publishes the metrics of every robot with new results (and, for a robot whose effort is
/// watched, its payload message): each robot's snapshot taken under its own lock, then encoded
/// and sent after it is released, so a robot's samples wait at most for its own snapshot, never
/// for a metrics message's encoding and sending.
fn publish_due_metrics(fleet: &Fleet) {
    fleet.for_each_cell(|cell| {
        let (snapshot, publisher) = {
            let mut guard = cell.lock();
            let state = &mut *guard;
            let Some(snapshot) = state.twin.as_mut().and_then(Twin::take_due_metrics) else {
                return;
            };
            state.outputs.counts.last_active = Some(Instant::now());
            let publisher = state
                .outputs
                .declared
                .as_ref()
                .and_then(|declared| declared.metrics.clone());
            (snapshot, publisher)
        };
        if let Some(effort) = &snapshot.effort {
            let payload = json::payload_message_bytes(&snapshot.robot, effort);
            fleet
                .outputs
                .publish(None, &snapshot.robot, Stream::Payload, payload);
        }
        let payload = json::MetricsMessage::new(&snapshot).to_json_bytes();
        fleet
            .outputs
            .publish_metrics(publisher.as_deref(), &snapshot.robot, payload);
    });
}

/// Twin poses a robot publishes on plain keys within [`ROUTE_CACHE_WINDOW_S`] of source time
/// before the control thread declares the publishers (and input keys) that cache its routes: a
/// rate, not a count, so a robot that sends now and then never gets them. Zenoh computes the route
/// of a put on an undeclared key anew every time; a declaration is paid once, costs in proportion
/// to the keys beside it and holds memory for as long as the robot is tracked. A robot that
/// streams repays it; one under the rate spends less CPU on its plain keys than the declarations'
/// memory and their cost to every later declaration are worth (the figures: BENCHMARKS.md, "The
/// service next to a plain Zenoh echo").
pub(super) const ROUTE_CACHE_POSES: u32 = 64;

/// The span of source time (s) [`ROUTE_CACHE_POSES`] poses must fall in.
pub(super) const ROUTE_CACHE_WINDOW_S: f64 = 10.0;

/// Retires the robots idle for `forget_after` ([`Fleet::retire_idle`]), then, without any lock,
/// finishes each (its final metrics and unpaired measurements go out) and undeclares its
/// publishers, input keys and liveliness token.
fn retire_idle(fleet: &Fleet, forget_after: Duration) {
    let retired = fleet.retire_idle(forget_after);
    if retired.is_empty() {
        return;
    }
    let count = retired.len();
    let mut declarations = Declarations::default();
    for Retired { robot, mut state } in retired {
        declarations.finish(&fleet.outputs, robot.shared_id(), &mut state);
        debug!(
            robot = robot.id(),
            "robot retired: nothing from it for service.forget_after_s"
        );
    }
    declarations.undeclare(&fleet.outputs);
    give_back_freed_memory();
    info!(
        robots = count,
        forget_after_s = forget_after.as_secs_f64(),
        "robots retired: nothing from them for service.forget_after_s"
    );
}

/// The publishers and tokens of robots whose twins were finished, to undeclare together.
#[derive(Default)]
struct Declarations {
    publishers: Vec<(Arc<str>, RobotPublishers)>,
    tokens: Vec<(Arc<str>, LivelinessToken)>,
}

impl Declarations {
    /// Finishes `state`'s twin, if it has one (its final metrics and unpaired measurements go
    /// out), and takes its publishers and token; whether it had a twin.
    fn finish(&mut self, outputs: &Outputs, id: &Arc<str>, state: &mut RobotState) -> bool {
        let finished = state.twin.as_mut().map(|twin| {
            twin.finish(&mut ZenohSink::of(outputs, &mut state.outputs));
        });
        if let Some(publishers) = state.outputs.declared.take() {
            self.publishers.push((Arc::clone(id), publishers));
        }
        if let Some(token) = state.outputs.token.take() {
            self.tokens.push((Arc::clone(id), token));
        }
        finished.is_some()
    }

    fn undeclare(self, outputs: &Outputs) {
        outputs.undeclare_all(self.publishers, self.tokens);
    }
}

/// The control thread's periods.
#[derive(Clone, Copy)]
pub(super) struct Periods {
    /// `[service] metrics_period_ms`.
    pub(super) metrics: Duration,
    /// `[self_calibration]` (its refit period).
    pub(super) self_calibration: SelfCalibrationConfig,
    /// `[service] forget_after_s`, if robots are ever retired.
    pub(super) forget_after: Option<Duration>,
}

/// How often idle robots are looked for: a quarter of `forget_after` (a robot is retired at
/// most a quarter late), between 0.1 s and a minute.
fn sweep_period(forget_after: Duration) -> Duration {
    (forget_after / 4).clamp(Duration::from_millis(100), Duration::from_secs(60))
}

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
    sweep_period: Option<Duration>,
    next_metrics: Instant,
    next_refit: Instant,
    next_snapshot: Option<Instant>,
    next_sweep: Option<Instant>,
}

/// The duties due at one turn of the control loop.
#[allow(
    clippy::struct_excessive_bools,
    reason = "independent duties, any combination due at once"
)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Due {
    metrics: bool,
    refit: bool,
    snapshot: bool,
    /// Look for idle robots to retire.
    sweep: bool,
}

impl Schedule {
    /// Each duty first due one period after `now`; snapshots and sweeps only with a period.
    fn new(
        now: Instant,
        metrics_period: Duration,
        refit_period: Duration,
        (snapshot_period, sweep_period): (Option<Duration>, Option<Duration>),
    ) -> Self {
        Self {
            metrics_period,
            refit_period,
            snapshot_period,
            sweep_period,
            next_metrics: now + metrics_period,
            next_refit: now + refit_period,
            next_snapshot: snapshot_period.map(|period| now + period),
            next_sweep: sweep_period.map(|period| now + period),
        }
    }

    /// How long the thread may wait for a request at `now`: until the next duty, or not at all
    /// while route caches wait to be declared (one is declared per turn, so that every new
    /// robot's token, asked for meanwhile, goes first).
    fn wait(&self, now: Instant, declarations_waiting: bool) -> Duration {
        if declarations_waiting {
            return Duration::ZERO;
        }
        [self.next_snapshot, self.next_sweep]
            .into_iter()
            .flatten()
            .fold(self.next_metrics.min(self.next_refit), Instant::min)
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
        let sweep = self.next_sweep.is_some_and(|due| now >= due);
        if sweep {
            self.next_sweep = self.sweep_period.map(|period| now + period);
        }
        Due {
            metrics,
            refit,
            snapshot,
            sweep,
        }
    }
}

/// What the control thread's duties work with.
struct Duties<'a> {
    /// The self-calibration thread's queue.
    jobs: &'a Sender<FitJob>,
    store: Option<&'a SnapshotStore>,
    forget_after: Option<Duration>,
}

/// Gives `entity` (a token or publishers declared for `robot` without any lock) to the robot's
/// cell with `install`, or back to the caller, to undeclare, when the robot was retired
/// meanwhile.
fn give_to_live_cell<T>(
    fleet: &Fleet,
    robot: &Robot,
    entity: T,
    install: impl FnOnce(&mut super::fleet::RobotState, T),
) -> Option<T> {
    let Some(cell) = fleet.live_cell(robot) else {
        return Some(entity);
    };
    let mut guard = cell.lock();
    if guard.is_retired() {
        return Some(entity);
    }
    install(&mut guard, entity);
    None
}

/// Declares `robot`'s publishers and input keys and gives them to its cell; whether it has them
/// now (not when the declaration failed or the robot was retired meanwhile).
fn declare_route_caches(fleet: &Fleet, robot: &Robot) -> bool {
    let outputs = &fleet.outputs;
    match outputs.declare(robot.id()) {
        Ok(publishers) => {
            let refused = give_to_live_cell(fleet, robot, publishers, |state, publishers| {
                state.outputs.declared = Some(publishers);
            });
            let installed = refused.is_none();
            if let Some(publishers) = refused {
                outputs.undeclare_all(
                    vec![(Arc::clone(robot.shared_id()), publishers)],
                    Vec::new(),
                );
            }
            installed
        }
        Err(e) => {
            warn!(robot = robot.id(), error = %e, "cannot declare the robot's publishers");
            false
        }
    }
}

/// Declares `robot`'s metrics publisher and gives it to its publishers. A robot retired
/// meanwhile drops it, which undeclares it.
fn declare_metrics_publisher(fleet: &Fleet, robot: &Robot) {
    match fleet.outputs.declare_metrics(robot.id()) {
        Ok(publisher) => {
            let _dropped = give_to_live_cell(fleet, robot, publisher, |state, publisher| {
                if let Some(declared) = state.outputs.declared.as_mut() {
                    declared.metrics = Some(Arc::new(publisher));
                }
            });
        }
        Err(e) => {
            warn!(robot = robot.id(), error = %e, "cannot declare the robot's metrics publisher");
        }
    }
}

impl Control {
    /// Starts the thread that declares robots' Zenoh entities (never on Zenoh's own threads),
    /// publishes the periodic metrics, and finishes the pipeline at the end.
    pub(super) fn thread(
        fleet: Arc<Fleet>,
        rx: Receiver<Self>,
        periods: Periods,
        snapshots: Option<(SnapshotStore, Duration)>,
    ) -> Result<std::thread::JoinHandle<ServeReport>, ServiceError> {
        let (jobs_tx, jobs_rx) = channel::<FitJob>();
        let fitting = fitting_thread(Arc::clone(&fleet), jobs_rx, periods.self_calibration)?;
        std::thread::Builder::new()
            .name("armtwin-control".to_owned())
            .spawn(move || {
                let schedule = Schedule::new(
                    Instant::now(),
                    periods.metrics,
                    periods.self_calibration.refit_period,
                    (
                        snapshots.as_ref().map(|(_, period)| *period),
                        periods.forget_after.map(sweep_period),
                    ),
                );
                let store = snapshots.as_ref().map(|(store, _)| store);
                let duties = Duties {
                    jobs: &jobs_tx,
                    store,
                    forget_after: periods.forget_after,
                };
                let report = Self::run(&fleet, &rx, schedule, &duties);
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
        duties: &Duties<'_>,
    ) -> ServeReport {
        let outputs = &fleet.outputs;
        // Streaming robots whose route caches are asked for and not yet declared.
        let mut undeclared = VecDeque::new();
        // Streaming robots with route caches and no metrics publisher yet.
        let mut metrics_undeclared = VecDeque::new();
        loop {
            // Every new robot's token before any robot's publishers, and every streaming robot's
            // publishers of its per-sample outputs before any robot's metrics publisher: each
            // Zenoh declaration costs in proportion to the keys beside it, and a fleet is
            // tracked once its tokens are.
            let wait = schedule.wait(
                Instant::now(),
                !undeclared.is_empty() || !metrics_undeclared.is_empty(),
            );
            // Declared without the lock: samples keep flowing meanwhile (their outputs go out
            // with an undeclared key until the publishers exist).
            match rx.recv_timeout(wait) {
                Ok(Self::Stop) | Err(RecvTimeoutError::Disconnected) => break,
                Ok(Self::Track(robot)) => match outputs.declare_token(robot.id()) {
                    Ok(token) => {
                        info!(robot = robot.id(), "tracking robot");
                        // A robot retired meanwhile: its token goes at once.
                        if let Some(token) =
                            give_to_live_cell(fleet, &robot, token, |state, token| {
                                state.outputs.token = Some(token);
                            })
                        {
                            outputs.undeclare_all(
                                Vec::new(),
                                vec![(Arc::clone(robot.shared_id()), token)],
                            );
                        }
                    }
                    Err(e) => {
                        warn!(robot = robot.id(), error = %e, "cannot declare the robot's liveliness token");
                    }
                },
                Ok(Self::CacheRoutes(robot)) => undeclared.push_back(robot),
                Err(RecvTimeoutError::Timeout) => {
                    if let Some(robot) = undeclared.pop_front() {
                        if declare_route_caches(fleet, &robot) {
                            metrics_undeclared.push_back(robot);
                        }
                        if undeclared.is_empty() {
                            debug!("every streaming robot's publishers are declared");
                        }
                    } else if let Some(robot) = metrics_undeclared.pop_front() {
                        declare_metrics_publisher(fleet, &robot);
                    }
                }
            }
            fleet.tick();
            let due = schedule.take_due(Instant::now());
            if due.metrics {
                publish_due_metrics(fleet);
            }
            if due.refit {
                schedule_fits(fleet, duties.jobs);
            }
            if let (true, Some(forget_after)) = (due.sweep, duties.forget_after) {
                retire_idle(fleet, forget_after);
            }
            if let (true, Some(store)) = (due.snapshot, duties.store) {
                // A failure is counted and logged there; the next period tries again.
                let _written = save_snapshot(fleet, store);
            }
        }
        // Set before any twin is finished: an input that takes a robot's lock after the control
        // thread finished that robot's twin sees it and is ignored.
        fleet.stop();
        let mut robots = 0;
        let mut declarations = Declarations::default();
        let counted = fleet.walk(|cell, guard| {
            if declarations.finish(outputs, cell.robot.shared_id(), guard) {
                robots += 1;
            }
        });
        let report = ServeReport {
            inputs: counted.inputs,
            poses: counted.poses,
            robots,
            publish_errors: outputs.publish_errors.load(Ordering::Relaxed),
        };
        if let Some(store) = duties.store {
            save_final_snapshot(fleet, store);
        }
        declarations.undeclare(outputs);
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
        sweep: false,
    };

    fn ms(ms: u64) -> Duration {
        Duration::from_millis(ms)
    }

    #[test]
    fn waits_for_the_earliest_duty_and_not_at_all_while_declarations_wait() {
        let start = Instant::now();
        let schedule = Schedule::new(start, ms(1000), ms(5000), (Some(ms(300)), None));
        assert_eq!(schedule.wait(start, false), ms(300));
        assert_eq!(schedule.wait(start + ms(100), false), ms(200));
        assert_eq!(schedule.wait(start, true), Duration::ZERO);
        // Past a deadline the wait is zero, not negative.
        assert_eq!(schedule.wait(start + ms(400), false), Duration::ZERO);
        let without_snapshots = Schedule::new(start, ms(1000), ms(5000), (None, None));
        assert_eq!(without_snapshots.wait(start, false), ms(1000));
    }

    #[test]
    fn each_duty_falls_due_at_its_period_and_is_rescheduled_from_the_turn() {
        let start = Instant::now();
        let mut schedule = Schedule::new(start, ms(1000), ms(2500), (Some(ms(1500)), None));
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
                sweep: false,
            }
        );
        assert_eq!(schedule.take_due(start + ms(9999)), NONE_DUE);
        assert_eq!(schedule.wait(start + ms(9000), false), ms(1000));
    }

    #[test]
    fn idle_robots_are_looked_for_a_quarter_of_forget_after_apart_within_bounds() {
        assert_eq!(super::sweep_period(ms(2000)), ms(500));
        assert_eq!(
            super::sweep_period(ms(100)),
            ms(100),
            "at most ten times a second"
        );
        assert_eq!(
            super::sweep_period(Duration::from_secs(7 * 24 * 3600)),
            Duration::from_secs(60),
            "at least once a minute"
        );
        let start = Instant::now();
        let mut schedule = Schedule::new(start, ms(1000), ms(5000), (None, Some(ms(500))));
        assert_eq!(schedule.wait(start, false), ms(500));
        assert_eq!(
            schedule.take_due(start + ms(500)),
            Due {
                sweep: true,
                ..NONE_DUE
            }
        );
        assert_eq!(schedule.take_due(start + ms(900)), NONE_DUE);
    }

    #[test]
    fn without_a_snapshot_period_no_snapshot_is_ever_due() {
        let start = Instant::now();
        let mut schedule = Schedule::new(start, ms(10), ms(10), (None, None));
        for turn in 1..100 {
            assert!(!schedule.take_due(start + ms(turn * 7)).snapshot);
        }
    }
}
