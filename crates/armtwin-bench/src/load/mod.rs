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
//! With `--paired` the replies come on `paired/<robot>`, one per sample: the echo's (`echo
//! --paired`) stand for a pose and its deviation each, armtwin's (`[service] outputs = "paired"`)
//! for a pose, and for its deviation when they carry one.
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
//! also times how long the system takes to declare the robots new to it; `--memory-stream-hz`:
//! each robot streams until its window is full); a first-contact trial
//! (`--first-contact-rate`: full rate to robots the system has never seen, no warm-up); the
//! wait for a restarted armtwin's liveliness tokens (`--await-tokens`); or a soak with churn
//! (`--soak-duration`, in `churn`: a JSON line per interval as it goes). Results go to standard
//! output as one JSON object; progress to standard error.
//!
//! Here: the flags, the errors, the sessions opened and closed, and the run in order;
//! `replies` (what the receive callbacks count and time), `robots` (each robot's publishers and
//! one sample put), `trials` (the warm-up, a trial on schedule, the latency run, the search),
//! `memory` (resident memory at fleet size), `tokens` (armtwin's liveliness tokens), `churn` (the
//! soak) and `report` (the report's types).
#![allow(
    clippy::print_stdout,
    clippy::print_stderr,
    reason = "a benchmark command's progress and report, on its terminal"
)]

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::thread;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use armtwin_cli::flags::ZenohArgs;
use armtwin_mesh::MeshError;
use armtwin_mesh::keys::Stream;
use clap::{Args, ValueEnum};
use serde::{Deserialize, Serialize};
use thiserror::Error;
use zenoh::Wait;
use zenoh::pubsub::Subscriber;
use zenoh::session::Session;

mod churn;
mod memory;
mod replies;
mod report;
mod robots;
mod tokens;
mod trials;

pub use churn::{Soak, SoakInterval};
pub use report::{Counts, Latency, LoadReport, Memory, Search, Trial};

use crate::net;
use crate::procfs::ProcError;
use crate::workload::{Workload, WorkloadError};
use replies::{OnReply, Replies};
use robots::RobotKeys;
use tokens::Tokens;

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
#[allow(
    clippy::struct_excessive_bools,
    reason = "independent command-line switches, not a state"
)]
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
    /// Replies come paired, one message per sample on `paired/<robot>` (armtwin with `[service]
    /// outputs = "paired"`, the echo with `--paired`), instead of on `pose` and `deviation`.
    #[arg(long)]
    pub paired: bool,
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
    /// Memory measurement: after each robot's first sample, stream the rest stamped this many
    /// per second of source time apart, as fast as the system under test answers them, instead
    /// of in rounds stamped as sent (the windows fill in source time, not in wall time).
    #[arg(long)]
    pub memory_stream_hz: Option<f64>,
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
            paired_always_deviation: args.target == Target::Echo,
            untimed_key: args
                .slow_subscriber_ms
                .map(|_| net::key(net::POSE, &net::robot_id(0))),
            slow_poses: AtomicU64::new(0),
            soak: OnceLock::new(),
        });
        let mut streams: Vec<(Stream, OnReply)> = if args.paired {
            vec![(net::PAIRED, Replies::paired)]
        } else {
            vec![
                (net::POSE, Replies::pose),
                (net::DEVIATION, |replies, _| replies.deviation()),
            ]
        };
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
}
