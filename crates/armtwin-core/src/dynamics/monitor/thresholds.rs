//! Collision thresholds learnt from the arm's own normal motion: per joint, the distribution of
//! the detector's output while nothing touches the arm, kept in a fixed log-spaced histogram
//! over a learning period, then `factor ×` its 99.9th percentile, never below the rated-torque
//! share (the floor). Until learnt, the floor doubled: wide enough for a real drive's normal
//! residual, still catching a hard impact.
//!
//! Owns the histogram and the thresholds in force. Must not decide what counts as normal motion:
//! the observer hands in only armed, program-mode samples with no alarm on.

/// Histogram bins per joint, log-spaced over [`LOWEST_NM`, `LOWEST_NM · 10^DECADES`).
const BINS: usize = 100;
const LOWEST_NM: f64 = 0.01;
const DECADES: f64 = 5.0;
/// The quantile of normal motion the thresholds are drawn from.
const QUANTILE: f64 = 0.999;
/// While learning, the floor times this.
const LEARNING_FLOOR_FACTOR: f64 = 2.0;

/// Where a joint's collision threshold comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ThresholdSource {
    /// Set in the configuration.
    Configured,
    /// The rated-torque share: learning is off.
    Rated,
    /// Twice the rated-torque share while the arm's normal motion is being learnt.
    Learning,
    /// Learnt from the arm's normal motion.
    Learned,
}

impl ThresholdSource {
    /// The wire name.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Configured => "configured",
            Self::Rated => "rated",
            Self::Learning => "learning",
            Self::Learned => "learned",
        }
    }
}

/// The thresholds in force and, while learning, what is being learnt from.
#[derive(Debug, Clone)]
pub(super) struct Thresholds<const N: usize> {
    pub(super) nm: [f64; N],
    pub(super) source: ThresholdSource,
    floor_nm: [f64; N],
    factor: f64,
    learning_s: f64,
    learned_s: f64,
    /// Counts per joint and bin; dropped once learnt (allocated once, at the start).
    histogram: Option<Box<[[u32; BINS]; N]>>,
}

impl<const N: usize> Thresholds<N> {
    /// Fixed thresholds (configured, or the floor when `learning_s` is not positive), else the
    /// learning floor until `learning_s` of normal motion is in.
    pub(super) fn new(
        configured_nm: Option<[f64; N]>,
        floor_nm: [f64; N],
        factor: f64,
        learning_s: f64,
    ) -> Self {
        let (nm, source, histogram) = match configured_nm {
            Some(nm) => (nm, ThresholdSource::Configured, None),
            None if learning_s > 0.0 => (
                floor_nm.map(|f| f * LEARNING_FLOOR_FACTOR),
                ThresholdSource::Learning,
                Some(Box::new([[0; BINS]; N])),
            ),
            None => (floor_nm, ThresholdSource::Rated, None),
        };
        Self {
            nm,
            source,
            floor_nm,
            factor,
            learning_s,
            learned_s: 0.0,
            histogram,
        }
    }

    /// Takes one sample of normal motion `step_s` long: per joint the detector's output less its
    /// baseline (N·m). Learnt once `learning_s` is in.
    pub(super) fn learn(&mut self, step_s: f64, value_nm: &[f64; N]) {
        let Some(histogram) = &mut self.histogram else {
            return;
        };
        for (counts, value) in histogram.iter_mut().zip(value_nm) {
            counts[bin(value.abs())] += 1;
        }
        self.learned_s += step_s;
        if self.learned_s >= self.learning_s {
            self.nm = std::array::from_fn(|k| {
                (self.factor * quantile_nm(&histogram[k], QUANTILE)).max(self.floor_nm[k])
            });
            self.source = ThresholdSource::Learned;
            self.histogram = None;
        }
    }
}

#[allow(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    reason = "clamped to the bins first"
)]
fn bin(value_nm: f64) -> usize {
    let position = (value_nm / LOWEST_NM).log10() / DECADES * BINS as f64;
    if position.is_nan() || position < 0.0 {
        0
    } else {
        (position as usize).min(BINS - 1)
    }
}

/// The upper edge of the bin holding quantile `q` of the counts.
#[allow(
    clippy::cast_precision_loss,
    reason = "counts far below 2⁵³, bin indices tiny"
)]
fn quantile_nm(counts: &[u32; BINS], q: f64) -> f64 {
    let total: u64 = counts.iter().map(|c| u64::from(*c)).sum();
    let wanted = q * total as f64;
    let mut seen = 0_u64;
    for (index, count) in counts.iter().enumerate() {
        seen += u64::from(*count);
        if seen as f64 >= wanted {
            return LOWEST_NM * 10_f64.powf(DECADES * (index + 1) as f64 / BINS as f64);
        }
    }
    LOWEST_NM * 10_f64.powf(DECADES)
}

#[cfg(test)]
#[allow(
    clippy::float_cmp,
    reason = "thresholds are copied, not computed, where compared exactly"
)]
mod tests {
    use super::*;

    const N: usize = 6;

    #[test]
    fn learnt_thresholds_are_the_factor_times_the_quantile_above_the_floor() {
        let floor = [1.0, 1.0, 1.0, 0.1, 0.1, 0.1];
        let mut thresholds = Thresholds::new(None, floor, 2.0, 10.0);
        assert_eq!(thresholds.source, ThresholdSource::Learning);
        assert_eq!(thresholds.nm, floor.map(|f| f * 2.0));
        // 1 001 samples of 0.01 s (the last completes 10 s despite rounding): joint k's values spread evenly over [0, (k + 1)·0.3) N·m.
        for i in 0..=1000 {
            let fraction = f64::from(i) / 1000.0;
            let values: [f64; N] = std::array::from_fn(|k| {
                #[allow(clippy::cast_precision_loss, reason = "a joint index")]
                let top = (k + 1) as f64 * 0.3;
                fraction * top
            });
            thresholds.learn(0.01, &values);
        }
        assert_eq!(thresholds.source, ThresholdSource::Learned);
        for (k, threshold) in thresholds.nm.iter().enumerate() {
            #[allow(clippy::cast_precision_loss, reason = "a joint index")]
            let learnt = 2.0 * (k + 1) as f64 * 0.3;
            let expected = learnt.max(floor[k]);
            // One bin is 12 % wide.
            assert!(
                (*threshold / expected - 1.0).abs() < 0.13,
                "{k}: {threshold} vs {expected}"
            );
        }
        assert!(thresholds.histogram.is_none());
    }

    #[test]
    fn configured_thresholds_are_not_learnt_over() {
        let mut thresholds = Thresholds::new(Some([3.0; N]), [1.0; N], 2.0, 1.0);
        thresholds.learn(2.0, &[50.0; N]);
        assert_eq!(thresholds.nm, [3.0; N]);
        assert_eq!(thresholds.source, ThresholdSource::Configured);
        let rated = Thresholds::new(None, [1.0; N], 2.0, 0.0);
        assert_eq!((rated.nm, rated.source), ([1.0; N], ThresholdSource::Rated));
    }
}
