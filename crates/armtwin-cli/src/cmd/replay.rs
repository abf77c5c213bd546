//! `armtwin replay`: a recording published to the mesh as a gateway would, with a progress bar.
//!
//! Owns the flags' checks and the summary line; must not encode or publish (the library's
//! `replay` does).

use anyhow::{Context, Result, bail};
use armtwin_mesh::zenoh_section::ZenohSection;
use armtwin_offline::replay::{self, ReplaySettings};

use super::{progress_bar, shutdown_signal};
use crate::flags::ReplayArgs;

pub(super) fn run(args: &ReplayArgs) -> Result<()> {
    if !(args.speed.is_finite() && args.speed > 0.0) {
        bail!("--speed must be a positive number, got {}", args.speed);
    }
    let (recording, times) = args.input.load()?;
    let settings = ReplaySettings {
        zenoh: ZenohSection::joining_default_service().overridden(&args.zenoh.overrides()),
        key_prefix: args.prefix.clone(),
        robot: args.robot.clone(),
        speed: (!args.max_rate).then_some(args.speed),
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let bar = progress_bar(recording.entries.len(), "replay");
    let report = runtime.block_on(replay::replay(
        &recording,
        &times,
        &settings,
        shutdown_signal(),
        |done| {
            if done % 256 == 0 {
                bar.set_position(done as u64);
            }
        },
    ))?;
    bar.finish_and_clear();
    eprintln!(
        "published {} messages ({} malformed lines as raw text){}",
        report.published,
        report.malformed,
        if report.interrupted {
            ", interrupted"
        } else {
            ""
        }
    );
    Ok(())
}
