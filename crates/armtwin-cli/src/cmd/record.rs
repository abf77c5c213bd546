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

/// How `record` joins the mesh: a client, which the peer it joins (a bare `armtwin serve`) routes
/// every robot's streams to, the gateways' included, where a peer would hear only what that peer
/// publishes itself.
fn joining(args: &RecordArgs) -> ZenohSection {
    ZenohSection {
        mode: ZenohMode::Client,
        ..ZenohSection::joining_default_service()
    }
    .overridden(&args.zenoh.overrides())
}

/// `--incident ROBOT`: the twin's reply printed (JSON, on stdout), and the file's name on stderr.
#[allow(clippy::print_stdout, reason = "the reply is the command's output")]
fn incident(args: &RecordArgs, robot: &str) -> Result<()> {
    for (name, value) in [("--pre-s", args.pre_s), ("--post-s", args.post_s)] {
        if let Some(value) = value
            && !(value.is_finite() && value >= 0.0)
        {
            bail!("{name} must be a number of seconds, 0 or more, got {value}");
        }
    }
    // Zenoh's runtime needs a multi-threaded one; one worker does for one query.
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let reply = runtime.block_on(record::ask_incident(
        &joining(args),
        &args.prefix,
        robot,
        (args.pre_s, args.post_s),
    ))?;
    println!("{reply}");
    if let Some(path) = reply.get("path").and_then(|path| path.as_str()) {
        eprintln!("{robot}: incident file {path}");
    }
    Ok(())
}

/// Robots named on the progress line; the rest are counted.
const NAMED: usize = 4;

pub(super) fn run(args: &RecordArgs) -> Result<()> {
    if let Some(robot) = &args.incident {
        return incident(args, robot);
    }
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
    let Some(out) = &args.out else {
        bail!("--out is needed to record");
    };
    let output = if out.extension().is_some_and(|e| e == "mcap") {
        RecordOutput::File(out.clone())
    } else {
        RecordOutput::Directory(out.clone())
    };
    let settings = RecordSettings {
        zenoh: joining(args),
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
