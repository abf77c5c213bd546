//! `armtwin record`: the live streams of the robots matching key expressions, taken from the mesh
//! and written as one MCAP file per robot ([`armtwin_recorder::live`]) for a duration or until
//! stopped.
//!
//! Zenoh's callbacks only copy a message and hand it to a bounded queue (a full queue drops it,
//! counted); a writer thread of its own decodes, admits robots (at most `max_robots`: ids are
//! untrusted) and writes every file. Must not know the twin: it records what goes over the mesh.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::future::Future;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, TrySendError, sync_channel};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use tracing::{info, warn};
use zenoh::key_expr::KeyExpr;

use armtwin_codec::gateway::Codec;
use armtwin_mesh::ingest;
use armtwin_mesh::keys::{KeyPrefixError, KeySpace, Stream};
use armtwin_mesh::zenoh_section::ZenohSection;
use armtwin_mesh::{
    MeshError, TEARDOWN_STEP, bounded, close_session, transport_stamp_s, zenoh_config_of,
};
use armtwin_recorder::live::{self, LiveFile, LiveStream};
use armtwin_recorder::store::{robot_directory, with_causes};

/// How often the progress callback is called.
const PROGRESS_PERIOD: Duration = Duration::from_millis(250);

/// How long to wait for the mesh to answer the query behind the subscribers' declarations.
const DECLARED_LIMIT: Duration = Duration::from_secs(5);

/// Where the files go.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RecordOutput {
    /// One file per robot in this directory: `<robot, escaped as the recorder's directories
    /// are>.mcap`.
    Directory(PathBuf),
    /// One file, of the first robot heard; other robots are refused.
    File(PathBuf),
}

/// `armtwin record`'s options.
#[derive(Debug, Clone)]
pub struct RecordSettings {
    /// How to join the mesh.
    pub zenoh: ZenohSection,
    /// Key prefix (`twin`).
    pub key_prefix: String,
    /// Robot ids or key expressions over them (`r1`, `cell-1/*`, `**`).
    pub robots: Vec<String>,
    /// Where the files go.
    pub output: RecordOutput,
    /// Joints of the robots' arms (a joint message with another count is malformed).
    pub joint_count: usize,
    /// Robots recorded at most; messages of further ids are refused.
    pub max_robots: usize,
    /// Messages waiting for the writer thread; more are dropped (and counted).
    pub queue: usize,
    /// How long to record (`None`: until `shutdown`).
    pub duration: Option<Duration>,
}

/// One robot's file.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedFile {
    /// Robot id.
    pub robot: String,
    /// The file.
    pub path: PathBuf,
    /// Messages in it.
    pub messages: u64,
    /// By stream.
    pub counts: live::LiveCounts,
    /// Its size.
    pub bytes: u64,
}

/// What a recording took, wrote and left out.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecordReport {
    /// The files written.
    pub files: Vec<RecordedFile>,
    /// Messages dropped because the writer thread's queue was full.
    pub dropped: u64,
    /// Messages that did not decode (skipped).
    pub malformed: u64,
    /// Messages of robots refused (over `max_robots`, or a second robot for one file).
    pub refused: u64,
    /// Robots whose file could not be written, and why.
    pub failures: Vec<(String, String)>,
    /// Whether `shutdown` ended the recording.
    pub interrupted: bool,
}

/// Messages written so far, per robot, for a progress line.
pub type Progress = BTreeMap<String, u64>;

/// Why a recording did not start or end well.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The session could not be configured or opened.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// Zenoh failed (declaring a subscriber, …).
    #[error("zenoh: {0}")]
    Zenoh(#[from] zenoh::Error),
    /// `--prefix` is not a plain key.
    #[error(transparent)]
    KeyPrefix(#[from] KeyPrefixError),
    /// A robot expression that makes no key expression.
    #[error("robots '{robots}': {reason}")]
    Robots {
        /// The expression given.
        robots: String,
        /// Zenoh's reason.
        reason: String,
    },
    /// The output directory could not be made.
    #[error("{path}: {source}")]
    Output {
        /// The directory.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The writer thread could not start or ended in a panic.
    #[error("the writer thread: {0}")]
    Writer(String),
    /// No twin answered the incident request.
    #[error(
        "no twin of '{robot}' answered within {limit:?}: is armtwin serving it, and may this \
         session's identity ask (the operator role, behind an access control)?"
    )]
    Unanswered {
        /// The robot asked for.
        robot: String,
        /// How long the request waited.
        limit: Duration,
    },
    /// The twin refused the incident request.
    #[error("the twin of '{robot}' refused: {reason}")]
    Refused {
        /// The robot asked for.
        robot: String,
        /// The twin's reply.
        reason: String,
    },
}

/// How long a twin may take to answer an incident request.
pub const INCIDENT_LIMIT: Duration = Duration::from_secs(10);

/// Asks the twin of `robot` for an incident file now, as an operator does with
/// `get <prefix>/admin/record/<robot>` (docs/recorder.md): of the seconds before its newest sample
/// and after, `pre_s` and `post_s` (the configured ones when `None`). Returns the twin's reply,
/// which names the file the incident will be.
pub async fn ask_incident(
    zenoh: &ZenohSection,
    key_prefix: &str,
    robot: &str,
    (pre_s, post_s): (Option<f64>, Option<f64>),
) -> Result<serde_json::Value, RecordError> {
    let keys = KeySpace::of_prefix(key_prefix)?;
    armtwin_mesh::keys::robot_id(robot).map_err(|problem| RecordError::Robots {
        robots: robot.to_owned(),
        reason: problem.to_string(),
    })?;
    let key = keys.key(Stream::Record, robot);
    let parameters: Vec<String> = [("pre_s", pre_s), ("post_s", post_s)]
        .into_iter()
        .filter_map(|(name, value)| value.map(|value| format!("{name}={value}")))
        .collect();
    let selector = if parameters.is_empty() {
        key
    } else {
        format!("{key}?{}", parameters.join(";"))
    };
    let session = zenoh::open(zenoh_config_of(zenoh)?).await?;
    let answer = async {
        let replies = session
            .get(selector.as_str())
            .timeout(INCIDENT_LIMIT)
            .await?;
        match replies.recv_async().await {
            Ok(reply) => match reply.result() {
                Ok(sample) => Ok(serde_json::from_slice(&sample.payload().to_bytes())
                    .unwrap_or_else(|_| {
                        serde_json::Value::String(
                            String::from_utf8_lossy(&sample.payload().to_bytes()).into_owned(),
                        )
                    })),
                Err(error) => {
                    let text = String::from_utf8_lossy(&error.payload().to_bytes()).into_owned();
                    // The twin's refusals are `{"error": "…"}`.
                    let reason = serde_json::from_str::<serde_json::Value>(&text)
                        .ok()
                        .and_then(|body| body.get("error")?.as_str().map(str::to_owned))
                        .unwrap_or(text);
                    Err(RecordError::Refused {
                        robot: robot.to_owned(),
                        reason,
                    })
                }
            },
            Err(_) => Err(RecordError::Unanswered {
                robot: robot.to_owned(),
                limit: INCIDENT_LIMIT,
            }),
        }
    }
    .await;
    let _ = close_session(&session).await;
    answer
}

/// A message as it arrived, for the writer thread.
struct Arrived {
    stream: LiveStream,
    key: String,
    codec: Codec,
    payload: Vec<u8>,
    fallback_s: f64,
}

/// The keys recorded: each stream under each robot expression.
const STREAMS: [(LiveStream, Stream); 4] = [
    (LiveStream::Joints, Stream::Joints),
    (LiveStream::Measured, Stream::Measured),
    (LiveStream::TwinPose, Stream::Pose),
    (LiveStream::Deviation, Stream::Deviation),
];

/// Records until `settings.duration` has passed or `shutdown` completes, calling `progress` now
/// and then with the messages written per robot.
pub async fn record(
    settings: &RecordSettings,
    shutdown: impl Future<Output = ()>,
    mut progress: impl FnMut(&Progress),
) -> Result<RecordReport, RecordError> {
    let keys = KeySpace::of_prefix(&settings.key_prefix)?;
    let mut subscribed = Vec::new();
    for robots in &settings.robots {
        for (stream, key_stream) in STREAMS {
            let key = keys.key(key_stream, robots);
            KeyExpr::try_from(key.clone()).map_err(|e| RecordError::Robots {
                robots: robots.clone(),
                reason: e.to_string(),
            })?;
            subscribed.push((stream, key));
        }
    }
    if let RecordOutput::Directory(dir) = &settings.output {
        std::fs::create_dir_all(dir).map_err(|source| RecordError::Output {
            path: dir.clone(),
            source,
        })?;
    }
    let (queue, arrivals) = sync_channel::<Arrived>(settings.queue.max(1));
    let shared = Arc::new(Shared::default());
    let writer = {
        let writer = Writer::new(settings, keys.clone(), Arc::clone(&shared));
        std::thread::Builder::new()
            .name("armtwin-record".to_owned())
            .spawn(move || writer.run(&arrivals))
            .map_err(|e| RecordError::Writer(e.to_string()))?
    };
    let session = zenoh::open(zenoh_config_of(&settings.zenoh)?).await?;
    let mut subscribers = Vec::new();
    for (stream, key) in subscribed {
        let queue = queue.clone();
        let shared = Arc::clone(&shared);
        let subscriber = session
            .declare_subscriber(key.clone())
            .callback(move |sample| {
                let arrived = Arrived {
                    stream,
                    key: sample.key_expr().as_str().to_owned(),
                    codec: ingest::codec_of(sample.encoding()),
                    payload: sample.payload().to_bytes().into_owned(),
                    fallback_s: transport_stamp_s(&sample),
                };
                if let Err(TrySendError::Full(_)) = queue.try_send(arrived) {
                    shared.dropped.fetch_add(1, Ordering::Relaxed);
                }
            })
            .await?;
        info!(%key, "recording");
        subscribers.push(subscriber);
    }
    drop(queue);
    declared(&session, &keys, &settings.robots).await;
    info!("recording started");
    let interrupted = wait(settings.duration, shutdown, &shared, &mut progress).await;
    for subscriber in subscribers {
        if let Some(result) = bounded(
            "undeclaring a subscriber",
            TEARDOWN_STEP,
            subscriber.undeclare(),
        )
        .await
        {
            result?;
        }
    }
    close_session(&session).await?;
    // The callbacks' queue senders went with the subscribers: the thread ends once it has
    // written what is queued.
    let mut report = tokio::task::spawn_blocking(move || writer.join())
        .await
        .map_err(|e| RecordError::Writer(e.to_string()))?
        .map_err(|_| RecordError::Writer("panicked".to_owned()))?;
    progress(&shared.progress());
    report.dropped = shared.dropped.load(Ordering::Relaxed);
    report.interrupted = interrupted;
    info!(
        files = report.files.len(),
        dropped = report.dropped,
        malformed = report.malformed,
        refused = report.refused,
        "recording done"
    );
    Ok(report)
}

/// Waits until the peer this session joined through has taken its subscribers: a query for the
/// robots' state travels behind the declarations on the same link, so its final reply is a
/// barrier (a publisher that starts after it reaches this recorder from its first message).
/// Without an `armtwin serve` answering it returns at once.
async fn declared(session: &zenoh::Session, keys: &KeySpace, robots: &[String]) {
    for robots in robots {
        let key = keys.key(Stream::State, robots);
        match session.get(&key).timeout(DECLARED_LIMIT).await {
            Ok(replies) => while replies.recv_async().await.is_ok() {},
            Err(e) => {
                warn!(error = %e, %key, "could not wait for the mesh to take the subscribers");
            }
        }
    }
}

/// Waits for the duration or `shutdown`, calling `progress` meanwhile; whether `shutdown` ended
/// it.
async fn wait(
    duration: Option<Duration>,
    shutdown: impl Future<Output = ()>,
    shared: &Shared,
    progress: &mut impl FnMut(&Progress),
) -> bool {
    let deadline = duration.and_then(|d| tokio::time::Instant::now().checked_add(d));
    let until_deadline = async {
        match deadline {
            Some(deadline) => tokio::time::sleep_until(deadline).await,
            None => std::future::pending().await,
        }
    };
    tokio::pin!(shutdown, until_deadline);
    let mut ticks = tokio::time::interval(PROGRESS_PERIOD);
    loop {
        tokio::select! {
            () = &mut shutdown => return true,
            () = &mut until_deadline => return false,
            _ = ticks.tick() => progress(&shared.progress()),
        }
    }
}

/// What the callbacks and the writer thread share with the task that waits.
#[derive(Default)]
struct Shared {
    dropped: AtomicU64,
    written: Mutex<Progress>,
}

impl Shared {
    fn progress(&self) -> Progress {
        self.written
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }
}

/// A robot's file being written.
struct Open {
    path: PathBuf,
    part: PathBuf,
    file: LiveFile<BufWriter<File>>,
    /// The same file, to sync before it is renamed.
    sync: File,
}

/// A robot heard: its file, or why it has none.
enum Robot {
    Recording(Box<Open>),
    Failed,
}

/// The writer thread's state.
struct Writer {
    keys: KeySpace,
    output: RecordOutput,
    joint_count: usize,
    max_robots: usize,
    shared: Arc<Shared>,
    robots: HashMap<String, Robot>,
    /// Refused ids warned about (bounded as the robots are).
    refused_ids: Vec<String>,
    report: RecordReport,
}

impl Writer {
    fn new(settings: &RecordSettings, keys: KeySpace, shared: Arc<Shared>) -> Self {
        Self {
            keys,
            output: settings.output.clone(),
            joint_count: settings.joint_count,
            max_robots: match settings.output {
                RecordOutput::Directory(_) => settings.max_robots,
                RecordOutput::File(_) => 1,
            },
            shared,
            robots: HashMap::new(),
            refused_ids: Vec::new(),
            report: RecordReport::default(),
        }
    }

    fn run(mut self, arrivals: &Receiver<Arrived>) -> RecordReport {
        while let Ok(arrived) = arrivals.recv() {
            self.take(&arrived);
        }
        let mut robots: Vec<_> = self.robots.drain().collect();
        robots.sort_by(|a, b| a.0.cmp(&b.0));
        for (robot, state) in robots {
            if let Robot::Recording(open) = state {
                let counts = open.file.counts();
                match finish(*open) {
                    Ok((path, messages, bytes)) => {
                        info!(%robot, path = %path.display(), messages, bytes, "recorded");
                        self.report.files.push(RecordedFile {
                            robot,
                            path,
                            messages,
                            counts,
                            bytes,
                        });
                    }
                    Err(error) => {
                        warn!(%robot, %error, "the robot's file could not be completed");
                        self.report.failures.push((robot, error));
                    }
                }
            }
        }
        self.report
    }

    fn take(&mut self, arrived: &Arrived) {
        let stream = match arrived.stream {
            LiveStream::Joints => Stream::Joints,
            LiveStream::Measured => Stream::Measured,
            LiveStream::TwinPose => Stream::Pose,
            LiveStream::Deviation => Stream::Deviation,
        };
        let robot = match self.keys.robot_of(stream, &arrived.key) {
            Ok(robot) => robot,
            Err(error) => {
                self.report.malformed += 1;
                warn!(key = %arrived.key, %error, "a message on a key that names no robot: skipped");
                return;
            }
        };
        let message = match live::decode(
            arrived.stream,
            arrived.codec,
            &arrived.payload,
            self.joint_count,
            arrived.fallback_s,
        ) {
            Ok(message) => message,
            Err(error) => {
                self.report.malformed += 1;
                warn!(key = %arrived.key, %error, "a malformed message: skipped");
                return;
            }
        };
        if !self.robots.contains_key(robot) && !self.admit(robot) {
            return;
        }
        let Some(Robot::Recording(open)) = self.robots.get_mut(robot) else {
            return;
        };
        if let Err(error) = open.file.write(&message) {
            warn!(%robot, %error, "the robot's file could not be written: its recording stops");
            self.report
                .failures
                .push((robot.to_owned(), with_causes(&error)));
            let _ = std::fs::remove_file(&open.part);
            self.robots.insert(robot.to_owned(), Robot::Failed);
            return;
        }
        let written = open.file.counts();
        self.shared
            .written
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .insert(
                robot.to_owned(),
                written.joints + written.measured + written.twin_poses + written.deviations,
            );
    }

    /// Opens a file for `robot`, heard for the first time; whether it is recorded.
    fn admit(&mut self, robot: &str) -> bool {
        if self.robots.len() >= self.max_robots {
            self.report.refused += 1;
            if self.refused_ids.len() < self.max_robots
                && !self.refused_ids.iter().any(|r| r == robot)
            {
                warn!(
                    robot,
                    max_robots = self.max_robots,
                    "more robots than recorded at most: refused"
                );
                self.refused_ids.push(robot.to_owned());
            }
            return false;
        }
        let path = match &self.output {
            RecordOutput::Directory(dir) => dir.join(format!("{}.mcap", robot_directory(robot))),
            RecordOutput::File(path) => path.clone(),
        };
        let mut part = path.clone().into_os_string();
        part.push(".part");
        let part = PathBuf::from(part);
        let opened = File::create(&part)
            .and_then(|file| Ok((file.try_clone()?, file)))
            .map_err(|e| e.to_string())
            .and_then(|(sync, file)| {
                let file = LiveFile::create(BufWriter::new(file), robot, self.joint_count)
                    .map_err(|e| with_causes(&e))?;
                Ok((sync, file))
            });
        match opened {
            Ok((sync, file)) => {
                info!(robot, path = %path.display(), "recording the robot");
                self.robots.insert(
                    robot.to_owned(),
                    Robot::Recording(Box::new(Open {
                        path,
                        part,
                        file,
                        sync,
                    })),
                );
                true
            }
            Err(error) => {
                warn!(robot, path = %part.display(), %error, "cannot start the robot's file");
                let _ = std::fs::remove_file(&part);
                self.report.failures.push((robot.to_owned(), error));
                self.robots.insert(robot.to_owned(), Robot::Failed);
                false
            }
        }
    }
}

/// Ends a robot's file and gives it its name: the path, messages and bytes.
fn finish(open: Open) -> Result<(PathBuf, u64, u64), String> {
    let Open {
        path,
        part,
        file,
        sync,
    } = open;
    let result = file
        .finish()
        .map_err(|e| with_causes(&e))
        .and_then(|messages| {
            sync.sync_all().map_err(|e| e.to_string())?;
            std::fs::rename(&part, &path).map_err(|e| e.to_string())?;
            Ok(messages)
        });
    match result {
        Ok(messages) => Ok((path.clone(), messages, size_of_file(&path))),
        Err(error) => {
            let _ = std::fs::remove_file(&part);
            Err(error)
        }
    }
}

fn size_of_file(path: &Path) -> u64 {
    std::fs::metadata(path).map_or(0, |m| m.len())
}
