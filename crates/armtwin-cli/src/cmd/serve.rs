//! `armtwin serve`: the configuration loaded with the flags' overrides, then the service run on a
//! tokio runtime until Ctrl-C or SIGTERM.
//!
//! Owns the runtime and the shutdown signal's wiring; must not hold service logic.

use anyhow::{Context, Result};
use armtwin_service::config::{Overrides, ServiceConfig};
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
    runtime.block_on(async {
        let http = armtwin_dashboard::DashboardDoor::new(config.http_access.clone());
        service::serve(config, Some(Box::new(http)), shutdown_signal()).await?;
        Ok(())
    })
}
