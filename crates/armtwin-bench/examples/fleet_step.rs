//! A tracked robot's CPU per sample as the fleet grows: N robots each streaming at 100 Hz of
//! source time, their samples round robin as `armtwin-bench load` sends them, through the
//! service's entry points (`ingest::joint_message` / `ingest::measured_message`, JSON payloads)
//! into one pipeline configured as `armtwin-bench run` configures the service, outputs dropped.
//! Timed once every robot's 10-s window is full, when a streaming robot's state is largest: what
//! the state's layout costs once it no longer fits the CPU's caches is the ratio to 1 robot.
//!
//! `cargo run --release -p armtwin-bench --example fleet_step [-- ROBOTS,... [json|decoded]]`
//! (default 1,10,100,1000, json); prints, per robot count, the fastest and the median pass in ns
//! per sample. `decoded` feeds the same samples decoded ahead of time into the pipeline's own
//! entry points (`Pipeline::joints` / `Pipeline::measured`): the twin's own work per paired
//! sample, without the codec.
#![allow(
    clippy::expect_used,
    reason = "a measuring binary whose fixtures are the checkout's own constants"
)]
#![allow(clippy::print_stdout, reason = "a benchmark's report")]

use std::time::Instant;

use armtwin_bench::ingest_fixture::{Load, RENDERED, RobotKeys, Twin, feed};
use armtwin_codec::json::{self, DecodedJoints};
use armtwin_core::pipeline::{Discard, MeasuredStream, Pipeline, Robot};
use armtwin_core::sample::MeasuredSample;
use armtwin_mesh::ingest::Codec;

/// How the samples enter the pipeline.
#[derive(Clone, Copy, PartialEq)]
enum Mode {
    /// JSON payloads through the service's entry points, decoded there.
    Json,
    /// Decoded ahead of time, into the pipeline's own entry points.
    Decoded,
}

/// The load's samples, decoded once.
struct Decoded {
    samples: Vec<(f64, DecodedJoints, MeasuredSample)>,
}

impl Decoded {
    fn of(load: &Load) -> Self {
        let samples = load
            .samples
            .iter()
            .map(|(stamp_s, joints, measured)| {
                (
                    *stamp_s,
                    json::read_joints(joints.as_bytes(), 6).expect("a valid joint message"),
                    json::read_measured(measured.as_bytes()).expect("a valid measured pose"),
                )
            })
            .collect();
        Self { samples }
    }

    /// Sample `index` of `robot` into `pipeline`: its joints, then its measured pose.
    fn feed(&self, pipeline: &mut Pipeline, (robot, keys): (&Robot, &RobotKeys), index: usize) {
        let (stamp_s, joints, measured) = &self.samples[index];
        pipeline.joints(robot, &keys.joints, *stamp_s, &joints.sample, &mut Discard);
        pipeline.measured(
            robot,
            &keys.measured,
            MeasuredStream::Robot,
            *stamp_s,
            &measured.pose,
            &mut Discard,
        );
    }
}

/// Samples per robot before the timing starts: more than the 10-s window holds at 100 Hz.
const WARM_UP: usize = 1100;
/// Samples timed per pass, over all robots.
const TIMED: usize = 400_000;

/// A fresh pipeline of `robots` robots, warmed up, then `TIMED` samples: ns per sample.
fn pass(load: &Load, decoded: Option<&Decoded>, robots: usize) -> f64 {
    let Twin {
        robots: directory,
        mut pipeline,
    } = Twin::of(robots);
    let keys: Vec<RobotKeys> = (0..robots).map(RobotKeys::of).collect();
    // Every robot gets the same payloads: each robot's own stream is what matters, and one set
    // of rendered payloads keeps the load's memory out of the measurement.
    let round = |index: usize, pipeline: &mut _| {
        let (stamp_s, joints, measured) = &load.samples[index];
        for keys in &keys {
            let robot = directory.find(&keys.id).expect("a configured robot");
            if let Some(decoded) = decoded {
                decoded.feed(pipeline, (robot, keys), index);
                continue;
            }
            feed(
                pipeline,
                (robot, keys),
                (Codec::Json, Codec::Json),
                (*stamp_s, joints.as_bytes(), measured.as_bytes()),
                &mut Discard,
            );
        }
    };
    for index in 0..WARM_UP {
        round(index, &mut pipeline);
    }
    let rounds = (TIMED / robots).clamp(1, RENDERED - WARM_UP);
    let start = Instant::now();
    for index in WARM_UP..WARM_UP + rounds {
        round(index, &mut pipeline);
    }
    start.elapsed().as_nanos() as f64 / (rounds * robots) as f64
}

fn main() {
    let counts: Vec<usize> = std::env::args().nth(1).map_or_else(
        || vec![1, 10, 100, 1000],
        |list| {
            list.split(',')
                .map(|count| count.trim().parse().expect("robot counts: 1,10,1000"))
                .collect()
        },
    );
    let mode = match std::env::args().nth(2).as_deref() {
        None | Some("json") => Mode::Json,
        Some("decoded") => Mode::Decoded,
        Some(other) => panic!("mode {other}: json or decoded"),
    };
    let load = Load::starting_at(0);
    let decoded = (mode == Mode::Decoded).then(|| Decoded::of(&load));
    let decoded = decoded.as_ref();
    // Untimed: a process's first pass runs slower (the rendered payloads' first reads).
    let _ = pass(&load, decoded, 1);
    println!("| robots | fastest pass ns/sample | median pass ns/sample | median / 1 robot's |");
    println!("| ---: | ---: | ---: | ---: |");
    let mut one_robot = None;
    for robots in counts {
        let passes = if robots >= 1000 { 3 } else { 7 };
        let mut ns: Vec<f64> = (0..passes)
            .map(|_| pass(&load, decoded, robots.max(1)))
            .collect();
        ns.sort_by(f64::total_cmp);
        let median = ns[ns.len() / 2];
        if robots == 1 {
            one_robot = Some(median);
        }
        let ratio =
            one_robot.map_or_else(|| "–".to_owned(), |base| format!("{:.2}", median / base));
        println!("| {robots} | {:.0} | {median:.0} | {ratio} |", ns[0]);
    }
}
