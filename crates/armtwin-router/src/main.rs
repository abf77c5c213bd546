//! `armtwin-router`: a Zenoh router with the REST plugin linked in, the way Zenoh's own bridges
//! build theirs (`zenoh-bridge-ros2dds`): the same engine as `zenohd`, built from the zenoh
//! crate the workspace already compiles, so a fleet's router and its tests need no separate
//! `zenohd` build nor a plugin library whose compiler and feature set must match it exactly.
//! Built with the feature `ros2dds`, it is also `zenoh-bridge-ros2dds`: the configuration's
//! `plugins/ros2dds` section (read exactly as that bridge reads it) or `--ros2dds` starts the
//! ROS 2 ⇄ Zenoh bridge in the same process.
//!
//! It takes a Zenoh JSON5 configuration (`-c`), `zenohd`'s flags for endpoints and the REST port,
//! and `--cfg KEY:VALUE` for any other setting; it owns no armtwin logic.

use anyhow::{Context, Result};
use clap::Parser;
use zenoh::Config;
use zenoh::internal::plugins::PluginsManager;
use zenoh::internal::runtime::RuntimeBuilder;

/// A Zenoh router (`zenohd` 1.10) with the REST plugin (and, built with the feature `ros2dds`,
/// the ROS 2 DDS bridge) built in.
#[derive(Debug, Parser)]
#[command(name = "armtwin-router", version)]
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
    /// Serve the REST API on this port or `ADDRESS:PORT` (e.g. `127.0.0.1:8000`); `none` to
    /// leave it off even if the file configures it.
    #[arg(long, value_name = "PORT")]
    rest_http_port: Option<String>,
    /// Turn multicast scouting off (routers find each other through `--connect`).
    #[arg(long)]
    no_multicast_scouting: bool,
    /// Start the ROS 2 DDS bridge with its defaults (DDS domain `ROS_DOMAIN_ID` or 0, namespace
    /// `/`) when the file has no `plugins/ros2dds` section; needs the feature `ros2dds`.
    #[arg(long)]
    ros2dds: bool,
    /// A JSON5 value at a path of the Zenoh configuration, applied last
    /// (`--cfg transport/link/tx/lease:3000`).
    #[arg(long, value_name = "KEY:VALUE")]
    cfg: Vec<String>,
}

fn json_list(items: &[String]) -> String {
    let quoted: Vec<String> = items.iter().map(|item| format!("{item:?}")).collect();
    format!("[{}]", quoted.join(","))
}

/// The REST plugin's `http_port` value: a bare port or `ADDRESS:PORT`, as `zenohd` takes it.
fn rest_port_json(value: &str) -> String {
    if value.parse::<u16>().is_ok() {
        value.to_owned()
    } else {
        format!("{value:?}")
    }
}

fn config_from(args: &Args) -> Result<Config> {
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
    match args.rest_http_port.as_deref() {
        None => {}
        Some("none") => inserts.push(("plugins/rest".to_owned(), "null".to_owned())),
        Some(port) => {
            inserts.push(("plugins/rest/http_port".to_owned(), rest_port_json(port)));
        }
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
    // The admin space serves the plugin's status under @/…; plugins are linked in, so loading is
    // only the declaration below (no library is searched for).
    config
        .insert_json5("adminspace/enabled", "true")
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    config
        .insert_json5("plugins_loading/enabled", "true")
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok(config)
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
    let config = config_from(&args)?;
    let mut plugins = PluginsManager::static_plugins_only();
    if config.plugin("rest").is_some() {
        plugins.declare_static_plugin::<zenoh_plugin_rest::RestPlugin, &str>("rest", true);
    }
    let bridge = config.plugin("ros2dds").is_some();
    if bridge {
        declare_ros2dds(&mut plugins)?;
    }
    let mut runtime = RuntimeBuilder::new(config)
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
    shutdown_signal().await?;
    tracing::info!("armtwin-router stopping");
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
