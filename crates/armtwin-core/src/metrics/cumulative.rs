//! Error statistics over every sample since the start or the last reset, in compensated sums, and
//! their plain-data form for a caller that keeps them across restarts.

use super::{MAGNITUDE_LIMIT, METRIC_COUNT, StatsSet, acceptable};

/// A running sum with Neumaier's compensation: the error stays at a few units in the last place of
/// the result, independent of the number of terms (for terms of one sign).
#[derive(Debug, Clone, Copy, Default)]
struct CompensatedSum {
    sum: f64,
    compensation: f64,
}

impl CompensatedSum {
    fn add(&mut self, x: f64) {
        let t = self.sum + x;
        // The rounding error of `sum + x`, recovered exactly from whichever operand is larger.
        self.compensation += if self.sum.abs() >= x.abs() {
            (self.sum - t) + x
        } else {
            (x - t) + self.sum
        };
        self.sum = t;
    }

    fn value(self) -> f64 {
        self.sum + self.compensation
    }
}

/// Error statistics over every sample since construction or the last [`reset`](Self::reset).
///
/// O(1) time and memory per sample. Sums use Neumaier compensated summation, whose error does not
/// grow with the number of (same-sign) terms: after 10⁷ samples the mean and RMS still agree with
/// an exactly rounded computation to a few units in the last place.
#[derive(Debug, Clone)]
pub struct CumulativeStats {
    n: u64,
    sums: [CompensatedSum; METRIC_COUNT],
    sums_of_squares: [CompensatedSum; METRIC_COUNT],
    maxima: [f64; METRIC_COUNT],
}

impl Default for CumulativeStats {
    fn default() -> Self {
        Self::new()
    }
}

impl CumulativeStats {
    /// Empty statistics.
    #[must_use]
    pub fn new() -> Self {
        Self {
            n: 0,
            sums: [CompensatedSum::default(); METRIC_COUNT],
            sums_of_squares: [CompensatedSum::default(); METRIC_COUNT],
            maxima: [f64::NEG_INFINITY; METRIC_COUNT],
        }
    }

    /// Adds one sample's magnitudes ([`Deviation::magnitudes`]).
    ///
    /// Returns `false`, leaving the statistics unchanged, when a value is negative, not finite or
    /// above 1e100 (garbage in any unit); callers normally reject such samples earlier.
    pub fn add(&mut self, magnitudes: &[f64; METRIC_COUNT]) -> bool {
        if !acceptable(magnitudes) {
            return false;
        }
        self.n += 1;
        for (m, &x) in magnitudes.iter().enumerate() {
            self.sums[m].add(x);
            self.sums_of_squares[m].add(x * x);
            self.maxima[m] = self.maxima[m].max(x);
        }
        true
    }

    /// The statistics of every sample added so far.
    #[must_use]
    pub fn readout(&self) -> StatsSet {
        StatsSet::from_sums(
            self.n,
            self.sums.map(CompensatedSum::value),
            self.sums_of_squares.map(CompensatedSum::value),
            self.maxima,
        )
    }

    /// Forgets every sample.
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// The running sums as plain data, for a caller that keeps them across restarts
    /// ([`from_parts`](Self::from_parts) gives the same statistics back, bit for bit).
    #[must_use]
    pub fn to_parts(&self) -> CumulativeParts {
        let pairs = |sums: &[CompensatedSum; METRIC_COUNT]| sums.map(|s| [s.sum, s.compensation]);
        CumulativeParts {
            n: self.n,
            sums: pairs(&self.sums),
            sums_of_squares: pairs(&self.sums_of_squares),
            maxima: self.maxima,
        }
    }

    /// Statistics that continue from `parts`; `None` when they cannot be the sums of any
    /// samples (a value not finite, a negative sum of squares, maxima of an empty set), so
    /// that a damaged record is refused rather than continued.
    #[must_use]
    pub fn from_parts(parts: &CumulativeParts) -> Option<Self> {
        if parts.n == 0 {
            return Some(Self::new());
        }
        let finite =
            |pairs: &[[f64; 2]; METRIC_COUNT]| pairs.iter().flatten().all(|x| x.is_finite());
        let squares_ok = parts
            .sums_of_squares
            .iter()
            .all(|[sum, compensation]| sum + compensation >= 0.0);
        let maxima_ok = parts
            .maxima
            .iter()
            .all(|x| x.is_finite() && x.abs() <= MAGNITUDE_LIMIT);
        if !(finite(&parts.sums) && finite(&parts.sums_of_squares) && squares_ok && maxima_ok) {
            return None;
        }
        let sums = |pairs: &[[f64; 2]; METRIC_COUNT]| {
            pairs.map(|[sum, compensation]| CompensatedSum { sum, compensation })
        };
        Some(Self {
            n: parts.n,
            sums: sums(&parts.sums),
            sums_of_squares: sums(&parts.sums_of_squares),
            maxima: parts.maxima,
        })
    }
}

/// [`CumulativeStats`] as plain data: sample count, per metric (in [`METRIC_NAMES`] order) the
/// compensated sums of magnitudes and of their squares as `[sum, compensation]`, and maxima.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CumulativeParts {
    /// Samples added.
    pub n: u64,
    /// Sums of the magnitudes, `[sum, compensation]`.
    pub sums: [[f64; 2]; METRIC_COUNT],
    /// Sums of the squared magnitudes, `[sum, compensation]`.
    pub sums_of_squares: [[f64; 2]; METRIC_COUNT],
    /// Largest magnitudes (`-inf` while `n` is 0).
    pub maxima: [f64; METRIC_COUNT],
}
