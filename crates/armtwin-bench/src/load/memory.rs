//! The memory measurement: resident memory of the system under test with a baseline of robots
//! tracked, then with every robot tracked, and how long the robots new after the baseline took
//! to be declared.

use std::thread;
use std::time::{Duration, Instant};

use super::{Load, LoadError, Memory};
use crate::procfs;

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
        let settle = Duration::from_secs(1);
        for _ in 0..samples {
            self.warm_up(0..base_robots)?;
        }
        self.wait_for_tracking(base_robots)?;
        thread::sleep(settle);
        let rss_base_kib = procfs::rss_kib(pid)?;
        eprintln!("load: memory baseline {rss_base_kib} KiB with {base_robots} robots");
        self.declare_robots(robots)?;
        let mut declare_s = None;
        for round in 0..samples {
            let started = Instant::now();
            self.warm_up(base_robots..robots)?;
            if round == 0 && self.wait_for_tracking(robots)? {
                let elapsed_s = started.elapsed().as_secs_f64();
                declare_s = Some(elapsed_s);
                eprintln!(
                    "load: {} new robots declared {elapsed_s:.1} s after their first samples",
                    robots - base_robots,
                );
            }
            eprintln!("load: memory round {}/{samples} done", round + 1);
        }
        thread::sleep(settle);
        let rss_full_kib = procfs::rss_kib(pid)?;
        let added = robots.saturating_sub(base_robots).max(1);
        Ok(Memory {
            base_robots,
            robots,
            samples_per_robot: samples,
            rss_start_kib,
            rss_base_kib,
            rss_full_kib,
            bytes_per_robot: (rss_full_kib as f64 - rss_base_kib as f64) * 1024.0 / added as f64,
            declare_s,
        })
    }
}
