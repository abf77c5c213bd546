//! Heap allocations of the service's own work per steady-state sample, counted by a global
//! allocator: one robot's joint and measured messages, as `armtwin-bench load` sends them, decoded
//! and stepped through the service's entry points (`ingest::joint_message` /
//! `ingest::measured_message`) into a sink that encodes each output as `armtwin serve` does before
//! its `put`. Only this thread's allocations count (the test harness's threads allocate too).
//!
//! What Zenoh adds is not counted here: each `put` wraps its payload in an `Arc` (an array: one
//! allocation; a `Vec`: one more), and its routing and transport allocate on their own.
#![allow(
    clippy::expect_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]
#![allow(
    unsafe_code,
    reason = "a global allocator is an `unsafe impl`; this test binary is not product code"
)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use armtwin_bench::ingest_fixture::{Encode, Load, RobotKeys, feed};
use armtwin_bench::workload::Workload;
use armtwin_codec::zser;
use armtwin_mesh::ingest::Codec;

thread_local! {
    /// Allocations (and reallocations) made by this thread.
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

/// `System`, counting each thread's allocations.
struct Counting;

fn count() {
    // `try_with`: a thread being torn down has no counter any more, and is not measured.
    let _ = ALLOCATIONS.try_with(|allocations| allocations.set(allocations.get() + 1));
}

// SAFETY: every call is forwarded unchanged to `System`, which upholds `GlobalAlloc`'s contract;
// the counter only observes calls (a `const` thread-local of a `Cell` never allocates).
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: the caller's layout goes to `System` as given.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: as for `alloc`.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from this allocator, i.e. from `System`, with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: as for `dealloc`; `new_size` is the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}

/// Samples before the count: the 10-s window full at 100 Hz, and its buffers at their size.
const WARM_UP: u64 = 3_000;
/// Samples counted.
const COUNTED: u64 = 2_000;

/// Allocations over the [`COUNTED`] samples after [`WARM_UP`], and the outputs encoded meanwhile.
fn counted(binary: bool) -> (u64, u64) {
    let workload = Workload::ur10e().expect("the ur10e's payloads");
    let keys = RobotKeys::of(0);
    let mut twin = Load::pipeline();
    let robot = twin
        .robots
        .find(&keys.id)
        .expect("a configured robot")
        .clone();
    // The codecs `ingest::codec_of` picks for the load's encodings.
    let codecs = if binary {
        (
            Codec::ZenohSerialized(Some(zser::Schema::Joints)),
            Codec::ZenohSerialized(Some(zser::Schema::Pose)),
        )
    } else {
        (Codec::Json, Codec::Json)
    };
    // Rendered ahead: the load's payloads are the gateway's allocations, not the service's.
    let payloads: Vec<(f64, Vec<u8>, Vec<u8>)> = (0..WARM_UP + COUNTED)
        .map(|sample| {
            let stamp_s = 1000.0 + sample as f64 * 0.01;
            if binary {
                (
                    stamp_s,
                    workload.joints_zser(sample, stamp_s, sample + 1, false),
                    workload.measured_zser(sample, stamp_s),
                )
            } else {
                (
                    stamp_s,
                    workload.joints(sample, stamp_s).into_bytes(),
                    workload.measured(sample, stamp_s).into_bytes(),
                )
            }
        })
        .collect();
    let mut sink = Encode {
        binary,
        ..Encode::default()
    };
    let mut before = (0, 0);
    for (sample, (stamp_s, joints, measured)) in payloads.iter().enumerate() {
        if sample as u64 == WARM_UP {
            before = (allocations(), sink.outputs);
        }
        feed(
            &mut twin.pipeline,
            (&robot, &keys),
            codecs,
            (*stamp_s, joints, measured),
            &mut sink,
        );
    }
    assert_eq!(sink.events, 0, "nothing rejected, no gap");
    (allocations() - before.0, sink.outputs - before.1)
}

#[test]
fn a_steady_binary_sample_allocates_nothing_in_or_out() {
    let (allocations, outputs) = counted(true);
    assert_eq!(outputs, 2 * COUNTED, "a pose and a deviation per sample");
    assert_eq!(allocations, 0, "decode, twin, statistics and encoding");
}

#[test]
fn a_steady_json_sample_allocates_only_its_two_output_texts() {
    let (allocations, outputs) = counted(false);
    assert_eq!(outputs, 2 * COUNTED);
    // Each output's text is a `Vec` Zenoh takes over; decoding and the twin allocate nothing.
    assert_eq!(allocations, outputs);
}
