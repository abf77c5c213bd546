//! `armtwin-bench run`: the orchestrator. For each row (robot count, encoding, gateway count) it
//! starts the plain echo, then `armtwin serve`, each as a subprocess on a free loopback port,
//! with the load generator in a process of its own, so that each row's ratio compares the two
//! on the same machine within minutes. Then robots new to a fresh echo and armtwin at full rate
//! (first contact); `armtwin serve` once more for resident memory at fleet size, timing how long
//! it takes to declare the robots and, restarted on its snapshot, to declare them again; the
//! echo's memory; memory per robot streaming until its window is full, armtwin's and the
//! echo's, at each rate, and armtwin's RSS with the whole fleet streaming. Prints the ratios and every target met or not, and writes them, with every
//! trial, to `bench.json`.
//!
//! Owns process lifetimes, the generated service configuration and the report; measures
//! nothing itself (the load generator does). Here: the flags, the settings and the run in order;
//! `trials` (the systems started and compared under load, first contact), `memory` (resident
//! memory at fleet size, the declaration and the restart, streaming), `system` (a subprocess under test),
//! `report` (`bench.json`'s types, the tables and the targets).
#![allow(
    clippy::print_stdout,
    clippy::print_stderr,
    reason = "a benchmark command's progress and report, on its terminal"
)]

mod memory;
mod report;
pub(crate) mod system;
pub(crate) mod trials;

pub use report::{
    Comparison, EchoMemory, FirstContact, Fleet, Host, LatencySummary, Report, StreamingMemory,
    TargetRow,
};

use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result, bail};
use clap::Args;
use serde::Serialize;

use crate::load::WireEncoding;
use report::{table, targets};
use trials::Orchestrator;

/// How long a system under test may take to listen.
const STARTUP_TIMEOUT: Duration = Duration::from_secs(60);
/// armtwin's snapshot period in the memory run: short, so that the restart finds a snapshot of
/// every robot even if stopping it fails to write the final one.
const SNAPSHOT_PERIOD_S: f64 = 2.0;
/// How long a system under test may take to stop after SIGTERM.
const STOP_TIMEOUT: Duration = Duration::from_secs(20);

/// `armtwin-bench run` arguments; `--quick` changes the defaults to a smoke run of seconds.
#[derive(Debug, Clone, Args)]
#[allow(
    clippy::struct_excessive_bools,
    reason = "independent command-line switches, not a state"
)]
pub struct RunArgs {
    /// A short smoke run: small fleets, short trials, low rates.
    #[arg(long)]
    pub quick: bool,
    /// Robot counts (default 1,100,1000; quick 1,10).
    #[arg(long, value_delimiter = ',')]
    pub robots: Vec<usize>,
    /// The samples' formats, and armtwin's poses' and deviations' (`[service] encoding`): every
    /// robot count is compared in each (default json,zenoh-serialized).
    #[arg(long, alias = "encoding", value_enum, value_delimiter = ',')]
    pub encodings: Vec<WireEncoding>,
    /// Load sessions (gateways) the robots are split over (default 1,4). The first count runs
    /// every robot count in every encoding; each further one the largest robot count in the
    /// last encoding, and the memory and declaration measurements use the largest.
    #[arg(long, value_delimiter = ',', value_parser = clap::value_parser!(u16).range(1..))]
    pub gateways: Vec<u16>,
    /// Robots for the memory measurement, whose run also times declaring them and a restart
    /// (default 10000; quick 100; 0 skips it).
    #[arg(long)]
    pub memory_robots: Option<usize>,
    /// Robots tracked for the memory baseline.
    #[arg(long, default_value_t = 10)]
    pub memory_base_robots: usize,
    /// Samples each robot sends in the memory measurement.
    #[arg(long, default_value_t = 4)]
    pub memory_samples: u64,
    /// Skip the restart after the memory measurement.
    #[arg(long)]
    pub no_restart: bool,
    /// Robots of the streaming memory measurement at each `--memory-stream-hz`, every robot's
    /// window full, armtwin against the echo (default 1000; quick 6; 0 skips it).
    #[arg(long)]
    pub memory_stream_robots: Option<usize>,
    /// Per-robot rates of the streaming memory measurement, Hz of source time (default 100,500;
    /// quick 10,50); the fleet's RSS is measured at the first.
    #[arg(long, value_delimiter = ',')]
    pub memory_stream_hz: Vec<f64>,
    /// Seconds of source time each robot streams: more than `window_s` (10 s), so that its
    /// window and the aligner's history are full (default 11).
    #[arg(long, default_value_t = 11.0)]
    pub memory_stream_seconds: f64,
    /// Robots streaming at the first `--memory-stream-hz` for armtwin's RSS at fleet size
    /// (default 0, skipped: 10000 fill their windows in ~18 min on 2 cores; quick 8).
    #[arg(long)]
    pub memory_stream_fleet_robots: Option<usize>,
    /// Seconds per throughput trial (default 1; quick 0.25).
    #[arg(long)]
    pub duration: Option<f64>,
    /// First rate of the echo's throughput search, samples/s (default 40000; quick 200);
    /// armtwin's starts at half the echo's result.
    #[arg(long)]
    pub start_rate: Option<f64>,
    /// Highest rate tried, samples/s (default 2000000; quick 800).
    #[arg(long)]
    pub max_rate: Option<f64>,
    /// Bisection steps of the search (default 4; quick 1).
    #[arg(long)]
    pub bisect_steps: Option<u32>,
    /// Runs of a failed search trial again before its rate counts as failed (default 1; quick 0).
    #[arg(long)]
    pub retries: Option<u32>,
    /// Latency run rate, samples/s (default 1000; quick 200).
    #[arg(long)]
    pub latency_rate: Option<f64>,
    /// Latency run length, seconds (default 2; quick 0.5).
    #[arg(long)]
    pub latency_duration: Option<f64>,
    /// Latency rounds per system, alternating between them (default 2; quick 1).
    #[arg(long)]
    pub latency_rounds: Option<u32>,
    /// Per-robot rate of the fleet check at the largest robot count, Hz (default 100; quick 10).
    /// The check sends embedded samples in the last encoding over the most gateways.
    #[arg(long)]
    pub fleet_hz: Option<f64>,
    /// Seconds of the fleet check (default 10; quick 0.5; 0 skips it).
    #[arg(long)]
    pub fleet_duration: Option<f64>,
    /// Robots of the paced comparison, each sending at `--paced-hz` with its measured pose
    /// embedded, as a plant's gateways send (default 200; quick 10).
    #[arg(long)]
    pub paced_robots: Option<usize>,
    /// Per-robot rate of the paced comparison, Hz (default 100; quick 10).
    #[arg(long)]
    pub paced_hz: Option<f64>,
    /// Seconds of each paced round (default 10; quick 0.5; 0 skips it). Rounds alternate between
    /// the systems, as many as latency rounds, after one unmeasured round each.
    #[arg(long)]
    pub paced_duration: Option<f64>,
    /// Robots of the first-contact trial, all new to a freshly started system (default: the
    /// largest robot count; 0 skips it).
    #[arg(long)]
    pub first_contact_robots: Option<usize>,
    /// Rate of the first-contact trial, samples/s (default: the echo's sustained rate at the
    /// largest robot count in the last encoding).
    #[arg(long)]
    pub first_contact_rate: Option<f64>,
    /// Seconds of the first-contact trial (default 3; quick 0.5).
    #[arg(long)]
    pub first_contact_duration: Option<f64>,
    /// Send each sample as one joint message with the measured pose embedded (RTDE style), not
    /// as a joint and a measured message.
    #[arg(long)]
    pub embedded: bool,
    /// armtwin with `[service] outputs = "paired"` (one message per paired sample, pose and
    /// deviation in it), against the echo with `--paired` (one message per sample).
    #[arg(long)]
    pub paired: bool,
    /// The `armtwin` binary (default: next to this one).
    #[arg(long)]
    pub armtwin: Option<PathBuf>,
    /// TOML appended to every configuration `armtwin serve` is started with, e.g. an `[opcua]`
    /// section: the same run with and without a part of the service switched on.
    #[arg(long, value_name = "FILE")]
    pub armtwin_config_extra: Option<PathBuf>,
    /// Where to write the report.
    #[arg(long, default_value = "bench.json")]
    pub out: PathBuf,
}

/// The settings of one run, defaults filled in.
#[derive(Debug, Clone, Serialize)]
#[allow(
    clippy::struct_excessive_bools,
    reason = "independent settings, not a state"
)]
pub struct Settings {
    /// Smoke run.
    pub quick: bool,
    /// Robot counts.
    pub robots: Vec<usize>,
    /// The samples' formats, and armtwin's poses' and deviations'.
    pub encodings: Vec<WireEncoding>,
    /// Load sessions the robots are split over.
    pub gateways: Vec<u16>,
    /// Robots of the memory measurement (0: none).
    pub memory_robots: usize,
    /// Robots of the memory baseline.
    pub memory_base_robots: usize,
    /// Samples per robot in the memory measurement.
    pub memory_samples: u64,
    /// A restart after the memory measurement.
    pub restart: bool,
    /// Robots of the streaming memory measurement (0: none).
    pub memory_stream_robots: usize,
    /// Its per-robot rates, Hz of source time.
    pub memory_stream_hz: Vec<f64>,
    /// Seconds of source time each robot streams.
    pub memory_stream_seconds: f64,
    /// Robots streaming at the first rate for the RSS at fleet size (0: none).
    pub memory_stream_fleet_robots: usize,
    /// Seconds per throughput trial.
    pub duration_s: f64,
    /// First rate of the echo's search.
    pub start_rate: f64,
    /// Highest rate tried.
    pub max_rate: f64,
    /// Bisection steps.
    pub bisect_steps: u32,
    /// Repeats of a failed search trial.
    pub retries: u32,
    /// Latency run rate.
    pub latency_rate: f64,
    /// Latency run seconds.
    pub latency_duration_s: f64,
    /// Latency rounds per system.
    pub latency_rounds: u32,
    /// Fleet check: Hz per robot.
    pub fleet_hz: f64,
    /// Fleet check: seconds (0: none).
    pub fleet_duration_s: f64,
    /// Paced comparison: robots.
    pub paced_robots: usize,
    /// Paced comparison: Hz per robot.
    pub paced_hz: f64,
    /// Paced comparison: seconds per round (0: none).
    pub paced_duration_s: f64,
    /// First contact: robots (0: none).
    pub first_contact_robots: usize,
    /// First contact: samples/s (none: the echo's sustained rate).
    pub first_contact_rate: Option<f64>,
    /// First contact: seconds.
    pub first_contact_duration_s: f64,
    /// Measured poses embedded in the joint messages.
    pub embedded: bool,
    /// armtwin's poses and deviations paired in one message, the echo's one message per sample.
    pub paired: bool,
    /// The file whose TOML is appended to armtwin's configurations.
    pub armtwin_config_extra: Option<PathBuf>,
}

impl Settings {
    fn of(args: &RunArgs) -> Self {
        let quick = args.quick;
        let pick = |value: Option<f64>, normal: f64, smoke: f64| {
            value.unwrap_or(if quick { smoke } else { normal })
        };
        let robots = if args.robots.is_empty() {
            if quick {
                vec![1, 10]
            } else {
                vec![1, 100, 1000]
            }
        } else {
            args.robots.clone()
        };
        let largest = robots.iter().copied().max().unwrap_or(1);
        Self {
            quick,
            robots,
            encodings: if args.encodings.is_empty() {
                vec![WireEncoding::Json, WireEncoding::ZenohSerialized]
            } else {
                args.encodings.clone()
            },
            gateways: if args.gateways.is_empty() {
                vec![1, 4]
            } else {
                args.gateways.clone()
            },
            memory_robots: args
                .memory_robots
                .unwrap_or(if quick { 100 } else { 10_000 }),
            memory_base_robots: args.memory_base_robots,
            memory_samples: args.memory_samples,
            restart: !args.no_restart,
            memory_stream_robots: args
                .memory_stream_robots
                .unwrap_or(if quick { 6 } else { 1000 }),
            memory_stream_hz: if args.memory_stream_hz.is_empty() {
                if quick {
                    vec![10.0, 50.0]
                } else {
                    vec![100.0, 500.0]
                }
            } else {
                args.memory_stream_hz.clone()
            },
            memory_stream_seconds: args.memory_stream_seconds,
            memory_stream_fleet_robots: args.memory_stream_fleet_robots.unwrap_or(if quick {
                8
            } else {
                0
            }),
            duration_s: pick(args.duration, 1.0, 0.25),
            start_rate: pick(args.start_rate, 40_000.0, 200.0),
            max_rate: pick(args.max_rate, 2_000_000.0, 800.0),
            bisect_steps: args.bisect_steps.unwrap_or(if quick { 1 } else { 4 }),
            retries: args.retries.unwrap_or(u32::from(!quick)),
            latency_rate: pick(args.latency_rate, 1000.0, 200.0),
            latency_duration_s: pick(args.latency_duration, 2.0, 0.5),
            latency_rounds: args.latency_rounds.unwrap_or(if quick { 1 } else { 2 }),
            fleet_hz: pick(args.fleet_hz, 100.0, 10.0),
            fleet_duration_s: pick(args.fleet_duration, 10.0, 0.5),
            paced_robots: args.paced_robots.unwrap_or(if quick { 10 } else { 200 }),
            paced_hz: pick(args.paced_hz, 100.0, 10.0),
            paced_duration_s: pick(args.paced_duration, 10.0, 0.5),
            first_contact_robots: args.first_contact_robots.unwrap_or(largest),
            first_contact_rate: args.first_contact_rate,
            first_contact_duration_s: pick(args.first_contact_duration, 3.0, 0.5),
            embedded: args.embedded,
            paired: args.paired,
            armtwin_config_extra: args.armtwin_config_extra.clone(),
        }
    }

    /// The encoding of the rows beyond the first gateway count, the fleet check, first contact
    /// and memory: the last one asked for.
    fn last_encoding(&self) -> WireEncoding {
        self.encodings.last().copied().unwrap_or_default()
    }

    fn first_gateways(&self) -> u16 {
        self.gateways.first().copied().unwrap_or(1)
    }

    fn most_gateways(&self) -> u16 {
        self.gateways.iter().copied().max().unwrap_or(1)
    }

    /// Samples each robot streams at `hz`: `memory_stream_seconds` of source time.
    fn stream_samples(&self, hz: f64) -> u64 {
        ((hz * self.memory_stream_seconds).round() as u64).max(2)
    }
}

pub(crate) fn unix_now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// This `armtwin-bench` and the `armtwin` it runs: `given`, or the one beside it; an error
/// when that is not a file.
pub(crate) fn bench_and_armtwin(given: Option<&PathBuf>) -> Result<(PathBuf, PathBuf)> {
    let bench = std::env::current_exe().context("locating armtwin-bench")?;
    let armtwin = given.cloned().unwrap_or_else(|| {
        bench.with_file_name(format!("armtwin{}", std::env::consts::EXE_SUFFIX))
    });
    if !armtwin.is_file() {
        bail!(
            "{} not found: build it (cargo build --release) or pass --armtwin",
            armtwin.display()
        );
    }
    Ok((bench, armtwin))
}

/// Runs the whole benchmark and writes the report.
///
/// In order: each robot count in each encoding over the first gateway count; the largest robot
/// count in the last encoding over each further gateway count (the fleet check rides on the row
/// of the most gateways); first contact at the echo's sustained rate of the largest robot count;
/// the paced comparison; armtwin's memory at fleet size, with the declaration time and the restart; the echo's memory;
/// memory per streaming robot at each rate, armtwin's then the echo's; armtwin's RSS with the
/// fleet streaming.
pub fn run(args: &RunArgs) -> Result<Report> {
    let wall = Instant::now();
    let settings = Settings::of(args);
    let (bench, armtwin) = bench_and_armtwin(args.armtwin.as_ref())?;
    let work_dir = std::env::temp_dir().join(format!("armtwin-bench-{}", std::process::id()));
    std::fs::create_dir_all(&work_dir)?;
    let orchestrator = Orchestrator::new(settings.clone(), bench, armtwin, work_dir.clone())?;
    let started_unix_s = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let host = Host::probe();
    let largest = settings.robots.iter().copied().max().unwrap_or(1);
    let last_encoding = settings.last_encoding();
    let (first_gateways, most_gateways) = (settings.first_gateways(), settings.most_gateways());
    let fleet_rate =
        (settings.fleet_duration_s > 0.0).then_some(settings.fleet_hz * largest as f64);
    let fleet_row = (largest, last_encoding, most_gateways);
    let by_robots = orchestrator.compare_rows(fleet_row, fleet_rate)?;
    let headline_row = (largest, last_encoding, first_gateways);
    let headline = by_robots
        .iter()
        .find(|c| (c.robots, c.encoding, c.gateways) == headline_row)
        .context("no robot count measured")?;
    // A failed measurement below still leaves the comparisons reported.
    let echo_rate = Some(headline.echo_throughput).filter(|rate| *rate > 0.0);
    let first_contact_rate = settings.first_contact_rate.or(echo_rate);
    let first_contact = if settings.first_contact_robots == 0 {
        None
    } else if let Some(rate) = first_contact_rate {
        orchestrator
            .first_contact(rate)
            .inspect_err(|error| eprintln!("armtwin-bench: first contact failed: {error:#}"))
            .ok()
    } else {
        eprintln!("armtwin-bench: first contact skipped: no rate to offer");
        None
    };
    let paced = if settings.paced_duration_s > 0.0 && settings.paced_robots > 0 {
        orchestrator
            .paced()
            .inspect_err(|error| eprintln!("armtwin-bench: the paced comparison failed: {error:#}"))
            .ok()
    } else {
        None
    };
    let (memory, restart_s, echo_memory) = orchestrator.fleet_size();
    let streaming_memory = orchestrator.streaming_memory();
    let (streaming_fleet, streaming_fleet_stop_s) = orchestrator
        .streaming_fleet()
        .map_or((None, None), |(memory, stop_s)| (Some(memory), stop_s));
    let _ = std::fs::remove_dir_all(&work_dir);
    let fleet_comparison = by_robots
        .iter()
        .find(|c| (c.robots, c.encoding, c.gateways) == fleet_row);
    let fleet = fleet_rate.zip(fleet_comparison).map(|(rate, c)| Fleet {
        robots: largest,
        encoding: last_encoding,
        gateways: most_gateways,
        embedded: true,
        hz_per_robot: settings.fleet_hz,
        rate,
        echo_sustained: c.echo.check.as_ref().is_some_and(|t| t.sustained),
        armtwin_sustained: c.armtwin.check.as_ref().is_some_and(|t| t.sustained),
    });
    let memory_figures = memory.as_ref().and_then(|m| m.memory.as_ref());
    let mut report = Report {
        started_unix_s,
        host,
        headline_robots: largest,
        headline_encoding: last_encoding,
        headline_gateways: first_gateways,
        echo_throughput: headline.echo_throughput,
        armtwin_throughput: headline.armtwin_throughput,
        throughput_ratio: headline.throughput_ratio,
        added_latency_p99_us: headline.added_latency_p99_us,
        bytes_per_robot: memory_figures.map(|m| m.bytes_per_robot),
        declare_s: memory_figures.and_then(|m| m.declare_s),
        restart_s,
        settings,
        fleet,
        paced,
        memory,
        echo_bytes_per_robot: echo_memory.as_ref().map(|m| m.bytes_per_robot),
        echo_memory,
        streaming_memory,
        streaming_fleet,
        streaming_fleet_stop_s,
        first_contact: first_contact.into_iter().collect(),
        by_robots,
        targets: Vec::new(),
        wall_s: wall.elapsed().as_secs_f64(),
    };
    report.targets = targets(&report);
    let json = serde_json::to_string_pretty(&report)?;
    std::fs::write(&args.out, json + "\n")
        .with_context(|| format!("writing {}", args.out.display()))?;
    println!("{}", table(&report));
    println!("written: {}", args.out.display());
    Ok(report)
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use armtwin_service::config::{Overrides, ServiceConfig};

    use super::trials::with_config_extra;
    use crate::net;

    #[test]
    fn extra_configuration_is_appended_after_the_robots() {
        let text = with_config_extra(
            &crate::fleet::service_config_encoded(2, "zenoh-serialized"),
            "[opcua]\nendpoint = \"opc.tcp://127.0.0.1:4840\"\nanonymous = true",
        );
        let config = ServiceConfig::parse(&text, "generated", Path::new(""), &Overrides::default())
            .expect("valid configuration");
        assert_eq!(config.robots.len(), 2);
        let opcua = config.opcua.expect("the OPC UA server configured");
        assert_eq!(
            opcua.sampling_interval,
            std::time::Duration::from_millis(100)
        );
        let unchanged = with_config_extra("[service]\n", "");
        assert_eq!(unchanged, "[service]\n");
    }

    #[test]
    fn the_generated_configuration_lists_every_robot() {
        let config = crate::fleet::parsed_service_config(3).expect("valid configuration");
        assert_eq!(config.robots.len(), 3);
        assert!(config.robots.contains_key(&net::robot_id(2)));
        assert!(
            config.default_robot.is_none(),
            "unknown robots are rejected"
        );
    }
}
