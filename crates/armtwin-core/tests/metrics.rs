//! Streaming metrics against naive two-pass and exact-integer recomputations over the same
//! samples (the window's: the same slices), and deviations by hand.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]
#![allow(
    clippy::float_cmp,
    reason = "exact sums, maxima and hand-made cases are exact"
)]

use std::f64::consts::PI;

use armtwin_core::kinematics::PoseReadout;
use armtwin_core::metrics::{
    CumulativeStats, Deviation, METRIC_COUNT, METRIC_NAMES, StatsSet, WindowStats,
};
use armtwin_core::orientation::{Rpy, matrix_from_rpy, quaternion_from_matrix};
use nalgebra::{UnitQuaternion, Vector3};
use proptest::prelude::*;

type Magnitudes = [f64; METRIC_COUNT];

/// Mean, RMS and maximum of each metric computed the textbook way, after the fact.
fn naive(samples: &[Magnitudes]) -> StatsSet {
    let mut expected = StatsSet {
        n: samples.len() as u64,
        ..StatsSet::default()
    };
    if samples.is_empty() {
        return expected;
    }
    let n = samples.len() as f64;
    for (m, stats) in expected.stats.iter_mut().enumerate() {
        let sum: f64 = samples.iter().map(|s| s[m]).sum();
        let sum_of_squares: f64 = samples.iter().map(|s| s[m] * s[m]).sum();
        stats.mae = sum / n;
        stats.rmse = (sum_of_squares / n).sqrt();
        stats.max = samples
            .iter()
            .map(|s| s[m])
            .fold(f64::NEG_INFINITY, f64::max);
    }
    expected
}

fn close(got: f64, expected: f64, relative: f64) -> bool {
    (got - expected).abs() <= relative * expected.abs()
}

/// Compares every statistic; the maximum must be exact.
fn check(got: &StatsSet, expected: &StatsSet, relative: f64) -> Result<(), TestCaseError> {
    prop_assert_eq!(got.n, expected.n);
    for (m, (g, e)) in got.stats.iter().zip(&expected.stats).enumerate() {
        let name = METRIC_NAMES[m];
        prop_assert!(close(g.mae, e.mae, relative), "{name} mae {g:?} vs {e:?}");
        prop_assert!(
            close(g.rmse, e.rmse, relative),
            "{name} rmse {g:?} vs {e:?}"
        );
        prop_assert!(
            g.max.to_bits() == e.max.to_bits(),
            "{name} max {g:?} vs {e:?}"
        );
    }
    Ok(())
}

/// A magnitude spanning twelve orders of magnitude, sometimes exactly zero, sometimes one of two
/// values that recur (ties for the maximum).
fn magnitude() -> impl Strategy<Value = f64> {
    prop_oneof![
        1 => Just(0.0),
        2 => prop_oneof![Just(1e-3), Just(2e-3)],
        9 => (1.0..10.0f64, -9..3i32).prop_map(|(mantissa, exponent)| mantissa * 10f64.powi(exponent)),
    ]
}

fn magnitudes() -> impl Strategy<Value = Magnitudes> {
    prop::array::uniform9(magnitude())
}

/// Gaps between stamps (s): repeated stamps, steady ticks, jitter and outages.
fn gap_s() -> impl Strategy<Value = f64> {
    prop_oneof![
        2 => Just(0.0),
        4 => Just(0.002),
        4 => 0.0..0.05f64,
        1 => 0.5..20.0f64,
    ]
}

/// A sample as the window's oracle sees it: stamp, values, and the slice the window puts it in.
struct Stamped {
    stamp_s: f64,
    slice: i64,
    values: Magnitudes,
}

/// The window's contract kept by hand: every sample it took, and the newest slice.
struct Reference {
    slices: i64,
    newest: Option<i64>,
    taken: Vec<Stamped>,
}

impl Reference {
    fn new(slices: usize) -> Self {
        Self {
            slices: i64::try_from(slices).expect("a window's slices"),
            newest: None,
            taken: Vec::new(),
        }
    }

    fn inside(&self, slice: i64) -> bool {
        self.newest
            .is_none_or(|newest| slice > newest - self.slices)
    }

    /// A sample at `stamp_s` in `slice`: taken unless its slice has left the window.
    fn add(&mut self, stamp_s: f64, slice: i64, values: Magnitudes) -> bool {
        if !self.inside(slice) {
            return false;
        }
        self.advance(slice);
        self.taken.push(Stamped {
            stamp_s,
            slice,
            values,
        });
        true
    }

    fn advance(&mut self, slice: i64) {
        self.newest = Some(self.newest.map_or(slice, |newest| newest.max(slice)));
    }

    /// The samples in the window now, by the definition: those of its last `slices` slices.
    fn window(&self) -> Vec<&Stamped> {
        self.taken.iter().filter(|s| self.inside(s.slice)).collect()
    }
}

/// The window's edge in source time: nothing `window_s` old or older is in it, and everything
/// taken that is less than `window_s − window_s / slices` old is (a margin of 1e-9 relative
/// keeps stamps that sit on a slice bound out of the question).
fn check_edge(
    reference: &Reference,
    window_s: f64,
    slices: usize,
    newest_s: f64,
) -> Result<(), TestCaseError> {
    let in_window: Vec<f64> = reference.window().iter().map(|s| s.stamp_s).collect();
    let margin = 1e-9 * (newest_s.abs() + window_s);
    for sample in &reference.taken {
        let age_s = newest_s - sample.stamp_s;
        let inside = in_window.contains(&sample.stamp_s);
        if age_s >= window_s + margin {
            prop_assert!(!inside, "{} s old in a {window_s} s window", age_s);
        }
        if age_s < window_s - window_s / slices as f64 - margin {
            prop_assert!(inside, "{} s old left a {window_s} s window", age_s);
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    #[test]
    fn cumulative_matches_naive(samples in prop::collection::vec(magnitudes(), 0..400)) {
        let mut stats = CumulativeStats::new();
        for (i, sample) in samples.iter().enumerate() {
            prop_assert!(stats.add(sample));
            if i % 37 == 0 {
                check(&stats.readout(), &naive(&samples[..=i]), 1e-12)?;
            }
        }
        check(&stats.readout(), &naive(&samples), 1e-12)?;
        stats.reset();
        check(&stats.readout(), &StatsSet::default(), 0.0)?;
    }

    #[test]
    fn window_matches_naive_over_the_same_slices(
        start_s in -1e3..1e4f64,
        stream in prop::collection::vec((gap_s(), lateness(), magnitudes()), 1..400),
        window_exponent in -3.0..1.0f64,
        slices in prop_oneof![1..8usize, Just(100usize), 8..300usize],
        loud_until in 0..400usize,
    ) {
        let window_s = 10f64.powf(window_exponent);
        let mut window = WindowStats::new(window_s, slices);
        let mut reference = Reference::new(slices);
        let (mut now_s, mut newest_s) = (start_s, f64::NEG_INFINITY);
        for (i, (gap_s, late, sample)) in stream.into_iter().enumerate() {
            now_s += gap_s;
            // Loud samples first, then quiet ones: what the loud ones leave behind when they go
            // must not show in the quiet ones' statistics.
            let sample = if i < loud_until { sample.map(|x| x * 1e6) } else { sample };
            // Every fifth step only moves time on, as a joint sample without a pair does.
            if i % 5 == 4 {
                window.advance_to(now_s);
                reference.advance(window.slice_of(now_s));
                newest_s = newest_s.max(now_s);
                continue;
            }
            let stamp_s = now_s - late * window_s;
            let slice = window.slice_of(stamp_s);
            let taken = reference.add(stamp_s, slice, sample);
            prop_assert_eq!(window.add(stamp_s, &sample), taken, "at {} s", stamp_s);
            if taken {
                newest_s = newest_s.max(stamp_s);
            }
            prop_assert_eq!(window.newest_slice(), reference.newest);
            let expected: Vec<Magnitudes> =
                reference.window().iter().map(|s| s.values).collect();
            prop_assert_eq!(window.len(), expected.len() as u64);
            check(&window.readout(), &naive(&expected), 1e-12)?;
            check_edge(&reference, window_s, slices, newest_s)?;
        }
        window.reset();
        prop_assert!(window.is_empty());
        check(&window.readout(), &StatsSet::default(), 0.0)?;
    }
}

/// How late a sample is stamped, in windows: mostly on time, sometimes within the window,
/// sometimes beyond it.
fn lateness() -> impl Strategy<Value = f64> {
    prop_oneof![
        6 => Just(0.0),
        3 => 0.0..1.0f64,
        1 => 0.9..2.0f64,
    ]
}

/// `SplitMix64`: a reproducible stream without another dependency.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// An integer in [0, 2⁴⁰), log-uniformly spread over its bit lengths.
    fn wide_integer(&mut self) -> u64 {
        let r = self.next();
        // The low bits pick the length, the high 40 bits the digits.
        (r >> 24) >> (40 - r % 41)
    }
}

/// Scale of the dyadic test values `k · 2⁻³⁰`: every value, square and sum is then an exact integer
/// multiple of a power of two, so `i128` arithmetic gives the exact statistics to compare against.
const SCALE: f64 = 1.0 / 1_073_741_824.0;

/// Exact mean and RMS of dyadic values `k · 2⁻³⁰` from integer sums of `k` and `k²`.
fn exact_mean_and_rms(sum_k: i128, sum_k_squared: i128, n: u64) -> (f64, f64) {
    let count = n as f64;
    // `i128 as f64` rounds to nearest, exactly like `math.fsum`; scaling by a power of two is exact.
    let mean = sum_k as f64 * SCALE / count;
    let rms = (sum_k_squared as f64 * SCALE * SCALE / count).sqrt();
    (mean, rms)
}

#[test]
fn cumulative_ten_million_samples_match_exact_sums() {
    const N: u64 = 10_000_000;
    let mut rng = SplitMix64(7);
    let mut stats = CumulativeStats::new();
    let mut sum_k = [0i128; METRIC_COUNT];
    let mut sum_k_squared = [0i128; METRIC_COUNT];
    let mut max_k = [0u64; METRIC_COUNT];
    for _ in 0..N {
        let mut sample = [0.0; METRIC_COUNT];
        for m in 0..METRIC_COUNT {
            let k = rng.wide_integer();
            sample[m] = k as f64 * SCALE;
            sum_k[m] += i128::from(k);
            sum_k_squared[m] += i128::from(k) * i128::from(k);
            max_k[m] = max_k[m].max(k);
        }
        assert!(stats.add(&sample));
    }
    let readout = stats.readout();
    assert_eq!(readout.n, N);
    for m in 0..METRIC_COUNT {
        let (mean, rms) = exact_mean_and_rms(sum_k[m], sum_k_squared[m], N);
        let got = readout.stats[m];
        assert!(close(got.mae, mean, 1e-12), "{got:?} vs {mean}");
        assert!(close(got.rmse, rms, 1e-12), "{got:?} vs {rms}");
        assert_eq!(got.max, max_k[m] as f64 * SCALE);
    }
}

#[test]
fn window_does_not_drift_over_two_million_samples() {
    const N: u64 = 2_000_000;
    const WINDOW_S: f64 = 0.25;
    const SLICES: usize = 100;
    let mut rng = SplitMix64(11);
    let mut window = WindowStats::new(WINDOW_S, SLICES);
    let mut reference = Reference::new(SLICES);
    let mut now_s = 0.0;
    for i in 0..N {
        // 500 Hz with jitter, the odd outage and the odd late sample; values of every size, ending
        // with a quiet tail so that large values which have left would show up as residue if
        // anything drifted.
        now_s += match rng.next() % 1000 {
            0 => 3.0,
            1..=100 => 0.0,
            _ => 0.002 * (0.5 + (rng.next() % 1000) as f64 / 1000.0),
        };
        let stamp_s = if rng.next().is_multiple_of(50) {
            now_s - WINDOW_S * (rng.next() % 1000) as f64 / 800.0
        } else {
            now_s
        };
        let quiet = i > N - 1000;
        let sample: Magnitudes = std::array::from_fn(|_| {
            let k = rng.wide_integer();
            if quiet {
                (k % 1024) as f64 * SCALE
            } else {
                k as f64 * SCALE
            }
        });
        let taken = reference.add(stamp_s, window.slice_of(stamp_s), sample);
        assert_eq!(window.add(stamp_s, &sample), taken);
        if reference.taken.len() > 4000 {
            let newest = reference.newest.expect("samples were taken");
            reference
                .taken
                .retain(|s| s.slice > newest - reference.slices);
        }
    }
    let expected: Vec<Magnitudes> = reference.window().iter().map(|s| s.values).collect();
    assert!(
        expected.len() > 10,
        "the final window should not be trivially small"
    );
    assert_eq!(window.len(), expected.len() as u64);
    let readout = window.readout();
    let reference = naive(&expected);
    // Dyadic values: the integer sums give the exactly rounded reference too.
    for m in 0..METRIC_COUNT {
        let ks: Vec<i128> = expected.iter().map(|s| (s[m] / SCALE) as i128).collect();
        let (mean, rms) = exact_mean_and_rms(
            ks.iter().sum(),
            ks.iter().map(|k| k * k).sum(),
            expected.len() as u64,
        );
        let got = readout.stats[m];
        assert!(close(got.mae, mean, 1e-12), "{}", METRIC_NAMES[m]);
        assert!(close(got.rmse, rms, 1e-12), "{}", METRIC_NAMES[m]);
        assert!(close(got.mae, reference.stats[m].mae, 1e-12));
        assert!(close(got.rmse, reference.stats[m].rmse, 1e-12));
        assert_eq!(got.max, reference.stats[m].max);
    }
}

fn pose(position_m: [f64; 3], rpy: Rpy) -> PoseReadout {
    PoseReadout::from_position_quaternion(
        position_m,
        &quaternion_from_matrix(&matrix_from_rpy(rpy)),
    )
}

#[test]
fn deviation_of_a_yaw_turn_and_a_3_4_12_offset() {
    let twin =
        PoseReadout::from_position_quaternion([1.5, -2.0, 12.25], &UnitQuaternion::identity());
    let measured = PoseReadout::from_position_quaternion(
        [-1.5, -6.0, 0.25],
        &UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.5)),
    );
    let d = Deviation::between(&twin, &measured);
    assert_eq!([d.dx_m, d.dy_m, d.dz_m], [3.0, 4.0, 12.0]);
    assert_eq!(d.position_m, 13.0);
    assert!((d.angle_rad - 0.5).abs() < 1e-15, "{d:?}");
    assert!(
        (d.quat_distance - (1.0 - 0.25f64.cos())).abs() < 1e-15,
        "{d:?}"
    );
    assert!((d.dyaw_rad + 0.5).abs() < 1e-15, "{d:?}");
    assert!(
        d.droll_rad.abs() < 1e-15 && d.dpitch_rad.abs() < 1e-15,
        "{d:?}"
    );
    let magnitudes = d.magnitudes();
    let expected = [
        13.0,
        3.0,
        4.0,
        12.0,
        d.quat_distance,
        d.angle_rad,
        0.0,
        0.0,
        0.5,
    ];
    for (m, (got, want)) in magnitudes.iter().zip(expected).enumerate() {
        assert!(
            (got - want).abs() < 1e-15,
            "{}: {got} vs {want}",
            METRIC_NAMES[m]
        );
    }
    // Swapping the roles flips the signed differences only.
    let back = Deviation::between(&measured, &twin);
    assert_eq!([back.dx_m, back.dy_m, back.dz_m], [-3.0, -4.0, -12.0]);
    assert!((back.dyaw_rad - 0.5).abs() < 1e-15);
    assert_eq!(back.magnitudes(), magnitudes);
}

#[test]
fn deviation_wraps_yaw_across_plus_minus_pi() {
    let twin = pose(
        [0.0; 3],
        Rpy {
            roll_rad: 0.0,
            pitch_rad: 0.0,
            yaw_rad: 3.0,
        },
    );
    let measured = pose(
        [0.0; 3],
        Rpy {
            roll_rad: 0.0,
            pitch_rad: 0.0,
            yaw_rad: -3.0,
        },
    );
    let d = Deviation::between(&twin, &measured);
    let across = 2.0 * PI - 6.0;
    // 3 − (−3) = 6 rad wraps to 6 − 2π: the short way round, matching the rotation angle.
    assert!((d.dyaw_rad + across).abs() < 1e-12, "{d:?}");
    assert!((d.angle_rad - across).abs() < 1e-12, "{d:?}");
    assert_eq!(d.position_m, 0.0);
    assert!(d.magnitudes().iter().all(|x| *x >= 0.0));
}
