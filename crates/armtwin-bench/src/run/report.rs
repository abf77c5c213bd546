//! `armtwin-bench run`'s report: `bench.json`'s types, the tables printed at the end and the
//! benchmark's targets against what the run measured.
//!
//! Owns the report's shape and wording; must not start processes or measure.

use std::fmt::Write as _;

use serde::Serialize;

use super::Settings;
use crate::load::{Latency, LoadReport, Memory, Trial, WireEncoding};

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
    pub(super) fn of(rounds: Vec<Latency>) -> Self {
        let of_rounds = |pick: fn(&Latency) -> f64| median(rounds.iter().map(pick).collect());
        Self {
            p50_us: of_rounds(|l| l.p50_us),
            p99_us: of_rounds(|l| l.p99_us),
            p999_us: of_rounds(|l| l.p999_us),
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

/// The median of `values` (NaN when there are none).
pub(super) fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    match values.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => values[n / 2],
        n => f64::midpoint(values[n / 2 - 1], values[n / 2]),
    }
}

/// A plant's load: every robot at a fixed rate with its measured pose embedded, the same
/// schedule offered to both systems in alternated rounds. Each figure is the median over the
/// rounds.
#[derive(Debug, Clone, Serialize)]
pub struct Paced {
    /// Robots.
    pub robots: usize,
    /// Hz per robot.
    pub hz_per_robot: f64,
    /// Samples per second in total.
    pub rate: f64,
    /// The samples' format.
    pub encoding: WireEncoding,
    /// Load sessions.
    pub gateways: u16,
    /// Seconds per round.
    pub duration_s: f64,
    /// The echo's CPU over a round / its seconds (cores).
    pub echo_cores: f64,
    /// Same for armtwin.
    pub armtwin_cores: f64,
    /// armtwin's cores / the echo's.
    pub cpu_ratio: f64,
    /// armtwin's p99 latency / the echo's.
    pub p99_ratio: f64,
    /// Expected replies that never arrived, over every round of the echo.
    pub echo_lost: u64,
    /// Same for armtwin.
    pub armtwin_lost: u64,
    /// The echo's latency (and each round's trial).
    pub echo_latency: LatencySummary,
    /// armtwin's latency.
    pub armtwin_latency: LatencySummary,
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
    /// The paced comparison (null when not measured).
    pub paced: Option<Paced>,
    /// The memory measurement's load report.
    pub memory: Option<LoadReport>,
    /// The echo's resident bytes per robot, the transport's own share (null when not measured).
    pub echo_bytes_per_robot: Option<f64>,
    /// The echo's memory measurement.
    pub echo_memory: Option<EchoMemory>,
    /// Memory per robot streaming until its window is full, at each rate.
    pub streaming_memory: Vec<StreamingMemory>,
    /// armtwin's memory with the whole fleet streaming at the first rate (null when not
    /// measured).
    pub streaming_fleet: Option<Memory>,
    /// Seconds from SIGTERM until that armtwin exited (null when not measured, or when it had to
    /// be killed).
    pub streaming_fleet_stop_s: Option<f64>,
}

/// Resident memory per robot streaming at one rate until its window (and the aligner's
/// history) is full: armtwin's, and the echo's with the same keys and traffic. The samples go
/// out as fast as each system answers them, stamped at the rate in source time, which is what
/// the window follows.
#[derive(Debug, Clone, Serialize)]
pub struct StreamingMemory {
    /// Hz of source time per robot.
    pub hz_per_robot: f64,
    /// Seconds of source time each robot streamed.
    pub source_s: f64,
    /// armtwin's measurement.
    pub armtwin: Memory,
    /// The echo's (null when it failed).
    pub echo: Option<EchoMemory>,
    /// armtwin's bytes per robot minus the echo's.
    pub added_bytes_per_robot: Option<f64>,
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
    pub(crate) fn probe() -> Self {
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

fn fmt_rate(rate: f64) -> String {
    if rate >= 1000.0 {
        format!("{:.1} k", rate / 1000.0)
    } else {
        format!("{rate:.0}")
    }
}

/// The table printed at the end (also the one in this crate's README.md).
pub(super) fn table(report: &Report) -> String {
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
    if let Some(paced) = &report.paced {
        let latency =
            |l: &LatencySummary| format!("{:.0} / {:.0} / {:.0}", l.p50_us, l.p99_us, l.p999_us);
        let _ = writeln!(
            text,
            "paced: {} robots × {} Hz = {} samples/s, embedded, {}, {} gateways, {} s rounds: CPU echo {:.3} / armtwin {:.3} cores ({:.2}×); p50 / p99 / p99.9 µs echo {} / armtwin {} (p99 {:.2}×); lost echo {} / armtwin {}",
            paced.robots,
            paced.hz_per_robot,
            fmt_rate(paced.rate),
            paced.encoding.as_str(),
            paced.gateways,
            paced.duration_s,
            paced.echo_cores,
            paced.armtwin_cores,
            paced.cpu_ratio,
            latency(&paced.echo_latency),
            latency(&paced.armtwin_latency),
            paced.p99_ratio,
            paced.echo_lost,
            paced.armtwin_lost,
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
    text.push_str(&streaming_notes(report));
    text
}

/// Memory per streaming robot at each rate, and the fleet streaming, a line each.
fn streaming_notes(report: &Report) -> String {
    let mut text = String::new();
    for row in &report.streaming_memory {
        let a = &row.armtwin;
        let echo = row.echo.as_ref().map_or_else(
            || "echo not measured".to_owned(),
            |echo| {
                format!(
                    "echo {} / {} KiB: {:.0} bytes per robot; armtwin − echo {:.0} bytes",
                    echo.rss_base_kib,
                    echo.rss_full_kib,
                    echo.bytes_per_robot,
                    a.bytes_per_robot - echo.bytes_per_robot
                )
            },
        );
        let _ = writeln!(
            text,
            "memory, streaming at {} Hz ({} samples, {:.1} s of source time per robot, windows full), RSS with {} / {} robots: armtwin {} / {} KiB: {:.0} bytes per robot; {echo}",
            row.hz_per_robot,
            a.samples_per_robot,
            row.source_s,
            a.base_robots,
            a.robots,
            a.rss_base_kib,
            a.rss_full_kib,
            a.bytes_per_robot,
        );
    }
    if let Some(fleet) = &report.streaming_fleet {
        let _ = writeln!(
            text,
            "memory, {} robots streaming at {} Hz ({} samples each, windows full): armtwin RSS {} KiB ({:.1} MB), {:.0} bytes per robot over {} robots",
            fleet.robots,
            fleet.stream_hz.unwrap_or(f64::NAN),
            fleet.samples_per_robot,
            fleet.rss_full_kib,
            rss_mb(fleet.rss_full_kib),
            fleet.bytes_per_robot,
            fleet.base_robots,
        );
        let fill = fill_rates(report).map_or_else(
            || "not measured".to_owned(),
            |(small, fleet_rate, ratio)| {
                format!(
                    "{fleet_rate:.0} samples/s against {small:.0} at the smaller fleet: {ratio:.2}"
                )
            },
        );
        let stop = report.streaming_fleet_stop_s.map_or_else(
            || "killed (or not measured)".to_owned(),
            |s| format!("{s:.2} s"),
        );
        let _ = writeln!(
            text,
            "filling {} robots' windows: {fill}; then SIGTERM to exit: {stop}",
            fleet.robots
        );
    }
    text
}

/// The streamed fill rate of the smaller streaming fleet (the first rate's memory row, at the
/// streaming fleet's rate), the whole streaming fleet's, and their ratio.
fn fill_rates(report: &Report) -> Option<(f64, f64, f64)> {
    let fleet = report.streaming_fleet.as_ref()?;
    let small = report
        .streaming_memory
        .iter()
        .find(|row| Some(row.hz_per_robot) == fleet.stream_hz)?;
    let small_rate = small.armtwin.fill_samples_per_s?;
    let fleet_rate = fleet.fill_samples_per_s?;
    Some((small_rate, fleet_rate, fleet_rate / small_rate))
}

/// KiB as megabytes (10^6 bytes).
fn rss_mb(kib: u64) -> f64 {
    kib as f64 * 1024.0 / 1e6
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
pub(super) fn targets(report: &Report) -> Vec<TargetRow> {
    let mut rows = Vec::new();
    for c in &report.by_robots {
        // The figures of BENCHMARKS.md's Targets table.
        let least = match c.encoding {
            WireEncoding::ZenohSerialized if c.robots >= 1000 => 0.6,
            WireEncoding::ZenohSerialized => 0.8,
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
    rows.extend(report.paced.as_ref().map_or_else(Vec::new, paced_targets));
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
    rows.extend(streaming_targets(report));
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

/// What a streaming robot may cost beyond the echo's, every default on (window, history,
/// recorder), at any rate.
const STREAMING_BUDGET_BYTES: f64 = 32.0 * 1024.0;

/// The most RSS of the streaming fleet (10 000 robots at 100 Hz), MB.
const STREAMING_FLEET_MB: f64 = 500.0;

/// Memory per streaming robot against the echo's, at each rate, and the fleet's RSS.
fn streaming_targets(report: &Report) -> Vec<TargetRow> {
    let mut rows = Vec::new();
    for row in &report.streaming_memory {
        let bytes = row.armtwin.bytes_per_robot;
        let allowed = row
            .echo
            .as_ref()
            .map(|echo| echo.bytes_per_robot + STREAMING_BUDGET_BYTES);
        rows.push(TargetRow {
            figure: format!(
                "bytes per robot streaming at {} Hz, windows full, {} robots",
                row.hz_per_robot, row.armtwin.robots
            ),
            measured: Some(bytes),
            target: allowed.map_or_else(
                || "≤ the echo's + 32 KiB (echo not measured)".to_owned(),
                |allowed| format!("≤ the echo's + 32 KiB = {allowed:.0}"),
            ),
            met: allowed.is_some_and(|allowed| bytes <= allowed),
        });
    }
    if let Some(fleet) = &report.streaming_fleet {
        let mb = rss_mb(fleet.rss_full_kib);
        rows.push(TargetRow {
            figure: format!(
                "RSS with {} robots streaming at {} Hz, windows full (MB)",
                fleet.robots,
                fleet.stream_hz.unwrap_or(f64::NAN)
            ),
            measured: Some(mb),
            target: format!("≤ {STREAMING_FLEET_MB}"),
            met: mb <= STREAMING_FLEET_MB,
        });
        let fill = fill_rates(report);
        rows.push(TargetRow {
            figure: format!(
                "fill rate with {} robots streaming / with {}",
                fleet.robots,
                report
                    .streaming_memory
                    .first()
                    .map_or(0, |row| row.armtwin.robots)
            ),
            measured: fill.map(|(_, _, ratio)| ratio),
            target: "≥ 0.8".to_owned(),
            met: fill.is_some_and(|(_, _, ratio)| ratio >= 0.8),
        });
        rows.push(TargetRow {
            figure: format!("SIGTERM to exit with {} robots streaming (s)", fleet.robots),
            measured: report.streaming_fleet_stop_s,
            target: "≤ 10".to_owned(),
            met: report.streaming_fleet_stop_s.is_some_and(|s| s <= 10.0),
        });
    }
    rows
}

/// The paced comparison's targets: CPU and p99 latency against the echo's, and no loss.
fn paced_targets(paced: &Paced) -> Vec<TargetRow> {
    let mut rows = Vec::new();
    let row = format!(
        "paced {} robots × {} Hz, embedded, {}",
        paced.robots,
        paced.hz_per_robot,
        paced.encoding.as_str()
    );
    rows.push(TargetRow {
        figure: format!("{row}: CPU / echo's"),
        measured: Some(paced.cpu_ratio),
        target: "≤ 1.1".to_owned(),
        met: paced.cpu_ratio <= 1.1,
    });
    rows.push(TargetRow {
        figure: format!("{row}: p99 latency / echo's"),
        measured: Some(paced.p99_ratio),
        target: "≤ 1.5".to_owned(),
        met: paced.p99_ratio <= 1.5,
    });
    rows.push(TargetRow {
        figure: format!("{row}: replies lost (armtwin)"),
        measured: Some(paced.armtwin_lost as f64),
        target: "0".to_owned(),
        met: paced.armtwin_lost == 0,
    });
    rows
}
