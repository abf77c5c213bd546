//! `armtwin-router`: a Zenoh router with a REST API, built the way Zenoh's own bridges build
//! theirs (`zenoh-bridge-ros2dds`): the same engine as `zenohd`, built from the zenoh crate the
//! workspace already compiles, so a fleet's router and its tests need no separate `zenohd` build
//! nor a plugin library whose compiler and feature set must match it exactly. REST speaks
//! `zenohd`'s REST plugin's requests, bounded ([`rest_http`]).
//! Built with the feature `ros2dds`, it is also `zenoh-bridge-ros2dds`: the configuration's
//! `plugins/ros2dds` section (read exactly as that bridge reads it) or `--ros2dds` starts the
//! ROS 2 ⇄ Zenoh bridge in the same process; beside access control only with `--ros2-trusted`
//! ([`ros2`]).
//!
//! It takes a Zenoh JSON5 configuration (`-c`), `zenohd`'s flags for endpoints and the REST port,
//! and `--cfg KEY:VALUE` for any other setting; it owns no armtwin logic. Unlike `zenohd`, a bare
//! `--rest-http-port PORT` binds loopback, and beside access control REST runs as an identity the
//! rules name, or not at all unless trusted on loopback ([`rest`]).

mod rest;
mod rest_http;
mod ros2;

use anyhow::{Context, Result};
use clap::Parser;
use zenoh::internal::plugins::PluginsManager;
use zenoh::internal::runtime::{DynamicRuntime, Runtime, RuntimeBuilder};
use zenoh::{Config, Session};

use crate::rest::{RestDoor, RestFlags};

/// A Zenoh router (`zenohd` 1.10) with a bounded REST API (and, built with the feature
/// `ros2dds`, the ROS 2 DDS bridge) built in.
#[derive(Debug, Parser)]
#[command(name = "armtwin-router", version)]
#[allow(
    clippy::struct_excessive_bools,
    reason = "each is a command-line switch of its own"
)]
struct Args {
    /// A Zenoh JSON5 configuration file (TLS, access control, plugins …); the flags below are
    /// applied over it.
    #[arg(short, long, value_name = "FILE")]
    config: Option<std::path::PathBuf>,
    /// Endpoints to listen on (replace the file's), e.g. `tcp/127.0.0.1:7447`.
    #[arg(short, long, value_name = "ENDPOINT")]
    listen: Vec<String>,
    /// Endpoints of other routers to connect to (replace the file's).
    #[arg(short = 'e', long, value_name = "ENDPOINT")]
    connect: Vec<String>,
    /// Serve the REST API on this port of loopback (`8000`) or on `ADDRESS:PORT`
    /// (`0.0.0.0:8000`); `none` to leave it off even if the file configures it. Beside access
    /// control it needs --rest-certificate/--rest-private-key, or --rest-trusted on loopback.
    #[arg(long, value_name = "PORT")]
    rest_http_port: Option<String>,
    /// REST speaks as this certificate (PEM; its subject CN is what the access control's
    /// subjects name): a Zenoh client of this router over mutual TLS, so every HTTP request is
    /// allowed or dropped by the same rules as any session of that name.
    #[arg(long, value_name = "FILE", requires = "rest_private_key")]
    rest_certificate: Option<std::path::PathBuf>,
    /// The private key of --rest-certificate (PEM).
    #[arg(long, value_name = "FILE", requires = "rest_certificate")]
    rest_private_key: Option<std::path::PathBuf>,
    /// Run REST inside the router, past its access control, as `zenohd` does: whoever reaches
    /// the REST port may put any input and change any twin. Loopback addresses only.
    #[arg(long)]
    rest_trusted: bool,
    /// A web page's origin (`http://hmi.plant:8080`) allowed to call REST from a browser; repeat
    /// for more. Replaces the file's `plugins/rest/allowed_origins`. Without any, requests that
    /// carry an `Origin` are refused.
    #[arg(long, value_name = "ORIGIN")]
    rest_allow_origin: Vec<String>,
    /// Turn multicast scouting off (routers find each other through `--connect`).
    #[arg(long)]
    no_multicast_scouting: bool,
    /// Start the ROS 2 DDS bridge with its defaults (DDS domain `ROS_DOMAIN_ID` or 0, namespace
    /// `/`) when the file has no `plugins/ros2dds` section; needs the feature `ros2dds`.
    #[arg(long)]
    ros2dds: bool,
    /// Run the ROS 2 bridge beside access control: the bridge speaks as the router itself, past
    /// the rules, so every participant of its DDS domain may put any key. Only for a trusted
    /// domain.
    #[arg(long)]
    ros2_trusted: bool,
    /// A JSON5 value at a path of the Zenoh configuration, applied last
    /// (`--cfg transport/link/tx/lease:3000`).
    #[arg(long, value_name = "KEY:VALUE")]
    cfg: Vec<String>,
}

fn json_list(items: &[String]) -> String {
    let quoted: Vec<String> = items.iter().map(|item| format!("{item:?}")).collect();
    format!("[{}]", quoted.join(","))
}

/// The router's configuration (without `plugins/rest`, which is read here and served by
/// [`rest_http`], not by a plugin), where REST runs and the origins it serves.
fn config_from(args: &Args) -> Result<(Config, RestDoor, Vec<String>)> {
    let mut config = match &args.config {
        Some(path) => Config::from_file(path)
            .map_err(|e| anyhow::anyhow!("{e}"))
            .with_context(|| format!("cannot load the Zenoh configuration {}", path.display()))?,
        None => Config::default(),
    };
    let mut inserts: Vec<(String, String)> = vec![("mode".to_owned(), "\"router\"".to_owned())];
    if !args.listen.is_empty() {
        inserts.push(("listen/endpoints".to_owned(), json_list(&args.listen)));
    }
    if !args.connect.is_empty() {
        inserts.push(("connect/endpoints".to_owned(), json_list(&args.connect)));
    }
    if args.no_multicast_scouting {
        inserts.push(("scouting/multicast/enabled".to_owned(), "false".to_owned()));
    }
    if args.ros2dds && config.plugin("ros2dds").is_none() {
        inserts.push(("plugins/ros2dds".to_owned(), "{}".to_owned()));
    }
    for entry in &args.cfg {
        let (key, value) = entry
            .split_once(':')
            .with_context(|| format!("--cfg '{entry}' is not KEY:VALUE"))?;
        inserts.push((key.trim().to_owned(), value.trim().to_owned()));
    }
    for (key, value) in inserts {
        config
            .insert_json5(&key, &value)
            .map_err(|e| anyhow::anyhow!("{e}"))
            .with_context(|| format!("cannot set Zenoh configuration {key} to {value}"))?;
    }
    let door = rest::door(
        rest::access_control_enabled(&config),
        config.plugin("rest").and_then(|rest| rest.get("http_port")),
        &RestFlags {
            http_port: args.rest_http_port.clone(),
            trusted: args.rest_trusted,
            certificate: args.rest_certificate.clone(),
            private_key: args.rest_private_key.clone(),
        },
    )?;
    let origins = rest::allowed_origins(
        config
            .plugin("rest")
            .and_then(|rest| rest.get("allowed_origins")),
        &args.rest_allow_origin,
    )?;
    if config.plugin("rest").is_some() {
        config
            .remove("plugins/rest")
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    // Plugins (the ROS 2 bridge) are linked in, so loading is only their declaration (no library
    // is searched for).
    for key in ["adminspace/enabled", "plugins_loading/enabled"] {
        config
            .insert_json5(key, "true")
            .map_err(|e| anyhow::anyhow!("{e}"))
            .with_context(|| format!("cannot set Zenoh configuration {key} to true"))?;
    }
    Ok((config, door, origins))
}

/// The session REST speaks with: the router's own, or a client's with the identity's
/// certificate (after the router listens).
async fn rest_session(
    runtime: &Runtime,
    router: &Config,
    door: &RestDoor,
) -> Result<Option<Session>> {
    match door {
        RestDoor::Off => Ok(None),
        RestDoor::Inside { .. } => zenoh::session::init(DynamicRuntime::from(runtime.clone()))
            .await
            .map(Some)
            .map_err(|e| anyhow::anyhow!("{e}"))
            .context("cannot open REST's session on the router"),
        RestDoor::Identity {
            certificate,
            private_key,
            ..
        } => {
            let config = rest::identity_client_config(router, certificate, private_key)?;
            zenoh::open(config)
                .await
                .map(Some)
                .map_err(|e| anyhow::anyhow!("{e}"))
                .with_context(|| {
                    format!(
                        "REST's client cannot join the router with {}: is it a certificate of \
                         the router's CA?",
                        certificate.display()
                    )
                })
        }
    }
}

async fn shutdown_signal() -> Result<()> {
    let mut terminate = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        .context("cannot listen for SIGTERM")?;
    tokio::select! {
        result = tokio::signal::ctrl_c() => result.context("cannot listen for Ctrl-C")?,
        _ = terminate.recv() => {}
    }
    Ok(())
}

#[cfg(feature = "ros2dds")]
#[expect(
    clippy::unnecessary_wraps,
    reason = "the same signature as the build without the bridge, which refuses"
)]
fn declare_ros2dds(plugins: &mut PluginsManager) -> Result<()> {
    // The bridge reads `ROS_DISTRO` for the `ros_discovery_info` layout (Iron's and later ones'
    // when it is unset, which is also Jazzy's).
    plugins.declare_static_plugin::<zenoh_plugin_ros2dds::ROS2Plugin, &str>("ros2dds", true);
    Ok(())
}

#[cfg(not(feature = "ros2dds"))]
fn declare_ros2dds(_plugins: &mut PluginsManager) -> Result<()> {
    anyhow::bail!(
        "the configuration starts the ROS 2 DDS bridge (plugins/ros2dds or --ros2dds), but this \
         armtwin-router was built without it: cargo build --release -p armtwin-router \
         --features ros2dds (needs cmake and libclang)"
    )
}

#[tokio::main]
async fn main() -> Result<()> {
    zenoh::init_log_from_env_or("z=info,armtwin_router=info");
    let args = Args::parse();
    let (config, door, origins) = config_from(&args)?;
    // Bound first: a taken port stops the router before it joins the mesh.
    let rest_listener = match &door {
        RestDoor::Inside { address } | RestDoor::Identity { address, .. } => Some(
            rest_http::bind(*address)
                .await
                .with_context(|| format!("cannot serve REST on {address} (is it taken?)"))?,
        ),
        RestDoor::Off => None,
    };
    let mut plugins = PluginsManager::static_plugins_only();
    let bridge = config.plugin("ros2dds").is_some();
    let bridge_trusted = ros2::bridge_allowed(
        bridge,
        rest::access_control_enabled(&config),
        args.ros2_trusted,
    )?;
    if bridge {
        declare_ros2dds(&mut plugins)?;
    }
    let mut runtime = RuntimeBuilder::new(config.clone())
        .plugins_manager(plugins)
        .build()
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))
        .context("cannot build the Zenoh router")?;
    runtime
        .start()
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))
        .context("cannot start the Zenoh router (is a listen port taken?)")?;
    tracing::info!(zid = %runtime.zid(), "armtwin-router started");
    if bridge_trusted {
        tracing::warn!("ROS 2 bridge inside the router, past its access control (--ros2-trusted)");
    }
    let session = rest_session(&runtime, &config, &door).await?;
    let (stop_rest, rest_stopped) = tokio::sync::oneshot::channel::<()>();
    let rest_task = match (rest_listener, session.clone()) {
        (Some(listener), Some(session)) => Some(tokio::spawn(rest_http::serve(
            listener,
            session,
            origins.clone(),
            async {
                let _ = rest_stopped.await;
            },
        ))),
        _ => None,
    };
    match &door {
        RestDoor::Off => {}
        RestDoor::Inside { address } => {
            tracing::info!(%address, ?origins, "REST inside the router, past any access control");
        }
        RestDoor::Identity {
            address,
            certificate,
            ..
        } => tracing::info!(
            %address,
            ?origins,
            certificate = %certificate.display(),
            "REST as the certificate's subject, through the access control"
        ),
    }
    shutdown_signal().await?;
    tracing::info!("armtwin-router stopping");
    let _ = stop_rest.send(());
    if let Some(task) = rest_task {
        let _ = task.await;
    }
    if let Some(session) = session {
        session
            .close()
            .await
            .map_err(|e| anyhow::anyhow!("{e}"))
            .context("cannot close REST's session")?;
    }
    if bridge {
        // Zenoh 1.10.2 panics in its routing tables when a closing runtime still holds the
        // bridge's queryables (and then aborts on a second panic in a destructor);
        // `zenoh-bridge-ros2dds` never closes its runtime either. The process ends here: peers
        // see the link close, DDS readers the bridge's participant leave.
        std::process::exit(0);
    }
    runtime
        .close()
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))
        .context("cannot close the Zenoh router")?;
    Ok(())
}
