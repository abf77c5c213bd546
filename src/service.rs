//! `armtwin serve`: the pipeline on a Zenoh mesh.
//!
//! Owns the session, the wildcard subscriptions and queryables, the per-robot publishers and
//! liveliness tokens, and the ordered teardown. Zenoh's callbacks only enqueue the sample (or
//! query) into a bounded channel; one worker thread decodes, runs the [`Pipeline`] and publishes,
//! so FK never runs on Zenoh's receive thread and the pipeline needs no lock.
//!
//! Flow control: inputs are received reliably; when the worker falls behind and the queue is
//! full, the callback waits for room (as Zenoh's own FIFO handler does), which backpressures the
//! transport and, through it, the gateways: nothing valid is dropped. Outputs use the configured
//! congestion control (`block` by default: a slow subscriber slows the twin; after Zenoh's
//! `wait_before_close` a subscriber that stopped reading is disconnected; `drop`: the twin never
//! waits and a slow subscriber misses outputs).

use std::collections::HashMap;
use std::future::Future;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, sync_channel};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use thiserror::Error;
use tracing::{debug, info, warn};
use zenoh::Wait;
use zenoh::key_expr::KeyExpr;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::query::Query;
use zenoh::sample::Sample;
use zenoh::session::Session;

use crate::codec::wire;
use crate::config::{Congestion, EventBudget, ServiceConfig, ZenohSection};
use crate::ingest;
use crate::kinematics::{OutputFrame, PoseReadout};
use crate::metrics::Deviation;
use crate::pipeline::{Event, EventKind, MeasuredStream, MetricsSnapshot, Pipeline, Sink};

/// How long each teardown step may take.
const TEARDOWN_STEP: Duration = Duration::from_secs(5);

/// Why the service stopped with an error.
#[derive(Debug, Error)]
pub enum ServiceError {
    /// The Zenoh configuration is invalid.
    #[error("zenoh configuration: {0}")]
    ZenohConfig(String),
    /// Zenoh failed (opening the session, declaring, …).
    #[error("zenoh: {0}")]
    Zenoh(#[from] zenoh::Error),
    /// The worker thread failed.
    #[error("worker: {0}")]
    Worker(String),
}

/// Totals reported when the service stops.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ServeReport {
    /// Inputs taken from the queue.
    pub inputs: u64,
    /// Twin poses published.
    pub poses: u64,
    /// Robots tracked.
    pub robots: usize,
    /// Outputs Zenoh refused to send.
    pub publish_errors: u64,
}

/// Wraps a query of one queryable into the worker's input.
type QueryInput = fn(Query) -> Input;

/// Everything that reaches the worker.
enum Input {
    Joints(Sample),
    Measured(Sample),
    Sensor {
        robot: Arc<str>,
        index: usize,
        sample: Sample,
    },
    State(Query),
    Fk(Query),
    Reset(Query),
    Stop,
}

/// Builds the Zenoh configuration of a `[zenoh]` section.
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
    Ok(zenoh)
}

/// Runs the service until `shutdown` completes, then tears down in order: stop intake, finish
/// the pipeline (final metrics for every robot), undeclare, close the session.
pub async fn serve(
    config: ServiceConfig,
    shutdown: impl Future<Output = ()>,
) -> Result<ServeReport, ServiceError> {
    let session = zenoh::open(zenoh_config_of(&config.zenoh)?).await?;
    info!(
        zid = %session.zid(),
        mode = %config.zenoh.mode,
        listen = ?config.zenoh.listen,
        connect = ?config.zenoh.connect,
        prefix = %config.key_prefix,
        "armtwin serving"
    );
    let (tx, rx) = sync_channel::<Input>(config.queue_capacity);
    let prefix = config.key_prefix.clone();

    let pipeline = Pipeline::new(
        config.pipeline,
        config.default_robot.clone(),
        config.robots.clone(),
    );
    let worker = Worker {
        sink: ZenohSink::new(
            session.clone(),
            prefix.clone(),
            config.congestion,
            config.event_budget,
        ),
        pipeline,
        rx,
        prefix: prefix.clone(),
        metrics_period: config.metrics_period,
        inputs: 0,
    };
    let worker = std::thread::Builder::new()
        .name("armtwin-worker".to_owned())
        .spawn(move || worker.run())
        .map_err(|e| ServiceError::Worker(e.to_string()))?;

    let intake = declare_intake(&session, &prefix, &config, &tx).await;
    let intake = match intake {
        Ok(intake) => intake,
        Err(e) => {
            let _ = tx.send(Input::Stop);
            let _ = tokio::task::spawn_blocking(move || worker.join()).await;
            let _ = session.close().await;
            return Err(e);
        }
    };

    shutdown.await;
    info!("shutting down: stopping intake");
    intake.undeclare().await;
    // Everything enqueued before this point is processed before the worker stops.
    let stop_tx = tx.clone();
    drop(tx);
    let _ = tokio::task::spawn_blocking(move || {
        // Fails only if the worker already stopped, which is what we want anyway.
        let _ = stop_tx.send(Input::Stop);
    })
    .await;
    let report = match tokio::time::timeout(
        TEARDOWN_STEP * 4,
        tokio::task::spawn_blocking(move || worker.join()),
    )
    .await
    {
        Ok(Ok(Ok(report))) => report,
        Ok(Ok(Err(_))) => return Err(ServiceError::Worker("the worker panicked".to_owned())),
        Ok(Err(e)) => return Err(ServiceError::Worker(e.to_string())),
        Err(_) => {
            return Err(ServiceError::Worker(
                "the worker did not stop in time".to_owned(),
            ));
        }
    };
    if tokio::time::timeout(TEARDOWN_STEP, session.close())
        .await
        .is_err()
    {
        warn!("the session did not close in time");
    }
    info!(
        inputs = report.inputs,
        poses = report.poses,
        robots = report.robots,
        publish_errors = report.publish_errors,
        "armtwin stopped"
    );
    Ok(report)
}

/// The subscribers and queryables that feed the worker.
struct Intake {
    subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    queryables: Vec<zenoh::query::Queryable<()>>,
}

impl Intake {
    async fn undeclare(self) {
        for subscriber in self.subscribers {
            if let Err(e) = subscriber.undeclare().await {
                warn!(error = %e, "undeclaring a subscriber failed");
            }
        }
        for queryable in self.queryables {
            if let Err(e) = queryable.undeclare().await {
                warn!(error = %e, "undeclaring a queryable failed");
            }
        }
    }
}

fn enqueue(tx: &SyncSender<Input>, input: Input) {
    // Waits while the queue is full: backpressure instead of loss. Fails only after the worker
    // stopped, when inputs are no longer wanted.
    let _ = tx.send(input);
}

async fn declare_intake(
    session: &Session,
    prefix: &str,
    config: &ServiceConfig,
    tx: &SyncSender<Input>,
) -> Result<Intake, ServiceError> {
    let mut subscribers = Vec::new();
    let mut queryables = Vec::new();
    let joints_tx = tx.clone();
    subscribers.push(
        session
            .declare_subscriber(format!("{prefix}/joints/**"))
            .callback(move |sample| enqueue(&joints_tx, Input::Joints(sample)))
            .await?,
    );
    let measured_tx = tx.clone();
    subscribers.push(
        session
            .declare_subscriber(format!("{prefix}/measured/**"))
            .callback(move |sample| enqueue(&measured_tx, Input::Measured(sample)))
            .await?,
    );
    for (robot, settings) in &config.robots {
        for (index, sensor) in settings.sensors.iter().enumerate() {
            let sensor_tx = tx.clone();
            let robot: Arc<str> = Arc::from(robot.as_str());
            subscribers.push(
                session
                    .declare_subscriber(sensor.key_expr.clone())
                    .callback(move |sample| {
                        enqueue(
                            &sensor_tx,
                            Input::Sensor {
                                robot: robot.clone(),
                                index,
                                sample,
                            },
                        );
                    })
                    .await?,
            );
        }
    }
    let queries: [(&str, QueryInput); 3] = [
        ("state", Input::State),
        ("fk", Input::Fk),
        ("reset", Input::Reset),
    ];
    for (stream, wrap) in queries {
        let query_tx = tx.clone();
        queryables.push(
            session
                .declare_queryable(format!("{prefix}/{stream}/**"))
                .callback(move |query| enqueue(&query_tx, wrap(query)))
                .await?,
        );
    }
    Ok(Intake {
        subscribers,
        queryables,
    })
}

fn unix_now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// The stamp of a message without its own: the Zenoh timestamp, else the arrival time.
fn transport_stamp_s(sample: &Sample) -> f64 {
    sample
        .timestamp()
        .map_or_else(unix_now_s, |t| t.get_time().as_secs_f64())
}

struct Worker {
    sink: ZenohSink,
    pipeline: Pipeline,
    rx: Receiver<Input>,
    prefix: String,
    metrics_period: Duration,
    inputs: u64,
}

impl Worker {
    fn run(mut self) -> ServeReport {
        let mut next_metrics = Instant::now() + self.metrics_period;
        loop {
            let wait = next_metrics.saturating_duration_since(Instant::now());
            match self.rx.recv_timeout(wait) {
                Ok(Input::Stop) | Err(RecvTimeoutError::Disconnected) => break,
                Ok(input) => {
                    self.inputs += 1;
                    self.handle(input);
                }
                Err(RecvTimeoutError::Timeout) => {}
            }
            let now = Instant::now();
            if now >= next_metrics {
                self.pipeline.publish_due_metrics(&mut self.sink);
                next_metrics = now + self.metrics_period;
            }
        }
        self.pipeline.finish(&mut self.sink);
        let report = ServeReport {
            inputs: self.inputs,
            poses: self.sink.poses,
            robots: self.sink.outputs.len(),
            publish_errors: self.sink.publish_errors,
        };
        self.sink.undeclare_all();
        report
    }

    /// The robot id in `key` after `<prefix>/<stream>/`, if it is a plain key (a put on a
    /// wildcard key expression names no robot, and must not become one).
    fn robot_of<'k>(&self, key: &'k str, stream: &str) -> Option<&'k str> {
        key.strip_prefix(self.prefix.as_str())?
            .strip_prefix('/')?
            .strip_prefix(stream)?
            .strip_prefix('/')
            .filter(|robot| !robot.is_empty() && !robot.contains(['*', '$']))
    }

    fn handle(&mut self, input: Input) {
        match input {
            Input::Joints(sample) => self.joints(&sample),
            Input::Measured(sample) => {
                let key = sample.key_expr().as_str();
                let Some(robot) = self.robot_of(key, "measured") else {
                    warn!(%key, "measured pose without a robot id in its key: ignored");
                    return;
                };
                self.measured(robot, MeasuredStream::Robot, &sample);
            }
            Input::Sensor {
                robot,
                index,
                sample,
            } => self.measured(&robot, MeasuredStream::Sensor(index), &sample),
            Input::State(query) => self.state(&query),
            Input::Fk(query) => self.fk(&query),
            Input::Reset(query) => self.reset(&query),
            Input::Stop => {}
        }
    }

    fn joints(&mut self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        let Some(robot) = self.robot_of(key, "joints") else {
            warn!(%key, "joint sample without a robot id in its key: ignored");
            return;
        };
        ingest::joint_message(
            &mut self.pipeline,
            robot,
            key,
            &sample.payload().to_bytes(),
            transport_stamp_s(sample),
            &mut self.sink,
        );
    }

    fn measured(&mut self, robot: &str, stream: MeasuredStream, sample: &Sample) {
        ingest::measured_message(
            &mut self.pipeline,
            robot,
            sample.key_expr().as_str(),
            stream,
            &sample.payload().to_bytes(),
            transport_stamp_s(sample),
            &mut self.sink,
        );
    }

    /// Tracked robots whose `<prefix>/<stream>/<robot>` key the query's key expression covers.
    fn matching_robots(&self, query: &Query, stream: &str) -> Vec<(String, KeyExpr<'static>)> {
        let mut robots: Vec<(String, KeyExpr<'static>)> = self
            .pipeline
            .tracked_robots()
            .filter_map(|robot| {
                let key = KeyExpr::try_from(format!("{}/{stream}/{robot}", self.prefix)).ok()?;
                query
                    .key_expr()
                    .intersects(&key)
                    .then(|| (robot.to_owned(), key))
            })
            .collect();
        robots.sort_by(|a, b| a.0.cmp(&b.0));
        robots
    }

    fn reply(query: &Query, key: &KeyExpr<'static>, payload: Vec<u8>) {
        if let Err(e) = query.reply(key.clone(), payload).wait() {
            warn!(error = %e, %key, "reply failed");
        }
    }

    fn reply_err(query: &Query, message: &str) {
        let body = serde_json::json!({ "error": message }).to_string();
        if let Err(e) = query.reply_err(body).wait() {
            warn!(error = %e, "error reply failed");
        }
    }

    fn state(&self, query: &Query) {
        for (robot, key) in self.matching_robots(query, "state") {
            if let Some(state) = self.pipeline.state(&robot) {
                Self::reply(
                    query,
                    &key,
                    wire::to_json_bytes(&wire::StateMessage::new(&state)),
                );
            }
        }
    }

    fn reset(&mut self, query: &Query) {
        let robots = self.matching_robots(query, "reset");
        if robots.is_empty() {
            Self::reply_err(query, "no tracked robot matches this key expression");
        }
        for (robot, key) in robots {
            if let Some(snapshot) = self.pipeline.reset(&robot, &mut self.sink) {
                info!(%robot, "metrics reset");
                Self::reply(
                    query,
                    &key,
                    wire::to_json_bytes(&wire::MetricsMessage::new(&snapshot)),
                );
            }
        }
    }

    fn fk(&self, query: &Query) {
        let key = query.key_expr().as_str();
        let Some(robot) = self.robot_of(key, "fk") else {
            Self::reply_err(
                query,
                "ask one robot: <prefix>/fk/<robot id> with {\"q\": [...]}",
            );
            return;
        };
        let Some(settings) = self.pipeline.settings_for(robot) else {
            Self::reply_err(query, &format!("robot '{robot}' is not configured"));
            return;
        };
        let payload = query
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default();
        let joints = match wire::decode_joints(&payload, settings.model.joint_count()) {
            Ok(decoded) => decoded.sample,
            Err(e) => {
                Self::reply_err(query, &e.to_string());
                return;
            }
        };
        match self.pipeline.fk(robot, &joints.q_rad) {
            Some(Ok(pose)) => {
                let Ok(reply_key) = KeyExpr::try_from(key.to_owned()) else {
                    return;
                };
                let frame = settings.model.frame().as_str();
                let message =
                    wire::PoseMessage::new(robot, joints.stamp_s.unwrap_or(0.0), 0, frame, &pose);
                Self::reply(query, &reply_key, wire::to_json_bytes(&message));
            }
            Some(Err(e)) => Self::reply_err(query, &e.to_string()),
            None => Self::reply_err(query, &format!("robot '{robot}' is not configured")),
        }
    }
}

/// Per-robot Zenoh entities.
struct RobotOutputs {
    pose: Publisher<'static>,
    deviation: Publisher<'static>,
    metrics: Publisher<'static>,
    events: Publisher<'static>,
    token: Option<LivelinessToken>,
    /// The robot's input keys, declared so Zenoh caches their routes.
    inputs: Vec<KeyExpr<'static>>,
}

/// Publishes the pipeline's results on Zenoh.
struct ZenohSink {
    session: Session,
    prefix: String,
    congestion: CongestionControl,
    outputs: HashMap<String, RobotOutputs>,
    poses: u64,
    publish_errors: u64,
    event_budget: EventBudget,
    /// Per tracked robot; robots that are not tracked (unknown and rejected) share the entry
    /// under the empty id, so a flood of made-up ids cannot grow it.
    event_buckets: HashMap<String, EventBucket>,
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

impl ZenohSink {
    fn new(
        session: Session,
        prefix: String,
        congestion: Congestion,
        event_budget: EventBudget,
    ) -> Self {
        Self {
            session,
            prefix,
            congestion: match congestion {
                Congestion::Block => CongestionControl::Block,
                Congestion::Drop => CongestionControl::Drop,
            },
            outputs: HashMap::new(),
            poses: 0,
            publish_errors: 0,
            event_budget,
            event_buckets: HashMap::new(),
        }
    }

    fn publisher(&self, stream: &str, robot: &str) -> zenoh::Result<Publisher<'static>> {
        self.session
            .declare_publisher(format!("{}/{stream}/{robot}", self.prefix))
            .congestion_control(self.congestion)
            .wait()
    }

    fn declare(&self, robot: &str) -> zenoh::Result<RobotOutputs> {
        let mut inputs = Vec::new();
        for stream in ["joints", "measured"] {
            inputs.push(
                self.session
                    .declare_keyexpr(format!("{}/{stream}/{robot}", self.prefix))
                    .wait()?,
            );
        }
        let token = self
            .session
            .liveliness()
            .declare_token(format!("{}/alive/{robot}", self.prefix))
            .wait()?;
        Ok(RobotOutputs {
            pose: self.publisher("pose", robot)?,
            deviation: self.publisher("deviation", robot)?,
            metrics: self.publisher("metrics", robot)?,
            events: self.publisher("events", robot)?,
            token: Some(token),
            inputs,
        })
    }

    fn put(publisher: &Publisher<'static>, payload: Vec<u8>, errors: &mut u64) {
        if let Err(e) = publisher.put(payload).wait() {
            *errors += 1;
            warn!(error = %e, key = %publisher.key_expr(), "publish failed");
        }
    }

    fn undeclare_all(&mut self) {
        for (robot, outputs) in self.outputs.drain() {
            let RobotOutputs {
                pose,
                deviation,
                metrics,
                events,
                token,
                inputs,
            } = outputs;
            for publisher in [pose, deviation, metrics, events] {
                if let Err(e) = publisher.undeclare().wait() {
                    warn!(%robot, error = %e, "undeclaring a publisher failed");
                }
            }
            if let Some(token) = token
                && let Err(e) = token.undeclare().wait()
            {
                warn!(%robot, error = %e, "undeclaring the liveliness token failed");
            }
            for key in inputs {
                if let Err(e) = self.session.undeclare(key).wait() {
                    warn!(%robot, error = %e, "undeclaring a key expression failed");
                }
            }
        }
    }
}

impl Sink for ZenohSink {
    fn tracking(&mut self, robot: &str) {
        match self.declare(robot) {
            Ok(outputs) => {
                info!(%robot, "tracking robot");
                self.outputs.insert(robot.to_owned(), outputs);
            }
            Err(e) => warn!(%robot, error = %e, "cannot declare the robot's outputs"),
        }
    }

    fn pose(
        &mut self,
        robot: &str,
        stamp_s: f64,
        seq: u64,
        frame: OutputFrame,
        pose: &PoseReadout,
    ) {
        let Some(outputs) = self.outputs.get(robot) else {
            return;
        };
        let message = wire::PoseMessage::new(robot, stamp_s, seq, frame.as_str(), pose);
        Self::put(
            &outputs.pose,
            wire::to_json_bytes(&message),
            &mut self.publish_errors,
        );
        self.poses += 1;
    }

    fn deviation(
        &mut self,
        robot: &str,
        stamp_s: f64,
        _measured: &PoseReadout,
        deviation: &Deviation,
    ) {
        let Some(outputs) = self.outputs.get(robot) else {
            return;
        };
        let message = wire::DeviationMessage::new(robot, stamp_s, deviation);
        Self::put(
            &outputs.deviation,
            wire::to_json_bytes(&message),
            &mut self.publish_errors,
        );
    }

    fn event(&mut self, event: &Event<'_>) {
        let always = matches!(
            event.kind,
            EventKind::Alarm | EventKind::Recovered | EventKind::Restart
        );
        let bucket_id = if self.outputs.contains_key(event.robot) {
            event.robot
        } else {
            ""
        };
        let now = Instant::now();
        let budget = self.event_budget;
        let bucket = match self.event_buckets.get_mut(bucket_id) {
            Some(bucket) => bucket,
            None => self
                .event_buckets
                .entry(bucket_id.to_owned())
                .or_insert_with(|| EventBucket::full(budget, now)),
        };
        if !bucket.admit(budget, now, always) {
            if bucket.suppressed == 1 {
                warn!(robot = %event.robot, per_s = budget.per_s, burst = budget.burst, "event rate limit reached: further events are counted, not published");
            }
            return;
        }
        let mut message = wire::EventMessage::new(event);
        message.suppressed = std::mem::take(&mut bucket.suppressed);
        let payload = wire::to_json_bytes(&message);
        if let Some(outputs) = self.outputs.get(event.robot) {
            Self::put(&outputs.events, payload, &mut self.publish_errors);
        } else {
            // An untracked robot (unknown and rejected): no declared publisher.
            let key = format!("{}/events/{}", self.prefix, event.robot);
            if let Err(e) = self
                .session
                .put(key, payload)
                .congestion_control(self.congestion)
                .wait()
            {
                self.publish_errors += 1;
                warn!(error = %e, robot = %event.robot, "publishing an event failed");
            }
        }
        match event.kind {
            EventKind::Rejected | EventKind::Alarm => {
                warn!(robot = %event.robot, kind = event.kind.as_str(), reason = %event.reason, "event");
            }
            EventKind::Recovered | EventKind::Restart => {
                info!(robot = %event.robot, kind = event.kind.as_str(), reason = %event.reason, "event");
            }
            EventKind::Gap | EventKind::Unpaired => {
                debug!(robot = %event.robot, kind = event.kind.as_str(), reason = %event.reason, "event");
            }
        }
    }

    fn metrics(&mut self, snapshot: &MetricsSnapshot) {
        let Some(outputs) = self.outputs.get(&snapshot.robot) else {
            return;
        };
        let message = wire::MetricsMessage::new(snapshot);
        Self::put(
            &outputs.metrics,
            wire::to_json_bytes(&message),
            &mut self.publish_errors,
        );
    }
}
