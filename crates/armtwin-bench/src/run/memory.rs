//! The runs at fleet size: armtwin's resident memory (timing how long it takes to declare the
//! robots) and its restart on the snapshot it wrote, then the echo's memory; then memory per
//! robot streaming until its window is full, armtwin's and the echo's, and armtwin's with the
//! whole fleet streaming.
//!
//! Owns those runs' order and their configuration; must not measure (the load generator does).

use anyhow::{Context, Result};

use super::SNAPSHOT_PERIOD_S;
use super::report::{EchoMemory, StreamingMemory};
use super::trials::Orchestrator;
use super::unix_now_s;
use crate::fleet::service_config_with_state;
use crate::load::{LoadReport, Memory, Target, WireEncoding};

/// The load's flags that feed each robot of a memory measurement `samples` samples, streamed at
/// `stream_hz` of source time when given.
fn feed_flags(samples: u64, stream_hz: Option<f64>) -> Vec<String> {
    let mut flags = vec!["--memory-samples".into(), samples.to_string()];
    if let Some(hz) = stream_hz {
        flags.extend(["--memory-stream-hz".into(), hz.to_string()]);
    }
    flags
}

/// The baseline's robots out of `robots`: `asked`, but fewer than `robots` (at least one).
fn base_robots_of(asked: usize, robots: usize) -> usize {
    asked.min(robots.saturating_sub(1)).max(1)
}

impl Orchestrator {
    /// armtwin's memory at fleet size (which also times declaring the robots new after the
    /// baseline), then, unless skipped, a restart on the snapshot it wrote when stopped: seconds
    /// from starting the process until every robot's token is visible again.
    pub(super) fn memory(&self) -> Result<(LoadReport, Option<f64>)> {
        let s = &self.settings;
        let encoding = s.last_encoding();
        eprintln!("== memory: armtwin serve with {} robots", s.memory_robots);
        let state_dir = self.work_dir.join("state");
        std::fs::create_dir_all(&state_dir)?;
        let config_name = format!("armtwin-{}-state.toml", s.memory_robots);
        let config = service_config_with_state(
            s.memory_robots,
            encoding.as_str(),
            &state_dir,
            SNAPSHOT_PERIOD_S,
        );
        let sut = self.start_armtwin_with(&config_name, &config)?;
        let report = self.load(
            &sut,
            Target::Armtwin,
            encoding,
            &self.memory_flags(
                s.memory_robots,
                s.memory_base_robots,
                feed_flags(s.memory_samples, None),
            ),
        )?;
        // SIGTERM: armtwin writes its snapshot as it stops.
        sut.stop();
        if !s.restart {
            return Ok((report, None));
        }
        // A failed restart still leaves the memory reported.
        let restart_s = self
            .restart(&config_name, &config, encoding)
            .inspect_err(|error| eprintln!("armtwin-bench: the restart failed: {error:#}"))
            .ok();
        Ok((report, restart_s))
    }

    /// Starts armtwin with `config` (whose `state_dir` holds a snapshot) and returns the seconds
    /// from the start until every robot's liveliness token is visible.
    pub(super) fn restart(
        &self,
        config_name: &str,
        config: &str,
        encoding: WireEncoding,
    ) -> Result<f64> {
        let robots = self.settings.memory_robots;
        eprintln!("== restart: armtwin serve on the snapshot of {robots} robots");
        let started_unix_s = unix_now_s();
        let sut = self.start_armtwin_with(config_name, config)?;
        let restarted = self.load(
            &sut,
            Target::Armtwin,
            encoding,
            &[
                "--robots".into(),
                robots.to_string(),
                "--await-tokens".into(),
            ],
        )?;
        sut.stop();
        let restart_s = restarted
            .tokens_unix_s
            .context("the load did not wait for the tokens")?
            - started_unix_s;
        eprintln!("== restart: every token visible {restart_s:.1} s after the start");
        Ok(restart_s)
    }

    /// The load's flags of a memory measurement: `robots` over the most gateways, `base_robots`
    /// of them for the baseline, each fed as `feed` says.
    fn memory_flags(&self, robots: usize, base_robots: usize, feed: Vec<String>) -> Vec<String> {
        let mut flags = vec![
            "--robots".into(),
            robots.to_string(),
            "--gateways".into(),
            self.settings.most_gateways().to_string(),
            "--memory-base-robots".into(),
            base_robots.to_string(),
        ];
        flags.extend(feed);
        flags
    }

    pub(super) fn echo_memory(&self) -> Result<EchoMemory> {
        let s = &self.settings;
        self.echo_memory_of(
            s.memory_base_robots,
            s.memory_robots,
            &feed_flags(s.memory_samples, None),
        )
    }

    /// The echo's RSS with `base_robots`, then, started afresh, with `robots`, each robot fed as
    /// `feed` says.
    fn echo_memory_of(
        &self,
        base_robots: usize,
        robots: usize,
        feed: &[String],
    ) -> Result<EchoMemory> {
        let mut rss_kib = Vec::new();
        for robots in [base_robots, robots] {
            eprintln!("== memory: echo with {robots} robots");
            let sut = self.start_echo(robots, false)?;
            let report = self.load(
                &sut,
                Target::Echo,
                self.settings.last_encoding(),
                &self.memory_flags(robots, robots, feed.to_vec()),
            )?;
            sut.stop();
            let memory = report.memory.context("the load measured no memory")?;
            rss_kib.push(memory.rss_full_kib);
        }
        let added = robots.saturating_sub(base_robots).max(1);
        Ok(EchoMemory {
            base_robots,
            rss_base_kib: rss_kib[0],
            robots,
            rss_full_kib: rss_kib[1],
            bytes_per_robot: (rss_kib[1] as f64 - rss_kib[0] as f64) * 1024.0 / added as f64,
        })
    }

    /// A fresh armtwin's RSS with `base_robots`, then `robots`, streaming at `hz` until every
    /// window is full, and the seconds it then took to stop (SIGTERM to exit; `None`: killed).
    fn streaming_armtwin(
        &self,
        robots: usize,
        base_robots: usize,
        hz: f64,
    ) -> Result<(Memory, Option<f64>)> {
        let encoding = self.settings.last_encoding();
        let samples = self.settings.stream_samples(hz);
        eprintln!(
            "== memory: armtwin serve with {robots} robots streaming {samples} samples at {hz} Hz"
        );
        let sut = self.start_armtwin(robots, encoding)?;
        let report = self.load(
            &sut,
            Target::Armtwin,
            encoding,
            &self.memory_flags(robots, base_robots, feed_flags(samples, Some(hz))),
        )?;
        let stop_s = sut.stop();
        match stop_s {
            Some(stop_s) => eprintln!("== armtwin with {robots} robots stopped in {stop_s:.2} s"),
            None => eprintln!("== armtwin with {robots} robots did not stop by itself: killed"),
        }
        let memory = report.memory.context("the load measured no memory")?;
        Ok((memory, stop_s))
    }

    /// Memory per robot streaming at `hz` until its window is full: armtwin's, then the echo's
    /// with the same keys and traffic (a failed echo is reported and left out).
    fn streaming_at(&self, hz: f64) -> Result<StreamingMemory> {
        let s = &self.settings;
        let robots = s.memory_stream_robots;
        let base_robots = base_robots_of(s.memory_base_robots, robots);
        let (armtwin, _stop_s) = self.streaming_armtwin(robots, base_robots, hz)?;
        let echo = self
            .echo_memory_of(
                base_robots,
                robots,
                &feed_flags(s.stream_samples(hz), Some(hz)),
            )
            .inspect_err(|error| {
                eprintln!("armtwin-bench: the echo's streaming memory failed: {error:#}");
            })
            .ok();
        Ok(StreamingMemory {
            hz_per_robot: hz,
            source_s: armtwin.samples_per_robot as f64 / hz,
            added_bytes_per_robot: echo
                .as_ref()
                .map(|echo| armtwin.bytes_per_robot - echo.bytes_per_robot),
            armtwin,
            echo,
        })
    }

    /// Memory per streaming robot at each rate; a failed rate is reported and left out.
    pub(super) fn streaming_memory(&self) -> Vec<StreamingMemory> {
        if self.settings.memory_stream_robots == 0 {
            return Vec::new();
        }
        self.settings
            .memory_stream_hz
            .iter()
            .filter_map(|&hz| {
                self.streaming_at(hz)
                    .inspect_err(|error| {
                        eprintln!("armtwin-bench: streaming memory at {hz} Hz failed: {error:#}");
                    })
                    .ok()
            })
            .collect()
    }

    /// armtwin's RSS with the whole fleet streaming at the first rate, every window full, and the
    /// seconds it then took to stop (`None`: killed).
    pub(super) fn streaming_fleet(&self) -> Option<(Memory, Option<f64>)> {
        let s = &self.settings;
        let robots = s.memory_stream_fleet_robots;
        let hz = *s.memory_stream_hz.first()?;
        if robots == 0 {
            return None;
        }
        self.streaming_armtwin(robots, base_robots_of(s.memory_base_robots, robots), hz)
            .inspect_err(|error| {
                eprintln!("armtwin-bench: the streaming fleet's memory failed: {error:#}");
            })
            .ok()
    }

    /// armtwin's memory (with the declaration time and the restart), then the echo's; a failed
    /// measurement is reported and left out.
    pub(super) fn fleet_size(&self) -> (Option<LoadReport>, Option<f64>, Option<EchoMemory>) {
        if self.settings.memory_robots == 0 {
            return (None, None, None);
        }
        let (memory, restart_s) = self
            .memory()
            .inspect_err(|error| eprintln!("armtwin-bench: memory measurement failed: {error:#}"))
            .ok()
            .map_or((None, None), |(memory, restart_s)| {
                (Some(memory), restart_s)
            });
        let echo_memory = self
            .echo_memory()
            .inspect_err(|error| {
                eprintln!("armtwin-bench: the echo's memory measurement failed: {error:#}");
            })
            .ok();
        (memory, restart_s, echo_memory)
    }
}
