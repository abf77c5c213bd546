//! The residual statistics: cumulative since the start (or a reset), and over the last
//! `window_s` in the core's sliced window of the residual magnitudes, whose edge moves in steps
//! of an eighth of the window.

use super::{EffortMonitor, J, ResidualStats};

/// Slices the residual window is kept in: its edge moves in steps of an eighth of the window.
pub(super) const WINDOW_SLICES: usize = 8;

/// Residual statistics since the start or the last reset.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Block {
    pub(super) n: u64,
    pub(super) sum_squares: [f64; J],
    pub(super) max_nm: [f64; J],
}

impl Block {
    pub(super) fn add(&mut self, residual_nm: &[f64; J]) {
        self.n += 1;
        for ((sum, max), residual) in self
            .sum_squares
            .iter_mut()
            .zip(&mut self.max_nm)
            .zip(residual_nm)
        {
            *sum += residual * residual;
            *max = max.max(residual.abs());
        }
    }

    pub(super) fn stats(&self) -> ResidualStats {
        residual_stats(self.n, &self.sum_squares, self.max_nm)
    }
}

/// RMS and maximum of `n` residuals from their sums of squares and maxima (0 when `n` is 0).
#[allow(
    clippy::cast_precision_loss,
    reason = "counts below 2⁵³ are exact in f64"
)]
pub(super) fn residual_stats(n: u64, sum_squares: &[f64; J], max_nm: [f64; J]) -> ResidualStats {
    let count = n.max(1) as f64;
    ResidualStats {
        n,
        rms_nm: std::array::from_fn(|k| (sum_squares[k] / count).sqrt()),
        max_nm,
    }
}

impl EffortMonitor {
    pub(super) fn add_residual(&mut self, stamp_s: f64, residual_nm: &[f64; J]) {
        self.cumulative.add(residual_nm);
        self.window.add(stamp_s, &residual_nm.map(f64::abs));
    }
}
