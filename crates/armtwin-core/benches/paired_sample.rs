//! A paired sample's arithmetic, part by part, in ns per call: the deviation of two poses, the
//! aligner's bracket of a measured stamp, the cumulative statistics, the sliced window (an add
//! into a full window at 100 and at 500 Hz, moving time on, a readout), the alarms; and the
//! twin's whole step for one decoded joint sample and its measured pose, as `armtwin-bench load`
//! sends them (a joint message, then the measured pose 0.54 mm off), the window full. The FK is `armtwin-bench`'s `benches/fk.rs` (`parts/pose_only_calibrated`
//! for a calibrated arm, `parts/readout_only`), the codecs its `benches/ingest.rs`.
//!
//! `cargo bench -p armtwin-core --bench paired_sample`
#![allow(
    clippy::expect_used,
    reason = "a measuring binary whose fixtures are the checkout's own constants"
)]
use std::collections::HashMap;
use std::hint::black_box;
use std::sync::Arc;
use std::time::{Duration, Instant};

use armtwin_core::align::{AlignConfig, Aligner};
use armtwin_core::kinematics::PoseReadout;
use armtwin_core::metrics::{
    CumulativeStats, DEFAULT_HISTORY_S, DEFAULT_WINDOW_SLICES, Deviation, METRIC_COUNT,
    WindowStats, WindowWithHistory,
};
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::{
    AlarmConfig, AlarmStates, Discard, MeasuredStream, Pipeline, PipelineConfig, Robot,
    RobotDirectory, RobotSettings,
};
use armtwin_core::sample::JointSample;
use criterion::{Criterion, criterion_group, criterion_main};

/// Joint angles (rad) of a UR10e in a working pose.
const Q: [f64; 6] = [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739];

/// Deviation-like magnitudes of sample `i`: millimetres and milliradians with some noise.
fn magnitudes(i: u64) -> [f64; METRIC_COUNT] {
    std::array::from_fn(|m| {
        let phase = (i as f64) * 0.37 + m as f64;
        1e-3 * (1.5 + phase.sin()) * (1.0 + 1e-3 * (phase * 7.1).cos())
    })
}

/// A 10-s window filled at `rate_hz`: every further add moves it on as a stream does.
fn full_window(rate_hz: u32) -> (WindowStats, u64) {
    let mut window = WindowStats::new(10.0, DEFAULT_WINDOW_SLICES);
    let filled = 10 * u64::from(rate_hz);
    for i in 0..filled {
        window.add(i as f64 / f64::from(rate_hz), &magnitudes(i));
    }
    (window, filled)
}

fn statistics(c: &mut Criterion) {
    let samples: Vec<[f64; METRIC_COUNT]> = (0..4096).map(magnitudes).collect();
    for (name, rate_hz) in [
        ("window/add_steady_state", 100),
        ("window/add_steady_state_500hz", 500),
    ] {
        let (mut window, mut next) = full_window(rate_hz);
        c.bench_function(name, |b| {
            b.iter(|| {
                let x = &samples[(next % 4096) as usize];
                window.add(black_box(next as f64 / f64::from(rate_hz)), black_box(x));
                next += 1;
            });
        });
    }
    // The same with the hour of per-second history the twin keeps by default, its ring full.
    for (name, rate_hz) in [
        ("window_with_history/add_steady_state", 100_u32),
        ("window_with_history/add_steady_state_500hz", 500),
    ] {
        let mut window = WindowWithHistory::new(10.0, DEFAULT_WINDOW_SLICES, DEFAULT_HISTORY_S);
        let filled = u64::try_from(DEFAULT_HISTORY_S).unwrap_or(u64::MAX) * u64::from(rate_hz);
        for i in 0..filled {
            window.add(i as f64 / f64::from(rate_hz), &magnitudes(i));
        }
        let mut next = filled;
        c.bench_function(name, |b| {
            b.iter(|| {
                let x = &samples[(next % 4096) as usize];
                window.add(black_box(next as f64 / f64::from(rate_hz)), black_box(x));
                next += 1;
            });
        });
    }
    // What the twin does for each accepted sample: source time moves on.
    let (mut window, mut next) = full_window(100);
    c.bench_function("window/advance_to", |b| {
        b.iter(|| {
            window.advance_to(black_box(next as f64 * 0.01));
            next += 1;
        });
    });
    let (window, _) = full_window(100);
    c.bench_function("window/readout", |b| {
        b.iter(|| black_box(&window).readout());
    });
    let mut cumulative = CumulativeStats::new();
    let mut next = 0u64;
    c.bench_function("cumulative/add", |b| {
        b.iter(|| {
            cumulative.add(black_box(&samples[(next % 4096) as usize]));
            next += 1;
        });
    });
}

/// `pose` moved 0.54 mm along x and turned 0.2 mrad about z, as a measured pose would be.
fn measured_near(pose: &PoseReadout) -> PoseReadout {
    let turn = nalgebra::UnitQuaternion::from_scaled_axis(nalgebra::Vector3::new(0.0, 0.0, 2e-4));
    let mut position_m = pose.position_m;
    position_m[0] += 5.4e-4;
    PoseReadout::from_position_quaternion(position_m, &(pose.quaternion() * turn))
}

fn parts(c: &mut Criterion) {
    let model = RobotModel::nominal("ur10e").expect("catalog");
    let twin = model.pose(&Q).expect("within limits").readout();
    let measured = measured_near(&twin);
    c.bench_function("deviation/between", |b| {
        b.iter(|| Deviation::between(black_box(&twin), black_box(&measured)));
    });
    let deviation = Deviation::between(&twin, &measured);
    c.bench_function("deviation/magnitudes", |b| {
        b.iter(|| black_box(&deviation).magnitudes());
    });

    let mut aligner = Aligner::<()>::new(AlignConfig::default());
    let mut next = 0u64;
    c.bench_function("align/push_and_bracket", |b| {
        b.iter(|| {
            let stamp_s = next as f64 * 0.01;
            aligner.push_joints(black_box(stamp_s), black_box(&Q));
            next += 1;
            black_box(aligner.bracket(black_box(stamp_s)));
        });
    });

    let config = AlarmConfig {
        position_m: Some(1e-3),
        angle_rad: Some(1e-2),
        hold_s: 0.2,
    };
    let mut alarms = AlarmStates::default();
    let mut next = 0u64;
    c.bench_function("alarms/update", |b| {
        b.iter(|| {
            next += 1;
            alarms.update(
                &config,
                black_box(next as f64 * 0.01),
                black_box(&deviation),
            )
        });
    });
}

/// Samples rendered ahead; the step starts on a fresh pipeline when they run out.
const RENDERED: usize = 4096;
/// Samples a fresh pipeline takes untimed: past the 10-s window at 100 Hz.
const WARM_UP: usize = 1100;

/// The twin's whole step for decoded inputs, one robot at 100 Hz (a nominal UR10e, as the
/// service benchmark configures it): its joint sample, then its measured pose.
#[allow(
    clippy::disallowed_methods,
    reason = "a benchmark times its own chunks, leaving out the untimed refills"
)]
fn twin_step(c: &mut Criterion) {
    let model = Arc::new(RobotModel::nominal("ur10e").expect("catalog"));
    let inputs: Vec<(f64, JointSample, PoseReadout)> = (0..RENDERED)
        .map(|i| {
            let stamp_s = 1000.0 + i as f64 * 0.01;
            let q: [f64; 6] =
                std::array::from_fn(|k| Q[k] + 0.3 * (0.7 * stamp_s + k as f64).sin());
            let pose = model.pose(&q).expect("within limits").readout();
            let joints = JointSample {
                stamp_s: Some(stamp_s),
                seq: None,
                q_rad: q.into_iter().collect(),
                measured: None,
                state: None,
            };
            (stamp_s, joints, measured_near(&pose))
        })
        .collect();
    let settings = RobotSettings {
        model,
        alarm: AlarmConfig {
            position_m: Some(0.01),
            angle_rad: Some(0.05),
            hold_s: 0.5,
        },
        sensors: Vec::new(),
        self_calibration: None,
        effort: None,
    };
    let mut directory = RobotDirectory::new(Some(settings), HashMap::new());
    let robot: Robot = directory.admit("fleet/r00000").expect("default").clone();
    let (joints_key, measured_key) = ("twin/joints/fleet/r00000", "twin/measured/fleet/r00000");
    let step = |pipeline: &mut Pipeline, index: usize| {
        let (stamp_s, joints, measured) = &inputs[index];
        pipeline.joints(&robot, joints_key, *stamp_s, joints, &mut Discard);
        pipeline.measured(
            &robot,
            measured_key,
            MeasuredStream::Robot,
            *stamp_s,
            measured,
            &mut Discard,
        );
    };
    let fresh = || {
        let mut pipeline = Pipeline::new(PipelineConfig::default());
        for index in 0..WARM_UP {
            step(&mut pipeline, index);
        }
        pipeline
    };
    let mut pipeline = fresh();
    let mut next = WARM_UP;
    c.bench_function("twin/paired_sample", |b| {
        b.iter_custom(|iterations| {
            let mut elapsed = Duration::ZERO;
            let mut left = iterations as usize;
            while left > 0 {
                if next == RENDERED {
                    pipeline = fresh();
                    next = WARM_UP;
                }
                let chunk = left.min(RENDERED - next);
                let start = Instant::now();
                for index in next..next + chunk {
                    step(&mut pipeline, index);
                }
                elapsed += start.elapsed();
                next += chunk;
                left -= chunk;
            }
            elapsed
        });
    });
}

criterion_group!(benches, statistics, parts, twin_step);
criterion_main!(benches);
