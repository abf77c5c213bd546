//! armtwin's RNEA timed exactly as `benches/pinocchio_rnea.cpp` times Pinocchio's, for a
//! like-for-like comparison: the UR10e with a 5 kg payload and rotor inertia, 3 000 rounds of 200
//! calls, reporting the fastest round and the median per call, and the torques for the state.
//!
//! `cargo run --release -p armtwin-core --example dynamics_min_time`
#![allow(
    clippy::print_stdout,
    clippy::expect_used,
    reason = "a measuring binary whose fixtures are the checkout's own constants"
)]
#![allow(
    clippy::disallowed_methods,
    reason = "a timing tool at the edge: it reads the clock the core never does"
)]

use std::hint::black_box;
use std::time::Instant;

use armtwin_core::dynamics::{ArmDynamics, Payload};
use armtwin_core::model::catalog;

fn main() {
    let dynamics = ArmDynamics::<6>::from_arm(&catalog::arm("ur10e").expect("catalog model"))
        .expect("published parameters")
        .with_payload(Payload::point_mass(5.0, [0.01, 0.0, 0.08]))
        .expect("valid payload");
    let mut q = [0.31, -1.22, 1.43, -0.87, 1.52, 0.64];
    let qd = [0.4, -0.3, 0.5, 0.8, -0.6, 1.1];
    let qdd = [1.5, -2.0, 2.5, 3.0, -1.0, 4.0];
    let (rounds, calls) = (3000, 200);
    let mut per_call_ns = Vec::with_capacity(rounds);
    let mut sink = 0.0;
    for _ in 0..rounds {
        let start = Instant::now();
        for _ in 0..calls {
            // A fresh state each call, as the C++ side does.
            q[0] += 1e-12;
            sink += dynamics.inverse_dynamics_nm(black_box(&q), black_box(&qd), black_box(&qdd))[1];
        }
        per_call_ns.push(start.elapsed().as_secs_f64() * 1e9 / f64::from(calls));
    }
    per_call_ns.sort_by(f64::total_cmp);
    q[0] = 0.31;
    println!(
        "armtwin rnea/ur10e: fastest round {:.1} ns, median {:.1} ns per call (sink {sink:e})",
        per_call_ns[0],
        per_call_ns[rounds / 2]
    );
    println!("tau_nm = {:?}", dynamics.inverse_dynamics_nm(&q, &qd, &qdd));
}
