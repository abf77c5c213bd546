//! The memory measurement: resident memory of the system under test with a baseline of robots
//! tracked, then with every robot tracked, and how long the robots new after the baseline took
//! to be declared. Each robot sends a few samples in answered rounds, or (`--memory-stream-hz`)
//! streams until its window is full.

use std::ops::Range;
use std::thread;
use std::time::{Duration, Instant};

use super::{Counts, Load, LoadError, Memory};
use crate::procfs;

/// Streamed samples sent and not yet answered, at most: enough that the system under test never
/// waits for the load, few enough that nothing queues long enough to be dropped.
const IN_FLIGHT: u64 = 2_000;
/// How long streaming waits without any new answer before it gives up.
const STREAM_STALL: Duration = Duration::from_secs(10);
/// The system under test counts as done with the samples (armtwin declares a streaming robot's
/// publishers on its control thread, one per turn, after the samples that prompted them) once
/// it uses less than this many cores over a second.
const IDLE_CORES: f64 = 0.05;
/// How long the memory measurement waits for that before it reads the RSS anyway.
const SETTLE_LIMIT: Duration = Duration::from_secs(120);

impl Load {
    /// RSS of the system under test with `base_robots` tracked, then with every robot tracked,
    /// each robot having sent the same number of samples; keys are declared only for the robots
    /// in play, as gateways would.
    pub(super) fn memory(&mut self, base_robots: usize) -> Result<Memory, LoadError> {
        let pid = self
            .args
            .sut_pid
            .ok_or_else(|| LoadError::NoAnswer("memory needs --sut-pid".to_owned()))?;
        let robots = self.args.robots;
        let samples = self.args.memory_samples.max(1);
        self.declare_robots(base_robots)?;
        self.wait_for_subscriber()?;
        let rss_start_kib = procfs::rss_kib(pid)?;
        self.warm_up(0..base_robots)?;
        self.wait_for_tracking(base_robots)?;
        let _base_fill = self.more_samples(0..base_robots, samples)?;
        self.settle_for_rss(pid)?;
        let rss_base_kib = procfs::rss_kib(pid)?;
        eprintln!("load: memory baseline {rss_base_kib} KiB with {base_robots} robots");
        self.declare_robots(robots)?;
        let started = Instant::now();
        self.warm_up(base_robots..robots)?;
        let mut declare_s = None;
        if self.wait_for_tracking(robots)? {
            let elapsed_s = started.elapsed().as_secs_f64();
            declare_s = Some(elapsed_s);
            eprintln!(
                "load: {} new robots declared {elapsed_s:.1} s after their first samples",
                robots - base_robots,
            );
        }
        let fill_samples_per_s = self.more_samples(base_robots..robots, samples)?;
        self.settle_for_rss(pid)?;
        let rss_full_kib = procfs::rss_kib(pid)?;
        let added = robots.saturating_sub(base_robots).max(1);
        Ok(Memory {
            base_robots,
            robots,
            samples_per_robot: samples,
            stream_hz: self.args.memory_stream_hz,
            rss_start_kib,
            rss_base_kib,
            rss_full_kib,
            bytes_per_robot: (rss_full_kib as f64 - rss_base_kib as f64) * 1024.0 / added as f64,
            declare_s,
            fill_samples_per_s,
        })
    }

    /// The samples after each robot's first (the warm-up's) up to `samples` per robot: streamed
    /// with `--memory-stream-hz` (returning the samples per second they were answered at), else
    /// in rounds like the warm-up.
    fn more_samples(
        &mut self,
        robots: Range<usize>,
        samples: u64,
    ) -> Result<Option<f64>, LoadError> {
        if let Some(hz) = self.args.memory_stream_hz {
            return self.stream(robots, samples - 1, hz);
        }
        for round in 1..samples {
            self.warm_up(robots.clone())?;
            eprintln!("load: memory round {}/{samples} done", round + 1);
        }
        Ok(None)
    }

    /// Sends `samples` more samples of each robot of `robots`, round robin, the k-th of each
    /// robot stamped `k / hz` seconds after now: a fleet streaming at `hz` in source time. They
    /// go out as fast as the system under test answers them, at most [`IN_FLIGHT`] unanswered,
    /// so nothing is lost and a window of seconds of source time fills in less wall time. Returns
    /// the samples per second, from the first sent until the last answered.
    fn stream(
        &mut self,
        robots: Range<usize>,
        samples: u64,
        hz: f64,
    ) -> Result<Option<f64>, LoadError> {
        if robots.is_empty() || samples == 0 {
            return Ok(None);
        }
        let base = self.replies.counts();
        let origin_s = self.replies.now_s();
        let total = robots.len() as u64 * samples;
        let started = Instant::now();
        let mut sent: u64 = 0;
        for k in 1..=samples {
            let stamp_s = origin_s + k as f64 / hz;
            for robot in robots.clone() {
                self.await_answers(base, sent.saturating_sub(IN_FLIGHT))?;
                self.send_stamped(robot, stamp_s)?;
                sent += 1;
            }
        }
        self.await_answers(base, total)?;
        self.accounted = self.replies.counts();
        let elapsed_s = started.elapsed().as_secs_f64();
        eprintln!(
            "load: {} robots streamed {samples} samples each at {hz} Hz of source time in {elapsed_s:.1} s ({:.0} samples/s), every one answered",
            robots.len(),
            total as f64 / elapsed_s,
        );
        Ok(Some(total as f64 / elapsed_s))
    }

    /// Waits before reading the RSS: a second, and streamed samples until `pid` is idle (under
    /// [`IDLE_CORES`] over a second) or [`SETTLE_LIMIT`] has passed. Not after rounds: their
    /// robots prompt no declaration, and the snapshots of a system with a `state_dir` would
    /// keep it from ever looking idle.
    fn settle_for_rss(&self, pid: u32) -> Result<(), LoadError> {
        let started = Instant::now();
        loop {
            let before_s = procfs::cpu_s(pid)?;
            thread::sleep(Duration::from_secs(1));
            let cores = procfs::cpu_s(pid)? - before_s;
            if self.args.memory_stream_hz.is_none() || cores < IDLE_CORES {
                return Ok(());
            }
            if started.elapsed() >= SETTLE_LIMIT {
                eprintln!(
                    "load: the system under test still uses {cores:.2} cores after {} s: RSS read anyway",
                    SETTLE_LIMIT.as_secs()
                );
                return Ok(());
            }
        }
    }

    /// Samples answered since `base`: a pose, and a deviation where one is expected.
    fn answered(&self, base: Counts) -> u64 {
        let got = self.replies.counts().since(base);
        if self.deviations_per_sample() == 0 {
            got.poses
        } else {
            got.poses.min(got.deviations)
        }
    }

    /// Waits until at least `samples` samples sent since `base` are answered; fails when no new
    /// answer comes for [`STREAM_STALL`].
    fn await_answers(&self, base: Counts, samples: u64) -> Result<(), LoadError> {
        let mut answered = self.answered(base);
        let mut progress = Instant::now();
        while answered < samples {
            thread::sleep(Duration::from_micros(200));
            let now_answered = self.answered(base);
            if now_answered > answered {
                answered = now_answered;
                progress = Instant::now();
            } else if progress.elapsed() >= STREAM_STALL {
                return Err(LoadError::NoAnswer(format!(
                    "streaming stalled: {answered} of {samples} samples answered, none for {} s",
                    STREAM_STALL.as_secs()
                )));
            }
        }
        Ok(())
    }
}
