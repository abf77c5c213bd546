//! `armtwin-bench run`: the orchestrator. For each row (robot count, encoding, gateway count) it
//! starts the plain echo, then `armtwin serve`, each as a subprocess on a free loopback port,
//! with the load generator in a process of its own, so that each row's ratio compares the two
//! on the same machine within minutes. Then robots new to a fresh echo and armtwin at full rate
//! (first contact); `armtwin serve` once more for resident memory at fleet size, timing how long
//! it takes to declare the robots and, restarted on its snapshot, to declare them again; the
//! echo's memory. Prints the ratios and every target met or not, and writes them, with every
//! trial, to `bench.json`.
//!
//! Owns process lifetimes, the generated service configuration and the report; measures
//! nothing itself (the load generator does).
#![allow(
    clippy::print_stdout,
    clippy::print_stderr,
    reason = "a benchmark command's progress and report, on its terminal"
)]

use std::fmt::Write as _;
use std::io::{BufRead, BufReader};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result, bail};
use clap::Args;
use serde::Serialize;

use crate::fleet::{service_config_encoded, service_config_with_state};
use crate::load::{Latency, LoadReport, Target, Trial, WireEncoding};
use crate::net;

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
    /// The `armtwin` binary (default: next to this one).
    #[arg(long)]
    pub armtwin: Option<PathBuf>,
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
    /// First contact: robots (0: none).
    pub first_contact_robots: usize,
    /// First contact: samples/s (none: the echo's sustained rate).
    pub first_contact_rate: Option<f64>,
    /// First contact: seconds.
    pub first_contact_duration_s: f64,
    /// Measured poses embedded in the joint messages.
    pub embedded: bool,
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
            first_contact_robots: args.first_contact_robots.unwrap_or(largest),
            first_contact_rate: args.first_contact_rate,
            first_contact_duration_s: pick(args.first_contact_duration, 3.0, 0.5),
            embedded: args.embedded,
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
}

/// Echo and armtwin at one robot count, encoding and gateway count.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    /// Robots.
    pub robots: usize,
    /// The samples' format, and armtwin's poses' and deviations'.
    pub encoding: WireEncoding,
    /// Load sessions the robots were split over.
    pub gateways: u16,
    /// Highest sustained rate of the echo (samples/s).
    pub echo_throughput: f64,
    /// Highest sustained rate of armtwin (samples/s).
    pub armtwin_throughput: f64,
    /// armtwin / echo.
    pub throughput_ratio: f64,
    /// armtwin's p99 minus the echo's (µs).
    pub added_latency_p99_us: f64,
    /// CPU time of the system under test per sample in the search's best trial (µs).
    pub echo_cpu_us_per_sample: Option<f64>,
    /// Same for armtwin.
    pub armtwin_cpu_us_per_sample: Option<f64>,
    /// The echo's latency.
    pub echo_latency: LatencySummary,
    /// armtwin's latency.
    pub armtwin_latency: LatencySummary,
    /// The echo's throughput search (and fleet check).
    pub echo: LoadReport,
    /// armtwin's throughput search (and fleet check).
    pub armtwin: LoadReport,
}

/// Latency over several rounds: each percentile is the median of the rounds' (a round that a
/// burst of other work on the machine spoils does not decide the figure).
#[derive(Debug, Clone, Serialize)]
pub struct LatencySummary {
    /// Median over the rounds of the 50th percentile (µs).
    pub p50_us: f64,
    /// Median of the 99th percentiles (µs).
    pub p99_us: f64,
    /// Median of the 99.9th percentiles (µs).
    pub p999_us: f64,
    /// Every round.
    pub rounds: Vec<Latency>,
}

impl LatencySummary {
    fn of(rounds: Vec<Latency>) -> Self {
        let median = |pick: fn(&Latency) -> f64| {
            let mut values: Vec<f64> = rounds.iter().map(pick).collect();
            values.sort_by(f64::total_cmp);
            match values.len() {
                0 => f64::NAN,
                n if n % 2 == 1 => values[n / 2],
                n => f64::midpoint(values[n / 2 - 1], values[n / 2]),
            }
        };
        Self {
            p50_us: median(|l| l.p50_us),
            p99_us: median(|l| l.p99_us),
            p999_us: median(|l| l.p999_us),
            rounds,
        }
    }
}

/// Whether armtwin sustains the fleet rate at the largest robot count, embedded samples.
#[derive(Debug, Clone, Serialize)]
pub struct Fleet {
    /// Robots.
    pub robots: usize,
    /// The samples' format.
    pub encoding: WireEncoding,
    /// Load sessions.
    pub gateways: u16,
    /// Each sample one joint message with its measured pose embedded.
    pub embedded: bool,
    /// Hz per robot.
    pub hz_per_robot: f64,
    /// Samples per second in total.
    pub rate: f64,
    /// The echo at that rate, zero loss and on schedule.
    pub echo_sustained: bool,
    /// armtwin at that rate, zero loss and on schedule.
    pub armtwin_sustained: bool,
}

/// Robots new to a freshly started system at full rate: what comes through, armtwin against an
/// echo that also declares each robot's publishers on its first sample (`echo --lazy`).
#[derive(Debug, Clone, Serialize)]
pub struct FirstContact {
    /// Robots, all new.
    pub robots: usize,
    /// The samples' format.
    pub encoding: WireEncoding,
    /// Load sessions.
    pub gateways: u16,
    /// Samples/s offered.
    pub rate: f64,
    /// Poses/s the echo delivered (poses received / first send to last reply).
    pub echo_delivered_rate: f64,
    /// Same for armtwin.
    pub armtwin_delivered_rate: f64,
    /// armtwin / echo.
    pub ratio: f64,
    /// The echo's trial.
    pub echo: Trial,
    /// armtwin's trial.
    pub armtwin: Trial,
}

/// One of the benchmark's targets, against what this run measured.
#[derive(Debug, Clone, Serialize)]
pub struct TargetRow {
    /// The figure.
    pub figure: String,
    /// What was measured (null: not measured).
    pub measured: Option<f64>,
    /// The target, as text.
    pub target: String,
    /// Whether it was met.
    pub met: bool,
}

/// `bench.json`.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// Unix time of the start (s).
    pub started_unix_s: u64,
    /// Where it ran.
    pub host: Host,
    /// What was asked.
    pub settings: Settings,
    /// Robot count of the headline figures (the largest).
    pub headline_robots: usize,
    /// Encoding of the headline figures (the last).
    pub headline_encoding: WireEncoding,
    /// Gateways of the headline figures (the first count).
    pub headline_gateways: u16,
    /// Echo throughput of the headline row (samples/s; each sample one joint and one measured
    /// message in, two messages out).
    pub echo_throughput: f64,
    /// armtwin throughput at `headline_robots`.
    pub armtwin_throughput: f64,
    /// armtwin / echo at `headline_robots`.
    pub throughput_ratio: f64,
    /// armtwin p99 − echo p99 at `headline_robots` (µs).
    pub added_latency_p99_us: f64,
    /// Resident bytes per tracked robot (null when not measured).
    pub bytes_per_robot: Option<f64>,
    /// Every row: robot count, encoding, gateways.
    pub by_robots: Vec<Comparison>,
    /// First contact.
    pub first_contact: Vec<FirstContact>,
    /// Seconds from the first samples of the memory measurement's robots new after its baseline
    /// until every robot's liveliness token was visible (null when not measured).
    pub declare_s: Option<f64>,
    /// Seconds from starting armtwin again on the memory measurement's snapshot until every
    /// robot's liveliness token was visible (null when not measured).
    pub restart_s: Option<f64>,
    /// Every target and whether it was met.
    pub targets: Vec<TargetRow>,
    /// Seconds the whole run took.
    pub wall_s: f64,
    /// The fleet check.
    pub fleet: Option<Fleet>,
    /// The memory measurement's load report.
    pub memory: Option<LoadReport>,
    /// The echo's resident bytes per robot, the transport's own share (null when not measured).
    pub echo_bytes_per_robot: Option<f64>,
    /// The echo's memory measurement.
    pub echo_memory: Option<EchoMemory>,
}

/// The echo's resident memory with few and with many robots, each run started afresh (the echo
/// declares every robot's publishers and input keys up front), every robot having sent the same
/// samples: Zenoh's own per-robot cost for the same keys.
#[derive(Debug, Clone, Serialize)]
pub struct EchoMemory {
    /// Robots of the small run.
    pub base_robots: usize,
    /// RSS of the small run once every robot was answered (KiB).
    pub rss_base_kib: u64,
    /// Robots of the large run.
    pub robots: usize,
    /// RSS of the large run once every robot was answered (KiB).
    pub rss_full_kib: u64,
    /// `(rss_full − rss_base) / (robots − base_robots)`, bytes.
    pub bytes_per_robot: f64,
}

/// The machine.
#[derive(Debug, Clone, Serialize)]
pub struct Host {
    /// Logical CPUs.
    pub cpus: usize,
    /// `model name` of /proc/cpuinfo.
    pub cpu_model: String,
    /// 1-minute load average at the start (other work on the machine).
    pub loadavg_start: Option<f64>,
}

impl Host {
    fn probe() -> Self {
        let cpu_model = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|info| {
                info.lines()
                    .find_map(|line| line.strip_prefix("model name"))
                    .map(|rest| rest.trim_start_matches([' ', '\t', ':']).to_owned())
            })
            .unwrap_or_default();
        let loadavg_start = std::fs::read_to_string("/proc/loadavg")
            .ok()
            .and_then(|text| text.split_whitespace().next()?.parse().ok());
        Self {
            cpus: std::thread::available_parallelism().map_or(1, usize::from),
            cpu_model,
            loadavg_start,
        }
    }
}

/// A subprocess under test, stopped (SIGTERM, then SIGKILL) when dropped.
struct SystemUnderTest {
    child: Child,
    endpoint: String,
}

impl SystemUnderTest {
    fn pid(&self) -> u32 {
        self.child.id()
    }

    fn stop(mut self) {
        self.terminate();
    }

    fn terminate(&mut self) {
        if matches!(self.child.try_wait(), Ok(Some(_))) {
            return;
        }
        // std offers only SIGKILL; SIGTERM lets armtwin shut down as in production.
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        drop(self.child.stdin.take());
        let deadline = Instant::now() + STOP_TIMEOUT;
        while Instant::now() < deadline {
            if matches!(self.child.try_wait(), Ok(Some(_))) {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for SystemUnderTest {
    fn drop(&mut self) {
        self.terminate();
    }
}

fn free_port() -> Result<u16> {
    let listener = TcpListener::bind("127.0.0.1:0").context("finding a free port")?;
    Ok(listener.local_addr()?.port())
}

/// Waits until `port` accepts connections (the system under test is listening).
fn wait_listening(port: u16, child: &mut Child) -> Result<()> {
    let deadline = Instant::now() + STARTUP_TIMEOUT;
    while Instant::now() < deadline {
        if TcpStream::connect(("127.0.0.1", port)).is_ok() {
            return Ok(());
        }
        if let Some(status) = child.try_wait()? {
            bail!("the system under test exited before listening: {status}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    bail!("the system under test did not listen on port {port} within {STARTUP_TIMEOUT:?}")
}

struct Orchestrator {
    settings: Settings,
    /// Unix time (s) every load process's stamps count from.
    clock_origin_s: f64,
    bench: PathBuf,
    armtwin: PathBuf,
    work_dir: PathBuf,
}

impl Orchestrator {
    fn start_echo(&self, robots: usize, lazy: bool) -> Result<SystemUnderTest> {
        let port = free_port()?;
        let endpoint = net::loopback_endpoint(port);
        let mut child = Command::new(&self.bench)
            .args(["echo", "-l", &endpoint, "--robots", &robots.to_string()])
            .args(lazy.then_some("--lazy"))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting {}", self.bench.display()))?;
        let stdout = child.stdout.take().context("echo stdout")?;
        let mut line = String::new();
        BufReader::new(stdout).read_line(&mut line)?;
        if line.trim() != "ready" {
            let _ = child.kill();
            bail!("the echo did not start: {line:?}");
        }
        wait_listening(port, &mut child)?;
        Ok(SystemUnderTest { child, endpoint })
    }

    /// `armtwin serve` with `config` (a file name in the work directory, written with `text`).
    fn start_armtwin_with(&self, config: &str, text: &str) -> Result<SystemUnderTest> {
        let port = free_port()?;
        let endpoint = net::loopback_endpoint(port);
        let config = self.work_dir.join(config);
        std::fs::write(&config, text).with_context(|| format!("writing {}", config.display()))?;
        let mut child = Command::new(&self.armtwin)
            .arg("serve")
            .arg("-c")
            .arg(&config)
            .args(["-l", &endpoint])
            .env("RUST_LOG", "armtwin=warn,zenoh=error")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .with_context(|| format!("starting {}", self.armtwin.display()))?;
        wait_listening(port, &mut child)?;
        Ok(SystemUnderTest { child, endpoint })
    }

    fn start_armtwin(&self, robots: usize, encoding: WireEncoding) -> Result<SystemUnderTest> {
        self.start_armtwin_with(
            &format!("armtwin-{robots}-{}.toml", encoding.as_str()),
            &service_config_encoded(robots, encoding.as_str()),
        )
    }

    fn load(
        &self,
        sut: &SystemUnderTest,
        target: Target,
        encoding: WireEncoding,
        extra: &[String],
    ) -> Result<LoadReport> {
        let target_name = match target {
            Target::Echo => "echo",
            Target::Armtwin => "armtwin",
        };
        // One file per system under test: binary messages' gateway `seq` goes on from one load
        // process to the next.
        let seq_file = self
            .work_dir
            .join(format!("seq-{target_name}-{}.json", sut.pid()));
        let output = Command::new(&self.bench)
            .args(["load", "-e", &sut.endpoint, "--target", target_name])
            .args(["--sut-pid", &sut.pid().to_string()])
            .args(["--encoding", encoding.as_str()])
            .args(["--clock-origin", &self.clock_origin_s.to_string()])
            .arg("--seq-file")
            .arg(&seq_file)
            .args(extra)
            .stdin(Stdio::null())
            .stderr(Stdio::inherit())
            .output()
            .context("running the load generator")?;
        if !output.status.success() {
            bail!("the load generator failed: {}", output.status);
        }
        serde_json::from_slice(&output.stdout).context("reading the load generator's report")
    }

    /// The load's flags of a latency run.
    fn latency_flags(&self) -> [String; 4] {
        let s = &self.settings;
        [
            "--latency-rate".into(),
            s.latency_rate.to_string(),
            "--latency-duration".into(),
            s.latency_duration_s.to_string(),
        ]
    }

    /// Load arguments for `robots` over `gateways` sessions: a latency run only, or the search
    /// from `start_rate` (and the fleet check).
    fn load_args(
        &self,
        robots: usize,
        gateways: u16,
        latency: bool,
        start_rate: f64,
        fleet_rate: Option<f64>,
    ) -> Vec<String> {
        let s = &self.settings;
        let mut args: Vec<String> = vec![
            "--robots".into(),
            robots.to_string(),
            "--gateways".into(),
            gateways.to_string(),
        ];
        if s.embedded {
            args.push("--embedded".into());
        }
        if latency {
            args.extend(self.latency_flags());
            return args;
        }
        args.extend([
            "--start-rate".into(),
            start_rate.to_string(),
            "--max-rate".into(),
            s.max_rate.to_string(),
            "--duration".into(),
            s.duration_s.to_string(),
            "--bisect-steps".into(),
            s.bisect_steps.to_string(),
            "--retries".into(),
            s.retries.to_string(),
        ]);
        if let Some(rate) = fleet_rate {
            args.extend([
                "--check-rate".into(),
                rate.to_string(),
                "--check-duration".into(),
                s.fleet_duration_s.to_string(),
                "--check-embedded".into(),
            ]);
        }
        args
    }

    /// Both systems run side by side (each idle while the other is measured): latency rounds
    /// alternate between them, so that both see the same machine; then each one's search, the
    /// echo's from `start_rate`, armtwin's from half the echo's result. The last latency round
    /// runs in the load process of the search, which saves each system a load process's start
    /// and its declarations.
    fn compare(
        &self,
        robots: usize,
        encoding: WireEncoding,
        gateways: u16,
        start_rate: f64,
        fleet_rate: Option<f64>,
    ) -> Result<Comparison> {
        let row = format!(
            "{robots} robots, {}, {gateways} gateways",
            encoding.as_str()
        );
        let echo_sut = self.start_echo(robots, false)?;
        let armtwin_sut = self.start_armtwin(robots, encoding)?;
        let latency_args = self.load_args(robots, gateways, true, 0.0, None);
        let mut echo_rounds = Vec::new();
        let mut armtwin_rounds = Vec::new();
        for round in 1..self.settings.latency_rounds {
            eprintln!("== {row}: latency round {round}, echo then armtwin serve");
            echo_rounds.extend(
                self.load(&echo_sut, Target::Echo, encoding, &latency_args)?
                    .latency,
            );
            armtwin_rounds.extend(
                self.load(&armtwin_sut, Target::Armtwin, encoding, &latency_args)?
                    .latency,
            );
        }
        let throughput = |report: &LoadReport| {
            report
                .search
                .as_ref()
                .map_or(0.0, |search| search.max_sustained_rate)
        };
        // The last latency round, then the search.
        let with_latency = |mut search_args: Vec<String>| {
            if self.settings.latency_rounds > 0 {
                search_args.extend(self.latency_flags());
            }
            search_args
        };
        eprintln!("== {row}: echo latency and throughput");
        let echo_args =
            with_latency(self.load_args(robots, gateways, false, start_rate, fleet_rate));
        let echo = self.load(&echo_sut, Target::Echo, encoding, &echo_args)?;
        echo_sut.stop();
        echo_rounds.extend(echo.latency.clone());
        eprintln!("== {row}: armtwin serve latency and throughput");
        let armtwin_start = if throughput(&echo) > 0.0 {
            (throughput(&echo) / 2.0).round()
        } else {
            start_rate
        };
        let armtwin_args =
            with_latency(self.load_args(robots, gateways, false, armtwin_start, fleet_rate));
        let armtwin = self.load(&armtwin_sut, Target::Armtwin, encoding, &armtwin_args)?;
        armtwin_sut.stop();
        armtwin_rounds.extend(armtwin.latency.clone());
        let cpu_per_sample = |report: &LoadReport| {
            let search = report.search.as_ref()?;
            let best = search
                .trials
                .iter()
                .filter(|trial| trial.sustained)
                .max_by(|a, b| a.offered_rate.total_cmp(&b.offered_rate))?;
            Some(best.sut_cpu_s? * 1e6 / best.samples as f64)
        };
        let echo_latency = LatencySummary::of(echo_rounds);
        let armtwin_latency = LatencySummary::of(armtwin_rounds);
        Ok(Comparison {
            robots,
            encoding,
            gateways,
            echo_throughput: throughput(&echo),
            armtwin_throughput: throughput(&armtwin),
            throughput_ratio: throughput(&armtwin) / throughput(&echo),
            added_latency_p99_us: armtwin_latency.p99_us - echo_latency.p99_us,
            echo_cpu_us_per_sample: cpu_per_sample(&echo),
            armtwin_cpu_us_per_sample: cpu_per_sample(&armtwin),
            echo_latency,
            armtwin_latency,
            echo,
            armtwin,
        })
    }

    /// Robots new to a freshly started echo (`--lazy`) and armtwin, at `rate` for a few
    /// seconds, every reply awaited.
    fn first_contact(&self, rate: f64) -> Result<FirstContact> {
        let s = &self.settings;
        let (robots, encoding, gateways) = (
            s.first_contact_robots,
            s.last_encoding(),
            s.first_gateways(),
        );
        let args: Vec<String> = vec![
            "--robots".into(),
            robots.to_string(),
            "--gateways".into(),
            gateways.to_string(),
            "--first-contact-rate".into(),
            rate.to_string(),
            "--first-contact-duration".into(),
            s.first_contact_duration_s.to_string(),
        ];
        let trial = |sut: SystemUnderTest, target: Target| -> Result<Trial> {
            let trial = self
                .load(&sut, target, encoding, &args)?
                .first_contact
                .context("the load ran no first-contact trial")?;
            sut.stop();
            Ok(trial)
        };
        eprintln!("== first contact: {robots} new robots at {rate:.0} samples/s, echo --lazy");
        let echo = trial(self.start_echo(robots, true)?, Target::Echo)?;
        eprintln!("== first contact: armtwin serve");
        let armtwin = trial(self.start_armtwin(robots, encoding)?, Target::Armtwin)?;
        let echo_delivered_rate = echo.delivered_rate.unwrap_or(0.0);
        let armtwin_delivered_rate = armtwin.delivered_rate.unwrap_or(0.0);
        Ok(FirstContact {
            robots,
            encoding,
            gateways,
            rate,
            echo_delivered_rate,
            armtwin_delivered_rate,
            ratio: armtwin_delivered_rate / echo_delivered_rate,
            echo,
            armtwin,
        })
    }

    /// armtwin's memory at fleet size (which also times declaring the robots new after the
    /// baseline), then, unless skipped, a restart on the snapshot it wrote when stopped: seconds
    /// from starting the process until every robot's token is visible again.
    fn memory(&self) -> Result<(LoadReport, Option<f64>)> {
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
    fn restart(&self, config_name: &str, config: &str, encoding: WireEncoding) -> Result<f64> {
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

    fn echo_memory(&self) -> Result<EchoMemory> {
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
}

impl Orchestrator {
    /// armtwin's memory (with the declaration time and the restart), then the echo's; a failed
    /// measurement is reported and left out.
    fn fleet_size(&self) -> (Option<LoadReport>, Option<f64>, Option<EchoMemory>) {
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

    /// Every row: each robot count in each encoding over the first gateway count, then the
    /// largest robot count in the last encoding over each further gateway count; the fleet
    /// check (at `fleet_rate`) in `fleet_row`.
    fn compare_rows(
        &self,
        fleet_row: (usize, WireEncoding, u16),
        fleet_rate: Option<f64>,
    ) -> Result<Vec<Comparison>> {
        let settings = &self.settings;
        let largest = settings.robots.iter().copied().max().unwrap_or(1);
        let mut rows: Vec<(usize, WireEncoding, u16)> = Vec::new();
        for &encoding in &settings.encodings {
            for &robots in &settings.robots {
                rows.push((robots, encoding, settings.first_gateways()));
            }
        }
        for &gateways in settings.gateways.iter().skip(1) {
            rows.push((largest, settings.last_encoding(), gateways));
        }
        let mut by_robots: Vec<Comparison> = Vec::new();
        for &(robots, encoding, gateways) in &rows {
            let fleet = fleet_rate.filter(|_| (robots, encoding, gateways) == fleet_row);
            // The echo's search starts at its last result in the same encoding, where the next
            // row's usually is (fewer doubling trials than from the start rate).
            let start_rate = by_robots
                .iter()
                .rev()
                .find(|c| c.encoding == encoding && c.echo_throughput > 0.0)
                .map_or(settings.start_rate, |c| c.echo_throughput);
            by_robots.push(self.compare(robots, encoding, gateways, start_rate, fleet)?);
        }
        Ok(by_robots)
    }
}

fn unix_now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

fn fmt_rate(rate: f64) -> String {
    if rate >= 1000.0 {
        format!("{:.1} k", rate / 1000.0)
    } else {
        format!("{rate:.0}")
    }
}

/// The table printed at the end (also the one in BENCHMARKS.md).
fn table(report: &Report) -> String {
    let mut text = String::new();
    let _ = writeln!(
        text,
        "| robots | encoding | gateways | echo samples/s | armtwin samples/s | ratio | echo p50 / p99 / p99.9 µs | armtwin p50 / p99 / p99.9 µs | added p99 µs | CPU µs/sample echo / armtwin |"
    );
    let _ = writeln!(
        text,
        "| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
    );
    for c in &report.by_robots {
        let latency =
            |l: &LatencySummary| format!("{:.0} / {:.0} / {:.0}", l.p50_us, l.p99_us, l.p999_us);
        let cpu = |v: Option<f64>| v.map_or_else(|| "–".to_owned(), |v| format!("{v:.1}"));
        let _ = writeln!(
            text,
            "| {} | {} | {} | {} | {} | {:.2} | {} | {} | {:.0} | {} / {} |",
            c.robots,
            c.encoding.as_str(),
            c.gateways,
            fmt_rate(c.echo_throughput),
            fmt_rate(c.armtwin_throughput),
            c.throughput_ratio,
            latency(&c.echo_latency),
            latency(&c.armtwin_latency),
            c.added_latency_p99_us,
            cpu(c.echo_cpu_us_per_sample),
            cpu(c.armtwin_cpu_us_per_sample),
        );
    }
    let tracking: Vec<String> = report
        .by_robots
        .iter()
        .filter_map(|c| {
            c.armtwin.tracking_s.map(|s| {
                let plural = if c.robots == 1 { "" } else { "s" };
                format!(
                    "{} robot{plural} ({}, {} gateways) {s:.1} s",
                    c.robots,
                    c.encoding.as_str(),
                    c.gateways
                )
            })
        })
        .collect();
    if !tracking.is_empty() {
        let _ = writeln!(
            text,
            "\narmtwin's entities all declared (every liveliness token visible), after the warm-up: {}; the trials start then",
            tracking.join(", ")
        );
    }
    text.push_str(&notes(report));
    text.push_str(&targets_table(report));
    text
}

/// The fleet check, first contact and memory, a line each.
fn notes(report: &Report) -> String {
    let mut text = String::new();
    if let Some(fleet) = &report.fleet {
        let sustained = |yes: bool| if yes { "sustained" } else { "NOT sustained" };
        let _ = writeln!(
            text,
            "\nfleet check: {} robots × {} Hz = {} samples/s, embedded, {}, {} gateways, for the configured seconds: echo {}, armtwin {}",
            fleet.robots,
            fleet.hz_per_robot,
            fmt_rate(fleet.rate),
            fleet.encoding.as_str(),
            fleet.gateways,
            sustained(fleet.echo_sustained),
            sustained(fleet.armtwin_sustained),
        );
    }
    for contact in &report.first_contact {
        let _ = writeln!(
            text,
            "first contact: {} new robots, {}, {} samples/s offered: echo --lazy delivered {}/s, armtwin {}/s, ratio {:.2}",
            contact.robots,
            contact.encoding.as_str(),
            fmt_rate(contact.rate),
            fmt_rate(contact.echo_delivered_rate),
            fmt_rate(contact.armtwin_delivered_rate),
            contact.ratio
        );
    }
    if let Some(memory) = report.memory.as_ref().and_then(|m| m.memory.as_ref()) {
        let _ = writeln!(
            text,
            "memory: {} robots, {} samples each: RSS {} KiB at start, {} KiB with {} robots, {} KiB with all: {:.0} bytes per tracked robot",
            memory.robots,
            memory.samples_per_robot,
            memory.rss_start_kib,
            memory.rss_base_kib,
            memory.base_robots,
            memory.rss_full_kib,
            memory.bytes_per_robot
        );
    }
    if let Some(echo) = &report.echo_memory {
        let _ = writeln!(
            text,
            "memory, echo: RSS {} KiB with {} robots, {} KiB with {}: {:.0} bytes per robot",
            echo.rss_base_kib,
            echo.base_robots,
            echo.rss_full_kib,
            echo.robots,
            echo.bytes_per_robot
        );
    }
    text
}

/// The targets, each met or not, and the wall time.
fn targets_table(report: &Report) -> String {
    let mut text = String::new();
    let _ = writeln!(text, "\n| figure | measured | target | met |");
    let _ = writeln!(text, "| --- | ---: | --- | --- |");
    for row in &report.targets {
        let measured = row
            .measured
            .map_or_else(|| "not measured".to_owned(), |v| format!("{v:.2}"));
        let met = if row.met { "yes" } else { "no" };
        let _ = writeln!(
            text,
            "| {} | {measured} | {} | {met} |",
            row.figure, row.target
        );
    }
    let _ = writeln!(text, "\nwall time: {:.0} s", report.wall_s);
    text
}

/// The benchmark's targets against this run's figures.
fn targets(report: &Report) -> Vec<TargetRow> {
    let mut rows = Vec::new();
    for c in &report.by_robots {
        let least = match c.encoding {
            WireEncoding::ZenohSerialized => 0.85,
            WireEncoding::Json => 0.6,
        };
        rows.push(TargetRow {
            figure: format!(
                "throughput / echo's, {}, {} robots, {} gateways",
                c.encoding.as_str(),
                c.robots,
                c.gateways
            ),
            measured: Some(c.throughput_ratio),
            target: format!("≥ {least}"),
            met: c.throughput_ratio >= least,
        });
    }
    for contact in &report.first_contact {
        rows.push(TargetRow {
            figure: format!(
                "first contact / echo --lazy's, {}, {} new robots",
                contact.encoding.as_str(),
                contact.robots
            ),
            measured: Some(contact.ratio),
            target: "≥ 0.5".to_owned(),
            met: contact.ratio >= 0.5,
        });
    }
    if let Some(fleet) = &report.fleet {
        rows.push(TargetRow {
            figure: format!(
                "{} robots × {} Hz, embedded, {}, zero loss (armtwin; measured: samples/s delivered)",
                fleet.robots,
                fleet.hz_per_robot,
                fleet.encoding.as_str()
            ),
            measured: report
                .by_robots
                .iter()
                .find_map(|c| c.armtwin.check.as_ref())
                .and_then(|check| check.delivered_rate),
            target: "sustained".to_owned(),
            met: fleet.armtwin_sustained,
        });
    }
    if let Some(bytes) = report.bytes_per_robot {
        let allowed = report.echo_bytes_per_robot.map(|echo| echo + 2048.0);
        rows.push(TargetRow {
            figure: "bytes per tracked robot at fleet size".to_owned(),
            measured: Some(bytes),
            target: allowed.map_or_else(
                || "≤ the echo's + 2 KiB (echo not measured)".to_owned(),
                |allowed| format!("≤ the echo's + 2 KiB = {allowed:.0}"),
            ),
            met: allowed.is_some_and(|allowed| bytes <= allowed),
        });
    }
    for (figure, value) in [
        (
            "seconds until every new robot's token is visible",
            report.declare_s,
        ),
        (
            "seconds from a restart until every token is visible",
            report.restart_s,
        ),
    ] {
        rows.push(TargetRow {
            figure: figure.to_owned(),
            measured: value,
            target: "≤ 10".to_owned(),
            met: value.is_some_and(|s| s <= 10.0),
        });
    }
    rows.push(TargetRow {
        figure: "armtwin-bench run wall time (s)".to_owned(),
        measured: Some(report.wall_s),
        target: "≤ 600".to_owned(),
        met: report.wall_s <= 600.0,
    });
    rows
}

fn default_armtwin(bench: &Path) -> PathBuf {
    bench.with_file_name(format!("armtwin{}", std::env::consts::EXE_SUFFIX))
}

/// Runs the whole benchmark and writes the report.
///
/// In order: each robot count in each encoding over the first gateway count; the largest robot
/// count in the last encoding over each further gateway count (the fleet check rides on the row
/// of the most gateways); first contact at the echo's sustained rate of the largest robot count;
/// armtwin's memory at fleet size, with the declaration time and the restart; the echo's memory.
pub fn run(args: &RunArgs) -> Result<Report> {
    let wall = Instant::now();
    let settings = Settings::of(args);
    let bench = std::env::current_exe().context("locating armtwin-bench")?;
    let armtwin = args
        .armtwin
        .clone()
        .unwrap_or_else(|| default_armtwin(&bench));
    if !armtwin.is_file() {
        bail!(
            "{} not found: build it (cargo build --release) or pass --armtwin",
            armtwin.display()
        );
    }
    let work_dir = std::env::temp_dir().join(format!("armtwin-bench-{}", std::process::id()));
    std::fs::create_dir_all(&work_dir)?;
    let orchestrator = Orchestrator {
        settings: settings.clone(),
        clock_origin_s: unix_now_s(),
        bench,
        armtwin,
        work_dir: work_dir.clone(),
    };
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
    let (memory, restart_s, echo_memory) = orchestrator.fleet_size();
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
        memory,
        echo_bytes_per_robot: echo_memory.as_ref().map(|m| m.bytes_per_robot),
        echo_memory,
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
    use super::*;

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
