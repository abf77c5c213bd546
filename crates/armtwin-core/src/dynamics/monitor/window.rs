//! The residual statistics: cumulative since the start (or a reset), and over a sliding window
//! kept in a few blocks, so that the window's statistics cover it to one block without keeping
//! every sample.

use super::{EffortMonitor, J, ResidualStats};

/// Blocks the residual window is kept in: its statistics cover the window to one block.
pub(super) const WINDOW_BLOCKS: usize = 8;

/// One block of the residual window.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Block {
    pub(super) start_s: f64,
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

    pub(super) fn merge(&mut self, other: &Self) {
        self.n += other.n;
        for k in 0..J {
            self.sum_squares[k] += other.sum_squares[k];
            self.max_nm[k] = self.max_nm[k].max(other.max_nm[k]);
        }
    }

    #[allow(
        clippy::cast_precision_loss,
        reason = "counts below 2⁵³ are exact in f64"
    )]
    pub(super) fn stats(&self) -> ResidualStats {
        let n = self.n.max(1) as f64;
        ResidualStats {
            n: self.n,
            rms_nm: std::array::from_fn(|k| (self.sum_squares[k] / n).sqrt()),
            max_nm: self.max_nm,
        }
    }
}

impl EffortMonitor {
    pub(super) fn add_residual(&mut self, stamp_s: f64, residual_nm: &[f64; J]) {
        self.cumulative.add(residual_nm);
        #[allow(clippy::cast_precision_loss, reason = "a handful of blocks")]
        let block_s = self.window_s / WINDOW_BLOCKS as f64;
        let newest = self
            .window
            .iter()
            .enumerate()
            .filter(|(_, block)| block.n > 0)
            .max_by(|a, b| a.1.start_s.total_cmp(&b.1.start_s))
            .map(|(index, block)| (index, block.start_s));
        let index = match newest {
            Some((index, start_s)) if stamp_s < start_s + block_s && stamp_s >= start_s => index,
            Some((index, _)) => {
                let next = (index + 1) % WINDOW_BLOCKS;
                self.window[next] = Block {
                    start_s: stamp_s,
                    ..Block::default()
                };
                next
            }
            None => {
                self.window[0] = Block {
                    start_s: stamp_s,
                    ..Block::default()
                };
                0
            }
        };
        self.window[index].add(residual_nm);
    }
}
