//! Batched trigonometry for the forward-kinematics hot path: `sin_cos` of [`BATCH`] angles and
//! `atan2` of [`ATAN2_BATCH`] pairs at once.
//!
//! Owns only these two functions. Both are branch-free so the compiler vectorises them: the
//! platform's `sin_cos` and `atan2` are scalar library calls, and the six `sin_cos` and three
//! `atan2` of one pose through them were most of its cost. Elsewhere armtwin uses `f64`'s own.
//!
//! Method (fdlibm's, as in musl): `sin_cos` reduces by π/2 with a two-part Cody–Waite constant
//! and evaluates fdlibm's minimax kernels on [−π/4, π/4], written as loops over fixed-size lane
//! arrays, each step across all lanes without per-lane branches (two-lane SSE2 on the x86-64
//! baseline); `atan2` reduces to atan on [0, 1], then to |t| < 7/16 around 0, atan(½) or π/4,
//! with fdlibm's atan kernel. Both stay within 2 ulp of
//! the exact values (tested against the platform over millions of arguments). `sin_cos` falls
//! back to `f64::sin_cos` for a batch holding an angle beyond [`REDUCTION_LIMIT_RAD`] (never a
//! real joint).

#![allow(
    clippy::excessive_precision,
    reason = "fdlibm's constants, written digit for digit as published"
)]

use std::f64::consts::{FRAC_2_PI, FRAC_PI_2, FRAC_PI_4, PI};

/// Angles per `sin_cos` batch: a six-joint arm fills one.
pub const BATCH: usize = 6;

/// Pairs per `atan2` batch: roll, pitch and yaw fill one.
pub const ATAN2_BATCH: usize = 3;

/// Largest |angle| the two-part reduction keeps exact (k · `PIO2_HI` must be exact: k < 2²⁰).
pub const REDUCTION_LIMIT_RAD: f64 = 1.0e5;

/// π/2 split in two: `PIO2_HI` has 33 significant bits, so `k · PIO2_HI` is exact for k < 2²⁰.
const PIO2_HI: f64 = 1.570_796_326_734_125_614_17e+00;
const PIO2_LO: f64 = 6.077_100_506_506_192_249_32e-11;

/// 1.5 · 2⁵²: adding it rounds to the nearest integer and leaves that integer in the low bits.
const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;

const S1: f64 = -1.666_666_666_666_663_243_48e-01;
const S2: f64 = 8.333_333_333_322_489_461_24e-03;
const S3: f64 = -1.984_126_982_985_794_931_34e-04;
const S4: f64 = 2.755_731_370_707_006_767_89e-06;
const S5: f64 = -2.505_076_025_340_686_341_95e-08;
const S6: f64 = 1.589_690_995_211_550_102_21e-10;

const C1: f64 = 4.166_666_666_666_660_190_37e-02;
const C2: f64 = -1.388_888_888_887_410_957_49e-03;
const C3: f64 = 2.480_158_728_947_672_941_78e-05;
const C4: f64 = -2.755_731_435_139_066_330_35e-07;
const C5: f64 = 2.087_572_321_298_174_827_90e-09;
const C6: f64 = -1.135_964_755_778_819_482_65e-11;

/// `(sin, cos)` of each of `angles_rad`, within 1 ulp.
#[must_use]
#[inline]
pub fn sin_cos_batch(angles_rad: &[f64; BATCH]) -> ([f64; BATCH], [f64; BATCH]) {
    sin_cos_batch_split(angles_rad, &[0.0; BATCH])
}

/// `(sin, cos)` of each angle `hi + lo`, the pair taken as an unrounded sum: `lo` is the rounding
/// error of a sum of angles (e.g. from a two-sum), at most an ulp or so of `hi`. This keeps
/// `sin(q₂ + q₃ + q₄)` as accurate as `sin(q₂)` where the rounded sum alone would lose up to half
/// an ulp of the sum (2e-15 rad for sums near 6π).
#[must_use]
#[inline(always)]
#[allow(
    clippy::inline_always,
    reason = "out of line, the caller's element-wise stores meet the kernel's paired loads (a store-forwarding stall)"
)]
pub fn sin_cos_batch_split(
    angles_hi_rad: &[f64; BATCH],
    angles_lo_rad: &[f64; BATCH],
) -> ([f64; BATCH], [f64; BATCH]) {
    // Non-short-circuit `|`: one vector comparison instead of a branch per angle.
    let huge = angles_hi_rad
        .iter()
        .fold(false, |huge, a| huge | (a.abs() > REDUCTION_LIMIT_RAD));
    if huge {
        return sin_cos_platform(angles_hi_rad, angles_lo_rad);
    }
    sin_cos_lanes(angles_hi_rad, angles_lo_rad)
}

/// The rare path for huge angles: the platform's `sin_cos` of `hi`, turned by the tiny `lo`
/// (first order; `lo²` is far below an ulp).
#[cold]
fn sin_cos_platform(hi: &[f64; BATCH], lo: &[f64; BATCH]) -> ([f64; BATCH], [f64; BATCH]) {
    let mut sin = [0.0; BATCH];
    let mut cos = [0.0; BATCH];
    for i in 0..BATCH {
        let (s, c) = hi[i].sin_cos();
        sin[i] = s + lo[i] * c;
        cos[i] = c - lo[i] * s;
    }
    (sin, cos)
}

/// The kernel for |hi| ≤ [`REDUCTION_LIMIT_RAD`], one step at a time across all lanes: plain
/// loops over fixed-size arrays with no per-lane branch, which LLVM turns into two-lane SSE2.
#[inline(always)]
#[allow(
    clippy::inline_always,
    reason = "out of line, the caller's element-wise stores meet the kernel's paired loads (a store-forwarding stall)"
)]
fn sin_cos_lanes<const N: usize>(hi: &[f64; N], lo: &[f64; N]) -> ([f64; N], [f64; N]) {
    let mut quadrant = [0_u64; N];
    let mut r = [0.0; N];
    for i in 0..N {
        let shifted = hi[i] * FRAC_2_PI + ROUND_MAGIC;
        quadrant[i] = shifted.to_bits();
        let k = shifted - ROUND_MAGIC;
        // Exact first step (Sterbenz and the 33-bit constant), then the small corrections.
        r[i] = ((hi[i] - k * PIO2_HI) - k * PIO2_LO) + lo[i];
    }
    let mut sin = [0.0; N];
    let mut cos = [0.0; N];
    for i in 0..N {
        let r = r[i];
        let z = r * r;
        let sin_r = r + r * z * (S1 + z * (S2 + z * (S3 + z * (S4 + z * (S5 + z * S6)))));
        let cos_r =
            1.0 - (0.5 * z - z * z * (C1 + z * (C2 + z * (C3 + z * (C4 + z * (C5 + z * C6))))));
        // Quadrant k mod 4: sin x = [s, c, −s, −c][k], cos x = [c, −s, −c, s][k].
        let swap = (quadrant[i] & 1).wrapping_neg();
        let sin_abs = (sin_r.to_bits() & !swap) | (cos_r.to_bits() & swap);
        let cos_abs = (cos_r.to_bits() & !swap) | (sin_r.to_bits() & swap);
        // Bit 1 of the quadrant moved to the sign bit.
        let sin_sign = (quadrant[i] & 2) << 62;
        let cos_sign = (quadrant[i].wrapping_add(1) & 2) << 62;
        sin[i] = f64::from_bits(sin_abs ^ sin_sign);
        cos[i] = f64::from_bits(cos_abs ^ cos_sign);
    }
    (sin, cos)
}

const AT: [f64; 11] = [
    3.333_333_333_333_293_180_27e-01,
    -1.999_999_999_987_648_324_76e-01,
    1.428_571_427_250_346_637_11e-01,
    -1.111_111_040_546_235_578_80e-01,
    9.090_887_133_436_506_561_96e-02,
    -7.691_876_205_044_829_994_95e-02,
    6.661_073_137_387_531_206_69e-02,
    -5.833_570_133_790_573_486_45e-02,
    4.976_877_994_615_932_360_17e-02,
    -3.653_157_274_421_691_552_70e-02,
    1.628_582_011_536_578_236_23e-02,
];
/// atan(½) and atan(1) = π/4, each as a high part and a low correction.
const ATAN_HALF_HI: f64 = 4.636_476_090_008_060_935_15e-01;
const ATAN_HALF_LO: f64 = 2.269_877_745_296_168_709_24e-17;
const ATAN_ONE_HI: f64 = FRAC_PI_4;
const ATAN_ONE_LO: f64 = 3.061_616_997_868_383_017_93e-17;
const FRAC_PI_2_HI: f64 = FRAC_PI_2;
const FRAC_PI_2_LO: f64 = 6.123_233_995_736_766_035_87e-17;
const PI_HI: f64 = PI;
const PI_LO: f64 = 1.224_646_799_147_353_207_17e-16;

/// `atan2(y, x)` of each pair, in [−π, π], within 2 ulp; `atan2(±0, ±0)` as IEEE defines it.
/// Arguments must be finite (they are rotation-matrix entries here).
#[must_use]
#[inline(always)]
#[allow(
    clippy::inline_always,
    reason = "out of line, the caller's element-wise stores meet the kernel's paired loads (a store-forwarding stall)"
)]
pub fn atan2_batch(y: &[f64; ATAN2_BATCH], x: &[f64; ATAN2_BATCH]) -> [f64; ATAN2_BATCH] {
    [
        atan2_kernel(y[0], x[0]),
        atan2_kernel(y[1], x[1]),
        atan2_kernel(y[2], x[2]),
    ]
}

#[inline]
fn atan2_kernel(y: f64, x: f64) -> f64 {
    {
        let (ay, ax) = (y.abs(), x.abs());
        let swap = ay > ax;
        let (num, den) = if swap { (ax, ay) } else { (ay, ax) };
        let a = if den > 0.0 { num / den } else { 0.0 };
        // atan(a) = base + atan(t) with |t| < 7/16.
        let (t, base_hi, base_lo) = if a < 0.4375 {
            (a, 0.0, 0.0)
        } else if a < 0.6875 {
            ((2.0 * a - 1.0) / (2.0 + a), ATAN_HALF_HI, ATAN_HALF_LO)
        } else {
            ((a - 1.0) / (a + 1.0), ATAN_ONE_HI, ATAN_ONE_LO)
        };
        let z = t * t;
        let w = z * z;
        let s1 = z * (AT[0] + w * (AT[2] + w * (AT[4] + w * (AT[6] + w * (AT[8] + w * AT[10])))));
        let s2 = w * (AT[1] + w * (AT[3] + w * (AT[5] + w * (AT[7] + w * AT[9]))));
        let atan_a = base_hi - ((t * (s1 + s2) - base_lo) - t);
        // Undo the reductions: |y| > |x| reflects about π/4, x < 0 (or −0) about π/2.
        let first_octants = if swap {
            (FRAC_PI_2_HI - atan_a) + FRAC_PI_2_LO
        } else {
            atan_a
        };
        let half_plane = if x.is_sign_negative() {
            (PI_HI - first_octants) + PI_LO
        } else {
            first_octants
        };
        half_plane.copysign(y)
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "special cases have exact answers")]
mod tests {
    use super::*;

    /// Distance in units in the last place (ulp of the larger magnitude, at least 2⁻¹⁰⁷⁴).
    fn ulps(a: f64, b: f64) -> f64 {
        let scale = a.abs().max(b.abs());
        let ulp = if scale == 0.0 {
            f64::from_bits(1)
        } else {
            f64::from_bits(scale.to_bits() + 1) - scale
        };
        (a - b).abs() / ulp
    }

    #[test]
    fn matches_the_platform_over_joint_ranges() {
        let mut worst = (0.0_f64, 0.0_f64);
        let mut angle = -40.0_f64;
        let step = 80.0 / 2_000_000.0;
        while angle < 40.0 {
            let batch: [f64; BATCH] = std::array::from_fn(|i| angle + i as f64 * 1.234_567e-3);
            let (sin, cos) = sin_cos_batch(&batch);
            for i in 0..BATCH {
                let (s, c) = batch[i].sin_cos();
                // Absolute error is what the kinematics needs; near zeros ulp counts mislead.
                worst.0 = worst.0.max((sin[i] - s).abs());
                worst.1 = worst.1.max((cos[i] - c).abs());
                if s.abs() > 0.5 {
                    assert!(
                        ulps(sin[i], s) <= 2.0,
                        "sin({}) = {} vs {}",
                        batch[i],
                        sin[i],
                        s
                    );
                }
                if c.abs() > 0.5 {
                    assert!(
                        ulps(cos[i], c) <= 2.0,
                        "cos({}) = {} vs {}",
                        batch[i],
                        cos[i],
                        c
                    );
                }
            }
            angle += step * BATCH as f64;
        }
        assert!(worst.0 < 3e-16 && worst.1 < 3e-16, "{worst:?}");
    }

    #[test]
    fn split_angles_are_taken_as_unrounded_sums() {
        // Sums of three joint angles up to 6π, whose rounding alone can reach 1.8e-15 rad.
        let mut worst_split = 0.0_f64;
        let mut k = 0_u32;
        while k < 200_000 {
            let batch: [[f64; 3]; BATCH] = std::array::from_fn(|i| {
                let u = f64::from(k) + i as f64 * 0.377;
                [
                    6.2 - (u * 1e-5) % 0.3,
                    6.1 + (u * 3.1e-6) % 0.18,
                    -6.2 + (u * 7.7e-6) % 12.4,
                ]
            });
            let mut hi = [0.0; BATCH];
            let mut lo = [0.0; BATCH];
            for i in 0..BATCH {
                let [a, b, c] = batch[i];
                let (ab, e1) = two_sum(a, b);
                let (abc, e2) = two_sum(ab, c);
                (hi[i], lo[i]) = (abc, e1 + e2);
            }
            let (sin, cos) = sin_cos_batch_split(&hi, &lo);
            for i in 0..BATCH {
                // Reference: the angle of (hi + lo) via sin(hi + lo) = sin hi + lo · cos hi.
                let (s, c) = hi[i].sin_cos();
                let (s_ref, c_ref) = (s + lo[i] * c, c - lo[i] * s);
                worst_split = worst_split
                    .max((sin[i] - s_ref).abs())
                    .max((cos[i] - c_ref).abs());
            }
            k += BATCH as u32;
        }
        assert!(worst_split < 3e-16, "{worst_split}");
        assert_eq!(
            sin_cos_batch_split(&[3.0e5; BATCH], &[1e-11; BATCH]).0[0],
            {
                let (s, c) = 3.0e5_f64.sin_cos();
                s + 1e-11 * c
            }
        );
    }

    fn two_sum(a: f64, b: f64) -> (f64, f64) {
        let sum = a + b;
        let b_part = sum - a;
        (sum, (a - (sum - b_part)) + (b - b_part))
    }

    #[test]
    fn atan2_matches_the_platform_in_every_octant() {
        let mut worst = 0.0_f64;
        let steps = 1_000_000;
        for k in 0..steps {
            // Points on a spiral through every octant and a wide range of radii.
            let angle = -PI + std::f64::consts::TAU * (f64::from(k) + 0.5) / f64::from(steps);
            let radius = 1e-3 + f64::from(k % 977) * 0.37;
            let (s, c) = angle.sin_cos();
            let y = [radius * s, c, -radius * c];
            let x = [radius * c, s * 1e-9, radius * s];
            let fast = atan2_batch(&y, &x);
            for i in 0..ATAN2_BATCH {
                let exact = y[i].atan2(x[i]);
                worst = worst.max((fast[i] - exact).abs());
                if exact.abs() > 1e-3 {
                    assert!(
                        ulps(fast[i], exact) <= 2.0,
                        "atan2({}, {}) = {} vs {exact}",
                        y[i],
                        x[i],
                        fast[i]
                    );
                }
            }
        }
        assert!(worst < 5e-16, "{worst}");
    }

    #[test]
    fn atan2_special_cases_follow_ieee() {
        let cases = [
            (0.0, 0.0),
            (-0.0, 0.0),
            (0.0, -0.0),
            (-0.0, -0.0),
            (1.0, 0.0),
            (-1.0, 0.0),
            (0.0, -1.0),
            (-0.0, -1.0),
            (1.0, 1.0),
            (-1.0, -1.0),
            (1e-300, 1.0),
            (1.0, 1e-300),
        ];
        for (y, x) in cases {
            let fast = atan2_batch(&[y; ATAN2_BATCH], &[x; ATAN2_BATCH])[0];
            let exact: f64 = y.atan2(x);
            assert!(
                fast.to_bits() == exact.to_bits() || ulps(fast, exact) <= 1.0,
                "atan2({y}, {x}) = {fast} vs {exact}"
            );
        }
    }

    #[test]
    fn exact_at_special_points_and_falls_back_for_huge_angles() {
        let mut batch = [0.0; BATCH];
        batch[1] = -0.0;
        batch[2] = std::f64::consts::FRAC_PI_2;
        batch[3] = -std::f64::consts::PI;
        batch[4] = 1e-300;
        batch[5] = 3.0e5;
        assert_eq!(BATCH, 6, "the cases below fill one batch");
        let (sin, cos) = sin_cos_batch(&batch);
        assert_eq!((sin[0], cos[0]), (0.0, 1.0));
        assert_eq!(cos[1], 1.0);
        assert!((sin[2] - 1.0).abs() < 1e-16 && cos[2].abs() < 1e-16);
        assert!(sin[3].abs() < 1e-15 && (cos[3] + 1.0).abs() < 1e-16);
        assert_eq!(sin[4], 1e-300);
        assert_eq!((sin[5], cos[5]), 3.0e5_f64.sin_cos());
    }
}
