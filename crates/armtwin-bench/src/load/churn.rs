//! The load's soak (`--soak-duration`): `--robots` robots at `--soak-hz` each on one fixed
//! schedule for a long time, a share of them replaced every churn period by robots the system
//! under test has never seen (new ids, the old ones gone for good), and a JSON line per interval
//! on standard output as the soak goes: samples sent, poses back, latency.
//!
//! A pose counts for the interval in which its sample was sent (its stamp says when), so an
//! interval is reported [`GRACE`] after it ends; a pose later than that is not lost, only late,
//! and the soak's total loss is counted after every reply had its chance.
//!
//! Owns the soak's schedule, churn and tally; measures nothing of the system under test's
//! process (the orchestrator reads that beside each line).

use std::io::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, PoisonError};
use std::thread;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use zenoh::Wait;

use super::robots::{Outgoing, RobotKeys};
use super::trials::{SETTLE, percentile_us};
use super::{Load, LoadError};

/// How long after an interval ends its poses are counted and it is reported.
const GRACE: Duration = Duration::from_secs(2);

/// Poses and their latencies, by the interval their samples were sent in. Filled by the
/// receive callbacks.
#[derive(Debug)]
pub(super) struct Tally {
    /// The stamp (s since the clock origin) the soak's schedule starts at.
    origin_s: f64,
    interval_s: f64,
    poses: Vec<AtomicU64>,
    latencies_ns: Vec<Mutex<Vec<u64>>>,
}

impl Tally {
    fn new(origin_s: f64, interval_s: f64, intervals: usize) -> Self {
        Self {
            origin_s,
            interval_s,
            poses: (0..intervals).map(|_| AtomicU64::new(0)).collect(),
            latencies_ns: (0..intervals).map(|_| Mutex::new(Vec::new())).collect(),
        }
    }

    /// The interval a sample stamped `stamp_s` belongs to (the last one for a sample sent
    /// after the schedule's end, as a load behind its schedule does).
    fn interval_of(&self, stamp_s: f64) -> usize {
        let position = ((stamp_s - self.origin_s) / self.interval_s).max(0.0);
        (position as usize).min(self.poses.len() - 1)
    }

    /// A pose whose sample was stamped `stamp_s` came back after `latency_ns`.
    pub(super) fn record(&self, stamp_s: f64, latency_ns: u64) {
        if stamp_s < self.origin_s {
            return;
        }
        let index = self.interval_of(stamp_s);
        if let (Some(poses), Some(latencies)) =
            (self.poses.get(index), self.latencies_ns.get(index))
        {
            poses.fetch_add(1, Ordering::Relaxed);
            latencies
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .push(latency_ns);
        }
    }

    /// Interval `index`'s poses so far and its latencies, sorted (taken: later ones are late).
    fn take(&self, index: usize) -> (u64, Vec<u64>) {
        let mut latencies = std::mem::take(
            &mut *self.latencies_ns[index]
                .lock()
                .unwrap_or_else(PoisonError::into_inner),
        );
        latencies.sort_unstable();
        (self.poses[index].load(Ordering::Relaxed), latencies)
    }
}

/// One interval of the soak, as the load saw it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SoakInterval {
    /// 0, 1, …
    pub index: usize,
    /// Seconds from the soak's start to the interval's end.
    pub end_s: f64,
    /// Samples sent in it.
    pub sent: u64,
    /// Their poses back within [`GRACE`] of its end.
    pub poses: u64,
    /// `sent − poses`: lost or later than the grace.
    pub unanswered: u64,
    /// Latency of its poses, sample sent → pose received (µs, nearest rank; none without poses).
    pub p50_us: Option<f64>,
    /// 99th percentile.
    pub p99_us: Option<f64>,
    /// Largest.
    pub max_us: Option<f64>,
    /// Robots that had left by its end (as many had joined).
    pub churned: u64,
}

/// The whole soak, as the load saw it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Soak {
    /// Robots sending at any time.
    pub robots: usize,
    /// Samples per second per robot.
    pub hz_per_robot: f64,
    /// Seconds of the schedule.
    pub duration_s: f64,
    /// Seconds the sending took (more than `duration_s`: the load fell behind its schedule).
    pub send_s: f64,
    /// Seconds per interval.
    pub interval_s: f64,
    /// Robots replaced per churn.
    pub churn_robots: usize,
    /// Seconds between churns.
    pub churn_period_s: f64,
    /// Samples sent.
    pub sent: u64,
    /// Poses and deviations that never came back.
    pub lost: u64,
    /// Poses later than their interval's report.
    pub late: u64,
    /// Robots that left (as many joined, each new).
    pub churned: u64,
    /// Robot ids used over the soak.
    pub ids_used: usize,
    /// Every interval.
    pub intervals: Vec<SoakInterval>,
}

/// The schedule's position: what was sent, when the next churn and report are due.
struct Schedule {
    rate: f64,
    interval_s: f64,
    sent_by_interval: Vec<u64>,
    reported: usize,
    churned: u64,
    intervals: Vec<SoakInterval>,
}

impl Schedule {
    /// Reports interval `index` on standard output (and keeps it).
    fn report(&mut self, tally: &Tally, index: usize, duration_s: f64) {
        let (poses, latencies) = tally.take(index);
        let sent = self.sent_by_interval[index];
        let percentile =
            |fraction: f64| (!latencies.is_empty()).then(|| percentile_us(&latencies, fraction));
        let interval = SoakInterval {
            index,
            end_s: ((index + 1) as f64 * self.interval_s).min(duration_s),
            sent,
            poses,
            unanswered: sent.saturating_sub(poses),
            p50_us: percentile(0.5),
            p99_us: percentile(0.99),
            max_us: percentile(1.0),
            churned: self.churned,
        };
        if let Ok(line) = serde_json::to_string(&interval) {
            let mut stdout = std::io::stdout().lock();
            // The orchestrator reads the lines as they come; a closed pipe ends nothing here.
            let _ = writeln!(stdout, "{line}");
            let _ = stdout.flush();
        }
        self.intervals.push(interval);
        self.reported += 1;
    }
}

impl Load {
    /// Runs the soak: the robots warmed up and tracked first, then the schedule with churn.
    pub(super) fn soak(&mut self, duration_s: f64) -> Result<Soak, LoadError> {
        let robots = self.args.robots.max(1);
        let interval_s = self.args.soak_interval.max(0.1);
        let period_s = self.args.churn_period.max(interval_s.min(1.0));
        let churn_robots = ((self.args.churn.clamp(0.0, 1.0)) * robots as f64).round() as usize;
        self.declare_robots(robots)?;
        self.wait_for_subscriber()?;
        self.warm_up(0..robots)?;
        self.wait_for_tracking(robots)?;
        let mut slots: Vec<RobotKeys> = std::mem::take(&mut self.robots);
        let mut next_id = robots;
        let intervals = ((duration_s / interval_s).ceil() as usize).max(1);
        let mut schedule = Schedule {
            rate: self.args.soak_hz * robots as f64,
            interval_s,
            sent_by_interval: vec![0; intervals],
            reported: 0,
            churned: 0,
            intervals: Vec::with_capacity(intervals),
        };
        let samples = (schedule.rate * duration_s).round().max(1.0) as u64;
        eprintln!(
            "load: soak of {duration_s} s, {robots} robots × {} Hz, {churn_robots} replaced every {period_s} s",
            self.args.soak_hz
        );
        let base = self.replies.counts();
        let start = Instant::now();
        let tally = self
            .replies
            .soak
            .get_or_init(|| Tally::new(self.replies.now_s(), interval_s, intervals));
        let (mut sent, mut cursor, mut next_churn) = (0_u64, 0_usize, 1_u32);
        while sent < samples {
            let due_s = sent as f64 / schedule.rate;
            if churn_robots > 0 && due_s >= f64::from(next_churn) * period_s {
                next_churn += 1;
                // The longest-serving robots leave: slots in turn, round robin.
                let first = schedule.churned as usize;
                for slot in (first..first + churn_robots).map(|n| n % robots) {
                    let joining = self.declare_robot(next_id)?;
                    next_id += 1;
                    self.undeclare(std::mem::replace(&mut slots[slot], joining));
                    schedule.churned += 1;
                }
            }
            let elapsed = start.elapsed();
            while schedule.reported < intervals
                && elapsed.as_secs_f64()
                    >= (schedule.reported + 1) as f64 * interval_s + GRACE.as_secs_f64()
            {
                schedule.report(tally, schedule.reported, duration_s);
            }
            if let Some(wait) = Duration::from_secs_f64(due_s).checked_sub(elapsed) {
                // Never spin: the system under test needs the cores.
                thread::sleep(wait);
            }
            let outgoing = Outgoing {
                workload: &self.workload,
                encoding: self.args.encoding,
                embedded: self.embedded,
            };
            let now_s = self.replies.now_s();
            outgoing.put(&mut slots[cursor], now_s)?;
            cursor = (cursor + 1) % robots;
            schedule.sent_by_interval[tally.interval_of(now_s)] += 1;
            sent += 1;
        }
        let send_s = start.elapsed().as_secs_f64();
        while schedule.reported < intervals {
            let report_at = Duration::from_secs_f64((schedule.reported + 1) as f64 * interval_s)
                .max(Duration::from_secs_f64(send_s))
                + GRACE;
            if let Some(wait) = report_at.checked_sub(start.elapsed()) {
                thread::sleep(wait);
            }
            schedule.report(tally, schedule.reported, duration_s);
        }
        let deviations = sent * self.deviations_per_sample();
        let got = self.settle(base, sent, deviations);
        let on_time: u64 = schedule.intervals.iter().map(|i| i.poses).sum();
        for keys in slots {
            self.undeclare(keys);
        }
        Ok(Soak {
            robots,
            hz_per_robot: self.args.soak_hz,
            duration_s,
            send_s,
            interval_s,
            churn_robots,
            churn_period_s: period_s,
            sent,
            lost: sent.saturating_sub(got.poses) + deviations.saturating_sub(got.deviations),
            late: got.poses.saturating_sub(on_time),
            churned: schedule.churned,
            ids_used: next_id,
            intervals: schedule.intervals,
        })
    }

    /// The replies since `base` once `poses` and `deviations` have come back, or after
    /// [`SETTLE`].
    fn settle(&self, base: super::Counts, poses: u64, deviations: u64) -> super::Counts {
        let settle_until = Instant::now() + SETTLE;
        let mut got = self.replies.counts().since(base);
        while Instant::now() < settle_until && (got.poses < poses || got.deviations < deviations) {
            thread::sleep(Duration::from_millis(10));
            got = self.replies.counts().since(base);
        }
        got
    }

    /// A robot leaves: its publishers and the reply keys declared for it are undeclared, so
    /// that only the system under test could still hold anything of it.
    fn undeclare(&self, keys: RobotKeys) {
        let RobotKeys {
            joints,
            measured,
            replies,
            ..
        } = keys;
        // An undeclaration that fails leaves a declaration behind in this process only.
        let _ = joints.undeclare().wait();
        let _ = measured.undeclare().wait();
        for key_expr in replies {
            let _ = self.session.undeclare(key_expr).wait();
        }
    }
}
