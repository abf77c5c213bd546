//! Streaming metrics against naive two-pass and exact-integer recomputations, and deviations by hand.
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

/// A magnitude spanning twelve orders of magnitude, sometimes exactly zero.
fn magnitude() -> impl Strategy<Value = f64> {
    prop_oneof![
        1 => Just(0.0),
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

/// The samples a window of `window_s` capped at `max_samples` holds, from the definition.
fn expected_window(
    stamped: &[(f64, Magnitudes)],
    window_s: f64,
    max_samples: usize,
) -> Vec<Magnitudes> {
    let Some(newest_s) = stamped.iter().map(|(stamp_s, _)| *stamp_s).reduce(f64::max) else {
        return Vec::new();
    };
    let inside: Vec<Magnitudes> = stamped
        .iter()
        .filter(|(stamp_s, _)| *stamp_s > newest_s - window_s)
        .map(|(_, m)| *m)
        .collect();
    inside[inside.len().saturating_sub(max_samples)..].to_vec()
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
    fn window_matches_naive(
        start_s in -1e3..1e4f64,
        stream in prop::collection::vec((gap_s(), magnitudes()), 1..400),
        window_exponent in -3.0..1.0f64,
        max_samples in prop_oneof![1..50usize, Just(usize::MAX)],
    ) {
        let window_s = 10f64.powf(window_exponent);
        let mut window = WindowStats::new(window_s, max_samples);
        let mut stamped = Vec::with_capacity(stream.len());
        let mut stamp_s = start_s;
        for (gap_s, sample) in stream {
            stamp_s += gap_s;
            prop_assert!(window.add(stamp_s, &sample));
            stamped.push((stamp_s, sample));
            let expected = expected_window(&stamped, window_s, max_samples);
            prop_assert_eq!(window.len(), expected.len());
            check(&window.readout(), &naive(&expected), 1e-12)?;
        }
        window.reset();
        prop_assert!(window.is_empty());
        check(&window.readout(), &StatsSet::default(), 0.0)?;
    }
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
    const MAX_SAMPLES: usize = 200;
    let mut rng = SplitMix64(11);
    let mut window = WindowStats::new(WINDOW_S, MAX_SAMPLES);
    let mut stamped: Vec<(f64, Magnitudes)> = Vec::new();
    let mut stamp_s = 0.0;
    for i in 0..N {
        // 500 Hz with jitter and the odd outage; values of every size, ending with a quiet tail so
        // that large values which have left would show up as residue if anything drifted.
        stamp_s += match rng.next() % 1000 {
            0 => 3.0,
            1..=100 => 0.0,
            _ => 0.002 * (0.5 + (rng.next() % 1000) as f64 / 1000.0),
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
        assert!(window.add(stamp_s, &sample));
        stamped.push((stamp_s, sample));
        if stamped.len() > 4 * MAX_SAMPLES {
            stamped.drain(..2 * MAX_SAMPLES);
        }
    }
    let expected = expected_window(&stamped, WINDOW_S, MAX_SAMPLES);
    assert!(
        expected.len() > 10,
        "the final window should not be trivially small"
    );
    assert_eq!(window.len(), expected.len());
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
        assert_eq!(got.mae, mean, "{}", METRIC_NAMES[m]);
        // Squares of 40-bit integers round, so the RMS is off the integer one by an ulp or so.
        assert!(close(got.rmse, rms, 1e-15), "{}", METRIC_NAMES[m]);
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
