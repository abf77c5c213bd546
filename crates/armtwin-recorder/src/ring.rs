//! A robot's recent streams at full rate: fixed-size records of `f64`s, kept for a span of
//! source time, within a byte budget of the robot's own and one the whole fleet shares.
//!
//! Pure: no I/O, no clock. Must stay cheap per record: a push copies the record's values and, now
//! and then, drops the oldest; memory grows (by doubling) only while the span is not yet full
//! and both budgets have room, so a slow robot holds little and a fast one at most its budget.

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Bytes the rings of a whole fleet may hold, and what they hold now.
#[derive(Debug)]
pub struct RingBudget {
    used_bytes: AtomicUsize,
    limit_bytes: usize,
}

impl RingBudget {
    /// A budget of `limit_bytes` for every ring that shares it.
    #[must_use]
    pub fn new(limit_bytes: usize) -> Arc<Self> {
        Arc::new(Self {
            used_bytes: AtomicUsize::new(0),
            limit_bytes,
        })
    }

    /// Bytes the rings hold now (their allocations).
    #[must_use]
    pub fn used_bytes(&self) -> usize {
        self.used_bytes.load(Ordering::Relaxed)
    }

    /// Takes `bytes` more if they fit under the limit.
    fn take(&self, bytes: usize) -> bool {
        self.used_bytes
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |used| {
                used.checked_add(bytes)
                    .filter(|&after| after <= self.limit_bytes)
            })
            .is_ok()
    }

    fn give_back(&self, bytes: usize) {
        self.used_bytes.fetch_sub(bytes, Ordering::Relaxed);
    }
}

/// Records of `stride` values each, the first of them the record's source stamp (s), in the
/// order they were pushed.
#[derive(Debug)]
pub struct RecordRing {
    stride: usize,
    span_s: f64,
    max_values: usize,
    values: VecDeque<f64>,
    budget: Arc<RingBudget>,
    /// Bytes taken from `budget` (the allocation's size when it was last grown).
    held_bytes: usize,
}

/// Records a ring allocates room for on its first push.
const FIRST_RECORDS: usize = 64;

impl RecordRing {
    /// An empty ring of records of `stride` values (`stride ≥ 1`), kept for `span_s` of source
    /// time before the newest, in at most `max_bytes`, sharing `budget` with the fleet's.
    #[must_use]
    pub fn new(stride: usize, span_s: f64, max_bytes: usize, budget: Arc<RingBudget>) -> Self {
        let stride = stride.max(1);
        Self {
            stride,
            span_s,
            max_values: (max_bytes / size_of::<f64>()) / stride * stride,
            values: VecDeque::new(),
            budget,
            held_bytes: 0,
        }
    }

    /// Values per record.
    #[must_use]
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// Records held.
    #[must_use]
    pub fn len(&self) -> usize {
        self.values.len() / self.stride
    }

    /// Whether no record is held.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Bytes the ring holds (its allocation).
    #[must_use]
    pub fn held_bytes(&self) -> usize {
        self.held_bytes
    }

    /// Appends `record` (`stride` values, the stamp first; a shorter one is padded with NaN, a
    /// longer one cut). Records older than the span before it are dropped; with no room left in
    /// either budget, the oldest is.
    pub fn push(&mut self, record: &[f64]) {
        let stamp_s = record.first().copied().unwrap_or(f64::NAN);
        while let Some(&oldest_s) = self.values.front() {
            // Also drops records stamped after this one: a clock that went back starts afresh.
            if oldest_s >= stamp_s - self.span_s && oldest_s <= stamp_s {
                break;
            }
            self.values.drain(..self.stride);
        }
        if self.values.len() + self.stride > self.values.capacity() && !self.grow() {
            if self.values.len() < self.stride {
                return;
            }
            self.values.drain(..self.stride);
        }
        let take = record.len().min(self.stride);
        self.values.extend(&record[..take]);
        self.values
            .extend(std::iter::repeat_n(f64::NAN, self.stride - take));
    }

    /// Makes room for more records, if both budgets allow; whether it did.
    fn grow(&mut self) -> bool {
        let capacity = self.values.capacity();
        let wanted = (capacity * 2)
            .max(FIRST_RECORDS * self.stride)
            .min(self.max_values);
        if wanted < self.values.len() + self.stride {
            return false;
        }
        let extra_bytes = (wanted - capacity) * size_of::<f64>();
        if !self.budget.take(extra_bytes) {
            return false;
        }
        self.values.reserve_exact(wanted - self.values.len());
        let now_bytes = self.values.capacity() * size_of::<f64>();
        // The allocator may give more than asked: counted as held.
        let granted = self.held_bytes + extra_bytes;
        if now_bytes > granted {
            // Over the limit by at most the allocator's rounding.
            self.budget
                .used_bytes
                .fetch_add(now_bytes - granted, Ordering::Relaxed);
        }
        self.held_bytes = now_bytes.max(granted);
        true
    }

    /// Appends to `out` every record stamped in `[from_s, until_s]`, oldest first; how many.
    pub fn copy_range(&self, from_s: f64, until_s: f64, out: &mut Vec<f64>) -> usize {
        let mut copied = 0;
        for start in (0..self.values.len()).step_by(self.stride) {
            let stamp_s = self.values[start];
            if (from_s..=until_s).contains(&stamp_s) {
                out.extend(self.values.range(start..start + self.stride));
                copied += 1;
            }
        }
        copied
    }

    /// The newest record's stamp, if any.
    #[must_use]
    pub fn newest_s(&self) -> Option<f64> {
        self.values
            .get(self.values.len().checked_sub(self.stride)?)
            .copied()
    }
}

impl Drop for RecordRing {
    fn drop(&mut self) {
        self.budget.give_back(self.held_bytes);
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::float_cmp, reason = "records are copied, not computed")]
    use super::{RecordRing, RingBudget};

    fn records(ring: &RecordRing) -> Vec<f64> {
        let mut out = Vec::new();
        ring.copy_range(f64::NEG_INFINITY, f64::INFINITY, &mut out);
        out
    }

    #[test]
    fn keeps_the_span_before_the_newest_record_and_no_more() {
        let budget = RingBudget::new(1 << 20);
        let mut ring = RecordRing::new(2, 1.0, 1 << 20, budget);
        for i in 0..500 {
            let stamp_s = f64::from(i) * 0.01;
            ring.push(&[stamp_s, f64::from(i)]);
        }
        // 4.99 back to 3.99: 101 records.
        assert_eq!(ring.len(), 101);
        let held = records(&ring);
        assert_eq!(held[1], 399.0);
        assert_eq!(held[held.len() - 1], 499.0);
        assert_eq!(ring.newest_s(), Some(4.99));
    }

    #[test]
    fn the_robots_budget_bounds_the_records_and_the_oldest_go() {
        let budget = RingBudget::new(1 << 20);
        // 64 records of two values in 1 KiB.
        let mut ring = RecordRing::new(2, 100.0, 1024, budget.clone());
        for i in 0..1000 {
            ring.push(&[f64::from(i), f64::from(i)]);
        }
        assert_eq!(ring.len(), 64);
        assert!(ring.held_bytes() <= 1024 + 64, "{}", ring.held_bytes());
        assert_eq!(records(&ring)[0], 936.0);
        assert_eq!(budget.used_bytes(), ring.held_bytes());
        drop(ring);
        assert_eq!(budget.used_bytes(), 0);
    }

    #[test]
    fn the_fleets_budget_is_shared_and_a_full_one_keeps_rings_at_their_size() {
        let budget = RingBudget::new(4096);
        let mut first = RecordRing::new(4, 100.0, 1 << 20, budget.clone());
        let mut second = RecordRing::new(4, 100.0, 1 << 20, budget.clone());
        for i in 0..1000 {
            first.push(&[f64::from(i), 0.0, 0.0, 0.0]);
            second.push(&[f64::from(i), 0.0, 0.0, 0.0]);
        }
        assert!(budget.used_bytes() <= 4096 + 128, "{}", budget.used_bytes());
        assert!(!first.is_empty());
        assert_eq!(records(&first).last(), Some(&0.0));
        assert_eq!(first.newest_s(), Some(999.0));
    }

    #[test]
    fn a_clock_that_goes_back_starts_afresh_and_ranges_select_by_stamp() {
        let budget = RingBudget::new(1 << 20);
        let mut ring = RecordRing::new(1, 10.0, 1 << 20, budget);
        for stamp_s in [100.0, 101.0, 102.0, 103.0] {
            ring.push(&[stamp_s]);
        }
        let mut out = Vec::new();
        assert_eq!(ring.copy_range(101.0, 102.5, &mut out), 2);
        assert_eq!(out, [101.0, 102.0]);
        ring.push(&[5.0]);
        assert_eq!(records(&ring), [5.0]);
    }

    #[test]
    fn short_records_are_padded_and_long_ones_cut() {
        let budget = RingBudget::new(1 << 20);
        let mut ring = RecordRing::new(3, 10.0, 1 << 20, budget);
        ring.push(&[1.0]);
        ring.push(&[2.0, 3.0, 4.0, 5.0]);
        let held = records(&ring);
        assert_eq!(held[0], 1.0);
        assert!(held[1].is_nan() && held[2].is_nan());
        assert_eq!(&held[3..], [2.0, 3.0, 4.0]);
    }
}
