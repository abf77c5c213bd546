//! The fleet: every robot the service tracks, each behind a lock of its own, and the one place
//! that takes the service's locks in their order.
//!
//! Must not publish, decode or declare anything itself: it hands out robots' cells, and the
//! callers step, answer and publish with a cell's lock alone.

#[cfg(debug_assertions)]
use std::cell::Cell;
use std::collections::HashMap;
use std::ops::RangeInclusive;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError, RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::time::{Duration, Instant};

use zenoh::key_expr::KeyExpr;

use super::calibration_slot::CalibrationSlot;
use super::events::EventBucket;
use super::publish::Outlet;
use super::recording::Recorder;
use super::sink::{RobotOutputState, Sinks, ZenohSink};
use crate::config::{ConfiguredTools, DescriptionRules, ServiceConfig};
use armtwin_codec::json;
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::{PipelineConfig, Robot, RobotDirectory, Sink, Twin, Untracked};
use armtwin_mesh::controller::ControllerFacts;
use armtwin_mesh::ros2::PublisherSeq;

/// Every robot the service tracks, shared by Zenoh's callbacks, the control and self-calibration
/// threads and the dashboard: each robot's twin and outputs behind a lock of its own
/// ([`RobotCell`]).
///
/// Samples are processed in Zenoh's receive callback itself, as the plain echo does: decode, FK,
/// statistics and the outputs' `put` take a few microseconds, and doing them there saves a queue,
/// a thread wake-up and a copy per sample. Backpressure is Zenoh's own: while the callback works,
/// its link is not read.
///
/// A sample finds its robot's cell in the [`Directory`] under its read lock (one hash of the id,
/// one index; a robot under the default settings is admitted, and a robot's cell made, under the
/// write lock on its first input, while the fleet has room) and clones the cell's `Arc` out: no
/// shared lock is held while it decodes against the cell's robot and steps the twin under the
/// cell's own lock. Samples of different robots never wait on each other's processing; samples of
/// one robot take turns on its lock. The sample path counts under the robot's lock only (its
/// inputs and poses): no counter shared by the fleet is written per sample, and the totals are the
/// robots' counts summed when read ([`Fleet::walk`]).
///
/// **Retirement.** A robot admitted under the default that sent nothing for `forget_after` is
/// retired by the control thread ([`Fleet::retire_idle`]): under the directory's write lock its
/// entry and cell slot go and its state is taken out of its cell, which is marked retired (and
/// keeps the robot's counts, for a walk that found it before). A sample that found the cell just
/// before sees the mark under the cell's lock and looks its robot up again, which admits it
/// afresh: no sample is lost to a retirement.
///
/// **Lock order**, held by this module: the directory, then one robot's cell. The directory's lock
/// is private here and no guard of it leaves this module, so only the functions below take it, and
/// each releases it before it returns a cell. A cell's lock is taken only through
/// [`RobotCell::lock`], whose guard (in debug builds) asserts that its thread holds no other cell
/// and takes no shared lock while it lives. Under a cell only leaf locks are taken,
/// briefly and never across a `put` (the untracked robots' event bucket, the snapshot time).
/// Nothing that can wait on the network runs under a robot's lock except its own outputs' `put`
/// (events and metrics with `block` congestion control, as the echo): a subscriber that stops
/// reading them stalls that robot and the Zenoh link's receive thread its input arrived on, not
/// the other robots. Declarations are made on the control thread.
pub(super) struct Fleet {
    /// `[service] robots`.
    shard: KeyExpr<'static>,
    /// Which robots' TCP the configuration sets.
    configured_tools: ConfiguredTools,
    /// The robots that take the model their controller says.
    models_from_controller: std::collections::HashSet<String>,
    /// What the robots' own descriptions do to their twins.
    descriptions: DescriptionRules,
    /// Descriptions refused: unreadable, too large or too frequent, of another joint count,
    /// or disagreeing with the robot's own model.
    descriptions_refused: AtomicU64,
    /// The models robots took from their own descriptions, by id: a robot retired and back
    /// computes with its own again (a transient-local description is not sent twice). At most
    /// `max_robots` of them; each shares its twin's model.
    taken_descriptions: Mutex<HashMap<Arc<str>, Arc<RobotModel>>>,
    /// `[service] max_robots`: the most `taken_descriptions` keeps.
    max_robots: usize,
    pipeline: PipelineConfig,
    directory: RwLock<Directory>,
    /// What every robot's sink shares.
    sinks: Sinks,
    /// Inputs that reached no robot's twin (queries, samples of robots refused) and those of
    /// robots since retired: with the robots' own counts, every input processed.
    inputs_elsewhere: AtomicU64,
    /// Twin poses of robots since retired.
    retired_poses: AtomicU64,
    /// Set by the control thread before it finishes the twins, each under its robot's lock:
    /// an input that takes a robot's lock after its twin was finished sees it and is ignored.
    stopped: AtomicBool,
    /// When the snapshot was last written (with `state_dir`). A leaf lock.
    snapshot_written: Mutex<Option<Instant>>,
    /// Samples of new robots refused because the fleet was full.
    refused_full: AtomicU64,
    /// Robots retired for sending nothing for `forget_after`.
    retired: AtomicU64,
    /// Snapshot writes that failed.
    snapshot_failures: AtomicU64,
    /// Snapshot writes failed since the last one that succeeded: the first is logged as a
    /// warning, the recovery as news, those between only counted.
    snapshot_failing: AtomicU64,
    /// When a refusal for a full fleet was last logged (ms on [`Fleet::clock_ms`]), so a flood of
    /// new ids logs once a minute, not once a sample.
    full_logged_ms: AtomicU64,
    /// The fleet's coarse clock: milliseconds since it was made, as of the control thread's last
    /// turn ([`Fleet::tick`]). A sample stamps its robot's last input with it: one relaxed load,
    /// where reading the system clock per sample would cost more than it tells.
    clock_ms: AtomicU64,
    started: Instant,
}

/// Who may be tracked, and each tracked robot's cell: one lock for both, so a sample finds its
/// robot's cell under a single read lock.
struct Directory {
    robots: RobotDirectory,
    /// By robot index, from the robot's first input (or its restored twin) on.
    cells: Vec<Option<Arc<RobotCell>>>,
}

impl Directory {
    /// `robot`'s cell, if it has one. `robot` must have been found in `robots` under the lock
    /// held: only then is its index its own.
    fn cell(&self, robot: &Robot) -> Option<Arc<RobotCell>> {
        self.cells.get(robot.index().get())?.clone()
    }

    /// `robot`'s cell, made now if it has none (with its last input at `now_ms`); `robot` as for
    /// [`cell`](Self::cell).
    fn cell_or_new(&mut self, robot: &Robot, now_ms: u64) -> Arc<RobotCell> {
        let index = robot.index().get();
        if self.cells.len() <= index {
            self.cells.resize_with(index + 1, || None);
        }
        Arc::clone(self.cells[index].get_or_insert_with(|| {
            Arc::new(RobotCell {
                robot: robot.clone(),
                state: Mutex::new(CellState {
                    last_input_ms: now_ms,
                    ..CellState::default()
                }),
            })
        }))
    }
}

/// Inputs processed and twin poses published, all robots.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) struct Totals {
    pub(super) inputs: u64,
    pub(super) poses: u64,
}

/// Where an input's robot id leads.
pub(super) enum Lookup {
    /// The robot's cell: configured, already tracked, or admitted now under the default settings.
    Found(Arc<RobotCell>),
    /// A robot of another instance (outside `[service] robots`): not this one's to take.
    Foreign,
    /// A robot this instance may not track: not configured while unknown robots are refused,
    /// or new while the fleet is full.
    Refused(Untracked),
}

/// One robot's place in the fleet: its handle, readable without a lock, beside the lock of
/// everything of it that changes.
pub(super) struct RobotCell {
    robot: Robot,
    state: Mutex<CellState>,
}

/// What a robot's cell holds under its lock: the robot's twin, its outputs' state and its
/// self-calibration.
#[derive(Default)]
pub(super) struct CellState {
    /// `None` until the robot's first input; its creation announces the robot
    /// ([`Sink::tracking`]).
    twin: Option<Twin>,
    outputs: RobotOutputState,
    calibration: CalibrationSlot,
    /// By `[[sources]]` index: how a ROS source's `rmw_zenoh` sequence numbers become gateway
    /// `seq`s (a robot has one or two sources at most: a short list beats a map).
    publisher_seqs: Vec<(usize, PublisherSeq)>,
    /// What a gateway last said of the robot's controller.
    controller: Option<ControllerFacts>,
    /// The robot's last description taken, boxed: most robots never send one.
    description: Option<Box<DescriptionSeen>>,
    /// Inputs stepped into the twin.
    inputs: u64,
    /// The robot's last input, on the fleet's clock ([`Fleet::clock_ms`]).
    last_input_ms: u64,
    /// The robot was retired: this cell is no longer the fleet's, and an input that finds it
    /// looks the robot up again.
    retired: bool,
}

/// What a robot's cell keeps of its descriptions ([`super::description`]).
#[derive(Debug)]
pub(super) struct DescriptionSeen {
    /// A hash of the last text read: the same text again is not read again.
    pub(super) digest: Option<u64>,
    /// The texts it may read.
    pub(super) reads: EventBucket,
    /// The refusals before reading it may say.
    pub(super) refusals: EventBucket,
}

#[cfg(debug_assertions)]
thread_local! {
    /// Robot cells this thread holds locked: at most one, and none while it takes a shared lock.
    static CELLS_HELD: Cell<u32> = const { Cell::new(0) };
}

/// Asserts, in debug builds, that this thread holds no robot's cell: the lock order's rule for
/// taking a shared lock or another cell.
fn assert_no_cell_held(taking: &str) {
    #[cfg(debug_assertions)]
    CELLS_HELD.with(|held| {
        assert!(
            held.get() == 0,
            "lock order: {taking} taken while holding a robot's cell"
        );
    });
    #[cfg(not(debug_assertions))]
    let _ = taking;
}

/// A robot's state, locked: the only way to it.
pub(super) struct CellGuard<'a> {
    guard: MutexGuard<'a, CellState>,
}

impl std::ops::Deref for CellGuard<'_> {
    type Target = CellState;
    fn deref(&self) -> &CellState {
        &self.guard
    }
}

impl std::ops::DerefMut for CellGuard<'_> {
    fn deref_mut(&mut self) -> &mut CellState {
        &mut self.guard
    }
}

impl Drop for CellGuard<'_> {
    fn drop(&mut self) {
        #[cfg(debug_assertions)]
        CELLS_HELD.with(|held| held.set(held.get() - 1));
    }
}

impl RobotCell {
    /// The robot this cell is of.
    pub(super) fn robot(&self) -> &Robot {
        &self.robot
    }

    /// The robot's state, locked.
    pub(super) fn lock(&self) -> CellGuard<'_> {
        assert_no_cell_held("a robot's cell");
        // A panic in a callback leaves the twin as consistent as each step left it; keep going.
        let guard = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        #[cfg(debug_assertions)]
        CELLS_HELD.with(|held| held.set(held.get() + 1));
        CellGuard { guard }
    }
}

/// One robot's twin locked for an input, with what the input's step needs beside it.
pub(super) struct Stepping<'a> {
    pub(super) twin: &'a mut Twin,
    pub(super) sink: ZenohSink<'a>,
    pub(super) publisher_seqs: &'a mut Vec<(usize, PublisherSeq)>,
    pub(super) controller: &'a mut Option<ControllerFacts>,
    pub(super) description: &'a mut Option<Box<DescriptionSeen>>,
}

impl CellState {
    /// Whether the robot was retired: this state is no longer the fleet's.
    pub(super) fn is_retired(&self) -> bool {
        self.retired
    }

    /// The robot's twin, from its first input on.
    pub(super) fn twin(&self) -> Option<&Twin> {
        self.twin.as_ref()
    }

    /// What a gateway last said of the robot's controller.
    pub(super) fn controller(&self) -> Option<&ControllerFacts> {
        self.controller.as_ref()
    }

    /// The same, to change.
    pub(super) fn twin_mut(&mut self) -> Option<&mut Twin> {
        self.twin.as_mut()
    }

    /// The robot's output state: its publishers, token and counts.
    pub(super) fn outputs(&self) -> &RobotOutputState {
        &self.outputs
    }

    /// The same, to change.
    pub(super) fn outputs_mut(&mut self) -> &mut RobotOutputState {
        &mut self.outputs
    }

    /// The robot's state answer (`None` before its first input), with what a gateway last said
    /// of its controller.
    pub(super) fn state_message(&self) -> Option<json::StateMessage> {
        let mut message = json::StateMessage::new(&self.twin.as_ref()?.state());
        message.controller = self
            .controller
            .as_ref()
            .and_then(|facts| serde_json::to_value(facts).ok());
        Some(message)
    }

    /// The robot's history answer for the completed seconds and minutes in `seconds` (`None`
    /// before its first input); `resolve` turns the robot's newest stamp into those seconds.
    pub(super) fn history_message(
        &self,
        robot: &str,
        resolve: impl FnOnce(Option<f64>) -> RangeInclusive<i64>,
    ) -> Option<json::HistoryMessage> {
        let twin = self.twin.as_ref()?;
        let newest_s = twin.newest_s();
        let seconds = resolve(newest_s);
        let rows = twin.history(seconds.clone());
        let minutes = twin.history_minutes(seconds);
        Some(json::HistoryMessage::new(
            robot,
            newest_s,
            json::HistorySpans {
                history_s: twin.history_s(),
                seconds_s: twin.history_exact_s(),
            },
            json::HistoryRows {
                seconds: &rows,
                minutes: &minutes,
            },
        ))
    }

    /// The robot's self-calibration fits.
    pub(super) fn calibration(&self) -> &CalibrationSlot {
        &self.calibration
    }

    /// The same, to change.
    pub(super) fn calibration_mut(&mut self) -> &mut CalibrationSlot {
        &mut self.calibration
    }

    /// The robot's twin (created, and the robot announced, on its first input) and a sink of its
    /// outputs: the twin and the sink borrow separate parts of the state.
    /// A twin made now computes with `taken`, the model the robot took from its own
    /// description before it was retired, if it did.
    fn stepping<'a>(
        &'a mut self,
        robot: &Robot,
        config: &PipelineConfig,
        sinks: &'a Sinks,
        taken: Option<Arc<RobotModel>>,
    ) -> Stepping<'a> {
        let mut sink = sinks.of(&mut self.outputs);
        let twin = self.twin.get_or_insert_with(|| {
            sink.tracking(robot);
            let mut twin = Twin::new(robot.clone(), config);
            if let Some(model) = taken {
                match twin.replace_model(Arc::clone(&model), &mut sink) {
                    Ok(_) => sink.model_replaced(robot, &model),
                    Err(error) => {
                        robot.set_joint_count(twin.model().joint_count());
                        tracing::warn!(robot = robot.id(), %error, "its own description cannot be its model again");
                    }
                }
            }
            sinks.history_log().attach(twin)
        });
        Stepping {
            twin,
            sink,
            publisher_seqs: &mut self.publisher_seqs,
            controller: &mut self.controller,
            description: &mut self.description,
        }
    }
}

/// What a retirement took out of a robot's cell: what is left to finish and undeclare, without
/// any lock.
pub(super) struct Retired {
    pub(super) robot: Robot,
    pub(super) state: CellState,
}

/// Robots retired under one hold of the shared write locks: a bound on how long samples of
/// other robots wait while a large fleet retires at once.
const RETIRE_BATCH: usize = 1024;

impl Fleet {
    /// No robot tracked yet; outputs go out through `sinks`.
    pub(super) fn new(config: &ServiceConfig, sinks: Sinks) -> Self {
        Self {
            shard: config.shard.clone(),
            configured_tools: config.configured_tools.clone(),
            models_from_controller: config.models_from_controller.clone(),
            descriptions: config.descriptions.clone(),
            descriptions_refused: AtomicU64::new(0),
            taken_descriptions: Mutex::new(HashMap::new()),
            max_robots: config.max_robots,
            pipeline: config.pipeline,
            directory: RwLock::new(Directory {
                robots: RobotDirectory::new(config.default_robot.clone(), config.robots.clone())
                    .limit_to(config.max_robots)
                    .with_groups(config.robot_groups.clone()),
                cells: Vec::new(),
            }),
            sinks,
            inputs_elsewhere: AtomicU64::new(0),
            retired_poses: AtomicU64::new(0),
            stopped: AtomicBool::new(false),
            snapshot_written: Mutex::new(None),
            refused_full: AtomicU64::new(0),
            retired: AtomicU64::new(0),
            snapshot_failures: AtomicU64::new(0),
            snapshot_failing: AtomicU64::new(0),
            full_logged_ms: AtomicU64::new(0),
            clock_ms: AtomicU64::new(0),
            started: Instant::now(),
        }
    }

    /// The outlet every robot's outputs go out through.
    pub(super) fn outlet(&self) -> &Outlet {
        self.sinks.outlet()
    }

    /// What the log of the histories' closed minutes holds and lost.
    pub(super) fn history_log_totals(&self) -> armtwin_view::HistoryLogTotals {
        self.sinks.history_log().totals()
    }

    /// The flight recorder every robot's sink feeds.
    pub(super) fn recorder(&self) -> &Recorder {
        self.sinks.recorder()
    }

    /// `state`'s twin, if it has one, with a sink of its outputs: for a call into the twin off
    /// the sample path (a reset, a model replaced, the final metrics).
    pub(super) fn twin_and_sink<'a>(
        &'a self,
        state: &'a mut CellState,
    ) -> Option<(&'a mut Twin, ZenohSink<'a>)> {
        let twin = state.twin.as_mut()?;
        Some((twin, self.sinks.of(&mut state.outputs)))
    }

    /// Gives `state`, `robot`'s locked, the restored `twin`, announcing the robot as its first
    /// input would ([`Sink::tracking`]), unless the robot has a twin already; whether it did.
    #[must_use = "a twin not installed is dropped"]
    pub(super) fn install_twin(&self, robot: &Robot, state: &mut CellState, twin: Twin) -> bool {
        if state.twin.is_some() {
            return false;
        }
        let model = Arc::clone(twin.model());
        let mut sink = self.sinks.of(&mut state.outputs);
        sink.tracking(robot);
        // A restored twin may compute with an applied calibration: its files draw that.
        sink.model_replaced(robot, &model);
        drop(sink);
        state.twin = Some(self.sinks.history_log().attach(twin));
        true
    }

    /// A sink for the rejection of an input of a robot that may not be tracked.
    pub(super) fn untracked_sink(&self) -> ZenohSink<'_> {
        self.sinks.untracked()
    }

    /// Advances the fleet's coarse clock to now (the control thread, at each turn).
    pub(super) fn tick(&self) {
        let now_ms = u64::try_from(self.started.elapsed().as_millis()).unwrap_or(u64::MAX);
        self.clock_ms.store(now_ms, Ordering::Relaxed);
    }

    /// The fleet's coarse clock (ms since it was made, as of the last [`tick`](Self::tick)).
    fn clock_ms(&self) -> u64 {
        self.clock_ms.load(Ordering::Relaxed)
    }

    /// Time since `state`'s robot last had an input, now (its input stamped to the coarse
    /// clock's last tick, so up to one control-thread turn more).
    pub(super) fn since_last_input(&self, state: &CellState) -> Duration {
        self.started
            .elapsed()
            .saturating_sub(Duration::from_millis(state.last_input_ms))
    }

    /// Counts a sample of a new robot refused for a full fleet; whether to log it (at most once
    /// a minute).
    pub(super) fn refuse_full(&self) -> bool {
        let refused = self.refused_full.fetch_add(1, Ordering::Relaxed) + 1;
        let now_ms = self.clock_ms();
        let last_ms = self.full_logged_ms.load(Ordering::Relaxed);
        if refused > 1 && now_ms.saturating_sub(last_ms) < 60_000 {
            return false;
        }
        // One thread of those that see the minute pass logs.
        self.full_logged_ms
            .compare_exchange(last_ms, now_ms, Ordering::Relaxed, Ordering::Relaxed)
            .is_ok()
    }

    /// Samples of new robots refused because the fleet was full, so far.
    pub(super) fn robots_refused(&self) -> u64 {
        self.refused_full.load(Ordering::Relaxed)
    }

    /// Robots retired for sending nothing for `forget_after`, so far.
    pub(super) fn robots_retired(&self) -> u64 {
        self.retired.load(Ordering::Relaxed)
    }

    /// Robots in the directory (configured and admitted) and the most it holds.
    pub(super) fn occupancy(&self) -> (usize, usize) {
        let directory = self.read_directory();
        (directory.robots.len(), directory.robots.max_robots())
    }

    fn read_directory(&self) -> RwLockReadGuard<'_, Directory> {
        assert_no_cell_held("the robot directory");
        // Entries are added and removed whole: a panic cannot leave half of one.
        self.directory
            .read()
            .unwrap_or_else(PoisonError::into_inner)
    }

    fn write_directory(&self) -> RwLockWriteGuard<'_, Directory> {
        assert_no_cell_held("the robot directory");
        self.directory
            .write()
            .unwrap_or_else(PoisonError::into_inner)
    }

    /// Robot `id`'s handle, if it is configured or tracked.
    pub(super) fn find(&self, id: &str) -> Option<Robot> {
        self.read_directory().robots.find(id).cloned()
    }

    /// The model robot `id`'s settings give it (configured, or the default's), if any.
    pub(super) fn configured_model(&self, id: &str) -> Option<Arc<RobotModel>> {
        self.read_directory()
            .robots
            .settings_for(id)
            .map(|settings| Arc::clone(&settings.model))
    }

    /// Whether the configuration sets robot `id`'s TCP: if not, the twin takes its controller's.
    pub(super) fn tool_configured(&self, id: &str) -> bool {
        self.configured_tools.sets(id)
    }

    /// What the robots' own descriptions do to their twins.
    pub(super) fn descriptions(&self) -> &DescriptionRules {
        &self.descriptions
    }

    /// Counts a refused description.
    pub(super) fn description_refused(&self) {
        self.descriptions_refused.fetch_add(1, Ordering::Relaxed);
    }

    /// Descriptions refused so far.
    pub(super) fn descriptions_refused(&self) -> u64 {
        self.descriptions_refused.load(Ordering::Relaxed)
    }

    /// Robot `robot` computes with `model`, taken from its own description: kept for its
    /// return after a retirement (unless `max_robots` others are kept).
    pub(super) fn remember_description(&self, robot: &Robot, model: &Arc<RobotModel>) {
        let mut taken = self
            .taken_descriptions
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if taken.len() < self.max_robots || taken.contains_key(robot.id()) {
            taken.insert(Arc::clone(robot.shared_id()), Arc::clone(model));
        }
    }

    /// The model robot `id` took from its own description, if it did.
    pub(super) fn taken_description(&self, id: &str) -> Option<Arc<RobotModel>> {
        self.taken_descriptions
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .get(id)
            .cloned()
    }

    /// Whether robot `id` takes the model its controller says (see
    /// [`ServiceConfig::models_from_controller`]).
    pub(super) fn model_from_controller(&self, id: &str) -> bool {
        self.models_from_controller.contains(id)
    }

    /// Admits robot `id` under the default settings (or finds it configured or tracked), or
    /// says why this instance may not track it.
    pub(super) fn admit(&self, id: &str) -> Result<Robot, Untracked> {
        self.write_directory().robots.admit(id).cloned()
    }

    /// Where an input of robot `id` goes: its cell (a robot under the default settings is
    /// admitted on its first input), or why it has none.
    pub(super) fn lookup(&self, id: &str) -> Lookup {
        let known = {
            let directory = self.read_directory();
            if let Some(robot) = directory.robots.find(id) {
                // Taken under the directory's lock: a retirement, which holds it for writing,
                // cannot come between the robot and its cell.
                if let Some(cell) = directory.cell(robot) {
                    return Lookup::Found(cell);
                }
                true
            } else {
                // Made-up ids of a service that rejects unknown robots, or of a full fleet, never
                // take the write lock.
                if let Err(why) = directory.robots.admission_of(id) {
                    if !crate::config::owns(&self.shard, id) {
                        return Lookup::Foreign;
                    }
                    return Lookup::Refused(why);
                }
                false
            }
        };
        // Inputs of another instance's robots reach this one only through a `[[sources]]` key
        // that covers several shards: they are that instance's to take.
        if !known && !crate::config::owns(&self.shard, id) {
            return Lookup::Foreign;
        }
        let now_ms = self.clock_ms();
        let mut directory = self.write_directory();
        let directory = &mut *directory;
        match directory.robots.admit(id) {
            Ok(robot) => {
                let robot = robot.clone();
                // Back after a retirement, its inputs are decoded against its own description's
                // joints from the first.
                if let Some(model) = self.taken_description(id) {
                    robot.set_joint_count(model.joint_count());
                }
                Lookup::Found(directory.cell_or_new(&robot, now_ms))
            }
            Err(why) => Lookup::Refused(why),
        }
    }

    /// Robot `id`'s cell, if it has one.
    pub(super) fn existing_cell_of(&self, id: &str) -> Option<Arc<RobotCell>> {
        let directory = self.read_directory();
        directory.cell(directory.robots.find(id)?)
    }

    /// `robot`'s cell while it is the fleet's: `None` once the robot was retired (its handle is
    /// then stale, and its index may be another robot's).
    pub(super) fn live_cell(&self, robot: &Robot) -> Option<Arc<RobotCell>> {
        let is_current = |current: &Robot| Arc::ptr_eq(current.shared_id(), robot.shared_id());
        {
            let directory = self.read_directory();
            let current = directory
                .robots
                .find(robot.id())
                .filter(|c| is_current(c))?;
            if let Some(cell) = directory.cell(current) {
                return Some(cell);
            }
        }
        let now_ms = self.clock_ms();
        let mut directory = self.write_directory();
        let current = directory
            .robots
            .find(robot.id())
            .filter(|c| is_current(c))?
            .clone();
        Some(directory.cell_or_new(&current, now_ms))
    }

    /// Retires every robot admitted under the default that has had no input for `idle`: each
    /// leaves the directory and its cell slot, its state is taken out of its cell (marked
    /// retired) and returned, so the caller finishes and undeclares it without any lock.
    pub(super) fn retire_idle(&self, idle: Duration) -> Vec<Retired> {
        let idle_ms = u64::try_from(idle.as_millis()).unwrap_or(u64::MAX);
        let now_ms = self.clock_ms();
        let is_idle = |state: &CellState| now_ms.saturating_sub(state.last_input_ms) >= idle_ms;
        // Found without the write lock (each cell's lock taken alone), checked again under it.
        let mut candidates = self.cells();
        {
            let directory = self.read_directory();
            candidates.retain(|cell| !directory.robots.is_configured(&cell.robot));
        }
        candidates.retain(|cell| is_idle(&cell.lock()));
        let mut retired = Vec::with_capacity(candidates.len());
        for batch in candidates.chunks(RETIRE_BATCH) {
            let mut directory = self.write_directory();
            for cell in batch {
                let mut guard = cell.lock();
                if guard.retired || !is_idle(&guard) || !directory.robots.forget(&cell.robot) {
                    continue;
                }
                if let Some(slot) = directory.cells.get_mut(cell.robot.index().get()) {
                    *slot = None;
                }
                let state = std::mem::take(&mut *guard);
                // The counts move to the fleet's under the directory's write lock, and stay in
                // the cell for a walk that took the cells before ([`Fleet::walk`]).
                guard.retired = true;
                guard.inputs = state.inputs;
                guard.outputs.counts_mut().poses = state.outputs.counts().poses;
                self.inputs_elsewhere
                    .fetch_add(state.inputs, Ordering::Relaxed);
                self.retired_poses
                    .fetch_add(state.outputs.counts().poses, Ordering::Relaxed);
                retired.push(Retired {
                    robot: cell.robot.clone(),
                    state,
                });
            }
        }
        self.retired.fetch_add(
            u64::try_from(retired.len()).unwrap_or(u64::MAX),
            Ordering::Relaxed,
        );
        retired
    }

    /// Every robot's cell, in index order: taken out so the robots can be locked one by one.
    pub(super) fn cells(&self) -> Vec<Arc<RobotCell>> {
        let directory = self.read_directory();
        directory.cells.iter().flatten().cloned().collect()
    }

    /// Calls `visit` with every robot's cell, in index order, a batch of cells at a time taken
    /// out under the directory's read lock: no list of the whole fleet is made, and admissions
    /// wait at most for one batch to be copied. A robot admitted or retired during the walk may
    /// be visited or not.
    pub(super) fn for_each_cell(&self, mut visit: impl FnMut(&Arc<RobotCell>)) {
        const BATCH: usize = 256;
        let mut batch = Vec::with_capacity(BATCH);
        let mut next = 0;
        loop {
            {
                let directory = self.read_directory();
                let Some(rest) = directory.cells.get(next..) else {
                    return;
                };
                let taken = rest.iter().take(BATCH);
                next += taken.len();
                batch.extend(taken.flatten().cloned());
                if next == directory.cells.len() && batch.is_empty() {
                    return;
                }
            }
            for cell in batch.drain(..) {
                visit(&cell);
            }
        }
    }

    /// Every robot's cell, locked in turn and handed to `visit` (under the robot's lock alone),
    /// and the fleet's totals: the robots' counts summed with the fleet's. The cells and the
    /// fleet's counts are taken under one read lock, and a robot retired since keeps its counts
    /// in its cell, so each input and pose is counted once.
    pub(super) fn walk(&self, mut visit: impl FnMut(&RobotCell, &mut CellGuard<'_>)) -> Totals {
        let (cells, mut totals) = {
            let directory = self.read_directory();
            let cells: Vec<_> = directory.cells.iter().flatten().cloned().collect();
            let totals = Totals {
                inputs: self.inputs_elsewhere.load(Ordering::Relaxed),
                poses: self.retired_poses.load(Ordering::Relaxed),
            };
            (cells, totals)
        };
        for cell in &cells {
            let mut guard = cell.lock();
            if !guard.retired {
                visit(cell, &mut guard);
            }
            totals.inputs += guard.inputs;
            totals.poses += guard.outputs.counts().poses;
        }
        totals
    }

    /// Whether the control thread has begun finishing the twins.
    pub(super) fn is_stopped(&self) -> bool {
        self.stopped.load(Ordering::Acquire)
    }

    /// Marks the fleet stopped, before any twin is finished: an input that takes a robot's lock
    /// after the control thread finished that robot's twin sees it and is ignored.
    pub(super) fn stop(&self) {
        self.stopped.store(true, Ordering::Release);
    }

    /// `cell`'s state, locked, unless the service stopped (checked under the lock: the control
    /// thread finishes each twin under its lock once stopped).
    pub(super) fn unless_stopped<'c>(&self, cell: &'c RobotCell) -> Option<CellGuard<'c>> {
        let guard = cell.lock();
        (!self.is_stopped()).then_some(guard)
    }

    /// Steps `cell`'s twin with one input under the robot's lock alone, unless the service
    /// stopped. `false` if the robot was retired since its cell was found: `input` did not run,
    /// and the caller looks the robot up again.
    #[must_use = "an input of a retired robot goes to its new cell"]
    pub(super) fn step(&self, cell: &RobotCell, input: impl FnOnce(Stepping<'_>)) -> bool {
        let Some(mut guard) = self.unless_stopped(cell) else {
            return true;
        };
        if guard.retired {
            return false;
        }
        guard.inputs += 1;
        guard.last_input_ms = self.clock_ms();
        let taken = guard
            .twin
            .is_none()
            .then(|| self.taken_description(cell.robot.id()))
            .flatten();
        input(guard.stepping(&cell.robot, &self.pipeline, &self.sinks, taken));
        true
    }

    /// Counts one input that reaches no robot's twin (a query, a refused robot's sample), unless
    /// the service stopped; whether it did.
    pub(super) fn count_input(&self) -> bool {
        if self.is_stopped() {
            return false;
        }
        self.inputs_elsewhere.fetch_add(1, Ordering::Relaxed);
        true
    }

    /// Notes that the snapshot was written now; the writes that had failed in a row before it.
    pub(super) fn snapshot_saved(&self) -> u64 {
        *self
            .snapshot_written
            .lock()
            .unwrap_or_else(PoisonError::into_inner) = Some(Instant::now());
        self.snapshot_failing.swap(0, Ordering::Relaxed)
    }

    /// Counts a snapshot write that failed; whether it is the first since one succeeded.
    pub(super) fn snapshot_failed(&self) -> bool {
        self.snapshot_failures.fetch_add(1, Ordering::Relaxed);
        self.snapshot_failing.fetch_add(1, Ordering::Relaxed) == 0
    }

    /// Snapshot writes that failed, so far.
    pub(super) fn snapshot_failures(&self) -> u64 {
        self.snapshot_failures.load(Ordering::Relaxed)
    }

    /// Seconds since the snapshot was last written, once it has been.
    pub(super) fn snapshot_age_s(&self) -> Option<f64> {
        self.snapshot_written
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .map(|written| written.elapsed().as_secs_f64())
    }
}

#[cfg(test)]
mod tests {
    #![allow(
        clippy::expect_used,
        reason = "a test that fails an expectation fails the test"
    )]

    use std::path::Path;
    use std::sync::Arc;

    use super::super::publish::Outlet;
    use super::super::requests;
    use super::super::sink::Sinks;
    use super::{Fleet, Lookup};
    use crate::config::{Overrides, ServiceConfig};
    use armtwin_core::pipeline::Untracked;

    /// A fleet on a session that joins nothing: it listens nowhere, scouts nothing and connects
    /// to nobody, so its puts go nowhere.
    async fn fleet_of(toml: &str) -> Arc<Fleet> {
        let config = ServiceConfig::parse(toml, "test", Path::new("."), &Overrides::default())
            .expect("valid configuration");
        let mut zenoh = zenoh::Config::default();
        for (key, value) in [
            ("listen/endpoints", "[]"),
            ("connect/endpoints", "[]"),
            ("scouting/multicast/enabled", "false"),
        ] {
            zenoh.insert_json5(key, value).expect("zenoh key");
        }
        let session = zenoh::open(zenoh).await.expect("session");
        let (requests, _) = requests::queue();
        let outlet = Outlet::new(session, &config);
        Arc::new(Fleet::new(
            &config,
            Sinks::new(
                outlet,
                requests,
                config.event_budget,
                super::super::recording::Recorder::new(config.recorder.clone(), None),
            ),
        ))
    }

    const SHARDED: &str = r#"
[service]
robots = "lab/**"
reject_unknown = true
[robots."lab/r1"]
model = "ur5e"
"#;

    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    async fn inputs_find_configured_robots_and_refuse_others_and_foreign_ones() {
        let fleet = fleet_of(SHARDED).await;
        let Lookup::Found(cell) = fleet.lookup("lab/r1") else {
            panic!("a configured robot has a cell");
        };
        assert_eq!(cell.robot.id(), "lab/r1");
        // The same cell on every look-up: one lock per robot.
        let Lookup::Found(again) = fleet.lookup("lab/r1") else {
            panic!("found again");
        };
        assert!(Arc::ptr_eq(&cell, &again));
        assert!(matches!(
            fleet.lookup("lab/unknown"),
            Lookup::Refused(Untracked::Unknown)
        ));
        assert!(matches!(fleet.lookup("plant/r1"), Lookup::Foreign));
        assert_eq!(fleet.cells().len(), 1);
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    async fn unlisted_robots_are_admitted_under_the_default_when_allowed() {
        let fleet = fleet_of("[service]\nrobots = \"lab/**\"\n").await;
        let Lookup::Found(cell) = fleet.lookup("lab/new") else {
            panic!("admitted under the default");
        };
        assert_eq!(cell.robot.id(), "lab/new");
        assert!(fleet.find("lab/new").is_some());
        assert!(matches!(fleet.lookup("plant/new"), Lookup::Foreign));
        assert!(fleet.find("plant/new").is_none());
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    async fn a_stopped_fleet_steps_and_counts_nothing() {
        let fleet = fleet_of(SHARDED).await;
        let Lookup::Found(cell) = fleet.lookup("lab/r1") else {
            panic!("found");
        };
        assert!(fleet.count_input());
        let mut stepped = 0;
        assert!(fleet.step(&cell, |_| stepped += 1));
        assert_eq!(stepped, 1);
        fleet.stop();
        assert!(
            fleet.step(&cell, |_| stepped += 1),
            "done with, not retired"
        );
        assert!(!fleet.count_input());
        assert_eq!(stepped, 1);
        assert_eq!(fleet.walk(|_, _| {}).inputs, 2);
        assert!(fleet.unless_stopped(&cell).is_none());
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    async fn totals_sum_the_robots_counts_and_keep_those_of_retired_robots() {
        let fleet = fleet_of("[service]\nrobots = \"lab/**\"\n").await;
        let (Lookup::Found(a), Lookup::Found(b)) = (fleet.lookup("lab/a"), fleet.lookup("lab/b"))
        else {
            panic!("both admitted");
        };
        for cell in [&a, &a, &b] {
            assert!(fleet.step(cell, |_| {}));
        }
        assert!(fleet.count_input());
        let mut visited = Vec::new();
        let totals = fleet.walk(|cell, _| visited.push(cell.robot.id().to_owned()));
        assert_eq!(visited, ["lab/a", "lab/b"]);
        assert_eq!(totals.inputs, 4);
        let retired = fleet.retire_idle(std::time::Duration::ZERO);
        assert_eq!(retired.len(), 2);
        // A retired cell keeps its counts for a walk that took it before the retirement; the
        // fleet's own count has them now, and a walk after finds no cell.
        assert_eq!(a.lock().inputs, 2);
        let mut visited = 0;
        assert_eq!(fleet.walk(|_, _| visited += 1).inputs, 4);
        assert_eq!(visited, 0);
        let mut cells = 0;
        fleet.for_each_cell(|_| cells += 1);
        assert_eq!(cells, 0);
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    async fn for_each_cell_visits_a_fleet_larger_than_a_batch_once_each() {
        let fleet = fleet_of("[service]\nrobots = \"lab/**\"\n").await;
        for robot in 0..600 {
            assert!(matches!(
                fleet.lookup(&format!("lab/r{robot}")),
                Lookup::Found(_)
            ));
        }
        let mut ids = Vec::new();
        fleet.for_each_cell(|cell| ids.push(cell.robot.id().to_owned()));
        assert_eq!(ids.len(), 600);
        ids.sort();
        ids.dedup();
        assert_eq!(ids.len(), 600);
    }

    #[cfg(debug_assertions)]
    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    #[should_panic(expected = "lock order")]
    async fn taking_the_directory_under_a_robots_cell_is_caught() {
        let fleet = fleet_of(SHARDED).await;
        let Lookup::Found(cell) = fleet.lookup("lab/r1") else {
            panic!("found");
        };
        let _guard = cell.lock();
        let _ = fleet.find("lab/r1");
    }

    #[cfg(debug_assertions)]
    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    #[should_panic(expected = "lock order")]
    async fn a_second_cell_under_a_first_is_caught() {
        let fleet = fleet_of("[service]\nrobots = \"lab/**\"\n").await;
        let (Lookup::Found(a), Lookup::Found(b)) = (fleet.lookup("lab/a"), fleet.lookup("lab/b"))
        else {
            panic!("both admitted");
        };
        let _first = a.lock();
        let _second = b.lock();
    }

    #[cfg(debug_assertions)]
    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    async fn a_released_cell_leaves_the_thread_free_to_take_the_directory() {
        let fleet = fleet_of(SHARDED).await;
        let Lookup::Found(cell) = fleet.lookup("lab/r1") else {
            panic!("found");
        };
        drop(cell.lock());
        assert!(fleet.find("lab/r1").is_some());
        let guard = fleet.unless_stopped(&cell);
        drop(guard);
        assert_eq!(fleet.cells().len(), 1);
    }
}
