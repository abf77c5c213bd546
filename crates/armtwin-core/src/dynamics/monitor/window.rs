//! The residual statistics: cumulative since the start (or a reset), and over the last
//! `window_s` in the core's sliced window of the residual magnitudes, whose edge moves in steps
//! of an eighth of the window.

use super::{JointValues, Monitor, ResidualStats};

/// Slices the residual window is kept in: its edge moves in steps of an eighth of the window.
pub(super) const WINDOW_SLICES: usize = 8;

/// Residual statistics since the start or the last reset.
#[derive(Debug, Clone, Copy)]
pub(super) struct Block<const N: usize> {
    pub(super) n: u64,
    pub(super) sum_squares: [f64; N],
    pub(super) max_nm: [f64; N],
}

impl<const N: usize> Default for Block<N> {
    fn default() -> Self {
        Self {
            n: 0,
            sum_squares: [0.0; N],
            max_nm: [0.0; N],
        }
    }
}

impl<const N: usize> Block<N> {
    pub(super) fn add(&mut self, residual_nm: &[f64; N]) {
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
pub(super) fn residual_stats<const N: usize>(
    n: u64,
    sum_squares: &[f64; N],
    max_nm: [f64; N],
) -> ResidualStats {
    let count = n.max(1) as f64;
    ResidualStats {
        n,
        rms_nm: JointValues::from_array(sum_squares.map(|sum| (sum / count).sqrt())),
        max_nm: JointValues::from_array(max_nm),
    }
}

impl<const N: usize> Monitor<N> {
    pub(super) fn add_residual(&mut self, stamp_s: f64, residual_nm: &[f64; N]) {
        self.cumulative.add(residual_nm);
        self.window.add(stamp_s, &residual_nm.map(f64::abs));
    }
}
