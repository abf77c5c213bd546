//! Heap bytes the pipeline keeps per tracked robot: `armtwin serve`'s memory benchmark without
//! Zenoh. A pipeline configured as `armtwin-bench run` configures the service (N robots listed, all
//! `ur10e`, unknown robots rejected), fed through the service's own entry points
//! (`ingest::joint_message` / `ingest::measured_message`, JSON payloads) into a sink that drops
//! everything, with a counting global allocator.
//!
//! `cargo bench -p armtwin-bench --bench pipeline_memory [-- ROBOTS [SAMPLES [RATE_HZ]]]`
//! (defaults: 10 000 robots, 4 samples each, 100 Hz); e.g. `-- 1000 1100` for robots streaming
//! with full windows, `-- 1000 5500 500` the same at 500 Hz.
#![allow(
    clippy::expect_used,
    reason = "a measuring binary whose fixtures are the checkout's own constants"
)]
#![allow(
    unsafe_code,
    reason = "a global allocator is an `unsafe impl`; this measuring binary is not product code"
)]
#![allow(clippy::print_stdout, reason = "a benchmark's report")]

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicIsize, AtomicUsize, Ordering};

use armtwin_bench::fleet::{parsed_service_config, robot_id};
use armtwin_bench::net;
use armtwin_core::align::Aligner;
use armtwin_core::kinematics::PoseReadout;
use armtwin_core::metrics::{CumulativeStats, Deviation, WindowStats};
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::{Discard, MeasuredStream, Pipeline, PipelineConfig, RobotDirectory};
use armtwin_mesh::ingest::{self, Codec};
use armtwin_mesh::keys::Stream;

/// `System`, counting the bytes live and the allocations made.
struct Counting;

static LIVE_BYTES: AtomicIsize = AtomicIsize::new(0);
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every call is forwarded unchanged to `System`, which upholds `GlobalAlloc`'s contract;
// the counters only observe sizes.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LIVE_BYTES.fetch_add(layout.size().cast_signed(), Ordering::Relaxed);
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the caller's layout goes to `System` as given.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        LIVE_BYTES.fetch_add(layout.size().cast_signed(), Ordering::Relaxed);
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: as for `alloc`.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE_BYTES.fetch_sub(layout.size().cast_signed(), Ordering::Relaxed);
        // SAFETY: `ptr` came from this allocator, i.e. from `System`, with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LIVE_BYTES.fetch_add(
            new_size.cast_signed() - layout.size().cast_signed(),
            Ordering::Relaxed,
        );
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: as for `dealloc`; `new_size` is the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn live_bytes() -> isize {
    LIVE_BYTES.load(Ordering::Relaxed)
}

/// The load's messages for one sample: a joint message and the measured pose that goes with it
/// (a millimetre off), as `armtwin-bench load` sends them.
struct Messages {
    model: RobotModel,
    rate_hz: f64,
}

impl Messages {
    fn q_rad(sample: usize) -> [f64; 6] {
        std::array::from_fn(|joint| 2.0 * (1.3 * sample as f64 + joint as f64).sin())
    }

    fn joints(sample: usize, stamp_s: f64) -> String {
        let q = Self::q_rad(sample).map(|angle| angle.to_string()).join(",");
        format!(r#"{{"t":{stamp_s},"q":[{q}]}}"#)
    }

    fn measured(&self, sample: usize, stamp_s: f64) -> String {
        let pose = self
            .model
            .pose(&Self::q_rad(sample))
            .expect("angles within the ur10e's limits")
            .readout();
        let [x, y, z] = pose.position_m;
        let [qx, qy, qz, qw] = pose.quaternion_xyzw;
        format!(
            r#"{{"t":{stamp_s},"x":{},"y":{y},"z":{z},"qx":{qx},"qy":{qy},"qz":{qz},"qw":{qw}}}"#,
            x + 0.001
        )
    }
}

/// Feeds robots `range` samples `samples` (joint, then measured unless `joints_only`) at
/// `messages.rate_hz`.
fn feed(
    (robots, pipeline): (&mut RobotDirectory, &mut Pipeline),
    messages: &Messages,
    (range, samples): (std::ops::Range<usize>, std::ops::Range<usize>),
    joints_only: bool,
) {
    let mut sink = Discard;
    for sample in samples {
        let stamp_s = 1000.0 + sample as f64 / messages.rate_hz;
        let joints = Messages::joints(sample, stamp_s);
        let measured = messages.measured(sample, stamp_s);
        for index in range.clone() {
            let id = robot_id(index);
            let joint_key = net::key(Stream::Joints, &id);
            let measured_key = net::key(Stream::Measured, &id);
            let robot = robots.admit(&id).expect("a configured robot");
            ingest::joint_message(
                pipeline,
                robot,
                &joint_key,
                Codec::Json,
                joints.as_bytes(),
                || stamp_s,
                &mut sink,
            );
            if joints_only {
                continue;
            }
            ingest::measured_message(
                pipeline,
                robot,
                &measured_key,
                MeasuredStream::Robot,
                Codec::Json,
                measured.as_bytes(),
                || stamp_s,
                &mut sink,
            );
        }
        // Taken as the service takes them (it sends them itself); this sink would drop them.
        for index in pipeline.robots_with_due_metrics() {
            drop(pipeline.take_due_metrics(index));
        }
    }
}

/// Heap bytes held by `make()`'s result (beyond its inline size), and the result.
fn heap_of<T>(make: impl FnOnce() -> T) -> (isize, T) {
    let before = live_bytes();
    let value = make();
    (live_bytes() - before, value)
}

/// Robots fed first, whose memory is the baseline (as the service benchmark's 10).
const FIRST: usize = 10;

fn main() {
    let arguments: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|argument| argument.parse().ok())
        .collect();
    let robots = arguments.first().copied().unwrap_or(10_000).max(11);
    let samples = arguments.get(1).copied().unwrap_or(4).max(1);
    let rate_hz = arguments.get(2).copied().unwrap_or(100).max(1) as f64;

    let (config_bytes, config) =
        heap_of(|| parsed_service_config(robots).expect("generated configuration"));
    let messages = Messages {
        model: RobotModel::nominal("ur10e").expect("catalog"),
        rate_hz,
    };
    let mut directory = RobotDirectory::new(config.default_robot, config.robots);
    let mut pipeline = Pipeline::new(config.pipeline);
    feed(
        (&mut directory, &mut pipeline),
        &messages,
        (0..FIRST, 0..samples),
        false,
    );
    let base = live_bytes();
    // Phases for the other robots: first joint message (tracking), first measured pose (first
    // pairing), the remaining samples.
    feed(
        (&mut directory, &mut pipeline),
        &messages,
        (FIRST..robots, 0..1),
        false,
    );
    let after_joint_and_measured = live_bytes();
    feed(
        (&mut directory, &mut pipeline),
        &messages,
        (FIRST..robots, 1..samples),
        false,
    );
    let after_all = live_bytes();
    let tracked = (robots - FIRST) as f64;
    let per_robot = |bytes: isize| bytes as f64 / tracked;

    println!(
        "pipeline memory: {robots} ur10e robots configured, {samples} samples each ({rate_hz} Hz)"
    );
    println!(
        "  configuration (parsed settings of every listed robot): {:.0} bytes per robot",
        config_bytes as f64 / robots as f64
    );
    println!(
        "  per tracked robot: {:.0} bytes live heap (robots {FIRST}..{robots})",
        per_robot(after_all - base)
    );
    println!(
        "    after the first sample: {:.0}; the next {}: {:.0}",
        per_robot(after_joint_and_measured - base),
        samples - 1,
        per_robot(after_all - after_joint_and_measured)
    );

    // Robots that only stream joints (no measured poses, so no deviation statistics).
    drop(pipeline);
    let config = parsed_service_config(robots).expect("generated configuration");
    let mut directory = RobotDirectory::new(config.default_robot, config.robots);
    let mut pipeline = Pipeline::new(config.pipeline);
    feed(
        (&mut directory, &mut pipeline),
        &messages,
        (0..FIRST, 0..samples),
        true,
    );
    let base = live_bytes();
    feed(
        (&mut directory, &mut pipeline),
        &messages,
        (FIRST..robots, 0..samples),
        true,
    );
    println!(
        "  per tracked robot streaming joints only: {:.0} bytes",
        per_robot(live_bytes() - base)
    );

    print_parts(&config.pipeline, samples, rate_hz);
    drop(pipeline);
}

/// The main parts' inline sizes and heap after `samples` samples, each built alone.
fn print_parts(pipeline: &PipelineConfig, samples: usize, rate_hz: f64) {
    let model = RobotModel::nominal("ur10e").expect("catalog");
    let (window_bytes, window) = heap_of(|| {
        let mut window = WindowStats::new(pipeline.window_s, pipeline.window_slices);
        for sample in 0..samples {
            let pose = model
                .pose(&Messages::q_rad(sample))
                .expect("valid")
                .readout();
            let mut measured = pose;
            measured.position_m[0] += 0.001;
            let deviation = Deviation::between(&pose, &measured);
            window.add(sample as f64 / rate_hz, &deviation.magnitudes());
        }
        window
    });
    let (aligner_bytes, aligner) = heap_of(|| {
        let mut aligner = Aligner::<PoseReadout>::new(pipeline.align);
        for sample in 0..samples {
            aligner.push_joints(sample as f64 / rate_hz, &Messages::q_rad(sample));
        }
        aligner
    });
    println!("  parts (inline size + heap after {samples} samples):");
    println!(
        "    WindowStats      {:>6} + {:>6}",
        size_of::<WindowStats>(),
        window_bytes
    );
    println!(
        "    CumulativeStats  {:>6} + {:>6}",
        size_of::<CumulativeStats>(),
        0
    );
    println!(
        "    Aligner          {:>6} + {:>6}",
        size_of::<Aligner<PoseReadout>>(),
        aligner_bytes
    );
    println!(
        "    robot id key     {:>6} + {:>6}",
        size_of::<String>(),
        robot_id(0).len()
    );
    drop((window, aligner));
}
