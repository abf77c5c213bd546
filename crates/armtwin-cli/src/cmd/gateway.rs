//! `armtwin gateway rtde`: one controller from the flags, or a fleet file, streamed until Ctrl-C
//! or SIGTERM.
//!
//! Owns the flags' checks and the runtime; must not speak RTDE or publish (`armtwin-gateway`
//! does).

use anyhow::{Context, Result, bail};
use armtwin_gateway::{self as gateway, ControllerSettings, GatewaySettings};
use armtwin_mesh::zenoh_section::ZenohSection;

use super::{read_text, shutdown_signal};
use crate::flags::RtdeArgs;

pub(super) fn rtde(args: &RtdeArgs) -> Result<()> {
    let (key_prefix, controllers) = match (&args.config, &args.host, &args.robot) {
        (Some(path), _, _) => {
            gateway::parse_fleet(&read_text(path)?, &path.display().to_string(), &args.prefix)?
        }
        (None, Some(host), Some(robot)) => (
            args.prefix.clone(),
            vec![ControllerSettings {
                robot: robot.clone(),
                host: host.clone(),
                port: args.port,
                dashboard_port: args.dashboard_port,
                frequency_hz: args.frequency,
                record: args.record.clone(),
            }],
        ),
        _ => bail!("give --host and --robot, or a fleet file with -c"),
    };
    let settings = GatewaySettings {
        zenoh: ZenohSection::joining_default_service().overridden(&args.zenoh.overrides()),
        key_prefix,
        controllers,
    };
    settings.check()?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(gateway::run(settings, shutdown_signal()))?;
    Ok(())
}
