//! `armtwin-bench soak`: a night under load. `armtwin serve` (the dashboard and `/metrics` on)
//! and the load generator's soak (robots at a steady rate, binary joint messages with their
//! measured poses embedded, a share of the robots replaced by never-seen ones every churn
//! period), Prometheus scraping `/metrics` and a dashboard client fetching the fleet page and
//! API, for as long as asked. Each interval the load reports, armtwin's RSS and CPU are read
//! beside it; at the end the RSS slope after the warm-up, the p99 per interval, loss and CPU,
//! the targets met or not, `soak.json` and the curves as an SVG.
//!
//! Owns the soak's processes and its report; the load generator measures, `run`'s pieces start
//! the processes, `procfs` reads them. Here: the flags, the run in order; `watch` (Prometheus
//! and the dashboard client), `report` (the figures, targets, table and curves).
#![allow(
    clippy::print_stdout,
    clippy::print_stderr,
    reason = "a benchmark command's progress and report, on its terminal"
)]

mod report;
mod watch;

pub use report::{Row, SoakReport, Summary, Target};
pub use watch::WatchSummary;

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::Stdio;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result, bail};
use clap::Args;
use serde::Serialize;

use crate::fleet::soak_service_config;
use crate::load::{LoadReport, SoakInterval, Target as LoadTarget, WireEncoding};
use crate::procfs;
use crate::run::system::{SystemUnderTest, free_port, wait_listening};
use crate::run::trials::load_command;
use crate::run::{Host, bench_and_armtwin, unix_now_s};
use report::{curves, row_line, summarize, table, targets};
use watch::Watchers;

/// The environment variable naming a Prometheus binary (as the project's tests use it).
const PROMETHEUS_ENV: &str = "ARMTWIN_PROMETHEUS";

/// `armtwin-bench soak` arguments.
#[derive(Debug, Clone, Args)]
pub struct SoakArgs {
    /// Robots sending at any time.
    #[arg(long, default_value_t = 200)]
    pub robots: usize,
    /// Samples per second per robot.
    #[arg(long, default_value_t = 100.0)]
    pub hz: f64,
    /// Seconds of the soak.
    #[arg(long, default_value_t = 3600.0)]
    pub duration: f64,
    /// Seconds per reported interval.
    #[arg(long, default_value_t = 10.0)]
    pub interval: f64,
    /// The share of the robots that leave, and as many never-seen robots that join, every
    /// churn period.
    #[arg(long, default_value_t = 0.1)]
    pub churn: f64,
    /// Seconds between two churns.
    #[arg(long, default_value_t = 60.0)]
    pub churn_period: f64,
    /// Seconds left out of the RSS slope and the p99's stability.
    #[arg(long, default_value_t = 600.0)]
    pub warm_up: f64,
    /// `[service] forget_after_s` of armtwin's configuration: a robot that sent nothing that
    /// long is retired, so the robots that left stop costing memory (0: never, as in the
    /// configuration).
    #[arg(long, default_value_t = 30.0)]
    pub forget_after: f64,
    /// `[service] max_robots` of armtwin's configuration (default: not set).
    #[arg(long)]
    pub max_robots: Option<usize>,
    /// Load sessions (gateways) the robots are split over.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u16).range(1..))]
    pub gateways: u16,
    /// The samples' format, and armtwin's outputs'.
    #[arg(long, value_enum, default_value_t = WireEncoding::ZenohSerialized)]
    pub encoding: WireEncoding,
    /// A Prometheus binary to scrape `/metrics` (default: `$ARMTWIN_PROMETHEUS`; without one
    /// the soak scrapes `/metrics` itself at the same pace).
    #[arg(long)]
    pub prometheus: Option<PathBuf>,
    /// Seconds between scrapes of `/metrics` (config/prometheus.yml's pace).
    #[arg(long, default_value_t = 5.0)]
    pub scrape_interval: f64,
    /// Seconds between two fetches of the dashboard client.
    #[arg(long, default_value_t = 2.0)]
    pub dashboard_period: f64,
    /// The `armtwin` binary (default: next to this one).
    #[arg(long)]
    pub armtwin: Option<PathBuf>,
    /// Where to write the report.
    #[arg(long, default_value = "soak.json")]
    pub out: PathBuf,
    /// Where to write the curves.
    #[arg(long, default_value = "soak.svg")]
    pub svg: PathBuf,
}

/// The settings of a soak, as run.
#[derive(Debug, Clone, Serialize)]
pub struct Settings {
    /// Robots sending at any time.
    pub robots: usize,
    /// Samples per second per robot.
    pub hz: f64,
    /// Seconds of the soak.
    pub duration_s: f64,
    /// Seconds per interval.
    pub interval_s: f64,
    /// Share of the robots replaced per churn.
    pub churn: f64,
    /// Seconds between churns.
    pub churn_period_s: f64,
    /// Seconds left out of the slope and the p99's stability.
    pub warm_up_s: f64,
    /// `[service] forget_after_s`.
    pub forget_after_s: Option<f64>,
    /// `[service] max_robots`.
    pub max_robots: Option<usize>,
    /// Load sessions.
    pub gateways: u16,
    /// The samples' format.
    pub encoding: WireEncoding,
    /// Measured poses embedded in the joint messages (always).
    pub embedded: bool,
}

/// Runs the soak, prints each interval as it comes and the summary at the end, and writes the
/// report and the curves.
pub fn run(args: &SoakArgs) -> Result<SoakReport> {
    let wall = Instant::now();
    let settings = Settings {
        robots: args.robots.max(1),
        hz: args.hz,
        duration_s: args.duration,
        interval_s: args.interval,
        churn: args.churn,
        churn_period_s: args.churn_period,
        warm_up_s: args.warm_up,
        forget_after_s: (args.forget_after > 0.0).then_some(args.forget_after),
        max_robots: args.max_robots,
        gateways: args.gateways,
        encoding: args.encoding,
        embedded: true,
    };
    let (bench, armtwin) = bench_and_armtwin(args.armtwin.as_ref())?;
    let prometheus = args
        .prometheus
        .clone()
        .or_else(|| std::env::var_os(PROMETHEUS_ENV).map(PathBuf::from));
    let work_dir = std::env::temp_dir().join(format!("armtwin-soak-{}", std::process::id()));
    std::fs::create_dir_all(&work_dir)?;
    let started_unix_s = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let http_port = free_port()?;
    let http = SocketAddr::from(([127, 0, 0, 1], http_port));
    let config = soak_service_config(
        settings.encoding.as_str(),
        &http.to_string(),
        settings.forget_after_s,
        settings.max_robots,
    );
    let mut sut = SystemUnderTest::armtwin(&armtwin, &work_dir.join("armtwin.toml"), &config)?;
    wait_listening(http_port, &mut sut.child)?;
    let watchers = Watchers::start(
        http,
        prometheus.as_deref(),
        Duration::from_secs_f64(args.scrape_interval.max(0.1)),
        Duration::from_secs_f64(args.dashboard_period.max(0.1)),
        &work_dir,
    )?;
    eprintln!(
        "== soak: armtwin serve (pid {}), /metrics scraped by {}",
        sut.pid(),
        if prometheus.is_some() {
            "Prometheus"
        } else {
            "this process"
        }
    );
    let rss_before_mib = procfs::rss_kib(sut.pid())? as f64 / 1024.0;
    let outcome = soak(&settings, &bench, &sut, &watchers, &work_dir);
    let watch_summary = watchers.stop();
    sut.stop();
    let _ = std::fs::remove_dir_all(&work_dir);
    let (rows, load, cpu_s, soak_wall_s) = outcome?;
    let summary = summarize(
        &rows,
        settings.warm_up_s,
        rss_before_mib,
        &load,
        cpu_s,
        soak_wall_s,
    );
    let mut report = SoakReport {
        started_unix_s,
        host: Host::probe(),
        retirement: settings.forget_after_s.is_some(),
        settings,
        targets: targets(&summary),
        summary,
        rows,
        watchers: watch_summary,
        load,
        wall_s: 0.0,
    };
    report.wall_s = wall.elapsed().as_secs_f64();
    let json = serde_json::to_string_pretty(&report)?;
    std::fs::write(&args.out, json + "\n")
        .with_context(|| format!("writing {}", args.out.display()))?;
    std::fs::write(&args.svg, curves(&report))
        .with_context(|| format!("writing {}", args.svg.display()))?;
    println!("{}", table(&report));
    println!("written: {}, {}", args.out.display(), args.svg.display());
    Ok(report)
}

/// The load's soak against `sut`, a row per interval with armtwin's process read beside it.
/// Returns the rows, the load's account, armtwin's CPU seconds and the seconds it took.
fn soak(
    settings: &Settings,
    bench: &std::path::Path,
    sut: &SystemUnderTest,
    watchers: &Watchers,
    work_dir: &std::path::Path,
) -> Result<(Vec<Row>, crate::load::Soak, f64, f64)> {
    let mut command = load_command(
        bench,
        sut,
        LoadTarget::Armtwin,
        settings.encoding,
        unix_now_s(),
        &work_dir.join("seq.json"),
    );
    command
        .args(["--robots", &settings.robots.to_string()])
        .args(["--gateways", &settings.gateways.to_string()])
        .arg("--embedded")
        .args(["--soak-duration", &settings.duration_s.to_string()])
        .args(["--soak-hz", &settings.hz.to_string()])
        .args(["--soak-interval", &settings.interval_s.to_string()])
        .args(["--churn", &settings.churn.to_string()])
        .args(["--churn-period", &settings.churn_period_s.to_string()])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit());
    let mut load = command.spawn().context("starting the load generator")?;
    let stdout = load.stdout.take().context("the load's standard output")?;
    let load_pid = load.id();
    let cpu_start_s = procfs::cpu_s(sut.pid())?;
    let mut previous = (
        Instant::now(),
        cpu_start_s,
        procfs::cpu_s(load_pid).unwrap_or(0.0),
    );
    let started = previous.0;
    let mut rows = Vec::new();
    let mut final_report = None;
    for line in BufReader::new(stdout).lines() {
        let line = line.context("reading the load generator")?;
        if let Ok(interval) = serde_json::from_str::<SoakInterval>(&line) {
            let now = Instant::now();
            let cpu_s = procfs::cpu_s(sut.pid())?;
            let load_cpu_s = procfs::cpu_s(load_pid).unwrap_or(previous.2);
            let wall_s = (now - previous.0).as_secs_f64().max(1e-3);
            let row = Row {
                index: interval.index,
                end_s: interval.end_s,
                rss_mib: procfs::rss_kib(sut.pid())? as f64 / 1024.0,
                cpu_percent: 100.0 * (cpu_s - previous.1) / wall_s,
                load_cpu_percent: 100.0 * (load_cpu_s - previous.2) / wall_s,
                sent: interval.sent,
                received: interval.poses,
                unanswered: interval.unanswered,
                p50_us: interval.p50_us.unwrap_or(f64::NAN),
                p99_us: interval.p99_us.unwrap_or(f64::NAN),
                max_us: interval.max_us.unwrap_or(f64::NAN),
                robots_tracked: watchers.robots_tracked(),
                churned: interval.churned,
            };
            println!("{}", row_line(&row));
            rows.push(row);
            previous = (now, cpu_s, load_cpu_s);
        } else {
            final_report = Some(
                serde_json::from_str::<LoadReport>(&line)
                    .with_context(|| format!("reading the load's report: {line}"))?,
            );
        }
    }
    let status = load.wait()?;
    if !status.success() {
        bail!("the load generator failed: {status}");
    }
    let cpu_s = procfs::cpu_s(sut.pid())? - cpu_start_s;
    let soak = final_report
        .and_then(|report| report.soak)
        .context("the load generator reported no soak")?;
    Ok((rows, soak, cpu_s, started.elapsed().as_secs_f64()))
}
