//! The control thread: declares newly tracked robots' liveliness tokens and, once a robot
//! streams, the publishers that cache its routes; publishes the periodic metrics, schedules
//! self-calibration fits and writes snapshots; at the end finishes every twin and hands back
//! what is still declared, for the session's close to undeclare at once.
//!
//! Must not run on Zenoh's threads, and never holds a robot's cell across a declaration.

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, channel};
use std::time::{Duration, Instant};

use tracing::{debug, info, warn};
use zenoh::liveliness::LivelinessToken;

use super::error::ServiceError;
use super::fleet::{CellState, Fleet, Retired};
use super::memory::give_back_freed_memory;
use super::publish::{Outlet, RobotPublishers};
use super::requests::Request;
use super::self_calibration::{FitJob, fitting_thread, schedule_fits};
use super::snapshot::{save_final_snapshot, save_snapshot};
use crate::config::SelfCalibrationConfig;
use crate::snapshot::SnapshotStore;
use armtwin_codec::json;
use armtwin_core::pipeline::{Robot, Twin};
use armtwin_mesh::keys::Stream;

/// Totals reported when the service stops.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ServeReport {
    /// Inputs (samples and queries) processed.
    pub inputs: u64,
    /// Twin poses published.
    pub poses: u64,
    /// Robots tracked.
    pub robots: usize,
    /// Outputs Zenoh refused to send.
    pub publish_errors: u64,
}

/// Publishes the metrics of every robot with new results (and, for a robot whose effort is
/// watched, its payload message): each robot's metrics read out under its own lock, then encoded
/// and sent after it is released, so a robot's samples wait at most for its own readout, never
/// for a metrics message's encoding and sending.
fn publish_due_metrics(fleet: &Fleet) {
    let outlet = fleet.outlet();
    let now = Instant::now();
    fleet.for_each_cell(|cell| {
        let (readout, publisher) = {
            let mut state = cell.lock();
            // A robot that stopped streaming within an incident's `post_s` leaves its file.
            let stalled = (state.outputs_mut().recording_mut())
                .and_then(|recording| recording.cut_stalled(cell.robot().id(), now));
            if let Some(incident) = stalled {
                fleet.recorder().send(incident);
            }
            let Some(readout) = state.twin_mut().and_then(Twin::take_due_metrics) else {
                // No input since the last turn: a twin pose still waiting for its measured pose
                // on the paired stream waits no longer.
                if let Some((_, mut sink)) = fleet.twin_and_sink(&mut state) {
                    sink.release_paired_pose(true);
                }
                return;
            };
            let outputs = state.outputs_mut();
            outputs.counts_mut().last_active = Some(Instant::now());
            (readout, outputs.metrics_publisher())
        };
        if let Some(effort) = &readout.effort {
            let payload = json::payload_message_bytes(&readout.robot, effort);
            outlet.publish(None, &readout.robot, Stream::Payload, payload);
        }
        let payload = json::MetricsMessage::new(&readout).to_json_bytes();
        outlet.publish_metrics(publisher.as_deref(), &readout.robot, payload);
    });
}

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
        declarations.finish(fleet, robot.shared_id(), &mut state);
        debug!(
            robot = robot.id(),
            "robot retired: nothing from it for service.forget_after_s"
        );
    }
    declarations.undeclare(fleet.outlet());
    give_back_freed_memory();
    info!(
        robots = count,
        forget_after_s = forget_after.as_secs_f64(),
        "robots retired: nothing from them for service.forget_after_s"
    );
}

/// The publishers and tokens of robots whose twins were finished, to undeclare together; or, at
/// the end, to drop once the session is closed. Closing the session undeclares them at once on
/// every peer (each remote liveliness subscriber sees every token go), where undeclaring them
/// one by one costs, in Zenoh, in proportion to the entities still declared, each
/// (crates/armtwin-bench/README.md, "Stopping").
#[derive(Default)]
pub(super) struct Declarations {
    publishers: Vec<(Arc<str>, RobotPublishers)>,
    tokens: Vec<(Arc<str>, LivelinessToken)>,
}

impl Declarations {
    /// Finishes `state`'s twin, if it has one (its final metrics and unpaired measurements go
    /// out), and takes its publishers and token; whether it had a twin.
    fn finish(&mut self, fleet: &Fleet, id: &Arc<str>, state: &mut CellState) -> bool {
        let finished = fleet
            .twin_and_sink(state)
            .map(|(twin, mut sink)| twin.finish(&mut sink));
        // An incident still in its `post_s` is written with what it has.
        let incident = state.outputs_mut().recording_mut().and_then(|r| r.cut(id));
        if let Some(incident) = incident {
            fleet.recorder().send(incident);
        }
        let (publishers, token) = state.outputs_mut().take_declared();
        if let Some(publishers) = publishers {
            self.publishers.push((Arc::clone(id), publishers));
        }
        if let Some(token) = token {
            self.tokens.push((Arc::clone(id), token));
        }
        finished.is_some()
    }

    fn undeclare(self, outlet: &Outlet) {
        outlet.undeclare_all(self.publishers, self.tokens);
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
    install: impl FnOnce(&mut CellState, T),
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
    let outlet = fleet.outlet();
    match outlet.declare(robot.id()) {
        Ok(publishers) => {
            let refused = give_to_live_cell(fleet, robot, publishers, |state, publishers| {
                state.outputs_mut().set_publishers(publishers);
            });
            let installed = refused.is_none();
            if let Some(publishers) = refused {
                outlet.undeclare_all(
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
    match fleet.outlet().declare_metrics(robot.id()) {
        Ok(publisher) => {
            let _dropped = give_to_live_cell(fleet, robot, publisher, |state, publisher| {
                state.outputs_mut().set_metrics_publisher(publisher);
            });
        }
        Err(e) => {
            warn!(robot = robot.id(), error = %e, "cannot declare the robot's metrics publisher");
        }
    }
}

/// Starts the control thread: it declares robots' Zenoh entities as `requests` ask (never on
/// Zenoh's own threads), runs the periodic duties, and finishes the pipeline at the end; it
/// returns the report and what is still declared, to drop after the session is closed.
pub(super) fn spawn(
    fleet: Arc<Fleet>,
    requests: Receiver<Request>,
    periods: Periods,
    snapshots: Option<(SnapshotStore, Duration)>,
) -> Result<std::thread::JoinHandle<(ServeReport, Declarations)>, ServiceError> {
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
            let report = run(&fleet, &requests, schedule, &duties);
            // Closing the queue ends the fitting thread after its current fit.
            drop(jobs_tx);
            if fitting.join().is_err() {
                warn!("the self-calibration thread panicked");
            }
            report
        })
        .map_err(|e| ServiceError::Worker(e.to_string()))
}

/// The control thread's loop: requests as they come, duties as they fall due, until asked to
/// stop; then every twin finished, and the robots' publishers and tokens handed back.
fn run(
    fleet: &Fleet,
    requests: &Receiver<Request>,
    mut schedule: Schedule,
    duties: &Duties<'_>,
) -> (ServeReport, Declarations) {
    let outlet = fleet.outlet();
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
        match requests.recv_timeout(wait) {
            Ok(Request::Stop) | Err(RecvTimeoutError::Disconnected) => break,
            Ok(Request::Track(robot)) => match outlet.declare_token(robot.id()) {
                Ok(token) => {
                    info!(robot = robot.id(), "tracking robot");
                    // A robot retired meanwhile: its token goes at once.
                    if let Some(token) = give_to_live_cell(fleet, &robot, token, |state, token| {
                        state.outputs_mut().set_token(token);
                    }) {
                        outlet.undeclare_all(
                            Vec::new(),
                            vec![(Arc::clone(robot.shared_id()), token)],
                        );
                    }
                }
                Err(e) => {
                    warn!(robot = robot.id(), error = %e, "cannot declare the robot's liveliness token");
                }
            },
            Ok(Request::CacheRoutes(robot)) => undeclared.push_back(robot),
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
        if declarations.finish(fleet, cell.robot().shared_id(), guard) {
            robots += 1;
        }
    });
    let report = ServeReport {
        inputs: counted.inputs,
        poses: counted.poses,
        robots,
        publish_errors: outlet.publish_errors(),
    };
    if let Some(store) = duties.store {
        save_final_snapshot(fleet, store);
    }
    (report, declarations)
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
