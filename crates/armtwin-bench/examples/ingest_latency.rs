//! The time armtwin's own work adds to each message, as a distribution: every joint and
//! measured message of the service benchmark's load timed one by one through the service's entry
//! points and encoders (`armtwin_bench::ingest_fixture`), without Zenoh. This is what
//! `armtwin serve` does inside Zenoh's receive callback beyond what the plain echo does there (both
//! `put` one message per message received), so its percentiles bound armtwin's added latency,
//! lock waits aside. Measured in process because the service benchmark's round trip cannot
//! resolve work this small on a shared machine (the echo's own tail latency moves far more
//! between runs).
//!
//! `cargo run --release -p armtwin-bench --example ingest_latency [-- MESSAGES]`
//! (default 2 000 000 messages). Prints percentiles in µs, and the clock's own cost.
#![allow(
    clippy::expect_used,
    reason = "a measuring binary whose fixtures are the checkout's own constants"
)]
#![allow(clippy::print_stdout, reason = "a measuring tool's report")]

use std::time::Instant;

use armtwin_bench::ingest_fixture::{Encode, Load, RENDERED};

/// The percentile `per_mille` / 1000 of sorted nanoseconds (nearest rank below), in µs.
fn percentile_us(sorted_ns: &[u64], per_mille: usize) -> f64 {
    sorted_ns[(sorted_ns.len() - 1) * per_mille / 1000] as f64 / 1e3
}

fn report(name: &str, mut ns: Vec<u64>) {
    ns.sort_unstable();
    let mean_us = ns.iter().sum::<u64>() as f64 / ns.len() as f64 / 1e3;
    println!(
        "{name:<16} {:>9} messages  mean {mean_us:6.2}  p50 {:6.2}  p99 {:6.2}  p99.9 {:7.2}  max {:8.1} µs",
        ns.len(),
        percentile_us(&ns, 500),
        percentile_us(&ns, 990),
        percentile_us(&ns, 999),
        percentile_us(&ns, 1000),
    );
}

fn main() {
    let messages: usize = std::env::args()
        .nth(1)
        .and_then(|argument| argument.parse().ok())
        .unwrap_or(2_000_000);
    let mut sink = Encode::default();
    let samples = messages / 2;
    let mut joints_ns = Vec::with_capacity(samples);
    let mut measured_ns = Vec::with_capacity(samples);
    let mut clock_ns = Vec::with_capacity(samples);
    // One pipeline throughout, as a robot's twin lives in the service: its window fills once.
    let mut pipeline = Load::pipeline();
    let mut done = 0;
    while done < samples {
        let load = Load::starting_at(done as u64);
        let chunk = (samples - done).min(RENDERED);
        for index in 0..chunk {
            let start = Instant::now();
            load.joints(&mut pipeline, index, &mut sink);
            let between = Instant::now();
            load.measured(&mut pipeline, index, &mut sink);
            let end = Instant::now();
            let after = Instant::now();
            joints_ns.push((between - start).as_nanos() as u64);
            measured_ns.push((end - between).as_nanos() as u64);
            clock_ns.push((after - end).as_nanos() as u64);
        }
        done += chunk;
    }
    println!(
        "armtwin's own work per message (decode, pipeline, encode; one robot, 100 Hz stamps):"
    );
    report("joint message", joints_ns.clone());
    report("measured pose", measured_ns.clone());
    joints_ns.extend(measured_ns);
    report("either", joints_ns);
    report("clock read", clock_ns);
}
