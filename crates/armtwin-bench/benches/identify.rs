//! Kinematic identification of 30 000 paired rows (the target: under 5 s): a `UR10e` with
//! millimetre-sized deltas, a smooth trajectory, poses rounded to 1 µm and 1e-6.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    missing_docs,
    reason = "a benchmark: a failed setup fails the run"
)]

use std::f64::consts::PI;

use armtwin_core::identify::{self, IdentifyOptions, PairedSample};
use armtwin_core::kinematics::{OutputFrame, Pose, TcpOffset};
use armtwin_core::model::calibration::{CalibrationForm, MountingDeltas};
use armtwin_core::model::{Calibration, RobotModel, catalog};
use criterion::{Criterion, criterion_group, criterion_main};

fn samples(rows: usize) -> Vec<PairedSample> {
    let deltas = MountingDeltas {
        delta_theta_rad: [2e-4, -1.1e-3, 8e-4, 3e-4, -6e-4, 2e-4],
        delta_a_m: [1e-4, -1.3e-3, 9e-4, 2e-4, 1e-4, 0.0],
        delta_d_m: [3e-4, 0.0, 0.0, 8e-4, -3e-4, 2e-4],
        delta_alpha_rad: [-4e-4, 7e-4, 1.1e-3, 5e-4, -3e-4, 0.0],
    };
    let truth = RobotModel::new(
        catalog::arm("ur10e").unwrap(),
        Some(Calibration {
            source_name: "bench".to_owned(),
            form: CalibrationForm::MountingDeltas(deltas),
        }),
        TcpOffset::FLANGE,
        OutputFrame::Base,
    )
    .unwrap();
    (0..rows)
        .map(|k| {
            let t = k as f64 / rows as f64;
            let q: [f64; 6] = std::array::from_fn(|j| {
                let base = [0.0, -1.4, 1.3, -1.4, -1.5, 0.0][j];
                base + 1.2 * (2.0 * PI * (3.0 + j as f64) * t + j as f64).sin()
            });
            let pose = truth.pose(&q).unwrap();
            PairedSample {
                q_rad: q,
                measured: Pose {
                    position_m: pose.position_m.map(|v| (v * 1e6).round() / 1e6),
                    rotation: pose.rotation,
                },
            }
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let rows = samples(30_000);
    let arm = catalog::arm("ur10e").unwrap();
    let mut group = c.benchmark_group("identify");
    group.sample_size(10);
    group.bench_function("ur10e_30000_rows", |b| {
        b.iter(|| {
            identify::identify(
                &arm,
                OutputFrame::Base,
                &TcpOffset::FLANGE,
                &rows,
                &IdentifyOptions::default(),
            )
            .unwrap()
        });
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
