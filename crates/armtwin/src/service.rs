//! `armtwin serve`: the pipeline on a Zenoh mesh.
//!
//! Owns the session, the wildcard subscriptions and queryables (and one subscription per
//! `[[sources]]` entry: JSON or ROS 2 on keys of their own), the per-robot publishers (the twin
//! pose as a ROS 2 `PoseStamped` among them, for robots with `ros2_pose`) and liveliness tokens,
//! and the ordered teardown. Samples and queries are handled in Zenoh's callbacks: each sample
//! resolves its robot and decodes against the robot's immutable settings first, then steps that
//! robot's twin under the robot's own lock, so robots arriving on different links never wait on
//! each other (see [`SharedTwin`]); a control thread declares newly tracked robots' liveliness
//! tokens (and, once a robot streams, the publishers that cache its routes), publishes the periodic metrics (and the snapshot, with `[service] state_dir`) and finishes
//! every twin at shutdown, each robot locked in turn.
//!
//! An instance owns the robots of `[service] robots`: its wildcard subscriptions and queryables
//! cover those ids alone, and it claims them on the mesh (`<prefix>/shards/<zid>`) before taking
//! input, refusing to start over another instance's claim. A snapshot is restored before the
//! first input, whole or not at all.
//!
//! Flow control: inputs are received reliably; while a callback works, Zenoh does not read its
//! link, which backpressures the transport and, through it, the gateways: nothing valid is
//! dropped. Poses and deviations use `[service] pose_congestion` (`drop` by default: a message a
//! subscriber's link cannot take is dropped for that subscriber alone, after at most Zenoh's
//! `wait_before_drop`, and the twin goes on; `block` waits). Metrics, events and query replies
//! always block: they are few and must arrive; a subscriber that stops reading them is
//! disconnected after Zenoh's `wait_before_close`. Every output carries its encoding.

use std::collections::VecDeque;
use std::future::{Future, IntoFuture};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, channel};
use std::sync::{Mutex, MutexGuard, PoisonError, RwLock, RwLockReadGuard};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use thiserror::Error;
use tracing::{debug, info, warn};
use zenoh::Wait;
use zenoh::bytes::Encoding;
use zenoh::key_expr::KeyExpr;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::query::Query;
use zenoh::sample::{Locality, Sample};
use zenoh::session::Session;

use crate::codec::decoded::{self, Arrival, Decoded, Decoder};
use crate::codec::gateway::{self, Codec, SourceCodec};
use crate::codec::ik::{IkAnswerJson, IkRequest};
use crate::codec::json::{self as wire, EstimateMessage};
use crate::codec::{PoseFields, cdr, zser};
use crate::config::{
    Congestion, EventBudget, OutputEncoding, SelfCalibrationConfig, ServiceConfig, SourceConfig,
    SourceRobot, SourceStream, ZenohSection,
};
use crate::dashboard;
use crate::ingest;
use crate::kinematics::{OutputFrame, PoseReadout};
use crate::metrics::Deviation;
use crate::model::RobotModel;
use crate::pipeline::{
    Event, EventDetail, EventKind, MeasuredStream, MetricsSnapshot, PipelineConfig, RejectCause,
    ReplaceModelError, RestoreError, Robot, RobotDirectory, RobotIndex, Sink, Twin, TwinRecord,
};
use crate::ros2::{self, Attachment, KeyScheme, PoseOutputs, PublisherSeq};
use crate::self_calibration::{self, CalibrationBatch, Estimate};
use crate::snapshot::{SnapshotError, SnapshotStore};

/// How long each teardown step may take.
pub(crate) const TEARDOWN_STEP: Duration = Duration::from_secs(5);

/// Why the service stopped with an error.
#[derive(Debug, Error)]
pub enum ServiceError {
    /// The Zenoh configuration is invalid.
    #[error("zenoh configuration: {0}")]
    ZenohConfig(String),
    /// Zenoh failed (opening the session, declaring, …).
    #[error("zenoh: {0}")]
    Zenoh(#[from] zenoh::Error),
    /// A sensor's key expression covers one of armtwin's own outputs: its own puts would feed
    /// back into it.
    #[error(
        "robot '{robot}': sensor key expression '{key_expr}' intersects armtwin's output '{output}'"
    )]
    SensorKeyLoop {
        /// The robot the sensor belongs to.
        robot: String,
        /// The sensor's key expression.
        key_expr: String,
        /// The output key expression it intersects.
        output: String,
    },
    /// The control thread failed.
    #[error("control thread: {0}")]
    Worker(String),
    /// Another instance on the mesh already owns some of this instance's robots.
    #[error(
        "service.robots '{own}' overlaps '{other}', owned by the armtwin instance {zid}: a robot \
         must belong to one instance (give each a disjoint key expression)"
    )]
    ShardOverlap {
        /// This instance's `[service] robots`.
        own: String,
        /// The other instance's.
        other: String,
        /// The other instance's Zenoh id.
        zid: String,
    },
    /// The dashboard's address cannot be listened on.
    #[error("http: cannot listen on {address}")]
    HttpListen {
        /// The `[http] listen` address.
        address: std::net::SocketAddr,
        /// Why.
        source: std::io::Error,
    },
}

/// Totals reported when the service stops.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ServeReport {
    /// Inputs (samples and queries) processed.
    pub inputs: u64,
    /// Twin poses published.
    pub poses: u64,
    /// Robots tracked.
    pub robots: usize,
    /// Outputs Zenoh refused to send.
    pub publish_errors: u64,
}

/// Builds the Zenoh configuration of a `[zenoh]` section (the command line's flags already
/// applied, [`ZenohSection::overridden`]): the one place every armtwin session gets its
/// configuration from. The section's `cfg` entries go in last, so they win.
pub fn zenoh_config_of(section: &ZenohSection) -> Result<zenoh::Config, ServiceError> {
    let mut zenoh = match &section.file {
        Some(path) => zenoh::Config::from_file(path)
            .map_err(|e| ServiceError::ZenohConfig(format!("{}: {e}", path.display())))?,
        None => zenoh::Config::default(),
    };
    let json = |value: &[String]| serde_json::to_string(value).unwrap_or_else(|_| "[]".to_owned());
    let inserts = [
        ("mode", format!("\"{}\"", section.mode)),
        ("listen/endpoints", json(&section.listen)),
        ("connect/endpoints", json(&section.connect)),
        (
            "scouting/multicast/enabled",
            section.multicast_scouting.to_string(),
        ),
    ];
    for (key, value) in inserts {
        zenoh
            .insert_json5(key, &value)
            .map_err(|e| ServiceError::ZenohConfig(format!("{key} = {value}: {e}")))?;
    }
    for insert in &section.cfg {
        if let Err(e) = zenoh.insert_json5(&insert.key, &insert.value) {
            // Zenoh's message is the parser's error in debug form (an escaped excerpt of the
            // value, then the reason after `= `) followed by Zenoh's source location.
            let message = e.to_string();
            let reason = message
                .split_once("msg: \"")
                .and_then(|(_, rest)| rest.split_once('"'))
                .map_or(message.as_str(), |(msg, _)| msg);
            let reason = reason.rsplit_once("= ").map_or(reason, |(_, last)| last);
            let reason = reason
                .find(" at ")
                .filter(|&at| reason[at..].contains(".rs:"))
                .map_or(reason, |at| &reason[..at]);
            let problem = if zenoh.get_json(&insert.key).is_err() {
                "Zenoh's configuration has no such key".to_owned()
            } else {
                format!("not a value this key takes: {reason}")
            };
            return Err(ServiceError::ZenohConfig(format!(
                "cannot set '{}' to '{}': {problem}",
                insert.key, insert.value
            )));
        }
    }
    Ok(zenoh)
}

/// Aggregates this session's publishers under `key_exprs` (Zenoh's `aggregation/publishers`),
/// unless the configuration already names publishers to aggregate: then the operator's choice
/// stands. Every publisher declared without it asks the mesh for its key's subscribers, a
/// reliable message to every peer that each answers; aggregated, the first publisher under a key
/// expression asks for all of them and the others ask nothing, so a fleet's publishers cost only
/// their local key declarations and no subscriber's link has to carry them.
pub fn aggregate_publishers(
    zenoh: &mut zenoh::Config,
    key_exprs: &[String],
) -> Result<(), ServiceError> {
    let configured = zenoh
        .get_json("aggregation/publishers")
        .map_err(|e| ServiceError::ZenohConfig(format!("aggregation/publishers: {e}")))?;
    let configured: Vec<String> = serde_json::from_str(&configured).unwrap_or_default();
    if !configured.is_empty() || key_exprs.is_empty() {
        return Ok(());
    }
    let value = serde_json::to_string(key_exprs).unwrap_or_else(|_| "[]".to_owned());
    zenoh
        .insert_json5("aggregation/publishers", &value)
        .map_err(|e| ServiceError::ZenohConfig(format!("aggregation/publishers = {value}: {e}")))
}

/// Awaits one teardown step for at most `limit`. `None`, with a warning naming the step, when it
/// did not finish in time: the step is abandoned and the teardown goes on, so a peer that stopped
/// answering cannot hold a shutdown forever.
pub(crate) async fn bounded<T>(
    step: &str,
    limit: Duration,
    future: impl IntoFuture<Output = T>,
) -> Option<T> {
    let outcome = tokio::time::timeout(limit, future).await.ok();
    if outcome.is_none() {
        warn!(
            step,
            limit_s = limit.as_secs_f64(),
            "teardown step did not finish in time: abandoned"
        );
    }
    outcome
}

/// Runs the service until `shutdown` completes, then tears down in order: stop intake, finish
/// every twin (final metrics for every robot), undeclare, close the session.
pub async fn serve(
    config: ServiceConfig,
    shutdown: impl Future<Output = ()>,
) -> Result<ServeReport, ServiceError> {
    // Bound first: an address in use fails the start before anything joins the mesh.
    let http_listener = bind_http(config.http_listen).await?;
    let mut zenoh_config = zenoh_config_of(&config.zenoh)?;
    let prefix = config.key_prefix.clone();
    // The outputs at the sample rate, one publisher per tracked robot on each.
    aggregate_publishers(
        &mut zenoh_config,
        &[
            format!("{prefix}/pose/**"),
            format!("{prefix}/deviation/**"),
        ],
    )?;
    let session = zenoh::open(zenoh_config).await?;
    info!(
        zid = %session.zid(),
        mode = %config.zenoh.mode,
        listen = ?config.zenoh.listen,
        connect = ?config.zenoh.connect,
        prefix = %config.key_prefix,
        "armtwin serving"
    );
    let (control_tx, control_rx) = channel::<Control>();
    let declarer = Declarer::new(
        session.clone(),
        prefix.clone(),
        config.encoding,
        config.pose_congestion,
        Arc::new(config.ros2_pose.clone()),
    );
    let twin = Arc::new(SharedTwin::new(&config, &declarer, control_tx.clone()));
    let snapshots = config.snapshots.as_ref().map(|settings| {
        (
            SnapshotStore::new(&settings.state_dir, &prefix),
            settings.period,
        )
    });
    let control = Control::thread(
        twin.clone(),
        declarer,
        control_rx,
        (config.metrics_period, config.self_calibration),
        snapshots.clone(),
    )?;
    if let Some((store, _)) = &snapshots {
        restore_snapshot(store, &twin, &config);
    }

    let intake = match declare_intake(&session, &prefix, &config, &twin).await {
        Ok(intake) => intake,
        Err(e) => {
            let _ = control_tx.send(Control::Stop);
            bounded(
                "stopping the control thread",
                TEARDOWN_STEP * 4,
                tokio::task::spawn_blocking(move || control.join()),
            )
            .await;
            bounded("closing the session", TEARDOWN_STEP, session.close()).await;
            return Err(e);
        }
    };

    let view = TwinView {
        twin: Arc::clone(&twin),
    };
    let dashboard = http_listener.map(|listener| dashboard::Dashboard::start(listener, view));

    shutdown.await;
    if let Some(dashboard) = dashboard {
        dashboard.stop().await;
    }
    info!("shutting down: stopping intake");
    intake.undeclare().await;
    // Samples that arrive after this are ignored: the control thread finishes the pipeline.
    let _ = control_tx.send(Control::Stop);
    let report = match bounded(
        "finishing the pipeline and undeclaring the robots' outputs",
        TEARDOWN_STEP * 4,
        tokio::task::spawn_blocking(move || control.join()),
    )
    .await
    {
        Some(Ok(Ok(report))) => Ok(report),
        Some(Ok(Err(_))) => Err(ServiceError::Worker(
            "the control thread panicked".to_owned(),
        )),
        Some(Err(e)) => Err(ServiceError::Worker(e.to_string())),
        None => Err(ServiceError::Worker(
            "the control thread did not stop in time".to_owned(),
        )),
    };
    // Closed even when the control thread failed: the session's links go down either way.
    if let Some(Err(e)) = bounded("closing the session", TEARDOWN_STEP, session.close()).await {
        warn!(error = %e, "closing the session failed");
    }
    let report = report?;
    info!(
        inputs = report.inputs,
        poses = report.poses,
        robots = report.robots,
        publish_errors = report.publish_errors,
        "armtwin stopped"
    );
    Ok(report)
}

/// The dashboard's listener, if `[http] listen` asks for one.
async fn bind_http(
    address: Option<std::net::SocketAddr>,
) -> Result<Option<tokio::net::TcpListener>, ServiceError> {
    let Some(address) = address else {
        return Ok(None);
    };
    tokio::net::TcpListener::bind(address)
        .await
        .map(Some)
        .map_err(|source| ServiceError::HttpListen { address, source })
}

/// The subscribers and queryables that feed the twin.
struct Intake {
    subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    queryables: Vec<zenoh::query::Queryable<()>>,
}

impl Intake {
    /// Undeclares every subscriber and queryable, each within [`TEARDOWN_STEP`].
    async fn undeclare(self) {
        for subscriber in self.subscribers {
            let step = format!("undeclaring the subscriber on {}", subscriber.key_expr());
            if let Some(Err(e)) = bounded(&step, TEARDOWN_STEP, subscriber.undeclare()).await {
                warn!(error = %e, step, "undeclaring failed");
            }
        }
        for queryable in self.queryables {
            let step = format!("undeclaring the queryable on {}", queryable.key_expr());
            if let Some(Err(e)) = bounded(&step, TEARDOWN_STEP, queryable.undeclare()).await {
                warn!(error = %e, step, "undeclaring failed");
            }
        }
    }
}

async fn declare_intake(
    session: &Session,
    prefix: &str,
    config: &ServiceConfig,
    twin: &Arc<SharedTwin>,
) -> Result<Intake, ServiceError> {
    let mut subscribers = Vec::new();
    let mut queryables = vec![claim_shard(session, prefix, &config.shard).await?];
    let shard = &config.shard;
    let joints = twin.clone();
    subscribers.push(
        session
            .declare_subscriber(format!("{prefix}/joints/{shard}"))
            .callback(move |sample| joints.joints(&sample))
            .await?,
    );
    let measured = twin.clone();
    subscribers.push(
        session
            .declare_subscriber(format!("{prefix}/measured/{shard}"))
            .callback(move |sample| measured.measured(&sample))
            .await?,
    );
    for (robot, settings) in &config.robots {
        // A configured robot is in the directory from the start: its sensors' samples need no
        // look-up at all.
        let Some(handle) = twin.read_robots().find(robot).cloned() else {
            continue;
        };
        for (index, sensor) in settings.sensors.iter().enumerate() {
            check_sensor_key(prefix, robot, &sensor.key_expr)?;
            let sensor_twin = twin.clone();
            let robot = handle.clone();
            subscribers.push(
                session
                    .declare_subscriber(sensor.key_expr.clone())
                    .callback(move |sample| sensor_twin.sensor(&robot, index, &sample))
                    .await?,
            );
        }
    }
    declare_sources(session, config, twin, &mut subscribers).await?;
    let queries: [(&str, QueryHandler); 5] = [
        ("state", SharedTwin::state),
        ("fk", SharedTwin::fk),
        ("reset", SharedTwin::reset),
        ("ik", SharedTwin::ik),
        ("calibrate", SharedTwin::calibrate),
    ];
    for (stream, handler) in queries {
        let query_twin = twin.clone();
        queryables.push(
            session
                .declare_queryable(format!("{prefix}/{stream}/{shard}"))
                .callback(move |query| query_twin.query(&query, handler))
                .await?,
        );
    }
    Ok(Intake {
        subscribers,
        queryables,
    })
}

/// How long an instance waits for the others' shard claims at start.
const SHARD_CLAIM_WAIT: Duration = Duration::from_secs(2);

/// Claims `[service] robots` on the mesh: a queryable `<prefix>/shards/<zid>` answers this
/// instance's key expression, declared before asking the others' so that of two instances
/// starting together at least the later one sees the earlier. Fails when another instance's
/// key expression intersects this one's.
async fn claim_shard(
    session: &Session,
    prefix: &str,
    shard: &KeyExpr<'static>,
) -> Result<zenoh::query::Queryable<()>, ServiceError> {
    let zid = session.zid().to_string();
    let claim = serde_json::json!({ "robots": shard.as_str(), "zid": zid }).to_string();
    let claim_key = KeyExpr::try_from(format!("{prefix}/shards/{zid}"))?;
    let reply_key = claim_key.clone();
    let queryable = session
        .declare_queryable(claim_key)
        .callback(move |query| {
            if let Err(e) = query
                .reply(reply_key.clone(), claim.clone())
                .encoding(Encoding::APPLICATION_JSON)
                .wait()
            {
                warn!(error = %e, "shard claim reply failed");
            }
        })
        .await?;
    let replies = session
        .get(format!("{prefix}/shards/**"))
        .allowed_destination(Locality::Remote)
        .timeout(SHARD_CLAIM_WAIT)
        .await?;
    while let Ok(reply) = replies.recv_async().await {
        let Ok(sample) = reply.result() else { continue };
        let text = sample.payload().try_to_string().unwrap_or_default();
        let claim: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
        let other = claim.get("robots").and_then(serde_json::Value::as_str);
        let Some(other_key) = other.and_then(|other| KeyExpr::try_from(other).ok()) else {
            warn!(key = %sample.key_expr(), "a shard claim that names no key expression: ignored");
            continue;
        };
        if other_key.intersects(shard) {
            let zid = claim.get("zid").and_then(serde_json::Value::as_str);
            return Err(ServiceError::ShardOverlap {
                own: shard.to_string(),
                other: other_key.to_string(),
                zid: zid.unwrap_or("?").to_owned(),
            });
        }
        debug!(other = %other_key, "another instance's robots, disjoint from this one's");
    }
    info!(robots = %shard, "robots claimed");
    Ok(queryable)
}

/// Restores the twins of the snapshot in `store`, if there is one, before any input arrives.
/// The file is taken whole or not at all: when it is damaged, of another format or service, or
/// names a robot this instance may not track (or of another arm), it is set aside with a
/// warning naming why, and the service starts fresh.
fn restore_snapshot(store: &SnapshotStore, twin: &SharedTwin, config: &ServiceConfig) {
    let path = store.path().display().to_string();
    let refuse = |error: &SnapshotError| match store.set_aside() {
        Ok(aside) => warn!(
            %error,
            kept_as = %aside.display(),
            "snapshot refused: starting fresh"
        ),
        Err(e) => warn!(%error, set_aside_error = %e, "snapshot refused: starting fresh"),
    };
    let records = match store.load() {
        Ok(Some(records)) => records,
        Ok(None) => {
            info!(%path, "no snapshot yet: starting fresh");
            return;
        }
        Err(e) => {
            refuse(&e);
            return;
        }
    };
    let foreign = |problem: String| SnapshotError::Foreign {
        path: path.clone(),
        problem,
    };
    let mut robots: Vec<(Robot, &TwinRecord)> = Vec::with_capacity(records.len());
    for record in &records {
        let id = record.robot.as_str();
        if !config.owns(id) {
            refuse(&foreign(format!(
                "robot '{id}' is outside service.robots '{}'",
                config.shard
            )));
            return;
        }
        let mut directory = twin.robots.write().unwrap_or_else(PoisonError::into_inner);
        let Ok(robot) = directory.admit(id) else {
            drop(directory);
            refuse(&foreign(format!(
                "robot '{id}' is not configured and service.reject_unknown is true"
            )));
            return;
        };
        robots.push((robot.clone(), record));
    }
    // Every twin is built before any is installed: one foreign record (or a robot recorded
    // twice) refuses the whole file, before any twin exists.
    let mut restored: Vec<Twin> = Vec::with_capacity(robots.len());
    for (robot, record) in robots {
        if restored
            .iter()
            .any(|twin| twin.robot().index() == robot.index())
        {
            let twice = RestoreError::AlreadyTracked {
                robot: robot.id().to_owned(),
            };
            refuse(&foreign(twice.to_string()));
            return;
        }
        match Twin::restored(robot, &config.pipeline, record) {
            Ok(twin) => restored.push(twin),
            Err(e) => {
                refuse(&foreign(e.to_string()));
                return;
            }
        }
    }
    let count = restored.len();
    for restored in restored {
        let entry = twin.entry(restored.robot());
        let mut guard = entry.lock();
        let state = &mut *guard;
        if state.twin.is_some() {
            let error = RestoreError::AlreadyTracked {
                robot: entry.robot.id().to_owned(),
            };
            warn!(robot = entry.robot.id(), %error, "twin not restored");
            continue;
        }
        RobotSink::of(&twin.output, &mut state.outputs).tracking(&entry.robot);
        state.twin = Some(restored);
    }
    info!(%path, robots = count, "twins restored from the snapshot");
}

/// Writes the snapshot of every tracked twin: each robot's record taken under its own lock,
/// one robot at a time, and the file written after.
fn save_snapshot(twin: &SharedTwin, store: &SnapshotStore) {
    let records: Vec<TwinRecord> = twin
        .entries()
        .iter()
        .filter_map(|entry| entry.lock().twin.as_ref().map(Twin::record))
        .collect();
    match store.save(&records) {
        Ok(()) => {
            *twin
                .snapshot_written
                .lock()
                .unwrap_or_else(PoisonError::into_inner) = Some(Instant::now());
            debug!(robots = records.len(), "snapshot written");
        }
        Err(e) => warn!(error = %e, "snapshot not written"),
    }
}

/// Refuses a sensor key expression that would receive armtwin's own outputs: a local put is
/// delivered in the publishing thread, which already holds the publishing robot's lock.
fn check_sensor_key(prefix: &str, robot: &str, key_expr: &str) -> Result<(), ServiceError> {
    let sensor = KeyExpr::try_from(key_expr)?;
    for stream in Stream::ALL {
        let output = KeyExpr::try_from(format!("{prefix}/{}/**", stream.as_str()))?;
        if sensor.intersects(&output) {
            return Err(ServiceError::SensorKeyLoop {
                robot: robot.to_owned(),
                key_expr: key_expr.to_owned(),
                output: output.to_string(),
            });
        }
    }
    Ok(())
}

/// One subscriber per `[[sources]]` entry (their keys were checked when the configuration
/// loaded: outside armtwin's own keys and twin pose outputs, disjoint from each other).
async fn declare_sources(
    session: &Session,
    config: &ServiceConfig,
    twin: &Arc<SharedTwin>,
    subscribers: &mut Vec<zenoh::pubsub::Subscriber<()>>,
) -> Result<(), ServiceError> {
    for (index, source) in config.sources.iter().enumerate() {
        let intake = Arc::new(SourceIntake {
            index,
            config: source.clone(),
        });
        let source_twin = twin.clone();
        subscribers.push(
            session
                .declare_subscriber(source.key_expr.clone())
                .callback(move |sample| source_twin.source(&intake, &sample))
                .await?,
        );
        info!(
            key = %source.key_expr,
            codec = source.codec.as_str(),
            stream = source.stream.as_str(),
            "source subscribed"
        );
    }
    Ok(())
}

/// A `[[sources]]` entry as the service runs it.
struct SourceIntake {
    /// Its place in `[[sources]]`: what a robot's entry keys the source's sequence numbers by.
    index: usize,
    config: SourceConfig,
}

impl SourceIntake {
    /// The gateway `seq` of a joint sample of `robot` with `attachment`; `by_source` is the
    /// robot's [`EntryState::publisher_seqs`], so only the robot's own lock is held.
    fn gateway_seq(
        &self,
        robot: &Robot,
        attachment: &Attachment,
        by_source: &mut Vec<(usize, PublisherSeq)>,
    ) -> u64 {
        let known = by_source
            .iter()
            .position(|(source, _)| *source == self.index);
        let position = known.unwrap_or_else(|| {
            by_source.push((self.index, PublisherSeq::default()));
            by_source.len() - 1
        });
        let (seq, changed) = by_source[position].1.gateway_seq(attachment);
        if changed {
            info!(
                robot = robot.id(),
                key = %self.config.key_expr,
                sequence_number = attachment.sequence_number,
                "another ROS publisher (gid): its sequence numbers carry on from the previous one's"
            );
        }
        seq
    }
}

fn unix_now_ns() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
}

fn unix_now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// The stamp of a message without its own: the Zenoh timestamp, else the arrival time (read only
/// for such a message: most carry `t`, and a clock read per message adds up).
fn transport_stamp_s(sample: &Sample) -> f64 {
    sample
        .timestamp()
        .map_or_else(unix_now_s, |t| t.get_time().as_secs_f64())
}

/// The robot id in `key` after `<prefix>/<stream>/`, if it is a plain key (a put on a wildcard
/// key expression names no robot, and must not become one).
fn robot_of<'k>(prefix: &str, key: &'k str, stream: &str) -> Option<&'k str> {
    key.strip_prefix(prefix)?
        .strip_prefix('/')?
        .strip_prefix(stream)?
        .strip_prefix('/')
        .filter(|robot| !robot.is_empty() && !robot.contains(['*', '$']))
}

/// Answers one kind of query; each handler locks the robots it reads one at a time.
type QueryHandler = fn(&SharedTwin, &Query);

/// The twin shared by Zenoh's callbacks and the control thread: every robot's twin and outputs
/// behind a lock of its own ([`RobotEntry`]).
///
/// Samples are processed in Zenoh's receive callback itself, as the plain echo does: decode, FK,
/// statistics and the outputs' `put` take a few microseconds, and doing them there saves a queue,
/// a thread wake-up and a copy per sample. Backpressure is Zenoh's own: while the callback works,
/// its link is not read.
///
/// A sample finds its robot in `robots` under a read lock (one hash of the id; a robot under the
/// default settings is admitted, under the write lock, on its first input), then the robot's
/// entry in `entries` under that vector's read lock (added, under its write lock, on the robot's
/// first input), and clones the entry's `Arc` out: no shared lock is held while it decodes
/// against the entry's robot and steps the twin under the entry's own lock. Samples of different
/// robots never wait on each other's processing; samples of one robot take turns on its lock.
///
/// Lock order: `robots` (read), then `entries` (read), then one robot entry. Nothing that holds
/// a robot entry takes `robots`, `entries`' write lock or another robot's entry; under an entry
/// only leaf locks are taken, briefly and never across a `put` (the untracked robots' event
/// bucket). Nothing that can wait on the network runs under a robot's lock except its own
/// outputs' `put` (events and metrics with `block` congestion control, as the echo): a
/// subscriber that stops reading them stalls that robot and the Zenoh link's receive thread its
/// input arrived on, not the other robots. Declarations are made on the control thread.
struct SharedTwin {
    prefix: String,
    /// `[service] robots`.
    shard: KeyExpr<'static>,
    pipeline: PipelineConfig,
    robots: RwLock<RobotDirectory>,
    /// By robot index, from the robot's first input (or its restored twin) on.
    entries: RwLock<Vec<Option<Arc<RobotEntry>>>>,
    /// What every robot's outputs share.
    output: Output,
    /// Inputs (samples and queries) processed.
    inputs: AtomicU64,
    /// Set by the control thread before it finishes the twins, each under its robot's lock:
    /// an input that takes a robot's lock after its twin was finished sees it and is ignored.
    stopped: AtomicBool,
    /// When the snapshot was last written (with `state_dir`).
    snapshot_written: Mutex<Option<Instant>>,
}

/// One robot's place in the service: its handle, readable without a lock, beside the lock of
/// everything of it that changes.
struct RobotEntry {
    robot: Robot,
    state: Mutex<EntryState>,
}

impl RobotEntry {
    fn lock(&self) -> MutexGuard<'_, EntryState> {
        // A panic in a callback leaves the twin as consistent as each step left it; keep going.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// A robot's twin, its outputs' state and its self-calibration; behind its [`RobotEntry`]'s lock.
#[derive(Default)]
struct EntryState {
    /// `None` until the robot's first input; its creation announces the robot
    /// ([`Sink::tracking`]).
    twin: Option<Twin>,
    outputs: RobotOutputState,
    calibration: CalibrationSlot,
    /// By `[[sources]]` index: how a ROS source's `rmw_zenoh` sequence numbers become gateway
    /// `seq`s (a robot has one or two sources at most: a short list beats a map).
    publisher_seqs: Vec<(usize, PublisherSeq)>,
}

/// One robot's twin locked for an input, with what the input's step needs beside it.
struct Stepping<'a> {
    twin: &'a mut Twin,
    sink: RobotSink<'a>,
    publisher_seqs: &'a mut Vec<(usize, PublisherSeq)>,
}

impl EntryState {
    /// The robot's twin (created, and the robot announced, on its first input) and a sink of its
    /// outputs: the twin and the sink borrow separate parts of the entry.
    fn stepping<'a>(
        &'a mut self,
        robot: &Robot,
        config: &PipelineConfig,
        output: &'a Output,
    ) -> Stepping<'a> {
        let mut sink = RobotSink::of(output, &mut self.outputs);
        let twin = self.twin.get_or_insert_with(|| {
            sink.tracking(robot);
            Twin::new(robot.clone(), config)
        });
        Stepping {
            twin,
            sink,
            publisher_seqs: &mut self.publisher_seqs,
        }
    }
}

impl SharedTwin {
    /// No robot tracked yet; outputs go out through `declarer`, and new robots are handed to the
    /// control thread (`control`) to declare.
    fn new(config: &ServiceConfig, declarer: &Declarer, control: Sender<Control>) -> Self {
        Self {
            prefix: config.key_prefix.clone(),
            shard: config.shard.clone(),
            pipeline: config.pipeline,
            robots: RwLock::new(RobotDirectory::new(
                config.default_robot.clone(),
                config.robots.clone(),
            )),
            entries: RwLock::new(Vec::new()),
            output: Output {
                declarer: declarer.clone(),
                control,
                event_budget: config.event_budget,
                untracked_bucket: Mutex::new(EventBucket::full(
                    config.event_budget,
                    Instant::now(),
                )),
                poses: AtomicU64::new(0),
                publish_errors: AtomicU64::new(0),
            },
            inputs: AtomicU64::new(0),
            stopped: AtomicBool::new(false),
            snapshot_written: Mutex::new(None),
        }
    }

    fn read_robots(&self) -> RwLockReadGuard<'_, RobotDirectory> {
        // The directory only grows, one whole entry at a time: a panic cannot leave half of one.
        self.robots.read().unwrap_or_else(PoisonError::into_inner)
    }

    /// Robot `index`'s entry, if it has one.
    fn existing_entry(&self, index: RobotIndex) -> Option<Arc<RobotEntry>> {
        // Grows only, one whole entry at a time, like the directory.
        let entries = self.entries.read().unwrap_or_else(PoisonError::into_inner);
        entries.get(index.get())?.clone()
    }

    /// `robot`'s entry, added on first use.
    fn entry(&self, robot: &Robot) -> Arc<RobotEntry> {
        if let Some(entry) = self.existing_entry(robot.index()) {
            return entry;
        }
        let mut entries = self.entries.write().unwrap_or_else(PoisonError::into_inner);
        let index = robot.index().get();
        if entries.len() <= index {
            entries.resize_with(index + 1, || None);
        }
        Arc::clone(entries[index].get_or_insert_with(|| {
            Arc::new(RobotEntry {
                robot: robot.clone(),
                state: Mutex::new(EntryState::default()),
            })
        }))
    }

    /// Every robot's entry, in index order: taken out so the robots can be locked one by one.
    fn entries(&self) -> Vec<Arc<RobotEntry>> {
        let entries = self.entries.read().unwrap_or_else(PoisonError::into_inner);
        entries.iter().flatten().cloned().collect()
    }

    /// `entry`'s state, locked, unless the service stopped (checked under the lock: the control
    /// thread finishes each twin under its lock once `stopped` is set).
    fn unless_stopped<'e>(&self, entry: &'e RobotEntry) -> Option<MutexGuard<'e, EntryState>> {
        let guard = entry.lock();
        (!self.stopped.load(Ordering::Acquire)).then_some(guard)
    }

    /// `entry`'s state for one more input, unless the service stopped.
    fn running<'e>(&self, entry: &'e RobotEntry) -> Option<MutexGuard<'e, EntryState>> {
        let guard = self.unless_stopped(entry)?;
        self.inputs.fetch_add(1, Ordering::Relaxed);
        Some(guard)
    }

    /// Steps `entry`'s twin with one input under the robot's lock alone, unless the service
    /// stopped.
    fn step(&self, entry: &RobotEntry, input: impl FnOnce(Stepping<'_>)) {
        if let Some(mut guard) = self.running(entry) {
            input(guard.stepping(&entry.robot, &self.pipeline, &self.output));
        }
    }

    /// One input of robot `id`, arrived on `key`, decoded with `decoder` and stepped into the
    /// robot's twin: the one intake path of every sample (armtwin's own keys, sensors' and
    /// `[[sources]]`', whatever the codec). The robot is found under the read locks or, on its
    /// first input, admitted under the default settings; the input of a robot that may not be
    /// tracked is rejected as such, at the stamp the decoder finds in it, instead.
    ///
    /// `fallback_s` gives the stamp of a message without one (read only then). `transport` sees
    /// the decoded message under the robot's lock before it is stepped: what the transport adds
    /// to it (`rmw_zenoh`'s attachment).
    #[allow(
        clippy::too_many_arguments,
        reason = "one input: who, where, how, and its bytes"
    )]
    fn intake<D: Decoder>(
        &self,
        id: &str,
        key: &str,
        stream: MeasuredStream,
        decoder: &D,
        payload: &[u8],
        fallback_s: impl FnOnce() -> f64,
        transport: impl FnOnce(&mut Stepping<'_>, &mut Decoded<D::Message, D::Error>),
    ) {
        let found = {
            let robots = self.read_robots();
            match robots.find(id) {
                Some(robot) => Ok(self.entry(robot)),
                None => Err(robots.admits_unlisted()),
            }
        };
        let admits_unlisted = match found {
            Ok(entry) => {
                let arrival = Arrival { key, stream };
                self.decode_and_step(&entry, arrival, decoder, payload, fallback_s, transport);
                return;
            }
            Err(admits_unlisted) => admits_unlisted,
        };
        // Inputs of another instance's robots reach this one only through a `[[sources]]` key
        // that covers several shards: they are that instance's to take.
        if !crate::config::owns(&self.shard, id) {
            debug!(robot = id, %key, "robot of another instance: ignored");
            return;
        }
        // Made-up ids of a service that rejects unknown robots never take the write lock.
        let admitted = admits_unlisted
            && self
                .robots
                .write()
                .unwrap_or_else(PoisonError::into_inner)
                .admit(id)
                .is_ok();
        if !admitted {
            if !self.stopped.load(Ordering::Acquire) {
                self.inputs.fetch_add(1, Ordering::Relaxed);
                let mut sink = RobotSink::untracked(&self.output);
                gateway::unknown_robot(id, key, decoder, payload, fallback_s, &mut sink);
            }
            return;
        }
        let entry = self.read_robots().find(id).map(|robot| self.entry(robot));
        if let Some(entry) = entry {
            let arrival = Arrival { key, stream };
            self.decode_and_step(&entry, arrival, decoder, payload, fallback_s, transport);
        }
    }

    /// Decodes an input against `entry`'s robot before taking its lock, then steps the twin
    /// with it under that lock alone.
    fn decode_and_step<D: Decoder>(
        &self,
        entry: &RobotEntry,
        arrival: Arrival<'_>,
        decoder: &D,
        payload: &[u8],
        fallback_s: impl FnOnce() -> f64,
        transport: impl FnOnce(&mut Stepping<'_>, &mut Decoded<D::Message, D::Error>),
    ) {
        let mut message = Decoded::decode(decoder, &entry.robot, payload, fallback_s);
        self.step(entry, |mut locked| {
            transport(&mut locked, &mut message);
            message.step(locked.twin, arrival, &mut locked.sink);
        });
    }

    fn joints(&self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        let Some(id) = robot_of(&self.prefix, key, "joints") else {
            warn!(%key, "joint sample without a robot id in its key: ignored");
            return;
        };
        let decoder = gateway::Joints(ingest::codec_of(sample.encoding()));
        let payload = sample.payload().to_bytes();
        let fallback_s = || transport_stamp_s(sample);
        let stream = MeasuredStream::Robot;
        self.intake(id, key, stream, &decoder, &payload, fallback_s, |_, _| {});
    }

    fn measured(&self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        let Some(id) = robot_of(&self.prefix, key, "measured") else {
            warn!(%key, "measured pose without a robot id in its key: ignored");
            return;
        };
        let decoder = gateway::Pose(ingest::codec_of(sample.encoding()));
        let payload = sample.payload().to_bytes();
        let fallback_s = || transport_stamp_s(sample);
        let stream = MeasuredStream::Robot;
        self.intake(id, key, stream, &decoder, &payload, fallback_s, |_, _| {});
    }

    /// A pose of one of `robot`'s sensors: the robot is the sensor's, resolved when its key was
    /// declared.
    fn sensor(&self, robot: &Robot, index: usize, sample: &Sample) {
        let arrival = Arrival {
            key: sample.key_expr().as_str(),
            stream: MeasuredStream::Sensor(index),
        };
        let decoder = gateway::Pose(ingest::codec_of(sample.encoding()));
        let payload = sample.payload().to_bytes();
        let fallback_s = || transport_stamp_s(sample);
        let entry = self.entry(robot);
        self.decode_and_step(&entry, arrival, &decoder, &payload, fallback_s, |_, _| {});
    }

    /// A sample of a `[[sources]]` entry: its robot from the source (fixed, or the key's ROS
    /// namespace), decoded with the source's codec, stepped like the built-in inputs.
    fn source(&self, source: &SourceIntake, sample: &Sample) {
        let key = sample.key_expr().as_str();
        let id = match &source.config.robot {
            SourceRobot::Fixed(id) => id.as_str(),
            SourceRobot::FromKey(rule) => {
                let Some(id) = rule.robot_of(key) else {
                    warn!(
                        %key,
                        source = %source.config.key_expr,
                        topic = rule.topic(),
                        "sample whose key names no robot (no ROS namespace before the topic, or \
                         another type): ignored"
                    );
                    return;
                };
                id
            }
        };
        let payload = sample.payload().to_bytes();
        let stream = MeasuredStream::Robot;
        let Some(ros2) = &source.config.ros2 else {
            let fallback_s = || transport_stamp_s(sample);
            let codec = match (source.config.codec, source.config.stream) {
                (SourceCodec::ZenohSerialized, SourceStream::Joints) => {
                    Codec::ZenohSerialized(Some(zser::Schema::Joints))
                }
                (SourceCodec::ZenohSerialized, SourceStream::Measured) => {
                    Codec::ZenohSerialized(Some(zser::Schema::Pose))
                }
                _ => ingest::codec_of(sample.encoding()),
            };
            match source.config.stream {
                SourceStream::Joints => {
                    let decoder = gateway::Joints(codec);
                    self.intake(id, key, stream, &decoder, &payload, fallback_s, |_, _| {});
                }
                SourceStream::Measured => {
                    let decoder = gateway::Pose(codec);
                    self.intake(id, key, stream, &decoder, &payload, fallback_s, |_, _| {});
                }
            }
            return;
        };
        // ROS 2: `header.stamp` is the source time (else the attachment's source timestamp,
        // else the transport's); the `rmw_zenoh` attachment's sequence number is the gateway
        // `seq` of joint samples, and an attachment that does not parse is rejected on its own
        // while the message still goes in.
        let attachment = match (ros2.scheme, sample.attachment()) {
            (KeyScheme::RmwZenoh, Some(bytes)) => Some(Attachment::parse(&bytes.to_bytes())),
            _ => None,
        };
        let source_stamp_s = attachment
            .as_ref()
            .and_then(|parsed| parsed.as_ref().ok())
            .and_then(Attachment::source_timestamp_s);
        let fallback_s = || source_stamp_s.unwrap_or_else(|| transport_stamp_s(sample));
        let reject_attachment = |locked: &mut Stepping<'_>, stamp_s: f64| {
            if let Some(Err(error)) = &attachment {
                decoded::reject(locked.twin, key, stamp_s, error, &mut locked.sink);
            }
        };
        match source.config.stream {
            SourceStream::Joints => {
                let decoder = cdr::JointStates(&ros2.joint_names);
                self.intake(
                    id,
                    key,
                    stream,
                    &decoder,
                    &payload,
                    fallback_s,
                    |locked, message| {
                        reject_attachment(locked, message.stamp_s());
                        if let (Some(Ok(attachment)), Some(sample)) =
                            (&attachment, message.message_mut())
                        {
                            let by_source = &mut *locked.publisher_seqs;
                            let robot = locked.twin.robot();
                            sample.seq = Some(source.gateway_seq(robot, attachment, by_source));
                        }
                    },
                );
            }
            SourceStream::Measured => {
                let decoder = cdr::PosesStamped {
                    expected_frame: &ros2.base_frame,
                };
                self.intake(
                    id,
                    key,
                    stream,
                    &decoder,
                    &payload,
                    fallback_s,
                    |locked, message| {
                        reject_attachment(locked, message.stamp_s());
                    },
                );
            }
        }
    }

    fn query(&self, query: &Query, handler: QueryHandler) {
        if self.stopped.load(Ordering::Acquire) {
            return;
        }
        self.inputs.fetch_add(1, Ordering::Relaxed);
        handler(self, query);
    }
}

/// Read access to the running twin for the dashboard and `/metrics`: each call copies what it
/// needs out under each robot's own lock in turn, and holds nothing afterwards (no second copy
/// of the state that could drift from it).
#[derive(Clone)]
pub(crate) struct TwinView {
    twin: Arc<SharedTwin>,
}

/// One tracked robot as the fleet page and `/metrics` read it.
#[derive(Debug, Clone)]
pub(crate) struct FleetRow {
    /// The robot id.
    pub(crate) id: Arc<str>,
    /// Its metrics at the read (counters and statistics of the current epoch).
    pub(crate) metrics: MetricsSnapshot,
    /// Position and angle alarms.
    pub(crate) alarms_active: [bool; 2],
    /// Its totals over the service's life (no recent events: the fleet does not show them).
    pub(crate) counts: RobotCounts,
}

/// The service's own totals.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ServiceTotals {
    /// Inputs (samples and queries) processed.
    pub(crate) inputs: u64,
    /// Twin poses published.
    pub(crate) poses: u64,
    /// Outputs Zenoh refused to send.
    pub(crate) publish_errors: u64,
    /// Robots tracked.
    pub(crate) robots: usize,
    /// Seconds since the snapshot was last written, once it has been (with `state_dir`).
    pub(crate) snapshot_age_s: Option<f64>,
}

/// One robot as its page reads it.
pub(crate) struct RobotDetail {
    /// What `get <prefix>/state/<robot>` answers.
    pub(crate) state: wire::StateMessage,
    /// The model the twin runs and the last valid joints, for the link frames.
    pub(crate) model: Arc<RobotModel>,
    /// Its totals and recent events.
    pub(crate) counts: RobotCounts,
}

impl TwinView {
    /// Every tracked robot's row, in id order, and the service's totals.
    pub(crate) fn fleet(&self) -> (ServiceTotals, Vec<FleetRow>) {
        let twin = &self.twin;
        let mut rows: Vec<FleetRow> = twin
            .entries()
            .iter()
            .filter_map(|entry| {
                let guard = entry.lock();
                let state = guard.twin.as_ref()?.state();
                Some(FleetRow {
                    id: Arc::clone(entry.robot.shared_id()),
                    metrics: state.metrics,
                    alarms_active: state.alarms_active,
                    counts: RobotCounts {
                        recent_events: VecDeque::new(),
                        ..guard.outputs.counts.clone()
                    },
                })
            })
            .collect();
        rows.sort_by(|a, b| a.id.cmp(&b.id));
        let totals = ServiceTotals {
            inputs: twin.inputs.load(Ordering::Relaxed),
            poses: twin.output.poses.load(Ordering::Relaxed),
            publish_errors: twin.output.publish_errors.load(Ordering::Relaxed),
            robots: rows.len(),
            snapshot_age_s: twin
                .snapshot_written
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .map(|written| written.elapsed().as_secs_f64()),
        };
        (totals, rows)
    }

    /// Robot `id`'s entry, if it has one.
    fn entry_of(&self, id: &str) -> Option<Arc<RobotEntry>> {
        let index = self.twin.read_robots().find(id)?.index();
        self.twin.existing_entry(index)
    }

    /// Robot `id`'s state, model and recent events, if it is tracked.
    pub(crate) fn robot(&self, id: &str) -> Option<RobotDetail> {
        let entry = self.entry_of(id)?;
        let guard = entry.lock();
        let twin = guard.twin.as_ref()?;
        Some(RobotDetail {
            state: wire::StateMessage::new(&twin.state()),
            model: Arc::clone(twin.model()),
            counts: guard.outputs.counts.clone(),
        })
    }

    /// Robot `id`'s twin pose count (`None` if it is not tracked): changes whenever it moves.
    pub(crate) fn poses_of(&self, id: &str) -> Option<u64> {
        let entry = self.entry_of(id)?;
        let guard = entry.lock();
        guard.twin.as_ref()?;
        Some(guard.outputs.counts.poses)
    }
}

/// Queries: each handler takes the robots it answers about one at a time, each under its own
/// lock, and replies once that lock is released.
impl SharedTwin {
    /// Robots with an entry whose `<prefix>/<stream>/<robot>` key the query's key expression
    /// covers, in id order.
    fn matching_robots(
        &self,
        query: &Query,
        stream: &str,
    ) -> Vec<(Arc<RobotEntry>, KeyExpr<'static>)> {
        let mut robots: Vec<(Arc<RobotEntry>, KeyExpr<'static>)> = self
            .entries()
            .into_iter()
            .filter_map(|entry| {
                let key =
                    KeyExpr::try_from(format!("{}/{stream}/{}", self.prefix, entry.robot.id()))
                        .ok()?;
                query.key_expr().intersects(&key).then_some((entry, key))
            })
            .collect();
        robots.sort_by(|a, b| a.0.robot.id().cmp(b.0.robot.id()));
        robots
    }

    fn reply(query: &Query, key: &KeyExpr<'static>, payload: Vec<u8>) {
        let reply = query
            .reply(key.clone(), payload)
            .encoding(Encoding::APPLICATION_JSON);
        if let Err(e) = reply.wait() {
            warn!(error = %e, %key, "reply failed");
        }
    }

    fn reply_err(query: &Query, message: &str) {
        let body = serde_json::json!({ "error": message }).to_string();
        if let Err(e) = query
            .reply_err(body)
            .encoding(Encoding::APPLICATION_JSON)
            .wait()
        {
            warn!(error = %e, "error reply failed");
        }
    }

    fn state(&self, query: &Query) {
        for (entry, key) in self.matching_robots(query, "state") {
            let payload = entry
                .lock()
                .twin
                .as_ref()
                .map(|twin| wire::to_json_bytes(&wire::StateMessage::new(&twin.state())));
            if let Some(payload) = payload {
                Self::reply(query, &key, payload);
            }
        }
    }

    fn reset(&self, query: &Query) {
        let mut replies = Vec::new();
        for (entry, key) in self.matching_robots(query, "reset") {
            let Some(mut guard) = self.unless_stopped(&entry) else {
                return;
            };
            let state = &mut *guard;
            let Some(twin) = &mut state.twin else {
                continue;
            };
            let snapshot = twin.reset(&mut RobotSink::of(&self.output, &mut state.outputs));
            drop(guard);
            info!(robot = entry.robot.id(), "metrics reset");
            replies.push((key, wire::MetricsMessage::new(&snapshot).to_json_bytes()));
        }
        if replies.is_empty() {
            Self::reply_err(query, "no tracked robot matches this key expression");
        }
        for (key, payload) in replies {
            Self::reply(query, &key, payload);
        }
    }

    /// The robot a per-robot query (`<prefix>/<stream>/<robot id>`) asks about, its current
    /// model and the query's payload; `None` once an error reply says why there are none.
    fn robot_query<'q>(
        &self,
        query: &'q Query,
        stream: &str,
        request: &str,
    ) -> Option<(&'q str, Arc<RobotModel>, Vec<u8>)> {
        let Some(robot) = robot_of(&self.prefix, query.key_expr().as_str(), stream) else {
            Self::reply_err(
                query,
                &format!("ask one robot: <prefix>/{stream}/<robot id> with {request}"),
            );
            return None;
        };
        let Some(model) = self.current_model(robot) else {
            Self::reply_err(query, &format!("robot '{robot}' is not configured"));
            return None;
        };
        let payload = query
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default();
        Some((robot, model, payload))
    }

    fn fk(&self, query: &Query) {
        let key = query.key_expr().as_str();
        let Some((robot, model, payload)) = self.robot_query(query, "fk", "{\"q\": [...]}") else {
            return;
        };
        let joints = match wire::decode_joints(&payload, model.joint_count()) {
            Ok(decoded) => decoded.sample,
            Err(e) => {
                Self::reply_err(query, &e.to_string());
                return;
            }
        };
        match model.pose(&joints.q_rad) {
            Ok(pose) => {
                let Ok(reply_key) = KeyExpr::try_from(key.to_owned()) else {
                    return;
                };
                let frame = model.frame().as_str();
                let message = wire::PoseMessage::new(
                    robot,
                    joints.stamp_s.unwrap_or(0.0),
                    0,
                    frame,
                    &pose.readout(),
                );
                Self::reply(query, &reply_key, message.to_json_bytes());
            }
            Err(e) => Self::reply_err(query, &e.to_string()),
        }
    }

    /// The model robot `id`'s FK runs: its twin's (which an applied calibration replaces), else
    /// the one its settings give it.
    fn current_model(&self, id: &str) -> Option<Arc<RobotModel>> {
        let (index, configured) = {
            let robots = self.read_robots();
            let index = robots.find(id).map(Robot::index);
            let configured = robots
                .settings_for(id)
                .map(|settings| Arc::clone(&settings.model));
            (index, configured)
        };
        let twin_model = index
            .and_then(|index| self.existing_entry(index))
            .and_then(|entry| {
                entry
                    .lock()
                    .twin
                    .as_ref()
                    .map(|twin| Arc::clone(twin.model()))
            });
        twin_model.or(configured)
    }

    /// `<prefix>/ik/<robot>` with `{"pose": [x, y, z, qx, qy, qz, qw], "seed": [...]}`: the joint
    /// configurations that reach the pose with the robot's current model.
    fn ik(&self, query: &Query) {
        let key = query.key_expr().as_str();
        let request = "{\"pose\": [x, y, z, qx, qy, qz, qw]}";
        let Some((_, model, payload)) = self.robot_query(query, "ik", request) else {
            return;
        };
        let answer = IkRequest::decode(&payload)
            .and_then(|request| Ok(crate::ik::solve(&model, &request.target, request.seed())?));
        match answer {
            Ok(answer) => {
                let Ok(reply_key) = KeyExpr::try_from(key.to_owned()) else {
                    return;
                };
                Self::reply(
                    query,
                    &reply_key,
                    wire::to_json_bytes(&IkAnswerJson::from(&answer)),
                );
            }
            Err(e) => Self::reply_err(query, &e.to_string()),
        }
    }

    /// `<prefix>/calibrate/<robot>` with `apply`, `discard` or `status` (the default), as the
    /// payload or the selector's `action` parameter.
    fn calibrate(&self, query: &Query) {
        let key = query.key_expr().as_str();
        let Some(id) = robot_of(&self.prefix, key, "calibrate") else {
            Self::reply_err(
                query,
                "ask one robot: <prefix>/calibrate/<robot id> with apply, discard or status",
            );
            return;
        };
        let payload = query
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default();
        let action = query.parameters().get("action").map_or_else(
            || String::from_utf8_lossy(&payload).trim().to_owned(),
            str::to_owned,
        );
        let Some(robot) = self.read_robots().find(id).cloned() else {
            Self::reply_err(query, &format!("robot '{id}' is not tracked"));
            return;
        };
        if robot.settings().self_calibration.is_none() {
            Self::reply_err(
                query,
                &format!(
                    "robot '{id}' does not self-calibrate (self_calibrate = true in its section)"
                ),
            );
            return;
        }
        let Ok(reply_key) = KeyExpr::try_from(key.to_owned()) else {
            return;
        };
        let entry = self.existing_entry(robot.index());
        match action.as_str() {
            "" | "status" => {
                let status = match &entry {
                    Some(entry) => calibration_status(&robot, Some(&*entry.lock())),
                    None => calibration_status(&robot, None),
                };
                Self::reply(query, &reply_key, wire::to_json_bytes(&status));
            }
            "discard" => {
                let discarded =
                    entry.is_some_and(|entry| entry.lock().calibration.pending.take().is_some());
                let body = serde_json::json!({ "robot": id, "discarded": discarded });
                Self::reply(query, &reply_key, body.to_string().into_bytes());
            }
            "apply" => {
                let applied = entry.and_then(|entry| self.apply_estimate(&entry));
                match applied {
                    None => {
                        Self::reply_err(query, &format!("robot '{id}' has no estimate to apply"));
                    }
                    Some(Ok(status)) => {
                        Self::reply(query, &reply_key, wire::to_json_bytes(&status));
                    }
                    Some(Err(e)) => Self::reply_err(query, &e.to_string()),
                }
            }
            other => Self::reply_err(query, &format!("'{other}' is not apply, discard or status")),
        }
    }

    /// Replaces `entry`'s model by its pending estimate's under its lock; `None` if it has no
    /// estimate (or the service stopped).
    fn apply_estimate(
        &self,
        entry: &RobotEntry,
    ) -> Option<Result<CalibrationStatus, ReplaceModelError>> {
        let mut guard = self.unless_stopped(entry)?;
        let state = &mut *guard;
        let pending = state.calibration.pending.take()?;
        let model = Arc::clone(&pending.estimate.model);
        let Some(twin) = &mut state.twin else {
            return Some(Err(ReplaceModelError::NotTracked));
        };
        let replaced =
            twin.replace_model(model, &mut RobotSink::of(&self.output, &mut state.outputs));
        Some(replaced.map(|_| {
            info!(
                robot = entry.robot.id(),
                improvement = pending.estimate.improvement(),
                "self-calibration applied"
            );
            calibration_status(&entry.robot, Some(&*state))
        }))
    }
}

/// What `status` answers for a self-calibrating robot (`state`: its entry's, if it has one).
fn calibration_status(robot: &Robot, state: Option<&EntryState>) -> CalibrationStatus {
    let slot = state.map(|state| &state.calibration);
    let twin = state.and_then(|state| state.twin.as_ref());
    let reservoir = twin.and_then(Twin::reservoir);
    let (train, held_out) = reservoir.map_or((0, 0), self_calibration::PairReservoir::kept);
    let view = twin.map(Twin::state);
    CalibrationStatus {
        robot: robot.id().to_owned(),
        epoch: view.as_ref().map_or(0, |view| view.metrics.epoch),
        calibration: view
            .as_ref()
            .and_then(|view| view.model.calibration())
            .map(|c| c.source_name.clone()),
        offered: reservoir.map_or(0, self_calibration::PairReservoir::offered),
        train_pairs: train,
        held_out_pairs: held_out,
        fits: slot.map_or(0, |slot| slot.fits),
        fitting: slot.is_some_and(|slot| slot.in_flight),
        pending: slot
            .and_then(|slot| slot.pending.as_ref())
            .map(|pending| pending.message.clone()),
        last: slot.and_then(|slot| slot.last.clone()),
    }
}

/// A self-calibrating robot's fits.
#[derive(Debug, Default)]
struct CalibrationSlot {
    /// The estimate waiting to be applied or discarded.
    pending: Option<Pending>,
    /// The last fit's message (an estimate or a refusal).
    last: Option<EstimateMessage>,
    /// Fits made.
    fits: u64,
    /// A fit is running.
    in_flight: bool,
    /// Pairs the reservoir had taken into account at the last fit: none new, no fit.
    fitted_offered: u64,
}

/// An estimate waiting for `apply` or `discard`.
#[derive(Debug)]
struct Pending {
    estimate: Estimate,
    message: EstimateMessage,
}

/// The `status` answer of `<prefix>/calibrate/<robot>`.
#[derive(Debug, serde::Serialize)]
struct CalibrationStatus {
    robot: String,
    /// The metrics epoch.
    epoch: u64,
    /// The source of the calibration the twin runs (`self-calibration` once one was applied).
    calibration: Option<String>,
    offered: u64,
    train_pairs: usize,
    held_out_pairs: usize,
    fits: u64,
    fitting: bool,
    pending: Option<EstimateMessage>,
    last: Option<EstimateMessage>,
}

/// One robot's pairs to fit, taken from its reservoir under its lock and fitted without it.
struct FitJob {
    robot: Robot,
    model: Arc<RobotModel>,
    epoch: u64,
    batch: CalibrationBatch,
}

/// Hands the pairs of every self-calibrating robot with pairs new since its last fit to the
/// fitting thread: each robot's batch copied under its own lock (a few thousand pairs).
fn schedule_fits(twin: &SharedTwin, jobs: &Sender<FitJob>) {
    for entry in twin.entries() {
        if entry.robot.settings().self_calibration.is_none() {
            continue;
        }
        let job = {
            let mut guard = entry.lock();
            let state = &mut *guard;
            let Some(tracked) = &state.twin else {
                continue;
            };
            let Some(reservoir) = tracked.reservoir() else {
                continue;
            };
            let slot = &mut state.calibration;
            if reservoir.offered() <= slot.fitted_offered || slot.in_flight {
                continue;
            }
            let job = FitJob {
                batch: reservoir.batch(),
                model: Arc::clone(tracked.model()),
                epoch: tracked.state().metrics.epoch,
                robot: entry.robot.clone(),
            };
            slot.in_flight = true;
            slot.fitted_offered = job.batch.offered;
            job
        };
        if jobs.send(job).is_err() {
            return;
        }
    }
}

/// Starts the thread that fits self-calibrating robots' pairs, one after another, off the
/// sample path and off the control thread (a fit of thousands of pairs takes longer than many
/// metrics periods); it ends when `jobs` closes.
fn fitting_thread(
    twin: Arc<SharedTwin>,
    jobs: Receiver<FitJob>,
    config: SelfCalibrationConfig,
) -> Result<std::thread::JoinHandle<()>, ServiceError> {
    std::thread::Builder::new()
        .name("armtwin-calibrate".to_owned())
        .spawn(move || {
            for job in jobs {
                let FitJob {
                    robot,
                    model,
                    epoch,
                    batch,
                } = job;
                let fit = self_calibration::fit(&model, &batch, &config.options);
                let message = match &fit {
                    Ok(estimate) => EstimateMessage::estimate(robot.id(), epoch, estimate),
                    Err(e) => EstimateMessage::refused(robot.id(), epoch, &batch, e),
                };
                let payload = wire::to_json_bytes(&message);
                let (message_status, message_improvement) = (message.status, message.improvement);
                {
                    let entry = twin.entry(&robot);
                    let mut guard = entry.lock();
                    let state = &mut *guard;
                    // Judged against a model the twin no longer runs: fit again next period.
                    let current = state
                        .twin
                        .as_ref()
                        .is_some_and(|now| Arc::ptr_eq(now.model(), &model));
                    let slot = &mut state.calibration;
                    slot.in_flight = false;
                    if !current {
                        slot.fitted_offered = 0;
                        continue;
                    }
                    slot.fits += 1;
                    slot.last = Some(message.clone());
                    if let Ok(estimate) = fit {
                        slot.pending = Some(Pending { estimate, message });
                    }
                }
                info!(
                    robot = robot.id(),
                    status = message_status,
                    improvement = message_improvement,
                    offered = batch.offered,
                    "self-calibration fit"
                );
                twin.output
                    .publish(None, robot.id(), Stream::Calibration, payload);
            }
        })
        .map_err(|e| ServiceError::Worker(e.to_string()))
}

/// Publishes the metrics of every robot with new results: each robot's snapshot taken under
/// its own lock, then encoded and sent after it is released, so a robot's samples wait at most
/// for its own snapshot, never for a metrics message's encoding and sending.
fn publish_due_metrics(twin: &SharedTwin) {
    for entry in twin.entries() {
        let snapshot = {
            let mut guard = entry.lock();
            let state = &mut *guard;
            let Some(snapshot) = state.twin.as_mut().and_then(Twin::take_due_metrics) else {
                continue;
            };
            state.outputs.counts.last_active = Some(Instant::now());
            snapshot
        };
        let payload = wire::MetricsMessage::new(&snapshot).to_json_bytes();
        twin.output
            .publish(None, &snapshot.robot, Stream::Metrics, payload);
    }
}

/// Twin poses a robot publishes on plain keys before the control thread declares the
/// publishers (and input keys) that cache its routes. Zenoh computes the route of a put on an
/// undeclared key anew every time; a declaration is paid once, costs in proportion to the keys
/// beside it and holds memory for as long as the robot is tracked: a robot that streams repays
/// it within a few dozen messages, while one that sends now and then never would, so a fleet of
/// mostly quiet robots holds route caches only for the few that stream.
const ROUTE_CACHE_AFTER_POSES: u64 = 64;

/// What the control thread is asked to do.
enum Control {
    /// Declare a newly tracked robot's liveliness token.
    Track(Robot),
    /// Declare the publishers and input keys that cache a streaming robot's routes.
    CacheRoutes(Robot),
    /// Finish the pipeline, undeclare everything and stop.
    Stop,
}

impl Control {
    /// Starts the thread that declares robots' Zenoh entities (never on Zenoh's own threads),
    /// publishes the periodic metrics, and finishes the pipeline at the end.
    fn thread(
        twin: Arc<SharedTwin>,
        declarer: Declarer,
        rx: Receiver<Self>,
        (metrics_period, self_calibration): (Duration, SelfCalibrationConfig),
        snapshots: Option<(SnapshotStore, Duration)>,
    ) -> Result<std::thread::JoinHandle<ServeReport>, ServiceError> {
        let (jobs_tx, jobs_rx) = channel::<FitJob>();
        let fitting = fitting_thread(Arc::clone(&twin), jobs_rx, self_calibration)?;
        std::thread::Builder::new()
            .name("armtwin-control".to_owned())
            .spawn(move || {
                let periods = (metrics_period, self_calibration.refit_period);
                let report =
                    Self::run(&twin, &declarer, &rx, periods, &jobs_tx, snapshots.as_ref());
                // Closing the queue ends the fitting thread after its current fit.
                drop(jobs_tx);
                if fitting.join().is_err() {
                    warn!("the self-calibration thread panicked");
                }
                report
            })
            .map_err(|e| ServiceError::Worker(e.to_string()))
    }

    fn run(
        twin: &SharedTwin,
        declarer: &Declarer,
        rx: &Receiver<Self>,
        (metrics_period, refit_period): (Duration, Duration),
        jobs: &Sender<FitJob>,
        snapshots: Option<&(SnapshotStore, Duration)>,
    ) -> ServeReport {
        let mut next_metrics = Instant::now() + metrics_period;
        let mut next_refit = Instant::now() + refit_period;
        let mut next_snapshot = snapshots.map(|(_, period)| Instant::now() + *period);
        let mut tokens = Vec::new();
        // Streaming robots whose route caches are asked for and not yet declared.
        let mut undeclared = VecDeque::new();
        loop {
            // Every new robot's token before any robot's publishers: each Zenoh declaration
            // costs in proportion to the keys beside it, and a fleet is tracked once its tokens
            // are.
            let wait = if undeclared.is_empty() {
                next_metrics
                    .min(next_refit)
                    .min(next_snapshot.unwrap_or(next_refit))
                    .saturating_duration_since(Instant::now())
            } else {
                Duration::ZERO
            };
            // Declared without the lock: samples keep flowing meanwhile (their outputs go out
            // with an undeclared key until the publishers exist).
            match rx.recv_timeout(wait) {
                Ok(Self::Stop) | Err(RecvTimeoutError::Disconnected) => break,
                Ok(Self::Track(robot)) => match declarer.declare_token(robot.id()) {
                    Ok(token) => {
                        info!(robot = robot.id(), "tracking robot");
                        tokens.push((Arc::clone(robot.shared_id()), token));
                    }
                    Err(e) => {
                        warn!(robot = robot.id(), error = %e, "cannot declare the robot's liveliness token");
                    }
                },
                Ok(Self::CacheRoutes(robot)) => undeclared.push_back(robot),
                Err(RecvTimeoutError::Timeout) => {
                    if let Some(robot) = undeclared.pop_front() {
                        match declarer.declare(robot.id()) {
                            Ok(outputs) => {
                                twin.entry(&robot).lock().outputs.declared = Some(outputs);
                            }
                            Err(e) => {
                                warn!(robot = robot.id(), error = %e, "cannot declare the robot's publishers");
                            }
                        }
                        if undeclared.is_empty() {
                            debug!("every tracked robot's publishers are declared");
                        }
                    }
                }
            }
            let now = Instant::now();
            if now >= next_metrics {
                publish_due_metrics(twin);
                next_metrics = now + metrics_period;
            }
            if now >= next_refit {
                schedule_fits(twin, jobs);
                next_refit = now + refit_period;
            }
            if let (Some(due), Some((store, period))) = (next_snapshot, snapshots)
                && now >= due
            {
                save_snapshot(twin, store);
                next_snapshot = Some(now + *period);
            }
        }
        // Set before any twin is finished: an input that takes a robot's lock after the control
        // thread finished that robot's twin sees it and is ignored.
        twin.stopped.store(true, Ordering::Release);
        let mut robots = 0;
        let mut outputs: Vec<(Arc<str>, RobotOutputs)> = Vec::new();
        for entry in twin.entries() {
            let mut guard = entry.lock();
            let state = &mut *guard;
            if let Some(tracked) = &mut state.twin {
                tracked.finish(&mut RobotSink::of(&twin.output, &mut state.outputs));
                robots += 1;
            }
            if let Some(declared) = state.outputs.declared.take() {
                outputs.push((Arc::clone(entry.robot.shared_id()), declared));
            }
        }
        let report = ServeReport {
            inputs: twin.inputs.load(Ordering::Relaxed),
            poses: twin.output.poses.load(Ordering::Relaxed),
            robots,
            publish_errors: twin.output.publish_errors.load(Ordering::Relaxed),
        };
        if let Some((store, _)) = snapshots {
            save_snapshot(twin, store);
            info!(path = %store.path().display(), "final snapshot written");
        }
        declarer.undeclare_all(outputs, tokens);
        report
    }
}

/// A streaming robot's publishers of its outputs at the sample rate, and its input keys:
/// declared so Zenoh caches their routes (after [`ROUTE_CACHE_AFTER_POSES`]). Its metrics, events and calibration, a few per second at most,
/// go out without a publisher: every declaration costs in proportion to the keys beside it, on
/// this side and on every subscriber's.
struct RobotOutputs {
    pose: Publisher<'static>,
    deviation: Publisher<'static>,
    /// The twin pose as a ROS 2 `PoseStamped`, if the robot has `ros2_pose`.
    ros2_pose: Option<Publisher<'static>>,
    inputs: Vec<KeyExpr<'static>>,
}

/// The output streams of a robot.
#[derive(Debug, Clone, Copy)]
enum Stream {
    Pose,
    Deviation,
    Metrics,
    Events,
    /// Self-calibration estimates: a few per minute.
    Calibration,
}

impl Stream {
    const ALL: [Self; 5] = [
        Self::Pose,
        Self::Deviation,
        Self::Metrics,
        Self::Events,
        Self::Calibration,
    ];

    fn as_str(self) -> &'static str {
        match self {
            Self::Pose => "pose",
            Self::Deviation => "deviation",
            Self::Metrics => "metrics",
            Self::Events => "events",
            Self::Calibration => "calibration",
        }
    }

    fn publisher(self, outputs: &RobotOutputs) -> Option<&Publisher<'static>> {
        match self {
            Self::Pose => Some(&outputs.pose),
            Self::Deviation => Some(&outputs.deviation),
            Self::Metrics | Self::Events | Self::Calibration => None,
        }
    }
}

/// Declares and undeclares robots' Zenoh entities.
#[derive(Clone)]
struct Declarer {
    session: Session,
    prefix: String,
    /// The format of poses and deviations.
    encoding: OutputEncoding,
    /// Of poses and deviations.
    pose_congestion: CongestionControl,
    pose_encoding: Encoding,
    deviation_encoding: Encoding,
    /// Which robots publish their twin pose for ROS tools, and where.
    ros2_pose: Arc<PoseOutputs>,
}

impl Declarer {
    fn new(
        session: Session,
        prefix: String,
        encoding: OutputEncoding,
        pose_congestion: Congestion,
        ros2_pose: Arc<PoseOutputs>,
    ) -> Self {
        let (pose_encoding, deviation_encoding) = match encoding {
            OutputEncoding::Json => (Encoding::APPLICATION_JSON, Encoding::APPLICATION_JSON),
            OutputEncoding::ZenohSerialized => (
                Encoding::ZENOH_SERIALIZED.with_schema(zser::TWIN_POSE_SCHEMA),
                Encoding::ZENOH_SERIALIZED.with_schema(zser::DEVIATION_SCHEMA),
            ),
        };
        Self {
            session,
            prefix,
            encoding,
            pose_congestion: match pose_congestion {
                Congestion::Block => CongestionControl::Block,
                Congestion::Drop => CongestionControl::Drop,
            },
            pose_encoding,
            deviation_encoding,
            ros2_pose,
        }
    }

    /// The congestion control and encoding of `stream`: poses and deviations as configured,
    /// metrics and events blocking JSON.
    fn qos(&self, stream: Stream) -> (CongestionControl, Encoding) {
        match stream {
            Stream::Pose => (self.pose_congestion, self.pose_encoding.clone()),
            Stream::Deviation => (self.pose_congestion, self.deviation_encoding.clone()),
            Stream::Metrics | Stream::Events | Stream::Calibration => {
                (CongestionControl::Block, Encoding::APPLICATION_JSON)
            }
        }
    }

    fn key(&self, stream: &str, robot: &str) -> String {
        format!("{}/{stream}/{robot}", self.prefix)
    }

    /// Publishes `payload` on `robot`'s `stream`: through its declared publisher, or, until the
    /// control thread has declared it (and for robots that are not tracked), on the plain key.
    /// Returns whether Zenoh took it; a failure is logged here, and counted by the caller.
    fn put(
        &self,
        outputs: Option<&RobotOutputs>,
        robot: &str,
        stream: Stream,
        payload: Vec<u8>,
    ) -> bool {
        let result = if let Some(publisher) = outputs.and_then(|outputs| stream.publisher(outputs))
        {
            publisher.put(payload).wait()
        } else {
            let (congestion, encoding) = self.qos(stream);
            self.session
                .put(self.key(stream.as_str(), robot), payload)
                .congestion_control(congestion)
                .encoding(encoding)
                .wait()
        };
        if let Err(e) = &result {
            warn!(error = %e, %robot, stream = stream.as_str(), "publish failed");
        }
        result.is_ok()
    }

    fn publisher(&self, stream: Stream, robot: &str) -> zenoh::Result<Publisher<'static>> {
        let (congestion, encoding) = self.qos(stream);
        self.session
            .declare_publisher(self.key(stream.as_str(), robot))
            .congestion_control(congestion)
            .encoding(encoding)
            .wait()
    }

    fn declare(&self, robot: &str) -> zenoh::Result<RobotOutputs> {
        let mut inputs = Vec::new();
        for stream in ["joints", "measured"] {
            inputs.push(
                self.session
                    .declare_keyexpr(self.key(stream, robot))
                    .wait()?,
            );
        }
        let pose = self.publisher(Stream::Pose, robot)?;
        let deviation = self.publisher(Stream::Deviation, robot)?;
        let ros2_pose = match self.ros2_pose.of(robot) {
            Some(output) => Some(
                self.session
                    .declare_publisher(output.key(robot))
                    .congestion_control(self.pose_congestion)
                    // Never delivered back into this session's sources, whatever their keys.
                    .allowed_destination(Locality::Remote)
                    .wait()?,
            ),
            None => None,
        };
        Ok(RobotOutputs {
            pose,
            deviation,
            ros2_pose,
            inputs,
        })
    }

    fn declare_token(&self, robot: &str) -> zenoh::Result<LivelinessToken> {
        self.session
            .liveliness()
            .declare_token(self.key("alive", robot))
            .wait()
    }

    fn undeclare_all(
        &self,
        outputs: Vec<(Arc<str>, RobotOutputs)>,
        tokens: Vec<(Arc<str>, LivelinessToken)>,
    ) {
        for (robot, outputs) in outputs {
            let RobotOutputs {
                pose,
                deviation,
                ros2_pose,
                inputs,
            } = outputs;
            for publisher in [pose, deviation].into_iter().chain(ros2_pose) {
                if let Err(e) = publisher.undeclare().wait() {
                    warn!(%robot, error = %e, "undeclaring a publisher failed");
                }
            }
            for key in inputs {
                if let Err(e) = self.session.undeclare(key).wait() {
                    warn!(%robot, error = %e, "undeclaring a key expression failed");
                }
            }
        }
        for (robot, token) in tokens {
            if let Err(e) = token.undeclare().wait() {
                warn!(%robot, error = %e, "undeclaring the liveliness token failed");
            }
        }
    }
}

/// What every robot's outputs share: the session's publishing side and the service's totals.
/// Per-robot output state lives in each robot's entry ([`RobotOutputState`]).
struct Output {
    declarer: Declarer,
    /// Asks the control thread to declare newly tracked robots.
    control: Sender<Control>,
    event_budget: EventBudget,
    /// Shared by the robots that may not be tracked, so a flood of made-up ids cannot grow the
    /// buckets. A leaf lock: held for a bucket's arithmetic only, never across a `put`.
    untracked_bucket: Mutex<EventBucket>,
    /// Twin poses published.
    poses: AtomicU64,
    /// Outputs Zenoh refused to send.
    publish_errors: AtomicU64,
}

impl Output {
    /// Publishes `payload` on `robot`'s `stream` ([`Declarer::put`], through `declared`, the
    /// robot's publishers, when they exist), counting a refusal: every robot output but the
    /// twin pose for ROS tools goes out here.
    fn publish(
        &self,
        declared: Option<&RobotOutputs>,
        robot: &str,
        stream: Stream,
        payload: Vec<u8>,
    ) {
        if !self.declarer.put(declared, robot, stream, payload) {
            self.publish_errors.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// A robot's output state: its publishers, event bucket, twin pose for ROS tools and totals.
#[derive(Default)]
struct RobotOutputState {
    /// Once the control thread has declared them.
    declared: Option<RobotOutputs>,
    /// From tracking on.
    event_bucket: Option<EventBucket>,
    /// From tracking on: the twin pose for ROS tools.
    ros2_pose: Option<Ros2PoseState>,
    /// What the dashboard and `/metrics` read beyond the twin's own state.
    counts: RobotCounts,
}

/// Events kept per robot for the dashboard's robot page.
const RECENT_EVENTS: usize = 10;

/// A robot's totals over the service's life (reset and model replacement do not touch them) and
/// its last published events.
#[derive(Debug, Default, Clone)]
pub(crate) struct RobotCounts {
    /// Twin poses published.
    pub(crate) poses: u64,
    /// Rejected inputs by cause (a handful of causes at most: a short list beats a map).
    pub(crate) rejected_by_cause: Vec<(RejectCause, u64)>,
    /// The last [`RECENT_EVENTS`] published events, oldest first, as published (JSON).
    pub(crate) recent_events: VecDeque<Arc<[u8]>>,
    /// When the control thread last found results of the robot it had not published (to its
    /// metrics period).
    pub(crate) last_active: Option<Instant>,
}

/// A robot's twin pose output for ROS tools, as the sink publishes it.
struct Ros2PoseState {
    /// Its key, for the poses sent before the publisher is declared.
    key: String,
    /// `<tf_prefix>base` or `<tf_prefix>base_link`: the robot's output frame.
    frame_id: String,
    /// `Some` for `rmw_zenoh`: the publisher gid of the attachment.
    gid: Option<[u8; 16]>,
    /// The attachment's next sequence number (from 1, as `rmw_zenoh` counts).
    next_seq: i64,
}

/// A token bucket of events (wall-clock time: it protects subscribers and logs, not statistics).
#[derive(Debug, Clone, Copy)]
struct EventBucket {
    tokens: f64,
    refilled: Instant,
    suppressed: u64,
}

impl EventBucket {
    fn full(budget: EventBudget, now: Instant) -> Self {
        Self {
            tokens: f64::from(budget.burst),
            refilled: now,
            suppressed: 0,
        }
    }

    /// Whether an event may go out now (`always` for the ones that must: alarms, recoveries,
    /// restarts); if not, it is counted as suppressed.
    fn admit(&mut self, budget: EventBudget, now: Instant, always: bool) -> bool {
        let elapsed_s = now.saturating_duration_since(self.refilled).as_secs_f64();
        self.tokens = (self.tokens + elapsed_s * budget.per_s).min(f64::from(budget.burst));
        self.refilled = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else if always {
            true
        } else {
            self.suppressed += 1;
            false
        }
    }
}

/// Publishes one robot's results on Zenoh: made for one call into the twin, from the shared
/// [`Output`] and the robot's own [`RobotOutputState`] (borrowed from the robot's locked entry),
/// or without one for inputs of robots that may not be tracked.
struct RobotSink<'a> {
    output: &'a Output,
    robot: Option<&'a mut RobotOutputState>,
}

impl<'a> RobotSink<'a> {
    fn of(output: &'a Output, robot: &'a mut RobotOutputState) -> Self {
        Self {
            output,
            robot: Some(robot),
        }
    }

    /// For the rejection of a robot that may not be tracked.
    fn untracked(output: &'a Output) -> Self {
        Self {
            output,
            robot: None,
        }
    }

    /// Publishes `payload` on `robot`'s `stream` ([`Output::publish`]).
    fn put(&self, robot: &str, stream: Stream, payload: Vec<u8>) {
        let declared = self
            .robot
            .as_deref()
            .and_then(|state| state.declared.as_ref());
        self.output.publish(declared, robot, stream, payload);
    }

    /// Prepares `robot`'s twin pose output for ROS tools, if it has one.
    fn track_ros2_pose(&mut self, robot: &Robot) {
        let declarer = &self.output.declarer;
        let Some(output) = declarer.ros2_pose.of(robot.id()) else {
            return;
        };
        if output.namespace.is_none()
            && let Err(e) = ros2::relative_ros_name(robot.id(), true)
        {
            warn!(robot = robot.id(), error = %e, "the robot id is its twin pose's ROS namespace, but not a ROS name: ROS nodes cannot subscribe to it (set ros2_pose.namespace)");
        }
        let state = Ros2PoseState {
            key: output.key(robot.id()),
            frame_id: cdr::frame_id(&output.tf_prefix, robot.settings().model.frame()),
            gid: output
                .attaches()
                .then(|| ros2::publisher_gid(&declarer.session.zid().to_le_bytes(), robot.id())),
            next_seq: 1,
        };
        if let Some(robot_state) = self.robot.as_deref_mut() {
            robot_state.ros2_pose = Some(state);
        }
    }

    /// Publishes the twin pose as a CDR `PoseStamped` (with `rmw_zenoh`'s attachment for that
    /// scheme), if `robot` has the output.
    fn put_ros2_pose(&mut self, robot: &Robot, stamp_s: f64, pose: &PoseReadout) {
        let Some(robot_state) = self.robot.as_deref_mut() else {
            return;
        };
        let Some(state) = &mut robot_state.ros2_pose else {
            return;
        };
        let payload = cdr::encode_pose_stamped(stamp_s, &state.frame_id, pose);
        let attachment = state.gid.map(|gid| {
            let seq = state.next_seq;
            state.next_seq += 1;
            ros2::encode_attachment(seq, unix_now_ns(), &gid)
        });
        let publisher = robot_state
            .declared
            .as_ref()
            .and_then(|outputs| outputs.ros2_pose.as_ref());
        let declarer = &self.output.declarer;
        let result = match publisher {
            Some(publisher) => publisher.put(payload).attachment(attachment).wait(),
            None => declarer
                .session
                .put(&state.key, payload)
                .attachment(attachment)
                .congestion_control(declarer.pose_congestion)
                .allowed_destination(Locality::Remote)
                .wait(),
        };
        if let Err(e) = result {
            warn!(error = %e, robot = robot.id(), key = %state.key, "publish failed");
            self.output.publish_errors.fetch_add(1, Ordering::Relaxed);
        }
    }
}

impl Sink for RobotSink<'_> {
    fn tracking(&mut self, robot: &Robot) {
        if let Some(state) = self.robot.as_deref_mut() {
            state.event_bucket = Some(EventBucket::full(self.output.event_budget, Instant::now()));
        }
        self.track_ros2_pose(robot);
        // Fails only once the control thread has stopped, when nothing is declared any more.
        let _ = self.output.control.send(Control::Track(robot.clone()));
    }

    fn pose(
        &mut self,
        robot: &Robot,
        stamp_s: f64,
        seq: u64,
        frame: OutputFrame,
        pose: &PoseReadout,
    ) {
        let payload = match self.output.declarer.encoding {
            OutputEncoding::Json => {
                wire::PoseMessage::new(robot.id(), stamp_s, seq, frame.as_str(), pose)
                    .to_json_bytes()
            }
            OutputEncoding::ZenohSerialized => {
                zser::twin_pose_bytes(stamp_s, seq, &PoseFields::from(pose))
            }
        };
        self.put(robot.id(), Stream::Pose, payload);
        self.output.poses.fetch_add(1, Ordering::Relaxed);
        if let Some(state) = self.robot.as_deref_mut() {
            state.counts.poses += 1;
            if state.counts.poses == ROUTE_CACHE_AFTER_POSES {
                // Fails only once the control thread has stopped.
                let _ = self
                    .output
                    .control
                    .send(Control::CacheRoutes(robot.clone()));
            }
        }
        self.put_ros2_pose(robot, stamp_s, pose);
    }

    fn deviation(
        &mut self,
        robot: &Robot,
        stamp_s: f64,
        _measured: &PoseReadout,
        deviation: &Deviation,
    ) {
        let payload = match self.output.declarer.encoding {
            OutputEncoding::Json => {
                wire::DeviationMessage::new(robot.id(), stamp_s, deviation).to_json_bytes()
            }
            OutputEncoding::ZenohSerialized => zser::deviation_bytes(stamp_s, deviation),
        };
        self.put(robot.id(), Stream::Deviation, payload);
    }

    /// Publishes the event unless its robot's rate limit keeps it back, and logs it once (at
    /// warn for rejections and alarms); a kept-back event is only counted, and formats nothing.
    fn event(&mut self, event: &Event<'_>) {
        let always = matches!(
            event.kind,
            EventKind::Alarm | EventKind::Recovered | EventKind::Restart | EventKind::Epoch
        );
        // An event names its robot's index only when it has a twin, whose entry this sink holds.
        let mut robot_state = self.robot.as_deref_mut().filter(|_| event.index.is_some());
        if let (Some(state), EventDetail::Rejected { cause }) = (&mut robot_state, &event.detail) {
            let by_cause = &mut state.counts.rejected_by_cause;
            match by_cause.iter_mut().find(|(counted, _)| counted == cause) {
                Some((_, count)) => *count += 1,
                None => by_cause.push((*cause, 1)),
            }
        }
        let now = Instant::now();
        let budget = self.output.event_budget;
        // The suppressed count the event carries if it goes out, else how many are suppressed.
        let pass = |bucket: &mut EventBucket| {
            if bucket.admit(budget, now, always) {
                Ok(std::mem::take(&mut bucket.suppressed))
            } else {
                Err(bucket.suppressed)
            }
        };
        let tracked = robot_state
            .as_mut()
            .and_then(|state| state.event_bucket.as_mut());
        let passed = match tracked {
            Some(bucket) => pass(bucket),
            None => pass(
                &mut self
                    .output
                    .untracked_bucket
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner),
            ),
        };
        let suppressed = match passed {
            Ok(suppressed) => suppressed,
            Err(suppressed) => {
                if suppressed == 1 {
                    warn!(robot = %event.robot, per_s = budget.per_s, burst = budget.burst, "event rate limit reached: further events are counted, not published");
                }
                return;
            }
        };
        let mut message = wire::EventMessage::new(event);
        message.suppressed = suppressed;
        let cause = match event.detail {
            EventDetail::Rejected { cause } => Some(cause.as_str()),
            EventDetail::Unpaired { cause, .. } => Some(cause),
            _ => None,
        };
        let payload = wire::to_json_bytes(&message);
        if let Some(state) = robot_state {
            let recent = &mut state.counts.recent_events;
            if recent.len() == RECENT_EVENTS {
                recent.pop_front();
            }
            recent.push_back(Arc::from(payload.as_slice()));
        }
        self.put(event.robot, Stream::Events, payload);
        let (robot, kind, key) = (event.robot, event.kind.as_str(), event.key);
        let reason = message.reason.as_str();
        match event.kind {
            EventKind::Rejected | EventKind::Alarm => {
                warn!(robot, kind, cause, key, reason, "event");
            }
            EventKind::Recovered | EventKind::Restart | EventKind::Epoch => {
                info!(robot, kind, cause, key, reason, "event");
            }
            EventKind::Gap | EventKind::Unpaired => {
                debug!(robot, kind, cause, key, reason, "event");
            }
        }
    }

    fn metrics(&mut self, robot: &Robot, snapshot: &MetricsSnapshot) {
        let message = wire::MetricsMessage::new(snapshot);
        self.put(robot.id(), Stream::Metrics, message.to_json_bytes());
    }
}
