//! `armtwin-bench load`: the load generator, in a process of its own.
//!
//! Publishes contract-shaped joint samples and, with each, the measured pose of the same stamp,
//! for N robots, round robin, on a fixed schedule; counts the replies (twin poses and deviations,
//! plus armtwin's metrics and events) and measures latency from the stamp each reply carries
//! back: a sample's `t` is the time it is sent (seconds since a clock origin shared by every load
//! process of a run, so stamps keep increasing for a system under test that outlives one), and
//! both the echo (the payload itself) and armtwin (`t` of the twin pose) return it unchanged.
//!
//! It declares every key it publishes (through its publishers) and every reply key it receives
//! (`declare_keyexpr`), so it does not pay Zenoh's per-key route computation itself.
//!
//! With `--encoding zenoh-serialized` the samples go out in Zenoh's serialization
//! (`armtwin/joints/v1`, `armtwin/pose/v1`) and replies are read as binary (a twin pose's and an
//! echoed joint message's first 8 bytes are both `t`). With `--slow-subscriber-ms` a second
//! session subscribes to the first robot's poses and sleeps in its callback for each one, and
//! only the other robots' poses are timed: what a slow dashboard costs everyone else.
//!
//! With `--gateways N` it opens N sessions to the system under test, each its own link, as N
//! gateway processes would, and robot `i` publishes on session `i % N`; the first session also
//! receives every reply. One thread sends on all of them: robots are sent round robin, so
//! consecutive samples go out on consecutive sessions and the schedule is the one-session
//! schedule. A sender thread per session was not chosen: on a machine whose cores the system
//! under test needs, more sending threads compete with it, and whether one thread keeps the
//! schedule is visible in every trial (`send_s` against `duration_s`).
//!
//! What it runs, in order, each optional: a latency run at a fixed moderate rate; the search for
//! the highest sustained rate (doubling until a rate fails, then bisecting; a failed trial is run
//! again before its rate counts as failed); a check at one fixed rate (`--check-embedded`: with
//! embedded measured poses). Or, alone: the memory measurement of a system under test (which
//! also times how long the system takes to declare the robots new to it); a first-contact trial
//! (`--first-contact-rate`: full rate to robots the system has never seen, no warm-up); the
//! wait for a restarted armtwin's liveliness tokens (`--await-tokens`); or a soak with churn
//! (`--soak-duration`, in `churn`: a JSON line per interval as it goes). Results go to standard
//! output as one JSON object; progress to standard error.
#![allow(
    clippy::print_stdout,
    clippy::print_stderr,
    reason = "a benchmark command's progress and report, on its terminal"
)]

use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, PoisonError};
use std::thread;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use armtwin::codec::zser;
use armtwin::keys::Stream;
use armtwin::mesh::MeshError;
use armtwin_cli::flags::ZenohArgs;
use clap::{Args, ValueEnum};
use serde::{Deserialize, Serialize};
use thiserror::Error;
use zenoh::Wait;
use zenoh::bytes::Encoding;
use zenoh::key_expr::KeyExpr;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::CongestionControl;
use zenoh::sample::{Sample, SampleKind};
use zenoh::session::Session;

mod churn;

pub use churn::{Soak, SoakInterval};

use crate::net;
use crate::procfs::{self, ProcError};
use crate::workload::{Workload, WorkloadError};

/// How long to wait for the system under test to subscribe.
const MATCH_TIMEOUT: Duration = Duration::from_secs(30);
/// Pause between trials, so one trial's tail never overlaps the next.
const PAUSE: Duration = Duration::from_millis(300);
/// How long the warm-up waits without any new reply before it sends again.
const STALL: Duration = Duration::from_secs(10);
/// How long a failed trial's stragglers are awaited before the next trial starts.
const SETTLE: Duration = Duration::from_secs(10);
/// How long the wait for armtwin's liveliness tokens goes on without any new one.
const TRACKING_STALL: Duration = Duration::from_secs(30);
/// Slack on a trial's completion for the last replies' own latency.
const COMPLETION_SLACK_S: f64 = 0.01;

/// Which system the load talks to, which decides the replies it expects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Target {
    /// The plain echo: the payloads come back on `pose` and `deviation`.
    Echo,
    /// `armtwin serve`: twin poses, deviations, metrics and events.
    Armtwin,
}

/// The format of the samples sent (and of armtwin's poses and deviations).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WireEncoding {
    /// JSON objects.
    #[default]
    Json,
    /// Zenoh's serialization with armtwin's schemas.
    ZenohSerialized,
}

impl WireEncoding {
    /// The command-line and configuration name.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Json => "json",
            Self::ZenohSerialized => "zenoh-serialized",
        }
    }
}

/// `armtwin-bench load` arguments.
#[derive(Debug, Clone, Args)]
#[command(mut_arg("connect", |arg| arg.required(true)))]
pub struct LoadArgs {
    /// How to join the mesh, as armtwin's commands do (`-e ENDPOINT` of the system under test
    /// required).
    #[command(flatten)]
    pub zenoh: ZenohArgs,
    /// The system under test.
    #[arg(long, value_enum)]
    pub target: Target,
    /// Its process id: its CPU time per trial and its resident memory are read from /proc.
    #[arg(long)]
    pub sut_pid: Option<u32>,
    /// Send each sample as one joint message with its measured pose embedded (RTDE style)
    /// instead of a joint and a measured message; the echo then returns one message per sample.
    #[arg(long)]
    pub embedded: bool,
    /// Robots (`fleet/r00000` …); the rate is spread over them round robin.
    #[arg(long, default_value_t = 1)]
    pub robots: usize,
    /// Latency run: samples per second (0: no latency run).
    #[arg(long, default_value_t = 0.0)]
    pub latency_rate: f64,
    /// Latency run: seconds.
    #[arg(long, default_value_t = 5.0)]
    pub latency_duration: f64,
    /// Throughput search: first rate tried, samples per second (0: no search).
    #[arg(long, default_value_t = 0.0)]
    pub start_rate: f64,
    /// Throughput search: highest rate tried.
    #[arg(long, default_value_t = 2_000_000.0)]
    pub max_rate: f64,
    /// Throughput search: seconds per trial.
    #[arg(long, default_value_t = 2.0)]
    pub duration: f64,
    /// Throughput search: bisection steps after the first failing rate.
    #[arg(long, default_value_t = 4)]
    pub bisect_steps: u32,
    /// A trial is sustained when every reply arrived within this fraction of its duration
    /// after it should have ended.
    #[arg(long, default_value_t = 0.05)]
    pub tolerance: f64,
    /// Throughput search: how many times a failed trial is run again before its rate counts as
    /// failed (a machine shared with others stalls now and then; a system that keeps up passes
    /// one of the runs, one that cannot fails them all).
    #[arg(long, default_value_t = 1)]
    pub retries: u32,
    /// A check at one rate after the search (0: none), samples per second.
    #[arg(long, default_value_t = 0.0)]
    pub check_rate: f64,
    /// Seconds of the check.
    #[arg(long, default_value_t = 10.0)]
    pub check_duration: f64,
    /// Unix time (s) that stamps count from: the orchestrator gives every load process the
    /// same, so stamps keep increasing from one load process to the next (default: now).
    #[arg(long)]
    pub clock_origin: Option<f64>,
    /// Memory measurement instead of everything above: robots tracked for the baseline.
    #[arg(long)]
    pub memory_base_robots: Option<usize>,
    /// Memory measurement: samples each robot sends.
    #[arg(long, default_value_t = 4)]
    pub memory_samples: u64,
    /// The format of the samples (armtwin must be configured with the same `encoding`).
    #[arg(long, value_enum, default_value_t = WireEncoding::Json)]
    pub encoding: WireEncoding,
    /// Binary messages carry a gateway `seq` that must keep increasing per robot over every
    /// load process sent to one system under test: each robot's next `seq` is read from this
    /// file at the start (if it exists) and written back at the end.
    #[arg(long)]
    pub seq_file: Option<PathBuf>,
    /// Sessions the robots are split over (robot `i` on session `i % N`), each its own link to
    /// the system under test, as N gateway processes would be; replies arrive on the first.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..))]
    pub gateways: u16,
    /// The check (`--check-rate`) sends each sample as one joint message with the measured pose
    /// embedded, whatever `--embedded` says for the rest.
    #[arg(long)]
    pub check_embedded: bool,
    /// Instead of everything above: a trial at this rate (samples/s) to robots the system
    /// under test has never seen, without a warm-up, waiting for every reply.
    #[arg(long)]
    pub first_contact_rate: Option<f64>,
    /// Seconds of the first-contact trial.
    #[arg(long, default_value_t = 3.0)]
    pub first_contact_duration: f64,
    /// Instead of everything above: only wait until armtwin's liveliness tokens of `--robots`
    /// robots are all visible (a restarted armtwin restoring its snapshot), sending nothing.
    #[arg(long)]
    pub await_tokens: bool,
    /// A second session subscribes to the first robot's poses and sleeps this long (ms) in its
    /// callback per pose; latencies are then those of the other robots only. Its link has a
    /// 64 KiB receive buffer (a dashboard on a slow network), so that it fills in seconds, not
    /// after the kernel has buffered megabytes.
    #[arg(long)]
    pub slow_subscriber_ms: Option<u64>,
    /// Instead of everything above: a soak of this many seconds, `--robots` robots each at
    /// `--soak-hz`, reporting every `--soak-interval` seconds (a JSON line on standard output),
    /// `--churn` of the robots leaving and as many never-seen ones joining every
    /// `--churn-period` seconds.
    #[arg(long)]
    pub soak_duration: Option<f64>,
    /// Soak: samples per second per robot.
    #[arg(long, default_value_t = 100.0)]
    pub soak_hz: f64,
    /// Soak: seconds per reported interval.
    #[arg(long, default_value_t = 10.0)]
    pub soak_interval: f64,
    /// Soak: the share of robots replaced by new ones every churn period (0: none).
    #[arg(long, default_value_t = 0.0)]
    pub churn: f64,
    /// Soak: seconds between two churns.
    #[arg(long, default_value_t = 60.0)]
    pub churn_period: f64,
}

/// Why the load generator failed.
#[derive(Debug, Error)]
pub enum LoadError {
    /// The Zenoh configuration was refused.
    #[error(transparent)]
    Config(#[from] MeshError),
    /// Zenoh failed.
    #[error("zenoh: {0}")]
    Zenoh(#[from] zenoh::Error),
    /// The payloads could not be built.
    #[error(transparent)]
    Workload(#[from] WorkloadError),
    /// The system under test could not be read.
    #[error(transparent)]
    Proc(#[from] ProcError),
    /// The system under test never answered.
    #[error("{0}")]
    NoAnswer(String),
    /// The `seq` file could not be read or written.
    #[error("seq file {path}: {detail}")]
    SeqFile {
        /// The file.
        path: String,
        /// What failed.
        detail: String,
    },
}

/// Reply counts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Counts {
    /// Twin poses (echo: republished joint samples).
    pub poses: u64,
    /// Deviations (echo: republished measured poses).
    pub deviations: u64,
    /// Metrics messages (armtwin).
    pub metrics: u64,
    /// Events (armtwin; none expected).
    pub events: u64,
}

impl Counts {
    fn since(self, base: Self) -> Self {
        Self {
            poses: self.poses - base.poses,
            deviations: self.deviations - base.deviations,
            metrics: self.metrics - base.metrics,
            events: self.events - base.events,
        }
    }
}

/// What the receive callbacks share with the sender.
#[derive(Debug)]
struct Replies {
    start: Instant,
    /// Seconds from the clock origin to `start`.
    start_s: f64,
    poses: AtomicU64,
    deviations: AtomicU64,
    metrics: AtomicU64,
    events: AtomicU64,
    /// Arrival of the newest pose or deviation (ns since `start`).
    last_ns: AtomicU64,
    /// Whether twin poses' latencies are being recorded.
    recording: AtomicBool,
    latencies_ns: Mutex<Vec<u64>>,
    /// Replies are binary: the stamp is the first 8 bytes.
    binary: bool,
    /// The pose key whose latencies are not recorded (the slow subscriber's robot).
    untimed_key: Option<String>,
    /// Poses the slow subscriber received.
    slow_poses: AtomicU64,
    /// The soak's per-interval tally of poses, set when the soak starts.
    soak: OnceLock<churn::Tally>,
}

/// What a subscriber does with a reply.
type OnReply = fn(&Replies, &Sample);

/// The stamp of a reply.
#[derive(Deserialize)]
struct Stamp {
    t: f64,
}

impl Replies {
    fn elapsed_ns(&self) -> u64 {
        self.start.elapsed().as_nanos() as u64
    }

    /// Now, in seconds since the clock origin: the stamp of a sample sent now.
    fn now_s(&self) -> f64 {
        self.start_s + self.start.elapsed().as_secs_f64()
    }

    fn counts(&self) -> Counts {
        Counts {
            poses: self.poses.load(Ordering::Acquire),
            deviations: self.deviations.load(Ordering::Acquire),
            metrics: self.metrics.load(Ordering::Relaxed),
            events: self.events.load(Ordering::Relaxed),
        }
    }

    /// The stamp a reply carries back.
    fn stamp_of(&self, sample: &Sample) -> Option<f64> {
        let payload = sample.payload().to_bytes();
        if self.binary {
            payload.get(..8)?.try_into().ok().map(f64::from_le_bytes)
        } else {
            serde_json::from_slice::<Stamp>(&payload).ok().map(|s| s.t)
        }
    }

    fn pose(&self, sample: &Sample) {
        let now_ns = self.elapsed_ns();
        let timed = self
            .untimed_key
            .as_deref()
            .is_none_or(|key| sample.key_expr().as_str() != key);
        let recording = self.recording.load(Ordering::Relaxed);
        let soak = self.soak.get();
        if timed
            && (recording || soak.is_some())
            && let Some(stamp_s) = self.stamp_of(sample)
        {
            let latency_s = self.start_s + now_ns as f64 / 1e9 - stamp_s;
            let latency_ns = (latency_s * 1e9).max(0.0) as u64;
            if let Some(tally) = soak {
                tally.record(stamp_s, latency_ns);
            }
            if recording {
                self.latencies_ns
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .push(latency_ns);
            }
        }
        self.last_ns.fetch_max(now_ns, Ordering::AcqRel);
        self.poses.fetch_add(1, Ordering::Release);
    }

    fn deviation(&self) {
        self.last_ns.fetch_max(self.elapsed_ns(), Ordering::AcqRel);
        self.deviations.fetch_add(1, Ordering::Release);
    }
}

/// One run at a fixed rate.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Trial {
    /// Samples per second offered (each sample: one joint and one measured message).
    pub offered_rate: f64,
    /// Samples sent (fewer than the schedule's when the system fell more than the trial's
    /// duration, at least a second, behind it and the trial was abandoned).
    pub samples: u64,
    /// Seconds the schedule lasts.
    pub duration_s: f64,
    /// Seconds sending took (more than `duration_s`: the load could not keep the schedule).
    pub send_s: f64,
    /// Seconds from the first send to the last expected reply, if they all arrived in time.
    pub complete_s: Option<f64>,
    /// Replies counted (after the settle time for an incomplete trial).
    pub replies: Counts,
    /// Expected poses and deviations that never arrived.
    pub lost: u64,
    /// `samples / complete_s`.
    pub achieved_rate: Option<f64>,
    /// Poses received / seconds from the first send to the last reply (after the settle time
    /// for an incomplete trial): what came through even when the trial was not sustained.
    pub delivered_rate: Option<f64>,
    /// CPU seconds the system under test used during the trial.
    pub sut_cpu_s: Option<f64>,
    /// Every reply arrived, within the tolerance of the schedule.
    pub sustained: bool,
}

/// Latency of the twin poses at a fixed rate (µs, nearest rank).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Latency {
    /// The run.
    pub trial: Trial,
    /// Poses timed.
    pub count: usize,
    /// Median.
    pub p50_us: f64,
    /// 99th percentile.
    pub p99_us: f64,
    /// 99.9th percentile.
    pub p999_us: f64,
    /// Largest.
    pub max_us: f64,
}

/// The throughput search.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Search {
    /// Highest offered rate sustained (samples per second; 0: none).
    pub max_sustained_rate: f64,
    /// Every trial, in order.
    pub trials: Vec<Trial>,
}

/// Resident memory of the system under test.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Memory {
    /// Robots tracked at the baseline.
    pub base_robots: usize,
    /// Robots tracked at the end.
    pub robots: usize,
    /// Samples each robot sent.
    pub samples_per_robot: u64,
    /// RSS before any sample (KiB).
    pub rss_start_kib: u64,
    /// RSS with `base_robots` tracked (KiB).
    pub rss_base_kib: u64,
    /// RSS with `robots` tracked (KiB).
    pub rss_full_kib: u64,
    /// `(rss_full − rss_base) / (robots − base_robots)`, bytes.
    pub bytes_per_robot: f64,
    /// armtwin: seconds from the first sample to the robots new after the baseline until every
    /// robot's liveliness token was visible (their first samples answered, then their tokens).
    pub declare_s: Option<f64>,
}

/// Everything a load run measured: its standard output.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LoadReport {
    /// The system under test.
    pub target: Target,
    /// Robots.
    pub robots: usize,
    /// Seconds until every robot's first sample was answered.
    pub warmup_s: f64,
    /// armtwin: seconds from the end of the warm-up until every robot's liveliness token was
    /// visible, i.e. armtwin tracked every robot.
    pub tracking_s: Option<f64>,
    /// The latency run.
    pub latency: Option<Latency>,
    /// The throughput search.
    pub search: Option<Search>,
    /// The check at a fixed rate.
    pub check: Option<Trial>,
    /// The memory measurement.
    pub memory: Option<Memory>,
    /// The first-contact trial.
    pub first_contact: Option<Trial>,
    /// `--await-tokens`: Unix time (s) when every robot's token was visible.
    pub tokens_unix_s: Option<f64>,
    /// Sessions the robots were split over.
    pub gateways: u16,
    /// Replies over the whole run.
    pub totals: Counts,
    /// Poses the slow subscriber received (`--slow-subscriber-ms`), of `totals.poses / robots`
    /// or so sent to it: the difference was dropped for it.
    pub slow_subscriber_poses: Option<u64>,
    /// The soak (`--soak-duration`).
    pub soak: Option<Soak>,
}

/// One robot's publishers and the reply keys it declared.
struct RobotKeys {
    joints: Publisher<'static>,
    measured: Publisher<'static>,
    /// Undeclared when the robot leaves a soak (churn).
    replies: Vec<KeyExpr<'static>>,
    /// Samples sent so far (which joint configuration comes next).
    next_seq: u64,
    /// The next gateway `seq` of a binary message.
    gateway_seq: u64,
    /// The last stamp sent (stamps increase strictly per robot).
    last_t_s: f64,
}

/// How a sample goes out: its payloads and their format.
struct Outgoing<'a> {
    workload: &'a Workload,
    encoding: WireEncoding,
    embedded: bool,
}

impl Outgoing<'_> {
    /// Puts one sample of the robot of `keys`, stamped `now_s` (or just after its last stamp).
    fn put(&self, keys: &mut RobotKeys, now_s: f64) -> Result<(), LoadError> {
        let stamp_s = if now_s > keys.last_t_s {
            now_s
        } else {
            keys.last_t_s + 1e-9
        };
        keys.last_t_s = stamp_s;
        let seq = keys.next_seq;
        keys.next_seq += 1;
        if self.encoding == WireEncoding::ZenohSerialized {
            let gateway_seq = keys.gateway_seq;
            keys.gateway_seq += 1;
            keys.joints
                .put(
                    self.workload
                        .joints_zser(seq, stamp_s, gateway_seq, self.embedded),
                )
                .wait()?;
            if !self.embedded {
                keys.measured
                    .put(self.workload.measured_zser(seq, stamp_s))
                    .wait()?;
            }
        } else if self.embedded {
            keys.joints
                .put(self.workload.joints_with_measured(seq, stamp_s))
                .wait()?;
        } else {
            keys.joints.put(self.workload.joints(seq, stamp_s)).wait()?;
            keys.measured
                .put(self.workload.measured(seq, stamp_s))
                .wait()?;
        }
        Ok(())
    }
}

struct Load {
    args: LoadArgs,
    /// The receiving session, also the first gateway's.
    session: Session,
    /// The other gateways' sessions (robot `i` on `i % gateways`, 0 being `session`).
    senders: Vec<Session>,
    /// Samples embed their measured pose (`--embedded`; the check may switch it on).
    embedded: bool,
    workload: Workload,
    replies: Arc<Replies>,
    robots: Vec<RobotKeys>,
    subscribers: Vec<Subscriber<()>>,
    /// The slow subscriber's session and subscriber.
    slow: Option<(Session, Subscriber<()>)>,
    /// armtwin's robots' liveliness tokens as they come and go (none for the echo).
    tokens: Option<Tokens>,
    /// Each robot's first gateway `seq` (from `--seq-file`).
    seq_start: Vec<u64>,
    /// The next robot (round robin over all trials).
    cursor: usize,
    /// Replies already accounted to earlier trials.
    accounted: Counts,
}

/// Runs the load and returns its report.
pub fn run(args: LoadArgs) -> Result<LoadReport, LoadError> {
    let mut load = Load::open(args)?;
    let robots = load.args.robots;
    let mut report = LoadReport {
        target: load.args.target,
        robots,
        warmup_s: 0.0,
        tracking_s: None,
        latency: None,
        search: None,
        check: None,
        memory: None,
        first_contact: None,
        tokens_unix_s: None,
        gateways: load.args.gateways,
        totals: Counts::default(),
        slow_subscriber_poses: None,
        soak: None,
    };
    if let Some(base_robots) = load.args.memory_base_robots {
        report.memory = Some(load.memory(base_robots.clamp(1, robots))?);
    } else if load.args.await_tokens {
        load.await_tokens(robots)?;
        report.tokens_unix_s = Some(
            SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64()),
        );
    } else if let Some(duration_s) = load.args.soak_duration {
        report.soak = Some(load.soak(duration_s)?);
    } else if let Some(rate) = load.args.first_contact_rate {
        load.declare_robots(robots)?;
        load.wait_for_subscriber()?;
        eprintln!("load: first contact at {rate} samples/s");
        report.first_contact = Some(load.trial(rate, load.args.first_contact_duration, false)?);
    } else {
        load.declare_robots(robots)?;
        load.wait_for_subscriber()?;
        let started = Instant::now();
        load.warm_up(0..robots)?;
        report.warmup_s = started.elapsed().as_secs_f64();
        let started = Instant::now();
        if load.wait_for_tracking(robots)? {
            report.tracking_s = Some(started.elapsed().as_secs_f64());
        }
        if load.args.latency_rate > 0.0 {
            report.latency = Some(load.latency()?);
        }
        if load.args.start_rate > 0.0 {
            report.search = Some(load.search()?);
        }
        if load.args.check_rate > 0.0 {
            eprintln!("load: check at {} samples/s", load.args.check_rate);
            load.embedded |= load.args.check_embedded;
            report.check =
                Some(load.trial(load.args.check_rate, load.args.check_duration, false)?);
        }
    }
    report.totals = load.replies.counts();
    report.slow_subscriber_poses = load
        .slow
        .as_ref()
        .map(|_| load.replies.slow_poses.load(Ordering::Relaxed));
    load.save_seq()?;
    load.close();
    Ok(report)
}

/// Each robot's next gateway `seq`, as [`Load::save_seq`] wrote them.
fn read_seq_file(path: &std::path::Path) -> Result<Vec<u64>, LoadError> {
    let error = |detail: String| LoadError::SeqFile {
        path: path.display().to_string(),
        detail,
    };
    let text = std::fs::read_to_string(path).map_err(|e| error(e.to_string()))?;
    serde_json::from_str(&text).map_err(|e| error(e.to_string()))
}

fn percentile_us(sorted_ns: &[u64], fraction: f64) -> f64 {
    if sorted_ns.is_empty() {
        return f64::NAN;
    }
    let rank = ((fraction * sorted_ns.len() as f64).ceil() as usize).clamp(1, sorted_ns.len());
    sorted_ns[rank - 1] as f64 / 1e3
}

impl Load {
    fn open(args: LoadArgs) -> Result<Self, LoadError> {
        let session = zenoh::open(net::config_of(&args.zenoh)?).wait()?;
        let senders = (1..args.gateways)
            .map(|_| Ok(zenoh::open(net::config_of(&args.zenoh)?).wait()?))
            .collect::<Result<Vec<_>, LoadError>>()?;
        let start = Instant::now();
        let unix_s = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        let replies = Arc::new(Replies {
            start,
            start_s: unix_s - args.clock_origin.unwrap_or(unix_s),
            poses: AtomicU64::new(0),
            deviations: AtomicU64::new(0),
            metrics: AtomicU64::new(0),
            events: AtomicU64::new(0),
            last_ns: AtomicU64::new(0),
            recording: AtomicBool::new(false),
            latencies_ns: Mutex::new(Vec::new()),
            binary: args.encoding == WireEncoding::ZenohSerialized,
            untimed_key: args
                .slow_subscriber_ms
                .map(|_| net::key(net::POSE, &net::robot_id(0))),
            slow_poses: AtomicU64::new(0),
            soak: OnceLock::new(),
        });
        let mut streams: Vec<(Stream, OnReply)> = vec![
            (net::POSE, Replies::pose),
            (net::DEVIATION, |replies, _| replies.deviation()),
        ];
        if args.target == Target::Armtwin {
            streams.push((net::METRICS, |replies, _| {
                replies.metrics.fetch_add(1, Ordering::Relaxed);
            }));
            streams.push((net::EVENTS, |replies, _| {
                replies.events.fetch_add(1, Ordering::Relaxed);
            }));
        }
        let mut subscribers = Vec::new();
        for (stream, on_reply) in streams {
            let replies = replies.clone();
            subscribers.push(
                session
                    .declare_subscriber(net::every_robot(stream))
                    .callback(move |sample| on_reply(&replies, &sample))
                    .wait()?,
            );
        }
        let slow = match args.slow_subscriber_ms {
            Some(sleep_ms) => {
                let mut zenoh = args.zenoh.clone();
                for endpoint in &mut zenoh.connect {
                    endpoint.push_str("#so_rcvbuf=65536");
                }
                let slow_session = zenoh::open(net::config_of(&zenoh)?).wait()?;
                let sleep = Duration::from_millis(sleep_ms);
                let replies = replies.clone();
                let subscriber = slow_session
                    .declare_subscriber(net::key(net::POSE, &net::robot_id(0)))
                    .callback(move |_| {
                        thread::sleep(sleep);
                        replies.slow_poses.fetch_add(1, Ordering::Relaxed);
                    })
                    .wait()?;
                Some((slow_session, subscriber))
            }
            None => None,
        };
        let seq_start = match &args.seq_file {
            Some(path) if path.exists() => read_seq_file(path)?,
            _ => Vec::new(),
        };
        let tokens = match args.target {
            Target::Armtwin => Some(Tokens::watch(&session)?),
            Target::Echo => None,
        };
        Ok(Self {
            workload: Workload::ur10e()?,
            embedded: args.embedded,
            args,
            session,
            senders,
            replies,
            robots: Vec::new(),
            subscribers,
            slow,
            tokens,
            seq_start,
            cursor: 0,
            accounted: Counts::default(),
        })
    }

    /// Writes each robot's next gateway `seq` to `--seq-file`.
    fn save_seq(&self) -> Result<(), LoadError> {
        let Some(path) = &self.args.seq_file else {
            return Ok(());
        };
        let next: Vec<u64> = (0..self.robots.len().max(self.seq_start.len()))
            .map(|robot| match self.robots.get(robot) {
                Some(keys) => keys.gateway_seq,
                None => self.seq_start[robot],
            })
            .collect();
        let error = |detail: String| LoadError::SeqFile {
            path: path.display().to_string(),
            detail,
        };
        let text = serde_json::to_string(&next).map_err(|e| error(e.to_string()))?;
        std::fs::write(path, text).map_err(|e| error(e.to_string()))
    }

    fn close(self) {
        drop(self.robots);
        drop(self.subscribers);
        drop(self.tokens);
        if let Some((slow_session, subscriber)) = self.slow {
            drop(subscriber);
            let _ = slow_session.close().wait();
        }
        // Failing to close a session at exit changes nothing measured.
        for sender in self.senders {
            let _ = sender.close().wait();
        }
        let _ = self.session.close().wait();
    }

    /// Declares publishers and reply keys of robots up to (not including) `count`. The memory
    /// measurement declares no reply keys: it receives a few replies per robot, and the system
    /// under test should not hold our declarations for it.
    fn declare_robots(&mut self, count: usize) -> Result<(), LoadError> {
        for index in self.robots.len()..count {
            let keys = self.declare_robot(index)?;
            self.robots.push(keys);
        }
        Ok(())
    }

    /// The publishers and reply keys of robot `index`, on gateway session `index % gateways`.
    fn declare_robot(&self, index: usize) -> Result<RobotKeys, LoadError> {
        let reply_streams: &[Stream] = match (self.args.target, self.args.memory_base_robots) {
            (_, Some(_)) => &[],
            (Target::Echo, None) => &[net::POSE, net::DEVIATION],
            (Target::Armtwin, None) => &[net::POSE, net::DEVIATION, net::METRICS, net::EVENTS],
        };
        let robot = net::robot_id(index);
        let gateway = index % (self.senders.len() + 1);
        let sender = match gateway {
            0 => &self.session,
            n => &self.senders[n - 1],
        };
        let binary = self.args.encoding == WireEncoding::ZenohSerialized;
        let publisher = |stream: Stream, schema: &str| {
            let encoding = if binary {
                Encoding::ZENOH_SERIALIZED.with_schema(schema)
            } else {
                Encoding::APPLICATION_JSON
            };
            sender
                .declare_publisher(net::key(stream, &robot))
                .congestion_control(CongestionControl::Block)
                .encoding(encoding)
                .wait()
        };
        let joints = publisher(net::JOINTS, zser::JOINTS_SCHEMA)?;
        let measured = publisher(net::MEASURED, zser::POSE_SCHEMA)?;
        let replies = reply_streams
            .iter()
            .map(|&stream| {
                self.session
                    .declare_keyexpr(net::key(stream, &robot))
                    .wait()
            })
            .collect::<Result<_, _>>()?;
        Ok(RobotKeys {
            joints,
            measured,
            replies,
            next_seq: 0,
            gateway_seq: self.seq_start.get(index).copied().unwrap_or(0),
            last_t_s: f64::NEG_INFINITY,
        })
    }

    /// Waits until the system under test subscribes to both input streams, on every gateway's
    /// session (each one's first robot).
    fn wait_for_subscriber(&self) -> Result<(), LoadError> {
        let deadline = Instant::now() + MATCH_TIMEOUT;
        if self.robots.is_empty() {
            return Err(LoadError::NoAnswer("no robots".to_owned()));
        }
        let firsts = &self.robots[..self.robots.len().min(self.senders.len() + 1)];
        for publisher in firsts
            .iter()
            .flat_map(|keys| [&keys.joints, &keys.measured])
        {
            while !publisher.matching_status().wait()?.matching() {
                if Instant::now() >= deadline {
                    return Err(LoadError::NoAnswer(format!(
                        "nobody subscribes to {} after {} s",
                        publisher.key_expr(),
                        MATCH_TIMEOUT.as_secs()
                    )));
                }
                thread::sleep(Duration::from_millis(20));
            }
        }
        // The subscriber's declaration and ours cross on the link; let ours land too.
        thread::sleep(Duration::from_millis(200));
        Ok(())
    }

    /// Sends one sample of `robot`: a joint and a measured message with the same stamp, or one
    /// joint message with the measured pose embedded.
    fn send(&mut self, robot: usize) -> Result<(), LoadError> {
        let now_s = self.replies.now_s();
        let outgoing = Outgoing {
            workload: &self.workload,
            encoding: self.args.encoding,
            embedded: self.embedded,
        };
        outgoing.put(&mut self.robots[robot], now_s)
    }

    /// Deviations expected per sample: one, except from the echo when the measured pose is
    /// embedded in the joint message (it returns that one message on `pose`).
    fn deviations_per_sample(&self) -> u64 {
        u64::from(!(self.embedded && self.args.target == Target::Echo))
    }

    /// armtwin declares a newly tracked robot's liveliness token on its control thread, after
    /// the robot's first sample has been answered, every new robot's token before any robot's
    /// route caches (Zenoh's declarations cost O(robots) each). The echo declares everything
    /// before it reports ready. So that both are measured tracking every robot, this waits until
    /// `robots` tokens are visible. Returns whether it waited (only armtwin has tokens).
    fn wait_for_tracking(&self, robots: usize) -> Result<bool, LoadError> {
        if self.tokens.is_none() || robots == 0 {
            return Ok(false);
        }
        self.await_tokens(robots)?;
        Ok(true)
    }

    /// Sends one sample per robot of `robots` until every one is answered. The system under
    /// test may take long to start tracking thousands of robots (Zenoh's declarations cost
    /// O(robots) each), so this waits as long as answers keep coming; a round that stalls for
    /// [`STALL`] is sent again (its first samples may have crossed our subscribers' declaration).
    fn warm_up(&mut self, robots: std::ops::Range<usize>) -> Result<(), LoadError> {
        let count = robots.len() as u64;
        for _ in 0..3 {
            let base = self.replies.counts();
            for robot in robots.clone() {
                self.send(robot)?;
            }
            let mut answered = 0;
            let mut progress = Instant::now();
            loop {
                let got = self.replies.counts().since(base);
                if got.poses >= count && got.deviations >= count * self.deviations_per_sample() {
                    thread::sleep(PAUSE);
                    self.accounted = self.replies.counts();
                    return Ok(());
                }
                let now = Instant::now();
                if got.poses + got.deviations > answered {
                    answered = got.poses + got.deviations;
                    progress = now;
                } else if now - progress >= STALL {
                    break;
                }
                thread::sleep(Duration::from_millis(5));
            }
            eprintln!(
                "load: warm-up stalled at {answered} of {} replies, sending again",
                2 * count
            );
        }
        Err(LoadError::NoAnswer(format!(
            "the system under test did not answer all of {count} robots' first samples"
        )))
    }

    fn sut_cpu_s(&self) -> Option<f64> {
        self.args.sut_pid.and_then(|pid| procfs::cpu_s(pid).ok())
    }

    /// Sends `rate × duration_s` samples on schedule and waits for their replies.
    fn trial(&mut self, rate: f64, duration_s: f64, record: bool) -> Result<Trial, LoadError> {
        let samples = (rate * duration_s).round().max(1.0) as u64;
        let base = self.accounted;
        let cpu_before = self.sut_cpu_s();
        if record {
            self.replies
                .latencies_ns
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .clear();
            self.replies.recording.store(true, Ordering::Relaxed);
        }
        let start = Instant::now();
        let start_ns = self.replies.elapsed_ns();
        // A system that falls this far behind the schedule is not keeping up: stop offering.
        let give_up_lag = Duration::from_secs_f64(duration_s.max(1.0));
        let mut sent = 0;
        while sent < samples {
            let due = start + Duration::from_secs_f64(sent as f64 / rate);
            let now = Instant::now();
            if due > now {
                // Never spin: the system under test needs the cores.
                thread::sleep(due - now);
            } else if now - due > give_up_lag {
                break;
            }
            let robot = self.cursor;
            self.cursor = (self.cursor + 1) % self.robots.len();
            self.send(robot)?;
            sent += 1;
        }
        let abandoned = sent < samples;
        let samples = sent;
        let send_s = start.elapsed().as_secs_f64();
        let deadline_s = duration_s * (1.0 + self.args.tolerance) + COMPLETION_SLACK_S;
        let wait_until = start + Duration::from_secs_f64(deadline_s.max(send_s) + 1.0);
        let deviations = samples * self.deviations_per_sample();
        let complete = |replies: Counts| {
            let got = replies.since(base);
            got.poses >= samples && got.deviations >= deviations
        };
        let mut complete_s = None;
        while Instant::now() < wait_until {
            if complete(self.replies.counts()) {
                let last_ns = self.replies.last_ns.load(Ordering::Acquire);
                complete_s = Some(last_ns.saturating_sub(start_ns) as f64 / 1e9);
                break;
            }
            thread::sleep(Duration::from_millis(1));
        }
        self.replies.recording.store(false, Ordering::Relaxed);
        let cpu_after = self.sut_cpu_s();
        if complete_s.is_none() {
            // Let the stragglers arrive, so that they do not count for the next trial.
            let settle_until = Instant::now() + SETTLE;
            while Instant::now() < settle_until && !complete(self.replies.counts()) {
                thread::sleep(Duration::from_millis(10));
            }
        }
        let now = self.replies.counts();
        let replies = now.since(base);
        self.accounted = now;
        let last_reply_s = self
            .replies
            .last_ns
            .load(Ordering::Acquire)
            .saturating_sub(start_ns) as f64
            / 1e9;
        let delivered_rate =
            (replies.poses > 0 && last_reply_s > 0.0).then(|| replies.poses as f64 / last_reply_s);
        let lost =
            samples.saturating_sub(replies.poses) + deviations.saturating_sub(replies.deviations);
        let sustained = !abandoned && lost == 0 && complete_s.is_some_and(|s| s <= deadline_s);
        let trial = Trial {
            offered_rate: rate,
            samples,
            duration_s,
            send_s,
            complete_s,
            replies,
            lost,
            achieved_rate: complete_s.map(|s| samples as f64 / s),
            delivered_rate,
            sut_cpu_s: cpu_before.zip(cpu_after).map(|(b, a)| a - b),
            sustained,
        };
        eprintln!(
            "load: {rate:.0}/s × {duration_s} s to {robots} robots: {} (sent in {send_s:.3} s, complete {}, lost {lost})",
            if sustained {
                "sustained"
            } else {
                "NOT sustained"
            },
            complete_s.map_or_else(|| "never".to_owned(), |s| format!("{s:.3} s")),
            robots = self.robots.len(),
        );
        thread::sleep(PAUSE);
        Ok(trial)
    }

    fn latency(&mut self) -> Result<Latency, LoadError> {
        let trial = self.trial(self.args.latency_rate, self.args.latency_duration, true)?;
        let mut sorted = std::mem::take(
            &mut *self
                .replies
                .latencies_ns
                .lock()
                .unwrap_or_else(PoisonError::into_inner),
        );
        sorted.sort_unstable();
        Ok(Latency {
            trial,
            count: sorted.len(),
            p50_us: percentile_us(&sorted, 0.5),
            p99_us: percentile_us(&sorted, 0.99),
            p999_us: percentile_us(&sorted, 0.999),
            max_us: percentile_us(&sorted, 1.0),
        })
    }

    /// Whether `rate` is sustained in one of `1 + retries` trials (stopping at the first that
    /// is); every trial run goes into `trials`.
    fn search_trial(
        &mut self,
        rate: f64,
        duration_s: f64,
        trials: &mut Vec<Trial>,
    ) -> Result<bool, LoadError> {
        for _ in 0..=self.args.retries {
            let trial = self.trial(rate, duration_s, false)?;
            let sustained = trial.sustained;
            trials.push(trial);
            if sustained {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Doubles the rate until a trial fails (halves it while the first ones fail), then
    /// bisects between the best sustained rate and the lowest failing one.
    fn search(&mut self) -> Result<Search, LoadError> {
        let duration_s = self.args.duration;
        let max_rate = self.args.max_rate;
        let mut trials = Vec::new();
        let mut sustained = 0.0_f64;
        let mut failed = f64::INFINITY;
        let mut rate = self.args.start_rate.min(max_rate);
        loop {
            if self.search_trial(rate, duration_s, &mut trials)? {
                sustained = rate;
                if rate >= max_rate || failed.is_finite() {
                    break;
                }
                rate = (rate * 2.0).min(max_rate);
            } else {
                failed = rate;
                if sustained > 0.0 || rate < 20.0 {
                    break;
                }
                rate /= 2.0;
            }
        }
        if failed.is_finite() && sustained > 0.0 {
            for _ in 0..self.args.bisect_steps {
                let rate = f64::midpoint(sustained, failed).round();
                if self.search_trial(rate, duration_s, &mut trials)? {
                    sustained = rate;
                } else {
                    failed = rate;
                }
            }
        }
        Ok(Search {
            max_sustained_rate: sustained,
            trials,
        })
    }

    /// RSS of the system under test with `base_robots` tracked, then with every robot tracked,
    /// each robot having sent the same number of samples; keys are declared only for the robots
    /// in play, as gateways would.
    fn memory(&mut self, base_robots: usize) -> Result<Memory, LoadError> {
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

    /// Waits until `robots` liveliness tokens are visible, in whatever order they are declared
    /// (a restarted armtwin declares its restored robots' tokens in its own order); fails if
    /// their count stops growing for [`TRACKING_STALL`].
    fn await_tokens(&self, robots: usize) -> Result<(), LoadError> {
        let tokens = self
            .tokens
            .as_ref()
            .ok_or_else(|| LoadError::NoAnswer("only armtwin declares tokens".to_owned()))?;
        let (mut seen, mut progress, mut reported) = (0, Instant::now(), Instant::now());
        loop {
            let now_seen = tokens.live();
            if now_seen >= robots {
                eprintln!("load: armtwin tracks {now_seen} robots (liveliness tokens)");
                return Ok(());
            }
            if now_seen > seen {
                seen = now_seen;
                progress = Instant::now();
            } else if progress.elapsed() >= TRACKING_STALL {
                return Err(LoadError::NoAnswer(format!(
                    "armtwin declared {seen} of {robots} robots' liveliness tokens, then none for {} s",
                    TRACKING_STALL.as_secs()
                )));
            }
            if reported.elapsed() >= Duration::from_secs(5) {
                reported = Instant::now();
                eprintln!("load: armtwin has declared {seen} of {robots} robots");
            }
            thread::sleep(Duration::from_millis(10));
        }
    }
}

/// The liveliness tokens of armtwin's robots, kept by a liveliness subscriber that is told of
/// those already declared and then of each one declared or undeclared. Watching them costs the
/// system under test one message per token; asking for all of them again and again (a
/// liveliness `get`) would cost it and this process work in proportion to the tokens each time.
struct Tokens {
    live: Arc<Mutex<HashSet<String>>>,
    _subscriber: Subscriber<()>,
}

impl Tokens {
    fn watch(session: &Session) -> Result<Self, LoadError> {
        let live = Arc::new(Mutex::new(HashSet::new()));
        let kept = Arc::clone(&live);
        let subscriber = session
            .liveliness()
            .declare_subscriber(net::every_robot(net::ALIVE))
            .history(true)
            .callback(move |sample| {
                let mut live = kept.lock().unwrap_or_else(PoisonError::into_inner);
                match sample.kind() {
                    SampleKind::Put => live.insert(sample.key_expr().as_str().to_owned()),
                    SampleKind::Delete => live.remove(sample.key_expr().as_str()),
                };
            })
            .wait()?;
        Ok(Self {
            live,
            _subscriber: subscriber,
        })
    }

    /// Tokens declared now.
    fn live(&self) -> usize {
        self.live
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_are_nearest_rank() {
        let sorted: Vec<u64> = (1..=1000).map(|v| v * 1000).collect();
        assert!((percentile_us(&sorted, 0.5) - 500.0).abs() < 1e-9);
        assert!((percentile_us(&sorted, 0.99) - 990.0).abs() < 1e-9);
        assert!((percentile_us(&sorted, 0.999) - 999.0).abs() < 1e-9);
        assert!((percentile_us(&sorted, 1.0) - 1000.0).abs() < 1e-9);
        assert!(percentile_us(&[], 0.5).is_nan());
    }
}
