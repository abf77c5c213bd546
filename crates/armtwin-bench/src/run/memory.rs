//! The runs at fleet size: armtwin's resident memory (timing how long it takes to declare the
//! robots) and its restart on the snapshot it wrote, then the echo's memory.
//!
//! Owns those runs' order and their configuration; must not measure (the load generator does).

use anyhow::{Context, Result};

use super::SNAPSHOT_PERIOD_S;
use super::report::EchoMemory;
use super::trials::Orchestrator;
use super::unix_now_s;
use crate::fleet::service_config_with_state;
use crate::load::{LoadReport, Target, WireEncoding};

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
            &[
                "--robots".into(),
                s.memory_robots.to_string(),
                "--gateways".into(),
                s.most_gateways().to_string(),
                "--memory-base-robots".into(),
                s.memory_base_robots.to_string(),
                "--memory-samples".into(),
                s.memory_samples.to_string(),
            ],
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

    pub(super) fn echo_memory(&self) -> Result<EchoMemory> {
        let s = &self.settings;
        let mut rss_kib = Vec::new();
        for robots in [s.memory_base_robots, s.memory_robots] {
            eprintln!("== memory: echo with {robots} robots");
            let sut = self.start_echo(robots, false)?;
            let report = self.load(
                &sut,
                Target::Echo,
                s.last_encoding(),
                &[
                    "--robots".into(),
                    robots.to_string(),
                    "--gateways".into(),
                    s.most_gateways().to_string(),
                    "--memory-base-robots".into(),
                    robots.to_string(),
                    "--memory-samples".into(),
                    s.memory_samples.to_string(),
                ],
            )?;
            sut.stop();
            let memory = report.memory.context("the load measured no memory")?;
            rss_kib.push(memory.rss_full_kib);
        }
        let added = s.memory_robots.saturating_sub(s.memory_base_robots).max(1);
        Ok(EchoMemory {
            base_robots: s.memory_base_robots,
            rss_base_kib: rss_kib[0],
            robots: s.memory_robots,
            rss_full_kib: rss_kib[1],
            bytes_per_robot: (rss_kib[1] as f64 - rss_kib[0] as f64) * 1024.0 / added as f64,
        })
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
