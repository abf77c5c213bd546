//! Inverse dynamics cost: one six-joint recursive Newton–Euler call (what a torque residual needs
//! per sample), gravity torques, the mass matrix and the momentum terms an observer needs, with
//! the nominal FK of the same arm as an in-run baseline (figures: README.md beside
//! this file, "Inverse dynamics").
//!
//! `cargo bench -p armtwin-core --bench dynamics`.
#![allow(
    clippy::expect_used,
    reason = "a measuring binary whose fixtures are the checkout's own constants"
)]
use std::hint::black_box;

use armtwin_core::dynamics::monitor::{EffortConfig, EffortMonitor};
use armtwin_core::dynamics::{ArmDynamics, JointFriction, Payload};
use armtwin_core::model::{RobotModel, catalog};
use armtwin_core::sample::{JointQuantity, JointState};
use criterion::{Criterion, criterion_group, criterion_main};

const Q_RAD: [f64; 6] = [0.31, -1.22, 1.43, -0.87, 1.52, 0.64];
const QD_RAD_S: [f64; 6] = [0.4, -0.3, 0.5, 0.8, -0.6, 1.1];
const QDD_RAD_S2: [f64; 6] = [1.5, -2.0, 2.5, 3.0, -1.0, 4.0];

fn dynamics(c: &mut Criterion) {
    let ur10e = ArmDynamics::<6>::from_arm(&catalog::arm("ur10e").expect("catalog model"))
        .expect("published parameters")
        .with_payload(Payload::point_mass(5.0, [0.01, 0.0, 0.08]))
        .expect("valid payload");
    c.bench_function("rnea/ur10e", |b| {
        b.iter(|| {
            ur10e.inverse_dynamics_nm(
                black_box(&Q_RAD),
                black_box(&QD_RAD_S),
                black_box(&QDD_RAD_S2),
            )
        });
    });
    let rubbing = ur10e
        .clone()
        .with_friction(
            [JointFriction {
                coulomb_nm: 4.0,
                viscous_nm_s_rad: 0.9,
            }; 6],
        )
        .expect("valid friction");
    c.bench_function("rnea/ur10e_friction", |b| {
        b.iter(|| {
            rubbing.inverse_dynamics_nm(
                black_box(&Q_RAD),
                black_box(&QD_RAD_S),
                black_box(&QDD_RAD_S2),
            )
        });
    });
    c.bench_function("gravity/ur10e", |b| {
        b.iter(|| ur10e.gravity_nm(black_box(&Q_RAD)));
    });
    c.bench_function("mass_matrix/ur10e", |b| {
        b.iter(|| ur10e.mass_matrix_kg_m2(black_box(&Q_RAD)));
    });
    c.bench_function("momentum/ur10e", |b| {
        b.iter(|| ur10e.momentum(black_box(&Q_RAD), black_box(&QD_RAD_S)));
    });
    // One live effort step: model, measured from currents, friction fit, residual statistics,
    // payload identification's forgetting and the momentum observer, as the service runs it per
    // joint sample of a robot with `effort = true` (a moving sample: no rest-time estimate).
    let arm = catalog::arm("ur10e").expect("catalog model");
    let mut monitor =
        EffortMonitor::new(&arm, &EffortConfig::default(), 10.0).expect("a UR10e monitor");
    let mut state = JointState::new(6);
    state.set(JointQuantity::Velocity, &QD_RAD_S);
    state.set(JointQuantity::TargetPosition, &Q_RAD);
    state.set(JointQuantity::TargetVelocity, &QD_RAD_S);
    state.set(JointQuantity::TargetAcceleration, &QDD_RAD_S2);
    state.set(JointQuantity::Current, &[0.5, -2.1, 1.3, 0.2, -0.1, 0.05]);
    state.set(JointQuantity::Temperature, &[35.0; 6]);
    let mut stamp_s = 0.0;
    c.bench_function("effort_step/ur10e", |b| {
        b.iter(|| {
            stamp_s += 0.002;
            monitor.step(
                black_box(stamp_s),
                black_box(&Q_RAD),
                black_box(&state),
                |_| {},
            )
        });
    });
    let model = RobotModel::nominal("ur10e").expect("catalog model");
    c.bench_function("baseline/fk_pose_only_ur10e", |b| {
        b.iter(|| model.chain().pose_unchecked(black_box(&Q_RAD)));
    });
}

criterion_group!(benches, dynamics);
criterion_main!(benches);
