//! `armtwin record`: live streams of chosen robots written as MCAP files, with a progress line.
//!
//! Owns the flags' checks, the progress line and the summary; must not subscribe, decode or
//! write (the library's `record` does).

use std::fmt::Write as _;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use armtwin_mesh::zenoh_section::{ZenohMode, ZenohSection};
use armtwin_offline::record::{self, Progress, RecordOutput, RecordSettings};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::shutdown_signal;
use crate::flags::RecordArgs;

/// Robots named on the progress line; the rest are counted.
const NAMED: usize = 4;

pub(super) fn run(args: &RecordArgs) -> Result<()> {
    let duration = args
        .duration
        .map(|s| {
            Duration::try_from_secs_f64(s)
                .ok()
                .filter(|d| !d.is_zero())
                .with_context(|| {
                    format!("--duration must be a positive number of seconds, got {s}")
                })
        })
        .transpose()?;
    if args.joints == 0 || args.max_robots == 0 || args.queue == 0 {
        bail!("--joints, --max-robots and --queue must be at least 1");
    }
    let output = if args.out.extension().is_some_and(|e| e == "mcap") {
        RecordOutput::File(args.out.clone())
    } else {
        RecordOutput::Directory(args.out.clone())
    };
    // A client: the peer it joins (a bare `armtwin serve`) routes every robot's streams to it,
    // the gateways' included, where a peer would hear only what that peer publishes itself.
    let zenoh = ZenohSection {
        mode: ZenohMode::Client,
        ..ZenohSection::joining_default_service()
    };
    let settings = RecordSettings {
        zenoh: zenoh.overridden(&args.zenoh.overrides()),
        key_prefix: args.prefix.clone(),
        robots: args.robots.clone(),
        output,
        joint_count: args.joints,
        max_robots: args.max_robots,
        queue: args.queue,
        duration,
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let bar = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template("record {spinner} {elapsed} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    let report = runtime.block_on(record::record(&settings, shutdown_signal(), |progress| {
        bar.set_message(progress_line(progress));
        bar.tick();
    }))?;
    bar.finish_and_clear();
    for file in &report.files {
        eprintln!(
            "{}: {} messages ({} joints, {} measured, {} twin poses, {} deviations), {} bytes: {}",
            file.robot,
            file.messages,
            file.counts.joints,
            file.counts.measured,
            file.counts.twin_poses,
            file.counts.deviations,
            file.bytes,
            file.path.display()
        );
    }
    for (robot, error) in &report.failures {
        eprintln!("{robot}: not written: {error}");
    }
    eprintln!(
        "recorded {} robots; {} messages dropped (queue full), {} malformed, {} of refused robots{}",
        report.files.len(),
        report.dropped,
        report.malformed,
        report.refused,
        if report.interrupted {
            ", interrupted"
        } else {
            ""
        }
    );
    if report.files.is_empty() {
        bail!("nothing recorded: no message of {:?} arrived", args.robots);
    }
    Ok(())
}

/// `N robots, M messages: r1 1234, r2 567, …`.
fn progress_line(progress: &Progress) -> String {
    let total: u64 = progress.values().sum();
    let mut line = format!("{} robots, {total} messages", progress.len());
    for (i, (robot, count)) in progress.iter().enumerate() {
        if i == NAMED {
            let _ = write!(line, ", …");
            break;
        }
        let _ = write!(line, "{} {robot} {count}", if i == 0 { ":" } else { "," });
    }
    line
}
