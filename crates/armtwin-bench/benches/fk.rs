//! FK cost: one pose with position, quaternion and roll/pitch/yaw (what the service computes per
//! joint sample), its parts (`pose_only` takes the UR closed form, `pose_only_link_by_link` the
//! general chain, `pose_only_calibrated` the calibrated arm's, link by link), and the platform's
//! scalar `sin_cos` / `atan2` as in-run baselines for the batched trig.
//!
//! `cargo bench -p armtwin-bench --bench fk`; `examples/fk_min_time.rs` times the same calls.
#![allow(
    clippy::expect_used,
    reason = "a measuring binary whose fixtures are the checkout's own constants"
)]
use std::hint::black_box;

use armtwin_bench::fk_fixture::{Q, calibrated_ur10e};
use armtwin_core::model::RobotModel;
use armtwin_core::orientation::{quaternion_from_matrix, rpy_from_matrix};
use armtwin_core::trig;
use criterion::{Criterion, criterion_group, criterion_main};

fn fk(c: &mut Criterion) {
    let model = RobotModel::nominal("ur10e").expect("catalog model");
    c.bench_function("fk_readout/ur10e", |b| {
        b.iter(|| model.pose(black_box(&Q)).expect("valid").readout());
    });
    let calibrated = calibrated_ur10e();
    c.bench_function("fk_readout/ur10e_yaml_calibration_tool_base_link", |b| {
        b.iter(|| calibrated.pose(black_box(&Q)).expect("valid").readout());
    });
    c.bench_function("parts/pose_only_calibrated", |b| {
        b.iter(|| calibrated.chain().pose_unchecked(black_box(&Q)));
    });
    c.bench_function("parts/pose_only", |b| {
        b.iter(|| model.chain().pose_unchecked(black_box(&Q)));
    });
    let link_by_link = model.chain().to_link_by_link();
    c.bench_function("parts/pose_only_link_by_link", |b| {
        b.iter(|| link_by_link.pose_unchecked(black_box(&Q)));
    });
    c.bench_function("parts/check_joints", |b| {
        b.iter(|| model.check_joints(black_box(&Q)));
    });
    let pose = model.pose(&Q).expect("valid");
    c.bench_function("parts/readout_only", |b| {
        b.iter(|| black_box(&pose).readout());
    });
    c.bench_function("parts/quaternion_from_matrix", |b| {
        b.iter(|| quaternion_from_matrix(black_box(&pose.rotation)));
    });
    c.bench_function("parts/rpy_from_matrix", |b| {
        b.iter(|| rpy_from_matrix(black_box(&pose.rotation)));
    });
    c.bench_function("trig/sin_cos_batch6", |b| {
        b.iter(|| trig::sin_cos_batch(black_box(&Q)));
    });
    c.bench_function("trig/platform_sin_cos_x6", |b| {
        b.iter(|| black_box(&Q).map(f64::sin_cos));
    });
    let (y, x) = ([0.3, -0.7, 0.9], [0.1, -0.2, 0.5]);
    c.bench_function("trig/atan2_batch3", |b| {
        b.iter(|| trig::atan2_batch(black_box(&y), black_box(&x)));
    });
    c.bench_function("trig/platform_atan2_x3", |b| {
        b.iter(|| {
            let (y, x) = (black_box(&y), black_box(&x));
            [y[0].atan2(x[0]), y[1].atan2(x[1]), y[2].atan2(x[2])]
        });
    });
}

criterion_group!(benches, fk);
criterion_main!(benches);
