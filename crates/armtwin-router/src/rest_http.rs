//! The REST API's HTTP: each request becomes one put, delete, query or subscription of one Zenoh
//! session (the router's own, or a client's with an identity, as [`crate::rest`] decides), and
//! every request is bounded before it reaches Zenoh.
//!
//! Why not `zenoh-plugin-rest`: 1.10.2 reads a request body whole whatever its size (the router
//! grows by the body; `tests/python/test_rest_bounds.py` measures it), answers every origin with `Access-Control-Allow-Origin: *`,
//! and turns any `GET` into a Zenoh query, so a link in a web page (`GET
//! /twin/admin/reset/r1`) resets a twin. None of it is configurable and its router is private,
//! so it cannot be bounded from inside; a bounded proxy in front of it would leave the plugin's
//! own port open to every process of the host. The API is four verbs on one session, so this
//! file serves it in a few hundred lines, with the plugin's request and answer formats (JSON
//! array of `{key, value, encoding, timestamp}`, `?_raw`, `text/event-stream`).
//!
//! The doors it keeps shut:
//! - size: a body over [`MAX_BODY_BYTES`] is answered 413, from its `Content-Length` before a
//!   byte is read, or as soon as a streamed body passes the bound; a query's answer stops at
//!   [`MAX_ANSWER_BYTES`];
//! - time: headers within [`HEADER_DEADLINE`], a body within [`BODY_DEADLINE`];
//! - count: at most [`MAX_CONNECTIONS`] connections at once (an event stream holds one);
//! - origin: a request that carries an `Origin` (a browser's, from some web page) is refused
//!   unless that origin is configured (`--rest-allow-origin`): the API serves no page of its
//!   own, so no same-origin caller exists;
//! - changes by reading: a query (`GET`, `POST`) whose key expression has an `admin` chunk is
//!   refused. armtwin changes a twin only for a query within `<prefix>/admin/<change>/**`, so a
//!   change can only be asked with that chunk spelled out; queries are what a browser sends
//!   from any page without asking (a link, an image, a form), so REST never carries them.
//!   Changes stay on Zenoh, where the router's access control rules them.
//!
//! Must not know armtwin's keys beyond the `admin` chunk, nor decide where REST runs.

use std::convert::Infallible;
use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::extract::{Request, State};
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use base64::Engine;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio::sync::{Semaphore, mpsc};
use zenoh::Session;
use zenoh::bytes::{Encoding, ZBytes};
use zenoh::key_expr::KeyExpr;
use zenoh::qos::CongestionControl;
use zenoh::query::{ConsolidationMode, Parameters, QueryConsolidation, Selector, ZenohParameters};
use zenoh::sample::Sample;

/// The largest request body: joint samples are hundreds of bytes; a few MiB leaves room for a
/// calibration or a model and none for a flood.
pub const MAX_BODY_BYTES: usize = 4 << 20;
/// The most payload bytes one query's answer collects before it is cut off (507).
pub const MAX_ANSWER_BYTES: usize = 16 << 20;
/// Connections served at once; the next waits in the kernel's backlog.
pub const MAX_CONNECTIONS: usize = 256;
/// Time for a request's headers to arrive.
pub const HEADER_DEADLINE: Duration = Duration::from_secs(10);
/// Time for a request's body to arrive, whole.
pub const BODY_DEADLINE: Duration = Duration::from_secs(30);
/// Samples an event stream holds for a slow reader; beyond, new ones are dropped for it alone,
/// so that its reader never holds up the session that feeds it.
const EVENT_STREAM_DEPTH: usize = 256;
/// The query parameter that asks for the first reply's payload as is.
const RAW_KEY: &str = "_raw";

#[derive(Clone)]
struct Door {
    session: Session,
    allowed_origins: Arc<[String]>,
}

/// Serves REST on `listener` with `session` until `shutdown` resolves; requests from a browser
/// page are served only if its origin is in `allowed_origins` (`scheme://host[:port]`).
pub async fn serve(
    listener: TcpListener,
    session: Session,
    allowed_origins: Vec<String>,
    shutdown: impl Future<Output = ()>,
) {
    let door = Door {
        session,
        allowed_origins: allowed_origins.into(),
    };
    let app = Router::new()
        .fallback(route)
        .layer(middleware::from_fn_with_state(door.clone(), origin_gate))
        .with_state(door);
    let permits = Arc::new(Semaphore::new(MAX_CONNECTIONS));
    let accept = async {
        loop {
            let Ok(permit) = permits.clone().acquire_owned().await else {
                return;
            };
            let (stream, peer) = match listener.accept().await {
                Ok(accepted) => accepted,
                Err(e) => {
                    // Out of descriptors, most likely: wait rather than spin.
                    tracing::warn!(error = %e, "REST cannot accept a connection");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            };
            let service = TowerToHyperService::new(app.clone());
            tokio::spawn(async move {
                let served = hyper::server::conn::http1::Builder::new()
                    .timer(TokioTimer::new())
                    .header_read_timeout(HEADER_DEADLINE)
                    .serve_connection(TokioIo::new(stream), service)
                    .await;
                if let Err(e) = served {
                    tracing::debug!(%peer, error = %e, "REST connection ended");
                }
                drop(permit);
            });
        }
    };
    tokio::select! {
        () = accept => {}
        () = shutdown => {}
    }
}

/// Binds REST's address, before anything else starts, so a taken port stops the router at once.
pub async fn bind(address: SocketAddr) -> std::io::Result<TcpListener> {
    TcpListener::bind(address).await
}

fn refuse(status: StatusCode, why: impl Into<String>) -> Response {
    (status, why.into()).into_response()
}

/// Refuses a browser page's request unless its origin is configured, and tells the browser so
/// (`Access-Control-Allow-*`) when it is.
async fn origin_gate(State(door): State<Door>, request: Request, next: Next) -> Response {
    let Some(origin) = request.headers().get(header::ORIGIN).cloned() else {
        return next.run(request).await;
    };
    let allowed = origin
        .to_str()
        .is_ok_and(|origin| door.allowed_origins.iter().any(|o| o == origin));
    if !allowed {
        return refuse(
            StatusCode::FORBIDDEN,
            "a web page's request (Origin) is served only from an origin the router allows \
             (--rest-allow-origin)",
        );
    }
    let mut response = if request.method() == Method::OPTIONS {
        let mut preflight = StatusCode::NO_CONTENT.into_response();
        let headers = preflight.headers_mut();
        headers.insert(
            header::ACCESS_CONTROL_ALLOW_METHODS,
            HeaderValue::from_static("GET, POST, PUT, PATCH, DELETE"),
        );
        headers.insert(
            header::ACCESS_CONTROL_ALLOW_HEADERS,
            HeaderValue::from_static("content-type, accept"),
        );
        headers.insert(
            header::ACCESS_CONTROL_MAX_AGE,
            HeaderValue::from_static("600"),
        );
        preflight
    } else {
        next.run(request).await
    };
    let headers = response.headers_mut();
    headers.insert(header::ACCESS_CONTROL_ALLOW_ORIGIN, origin);
    headers.insert(header::VARY, HeaderValue::from_static("origin"));
    response
}

async fn route(State(door): State<Door>, request: Request) -> Response {
    let key_expr = match key_expr_of(&door.session, request.uri().path()) {
        Ok(key_expr) => key_expr,
        Err(refusal) => return refusal,
    };
    let method = request.method().clone();
    let reads = method == Method::GET || method == Method::POST;
    if !reads && method != Method::PUT && method != Method::PATCH && method != Method::DELETE {
        return refuse(
            StatusCode::METHOD_NOT_ALLOWED,
            "GET, POST, PUT, PATCH or DELETE",
        );
    }
    if reads && key_expr.split('/').any(|chunk| chunk == "admin") {
        return refuse(
            StatusCode::FORBIDDEN,
            "REST does not ask for changes: a query under admin/ is asked on Zenoh, where the \
             access control and the service's admin rule decide",
        );
    }
    let event_stream = reads && accepts_event_stream(request.headers());
    let encoding = request
        .headers()
        .get(header::CONTENT_TYPE)
        .map_or_else(Encoding::default, |value| {
            Encoding::from(String::from_utf8_lossy(value.as_bytes()).as_ref())
        });
    let parameters = request.uri().query().unwrap_or_default().to_owned();
    let body = match read_body(request.into_body(), request_length(&method)).await {
        Ok(body) => body,
        Err(refusal) => return refusal,
    };
    if event_stream {
        return subscribe(&door.session, key_expr).await;
    }
    if reads {
        return query(&door.session, key_expr, &parameters, encoding, body).await;
    }
    // A 200 says the write went out: it waits for room on a busy link (Zenoh closes a link
    // that stays stuck) rather than being dropped, as a put is by default.
    let result = if method == Method::DELETE {
        door.session
            .delete(key_expr)
            .congestion_control(CongestionControl::Block)
            .await
    } else {
        door.session
            .put(key_expr, body)
            .encoding(encoding)
            .congestion_control(CongestionControl::Block)
            .await
    };
    match result {
        Ok(()) => StatusCode::OK.into_response(),
        Err(e) => refuse(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()),
    }
}

/// The key expression a path names (`@/local` is this session's admin space, as in the plugin).
#[expect(
    clippy::result_large_err,
    reason = "the refusal is the response, built once"
)]
fn key_expr_of(session: &Session, path: &str) -> Result<KeyExpr<'static>, Response> {
    let path = path.trim_start_matches('/');
    let path = match path.strip_prefix("@/local") {
        Some(rest) if rest.is_empty() || rest.starts_with('/') => {
            format!("@/{}{rest}", session.zid())
        }
        _ => path.to_owned(),
    };
    KeyExpr::try_from(path).map_err(|e| refuse(StatusCode::BAD_REQUEST, e.to_string()))
}

fn accepts_event_stream(headers: &HeaderMap) -> bool {
    headers
        .get(header::ACCEPT)
        .and_then(|h| h.to_str().ok())
        .and_then(|h| h.split(',').next())
        .and_then(|h| h.split(';').next())
        .is_some_and(|h| h.trim() == "text/event-stream")
}

/// What a request of `method` may send: everything but `DELETE` may carry a body.
fn request_length(method: &Method) -> usize {
    if method == Method::DELETE {
        0
    } else {
        MAX_BODY_BYTES
    }
}

/// The body, at most `limit` bytes within [`BODY_DEADLINE`]: 413 from a `Content-Length` over
/// the limit before reading, or once a streamed body passes it (hyper then closes the
/// connection rather than read the rest); 408 past the deadline.
async fn read_body(body: Body, limit: usize) -> Result<ZBytes, Response> {
    let too_large = || {
        refuse(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("a REST request's body is at most {limit} bytes"),
        )
    };
    // A `Content-Length` is the hint's lower bound (a chunked body's is 0).
    if http_body::Body::size_hint(&body).lower() > limit as u64 {
        return Err(too_large());
    }
    match tokio::time::timeout(BODY_DEADLINE, axum::body::to_bytes(body, limit)).await {
        Ok(Ok(bytes)) => Ok(ZBytes::from(bytes)),
        Ok(Err(e)) if is_length_limit(&e) => Err(too_large()),
        Ok(Err(e)) => Err(refuse(StatusCode::BAD_REQUEST, e.to_string())),
        Err(_) => Err(refuse(
            StatusCode::REQUEST_TIMEOUT,
            format!(
                "a REST request's body must arrive within {} s",
                BODY_DEADLINE.as_secs()
            ),
        )),
    }
}

fn is_length_limit(error: &axum::Error) -> bool {
    let mut source: Option<&(dyn std::error::Error + 'static)> = Some(error);
    while let Some(e) = source {
        if e.is::<http_body_util::LengthLimitError>() {
            return true;
        }
        source = e.source();
    }
    false
}

/// A query's answer: a JSON array of the replies (`ERROR` as the key of an error reply), or with
/// `?_raw` the first reply's payload under its own encoding.
async fn query(
    session: &Session,
    key_expr: KeyExpr<'static>,
    parameters: &str,
    encoding: Encoding,
    body: ZBytes,
) -> Response {
    let parameters = Parameters::from(parameters);
    let consolidation = if parameters.time_range().is_some() {
        ConsolidationMode::None
    } else {
        ConsolidationMode::Latest
    };
    let raw = parameters.contains_key(RAW_KEY);
    let mut get = session
        .get(Selector::borrowed(&key_expr, &parameters))
        .consolidation(QueryConsolidation::from(consolidation));
    if !body.is_empty() {
        get = get.payload(body).encoding(encoding);
    }
    let replies = match get.await {
        Ok(replies) => replies,
        Err(e) => return refuse(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()),
    };
    if raw {
        let Ok(reply) = replies.recv_async().await else {
            return StatusCode::OK.into_response();
        };
        let (encoding, payload) = match reply.result() {
            Ok(sample) => (sample.encoding(), sample.payload()),
            Err(e) => (e.encoding(), e.payload()),
        };
        let mut response = Body::from(payload.to_bytes().into_owned()).into_response();
        if let Ok(value) = HeaderValue::from_str(&encoding.to_string()) {
            response.headers_mut().insert(header::CONTENT_TYPE, value);
        }
        return response;
    }
    let mut answer = Vec::new();
    let mut answer_bytes = 0_usize;
    while let Ok(reply) = replies.recv_async().await {
        let item = match reply.result() {
            Ok(sample) => {
                answer_bytes += sample.payload().len();
                json_sample(sample)
            }
            Err(e) => {
                answer_bytes += e.payload().len();
                serde_json::json!({
                    "key": "ERROR",
                    "value": json_value(e.payload(), e.encoding()),
                    "encoding": e.encoding().to_string(),
                    "timestamp": null,
                })
            }
        };
        if answer_bytes > MAX_ANSWER_BYTES {
            return refuse(
                StatusCode::INSUFFICIENT_STORAGE,
                format!(
                    "the answer passed {MAX_ANSWER_BYTES} bytes: ask a narrower key expression"
                ),
            );
        }
        answer.push(item);
    }
    json_response(&serde_json::Value::Array(answer))
}

fn json_response(value: &serde_json::Value) -> Response {
    let mut response = Body::from(value.to_string()).into_response();
    response.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    response
}

fn json_sample(sample: &Sample) -> serde_json::Value {
    serde_json::json!({
        "key": sample.key_expr().as_str(),
        "value": json_value(sample.payload(), sample.encoding()),
        "encoding": sample.encoding().to_string(),
        "timestamp": sample.timestamp().map(ToString::to_string),
    })
}

/// A payload as the plugin shows it: JSON as JSON, text as a string, anything else in base64.
fn json_value(payload: &ZBytes, encoding: &Encoding) -> serde_json::Value {
    if payload.is_empty() {
        return serde_json::Value::Null;
    }
    let bytes = payload.to_bytes();
    let base64 = || base64::engine::general_purpose::STANDARD.encode(&bytes);
    let json = [
        Encoding::APPLICATION_JSON,
        Encoding::TEXT_JSON,
        Encoding::TEXT_JSON5,
    ];
    if json.contains(encoding) {
        serde_json::from_slice(&bytes).unwrap_or_else(|_| serde_json::Value::String(base64()))
    } else if [Encoding::TEXT_PLAIN, Encoding::ZENOH_STRING].contains(encoding) {
        std::str::from_utf8(&bytes).map_or_else(
            |_| serde_json::Value::String(base64()),
            |text| serde_json::Value::String(text.to_owned()),
        )
    } else {
        serde_json::Value::String(base64())
    }
}

/// Server-sent events of the samples on `key_expr`, for as long as the client reads. A reader
/// that falls [`EVENT_STREAM_DEPTH`] samples behind loses the newest ones, never holds the
/// session up.
async fn subscribe(session: &Session, key_expr: KeyExpr<'static>) -> Response {
    let (sender, receiver) = mpsc::channel::<Sample>(EVENT_STREAM_DEPTH);
    let subscriber = match session
        .declare_subscriber(key_expr)
        .callback(move |sample| {
            // Full: this reader is behind; the sample is dropped for it alone.
            let _ = sender.try_send(sample);
        })
        .await
    {
        Ok(subscriber) => subscriber,
        Err(e) => return refuse(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()),
    };
    // The stream owns the subscriber: dropped with the connection, it undeclares it.
    let events = futures_util::stream::unfold(
        (receiver, subscriber),
        |(mut receiver, subscriber)| async move {
            let sample = receiver.recv().await?;
            let data = json_sample(&sample);
            let event = Event::default()
                .event(sample.kind().to_string())
                .data(data.to_string());
            Some((Ok::<_, Infallible>(event), (receiver, subscriber)))
        },
    );
    Sse::new(events)
        .keep_alive(KeepAlive::default())
        .into_response()
}
