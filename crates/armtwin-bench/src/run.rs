//! `armtwin-bench run`: the orchestrator. For each robot count it starts the plain echo, then
//! `armtwin serve`, each as a subprocess on a free loopback port, with the load generator in a
//! process of its own; then `armtwin serve` once more for resident memory at fleet size. Prints
//! the ratios and writes them, with every trial, to `bench.json`.
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

use crate::fleet::service_config_encoded;
use crate::load::{Latency, LoadReport, Target, WireEncoding};
use crate::net;

/// How long a system under test may take to listen.
const STARTUP_TIMEOUT: Duration = Duration::from_secs(60);
/// How long a system under test may take to stop after SIGTERM.
const STOP_TIMEOUT: Duration = Duration::from_secs(20);

/// `armtwin-bench run` arguments; `--quick` changes the defaults to a smoke run of seconds.
#[derive(Debug, Clone, Args)]
pub struct RunArgs {
    /// A short smoke run: small fleets, short trials, low rates.
    #[arg(long)]
    pub quick: bool,
    /// Robot counts (default 1,100,1000; quick 1,10).
    #[arg(long, value_delimiter = ',')]
    pub robots: Vec<usize>,
    /// Robots for the memory measurement (default 10000; quick 100; 0 skips it).
    #[arg(long)]
    pub memory_robots: Option<usize>,
    /// Robots tracked for the memory baseline.
    #[arg(long, default_value_t = 10)]
    pub memory_base_robots: usize,
    /// Samples each robot sends in the memory measurement.
    #[arg(long, default_value_t = 4)]
    pub memory_samples: u64,
    /// Seconds per throughput trial (default 2; quick 0.25).
    #[arg(long)]
    pub duration: Option<f64>,
    /// First rate of the throughput search, samples/s (default 5000; quick 200).
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
    /// Latency run length, seconds (default 5; quick 0.5).
    #[arg(long)]
    pub latency_duration: Option<f64>,
    /// Latency rounds per system, alternating between them (default 3; quick 1).
    #[arg(long)]
    pub latency_rounds: Option<u32>,
    /// Per-robot rate of the fleet check at the largest robot count, Hz (default 100; quick 10).
    #[arg(long)]
    pub fleet_hz: Option<f64>,
    /// Seconds of the fleet check (default 10; quick 0.5; 0 skips it).
    #[arg(long)]
    pub fleet_duration: Option<f64>,
    /// Send each sample as one joint message with the measured pose embedded (RTDE style), not
    /// as a joint and a measured message.
    #[arg(long)]
    pub embedded: bool,
    /// The samples' format, and armtwin's poses' and deviations' (`[service] encoding`).
    #[arg(long, value_enum, default_value_t = WireEncoding::Json)]
    pub encoding: WireEncoding,
    /// The `armtwin` binary (default: next to this one).
    #[arg(long)]
    pub armtwin: Option<PathBuf>,
    /// Where to write the report.
    #[arg(long, default_value = "bench.json")]
    pub out: PathBuf,
}

/// The settings of one run, defaults filled in.
#[derive(Debug, Clone, Serialize)]
pub struct Settings {
    /// Smoke run.
    pub quick: bool,
    /// Robot counts.
    pub robots: Vec<usize>,
    /// Robots of the memory measurement (0: none).
    pub memory_robots: usize,
    /// Robots of the memory baseline.
    pub memory_base_robots: usize,
    /// Samples per robot in the memory measurement.
    pub memory_samples: u64,
    /// Seconds per throughput trial.
    pub duration_s: f64,
    /// First rate of the search.
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
    /// Measured poses embedded in the joint messages.
    pub embedded: bool,
    /// The samples' format, and armtwin's poses' and deviations'.
    pub encoding: WireEncoding,
}

impl Settings {
    fn of(args: &RunArgs) -> Self {
        let quick = args.quick;
        let pick = |value: Option<f64>, normal: f64, smoke: f64| {
            value.unwrap_or(if quick { smoke } else { normal })
        };
        Self {
            quick,
            robots: if args.robots.is_empty() {
                if quick {
                    vec![1, 10]
                } else {
                    vec![1, 100, 1000]
                }
            } else {
                args.robots.clone()
            },
            memory_robots: args
                .memory_robots
                .unwrap_or(if quick { 100 } else { 10_000 }),
            memory_base_robots: args.memory_base_robots,
            memory_samples: args.memory_samples,
            duration_s: pick(args.duration, 2.0, 0.25),
            start_rate: pick(args.start_rate, 5000.0, 200.0),
            max_rate: pick(args.max_rate, 2_000_000.0, 800.0),
            bisect_steps: args.bisect_steps.unwrap_or(if quick { 1 } else { 4 }),
            retries: args.retries.unwrap_or(u32::from(!quick)),
            latency_rate: pick(args.latency_rate, 1000.0, 200.0),
            latency_duration_s: pick(args.latency_duration, 5.0, 0.5),
            latency_rounds: args.latency_rounds.unwrap_or(if quick { 1 } else { 3 }),
            fleet_hz: pick(args.fleet_hz, 100.0, 10.0),
            fleet_duration_s: pick(args.fleet_duration, 10.0, 0.5),
            embedded: args.embedded,
            encoding: args.encoding,
        }
    }
}

/// Echo and armtwin at one robot count.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    /// Robots.
    pub robots: usize,
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

/// Whether armtwin sustains the fleet rate at the largest robot count.
#[derive(Debug, Clone, Serialize)]
pub struct Fleet {
    /// Robots.
    pub robots: usize,
    /// Hz per robot.
    pub hz_per_robot: f64,
    /// Samples per second in total.
    pub rate: f64,
    /// The echo at that rate, zero loss and on schedule.
    pub echo_sustained: bool,
    /// armtwin at that rate, zero loss and on schedule.
    pub armtwin_sustained: bool,
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
    /// Echo throughput at `headline_robots` (samples/s; each sample one joint and one measured
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
    /// Every robot count.
    pub by_robots: Vec<Comparison>,
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
    fn start_echo(&self, robots: usize) -> Result<SystemUnderTest> {
        let port = free_port()?;
        let endpoint = net::loopback_endpoint(port);
        let mut child = Command::new(&self.bench)
            .args(["echo", "-l", &endpoint, "--robots", &robots.to_string()])
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

    fn start_armtwin(&self, robots: usize) -> Result<SystemUnderTest> {
        let port = free_port()?;
        let endpoint = net::loopback_endpoint(port);
        let config = self.work_dir.join(format!("armtwin-{robots}.toml"));
        std::fs::write(
            &config,
            service_config_encoded(robots, self.settings.encoding.as_str()),
        )
        .with_context(|| format!("writing {}", config.display()))?;
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

    fn load(&self, sut: &SystemUnderTest, target: Target, extra: &[String]) -> Result<LoadReport> {
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
            .args(["--encoding", self.settings.encoding.as_str()])
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

    /// Load arguments for `robots`: a latency run only, or the search (and the fleet check).
    fn load_args(&self, robots: usize, latency: bool, fleet_rate: Option<f64>) -> Vec<String> {
        let s = &self.settings;
        let mut args: Vec<String> = vec![
            "--robots".into(),
            robots.to_string(),
            "--clock-origin".into(),
            self.clock_origin_s.to_string(),
        ];
        if s.embedded {
            args.push("--embedded".into());
        }
        if latency {
            args.extend([
                "--latency-rate".into(),
                s.latency_rate.to_string(),
                "--latency-duration".into(),
                s.latency_duration_s.to_string(),
            ]);
            return args;
        }
        args.extend([
            "--start-rate".into(),
            s.start_rate.to_string(),
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
            ]);
        }
        args
    }

    /// Both systems run side by side (each idle while the other is measured): latency rounds
    /// alternate between them, so that both see the same machine; then each one's search.
    fn compare(&self, robots: usize, fleet_rate: Option<f64>) -> Result<Comparison> {
        let echo_sut = self.start_echo(robots)?;
        let armtwin_sut = self.start_armtwin(robots)?;
        let latency_args = self.load_args(robots, true, None);
        let mut echo_rounds = Vec::new();
        let mut armtwin_rounds = Vec::new();
        for round in 1..=self.settings.latency_rounds {
            eprintln!("== {robots} robots: latency round {round}, echo then armtwin serve");
            echo_rounds.extend(self.load(&echo_sut, Target::Echo, &latency_args)?.latency);
            armtwin_rounds.extend(
                self.load(&armtwin_sut, Target::Armtwin, &latency_args)?
                    .latency,
            );
        }
        let search_args = self.load_args(robots, false, fleet_rate);
        eprintln!("== {robots} robots: echo throughput");
        let echo = self.load(&echo_sut, Target::Echo, &search_args)?;
        echo_sut.stop();
        eprintln!("== {robots} robots: armtwin serve throughput");
        let armtwin = self.load(&armtwin_sut, Target::Armtwin, &search_args)?;
        armtwin_sut.stop();
        let throughput = |report: &LoadReport| {
            report
                .search
                .as_ref()
                .map_or(0.0, |search| search.max_sustained_rate)
        };
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

    fn memory(&self) -> Result<LoadReport> {
        let s = &self.settings;
        eprintln!("== memory: armtwin serve with {} robots", s.memory_robots);
        let sut = self.start_armtwin(s.memory_robots)?;
        let report = self.load(
            &sut,
            Target::Armtwin,
            &[
                "--robots".into(),
                s.memory_robots.to_string(),
                "--memory-base-robots".into(),
                s.memory_base_robots.to_string(),
                "--memory-samples".into(),
                s.memory_samples.to_string(),
            ],
        )?;
        sut.stop();
        Ok(report)
    }

    fn echo_memory(&self) -> Result<EchoMemory> {
        let s = &self.settings;
        let mut rss_kib = Vec::new();
        for robots in [s.memory_base_robots, s.memory_robots] {
            eprintln!("== memory: echo with {robots} robots");
            let sut = self.start_echo(robots)?;
            let report = self.load(
                &sut,
                Target::Echo,
                &[
                    "--robots".into(),
                    robots.to_string(),
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
        "| robots | echo samples/s | armtwin samples/s | ratio | echo p50 / p99 / p99.9 µs | armtwin p50 / p99 / p99.9 µs | added p99 µs | CPU µs/sample echo / armtwin |"
    );
    let _ = writeln!(
        text,
        "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
    );
    for c in &report.by_robots {
        let latency =
            |l: &LatencySummary| format!("{:.0} / {:.0} / {:.0}", l.p50_us, l.p99_us, l.p999_us);
        let cpu = |v: Option<f64>| v.map_or_else(|| "–".to_owned(), |v| format!("{v:.1}"));
        let _ = writeln!(
            text,
            "| {} | {} | {} | {:.2} | {} | {} | {:.0} | {} / {} |",
            c.robots,
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
                format!("{} robot{plural} {s:.1} s", c.robots)
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
    if let Some(fleet) = &report.fleet {
        let _ = writeln!(
            text,
            "\nfleet check: {} robots × {} Hz = {} samples/s for the configured seconds: echo {}, armtwin {}",
            fleet.robots,
            fleet.hz_per_robot,
            fmt_rate(fleet.rate),
            if fleet.echo_sustained {
                "sustained"
            } else {
                "NOT sustained"
            },
            if fleet.armtwin_sustained {
                "sustained"
            } else {
                "NOT sustained"
            },
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

fn default_armtwin(bench: &Path) -> PathBuf {
    bench.with_file_name(format!("armtwin{}", std::env::consts::EXE_SUFFIX))
}

/// Runs the whole benchmark and writes the report.
pub fn run(args: &RunArgs) -> Result<Report> {
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
        clock_origin_s: SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64()),
        bench,
        armtwin,
        work_dir: work_dir.clone(),
    };
    let started_unix_s = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let host = Host::probe();
    let largest = settings.robots.iter().copied().max().unwrap_or(1);
    let fleet_rate =
        (settings.fleet_duration_s > 0.0).then_some(settings.fleet_hz * largest as f64);
    let mut by_robots = Vec::new();
    for &robots in &settings.robots {
        let fleet = fleet_rate.filter(|_| robots == largest);
        by_robots.push(orchestrator.compare(robots, fleet)?);
    }
    // A failed memory measurement still leaves the comparisons reported.
    let memory = if settings.memory_robots > 0 {
        orchestrator
            .memory()
            .inspect_err(|error| eprintln!("armtwin-bench: memory measurement failed: {error:#}"))
            .ok()
    } else {
        None
    };
    let echo_memory = if settings.memory_robots > 0 {
        orchestrator
            .echo_memory()
            .inspect_err(|error| {
                eprintln!("armtwin-bench: the echo's memory measurement failed: {error:#}");
            })
            .ok()
    } else {
        None
    };
    let _ = std::fs::remove_dir_all(&work_dir);
    let headline = by_robots
        .iter()
        .find(|c| c.robots == largest)
        .context("no robot count measured")?;
    let fleet = fleet_rate.map(|rate| Fleet {
        robots: largest,
        hz_per_robot: settings.fleet_hz,
        rate,
        echo_sustained: headline.echo.check.as_ref().is_some_and(|t| t.sustained),
        armtwin_sustained: headline.armtwin.check.as_ref().is_some_and(|t| t.sustained),
    });
    let report = Report {
        started_unix_s,
        host,
        headline_robots: largest,
        echo_throughput: headline.echo_throughput,
        armtwin_throughput: headline.armtwin_throughput,
        throughput_ratio: headline.throughput_ratio,
        added_latency_p99_us: headline.added_latency_p99_us,
        bytes_per_robot: memory
            .as_ref()
            .and_then(|m| m.memory.as_ref())
            .map(|m| m.bytes_per_robot),
        settings,
        fleet,
        memory,
        echo_bytes_per_robot: echo_memory.as_ref().map(|m| m.bytes_per_robot),
        echo_memory,
        by_robots,
    };
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
