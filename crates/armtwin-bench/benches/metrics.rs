//! Streaming statistics cost: one sample into the exact sliding window in steady state (each add
//! evicts one), a window readout (rounding the 18 exact sums), and the cumulative statistics.
//!
//! `cargo bench -p armtwin-bench --bench metrics`
#![allow(
    clippy::expect_used,
    reason = "a measuring binary whose fixtures are the checkout's own constants"
)]
use std::hint::black_box;

use armtwin::metrics::{CumulativeStats, METRIC_COUNT, WindowStats};
use criterion::{Criterion, criterion_group, criterion_main};

/// Deviation-like magnitudes of sample `i`: millimetres and milliradians with some noise.
fn magnitudes(i: u64) -> [f64; METRIC_COUNT] {
    std::array::from_fn(|m| {
        let phase = (i as f64) * 0.37 + m as f64;
        1e-3 * (1.5 + phase.sin()) * (1.0 + 1e-3 * (phase * 7.1).cos())
    })
}

/// A window of 10 s at 100 Hz, filled: every further add evicts the oldest sample.
fn full_window() -> (WindowStats, u64) {
    let mut window = WindowStats::new(10.0, 100_000);
    let filled = 1000;
    for i in 0..filled {
        window.add(i as f64 * 0.01, &magnitudes(i));
    }
    (window, filled)
}

fn window(c: &mut Criterion) {
    let samples: Vec<[f64; METRIC_COUNT]> = (0..4096).map(magnitudes).collect();
    let (mut window, mut next) = full_window();
    c.bench_function("window/add_steady_state", |b| {
        b.iter(|| {
            let x = &samples[(next % 4096) as usize];
            window.add(black_box(next as f64 * 0.01), black_box(x));
            next += 1;
        });
    });
    let (window, _) = full_window();
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

criterion_group!(benches, window);
criterion_main!(benches);
