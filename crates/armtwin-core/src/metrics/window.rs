//! A sliding window of source time kept as a ring of time slices: per slice and metric the count,
//! sum, sum of squares and maximum. A sample costs one slice update, and memory is fixed by the
//! number of slices, whatever the rate.
//!
//! Owns [`SlicedWindow`], the one windowed statistic of the core: the deviation metrics' window
//! ([`WindowStats`]) and the effort monitor's residual window are both one. Must not keep
//! samples: what a slice holds is what the window reports.

use super::{METRIC_COUNT, StatsSet, acceptable};

/// Slices a window is split into unless configured otherwise: each slice is 5 % of the window
/// (0.5 s of the default 10 s, so that a second holds whole slices); the window's memory is in
/// proportion to it.
pub const DEFAULT_WINDOW_SLICES: usize = 20;

/// The relative error that updating the window's totals may leave in them before they are rebuilt
/// from the slices: a tenth of the error the window promises (1e-12), the rest being the slices'
/// own rounding.
const DRIFT_LIMIT: f64 = 1e-13;

/// 2⁻⁵³, the unit roundoff: one addition's rounding error is at most this times its result.
const UNIT_ROUNDOFF: f64 = f64::EPSILON / 2.0;

/// What one slice holds of its samples, per metric (structure of arrays: each update touches
/// three rows of contiguous values).
#[derive(Debug, Clone, Copy)]
struct Slice<const M: usize> {
    count: u64,
    sums: [f64; M],
    sums_of_squares: [f64; M],
    /// 0 for an empty slice: values are non-negative, so 0 is the maximum of nothing.
    maxima: [f64; M],
}

impl<const M: usize> Default for Slice<M> {
    fn default() -> Self {
        Self {
            count: 0,
            sums: [0.0; M],
            sums_of_squares: [0.0; M],
            maxima: [0.0; M],
        }
    }
}

impl<const M: usize> Slice<M> {
    #[inline]
    fn add(&mut self, values: &[f64; M]) {
        self.count += 1;
        for (m, &x) in values.iter().enumerate() {
            self.sums[m] += x;
            self.sums_of_squares[m] += x * x;
            // Not `f64::max`: values are never NaN, and a plain comparison vectorises to one
            // instruction.
            self.maxima[m] = if x > self.maxima[m] {
                x
            } else {
                self.maxima[m]
            };
        }
    }
}

/// Count, sums, sums of squares and maxima of some samples, per metric: what a window reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowTotals<const M: usize> {
    /// Samples counted.
    pub n: u64,
    /// Per metric, the sum of the values.
    pub sums: [f64; M],
    /// Per metric, the sum of the squared values.
    pub sums_of_squares: [f64; M],
    /// Per metric, the largest value; 0 when `n` is 0.
    pub maxima: [f64; M],
}

/// Statistics of `M` non-negative metrics over the last `window_s` of source time, kept in
/// `slices` time slices of `window_s / slices` each.
///
/// **The window.** Source time is cut into slices on a fixed grid: slice `k` holds the stamps
/// `t` with `⌊t · slices / window_s⌋ = k` ([`slice_of`](Self::slice_of)). With `K` the slice of
/// the newest stamp seen (or of the time [`advance_to`](Self::advance_to) moved to), the window
/// holds the samples of slices `K − slices + 1 ..= K`. Its edge thus lies at the start of the
/// slice after the one holding `newest − window_s`: the window covers more than
/// `window_s − window_s / slices` and at most `window_s` of source time. A sample stamped
/// `newest − window_s` or earlier is never in it; one stamped less than `window_s − window_s /
/// slices` before the newest always is, however late it arrives.
///
/// **Accuracy.** `n` is exact; the maxima are exact. The sums are within 1e-12 relative of the
/// exact sums of the same samples while a slice holds at most ~8 000 samples (a slice's own
/// recursive sum and the sum over slices round at most `(samples per slice + slices)` times
/// 2⁻⁵³ relative, all terms being non-negative; the updates' rounding is held to 1e-13 below).
///
/// **Design.** A sample updates its slice: the newest, or, when stamped late but inside the
/// window, its own older slice (sums and maxima commute, so arrival order does not matter). The
/// totals of the closed slices are kept apart: a slice enters them when it closes, and the
/// oldest leaves them (subtracted) when the window moves past it. The maxima are recomputed from
/// the slices only when the last slice holding one leaves (a count of the slices that tie it
/// keeps a constant error from recomputing at every close). The sums are rebuilt from the slices
/// once per turn of the ring, so no rounding outlives one window, and sooner when subtracting a
/// large slice from small totals could leave more than 1e-13 of relative error in them (each
/// update's rounding is bounded by 2⁻⁵³ times its result, and those bounds are summed). Either
/// recomputation rebuilds everything: both read every slice.
///
/// **Cost.** An [`add`](Self::add) to the newest slice: one multiplication and floor for the
/// slice, then per metric an add, a multiply-add and a max. Closing a slice: per metric an add
/// and a subtract of the totals; a rebuild from the slices every `slices` closes, and when the
/// last holder of a maximum leaves (for an error that keeps falling, at every close). A
/// [`totals`](Self::totals) adds the newest slice to the closed totals. Memory fixed at `slices × (8 + 24 · M)` bytes, allocated at
/// construction: 22 KB for the nine deviation metrics in 100 slices.
#[derive(Debug, Clone)]
pub struct SlicedWindow<const M: usize> {
    window_s: f64,
    /// `slices / window_s`: a stamp times this, floored, is its slice.
    slices_per_s: f64,
    /// The ring: slice `k` lives at `k mod slices`. Every slice outside the window is empty.
    ring: Box<[Slice<M>]>,
    /// The newest slice, and where it lives in the ring; `None` before any time.
    newest: Option<(i64, usize)>,
    /// Totals of the slices in the window but the newest.
    closed: Slice<M>,
    /// Per metric, how many of those slices hold the closed maximum (when it is above 0): a
    /// maximum is recomputed only when the last of them leaves, so ties cost nothing.
    holders: [u32; M],
    /// Per total of `closed` (sums, then sums of squares), the sum of its values after each
    /// update since it was last rebuilt: 2⁻⁵³ times this bounds the rounding the updates left.
    drift: [[f64; M]; 2],
    /// Slices closed since `closed` was last rebuilt.
    closes_since_rebuild: usize,
}

/// [`SlicedWindow`] over the nine deviation metrics, reported as [`StatsSet`].
pub type WindowStats = SlicedWindow<METRIC_COUNT>;

impl<const M: usize> SlicedWindow<M> {
    /// An empty window over the last `window_s` seconds of source time, in `slices` slices.
    ///
    /// # Panics
    ///
    /// If `window_s` is not positive and finite, or `slices` is zero, or a slice is too short
    /// for a double to tell stamps apart (`slices / window_s` infinite): the configuration layer
    /// validates them.
    #[must_use]
    pub fn new(window_s: f64, slices: usize) -> Self {
        assert!(
            window_s > 0.0 && window_s.is_finite(),
            "window_s must be positive and finite, got {window_s}"
        );
        assert!(slices > 0, "a window needs at least one slice");
        let slices_per_s = slices as f64 / window_s;
        assert!(
            slices_per_s.is_finite(),
            "slices of {window_s} s / {slices}"
        );
        Self {
            window_s,
            slices_per_s,
            ring: vec![Slice::default(); slices].into_boxed_slice(),
            newest: None,
            closed: Slice::default(),
            holders: [0; M],
            drift: [[0.0; M]; 2],
            closes_since_rebuild: 0,
        }
    }

    /// The window length (s) of source time.
    #[must_use]
    pub fn window_s(&self) -> f64 {
        self.window_s
    }

    /// The number of slices the window is kept in.
    #[must_use]
    pub fn slices(&self) -> usize {
        self.ring.len()
    }

    /// The slice holding source time `stamp_s`: `⌊stamp_s · slices / window_s⌋` (saturating at
    /// the ends of `i64`).
    #[must_use]
    pub fn slice_of(&self, stamp_s: f64) -> i64 {
        (stamp_s * self.slices_per_s).floor() as i64
    }

    /// Where slice `slice` starts (source time, s): `slice · window_s / slices`.
    #[must_use]
    pub fn slice_start_s(&self, slice: i64) -> f64 {
        slice as f64 / self.slices_per_s
    }

    /// Count, sums, sums of squares and maxima of the samples in the newest slice alone.
    #[must_use]
    pub fn newest_totals(&self) -> WindowTotals<M> {
        let newest = self.newest_slot();
        WindowTotals {
            n: newest.count,
            sums: newest.sums,
            sums_of_squares: newest.sums_of_squares,
            maxima: newest.maxima,
        }
    }

    /// The newest slice: that of the newest stamp added or time advanced to; `None` before any.
    #[must_use]
    pub fn newest_slice(&self) -> Option<i64> {
        self.newest.map(|(slice, _)| slice)
    }

    /// Samples in the window.
    #[must_use]
    pub fn len(&self) -> u64 {
        self.closed.count + self.newest_slot().count
    }

    /// Whether the window holds no sample.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Adds one sample stamped `stamp_s` (source time, s): to the newest slice, or to a newer one
    /// (the window moves on), or, stamped late but inside the window, to its own slice.
    ///
    /// Returns `false`, leaving the window unchanged, when the sample does not enter it: stamped
    /// before the window (or not finite), or a value negative, not finite or above 1e100
    /// (garbage in any unit; callers normally reject such samples earlier).
    pub fn add(&mut self, stamp_s: f64, values: &[f64; M]) -> bool {
        if !stamp_s.is_finite() || !acceptable(values) {
            return false;
        }
        self.add_to_slice(self.slice_of(stamp_s), values)
    }

    /// [`add`](Self::add) of a sample whose stamp is finite, whose values are acceptable and
    /// whose slice the caller already computed.
    #[inline]
    pub(super) fn add_to_slice(&mut self, slice: i64, values: &[f64; M]) -> bool {
        match self.newest {
            Some((newest, slot)) if slice == newest => self.ring[slot].add(values),
            Some((newest, _)) if slice < newest => return self.add_late(slice, newest, values),
            _ => {
                self.move_to(slice);
                self.newest_slot_mut().add(values);
            }
        }
        true
    }

    /// Moves the window's end to source time `now_s` without adding a sample: the slices it
    /// leaves behind leave the window (so a window whose inputs stopped empties as time goes on).
    /// A time in the newest slice or earlier, or not finite, changes nothing.
    pub fn advance_to(&mut self, now_s: f64) {
        if !now_s.is_finite() {
            return;
        }
        let slice = self.slice_of(now_s);
        if self.newest.is_none_or(|(newest, _)| slice > newest) {
            self.move_to(slice);
        }
    }

    /// Count, sums, sums of squares and maxima of the samples in the window.
    #[must_use]
    pub fn totals(&self) -> WindowTotals<M> {
        let newest = self.newest_slot();
        let n = self.closed.count + newest.count;
        if n == 0 {
            return WindowTotals {
                n,
                sums: [0.0; M],
                sums_of_squares: [0.0; M],
                maxima: [0.0; M],
            };
        }
        // Never below 0: a total that subtraction took a rounding below the slices' is rebuilt,
        // but a sum of squares under a square root must not be negative even for an instant.
        WindowTotals {
            n,
            sums: std::array::from_fn(|m| (self.closed.sums[m] + newest.sums[m]).max(0.0)),
            sums_of_squares: std::array::from_fn(|m| {
                (self.closed.sums_of_squares[m] + newest.sums_of_squares[m]).max(0.0)
            }),
            maxima: std::array::from_fn(|m| self.closed.maxima[m].max(newest.maxima[m])),
        }
    }

    /// Forgets every sample and the newest time, keeping the window length and slices.
    pub fn reset(&mut self) {
        self.ring.fill(Slice::default());
        self.newest = None;
        self.clear_closed();
    }

    fn newest_slot(&self) -> &Slice<M> {
        &self.ring[self.newest.map_or(0, |(_, slot)| slot)]
    }

    fn newest_slot_mut(&mut self) -> &mut Slice<M> {
        &mut self.ring[self.newest.map_or(0, |(_, slot)| slot)]
    }

    /// The number of slices, as slice indices count.
    fn slice_count(&self) -> i64 {
        // A ring of more than 2⁶³ slices could not be allocated.
        i64::try_from(self.ring.len()).unwrap_or(i64::MAX)
    }

    /// Where slice `slice` lives in the ring.
    fn slot_of(&self, slice: i64) -> usize {
        // In `0..slices`.
        slice.rem_euclid(self.slice_count()).unsigned_abs() as usize
    }

    /// A sample of slice `slice`, older than the `newest`: into its slice, and into the closed
    /// totals, which hold that slice already; `false` if the slice has left the window.
    #[cold]
    fn add_late(&mut self, slice: i64, newest: i64, values: &[f64; M]) -> bool {
        if slice <= newest.saturating_sub(self.slice_count()) {
            return false;
        }
        let slot = self.slot_of(slice);
        let before = self.ring[slot].maxima;
        self.ring[slot].add(values);
        let closed = &mut self.closed;
        closed.count += 1;
        for (m, &x) in values.iter().enumerate() {
            closed.sums[m] += x;
            closed.sums_of_squares[m] += x * x;
            if x > closed.maxima[m] {
                closed.maxima[m] = x;
                self.holders[m] = 1;
            } else if x >= closed.maxima[m] && x > before[m] && x > 0.0 {
                // Its slice now ties the maximum too.
                self.holders[m] += 1;
            }
        }
        self.note_updates();
        self.rebuild_if_drifted();
        true
    }

    /// Makes `slice`, newer than the newest, the newest: closes the newest slice into the
    /// totals, and the slices the window leaves behind out of them.
    fn move_to(&mut self, slice: i64) {
        let slices = self.ring.len();
        let Some((newest, slot)) = self.newest else {
            // A fresh window: every slice is empty.
            self.newest = Some((slice, self.slot_of(slice)));
            return;
        };
        let steps = slice.saturating_sub(newest);
        if steps >= self.slice_count() {
            // Everything leaves.
            self.ring.fill(Slice::default());
            self.clear_closed();
            self.newest = Some((slice, self.slot_of(slice)));
            return;
        }
        // Positive and below `slices`.
        let steps = steps.unsigned_abs() as usize;
        let closing = self.ring[slot];
        self.merge_closed(&closing);
        let mut maximum_left = false;
        let mut next = slot;
        for _ in 0..steps {
            next = if next + 1 == slices { 0 } else { next + 1 };
            // Slice `newest + step − slices`, leaving; its place becomes an empty newer slice.
            let leaving = std::mem::take(&mut self.ring[next]);
            if leaving.count > 0 {
                maximum_left |= self.subtract_closed(&leaving);
            }
        }
        self.newest = Some((slice, next));
        self.closes_since_rebuild += steps;
        if self.closed.count == 0 {
            self.clear_closed();
        } else if self.closes_since_rebuild >= slices || maximum_left {
            // A rebuild reads every slice, as a maximum's recomputation would.
            self.rebuild();
        } else {
            self.rebuild_if_drifted();
        }
    }

    fn merge_closed(&mut self, slice: &Slice<M>) {
        let closed = &mut self.closed;
        closed.count += slice.count;
        for m in 0..M {
            closed.sums[m] += slice.sums[m];
            closed.sums_of_squares[m] += slice.sums_of_squares[m];
            if slice.maxima[m] > closed.maxima[m] {
                closed.maxima[m] = slice.maxima[m];
                self.holders[m] = 1;
            } else if slice.maxima[m] >= closed.maxima[m] && slice.maxima[m] > 0.0 {
                self.holders[m] += 1;
            }
        }
        self.note_updates();
    }

    /// Takes `slice` out of the closed totals; whether it was the last to hold one of their
    /// maxima.
    fn subtract_closed(&mut self, slice: &Slice<M>) -> bool {
        let closed = &mut self.closed;
        closed.count -= slice.count;
        let mut maximum_left = false;
        for m in 0..M {
            closed.sums[m] -= slice.sums[m];
            closed.sums_of_squares[m] -= slice.sums_of_squares[m];
            // The leaving slice's maximum is at most the totals'; a maximum of 0 (values are
            // never negative) stays 0 whatever leaves.
            if slice.maxima[m] >= closed.maxima[m] && slice.maxima[m] > 0.0 {
                self.holders[m] -= 1;
                maximum_left |= self.holders[m] == 0;
            }
        }
        self.note_updates();
        maximum_left
    }

    /// Adds the closed totals' new values to their drift bounds.
    fn note_updates(&mut self) {
        for m in 0..M {
            self.drift[0][m] += self.closed.sums[m].abs();
            self.drift[1][m] += self.closed.sums_of_squares[m].abs();
        }
    }

    /// Rebuilds the closed totals when the rounding the updates may have left in one exceeds
    /// [`DRIFT_LIMIT`] of it (or it went below 0).
    fn rebuild_if_drifted(&mut self) {
        let drifted = |bounds: &[f64; M], totals: &[f64; M]| {
            bounds
                .iter()
                .zip(totals)
                .any(|(bound, total)| UNIT_ROUNDOFF * bound > DRIFT_LIMIT * total)
        };
        if drifted(&self.drift[0], &self.closed.sums)
            || drifted(&self.drift[1], &self.closed.sums_of_squares)
        {
            self.rebuild();
        }
    }

    /// The closed totals afresh from the slices (every slice but the newest is closed: the ring
    /// holds no slice outside the window), their maxima's holders counted in the same pass.
    #[allow(
        clippy::needless_range_loop,
        reason = "one metric's entries in five arrays, indexed alike"
    )]
    fn rebuild(&mut self) {
        let newest_slot = self.newest.map_or(0, |(_, slot)| slot);
        let mut closed = Slice::default();
        let mut holders = [0; M];
        for (slot, slice) in self.ring.iter().enumerate() {
            if slot == newest_slot || slice.count == 0 {
                continue;
            }
            closed.count += slice.count;
            for m in 0..M {
                closed.sums[m] += slice.sums[m];
                closed.sums_of_squares[m] += slice.sums_of_squares[m];
                if slice.maxima[m] > closed.maxima[m] {
                    closed.maxima[m] = slice.maxima[m];
                    holders[m] = 1;
                } else if slice.maxima[m] >= closed.maxima[m] && slice.maxima[m] > 0.0 {
                    holders[m] += 1;
                }
            }
        }
        self.closed = closed;
        self.holders = holders;
        self.drift = [[0.0; M]; 2];
        self.closes_since_rebuild = 0;
    }

    fn clear_closed(&mut self) {
        self.closed = Slice::default();
        self.holders = [0; M];
        self.drift = [[0.0; M]; 2];
        self.closes_since_rebuild = 0;
    }
}

impl SlicedWindow<METRIC_COUNT> {
    /// The statistics of the samples now in the window.
    #[must_use]
    pub fn readout(&self) -> StatsSet {
        let totals = self.totals();
        StatsSet::from_sums(totals.n, totals.sums, totals.sums_of_squares, totals.maxima)
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "exact results are expected where tested")]
mod tests {
    use super::*;
    use crate::metrics::uniform;

    #[test]
    fn window_boundary_is_exclusive_of_exactly_window_s_ago() {
        let mut window = WindowStats::new(1.0, 100);
        assert!(window.add(0.0, &uniform(5.0)));
        assert!(window.add(0.5, &uniform(1.0)));
        assert!(window.add(0.75, &uniform(2.0)));
        assert_eq!(window.len(), 3);
        // 1.0 − 1.0 = 0.0: the sample stamped 0.0 is exactly window_s old and leaves.
        assert!(window.add(1.0, &uniform(3.0)));
        assert_eq!(window.len(), 3);
        let readout = window.readout();
        assert_eq!(readout.n, 3);
        assert_eq!(readout.stats[0].mae, 2.0);
        assert_eq!(readout.stats[0].max, 3.0);
        assert_eq!(readout.stats[0].rmse, (14.0_f64 / 3.0).sqrt());
        // A gap longer than the window leaves only the new sample.
        assert!(window.add(10.0, &uniform(0.25)));
        assert_eq!(window.len(), 1);
        assert_eq!(window.readout().stats[8].max, 0.25);
        assert_eq!(window.readout().stats[8].mae, 0.25);
    }

    #[test]
    fn the_edge_moves_in_slice_steps() {
        // Slices of 0.25 s: at 1.3 s the window is slices 2..=5, [0.5, 1.5).
        let mut window = WindowStats::new(1.0, 4);
        assert!(window.add(0.3, &uniform(1.0)));
        assert!(window.add(0.49, &uniform(2.0)));
        assert!(window.add(0.5, &uniform(4.0)));
        window.advance_to(1.3);
        assert_eq!(window.newest_slice(), Some(5));
        // 0.3 and 0.49 are less than window_s old, but their slice has left.
        assert_eq!(window.len(), 1);
        assert_eq!(window.readout().stats[0].max, 4.0);
        // Later times in the same slice change nothing; the next slice takes 0.5 out.
        window.advance_to(1.49);
        assert_eq!(window.len(), 1);
        window.advance_to(1.5);
        assert!(window.is_empty());
        assert_eq!(window.readout(), StatsSet::default());
    }

    #[test]
    fn max_follows_evictions_with_ties() {
        let mut window = WindowStats::new(2.5, 100);
        let values = [4.0, 4.0, 1.0, 3.0, 3.0, 0.5, 0.5, 0.5];
        let expected_max = [4.0, 4.0, 4.0, 4.0, 3.0, 3.0, 3.0, 0.5];
        for (i, (&x, &max)) in values.iter().zip(&expected_max).enumerate() {
            assert!(window.add(i as f64, &uniform(x)));
            assert_eq!(window.readout().stats[5].max, max, "after sample {i}");
        }
    }

    #[test]
    fn a_late_sample_goes_to_its_own_slice() {
        let mut window = WindowStats::new(1.0, 10);
        assert!(window.add(5.0, &uniform(1.0)));
        assert!(window.add(5.55, &uniform(1.0)));
        // Late, but inside the window (slice 46 of 46..=55): counted, and it leaves with its slice.
        assert!(window.add(4.65, &uniform(7.0)));
        assert_eq!(window.len(), 3);
        assert_eq!(window.readout().stats[0].max, 7.0);
        assert_eq!(window.readout().stats[0].mae, 3.0);
        // Too late: slice 45 has left.
        assert!(!window.add(4.55, &uniform(9.0)));
        assert_eq!(window.len(), 3);
        window.advance_to(5.65);
        assert_eq!(window.len(), 2);
        assert_eq!(window.readout().stats[0].max, 1.0);
        window.advance_to(6.0);
        assert_eq!(window.len(), 1);
    }

    #[test]
    fn ties_for_the_maximum_are_counted_once_per_slice() {
        // Slices of 10 ms, one sample each. The late samples below come after the rebuild of the
        // ring's third turn (at slice 200) and before their slices leave (250, 251), so that
        // only the count kept since then decides when the maximum is recomputed.
        let mut window = WindowStats::new(1.0, 100);
        let at = |slice: i32| f64::from(slice) * 0.01 + 0.005;
        for slice in 0..150 {
            assert!(window.add(at(slice), &uniform(0.5)));
        }
        assert!(window.add(at(150), &uniform(5.0)));
        assert!(window.add(at(151), &uniform(1.0)));
        for slice in 152..241 {
            assert!(window.add(at(slice), &uniform(2.0)));
        }
        // Late into slice 150, tying the maximum its slice already holds; late into slice 151,
        // a second slice holding it.
        assert!(window.add(at(150) + 0.001, &uniform(5.0)));
        assert!(window.add(at(151) + 0.001, &uniform(5.0)));
        window.advance_to(at(250));
        assert_eq!(
            window.readout().stats[0].max,
            5.0,
            "slice 151 still holds it"
        );
        window.advance_to(at(251));
        assert_eq!(window.readout().stats[0].max, 2.0);
    }

    #[test]
    fn a_large_value_that_left_leaves_no_residue() {
        // Slices of 1/128 s, one sample each (stamps and slice bounds exact in binary); the large
        // value enters mid-ring, so it leaves between two of the rebuilds each turn makes.
        let mut window = WindowStats::new(1.0, 128);
        for i in 0..500 {
            let value = if i == 50 { 1e90 } else { 1e-9 };
            assert!(window.add(f64::from(i) / 128.0, &uniform(value)));
            // Once the large value has left, the small ones are all there is.
            if i >= 50 + 128 {
                let readout = window.readout();
                assert_eq!(readout.n, 128);
                assert!(
                    (readout.stats[0].mae - 1e-9).abs() <= 1e-21,
                    "{i}: {readout:?}"
                );
                assert!(
                    (readout.stats[0].rmse - 1e-9).abs() <= 1e-21,
                    "{i}: {readout:?}"
                );
                assert_eq!(readout.stats[0].max, 1e-9);
            }
        }
    }

    #[test]
    fn reset_forgets_samples_and_newest_time() {
        let mut window = WindowStats::new(1.0, 100);
        assert!(window.add(100.0, &uniform(2.0)));
        window.reset();
        assert!(window.is_empty());
        assert_eq!(window.newest_slice(), None);
        assert_eq!(window.readout(), StatsSet::default());
        assert!(window.add(0.0, &uniform(1.0)));
        assert!(window.add(0.5, &uniform(1.0)));
        assert_eq!(window.len(), 2);
        assert_eq!(window.window_s(), 1.0);
        assert_eq!(window.slices(), 100);
    }

    #[test]
    fn stamps_at_the_ends_of_source_time_do_not_overflow() {
        let mut window = SlicedWindow::<1>::new(1.0, 3);
        assert!(window.add(-1e300, &[1.0]));
        assert!(window.add(1e300, &[2.0]));
        assert_eq!(window.len(), 1);
        assert!(!window.add(-1e300, &[1.0]));
        assert!(window.add(1e300, &[4.0]));
        assert_eq!(window.totals().sums, [6.0]);
    }

    #[test]
    #[should_panic(expected = "window_s must be positive")]
    fn zero_window_is_refused() {
        let _ = WindowStats::new(0.0, 10);
    }

    #[test]
    #[should_panic(expected = "at least one slice")]
    fn a_window_of_no_slices_is_refused() {
        let _ = WindowStats::new(1.0, 0);
    }
}
