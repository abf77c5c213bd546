//! The queryables: `state`, `history`, `fk`, `ik` and `calibrate` (reads), `admin/reset`,
//! `admin/calibrate`, `admin/payload` and `admin/record` (changes, on keys of their own so that an access control list can keep them
//! from those who only watch), each answered from the robots it names, one cell at a time,
//! replying once that cell's lock is released.
//!
//! Queries are answered off Zenoh's receive threads, by a few threads of their own behind a
//! bounded queue: a query that finds the queue full is refused at once ("busy"), so that a
//! querier cannot hold up the samples of the links it shares. A wildcard read (`state`,
//! `history`) answers at most a bounded number of robots and bytes, and says so in an error
//! reply after the last robot it answered.
//!
//! Must not hold a robot's cell across a reply.

use std::sync::Arc;
use std::sync::mpsc::{SyncSender, TrySendError, sync_channel};

use tracing::{info, warn};
use zenoh::Wait;
use zenoh::bytes::Encoding;
use zenoh::key_expr::KeyExpr;
use zenoh::query::{Query, ZenohParameters};

use super::calibration_slot::CalibrationStatus;
use super::fleet::{Fleet, RobotCell};
use super::time_range::seconds_in;
use armtwin_codec::ik::{IkAnswerJson, IkRequest};
use armtwin_codec::json;
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::ReplaceModelError;
use armtwin_mesh::keys::{KeySpace, Stream};

/// Answers one kind of query; each handler locks the robots it reads one at a time.
pub(super) type QueryHandler = fn(&Queries, &Query);

/// Queries waiting for a thread at most; more are refused as busy.
pub(super) const MAX_WAITING_QUERIES: usize = 64;
/// Threads answering queries.
const QUERY_THREADS: usize = 2;
/// Bytes of replies one `state` or `history` query gets at most.
pub(super) const MAX_READ_REPLY_BYTES: usize = 16 << 20;
/// Robots one `state` query answers at most.
pub(super) const MAX_STATE_ROBOTS: usize = 10_000;
/// Robots one `history` query answers at most (a robot's history is far larger than its state).
pub(super) const MAX_HISTORY_ROBOTS: usize = 64;

/// Where Zenoh's callbacks hand queries to the threads that answer them.
#[derive(Clone)]
pub(super) struct QueryPool {
    waiting: SyncSender<(Query, Stream, QueryHandler)>,
}

impl QueryPool {
    /// [`QUERY_THREADS`] threads answering with `queries`, until every handle of the pool is
    /// dropped (the queryables undeclared).
    pub(super) fn start(queries: Queries) -> std::io::Result<Self> {
        let queries = Arc::new(queries);
        let (waiting, received) =
            sync_channel::<(Query, Stream, QueryHandler)>(MAX_WAITING_QUERIES);
        let received = Arc::new(std::sync::Mutex::new(received));
        for index in 0..QUERY_THREADS {
            let queries = Arc::clone(&queries);
            let received = Arc::clone(&received);
            std::thread::Builder::new()
                .name(format!("armtwin-queries-{index}"))
                .spawn(move || {
                    loop {
                        // The lock is held only while waiting for the next query.
                        let next = received
                            .lock()
                            .unwrap_or_else(std::sync::PoisonError::into_inner)
                            .recv();
                        let Ok((query, stream, handler)) = next else {
                            return;
                        };
                        queries.answer(&query, stream, handler);
                    }
                })?;
        }
        Ok(Self { waiting })
    }

    /// Hands `query` (on `stream`) to a thread, or refuses it as busy when
    /// [`MAX_WAITING_QUERIES`] wait.
    pub(super) fn submit(&self, query: Query, stream: Stream, handler: QueryHandler) {
        match self.waiting.try_send((query, stream, handler)) {
            // Queued; or the threads are gone, as the service is stopping.
            Ok(()) | Err(TrySendError::Disconnected(_)) => {}
            Err(TrySendError::Full((query, _, _))) => {
                warn!(key = %query.key_expr(), "query refused: {MAX_WAITING_QUERIES} queries wait already");
                Queries::reply_err(
                    &query,
                    &format!("busy: {MAX_WAITING_QUERIES} queries wait already; ask again"),
                );
            }
        }
    }
}

/// How much of a wildcard read one query may take, and how much it took.
struct ReadBound {
    max_robots: usize,
    robots: usize,
    bytes: usize,
}

impl ReadBound {
    fn new(max_robots: usize) -> Self {
        Self {
            max_robots,
            robots: 0,
            bytes: 0,
        }
    }

    /// Whether a reply of `bytes` more fits; counted if it does.
    fn admits(&mut self, bytes: usize) -> bool {
        if self.robots >= self.max_robots || self.bytes + bytes > MAX_READ_REPLY_BYTES {
            return false;
        }
        self.robots += 1;
        self.bytes += bytes;
        true
    }

    /// The error reply that ends a read cut short: what it answered, of how many, and why.
    fn cut_short(&self, query: &Query, matching: usize) {
        Queries::reply_err_json(
            query,
            &serde_json::json!({
                "error": format!(
                    "truncated: {} of {matching} robots answered ({} bytes); one query answers at \
                     most {} robots and {MAX_READ_REPLY_BYTES} bytes: ask for fewer robots",
                    self.robots, self.bytes, self.max_robots
                ),
                "truncated": true,
                "answered": self.robots,
                "matching": matching,
                "max_robots": self.max_robots,
                "max_bytes": MAX_READ_REPLY_BYTES,
            }),
        );
    }
}

/// The queryables' side of the fleet. Each handler takes the robots it answers about one at a
/// time, each under its own lock, and replies once that lock is released.
pub(super) struct Queries {
    fleet: Arc<Fleet>,
    keys: KeySpace,
    /// Why the admin queries are refused (`[service] admin`), if they are.
    admin_refusal: Option<String>,
}

impl Queries {
    /// The queries about `fleet`'s robots, on `keys`; the admin queries refused with
    /// `admin_refusal`, if given.
    pub(super) fn new(fleet: Arc<Fleet>, keys: KeySpace, admin_refusal: Option<String>) -> Self {
        Self {
            fleet,
            keys,
            admin_refusal,
        }
    }

    /// The handlers, by the stream their queryable is declared on.
    pub(super) const HANDLERS: [(Stream, QueryHandler); 9] = [
        (Stream::State, Self::state),
        (Stream::History, Self::history),
        (Stream::Fk, Self::fk),
        (Stream::Reset, Self::reset),
        (Stream::Ik, Self::ik),
        (Stream::Calibrate, Self::calibrate),
        (Stream::ApplyCalibration, Self::apply_calibration),
        (Stream::ApplyPayload, Self::apply_payload),
        (Stream::Record, Self::record),
    ];

    /// Answers `query` on `stream` with `handler`, unless the service stopped; an admin query
    /// that asks for its stream by name gets the refusal instead, when there is one.
    pub(super) fn answer(&self, query: &Query, stream: Stream, handler: QueryHandler) {
        if !self.fleet.count_input() {
            return;
        }
        match &self.admin_refusal {
            Some(why) if stream.is_admin() => {
                if self.asks_for(query, stream) {
                    warn!(key = %query.key_expr(), "admin query refused");
                    Self::reply_err(query, why);
                }
            }
            _ => handler(self, query),
        }
    }

    /// Robots with a cell whose `<prefix>/<stream>/<robot>` key the query's key expression
    /// covers, in id order.
    fn matching_robots(
        &self,
        query: &Query,
        stream: Stream,
    ) -> Vec<(Arc<RobotCell>, KeyExpr<'static>)> {
        let mut robots: Vec<(Arc<RobotCell>, KeyExpr<'static>)> = self
            .fleet
            .cells()
            .into_iter()
            .filter_map(|cell| {
                let key = KeyExpr::try_from(self.keys.key(stream, cell.robot().id())).ok()?;
                query.key_expr().intersects(&key).then_some((cell, key))
            })
            .collect();
        robots.sort_by(|a, b| a.0.robot().id().cmp(b.0.robot().id()));
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

    /// A change query's action: its `action` parameter, else its payload as text.
    fn action_of(query: &Query) -> String {
        let payload = query
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default();
        query.parameters().get("action").map_or_else(
            || String::from_utf8_lossy(&payload).trim().to_owned(),
            str::to_owned,
        )
    }

    fn reply_err(query: &Query, message: &str) {
        Self::reply_err_json(query, &serde_json::json!({ "error": message }));
    }

    /// An error reply of `body`, a JSON object with at least `error`.
    fn reply_err_json(query: &Query, body: &serde_json::Value) {
        if let Err(e) = query
            .reply_err(body.to_string())
            .encoding(Encoding::APPLICATION_JSON)
            .wait()
        {
            warn!(error = %e, "error reply failed");
        }
    }

    fn state(&self, query: &Query) {
        let robots = self.matching_robots(query, Stream::State);
        let mut bound = ReadBound::new(MAX_STATE_ROBOTS);
        for (cell, key) in &robots {
            let payload = cell
                .lock()
                .state_message()
                .map(|message| json::to_json_bytes(&message));
            if let Some(payload) = payload {
                if !bound.admits(payload.len()) {
                    bound.cut_short(query, robots.len());
                    return;
                }
                Self::reply(query, key, payload);
            }
        }
    }

    /// `<prefix>/history/<robot>[?_time=<range>]`: each matching robot's completed seconds of
    /// history whose second lies in the range (`now()` being the robot's newest stamp; all it
    /// keeps without one), one reply per robot that has had input.
    fn history(&self, query: &Query) {
        let range = match query.parameters().time_range() {
            None => None,
            Some(Ok(range)) => Some(range),
            Some(Err(e)) => {
                Self::reply_err(query, &format!("_time: {e}"));
                return;
            }
        };
        let robots = self.matching_robots(query, Stream::History);
        let mut bound = ReadBound::new(MAX_HISTORY_ROBOTS);
        for (cell, key) in &robots {
            let message = cell.lock().history_message(cell.robot().id(), |newest_s| {
                range
                    .as_ref()
                    .map_or(i64::MIN..=i64::MAX, |range| seconds_in(range, newest_s))
            });
            if let Some(message) = message {
                let payload = json::to_json_bytes(&message);
                if !bound.admits(payload.len()) {
                    bound.cut_short(query, robots.len());
                    return;
                }
                Self::reply(query, key, payload);
            }
        }
    }

    /// Whether `query` asks for a change of `stream` by name: its key expression lies within
    /// `<prefix>/<stream>/**`. A wider one (`twin/**`, `twin/*/reset/**`) reaches the queryable
    /// too, but asks to read everything, not to change anything: it gets no reply here.
    fn asks_for(&self, query: &Query, stream: Stream) -> bool {
        KeyExpr::try_from(self.keys.every_robot(stream))
            .is_ok_and(|subtree| subtree.includes(query.key_expr()))
    }

    fn reset(&self, query: &Query) {
        if !self.asks_for(query, Stream::Reset) {
            return;
        }
        let mut replies = Vec::new();
        for (cell, key) in self.matching_robots(query, Stream::Reset) {
            let Some(mut state) = self.fleet.unless_stopped(&cell) else {
                return;
            };
            let Some((twin, mut sink)) = self.fleet.twin_and_sink(&mut state) else {
                continue;
            };
            let final_metrics = twin.reset(&mut sink);
            drop(sink);
            drop(state);
            info!(robot = cell.robot().id(), "metrics reset");
            replies.push((
                key,
                json::MetricsMessage::new(&final_metrics).to_json_bytes(),
            ));
        }
        if replies.is_empty() {
            Self::reply_err(query, "no tracked robot matches this key expression");
        }
        for (key, payload) in replies {
            Self::reply(query, &key, payload);
        }
    }

    /// `<prefix>/admin/record/<robot>[?pre_s=…;post_s=…]` (or `&`): the robot's recent streams, from
    /// `pre_s` before its newest sample to `post_s` after (each at most, and by default, the
    /// `[recorder]`'s), as an incident file; the reply names the file, the `recorded` event
    /// follows once it is written.
    fn record(&self, query: &Query) {
        let usage = "ask one robot: <prefix>/admin/record/<robot id>[?pre_s=<s>&post_s=<s>]";
        let Ok(robot) = self
            .keys
            .robot_of(Stream::Record, query.key_expr().as_str())
        else {
            Self::reply_err(query, usage);
            return;
        };
        let config = self.fleet.recorder().config();
        // Zenoh separates parameters with `;`; a URL's `&` is taken too.
        let parameters = query.parameters().as_str().to_owned();
        let given = |name: &str| {
            parameters
                .split([';', '&'])
                .find_map(|pair| pair.split_once('=').filter(|(key, _)| *key == name))
                .map(|(_, value)| value)
        };
        let parameter = |name: &str, most: f64| match given(name) {
            None => Ok(most),
            Some(text) => match text.parse::<f64>() {
                Ok(value) if value.is_finite() && value >= 0.0 => Ok(value.min(most)),
                _ => Err(format!("{name}={text} is not a duration ≥ 0 in seconds")),
            },
        };
        let span = match (
            parameter("pre_s", config.pre_s),
            parameter("post_s", config.post_s),
        ) {
            (Ok(pre_s), Ok(post_s)) => (pre_s, post_s),
            (Err(e), _) | (_, Err(e)) => {
                Self::reply_err(query, &e);
                return;
            }
        };
        let Some(cell) = self.fleet.existing_cell_of(robot) else {
            Self::reply_err(query, &format!("robot '{robot}' is not tracked"));
            return;
        };
        let requested = cell
            .lock()
            .outputs_mut()
            .recording_mut()
            .map(|recording| recording.request(robot, span));
        let requested = match requested {
            None => {
                Self::reply_err(
                    query,
                    &format!("robot '{robot}' does not record ([recorder])"),
                );
                return;
            }
            Some(None) => {
                Self::reply_err(
                    query,
                    &format!("robot '{robot}' has sent no joint sample yet"),
                );
                return;
            }
            Some(Some(requested)) => requested,
        };
        info!(
            robot,
            pre_s = span.0,
            post_s = span.1,
            "recording asked for"
        );
        let body = serde_json::json!({
            "robot": robot,
            "trigger": "operator",
            "from_s": requested.from_s,
            "until_s": requested.until_s,
            "path": config.store.dir.join(&requested.path),
        });
        let Ok(key) = KeyExpr::try_from(self.keys.key(Stream::Record, robot)) else {
            return;
        };
        Self::reply(query, &key, body.to_string().into_bytes());
    }

    /// The robot a per-robot query (`<prefix>/<stream>/<robot id>`) asks about, its current
    /// model and the query's payload; `None` once an error reply says why there are none.
    fn robot_query<'q>(
        &self,
        query: &'q Query,
        stream: Stream,
        request: &str,
    ) -> Option<(&'q str, Arc<RobotModel>, Vec<u8>)> {
        let Ok(robot) = self.keys.robot_of(stream, query.key_expr().as_str()) else {
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
        let Some((robot, model, payload)) = self.robot_query(query, Stream::Fk, "{\"q\": [...]}")
        else {
            return;
        };
        let joints = match json::decode_joints(&payload, model.joint_count()) {
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
                let message = json::PoseMessage::new(
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
        let configured = self.fleet.configured_model(id);
        let twin_model = self
            .fleet
            .existing_cell_of(id)
            .and_then(|cell| cell.lock().twin().map(|twin| Arc::clone(twin.model())));
        twin_model.or(configured)
    }

    /// `<prefix>/ik/<robot>` with `{"pose": [x, y, z, qx, qy, qz, qw], "seed": [...]}`: the joint
    /// configurations that reach the pose with the robot's current model.
    fn ik(&self, query: &Query) {
        let key = query.key_expr().as_str();
        let request = "{\"pose\": [x, y, z, qx, qy, qz, qw]}";
        let Some((_, model, payload)) = self.robot_query(query, Stream::Ik, request) else {
            return;
        };
        let answer = IkRequest::decode(&payload).and_then(|request| {
            Ok(armtwin_core::ik::solve(
                &model,
                &request.target,
                request.seed(),
            )?)
        });
        match answer {
            Ok(answer) => {
                let Ok(reply_key) = KeyExpr::try_from(key.to_owned()) else {
                    return;
                };
                Self::reply(
                    query,
                    &reply_key,
                    json::to_json_bytes(&IkAnswerJson::from(&answer)),
                );
            }
            Err(e) => Self::reply_err(query, &e.to_string()),
        }
    }

    /// `<prefix>/calibrate/<robot>`: the robot's self-calibration status (`status`, the
    /// default, as the payload or the selector's `action` parameter). `apply` and `discard` are
    /// changes: they are asked on `<prefix>/admin/calibrate/<robot>`.
    fn calibrate(&self, query: &Query) {
        self.calibration_query(query, Stream::Calibrate);
    }

    /// `<prefix>/admin/calibrate/<robot>` with `apply` or `discard` (or `status`).
    fn apply_calibration(&self, query: &Query) {
        if self.asks_for(query, Stream::ApplyCalibration) {
            self.calibration_query(query, Stream::ApplyCalibration);
        }
    }

    /// A query on `stream` (`calibrate`, read-only, or `admin/calibrate`) about one robot's
    /// self-calibration.
    fn calibration_query(&self, query: &Query, stream: Stream) {
        let key = query.key_expr().as_str();
        let Ok(id) = self.keys.robot_of(stream, key) else {
            if stream == Stream::Calibrate {
                Self::reply_err(
                    query,
                    "ask one robot: <prefix>/calibrate/<robot id> (status), or \
                     <prefix>/admin/calibrate/<robot id> with apply or discard",
                );
            }
            return;
        };
        let action = Self::action_of(query);
        if stream == Stream::Calibrate && matches!(action.as_str(), "apply" | "discard") {
            Self::reply_err(
                query,
                &format!(
                    "'{action}' changes the twin: ask {}",
                    self.keys.key(Stream::ApplyCalibration, id)
                ),
            );
            return;
        }
        let Some(robot) = self.fleet.find(id) else {
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
        let cell = self.fleet.existing_cell_of(id);
        match action.as_str() {
            "" | "status" => {
                let status = match &cell {
                    Some(cell) => {
                        let state = cell.lock();
                        CalibrationStatus::of(&robot, state.twin(), Some(state.calibration()))
                    }
                    None => CalibrationStatus::of(&robot, None, None),
                };
                Self::reply(query, &reply_key, json::to_json_bytes(&status));
            }
            "discard" => {
                let discarded = cell.is_some_and(|cell| cell.lock().calibration_mut().discard());
                let body = serde_json::json!({ "robot": id, "discarded": discarded });
                Self::reply(query, &reply_key, body.to_string().into_bytes());
            }
            "apply" => {
                let applied = cell.and_then(|cell| self.apply_estimate(&cell));
                match applied {
                    None => {
                        Self::reply_err(query, &format!("robot '{id}' has no estimate to apply"));
                    }
                    Some(Ok(status)) => {
                        Self::reply(query, &reply_key, json::to_json_bytes(&status));
                    }
                    Some(Err(e)) => Self::reply_err(query, &e.to_string()),
                }
            }
            other => Self::reply_err(query, &format!("'{other}' is not apply, discard or status")),
        }
    }

    /// `<prefix>/admin/payload/<robot>` with `apply` (the identified payload into the robot's
    /// effort model), `discard` (back to the controller's or configured payload) or `status`.
    fn apply_payload(&self, query: &Query) {
        if !self.asks_for(query, Stream::ApplyPayload) {
            return;
        }
        let key = query.key_expr().as_str();
        let Ok(id) = self.keys.robot_of(Stream::ApplyPayload, key) else {
            Self::reply_err(query, "ask one robot: <prefix>/admin/payload/<robot id>");
            return;
        };
        let action = Self::action_of(query);
        let Some(robot) = self.fleet.find(id) else {
            Self::reply_err(query, &format!("robot '{id}' is not tracked"));
            return;
        };
        if robot.settings().effort.is_none() {
            Self::reply_err(
                query,
                &format!("robot '{id}' has no effort monitor (effort = true in its section)"),
            );
            return;
        }
        let Ok(reply_key) = KeyExpr::try_from(key.to_owned()) else {
            return;
        };
        let Some(cell) = self.fleet.existing_cell_of(id) else {
            Self::reply_err(query, &format!("robot '{id}' has sent nothing yet"));
            return;
        };
        let Some(mut guard) = self.fleet.unless_stopped(&cell) else {
            return;
        };
        let Some(twin) = guard.twin_mut() else {
            drop(guard);
            Self::reply_err(query, &format!("robot '{id}' has sent nothing yet"));
            return;
        };
        let outcome = match action.as_str() {
            "" | "status" => Ok(()),
            "apply" => twin
                .apply_payload_estimate()
                .map(|applied| {
                    info!(robot = id, mass_kg = applied.mass_kg, cog_m = ?applied.cog_flange_m, "identified payload applied");
                })
                .ok_or_else(|| format!("robot '{id}' has no identified payload to apply")),
            "discard" => {
                twin.discard_applied_payload();
                info!(robot = id, "applied payload discarded");
                Ok(())
            }
            other => Err(format!("'{other}' is not apply, discard or status")),
        };
        let summary = twin.effort();
        drop(guard);
        match (outcome, summary) {
            (Ok(()), Some(summary)) => {
                let mut body = json::payload_readout_json(&summary.payload);
                body["robot"] = serde_json::json!(id);
                body["action"] = serde_json::json!(if action.is_empty() {
                    "status"
                } else {
                    action.as_str()
                });
                Self::reply(query, &reply_key, json::to_json_bytes(&body));
            }
            (Err(message), _) => Self::reply_err(query, &message),
            (Ok(()), None) => {
                Self::reply_err(query, &format!("robot '{id}' has no effort monitor"));
            }
        }
    }

    /// Replaces `cell`'s model by its pending estimate's under its lock; `None` if it has no
    /// estimate (or the service stopped).
    fn apply_estimate(
        &self,
        cell: &RobotCell,
    ) -> Option<Result<CalibrationStatus, ReplaceModelError>> {
        let mut state = self.fleet.unless_stopped(cell)?;
        let estimate = state.calibration_mut().take_estimate()?;
        let model = Arc::clone(&estimate.model);
        let Some((twin, mut sink)) = self.fleet.twin_and_sink(&mut state) else {
            return Some(Err(ReplaceModelError::NotTracked));
        };
        let replaced = twin.replace_model(Arc::clone(&model), &mut sink);
        if replaced.is_ok() {
            sink.model_replaced(cell.robot(), &model);
        }
        drop(sink);
        Some(replaced.map(|_| {
            info!(
                robot = cell.robot().id(),
                improvement = estimate.improvement(),
                "self-calibration applied"
            );
            CalibrationStatus::of(cell.robot(), state.twin(), Some(state.calibration()))
        }))
    }
}
