//! Twin-vs-robot deviation of one paired sample, and running error statistics over many:
//! cumulative (since start or reset) and over a sliding window of source time kept in time slices.
//!
//! Owns: [`Deviation`] (twin minus measured, per axis and per orientation measure), the nine
//! metric magnitudes in [`METRIC_NAMES`] order, and the streaming statistics over them (mean
//! absolute error, root mean square error, maximum) in [`CumulativeStats`] and [`WindowStats`]
//! (the nine-metric [`SlicedWindow`], which the effort monitor's residual window is too).
//! Must not do I/O, read clocks, log, or know about wire formats: time is the samples' own source
//! time, passed in by the caller, and formatting belongs to the codecs.
//!
//! Files: `deviation` (one pair's deviation), `stats` (statistics of a set of samples), `cumulative`
//! (since start, compensated sums), `window` (the sliced window), `history` (the window's
//! per-second totals over the last hour).

mod cumulative;
mod deviation;
mod history;
mod stats;
mod window;

pub use cumulative::{CumulativeParts, CumulativeStats};
pub use deviation::Deviation;
pub use history::{
    DEFAULT_HISTORY_S, HISTORY_METRICS, History, HistoryRow, MINUTE_S, MemorySeconds,
    MinuteOfSeconds, MinutesError, SECONDS_TIER_S, SecondTotals, SecondsArchive, WindowWithHistory,
    ring_slot, stats_of,
};
pub use stats::{Stats, StatsSet};
pub use window::{DEFAULT_WINDOW_SLICES, SlicedWindow, WindowStats, WindowTotals};

/// Number of metrics tracked per sample.
pub const METRIC_COUNT: usize = 9;

/// Metric names, in the order of [`Deviation::magnitudes`] and [`StatsSet::stats`]: position error
/// (m), the absolute x, y, z errors (m), quaternion distance (in [0, 1]), rotation angle (rad), and
/// the absolute wrapped roll, pitch, yaw differences (rad).
pub const METRIC_NAMES: [&str; METRIC_COUNT] = [
    "position",
    "x",
    "y",
    "z",
    "quat_distance",
    "angle",
    "roll",
    "pitch",
    "yaw",
];

/// One of the nine metrics, by name: its position in [`METRIC_NAMES`], [`Deviation::magnitudes`]
/// and [`StatsSet::stats`] is [`Metric::index`], so no caller counts positions by hand.
///
/// ```
/// use armtwin_core::metrics::{Metric, METRIC_NAMES};
/// assert_eq!(Metric::from_name("angle"), Some(Metric::Angle));
/// assert_eq!(Metric::from_name("angel"), None);
/// assert_eq!(METRIC_NAMES[Metric::Angle.index()], Metric::Angle.as_str());
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Metric {
    /// Position error (m).
    Position,
    /// Absolute x error (m).
    X,
    /// Absolute y error (m).
    Y,
    /// Absolute z error (m).
    Z,
    /// Quaternion distance, in [0, 1].
    QuatDistance,
    /// Rotation angle between the two orientations (rad).
    Angle,
    /// Absolute wrapped roll difference (rad).
    Roll,
    /// Absolute wrapped pitch difference (rad).
    Pitch,
    /// Absolute wrapped yaw difference (rad).
    Yaw,
}

impl Metric {
    /// Every metric, in [`METRIC_NAMES`] order.
    pub const ALL: [Self; METRIC_COUNT] = [
        Self::Position,
        Self::X,
        Self::Y,
        Self::Z,
        Self::QuatDistance,
        Self::Angle,
        Self::Roll,
        Self::Pitch,
        Self::Yaw,
    ];

    /// The metric called `name` (as in [`METRIC_NAMES`]); `None` for a name that is none.
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|metric| metric.as_str() == name)
    }

    /// Its name, as the wire formats and reports write it.
    #[must_use]
    pub const fn as_str(self) -> &'static str {
        METRIC_NAMES[self.index()]
    }

    /// Its position in [`METRIC_NAMES`], [`Deviation::magnitudes`] and [`StatsSet::stats`].
    #[must_use]
    pub const fn index(self) -> usize {
        self as usize
    }
}

/// Statistics accept only magnitudes at most this large: far beyond any physical deviation in
/// metres or radians, and small enough that no sum of squares can overflow to infinity (which
/// would poison a sliding window for ever, since `∞ − ∞` is NaN).
const MAGNITUDE_LIMIT: f64 = 1e100;

/// Whether every value is a magnitude the statistics accept: not negative, finite, at most
/// [`MAGNITUDE_LIMIT`] (NaN fails both comparisons).
fn acceptable<const M: usize>(magnitudes: &[f64; M]) -> bool {
    magnitudes
        .iter()
        .all(|&x| (0.0..=MAGNITUDE_LIMIT).contains(&x))
}

/// A test's sample: the same magnitude for every metric.
#[cfg(test)]
fn uniform(x: f64) -> [f64; METRIC_COUNT] {
    [x; METRIC_COUNT]
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "exact results are expected where tested")]
mod tests {
    use super::*;

    #[test]
    fn every_metric_is_named_at_its_index() {
        for (index, metric) in Metric::ALL.into_iter().enumerate() {
            assert_eq!(metric.index(), index);
            assert_eq!(Metric::from_name(METRIC_NAMES[index]), Some(metric));
        }
        assert_eq!(Metric::from_name("Position"), None, "names are exact");
        let deviation = Deviation {
            dx_m: 0.0,
            dy_m: 0.0,
            dz_m: 0.0,
            position_m: 1.0,
            quat_distance: 0.0,
            angle_rad: 2.0,
            droll_rad: 0.0,
            dpitch_rad: 0.0,
            dyaw_rad: 0.0,
        };
        let magnitudes = deviation.magnitudes();
        assert_eq!(magnitudes[Metric::Position.index()], 1.0);
        assert_eq!(magnitudes[Metric::Angle.index()], 2.0);
    }

    #[test]
    fn empty_readouts_are_all_zero() {
        assert_eq!(CumulativeStats::new().readout(), StatsSet::default());
        assert_eq!(WindowStats::new(1.0, 10).readout(), StatsSet::default());
        let zero = StatsSet::default();
        assert_eq!(zero.n, 0);
        assert!(zero.stats.iter().all(|s| *s == Stats::default()));
    }

    #[test]
    fn cumulative_mae_rmse_max() {
        let mut stats = CumulativeStats::new();
        assert!(stats.add(&uniform(3.0)));
        assert!(stats.add(&uniform(4.0)));
        let readout = stats.readout();
        assert_eq!(readout.n, 2);
        for s in readout.stats {
            assert_eq!(s.mae, 3.5);
            assert_eq!(s.rmse, 12.5_f64.sqrt());
            assert_eq!(s.max, 4.0);
        }
        stats.reset();
        assert_eq!(stats.readout(), StatsSet::default());
        assert!(stats.add(&uniform(1.0)));
        assert_eq!(stats.readout().stats[0].max, 1.0);
    }

    #[test]
    fn garbage_samples_are_rejected() {
        let mut cumulative = CumulativeStats::new();
        let mut window = WindowStats::new(1.0, 10);
        let mut bad = uniform(1.0);
        for value in [f64::NAN, f64::INFINITY, -f64::INFINITY, 1e101, -1e-300] {
            bad[4] = value;
            assert!(!cumulative.add(&bad));
            assert!(!window.add(0.0, &bad));
        }
        assert!(!window.add(f64::NAN, &uniform(1.0)));
        assert!(!window.add(f64::INFINITY, &uniform(1.0)));
        assert_eq!(cumulative.readout().n, 0);
        assert!(window.is_empty());
    }
}
