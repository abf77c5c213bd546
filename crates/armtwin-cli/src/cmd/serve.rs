//! `armtwin serve`: the configuration loaded with the flags' overrides, then the service run on a
//! tokio runtime until Ctrl-C or SIGTERM.
//!
//! Owns the runtime and the shutdown signal's wiring; must not hold service logic.

use anyhow::{Context, Result};
use armtwin_gateway::{ControllerSettings, InService};
use armtwin_mesh::beside::Beside;
use armtwin_service::config::{Overrides, RtdeLink, ServiceConfig};
use armtwin_service::service;

use super::shutdown_signal;
use crate::flags::ServeArgs;

pub(super) fn run(args: &ServeArgs) -> Result<()> {
    let overrides = Overrides {
        http_listen: args.http_listen,
        opcua_endpoint: args.opcua_endpoint.clone(),
        ..args.zenoh.overrides()
    };
    let config = ServiceConfig::load(args.config.as_deref(), &overrides)?;
    tracing::info!(config = %config.source_name, "configuration loaded");
    if !config.zenoh.reaches_anyone() {
        tracing::warn!(
            config = %config.source_name,
            mode = %config.zenoh.mode,
            "listening nowhere and connecting nowhere, with multicast scouting off: no gateway \
             or client can reach this service (set [zenoh] listen or connect, or -l / -e)"
        );
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let controllers = rtde_links(&config.rtde_links)?;
    runtime.block_on(async {
        let http = armtwin_dashboard::DashboardDoor::new(config.http_access.clone());
        service::serve(config, Some(Box::new(http)), controllers, shutdown_signal()).await?;
        Ok(())
    })
}

/// The controllers of `[robots."<id>"] rtde`, streamed by `armtwin gateway rtde`'s links on the
/// service's session; none without any.
fn rtde_links(links: &[RtdeLink]) -> Result<Option<Box<dyn Beside>>> {
    if links.is_empty() {
        return Ok(None);
    }
    let mut controllers = Vec::with_capacity(links.len());
    for link in links {
        let mut controller = ControllerSettings::at(&link.robot, &link.address)?;
        if let Some(port) = link.dashboard_port {
            controller.dashboard_port = port;
        }
        if let Some(frequency_hz) = link.frequency_hz {
            controller.frequency_hz = frequency_hz;
        }
        controller.record.clone_from(&link.record);
        tracing::info!(
            robot = %controller.robot,
            host = %controller.host,
            port = controller.port,
            "streaming the robot's controller over RTDE"
        );
        controllers.push(controller);
    }
    Ok(Some(Box::new(InService::new(controllers)?)))
}
