//! The service's HTTP side (`[http] listen`, `armtwin serve --http`): the fleet page, the robot
//! pages, their live streams (server-sent events), `/metrics` for Prometheus and `/healthz`.
//!
//! It runs on the service's tokio runtime and reads the twin only through
//! a [`FleetSource`] (the service implements it), each robot under its own lock in turn: it keeps no copy
//! of the twin's state beyond one fleet read shared by every fleet page for half a second. Each
//! stream is paced by its own timer that skips missed ticks and reads the twin only when the
//! client's socket takes more, so a slow or stalled browser costs the twin nothing. The pages and
//! three.js are embedded in the binary: nothing is fetched from elsewhere at run time.

mod access;
mod conn;
mod exposition;
mod fleet_page;

use armtwin_view::{
    FleetRow, FleetSource, HttpDoor, OpenHttpDoor, PeerFleet, RobotDetail, ServiceTotals,
};

use std::collections::BTreeMap;
use std::convert::Infallible;
use std::fmt::Write as _;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use axum::Router;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use serde::{Deserialize, Serialize};
use tokio::sync::watch;
use tokio::time::MissedTickBehavior;
use tracing::info;
use zenoh::key_expr::OwnedKeyExpr;

use self::fleet_page::{FleetQuery, fleet_page_json};
use armtwin_access::http_access::{HttpAccess, Token};
use armtwin_mesh::{TEARDOWN_STEP, bounded};

/// Fleet page updates: at most 2 per second per page.
const FLEET_PERIOD: Duration = Duration::from_millis(500);
/// How old the shared fleet read may be when a page's tick comes (a little under the period, so
/// every tick of a page sees a fresh read while ten pages still share one).
const FLEET_READ_MAX_AGE: Duration = Duration::from_millis(450);
/// Robot page updates: at most 30 per second per page (1000 / 30 = 33.3 ms).
const ROBOT_PERIOD: Duration = Duration::from_millis(34);
/// A robot page hears from an idle robot at least this often.
const ROBOT_IDLE_PERIOD: Duration = Duration::from_secs(1);
/// How old the shared read of the fleet's other instances may be: they answer at most once a
/// second, whatever the pages open.
const PEER_READ_MAX_AGE: Duration = Duration::from_secs(1);

/// The dashboard as the service's HTTP door, with who may use it.
#[derive(Debug, Clone)]
pub struct DashboardDoor {
    access: HttpAccess,
}

impl DashboardDoor {
    /// The dashboard, reachable as `access` says (`[http]`'s TLS identity and tokens).
    #[must_use]
    pub fn new(access: HttpAccess) -> Self {
        Self { access }
    }
}

impl HttpDoor for DashboardDoor {
    fn open(
        &self,
        listener: tokio::net::TcpListener,
        fleet: Arc<dyn FleetSource>,
    ) -> Box<dyn OpenHttpDoor> {
        Box::new(Dashboard::start(listener, &self.access, fleet))
    }
}

impl OpenHttpDoor for Dashboard {
    fn close(self: Box<Self>) -> std::pin::Pin<Box<dyn std::future::Future<Output = ()> + Send>> {
        Box::pin(self.stop())
    }
}

/// The running HTTP server.
struct Dashboard {
    stopping: watch::Sender<bool>,
    task: tokio::task::JoinHandle<()>,
}

impl Dashboard {
    /// Serves the dashboard on `listener` (already bound), as `access` says, until
    /// [`Dashboard::stop`].
    fn start(
        listener: tokio::net::TcpListener,
        access: &HttpAccess,
        view: Arc<dyn FleetSource>,
    ) -> Self {
        let (stopping, stop_rx) = watch::channel(false);
        let address = listener
            .local_addr()
            .map_or_else(|_| "?".to_owned(), |address| address.to_string());
        info!(
            %address,
            tls = access.tls.is_some(),
            tokens = access.tokens.len(),
            "dashboard listening"
        );
        let mut app = router(AppState {
            view,
            fleet: Arc::new(Shared::new()),
            peers: Arc::new(Shared::new()),
            stopping: stop_rx.clone(),
        });
        if !access.tokens.is_empty() {
            let tokens: Arc<[Token]> = access.tokens.clone().into();
            app = app.layer(axum::middleware::from_fn_with_state(tokens, access::guard));
        }
        let task = conn::serve(listener, access.tls.clone(), app, stop_rx);
        Self { stopping, task }
    }

    /// Ends every stream, stops accepting connections and waits (bounded) for the server.
    async fn stop(self) {
        info!("shutting down: stopping the dashboard");
        let _ = self.stopping.send(true);
        bounded("stopping the dashboard", TEARDOWN_STEP, self.task).await;
    }
}

/// One read of the fleet, shared by the fleet pages and `/metrics` for a moment.
struct FleetRead {
    /// When the read began.
    taken: Instant,
    totals: ServiceTotals,
    rows: Vec<FleetRow>,
    /// Each row's id as a key expression, for filters (`None` for an id that is not one).
    keys: Vec<Option<OwnedKeyExpr>>,
    /// The robots with a gateway token, and whether it streams.
    gateways: Vec<(Arc<str>, bool)>,
    /// The robots the configuration names.
    expected: Arc<[Arc<str>]>,
}

/// The fleet's other instances' robots, read through the mesh for the fleet pages.
struct PeerRead {
    /// The key expression of the robots this instance twins.
    own_shard: Arc<str>,
    fleet: PeerFleet,
    /// Each row's id as a key expression, for filters.
    keys: Vec<Option<OwnedKeyExpr>>,
}

/// A read shared by every page that asks for it while it is fresh: pages whose ticks meet wait
/// for one read, run on a blocking thread.
struct Shared<T> {
    latest: Mutex<Option<(Instant, Arc<T>)>>,
    /// Held while a read runs.
    reading: tokio::sync::Mutex<()>,
}

impl<T: Send + Sync + 'static> Shared<T> {
    fn new() -> Self {
        Self {
            latest: Mutex::new(None),
            reading: tokio::sync::Mutex::new(()),
        }
    }

    /// The latest read, or a new one by `read` if it began `max_age` or longer ago (`failed`
    /// stands for a read that panicked, until the next one).
    async fn get(
        &self,
        max_age: Duration,
        read: impl FnOnce() -> T + Send + 'static,
        failed: fn() -> T,
    ) -> Arc<T> {
        let asked = Instant::now();
        let fresh = || {
            let latest = self
                .latest
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .clone();
            // A read begun after the ask is fresh whatever `max_age` (zero for `/metrics`).
            latest
                .filter(|(taken, _)| *taken >= asked || taken.elapsed() < max_age)
                .map(|(_, value)| value)
        };
        if let Some(value) = fresh() {
            return value;
        }
        let _reading = self.reading.lock().await;
        if let Some(value) = fresh() {
            return value;
        }
        let (taken, value) = tokio::task::spawn_blocking(move || (Instant::now(), read()))
            .await
            .unwrap_or_else(|_| (Instant::now(), failed()));
        let value = Arc::new(value);
        *self.latest.lock().unwrap_or_else(PoisonError::into_inner) =
            Some((taken, Arc::clone(&value)));
        value
    }
}

#[derive(Clone)]
struct AppState {
    view: Arc<dyn FleetSource>,
    fleet: Arc<Shared<FleetRead>>,
    peers: Arc<Shared<PeerRead>>,
    stopping: watch::Receiver<bool>,
}

impl AppState {
    /// The shared fleet read, read again if older than `max_age`: it takes every robot's lock
    /// in turn.
    async fn fleet(&self, max_age: Duration) -> Arc<FleetRead> {
        let view = self.view.clone();
        let read = move || {
            // When the read began: what it shows is no older than this.
            let taken = Instant::now();
            let (totals, rows) = view.fleet();
            let keys = rows.iter().map(|row| key_of(&row.id)).collect();
            FleetRead {
                taken,
                totals,
                rows,
                keys,
                gateways: view.gateways(),
                expected: view.expected(),
            }
        };
        // Only a panic of the read gives an empty fleet, until the next read.
        let failed = || FleetRead {
            taken: Instant::now(),
            totals: ServiceTotals::default(),
            rows: Vec::new(),
            keys: Vec::new(),
            gateways: Vec::new(),
            expected: Arc::new([]),
        };
        self.fleet.get(max_age, read, failed).await
    }

    /// The shared read of the fleet's other instances, at most one a [`PEER_READ_MAX_AGE`].
    async fn peers(&self) -> Arc<PeerRead> {
        let view = self.view.clone();
        let read = move || {
            let fleet = view.peers();
            let keys = fleet.rows.iter().map(|row| key_of(&row.id)).collect();
            PeerRead {
                own_shard: view.own_shard(),
                fleet,
                keys,
            }
        };
        let failed = || PeerRead {
            own_shard: Arc::from(""),
            fleet: PeerFleet::default(),
            keys: Vec::new(),
        };
        self.peers.get(PEER_READ_MAX_AGE, read, failed).await
    }
}

/// A robot id as a key expression, for filters (`None` for an id that is not one).
fn key_of(id: &str) -> Option<OwnedKeyExpr> {
    OwnedKeyExpr::try_from(id).ok()
}

fn router(state: AppState) -> Router {
    Router::new()
        .route("/", get(fleet_page))
        .route("/robot/{*id}", get(robot_page))
        .route("/assets/{*path}", get(asset))
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics))
        .route("/api/fleet", get(fleet_json))
        .route("/api/fleet/stream", get(fleet_stream))
        .route("/api/robot", get(robot_json))
        .route("/api/robot/frames", get(robot_frames))
        .route("/api/robot/history", get(robot_history))
        .route("/api/robot/recordings", get(robot_recordings))
        .route("/api/robot/recording", get(robot_recording))
        .route("/api/robot/stream", get(robot_stream))
        .fallback(not_found)
        .with_state(state)
}

// ---------------------------------------------------------------------------------------------
// Pages and assets

const FLEET_HTML: &str = include_str!("assets/fleet.html");
const ROBOT_HTML: &str = include_str!("assets/robot.html");
const NOT_FOUND_HTML: &str = include_str!("assets/not_found.html");

/// The embedded files under `/assets/`: name, content type, bytes.
const ASSETS: [(&str, &str, &[u8]); 6] = [
    (
        "dashboard.css",
        "text/css; charset=utf-8",
        include_bytes!("assets/dashboard.css"),
    ),
    (
        "fleet.js",
        "text/javascript; charset=utf-8",
        include_bytes!("assets/fleet.js"),
    ),
    (
        "robot.js",
        "text/javascript; charset=utf-8",
        include_bytes!("assets/robot.js"),
    ),
    (
        "vendor/three/three.module.js",
        "text/javascript; charset=utf-8",
        include_bytes!("assets/vendor/three/three.module.js"),
    ),
    (
        "vendor/three/three.core.js",
        "text/javascript; charset=utf-8",
        include_bytes!("assets/vendor/three/three.core.js"),
    ),
    (
        "vendor/three/LICENSE",
        "text/plain; charset=utf-8",
        include_bytes!("assets/vendor/three/LICENSE"),
    ),
];

async fn fleet_page() -> Html<&'static str> {
    Html(FLEET_HTML)
}

async fn robot_page(State(state): State<AppState>, Path(id): Path<String>) -> Response {
    if state.view.poses_of(&id).is_none() {
        return not_found().await;
    }
    Html(ROBOT_HTML).into_response()
}

async fn asset(Path(path): Path<String>) -> Response {
    match ASSETS.iter().find(|(name, _, _)| *name == path) {
        Some(&(_, content_type, bytes)) => (
            [
                (header::CONTENT_TYPE, HeaderValue::from_static(content_type)),
                (
                    header::CACHE_CONTROL,
                    HeaderValue::from_static("public, max-age=3600"),
                ),
            ],
            bytes,
        )
            .into_response(),
        None => not_found().await,
    }
}

async fn not_found() -> Response {
    (StatusCode::NOT_FOUND, Html(NOT_FOUND_HTML)).into_response()
}

async fn healthz() -> &'static str {
    "ok\n"
}

async fn metrics(State(state): State<AppState>) -> Response {
    // A scrape sees the twin as it is at the scrape: no shared read older than it.
    let read = state.fleet(Duration::ZERO).await;
    let text = exposition::render(&read.totals, &read.rows, &read.gateways, &read.expected);
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/openmetrics-text; version=1.0.0; charset=utf-8"),
        )],
        text,
    )
        .into_response()
}

/// A 4xx answer with a one-line reason.
fn bad_request(status: StatusCode, reason: &str) -> Response {
    let body = serde_json::json!({ "error": reason }).to_string();
    (
        status,
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        body,
    )
        .into_response()
}

// ---------------------------------------------------------------------------------------------
// The fleet

fn json_response(body: String) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        body,
    )
        .into_response()
}

async fn fleet_json(State(state): State<AppState>, Query(query): Query<FleetQuery>) -> Response {
    let selection = match query.check() {
        Ok(selection) => selection,
        Err(reason) => return bad_request(StatusCode::BAD_REQUEST, &reason),
    };
    let (read, peers) = tokio::join!(state.fleet(FLEET_READ_MAX_AGE), state.peers());
    json_response(fleet_page_json(&read, &peers, &selection))
}

/// Events from `next` every `period` (missed ticks skipped), until the service stops; `next`
/// returning `None` sends nothing on that tick.
fn paced<S, F, Fut>(state: &AppState, period: Duration, context: S, next: F) -> Response
where
    S: Send + 'static,
    F: FnMut(&mut S) -> Fut + Send + 'static,
    Fut: Future<Output = Option<String>> + Send,
{
    let mut interval = tokio::time::interval(period);
    interval.set_missed_tick_behavior(MissedTickBehavior::Skip);
    let stopping = state.stopping.clone();
    let stream = futures_util::stream::unfold(
        (interval, stopping, context, next),
        |(mut interval, mut stopping, mut context, mut next)| async move {
            loop {
                if *stopping.borrow() {
                    return None;
                }
                tokio::select! {
                    _ = interval.tick() => {}
                    _ = stopping.changed() => return None,
                }
                if let Some(data) = next(&mut context).await {
                    let event = Event::default().data(data);
                    return Some((
                        Ok::<_, Infallible>(event),
                        (interval, stopping, context, next),
                    ));
                }
            }
        },
    );
    Sse::new(stream)
        .keep_alive(KeepAlive::default())
        .into_response()
}

async fn fleet_stream(State(state): State<AppState>, Query(query): Query<FleetQuery>) -> Response {
    let selection = match query.check() {
        Ok(selection) => Arc::new(selection),
        Err(reason) => return bad_request(StatusCode::BAD_REQUEST, &reason),
    };
    let app = state.clone();
    paced(&state, FLEET_PERIOD, (), move |()| {
        let (app, selection) = (app.clone(), Arc::clone(&selection));
        async move {
            let (read, peers) = tokio::join!(app.fleet(FLEET_READ_MAX_AGE), app.peers());
            Some(fleet_page_json(&read, &peers, &selection))
        }
    })
}

// ---------------------------------------------------------------------------------------------
// One robot

/// `?id=<robot id>`.
#[derive(Debug, Deserialize)]
struct RobotQuery {
    id: String,
}

#[derive(Serialize)]
struct FrameJson {
    position_m: [f64; 3],
    quaternion_xyzw: [f64; 4],
}

#[derive(Serialize)]
struct RobotJson<'a> {
    state: &'a armtwin_codec::json::StateMessage,
    /// The chain's link frames for the last valid joints, base to TCP (`null` before any).
    frames: Option<Vec<FrameJson>>,
    poses: u64,
    /// By cause name, in name order (a stable line on a page that redraws many times a second).
    rejected_by_cause: BTreeMap<&'static str, u64>,
    /// The robot's last published events, oldest first.
    events: Vec<serde_json::Value>,
}

/// The link frames of `detail`'s last joints with its model, if it has had joints.
fn frames_of(detail: &RobotDetail) -> Option<Vec<FrameJson>> {
    let joints = detail.state.joints.as_ref()?;
    let frames = detail.model.chain().link_frames(&joints.q).ok()?;
    Some(
        frames
            .iter()
            .map(|pose| {
                let readout = pose.readout();
                FrameJson {
                    position_m: readout.position_m,
                    quaternion_xyzw: readout.quaternion_xyzw,
                }
            })
            .collect(),
    )
}

fn robot_json_of(detail: &RobotDetail) -> String {
    let message = RobotJson {
        state: &detail.state,
        frames: frames_of(detail),
        poses: detail.counts.poses,
        rejected_by_cause: detail
            .counts
            .rejected_by_cause
            .iter()
            .map(|&(cause, count)| (cause.as_str(), count))
            .collect(),
        events: detail
            .counts
            .recent_events
            .iter()
            .filter_map(|event| serde_json::from_slice(event).ok())
            .collect(),
    };
    serde_json::to_string(&message).unwrap_or_default()
}

fn unknown_robot(id: &str) -> Response {
    bad_request(
        StatusCode::NOT_FOUND,
        &format!("robot '{id}' is not tracked"),
    )
}

async fn robot_json(State(state): State<AppState>, Query(query): Query<RobotQuery>) -> Response {
    match state.view.robot(&query.id) {
        Some(detail) => json_response(robot_json_of(&detail)),
        None => unknown_robot(&query.id),
    }
}

async fn robot_frames(State(state): State<AppState>, Query(query): Query<RobotQuery>) -> Response {
    let Some(detail) = state.view.robot(&query.id) else {
        return unknown_robot(&query.id);
    };
    let mut body = String::new();
    let frame = detail.state.frame;
    let model = detail.state.model.clone();
    let frames = frames_of(&detail);
    let message = serde_json::json!({
        "robot": query.id,
        "model": model,
        "frame": frame,
        "t": detail.state.joints.as_ref().map(|joints| joints.t),
        "q": detail.state.joints.as_ref().map(|joints| joints.q.clone()),
        "frames": frames,
    });
    let _ = write!(body, "{message}");
    json_response(body)
}

async fn robot_history(State(state): State<AppState>, Query(query): Query<RobotQuery>) -> Response {
    match state.view.history(&query.id) {
        Some(message) => json_response(serde_json::to_string(&message).unwrap_or_default()),
        None => unknown_robot(&query.id),
    }
}

async fn robot_recordings(
    State(state): State<AppState>,
    Query(query): Query<RobotQuery>,
) -> Response {
    // A directory listing: off the runtime's threads.
    let (view, id) = (Arc::clone(&state.view), query.id.clone());
    let files = tokio::task::spawn_blocking(move || view.recordings(&id))
        .await
        .unwrap_or_default();
    match files {
        Some(files) => {
            json_response(serde_json::json!({"robot": query.id, "files": files}).to_string())
        }
        None => unknown_robot(&query.id),
    }
}

#[derive(Deserialize)]
struct RecordingQuery {
    id: String,
    name: String,
}

/// The largest file the dashboard hands out: incident files hold seconds of streams; a longer
/// `armtwin record` file is read from the recorder's directory, not downloaded here.
const MAX_DOWNLOAD_BYTES: u64 = 256 * 1024 * 1024;

async fn robot_recording(
    State(state): State<AppState>,
    Query(query): Query<RecordingQuery>,
) -> Response {
    // Only a name the listing gives is looked up, so no request names a path of its own; the
    // listing reads a directory, off the runtime's threads.
    let (view, id, name) = (
        Arc::clone(&state.view),
        query.id.clone(),
        query.name.clone(),
    );
    let found = tokio::task::spawn_blocking(move || view.recording_file(&id, &name))
        .await
        .unwrap_or_default();
    let Some((path, size)) = found else {
        return bad_request(
            StatusCode::NOT_FOUND,
            &format!("robot '{}' has no recording '{}'", query.id, query.name),
        );
    };
    if size > MAX_DOWNLOAD_BYTES {
        return bad_request(
            StatusCode::PAYLOAD_TOO_LARGE,
            &format!(
                "'{}' is {size} bytes: read it from the recorder's directory",
                query.name
            ),
        );
    }
    match tokio::fs::read(&path).await {
        Ok(bytes) => (
            [
                (
                    header::CONTENT_TYPE,
                    HeaderValue::from_static("application/octet-stream"),
                ),
                (
                    header::CONTENT_DISPOSITION,
                    // The listed names are ASCII letters, digits, `.`, `-` and `T`/`Z`.
                    HeaderValue::from_str(&format!("attachment; filename=\"{}\"", query.name))
                        .unwrap_or_else(|_| HeaderValue::from_static("attachment")),
                ),
            ],
            bytes,
        )
            .into_response(),
        Err(error) => bad_request(
            StatusCode::NOT_FOUND,
            &format!("'{}' cannot be read: {error}", query.name),
        ),
    }
}

/// Where a robot page's stream is: the pose count it last sent at, and when.
struct RobotCursor {
    id: String,
    sent_poses: Option<u64>,
    sent_at: Instant,
}

async fn robot_stream(State(state): State<AppState>, Query(query): Query<RobotQuery>) -> Response {
    if state.view.poses_of(&query.id).is_none() {
        return unknown_robot(&query.id);
    }
    let view = state.view.clone();
    let cursor = RobotCursor {
        id: query.id,
        sent_poses: None,
        sent_at: Instant::now(),
    };
    paced(&state, ROBOT_PERIOD, cursor, move |cursor| {
        // The pose count alone is read each tick; the full state only when it moved (or once a
        // second for an idle robot, whose counters and events may still change).
        let poses = view.poses_of(&cursor.id);
        let due = poses != cursor.sent_poses || cursor.sent_at.elapsed() >= ROBOT_IDLE_PERIOD;
        let data = if due {
            view.robot(&cursor.id).map(|detail| {
                cursor.sent_poses = Some(detail.counts.poses);
                cursor.sent_at = Instant::now();
                robot_json_of(&detail)
            })
        } else {
            None
        };
        std::future::ready(data)
    })
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "values are copied, not computed")]
mod tests {
    use super::fleet_page::{FleetSelection, MAX_PAGE_ROWS};
    use super::*;
    use armtwin_core::metrics::{Metric, StatsSet};
    use armtwin_core::pipeline::{Alarms, MetricsReadout};
    use armtwin_view::{PeerRow, RobotCounts};

    fn row(id: &str, position_m: f64, paired: u64, alarm: bool) -> FleetRow {
        let mut window = StatsSet {
            n: paired,
            ..StatsSet::default()
        };
        window.stats[Metric::Position.index()].mae = position_m;
        FleetRow {
            id: Arc::from(id),
            metrics: MetricsReadout {
                robot: id.to_owned(),
                stamp_s: 1.0,
                paired,
                unpaired: 0,
                rejected: 0,
                cumulative: StatsSet::default(),
                window,
                window_s: 10.0,
                epoch: 0,
                effort: None,
            },
            alarms_active: Alarms {
                position: alarm,
                angle: false,
            },
            counts: RobotCounts::default(),
            joint_state: None,
            last_sample_age_s: 0.25,
        }
    }

    fn read(rows: Vec<FleetRow>) -> FleetRead {
        let keys = rows
            .iter()
            .map(|row| OwnedKeyExpr::try_from(&*row.id).ok())
            .collect();
        FleetRead {
            taken: Instant::now(),
            totals: ServiceTotals::default(),
            rows,
            keys,
            gateways: Vec::new(),
            expected: Arc::new([]),
        }
    }

    fn peers(own_shard: &str, rows: Vec<PeerRow>) -> PeerRead {
        PeerRead {
            own_shard: Arc::from(own_shard),
            keys: rows.iter().map(|row| key_of(&row.id)).collect(),
            fleet: PeerFleet {
                rows,
                truncated: false,
            },
        }
    }

    fn no_peers() -> PeerRead {
        peers("**", Vec::new())
    }

    fn peer(id: &str, shard: &str, position_m: f64, alarm: bool) -> PeerRow {
        PeerRow {
            id: Arc::from(id),
            shard: Some(Arc::from(shard)),
            position_m,
            angle_rad: 0.0,
            window_n: 4,
            paired: 40,
            unpaired: 0,
            rejected: 0,
            alarm_position: alarm,
            alarm_angle: false,
        }
    }

    fn select(query: &str) -> Result<FleetSelection, String> {
        let query: FleetQuery = serde_json::from_str(query).expect("query");
        query.check()
    }

    fn robots(page: &str) -> Vec<String> {
        let page: serde_json::Value = serde_json::from_str(page).expect("JSON");
        page["rows"]
            .as_array()
            .expect("rows")
            .iter()
            .map(|row| row["robot"].as_str().expect("robot").to_owned())
            .collect()
    }

    fn fleet() -> FleetRead {
        read(vec![
            row("a/1", 0.003, 10, false),
            row("a/2", 0.001, 30, true),
            row("b/1", 0.002, 20, false),
        ])
    }

    #[test]
    fn filters_by_key_expression_sorts_and_pages() {
        let fleet = fleet();
        let all = select("{}").expect("valid");
        assert_eq!(
            robots(&fleet_page_json(&fleet, &no_peers(), &all)),
            ["a/1", "a/2", "b/1"]
        );
        let only_a = select(r#"{"filter": "a/*"}"#).expect("valid");
        assert_eq!(
            robots(&fleet_page_json(&fleet, &no_peers(), &only_a)),
            ["a/1", "a/2"]
        );
        let by_error = select(r#"{"sort": "position", "order": "desc"}"#).expect("valid");
        assert_eq!(
            robots(&fleet_page_json(&fleet, &no_peers(), &by_error)),
            ["a/1", "b/1", "a/2"]
        );
        let paged = select(r#"{"sort": "paired", "offset": 1, "limit": 1}"#).expect("valid");
        let page: serde_json::Value =
            serde_json::from_str(&fleet_page_json(&fleet, &no_peers(), &paged)).expect("JSON");
        assert_eq!(page["matched"], 3);
        assert_eq!(page["alarms"], 1);
        assert_eq!(robots(&page.to_string()), ["b/1"]);
        assert_eq!(page["rows"][0]["position_m"], 0.002);
        assert!(page["rows"][0]["age_s"].is_null(), "never active");
    }

    #[test]
    fn the_other_instances_robots_join_the_page_with_their_shard() {
        let fleet = fleet();
        let others = peers(
            "a/**",
            vec![
                // Twinned here too (a claim that changed hands): this instance's row wins.
                peer("a/1", "x/**", 0.5, false),
                peer("0/9", "0/**", 0.004, true),
                peer("c/1", "c/**", 0.0, false),
            ],
        );
        let page = |query: &str| -> serde_json::Value {
            let selection = select(query).expect("valid");
            serde_json::from_str(&fleet_page_json(&fleet, &others, &selection)).expect("JSON")
        };
        let all = page("{}");
        assert_eq!(
            robots(&all.to_string()),
            ["0/9", "a/1", "a/2", "b/1", "c/1"]
        );
        assert_eq!(
            (all["matched"].clone(), all["alarms"].clone()),
            (5.into(), 2.into())
        );
        assert_eq!(all["shard"], "a/**");
        let shards: Vec<_> = all["rows"]
            .as_array()
            .expect("rows")
            .iter()
            .map(|row| (row["shard"].as_str(), row["local"].as_bool()))
            .collect();
        assert_eq!(
            shards,
            [
                (Some("0/**"), Some(false)),
                (Some("a/**"), Some(true)),
                (Some("a/**"), Some(true)),
                (Some("a/**"), Some(true)),
                (Some("c/**"), Some(false)),
            ]
        );
        assert_eq!(all["rows"][1]["position_m"], 0.003, "this instance's a/1");
        assert!(all["rows"][0]["poses"].is_null() && all["rows"][0]["age_s"].is_null());
        assert_eq!(robots(&page(r#"{"filter": "0/**"}"#).to_string()), ["0/9"]);
        let by_error = page(r#"{"sort": "position", "order": "desc", "limit": 2}"#);
        assert_eq!(robots(&by_error.to_string()), ["0/9", "a/1"]);
        assert_eq!(
            robots(&page(r#"{"sort": "shard"}"#).to_string()),
            ["0/9", "a/1", "a/2", "b/1", "c/1"]
        );
    }

    #[test]
    fn refuses_bad_filters_and_bounds_the_page() {
        assert!(select(r#"{"filter": "a**b"}"#).is_err());
        let long = format!(r#"{{"filter": "{}"}}"#, "a/".repeat(600));
        assert!(select(&long).is_err());
        assert_eq!(
            select(r#"{"limit": 1000000}"#).expect("valid").limit,
            MAX_PAGE_ROWS
        );
        assert_eq!(select(r#"{"limit": 0}"#).expect("valid").limit, 1);
    }

    #[test]
    fn the_exposition_escapes_ids_and_names_base_units() {
        let mut quoted = row("cell/\"odd\"\\id", 0.004, 5, true);
        quoted.counts.poses = 7;
        quoted.counts.rejected_by_cause =
            vec![(armtwin_core::pipeline::RejectCause::Decode("not_json"), 2)];
        let gateways = [
            (Arc::from("cell/\"odd\"\\id"), true),
            (Arc::from("gone"), false),
        ];
        let expected = [Arc::from("cell/\"odd\"\\id"), Arc::from("cell/silent")];
        let text = exposition::render(&ServiceTotals::default(), &[quoted], &gateways, &expected);
        let robot = r#"robot="cell/\"odd\"\\id""#;
        for line in [
            format!("armtwin_position_error_mae_meters{{{robot},scope=\"window\"}} 0.004"),
            format!("armtwin_poses_total{{{robot}}} 7"),
            format!("armtwin_rejected_total{{{robot},cause=\"not_json\"}} 2"),
            format!("armtwin_alarm_active{{{robot},metric=\"position\"}} 1"),
            format!("armtwin_robot_last_sample_age_seconds{{{robot}}} 0.25"),
            format!("armtwin_gateway_streaming{{{robot}}} 1"),
            "armtwin_gateway_streaming{robot=\"gone\"} 0".to_owned(),
            format!("armtwin_robot_expected{{{robot}}} 1"),
            "armtwin_robot_expected{robot=\"cell/silent\"} 1".to_owned(),
            "armtwin_robots_tracked 0".to_owned(),
            "armtwin_robots_refused_total 0".to_owned(),
            "armtwin_robots_retired_total 0".to_owned(),
            "armtwin_snapshot_failures_total 0".to_owned(),
            "armtwin_descriptions_refused_total 0".to_owned(),
            "armtwin_history_log_dropped_total 0".to_owned(),
            "armtwin_history_log_write_failures_total 0".to_owned(),
            "armtwin_history_log_bytes 0".to_owned(),
        ] {
            assert!(text.contains(&line), "{line} not in\n{text}");
        }
        assert!(text.ends_with("# EOF\n"), "{text}");
        assert!(
            !text.contains("snapshot_age"),
            "no snapshot written, no age"
        );
        let totals = ServiceTotals {
            snapshot_age_s: Some(2.5),
            ..ServiceTotals::default()
        };
        let text = exposition::render(&totals, &[], &[], &[]);
        assert!(text.contains("armtwin_snapshot_age_seconds 2.5"), "{text}");
    }
}
