//! `armtwin serve`: the pipeline on a Zenoh mesh.
//!
//! Owns the session, the wildcard subscriptions and queryables (and one subscription per
//! `[[sources]]` entry: JSON or ROS 2 on keys of their own), the per-robot publishers (the twin
//! pose as a ROS 2 `PoseStamped` among them, for robots with `ros2_pose`) and liveliness tokens,
//! and the ordered teardown. Samples and queries are handled in Zenoh's callbacks: each sample
//! resolves its robot and decodes against the robot's immutable settings first, then steps that
//! robot's twin under the robot's own lock, so robots arriving on different links never wait on
//! each other (see [`fleet::Fleet`]); a control thread declares newly tracked robots' liveliness
//! tokens (and, once a robot streams, the publishers that cache its routes), publishes the
//! periodic metrics (and writes the snapshot, with `[service] state_dir`) and finishes every twin
//! at shutdown, each robot locked in turn.
//!
//! An instance owns the robots of `[service] robots`: its wildcard subscriptions and queryables
//! cover those ids alone, and it claims them on the mesh (`<prefix>/shards/<zid>`) before taking
//! input, refusing to start over another instance's claim. A snapshot is restored before the
//! first input, whole or not at all.
//!
//! Flow control: inputs are received reliably; while a callback works, Zenoh does not read its
//! link, which backpressures the transport and, through it, the gateways: nothing valid is
//! dropped. Poses and deviations (or both in one message, with `[service] outputs = "paired"`)
//! use `[service] pose_congestion` (`drop` by default: a message a
//! subscriber's link cannot take is dropped for that subscriber alone, after at most Zenoh's
//! `wait_before_drop`, and the twin goes on; `block` waits). Metrics, events and query replies
//! always block: they are few and must arrive; a subscriber that stops reading them is
//! disconnected after Zenoh's `wait_before_close`. Every output carries its encoding.
//!
//! Its files depend one way (`armtwin-layout`'s `tests/layout.rs` holds the order): `error`; the leaves (`admin`, `events`,
//! `memory`, `recording`, `requests`, `calibration_slot`, `shard`, `gateways`, `peers`,
//! `time_range`, and `publish`, the Zenoh I/O); `sink`; `fleet`; the duties over the fleet (`controller`,
//! `queries`, `self_calibration`, `snapshot`, `view`); what runs them (`intake`, Zenoh's
//! callbacks, and `control`, the control thread); and this file.
//! `opcua_view` is the OPC UA server's read of the fleet, a duty beside `view`.

mod admin;
mod calibration_slot;
mod control;
mod controller;
mod description;
mod error;
mod events;
mod fleet;
mod gateways;
mod history_log;
mod intake;
mod memory;
mod opcua_view;
mod peers;
mod publish;
mod queries;
mod recording;
mod requests;
mod self_calibration;
mod shard;
mod sink;
mod snapshot;
mod time_range;
mod view;

use std::future::Future;
use std::sync::Arc;

use tracing::{info, warn};

use self::control::Periods;
pub use self::control::ServeReport;
pub use self::error::ServiceError;
use self::fleet::Fleet;
use self::gateways::{GatewayTokens, watch_gateways};
use self::intake::declare_intake;
use self::peers::Peers;
use self::publish::Outlet;
use self::sink::Sinks;
use self::snapshot::restore_snapshot;
use crate::config::{OutputShape, ServiceConfig};
use crate::snapshot::SnapshotStore;
use armtwin_mesh::beside::Beside;
use armtwin_mesh::keys::Stream;
use armtwin_mesh::{TEARDOWN_STEP, aggregate_publishers, bounded, close_session, zenoh_config_of};
use armtwin_view::{HttpDoor, OpenHttpDoor};

/// A start that failed after the control thread started: the thread stopped and the session
/// closed, each bounded in time.
async fn abandon(
    requests: &requests::Requests,
    control: std::thread::JoinHandle<(ServeReport, control::Declarations)>,
    session: &zenoh::Session,
) {
    requests.stop();
    bounded(
        "stopping the control thread",
        TEARDOWN_STEP * 4,
        tokio::task::spawn_blocking(move || control.join()),
    )
    .await;
    let _ = close_session(session).await;
}

/// Runs the service until `shutdown` completes, then tears down in order: stop intake, finish
/// every twin (final metrics for every robot), close the session (which undeclares the robots'
/// publishers and tokens at once). `http` serves
/// `[http] listen` (the command line hands in the dashboard); a configuration that asks for it
/// without one is refused. `beside` runs on the session from the first input to the shutdown's
/// start (the command line hands in the RTDE links of `[robots."<id>"] rtde`).
pub async fn serve(
    config: ServiceConfig,
    http: Option<Box<dyn HttpDoor>>,
    beside: Option<Box<dyn Beside>>,
    shutdown: impl Future<Output = ()>,
) -> Result<ServeReport, ServiceError> {
    // Bound first: an address in use fails the start before anything joins the mesh.
    let http_listener = bind_http(config.http_listen, http).await?;
    let opcua = match &config.opcua {
        Some(settings) => Some(armtwin_opcua::OpcUaServer::bind(settings).await?),
        None => None,
    };
    let mut zenoh_config = zenoh_config_of(&config.zenoh)?;
    let keys = &config.keys;
    aggregate_outputs(&config, &mut zenoh_config)?;
    let admin_refusal = admin::refusal(config.admin, &zenoh_config);
    let session = zenoh::open(zenoh_config).await?;
    // A list the `[zenoh] file` sets itself is the file's, which `listen`/`connect` do not hold.
    let [_, (_, listen, _), (_, connect, _)] = config.zenoh.with_origins();
    info!(
        zid = %session.zid(),
        mode = %config.zenoh.mode,
        listen = %listen,
        connect = %connect,
        prefix = keys.prefix(),
        "armtwin serving"
    );
    let (requests, received) = requests::queue();
    let outlet = Outlet::new(session.clone(), &config);
    let recorder = recording::start(&config.recorder, session.clone(), keys.clone());
    let sinks = Sinks::new(outlet, requests.clone(), config.event_budget, recorder)
        .with_history_log(history_log::HistoryLog::new(&config));
    let fleet = Arc::new(Fleet::new(&config, sinks));
    let snapshots = config.snapshots.as_ref().map(|settings| {
        (
            SnapshotStore::new(&settings.state_dir, keys.prefix()),
            settings.period,
        )
    });
    let control = control::spawn(
        fleet.clone(),
        received,
        Periods {
            metrics: config.metrics_period,
            self_calibration: config.self_calibration,
            forget_after: config.forget_after,
        },
        snapshots.clone(),
    )?;
    if let Some((store, _)) = &snapshots {
        restore_snapshot(store, &fleet, &config);
    }

    let intake = match declare_intake(&session, &config, &fleet, admin_refusal).await {
        Ok(intake) => intake,
        Err(e) => {
            abandon(&requests, control, &session).await;
            return Err(e);
        }
    };

    let (dashboard, gateway_watch) = match http_listener {
        None => (None, Vec::new()),
        Some((listener, door)) => {
            let (dashboard, watch) =
                start_dashboard(door.as_ref(), listener, &session, &config, &fleet).await;
            (Some(dashboard), watch)
        }
    };

    let opcua = opcua.and_then(|bound| start_opcua(bound, &fleet));
    let beside = beside.map(|beside| beside.start(session.clone(), keys.clone()));

    shutdown.await;
    close_doors(dashboard, gateway_watch, opcua).await;
    if let Some(beside) = beside {
        beside.stop().await;
    }
    info!("shutting down: stopping intake");
    intake.undeclare().await;
    // Samples that arrive after this are ignored: the control thread finishes the pipeline.
    requests.stop();
    // The robots' publishers and tokens outlive the session's close, which undeclares them all
    // at once ([`control::Declarations`]).
    let (report, declarations) = match finish(control).await {
        Ok((report, declarations)) => (Ok(report), Some(declarations)),
        Err(e) => (Err(e), None),
    };
    // The incidents the finished twins left are written, and their events sent, before the
    // session closes.
    let recording_fleet = Arc::clone(&fleet);
    bounded(
        "writing the last incident files",
        TEARDOWN_STEP * 4,
        tokio::task::spawn_blocking(move || recording_fleet.recorder().finish()),
    )
    .await;
    // Closed even when the control thread failed: the session's links go down either way.
    if let Err(e) = close_session(&session).await {
        warn!(error = %e, "closing the session failed");
    }
    drop(declarations);
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

/// Declares the outputs with a publisher per streaming robot (at the sample rate, and the
/// metrics) as one publisher each on the mesh.
fn aggregate_outputs(
    config: &ServiceConfig,
    zenoh_config: &mut zenoh::Config,
) -> Result<(), ServiceError> {
    let sample_rate_streams: &[Stream] = match config.outputs {
        OutputShape::Separate => &[Stream::Pose, Stream::Deviation],
        OutputShape::Paired => &[Stream::Paired],
    };
    let aggregated: Vec<String> = sample_rate_streams
        .iter()
        .chain(&[Stream::Metrics])
        .map(|&stream| config.keys.every_robot(stream))
        .collect();
    aggregate_publishers(zenoh_config, &aggregated)?;
    Ok(())
}

/// Starts the dashboard on `listener`, with the subscribers of the gateways' tokens it reads
/// (heard only for `/metrics`: a service without the dashboard holds no table of them).
/// Starts the bound OPC UA server over `fleet`, which it reads at its own sampling interval, never
/// on the sample path; a server that cannot start is a warning, and the twin goes on.
fn start_opcua(
    bound: armtwin_opcua::BoundServer,
    fleet: &Arc<Fleet>,
) -> Option<armtwin_opcua::OpcUaServer> {
    bound
        .start(Arc::new(opcua_view::OpcUaView::new(Arc::clone(fleet))))
        .inspect_err(|e| warn!(error = %e, "OPC UA server not started"))
        .ok()
}

/// Stops what serves people rather than gateways (the dashboard, with its watch of the gateways'
/// tokens, and the OPC UA server), first: nobody reads a twin that is being finished.
async fn close_doors(
    dashboard: Option<Box<dyn OpenHttpDoor>>,
    gateway_watch: Vec<zenoh::pubsub::Subscriber<()>>,
    opcua: Option<armtwin_opcua::OpcUaServer>,
) {
    if let Some(dashboard) = dashboard {
        dashboard.close().await;
    }
    for subscriber in gateway_watch {
        let step = "undeclaring the gateway token subscriber";
        if let Some(Err(e)) = bounded(step, TEARDOWN_STEP, subscriber.undeclare()).await {
            warn!(error = %e, step, "undeclaring failed");
        }
    }
    if let Some(opcua) = opcua {
        opcua.stop().await;
    }
}

async fn start_dashboard(
    door: &dyn HttpDoor,
    listener: tokio::net::TcpListener,
    session: &zenoh::Session,
    config: &ServiceConfig,
    fleet: &Arc<Fleet>,
) -> (Box<dyn OpenHttpDoor>, Vec<zenoh::pubsub::Subscriber<()>>) {
    let (robots, max_robots) = fleet.occupancy();
    let tokens = Arc::new(GatewayTokens::new(robots.max(max_robots)));
    let watch = watch_gateways(session, &config.keys, &config.shard, &tokens)
        .await
        .unwrap_or_else(|e| {
            warn!(error = %e, "cannot watch the gateways' liveliness tokens");
            Vec::new()
        });
    let view = view::FleetView::new(
        Arc::clone(fleet),
        tokens,
        Peers::new(session.clone(), config.keys.clone()),
        config.shard.as_str(),
        config.robots.keys(),
    );
    let dashboard = door.open(listener, Arc::new(view));
    (dashboard, watch)
}

/// Waits, bounded, for the control thread to finish the pipeline; its report, and the robots'
/// publishers and tokens it hands back.
async fn finish(
    control: std::thread::JoinHandle<(ServeReport, control::Declarations)>,
) -> Result<(ServeReport, control::Declarations), ServiceError> {
    match bounded(
        "finishing the pipeline",
        TEARDOWN_STEP * 4,
        tokio::task::spawn_blocking(move || control.join()),
    )
    .await
    {
        Some(Ok(Ok(finished))) => Ok(finished),
        Some(Ok(Err(_))) => Err(ServiceError::Worker(
            "the control thread panicked".to_owned(),
        )),
        Some(Err(e)) => Err(ServiceError::Worker(e.to_string())),
        None => Err(ServiceError::Worker(
            "the control thread did not stop in time".to_owned(),
        )),
    }
}

/// The HTTP side's listener with the door that serves it, if `[http] listen` asks for one.
async fn bind_http(
    address: Option<std::net::SocketAddr>,
    door: Option<Box<dyn HttpDoor>>,
) -> Result<Option<(tokio::net::TcpListener, Box<dyn HttpDoor>)>, ServiceError> {
    let Some(address) = address else {
        return Ok(None);
    };
    let door = door.ok_or(ServiceError::NoHttpDoor)?;
    let listener = tokio::net::TcpListener::bind(address)
        .await
        .map_err(|source| ServiceError::HttpListen { address, source })?;
    Ok(Some((listener, door)))
}
