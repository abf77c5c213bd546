//! Helpers shared by the core's integration tests.

use std::f64::consts::PI;

/// A small deterministic generator (`SplitMix64`), so every run tests the same inputs.
pub struct Rng(pub u64);

impl Rng {
    /// Uniform in [0, 1), 53 random bits.
    pub fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Six joint angles, each uniform in [−π, π) (rad).
    #[allow(
        dead_code,
        reason = "each test file compiles the helpers, and uses a part of them"
    )]
    pub fn joints(&mut self) -> [f64; 6] {
        std::array::from_fn(|_| (2.0 * self.unit() - 1.0) * PI)
    }
}
