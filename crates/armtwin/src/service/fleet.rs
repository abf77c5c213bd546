//! The fleet: every robot the service tracks, each behind a lock of its own, and the one place
//! that takes the service's locks in their order.
//!
//! Must not publish, decode or declare anything itself: it hands out robots' cells, and the
//! callers step, answer and publish with a cell's lock alone.

use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError, RwLock, RwLockReadGuard};
use std::time::Instant;

use zenoh::key_expr::KeyExpr;

use super::publish::Outputs;
use super::self_calibration::CalibrationSlot;
use super::sink::{RobotOutputState, ZenohSink};
use crate::config::ServiceConfig;
use crate::model::RobotModel;
use crate::pipeline::{PipelineConfig, Robot, RobotDirectory, Sink, Twin};
use crate::ros2::PublisherSeq;

/// Every robot the service tracks, shared by Zenoh's callbacks, the control and self-calibration
/// threads and the dashboard: each robot's twin and outputs behind a lock of its own
/// ([`RobotCell`]).
///
/// Samples are processed in Zenoh's receive callback itself, as the plain echo does: decode, FK,
/// statistics and the outputs' `put` take a few microseconds, and doing them there saves a queue,
/// a thread wake-up and a copy per sample. Backpressure is Zenoh's own: while the callback works,
/// its link is not read.
///
/// A sample finds its robot in `robots` under a read lock (one hash of the id; a robot under the
/// default settings is admitted, under the write lock, on its first input), then the robot's
/// cell in `cells` under that vector's read lock (added, under its write lock, on the robot's
/// first input), and clones the cell's `Arc` out: no shared lock is held while it decodes
/// against the cell's robot and steps the twin under the cell's own lock. Samples of different
/// robots never wait on each other's processing; samples of one robot take turns on its lock.
///
/// **Lock order**, held by this module: `robots`, then `cells`, then one robot's cell. Both
/// shared locks are private here and no guard of them leaves this module, so only the functions
/// below take them, and each releases them before it returns a cell. A cell's lock is taken only
/// through [`RobotCell::lock`], whose guard (in debug builds) asserts that its thread holds no
/// other cell and takes no shared lock while it lives. Under a cell only leaf locks are taken,
/// briefly and never across a `put` (the untracked robots' event bucket, the snapshot time).
/// Nothing that can wait on the network runs under a robot's lock except its own outputs' `put`
/// (events and metrics with `block` congestion control, as the echo): a subscriber that stops
/// reading them stalls that robot and the Zenoh link's receive thread its input arrived on, not
/// the other robots. Declarations are made on the control thread.
pub(super) struct Fleet {
    /// `[service] robots`.
    shard: KeyExpr<'static>,
    pub(super) pipeline: PipelineConfig,
    robots: RwLock<RobotDirectory>,
    /// By robot index, from the robot's first input (or its restored twin) on.
    cells: RwLock<Vec<Option<Arc<RobotCell>>>>,
    /// What every robot's outputs share.
    pub(super) outputs: Outputs,
    /// Inputs (samples and queries) processed.
    pub(super) inputs: AtomicU64,
    /// Set by the control thread before it finishes the twins, each under its robot's lock:
    /// an input that takes a robot's lock after its twin was finished sees it and is ignored.
    stopped: AtomicBool,
    /// When the snapshot was last written (with `state_dir`). A leaf lock.
    snapshot_written: Mutex<Option<Instant>>,
}

/// Where an input's robot id leads.
pub(super) enum Lookup {
    /// The robot's cell: configured, already tracked, or admitted now under the default settings.
    Found(Arc<RobotCell>),
    /// A robot of another instance (outside `[service] robots`): not this one's to take.
    Foreign,
    /// A robot this instance may not track (not configured, and unknown robots are refused).
    Refused,
}

/// One robot's place in the fleet: its handle, readable without a lock, beside the lock of
/// everything of it that changes.
pub(super) struct RobotCell {
    pub(super) robot: Robot,
    state: Mutex<RobotState>,
}

/// A robot's twin, its outputs' state and its self-calibration; behind its [`RobotCell`]'s lock.
#[derive(Default)]
pub(super) struct RobotState {
    /// `None` until the robot's first input; its creation announces the robot
    /// ([`Sink::tracking`]).
    pub(super) twin: Option<Twin>,
    pub(super) outputs: RobotOutputState,
    pub(super) calibration: CalibrationSlot,
    /// By `[[sources]]` index: how a ROS source's `rmw_zenoh` sequence numbers become gateway
    /// `seq`s (a robot has one or two sources at most: a short list beats a map).
    pub(super) publisher_seqs: Vec<(usize, PublisherSeq)>,
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
    guard: MutexGuard<'a, RobotState>,
}

impl std::ops::Deref for CellGuard<'_> {
    type Target = RobotState;
    fn deref(&self) -> &RobotState {
        &self.guard
    }
}

impl std::ops::DerefMut for CellGuard<'_> {
    fn deref_mut(&mut self) -> &mut RobotState {
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
}

impl RobotState {
    /// The robot's twin (created, and the robot announced, on its first input) and a sink of its
    /// outputs: the twin and the sink borrow separate parts of the entry.
    fn stepping<'a>(
        &'a mut self,
        robot: &Robot,
        config: &PipelineConfig,
        outputs: &'a Outputs,
    ) -> Stepping<'a> {
        let mut sink = ZenohSink::of(outputs, &mut self.outputs);
        let twin = self.twin.get_or_insert_with(|| {
            sink.tracking(robot);
            Twin::new(robot.clone(), config)
        });
        Stepping {
            twin,
            sink,
            publisher_seqs: &mut self.publisher_seqs,
        }
    }
}

impl Fleet {
    /// No robot tracked yet; outputs go out through `outputs`.
    pub(super) fn new(config: &ServiceConfig, outputs: Outputs) -> Self {
        Self {
            shard: config.shard.clone(),
            pipeline: config.pipeline,
            robots: RwLock::new(RobotDirectory::new(
                config.default_robot.clone(),
                config.robots.clone(),
            )),
            cells: RwLock::new(Vec::new()),
            outputs,
            inputs: AtomicU64::new(0),
            stopped: AtomicBool::new(false),
            snapshot_written: Mutex::new(None),
        }
    }

    fn read_robots(&self) -> RwLockReadGuard<'_, RobotDirectory> {
        assert_no_cell_held("the robot directory");
        // The directory only grows, one whole entry at a time: a panic cannot leave half of one.
        self.robots.read().unwrap_or_else(PoisonError::into_inner)
    }

    /// Robot `id`'s handle, if it is configured or tracked.
    pub(super) fn find(&self, id: &str) -> Option<Robot> {
        self.read_robots().find(id).cloned()
    }

    /// The model robot `id`'s settings give it (configured, or the default's), if any.
    pub(super) fn configured_model(&self, id: &str) -> Option<Arc<RobotModel>> {
        self.read_robots()
            .settings_for(id)
            .map(|settings| Arc::clone(&settings.model))
    }

    /// Admits robot `id` under the default settings (or finds it configured); `None` if this
    /// instance may not track it.
    pub(super) fn admit(&self, id: &str) -> Option<Robot> {
        assert_no_cell_held("the robot directory");
        let mut robots = self.robots.write().unwrap_or_else(PoisonError::into_inner);
        robots.admit(id).ok().cloned()
    }

    /// Where an input of robot `id` goes: its cell (a robot under the default settings is
    /// admitted on its first input), or why it has none.
    pub(super) fn lookup(&self, id: &str) -> Lookup {
        let admits_unlisted = {
            let robots = self.read_robots();
            match robots.find(id) {
                Some(robot) => return Lookup::Found(self.cell(robot)),
                None => robots.admits_unlisted(),
            }
        };
        // Inputs of another instance's robots reach this one only through a `[[sources]]` key
        // that covers several shards: they are that instance's to take.
        if !crate::config::owns(&self.shard, id) {
            return Lookup::Foreign;
        }
        // Made-up ids of a service that rejects unknown robots never take the write lock.
        if !admits_unlisted {
            return Lookup::Refused;
        }
        match self.admit(id) {
            Some(robot) => Lookup::Found(self.cell(&robot)),
            None => Lookup::Refused,
        }
    }

    /// Robot `id`'s cell, if it has one.
    pub(super) fn existing_cell_of(&self, id: &str) -> Option<Arc<RobotCell>> {
        let index = self.read_robots().find(id)?.index();
        assert_no_cell_held("the fleet's cells");
        // Grows only, one whole cell at a time, like the directory.
        let cells = self.cells.read().unwrap_or_else(PoisonError::into_inner);
        cells.get(index.get())?.clone()
    }

    /// `robot`'s cell, added on first use.
    pub(super) fn cell(&self, robot: &Robot) -> Arc<RobotCell> {
        assert_no_cell_held("the fleet's cells");
        let index = robot.index().get();
        {
            let cells = self.cells.read().unwrap_or_else(PoisonError::into_inner);
            if let Some(Some(cell)) = cells.get(index) {
                return Arc::clone(cell);
            }
        }
        let mut cells = self.cells.write().unwrap_or_else(PoisonError::into_inner);
        if cells.len() <= index {
            cells.resize_with(index + 1, || None);
        }
        Arc::clone(cells[index].get_or_insert_with(|| {
            Arc::new(RobotCell {
                robot: robot.clone(),
                state: Mutex::new(RobotState::default()),
            })
        }))
    }

    /// Every robot's cell, in index order: taken out so the robots can be locked one by one.
    pub(super) fn cells(&self) -> Vec<Arc<RobotCell>> {
        assert_no_cell_held("the fleet's cells");
        let cells = self.cells.read().unwrap_or_else(PoisonError::into_inner);
        cells.iter().flatten().cloned().collect()
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

    /// `cell`'s state for one more input, unless the service stopped.
    fn running<'c>(&self, cell: &'c RobotCell) -> Option<CellGuard<'c>> {
        let guard = self.unless_stopped(cell)?;
        self.inputs.fetch_add(1, Ordering::Relaxed);
        Some(guard)
    }

    /// Steps `cell`'s twin with one input under the robot's lock alone, unless the service
    /// stopped.
    pub(super) fn step(&self, cell: &RobotCell, input: impl FnOnce(Stepping<'_>)) {
        if let Some(mut guard) = self.running(cell) {
            input(guard.stepping(&cell.robot, &self.pipeline, &self.outputs));
        }
    }

    /// Counts one input that reaches no robot's twin (a query, a refused robot's sample), unless
    /// the service stopped; whether it did.
    pub(super) fn count_input(&self) -> bool {
        if self.is_stopped() {
            return false;
        }
        self.inputs.fetch_add(1, Ordering::Relaxed);
        true
    }

    /// Notes that the snapshot was written now.
    pub(super) fn snapshot_written(&self) {
        *self
            .snapshot_written
            .lock()
            .unwrap_or_else(PoisonError::into_inner) = Some(Instant::now());
    }

    /// Seconds since the snapshot was last written, once it has been.
    pub(super) fn snapshot_age_s(&self) -> Option<f64> {
        self.snapshot_written
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .map(|written| written.elapsed().as_secs_f64())
    }
}
