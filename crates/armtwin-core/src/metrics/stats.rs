//! Error statistics of a set of samples, as every statistic reports them: per metric the mean
//! absolute error, the root mean square error and the maximum, from sums, sums of squares and
//! maxima.

use super::{METRIC_COUNT, Metric};

/// Error statistics of one metric over a set of samples, in the metric's unit.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Stats {
    /// Mean absolute error: the mean of the magnitudes.
    pub mae: f64,
    /// Root mean square error: the square root of the mean of the squared magnitudes.
    pub rmse: f64,
    /// The largest magnitude.
    pub max: f64,
}

/// Statistics of every metric over one set of samples.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StatsSet {
    /// Number of samples; when 0 every statistic is 0.0 (never NaN).
    pub n: u64,
    /// One entry per metric, in [`METRIC_NAMES`] order.
    pub stats: [Stats; METRIC_COUNT],
}

impl StatsSet {
    /// The statistics of `metric`.
    #[must_use]
    pub fn of(&self, metric: Metric) -> &Stats {
        &self.stats[metric.index()]
    }

    /// Statistics from per-metric sums, sums of squares and maxima of `n` samples.
    pub(super) fn from_sums(
        n: u64,
        sums: [f64; METRIC_COUNT],
        sums_of_squares: [f64; METRIC_COUNT],
        maxima: [f64; METRIC_COUNT],
    ) -> Self {
        Self {
            n,
            stats: stats_from_sums(n, &sums, &sums_of_squares, &maxima),
        }
    }
}

/// Per metric, the statistics of `n` samples from their sums, sums of squares and maxima; all 0
/// when `n` is 0.
pub(super) fn stats_from_sums<const M: usize>(
    n: u64,
    sums: &[f64; M],
    sums_of_squares: &[f64; M],
    maxima: &[f64; M],
) -> [Stats; M] {
    if n == 0 {
        return [Stats::default(); M];
    }
    let count = n as f64;
    std::array::from_fn(|m| Stats {
        mae: sums[m] / count,
        rmse: (sums_of_squares[m] / count).sqrt(),
        max: maxima[m],
    })
}
