//! FK throughput: one pose with position, quaternion and roll/pitch/yaw, per catalog model.
use std::hint::black_box;

use armtwin::model::RobotModel;
use criterion::{Criterion, criterion_group, criterion_main};

fn fk(c: &mut Criterion) {
    let model = RobotModel::nominal("ur10e").expect("catalog model");
    let q = [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739];
    c.bench_function("fk_ur10e_readout", |b| {
        b.iter(|| model.pose(black_box(&q)).expect("valid").readout());
    });
    c.bench_function("fk_ur10e_pose_only", |b| {
        b.iter(|| model.chain().pose_unchecked(black_box(&q)));
    });
    let pose = model.pose(&q).expect("valid");
    c.bench_function("readout_only", |b| {
        b.iter(|| black_box(&pose).readout());
    });
    c.bench_function("sin_cos_x6", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for v in black_box(&q) {
                let (s, c) = v.sin_cos();
                acc += s * c;
            }
            acc
        });
    });
}

criterion_group!(benches, fk);
criterion_main!(benches);
