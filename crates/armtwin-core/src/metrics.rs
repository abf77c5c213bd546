//! Twin-vs-robot deviation of one paired sample, and running error statistics over many:
//! cumulative (since start or reset) and over an exact sliding window of source time.
//!
//! Owns: [`Deviation`] (twin minus measured, per axis and per orientation measure), the nine
//! metric magnitudes in [`METRIC_NAMES`] order, and the streaming statistics over them (mean
//! absolute error, root mean square error, maximum) in [`CumulativeStats`] and [`WindowStats`].
//! Must not do I/O, read clocks, log, or know about wire formats: time is the samples' own source
//! time, passed in by the caller, and formatting belongs to the codecs.

use std::collections::VecDeque;

use crate::kinematics::PoseReadout;
use crate::orientation;

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
/// would poison a sliding window forever, since `∞ − ∞` is NaN).
const MAGNITUDE_LIMIT: f64 = 1e100;

/// Twin minus measured for one paired sample: both poses in the same frame, at the same time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Deviation {
    /// `x_twin − x_measured` (m).
    pub dx_m: f64,
    /// `y_twin − y_measured` (m).
    pub dy_m: f64,
    /// `z_twin − z_measured` (m).
    pub dz_m: f64,
    /// Euclidean distance between the two positions (m), ≥ 0.
    pub position_m: f64,
    /// Quaternion distance `1 − |⟨q_twin, q_measured⟩|`, in [0, 1]
    /// ([`orientation::quaternion_distance`]).
    pub quat_distance: f64,
    /// Angle of the rotation between the two orientations (rad), in [0, π]
    /// ([`orientation::rotation_angle_between`]).
    pub angle_rad: f64,
    /// `roll_twin − roll_measured` (rad), wrapped to (−π, π].
    pub droll_rad: f64,
    /// `pitch_twin − pitch_measured` (rad), wrapped to (−π, π].
    pub dpitch_rad: f64,
    /// `yaw_twin − yaw_measured` (rad), wrapped to (−π, π].
    pub dyaw_rad: f64,
}

impl Deviation {
    /// The deviation of the twin's pose from the measured one (`twin − measured`).
    ///
    /// ```
    /// use armtwin_core::kinematics::PoseReadout;
    /// use armtwin_core::metrics::Deviation;
    /// use nalgebra::{UnitQuaternion, Vector3};
    /// let twin = PoseReadout::from_position_quaternion([3.0, 4.0, 12.0], &UnitQuaternion::identity());
    /// let turned = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.5));
    /// let measured = PoseReadout::from_position_quaternion([0.0; 3], &turned);
    /// let d = Deviation::between(&twin, &measured);
    /// assert!((d.position_m - 13.0).abs() < 1e-12 && (d.angle_rad - 0.5).abs() < 1e-12);
    /// assert!((d.dyaw_rad + 0.5).abs() < 1e-12);
    /// ```
    #[must_use]
    pub fn between(twin: &PoseReadout, measured: &PoseReadout) -> Self {
        let [dx_m, dy_m, dz_m] =
            std::array::from_fn(|axis| twin.position_m[axis] - measured.position_m[axis]);
        let (twin_q, measured_q) = (twin.quaternion(), measured.quaternion());
        let rpy = orientation::rpy_difference(twin.rpy, measured.rpy);
        Self {
            dx_m,
            dy_m,
            dz_m,
            position_m: (dx_m * dx_m + dy_m * dy_m + dz_m * dz_m).sqrt(),
            quat_distance: orientation::quaternion_distance(&twin_q, &measured_q),
            angle_rad: orientation::rotation_angle_between(&twin_q, &measured_q),
            droll_rad: rpy.roll_rad,
            dpitch_rad: rpy.pitch_rad,
            dyaw_rad: rpy.yaw_rad,
        }
    }

    /// The nine non-negative error magnitudes, in [`METRIC_NAMES`] order: position, |dx|, |dy|,
    /// |dz|, quaternion distance, angle, |droll|, |dpitch|, |dyaw|.
    #[must_use]
    pub fn magnitudes(&self) -> [f64; METRIC_COUNT] {
        [
            self.position_m,
            self.dx_m.abs(),
            self.dy_m.abs(),
            self.dz_m.abs(),
            self.quat_distance,
            self.angle_rad,
            self.droll_rad.abs(),
            self.dpitch_rad.abs(),
            self.dyaw_rad.abs(),
        ]
    }
}

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
    fn from_sums(
        n: u64,
        sums: [f64; METRIC_COUNT],
        sums_of_squares: [f64; METRIC_COUNT],
        maxima: [f64; METRIC_COUNT],
    ) -> Self {
        if n == 0 {
            return Self::default();
        }
        let count = n as f64;
        Self {
            n,
            stats: std::array::from_fn(|m| Stats {
                mae: sums[m] / count,
                rmse: (sums_of_squares[m] / count).sqrt(),
                max: maxima[m],
            }),
        }
    }
}

/// Whether a sample's magnitudes can enter the statistics (see [`MAGNITUDE_LIMIT`]).
fn acceptable(magnitudes: &[f64; METRIC_COUNT]) -> bool {
    magnitudes.iter().all(|x| x.abs() <= MAGNITUDE_LIMIT)
}

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
    /// Returns `false`, leaving the statistics unchanged, when a value is not finite or exceeds
    /// 1e100 in magnitude (garbage in any unit); callers normally reject such samples earlier.
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

/// Bit weight of chunk 0 of an [`ExactSum`]: 2⁻¹⁰⁸⁸, the multiple of 32 just below the smallest
/// subnormal (2⁻¹⁰⁷⁴), so every double is an integer multiple of it.
const EXACT_SUM_LOWEST_EXPONENT: i32 = -1088;

/// Chunk positions an [`ExactSum`] may use: bits up to 2⁷⁰⁴, so every accepted value (at most
/// 1e200 < 2⁶⁶⁵) lands below the last one.
const EXACT_SUM_CHUNKS: usize = 57;

/// Chunks an [`ExactSum`] holds without allocating: enough for values within about 2³² of each
/// other (3 chunks for one value, one more for its neighbours), as a metric's deviations are.
const EXACT_SUM_INLINE_CHUNKS: usize = 4;

/// `ExactSum::low` of a sum that has never held a non-zero value.
const EXACT_SUM_UNUSED: u16 = u16::MAX;

/// Operations an [`ExactSum`] absorbs before it must propagate carries: each adds less than 2³² to
/// a chunk, so chunks stay far from `i64` overflow.
const EXACT_SUM_OPS_BETWEEN_CARRIES: u32 = 1 << 30;

/// An exact sum of doubles, with exact subtraction: a fixed-point "superaccumulator" over every
/// value the statistics accept (finite, at most 1e200, as are squares of at most 1e100), holding
/// only the chunks its values have reached.
///
/// The value is `Σ chunks[i] · 2^(32·(low + i) − 1088)`. Adding a double adds its 53-bit
/// significand, shifted into place, to three chunks: branch-free integer additions, no rounding at
/// all. Chunks are signed and carries are deferred, so subtraction is the same operation with the
/// sign flipped, and carries are propagated only every 2³⁰ operations and on reading. This keeps a
/// sliding window's sum exact for ever at a fixed cost per operation, unlike Shewchuk's partials
/// (`math.fsum`), whose count and cost grow with the spread of the values.
///
/// The chunks span `low..low + len` of the 57 positions a double can reach (2⁻¹⁰⁸⁸ to 2⁷⁰⁴), grown
/// when a value lands outside and never shrunk (a window's values come back to the same range);
/// a metric's values span a few dozen binary orders, so 4 chunks, held inline, usually suffice.
/// No headroom is needed above the highest chunk: the top chunk keeps the carries, and a sum of
/// fewer than 2³² values each below 2²⁰ top-chunk units stays below 2⁵² of them.
///
/// 40 bytes: the position and carry counter share the first word with the variant's tag.
#[derive(Debug, Clone)]
enum ExactSum {
    /// At most [`EXACT_SUM_INLINE_CHUNKS`] chunks, held inline.
    Inline {
        /// Position of `chunks[0]` among the 57, or [`EXACT_SUM_UNUSED`].
        low: u16,
        ops_since_carry: u32,
        chunks: [i64; EXACT_SUM_INLINE_CHUNKS],
    },
    /// More chunks, on the heap.
    Spilled {
        /// Position of `chunks[0]` among the 57.
        low: u16,
        ops_since_carry: u32,
        chunks: Box<[i64]>,
    },
}

impl Default for ExactSum {
    fn default() -> Self {
        Self::Inline {
            low: EXACT_SUM_UNUSED,
            ops_since_carry: 0,
            chunks: [0; EXACT_SUM_INLINE_CHUNKS],
        }
    }
}

impl ExactSum {
    fn low(&self) -> u16 {
        match self {
            Self::Inline { low, .. } | Self::Spilled { low, .. } => *low,
        }
    }

    fn chunks(&self) -> &[i64] {
        match self {
            Self::Inline { chunks, .. } => chunks,
            Self::Spilled { chunks, .. } => chunks,
        }
    }

    fn ops_since_carry(&self) -> u32 {
        match self {
            Self::Inline {
                ops_since_carry, ..
            }
            | Self::Spilled {
                ops_since_carry, ..
            } => *ops_since_carry,
        }
    }

    /// The position, the carry counter and the chunks, with one look at the variant.
    fn parts_mut(&mut self) -> (u16, &mut u32, &mut [i64]) {
        match self {
            Self::Inline {
                low,
                ops_since_carry,
                chunks,
            } => (*low, ops_since_carry, chunks),
            Self::Spilled {
                low,
                ops_since_carry,
                chunks,
            } => (*low, ops_since_carry, chunks),
        }
    }

    /// Adds `x`, which must be finite and at most 1e200 in magnitude (the callers' acceptance
    /// check guarantees it; anything larger would reach past the 57 chunk positions).
    fn add(&mut self, x: f64) {
        const LOW_32: u128 = 0xFFFF_FFFF;
        let bits = x.to_bits();
        let biased_exponent = ((bits >> 52) & 0x7FF) as usize;
        let fraction = bits & ((1 << 52) - 1);
        // |x| = significand · 2^(max(biased, 1) − 1075), the hidden bit only for normal numbers.
        let significand = if biased_exponent == 0 {
            fraction
        } else {
            fraction | (1 << 52)
        };
        if significand == 0 {
            // ±0.0 adds nothing, and must not pull the chunks down to position 0.
            return;
        }
        // Position of the significand's lowest bit above 2⁻¹⁰⁸⁸.
        let position = biased_exponent.max(1) + 13;
        let index = position / 32;
        let placed = u128::from(significand) << (position % 32);
        let sign = if x.is_sign_negative() { -1 } else { 1 };
        let parts = [
            sign * (placed & LOW_32) as i64,
            sign * ((placed >> 32) & LOW_32) as i64,
            sign * (placed >> 64) as i64,
        ];
        let (low, ops_since_carry, chunks) = self.parts_mut();
        // Wraps to a huge slot below `low` (and for an unused sum), so one bounds check covers
        // both ends.
        let slot = index.wrapping_sub(usize::from(low));
        let Some(target) = chunks
            .get_mut(slot..)
            .and_then(<[i64]>::first_chunk_mut::<3>)
        else {
            self.add_uncovered(index, parts);
            return;
        };
        for (chunk, part) in target.iter_mut().zip(parts) {
            *chunk += part;
        }
        *ops_since_carry += 1;
        if *ops_since_carry == EXACT_SUM_OPS_BETWEEN_CARRIES {
            propagate_carries(chunks);
            *ops_since_carry = 0;
        }
    }

    /// [`add`](Self::add)'s rare path, kept out of line so the common one stays small: grows the
    /// chunks to hold position `index` on, then adds `parts` there.
    #[cold]
    #[inline(never)]
    fn add_uncovered(&mut self, index: usize, parts: [i64; 3]) {
        self.cover(index);
        let (low, ops_since_carry, chunks) = self.parts_mut();
        let slot = index - usize::from(low);
        for (chunk, part) in chunks[slot..slot + 3].iter_mut().zip(parts) {
            *chunk += part;
        }
        *ops_since_carry += 1;
        if *ops_since_carry == EXACT_SUM_OPS_BETWEEN_CARRIES {
            propagate_carries(chunks);
            *ops_since_carry = 0;
        }
    }

    /// Grows the chunks to cover positions `index..index + 3` as well as those in use. Chunks keep
    /// their deferred carries: each moves by less than 2³² per operation wherever it sits.
    fn cover(&mut self, index: usize) {
        let (old_low, ops_since_carry, old) = (self.low(), self.ops_since_carry(), self.chunks());
        let (low, end) = if old_low == EXACT_SUM_UNUSED {
            (index, index + 3)
        } else {
            let old_low = usize::from(old_low);
            (old_low.min(index), (old_low + old.len()).max(index + 3))
        };
        // Positions are below 57.
        let position = low as u16;
        let mut grown = if end - low <= EXACT_SUM_INLINE_CHUNKS {
            Self::Inline {
                low: position,
                ops_since_carry,
                chunks: [0; EXACT_SUM_INLINE_CHUNKS],
            }
        } else {
            Self::Spilled {
                low: position,
                ops_since_carry,
                chunks: vec![0; end - low].into_boxed_slice(),
            }
        };
        if old_low != EXACT_SUM_UNUSED {
            let offset = usize::from(old_low) - low;
            grown.parts_mut().2[offset..offset + old.len()].copy_from_slice(old);
        }
        *self = grown;
    }

    /// The exact sum rounded to the nearest double, ties to even.
    fn value(&self) -> f64 {
        if self.low() == EXACT_SUM_UNUSED {
            return 0.0;
        }
        let stored = self.chunks();
        let mut buffer = [0; EXACT_SUM_CHUNKS + EXACT_SUM_INLINE_CHUNKS];
        let chunks = &mut buffer[..stored.len()];
        chunks.copy_from_slice(stored);
        propagate_carries(chunks);
        let negative = chunks[chunks.len() - 1] < 0;
        if negative {
            for chunk in chunks.iter_mut() {
                *chunk = -*chunk;
            }
            propagate_carries(chunks);
        }
        // Chunks are now digits in [0, 2³²) (the top one possibly larger) of the magnitude.
        let Some(top) = chunks.iter().rposition(|&chunk| chunk != 0) else {
            return 0.0;
        };
        let lowest = top.saturating_sub(2);
        let leading = chunks[lowest..=top]
            .iter()
            .rev()
            .fold(0u128, |acc, &chunk| {
                (acc << 32) | u128::from(chunk.unsigned_abs())
            });
        let below = chunks[..lowest].iter().any(|&chunk| chunk != 0);
        #[allow(clippy::cast_possible_wrap, reason = "chunk positions are below 61")]
        let exponent = EXACT_SUM_LOWEST_EXPONENT + 32 * (usize::from(self.low()) + lowest) as i32;
        let magnitude = round_to_f64(leading, below, exponent);
        if negative { -magnitude } else { magnitude }
    }

    fn clear(&mut self) {
        *self = Self::default();
    }
}

/// Moves each chunk's excess over [0, 2³²) into the next one; the top chunk keeps the sign.
fn propagate_carries(chunks: &mut [i64]) {
    let Some((top, rest)) = chunks.split_last_mut() else {
        return;
    };
    let mut carry = 0;
    for chunk in rest {
        let value = *chunk + carry;
        *chunk = value & 0xFFFF_FFFF;
        // Arithmetic shift: floor division, so negative values borrow from the next chunk.
        carry = value >> 32;
    }
    *top += carry;
}

/// `(leading + δ) · 2^exponent` rounded to the nearest double (ties to even), where `δ` is in
/// (0, 1) if `below` and 0 otherwise. `leading` is non-zero and, when `below`, has at least 65
/// significant bits (so `δ` can only break ties); the result is below 2¹⁰²⁴.
fn round_to_f64(leading: u128, below: bool, exponent: i32) -> f64 {
    let bit_length = 128 - leading.leading_zeros().cast_signed();
    let top_exponent = exponent + bit_length - 1;
    let normal = top_exponent >= -1022;
    // Bits to drop: down to 53 significant bits, or down to units of 2⁻¹⁰⁷⁴ for a subnormal.
    let drop = if normal {
        bit_length - 53
    } else {
        -1074 - exponent
    };
    let significand = if drop <= 0 {
        (leading << -drop) as u64
    } else {
        let kept = leading >> drop;
        let remainder = leading & ((1u128 << drop) - 1);
        let half = 1u128 << (drop - 1);
        let round_up = remainder > half || (remainder == half && (below || kept & 1 == 1));
        (kept + u128::from(round_up)) as u64
    };
    let bits = if normal {
        // Adding the significand with its hidden bit to (exponent − 1) sets the exponent field, and
        // a significand rounded up to 2⁵³ carries into the exponent by itself.
        (u64::from((top_exponent + 1023 - 1).cast_unsigned()) << 52) + significand
    } else {
        // Subnormal: the bits are the significand; 2⁵² rounds up into the smallest normal.
        significand
    };
    f64::from_bits(bits)
}

/// One stored sample of a [`WindowStats`].
#[derive(Debug, Clone, Copy)]
struct WindowSample {
    stamp_s: f64,
    magnitudes: [f64; METRIC_COUNT],
}

/// Error statistics over a sliding window of source time: the samples stamped within the last
/// `window_s` seconds before the newest stamp, capped at `max_samples` (the newest kept).
///
/// **Exact**: the mean and RMS are the exactly rounded sums of precisely the samples in the window,
/// divided by their count, with no drift however many samples have passed through; the maximum is
/// the window's true maximum.
///
/// **Design.** Add/subtract running sums, made exact: each sum and sum of squares is a fixed-point
/// superaccumulator (signed 32-bit-digit chunks on a grid spanning 2⁻¹⁰⁸⁸ to beyond 2⁷⁰⁰, so any
/// accepted double lands on it without rounding; only the chunks the values reach are held). Adding a sample adds its values, evicting one subtracts
/// the very same values (squares rounded identically), so the state is the exact sum of the window
/// however many samples have passed: nothing drifts and nothing needs periodic recomputation. A
/// readout rounds each exact sum once. Each maximum is a monotonic deque of the positions of the
/// samples larger than every later one, so its front is the window's maximum.
///
/// Chosen over the two-stack aggregation, which stores prefix sums, sums of squares and maxima with
/// every sample (216 more bytes per sample, and its floating prefix sums still round); over
/// floating add/subtract sums with periodic recomputation, which between recomputations carry the
/// rounding of values that have left (one large error that left swamps the small ones remaining);
/// and over Shewchuk's exact partials (`math.fsum`), whose number, and cost, grows with the spread
/// of the values.
///
/// **Cost.** Amortised O(1) per [`add`](Self::add): branch-free integer additions to three chunks
/// per sum, and each sample enters and leaves each maximum deque once (the deques' data-dependent
/// branches take most of an add's time). A [`readout`](Self::readout) rounds the 18 sums.
/// Timings: `benches/metrics.rs`, figures in BENCHMARKS.md.
/// Memory O(samples in the window): 80 bytes per sample (stamp and nine values) plus at most 36
/// bytes of maximum-deque positions (4 bytes per metric, only while the sample is larger than every
/// later one; a handful in all for noisy errors), so at most 116 bytes per sample. The ring buffers
/// grow by doubling (at most 2× that allocated) and are trimmed once a quarter full (at most 4×
/// after the window shrinks a lot). Fixed: 40 bytes for each of the 18 exact sums, holding 4
/// chunks inline (values within about 2³² of each other); a sum whose values spread wider holds
/// 8 bytes per 2³² of spread on the heap (at most 57 chunks, 456 bytes).
///
/// **Stamps** should arrive in non-decreasing order. A stamp that goes backwards does not panic:
/// the window is kept in insertion order and eviction runs from the oldest-inserted sample while it
/// is too old relative to the newest stamp seen so far. A source that restarts its clock should be
/// followed by [`reset`](Self::reset), or its new samples all count as old.
#[derive(Debug, Clone)]
pub struct WindowStats {
    window_s: f64,
    max_samples: usize,
    /// Stored samples, oldest first.
    samples: VecDeque<WindowSample>,
    /// Sequence number of `samples[0]`; samples are numbered from 0 in insertion order.
    front_sequence: u64,
    /// The largest stamp added since construction or reset.
    newest_stamp_s: f64,
    sums: [ExactSum; METRIC_COUNT],
    sums_of_squares: [ExactSum; METRIC_COUNT],
    /// Per metric, sequence numbers (mod 2³², unambiguous because the window holds fewer than 2³²
    /// samples) of the samples whose value exceeds every later one's, oldest first: values strictly
    /// decrease from front to back and the front is the maximum.
    maxima: [VecDeque<u32>; METRIC_COUNT],
}

impl WindowStats {
    /// Empty statistics over the last `window_s` seconds of source time, holding at most
    /// `max_samples` samples (at most `u32::MAX`; larger values are clamped). An infinite
    /// `window_s` gives a window of the last `max_samples` samples.
    ///
    /// # Panics
    ///
    /// If `window_s` is not positive (or NaN) or `max_samples` is zero: the configuration layer
    /// validates both.
    #[must_use]
    pub fn new(window_s: f64, max_samples: usize) -> Self {
        assert!(window_s > 0.0, "window_s must be positive, got {window_s}");
        assert!(max_samples > 0, "max_samples must be positive");
        Self {
            window_s,
            max_samples: max_samples.min(u32::MAX as usize),
            samples: VecDeque::new(),
            front_sequence: 0,
            newest_stamp_s: f64::NEG_INFINITY,
            sums: Default::default(),
            sums_of_squares: Default::default(),
            maxima: Default::default(),
        }
    }

    /// The window length (s) of source time.
    #[must_use]
    pub fn window_s(&self) -> f64 {
        self.window_s
    }

    /// The cap on the number of samples held.
    #[must_use]
    pub fn max_samples(&self) -> usize {
        self.max_samples
    }

    /// Number of samples in the window.
    #[must_use]
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether the window holds no sample.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Adds one sample stamped `stamp_s` (source time, s) and evicts the samples it makes too old:
    /// afterwards the window holds the samples stamped after `newest − window_s`, where `newest` is
    /// the largest stamp seen, at most `max_samples` of them, newest kept. The sample just added is
    /// always kept, even if rounding in `newest − window_s` would say otherwise.
    ///
    /// Returns `false`, leaving the window unchanged, when the stamp is not finite or a magnitude
    /// is not finite or exceeds 1e100 (garbage in any unit); callers normally reject such samples
    /// earlier.
    pub fn add(&mut self, stamp_s: f64, magnitudes: &[f64; METRIC_COUNT]) -> bool {
        if !stamp_s.is_finite() || !acceptable(magnitudes) {
            return false;
        }
        let sequence = self.front_sequence + self.samples.len() as u64;
        for (m, &x) in magnitudes.iter().enumerate() {
            self.sums[m].add(x);
            self.sums_of_squares[m].add(x * x);
            let deque = &mut self.maxima[m];
            while let Some(&back) = deque.back() {
                if self.samples[offset(back, self.front_sequence)].magnitudes[m] > x {
                    break;
                }
                deque.pop_back();
            }
            deque.push_back(sequence as u32);
        }
        self.samples.push_back(WindowSample {
            stamp_s,
            magnitudes: *magnitudes,
        });
        self.newest_stamp_s = self.newest_stamp_s.max(stamp_s);

        let oldest_kept_after_s = self.newest_stamp_s - self.window_s;
        while self.samples.len() > self.max_samples
            || (self.samples.len() > 1 && self.samples[0].stamp_s <= oldest_kept_after_s)
        {
            self.evict_front();
        }
        trim_capacity(&mut self.samples);
        for deque in &mut self.maxima {
            trim_capacity(deque);
        }
        true
    }

    /// Moves the window's end to source time `now_s` without adding a sample: samples stamped at
    /// or before `now_s − window_s` leave (so a window whose inputs stopped empties as time goes
    /// on). Times earlier than the newest stamp seen change nothing.
    pub fn advance_to(&mut self, now_s: f64) {
        if !now_s.is_finite() || now_s <= self.newest_stamp_s {
            return;
        }
        self.newest_stamp_s = now_s;
        let oldest_kept_after_s = now_s - self.window_s;
        while self
            .samples
            .front()
            .is_some_and(|oldest| oldest.stamp_s <= oldest_kept_after_s)
        {
            self.evict_front();
        }
        trim_capacity(&mut self.samples);
        for deque in &mut self.maxima {
            trim_capacity(deque);
        }
    }

    /// The statistics of the samples now in the window.
    #[must_use]
    pub fn readout(&self) -> StatsSet {
        StatsSet::from_sums(
            self.samples.len() as u64,
            std::array::from_fn(|m| self.sums[m].value()),
            std::array::from_fn(|m| self.sums_of_squares[m].value()),
            std::array::from_fn(|m| {
                self.maxima[m].front().map_or(0.0, |&front| {
                    self.samples[offset(front, self.front_sequence)].magnitudes[m]
                })
            }),
        )
    }

    /// Forgets every sample and the newest stamp seen, keeping the window length and cap.
    pub fn reset(&mut self) {
        self.samples.clear();
        self.front_sequence = 0;
        self.newest_stamp_s = f64::NEG_INFINITY;
        for m in 0..METRIC_COUNT {
            self.sums[m].clear();
            self.sums_of_squares[m].clear();
            self.maxima[m].clear();
        }
    }

    fn evict_front(&mut self) {
        let Some(oldest) = self.samples.pop_front() else {
            return;
        };
        let sequence = self.front_sequence as u32;
        self.front_sequence += 1;
        for (m, &x) in oldest.magnitudes.iter().enumerate() {
            self.sums[m].add(-x);
            // `x * x` rounds exactly as it did when added, so the subtraction cancels it exactly.
            self.sums_of_squares[m].add(-(x * x));
            if self.maxima[m].front() == Some(&sequence) {
                self.maxima[m].pop_front();
            }
        }
    }
}

/// Position in a window's `samples` of the sample with this truncated sequence number, given the
/// sequence number of `samples[0]`.
fn offset(sequence: u32, front_sequence: u64) -> usize {
    sequence.wrapping_sub(front_sequence as u32) as usize
}

/// Gives memory back once a ring buffer is mostly empty (at most a quarter full); amortised O(1),
/// since halving the capacity again takes as many evictions as the copy costs.
fn trim_capacity<T>(deque: &mut VecDeque<T>) {
    const MIN_CAPACITY: usize = 64;
    if deque.capacity() > MIN_CAPACITY && deque.len() < deque.capacity() / 4 {
        deque.shrink_to((2 * deque.len()).max(MIN_CAPACITY));
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "exact results are expected where tested")]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn uniform(x: f64) -> [f64; METRIC_COUNT] {
        [x; METRIC_COUNT]
    }

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
        for value in [f64::NAN, f64::INFINITY, -f64::INFINITY, 1e101] {
            bad[4] = value;
            assert!(!cumulative.add(&bad));
            assert!(!window.add(0.0, &bad));
        }
        assert!(!window.add(f64::NAN, &uniform(1.0)));
        assert!(!window.add(f64::INFINITY, &uniform(1.0)));
        assert_eq!(cumulative.readout().n, 0);
        assert!(window.is_empty());
    }

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
    fn max_samples_cap_evicts_oldest() {
        let mut window = WindowStats::new(f64::INFINITY, 3);
        for (i, x) in [9.0, 1.0, 2.0, 3.0].into_iter().enumerate() {
            assert!(window.add(i as f64, &uniform(x)));
        }
        assert_eq!(window.len(), 3);
        let readout = window.readout();
        assert_eq!(readout.stats[3].max, 3.0);
        assert_eq!(readout.stats[3].mae, 2.0);
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
    fn backwards_stamp_stays_in_insertion_order() {
        let mut window = WindowStats::new(1.0, 100);
        assert!(window.add(5.0, &uniform(1.0)));
        // Too old relative to 5.0, but the sample just added is always kept.
        assert!(window.add(2.0, &uniform(7.0)));
        assert_eq!(window.len(), 2);
        // 5.9 evicts nothing: the front (5.0) is still inside; the 2.0 sample waits behind it.
        assert!(window.add(5.9, &uniform(1.0)));
        assert_eq!(window.len(), 3);
        assert_eq!(window.readout().stats[0].max, 7.0);
        // 6.0 evicts 5.0 and then the 2.0 sample behind it.
        assert!(window.add(6.0, &uniform(1.0)));
        assert_eq!(window.len(), 2);
        assert_eq!(window.readout().stats[0].max, 1.0);
    }

    #[test]
    fn reset_forgets_samples_and_newest_stamp() {
        let mut window = WindowStats::new(1.0, 100);
        assert!(window.add(100.0, &uniform(2.0)));
        window.reset();
        assert!(window.is_empty());
        assert_eq!(window.readout(), StatsSet::default());
        assert!(window.add(0.0, &uniform(1.0)));
        assert!(window.add(0.5, &uniform(1.0)));
        assert_eq!(window.len(), 2);
        assert_eq!(window.window_s(), 1.0);
        assert_eq!(window.max_samples(), 100);
    }

    /// Python's `math.fsum` (Shewchuk's partials, then one correct rounding): an independent
    /// exact oracle for [`ExactSum`].
    fn fsum(values: &[f64]) -> f64 {
        let mut partials: Vec<f64> = Vec::new();
        for &value in values {
            let mut x = value;
            let mut kept = 0;
            for j in 0..partials.len() {
                let mut y = partials[j];
                if x.abs() < y.abs() {
                    std::mem::swap(&mut x, &mut y);
                }
                let hi = x + y;
                let lo = y - (hi - x);
                if lo != 0.0 {
                    partials[kept] = lo;
                    kept += 1;
                }
                x = hi;
            }
            partials.truncate(kept);
            partials.push(x);
        }
        let Some(mut hi) = partials.pop() else {
            return 0.0;
        };
        let mut lo = 0.0;
        while let Some(y) = partials.pop() {
            let x = hi;
            hi = x + y;
            lo = y - (hi - x);
            if lo != 0.0 {
                break;
            }
        }
        if let Some(&next) = partials.last()
            && ((lo < 0.0 && next < 0.0) || (lo > 0.0 && next > 0.0))
        {
            let y = 2.0 * lo;
            let x = hi + y;
            if y == x - hi {
                hi = x;
            }
        }
        hi
    }

    fn exact_sum(values: &[f64]) -> f64 {
        let mut sum = ExactSum::default();
        for &x in values {
            sum.add(x);
        }
        sum.value()
    }

    #[test]
    fn exact_sum_cancels_across_magnitudes() {
        assert_eq!(exact_sum(&[]), 0.0);
        assert_eq!(exact_sum(&[1e100, 1.0, 1e-100, -1e100, 3.0]), 4.0);
        assert_eq!(exact_sum(&[1e200, 1e-100, -1e200]), 1e-100);
        assert_eq!(exact_sum(&[-1.5, 0.25]), -1.25);
        assert_eq!(exact_sum(&[0.1; 10]), fsum(&[0.1; 10]));
    }

    #[test]
    fn exact_sum_rounds_ties_to_even_and_keeps_subnormals() {
        let half_ulp = f64::EPSILON / 2.0;
        assert_eq!(exact_sum(&[1.0, half_ulp]), 1.0);
        assert_eq!(
            exact_sum(&[1.0 + f64::EPSILON, half_ulp]),
            1.0 + 2.0 * f64::EPSILON
        );
        // Anything beyond the tie, however small, rounds up.
        assert_eq!(exact_sum(&[1.0, half_ulp, 1e-300]), 1.0 + f64::EPSILON);
        assert_eq!(exact_sum(&[-1.0, -half_ulp, -1e-300]), -1.0 - f64::EPSILON);
        let tiny = f64::from_bits(1);
        assert_eq!(exact_sum(&[tiny, tiny, tiny]), f64::from_bits(3));
        assert_eq!(
            exact_sum(&[f64::MIN_POSITIVE, -tiny]),
            f64::from_bits((1 << 52) - 1)
        );
        assert_eq!(exact_sum(&[f64::MIN_POSITIVE / 2.0; 2]), f64::MIN_POSITIVE);
    }

    #[test]
    fn exact_sum_survives_deferred_carry_propagation() {
        let mut sum = ExactSum::Inline {
            low: EXACT_SUM_UNUSED,
            ops_since_carry: EXACT_SUM_OPS_BETWEEN_CARRIES - 2,
            chunks: [0; EXACT_SUM_INLINE_CHUNKS],
        };
        for x in [3.5, -1e-20, 2f64.powi(31), -7.0] {
            sum.add(x);
        }
        assert!(sum.ops_since_carry() < 4);
        assert_eq!(sum.value(), fsum(&[3.5, -1e-20, 2f64.powi(31), -7.0]));
    }

    /// Adds `values` one by one to `sum`, which holds `history`, checking the sum against
    /// `fsum` of everything added after each.
    fn check_adds(sum: &mut ExactSum, history: &mut Vec<f64>, values: &[f64]) {
        for &x in values {
            sum.add(x);
            history.push(x);
            assert_eq!(sum.value(), fsum(history), "after {history:?}");
        }
    }

    /// [`check_adds`] from an empty sum.
    fn check_prefixes(sum: &mut ExactSum, values: &[f64]) {
        check_adds(sum, &mut Vec::new(), values);
    }

    /// The chunk positions a sum holds.
    fn span(sum: &ExactSum) -> std::ops::Range<usize> {
        let low = usize::from(sum.low());
        low..low + sum.chunks().len()
    }

    #[test]
    #[cfg(target_pointer_width = "64")]
    fn exact_sum_is_five_words() {
        assert_eq!(size_of::<ExactSum>(), 40);
    }

    #[test]
    fn exact_sum_holds_clustered_values_inline() {
        let mut sum = ExactSum::default();
        assert_eq!(sum.value(), 0.0);
        // Zeros add nothing and claim no chunks.
        sum.add(0.0);
        sum.add(-0.0);
        assert_eq!(sum.low(), EXACT_SUM_UNUSED);
        assert_eq!(sum.value(), 0.0);
        // Deviations from a micrometre to a centimetre, and back out of the window.
        let values: Vec<f64> = (0..2000)
            .map(|i| 1e-6 * 1.7f64.powi(i % 17) * (1.0 + f64::from(i) * 1e-7))
            .collect();
        for &x in &values {
            sum.add(x);
        }
        assert!(matches!(sum, ExactSum::Inline { .. }), "{sum:?}");
        assert_eq!(sum.value(), fsum(&values));
        for &x in &values[..1000] {
            sum.add(-x);
        }
        assert_eq!(sum.value(), fsum(&values[1000..]));
        for &x in &values[1000..] {
            sum.add(-x);
        }
        assert_eq!(sum.value(), 0.0);
        assert!(matches!(sum, ExactSum::Inline { .. }));
    }

    #[test]
    fn exact_sum_grows_at_both_ends() {
        let (mut sum, mut history) = (ExactSum::default(), Vec::new());
        check_adds(&mut sum, &mut history, &[1.0, 3.0]);
        let start = span(&sum);
        assert!(matches!(sum, ExactSum::Inline { .. }));
        // Downwards, into the subnormals, keeping what is held.
        check_adds(&mut sum, &mut history, &[1e-300, f64::from_bits(1)]);
        let after_down = span(&sum);
        assert!(after_down.start < start.start && after_down.end == start.end);
        assert!(matches!(sum, ExactSum::Spilled { .. }));
        // Upwards, to the largest accepted values.
        let values = [1.0, 3.0, 1e-300, f64::from_bits(1), 1e200, -2.5e199, 1e200];
        let mut upwards = ExactSum::default();
        check_prefixes(&mut upwards, &values);
        let full = span(&upwards);
        assert_eq!(full.start, 0);
        assert!(full.end <= EXACT_SUM_CHUNKS, "{full:?}");
        // Everything but the smallest leaves again, exactly.
        for x in [1.0, 3.0, 1e-300, 1e200, -2.5e199, 1e200] {
            upwards.add(-x);
        }
        assert_eq!(upwards.value(), f64::from_bits(1));
        upwards.add(-f64::from_bits(1));
        assert_eq!(upwards.value(), 0.0);
        // Upwards alone, from small values to large ones.
        let mut sum = ExactSum::default();
        check_prefixes(&mut sum, &[1e-3, 2.0, 1e30, -1e-3, 7e100, -7e100, -1e30]);
        assert_eq!(sum.value(), 2.0);
    }

    #[test]
    fn exact_sum_changes_sign_and_cancels_to_zero() {
        let mut sum = ExactSum::default();
        check_prefixes(
            &mut sum,
            &[
                1.0,
                -3.0,
                2.5,
                -0.5,
                -1e-10,
                1e-10,
                2f64.powi(-60),
                -1e5,
                1e5,
            ],
        );
        assert_eq!(sum.value(), 2f64.powi(-60));
        sum.add(-(2f64.powi(-60)));
        assert_eq!(sum.value(), 0.0);
        // Negative results round to nearest, ties to even, like positive ones.
        let half_ulp = f64::EPSILON / 2.0;
        let mut negative = ExactSum::default();
        check_prefixes(&mut negative, &[-1.0, -half_ulp, 1e-200, -2e-200]);
        assert_eq!(negative.value(), -1.0 - f64::EPSILON);
    }

    #[test]
    fn exact_sum_subnormals_and_the_largest_values() {
        let tiny = f64::from_bits(1);
        let mut sum = ExactSum::default();
        check_prefixes(&mut sum, &[tiny, f64::MIN_POSITIVE, -tiny, tiny * 3.0]);
        assert_eq!(sum.value(), f64::from_bits(f64::MIN_POSITIVE.to_bits() + 3));
        let mut large = ExactSum::default();
        let values = vec![1e200; 1000];
        for &x in &values {
            large.add(x);
        }
        assert_eq!(large.value(), fsum(&values));
        for _ in 0..1000 {
            large.add(-1e200);
        }
        assert_eq!(large.value(), 0.0);
    }

    #[test]
    fn exact_sum_propagates_carries_in_spilled_chunks() {
        let mut sum = ExactSum::default();
        sum.add(1e-30);
        sum.add(1e10);
        assert!(matches!(sum, ExactSum::Spilled { .. }));
        *sum.parts_mut().1 = EXACT_SUM_OPS_BETWEEN_CARRIES - 2;
        for x in [-1e-30, 2f64.powi(31), -7.0, 1e-30] {
            sum.add(x);
        }
        assert!(sum.ops_since_carry() < 4);
        assert_eq!(sum.value(), fsum(&[1e10, 2f64.powi(31), -7.0, 1e-30]));
    }

    /// Values of one metric: positive, within `orders` binary orders of each other.
    fn clustered_value(orders: i32) -> impl Strategy<Value = f64> {
        (1.0..2.0f64, -orders..=0).prop_map(|(m, e)| m * 2f64.powi(e - 10))
    }

    fn signed_value() -> impl Strategy<Value = f64> {
        prop_oneof![
            (-1e200..1e200f64),
            (1.0..2.0f64, -1074..664i32, proptest::bool::ANY).prop_map(|(m, e, negative)| {
                let x = m * 2f64.powi(e);
                if negative { -x } else { x }
            }),
            (0u64..(1 << 52)).prop_map(f64::from_bits),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        #[test]
        fn exact_sum_matches_fsum(values in prop::collection::vec(signed_value(), 0..60)) {
            // `==` rather than bits: fsum may return −0.0 where the exact sum says 0.0.
            prop_assert_eq!(exact_sum(&values), fsum(&values));
        }

        #[test]
        fn exact_sum_slides_exactly(
            values in prop::collection::vec(prop_oneof![
                clustered_value(40),
                -1e100..1e100f64,
                (1.0..2.0f64, -1074..330i32).prop_map(|(m, e)| -m * 2f64.powi(e)),
            ], 1..80),
            width in 1usize..10,
        ) {
            // A sliding window: each value enters once and leaves `width` values later.
            let mut sum = ExactSum::default();
            for (i, &x) in values.iter().enumerate() {
                sum.add(x);
                sum.add(x * x);
                if i >= width {
                    let old = values[i - width];
                    sum.add(-old);
                    sum.add(-(old * old));
                }
                let kept = &values[i.saturating_sub(width - 1)..=i];
                let expected: Vec<f64> = kept.iter().flat_map(|&x| [x, x * x]).collect();
                prop_assert_eq!(sum.value(), fsum(&expected));
            }
        }

        #[test]
        fn exact_sum_subtracts_exactly(
            kept in prop::collection::vec(signed_value(), 0..20),
            removed in prop::collection::vec(signed_value(), 0..20),
        ) {
            let mut sum = ExactSum::default();
            for &x in removed.iter().chain(&kept) {
                sum.add(x);
            }
            for &x in &removed {
                sum.add(-x);
            }
            prop_assert_eq!(sum.value(), fsum(&kept));
        }
    }

    #[test]
    #[should_panic(expected = "window_s must be positive")]
    fn zero_window_is_refused() {
        let _ = WindowStats::new(0.0, 10);
    }

    #[test]
    fn window_memory_is_given_back() {
        let mut window = WindowStats::new(1.0, usize::MAX);
        for i in 0..10_000 {
            assert!(window.add(f64::from(i) * 1e-4, &uniform(f64::from(i))));
        }
        assert!(window.add(100.0, &uniform(1.0)));
        assert_eq!(window.len(), 1);
        assert!(window.samples.capacity() <= 64);
        assert!(window.maxima.iter().all(|d| d.capacity() <= 64));
    }
}
