//! FK timings robust to a shared, loaded machine: the fastest of 3 000 runs of 200 calls each, per
//! figure (preemption only ever adds time, so the minimum is what the code costs). Companion of
//! `benches/fk.rs` (same configuration, same names), whose wall-clock medians swing widely when
//! other jobs share the cores. Run: `cargo run --release -p armtwin-bench --example
//! fk_min_time`.
#![allow(
    clippy::expect_used,
    reason = "a measuring binary whose fixtures are the checkout's own constants"
)]
#![allow(clippy::print_stdout, reason = "a measuring tool's report")]
use std::hint::black_box;
use std::time::Instant;

use armtwin_bench::fk_fixture::{Q, calibrated_ur10e};
use armtwin_core::model::RobotModel;
use armtwin_core::orientation::{quaternion_from_matrix, rpy_from_matrix};
use armtwin_core::trig;

/// Prints the fastest per-call time of `f` (ns).
fn time<R>(name: &str, mut f: impl FnMut() -> R) {
    let mut best_ns = f64::MAX;
    for _ in 0..3_000 {
        let start = Instant::now();
        for _ in 0..200 {
            black_box(f());
        }
        best_ns = best_ns.min(start.elapsed().as_secs_f64() / 200.0 * 1e9);
    }
    println!("{name:50} {best_ns:7.1} ns");
}

fn main() {
    let model = RobotModel::nominal("ur10e").expect("catalog model");
    let calibrated = calibrated_ur10e();
    let pose = model.pose(&Q).expect("valid");
    let (y, x) = ([0.3, -0.7, 0.9], [0.1, -0.2, 0.5]);
    time("fk_readout/ur10e", || {
        model.pose(black_box(&Q)).expect("valid").readout()
    });
    time("fk_readout/ur10e_yaml_calibration_tool_base_link", || {
        calibrated.pose(black_box(&Q)).expect("valid").readout()
    });
    time("parts/pose_only", || {
        model.chain().pose_unchecked(black_box(&Q))
    });
    time("parts/check_joints", || model.check_joints(black_box(&Q)));
    time("parts/readout_only", || black_box(&pose).readout());
    time("parts/quaternion_from_matrix", || {
        quaternion_from_matrix(black_box(&pose.rotation))
    });
    time("parts/rpy_from_matrix", || {
        rpy_from_matrix(black_box(&pose.rotation))
    });
    time("trig/sin_cos_batch6", || trig::sin_cos_batch(black_box(&Q)));
    time("trig/platform_sin_cos_x6", || {
        black_box(&Q).map(f64::sin_cos)
    });
    time("trig/atan2_batch3", || {
        trig::atan2_batch(black_box(&y), black_box(&x))
    });
    time("trig/platform_atan2_x3", || {
        let (y, x) = (black_box(&y), black_box(&x));
        [y[0].atan2(x[0]), y[1].atan2(x[1]), y[2].atan2(x[2])]
    });
}
