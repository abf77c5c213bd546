//! Self-calibration of a live twin: a bounded reservoir of the robot's own paired samples, and
//! the re-fit of its kinematics from them, judged on samples the fit did not see.
//!
//! The pipeline offers every pair it makes to the robot's [`PairReservoir`] (opt-in per robot).
//! The reservoir keeps a uniform sample of the whole stream in two fixed-size parts: time is cut
//! into blocks of `block_s` and every `holdout_every`-th block goes to the held-out part, so the
//! held-out samples are whole stretches of motion the fit never saw, not neighbours of fitted
//! rows (a 500 Hz stream's consecutive samples are nearly the same). Within each part, reservoir
//! sampling (Algorithm R with a fixed-seed generator) keeps every offered sample equally likely
//! whatever the stream's length, with memory fixed by the configuration, never by the input.
//!
//! [`fit`] runs [`identify`] on a [`CalibrationBatch`] (a copy of the reservoir, taken so the
//! fit runs off the sample path) and compares the current model with the identified one on the
//! held-out part. Pure and deterministic: the same stream gives the same estimate.

use std::sync::Arc;

use nalgebra::{Quaternion, UnitQuaternion};
use thiserror::Error;

use crate::identify::{self, IdentifyError, IdentifyOptions, PairedSample, PoseErrors};
use crate::kinematics::{Pose, PoseReadout};
use crate::model::calibration::MountingDeltas;
use crate::model::{ModelError, RobotModel};
use crate::orientation;

/// The name an identified calibration carries in its model (`RobotModel::calibration`).
pub const SOURCE_NAME: &str = "self-calibration";

/// How a robot's pairs are kept for self-calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReservoirConfig {
    /// Pairs kept for fitting.
    pub train_capacity: usize,
    /// Pairs kept for judging the fit.
    pub held_out_capacity: usize,
    /// Length of the time blocks (s of source time) the stream is cut into.
    pub block_s: f64,
    /// Every this many-th block is held out (4: a quarter of the stream).
    pub holdout_every: u64,
    /// Pairs closer than this (s of source time) to the last one offered are skipped: at 500 Hz
    /// consecutive pairs add almost nothing, and skipping them costs no copy.
    pub min_spacing_s: f64,
}

impl Default for ReservoirConfig {
    fn default() -> Self {
        Self {
            train_capacity: 3000,
            held_out_capacity: 1000,
            block_s: 2.0,
            holdout_every: 4,
            min_spacing_s: 0.008,
        }
    }
}

/// A pair as kept: joint angles (rad), measured position (m) and quaternion `[qx, qy, qz, qw]`
/// in the output frame.
#[derive(Debug, Clone, Copy, PartialEq)]
struct KeptPair {
    q_rad: [f64; 6],
    position_m: [f64; 3],
    quaternion_xyzw: [f64; 4],
}

impl KeptPair {
    fn paired_sample(&self) -> PairedSample {
        let [x, y, z, w] = self.quaternion_xyzw;
        PairedSample {
            q_rad: self.q_rad,
            measured: Pose {
                position_m: self.position_m.into(),
                rotation: orientation::matrix_from_quaternion(&UnitQuaternion::new_normalize(
                    Quaternion::new(w, x, y, z),
                )),
            },
        }
    }
}

/// One part of the reservoir: Algorithm R over the pairs offered to it.
#[derive(Debug, Clone)]
struct Part {
    kept: Vec<KeptPair>,
    capacity: usize,
    seen: u64,
    rng_state: u64,
}

impl Part {
    fn new(capacity: usize, seed: u64) -> Self {
        Self {
            kept: Vec::new(),
            capacity,
            seen: 0,
            rng_state: seed,
        }
    }

    /// `SplitMix64`: small, fast and the same on every platform.
    fn next_random(&mut self) -> u64 {
        self.rng_state = self.rng_state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.rng_state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn offer(&mut self, pair: KeptPair) {
        self.seen += 1;
        if self.kept.len() < self.capacity {
            self.kept.push(pair);
            return;
        }
        // Uniform in [0, seen): the modulo's bias is below 2^-40 for any stream this sees.
        let slot = self.next_random() % self.seen;
        if let Some(kept) = usize::try_from(slot)
            .ok()
            .and_then(|slot| self.kept.get_mut(slot))
        {
            *kept = pair;
        }
    }
}

/// A robot's reservoir of paired samples for self-calibration.
#[derive(Debug, Clone)]
pub struct PairReservoir {
    config: ReservoirConfig,
    train: Part,
    held_out: Part,
    last_offered_s: Option<f64>,
    offered: u64,
}

impl PairReservoir {
    /// An empty reservoir.
    #[must_use]
    pub fn new(config: ReservoirConfig) -> Self {
        Self {
            config,
            train: Part::new(config.train_capacity, 0x5EED_0001),
            held_out: Part::new(config.held_out_capacity, 0x5EED_0002),
            last_offered_s: None,
            offered: 0,
        }
    }

    /// Offers one pair: joint angles (six; other arms are not identified) and the measured pose
    /// in the output frame, at `stamp_s`. Returns whether it was taken into account.
    pub fn offer(&mut self, stamp_s: f64, q_rad: &[f64], measured: &PoseReadout) -> bool {
        let Ok(q_rad) = <[f64; 6]>::try_from(q_rad) else {
            return false;
        };
        if !stamp_s.is_finite()
            || self
                .last_offered_s
                .is_some_and(|last_s| (stamp_s - last_s).abs() < self.config.min_spacing_s)
        {
            return false;
        }
        self.last_offered_s = Some(stamp_s);
        self.offered += 1;
        let pair = KeptPair {
            q_rad,
            position_m: measured.position_m,
            quaternion_xyzw: measured.quaternion_xyzw,
        };
        #[allow(
            clippy::cast_possible_truncation,
            reason = "a saturating cast: stamps beyond i64 blocks are not source times"
        )]
        let block = (stamp_s / self.config.block_s).floor() as i64;
        let every = i64::try_from(self.config.holdout_every.max(2)).unwrap_or(i64::MAX);
        if block.rem_euclid(every) == every - 1 {
            self.held_out.offer(pair);
        } else {
            self.train.offer(pair);
        }
        true
    }

    /// Pairs taken into account so far (kept or not).
    #[must_use]
    pub fn offered(&self) -> u64 {
        self.offered
    }

    /// Pairs kept for fitting and for judging.
    #[must_use]
    pub fn kept(&self) -> (usize, usize) {
        (self.train.kept.len(), self.held_out.kept.len())
    }

    /// A copy of what is kept, for a fit off the sample path.
    #[must_use]
    pub fn batch(&self) -> CalibrationBatch {
        CalibrationBatch {
            train: self
                .train
                .kept
                .iter()
                .map(KeptPair::paired_sample)
                .collect(),
            held_out: self
                .held_out
                .kept
                .iter()
                .map(KeptPair::paired_sample)
                .collect(),
            offered: self.offered,
        }
    }
}

/// The samples one fit uses.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationBatch {
    /// Pairs to fit.
    pub train: Vec<PairedSample>,
    /// Pairs to judge the fit on (other time blocks).
    pub held_out: Vec<PairedSample>,
    /// Pairs the reservoir had taken into account when the batch was made.
    pub offered: u64,
}

/// Why a fit gave no estimate.
#[derive(Debug, Error)]
pub enum FitError {
    /// Identification refused the samples (too few, too little motion, not a UR arm).
    #[error(transparent)]
    Identify(#[from] IdentifyError),
    /// Too few held-out pairs to judge a fit.
    #[error("{got} held-out pairs, at least {need} needed to judge a fit")]
    TooFewHeldOut {
        /// Held-out pairs there are.
        got: usize,
        /// At least this many.
        need: usize,
    },
    /// The identified parameters do not make a model.
    #[error("the identified parameters do not make a model: {0}")]
    Model(#[from] ModelError),
}

/// Held-out pairs a fit needs at least before it is judged.
pub const MIN_HELD_OUT: usize = 50;

/// A fitted estimate, judged on the held-out pairs.
#[derive(Debug, Clone)]
pub struct Estimate {
    /// The fit itself (deltas, tool, parameters, excitation).
    pub identification: identify::Identification,
    /// The model the estimate would make current.
    pub model: Arc<RobotModel>,
    /// The current model's errors on the held-out pairs.
    pub held_out_current: PoseErrors,
    /// The identified model's errors on the held-out pairs.
    pub held_out_identified: PoseErrors,
    /// Pairs fitted.
    pub train_pairs: usize,
    /// Pairs the reservoir had taken into account.
    pub offered: u64,
}

impl Estimate {
    /// Current over identified held-out position MAE (above 1: the estimate is better).
    #[must_use]
    pub fn improvement(&self) -> f64 {
        self.held_out_current.position_mae_m / self.held_out_identified.position_mae_m
    }

    /// The identified deltas.
    #[must_use]
    pub fn deltas(&self) -> &MountingDeltas {
        &self.identification.deltas
    }
}

/// Fits `current`'s arm to `batch` (its frame and tool as the start; the tool fitted with
/// [`IdentifyOptions::fit_tool`]) and judges the result against `current` on the held-out pairs.
pub fn fit(
    current: &RobotModel,
    batch: &CalibrationBatch,
    options: &IdentifyOptions,
) -> Result<Estimate, FitError> {
    if batch.held_out.len() < MIN_HELD_OUT {
        return Err(FitError::TooFewHeldOut {
            got: batch.held_out.len(),
            need: MIN_HELD_OUT,
        });
    }
    let identification = identify::identify(
        current.arm(),
        current.frame(),
        current.tool(),
        &batch.train,
        options,
    )?;
    let model = current.with_deltas(identification.deltas, identification.tool, SOURCE_NAME)?;
    Ok(Estimate {
        held_out_current: identify::pose_errors(current, &batch.held_out),
        held_out_identified: identify::pose_errors(&model, &batch.held_out),
        model: Arc::new(model),
        identification,
        train_pairs: batch.train.len(),
        offered: batch.offered,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn readout(x: f64) -> PoseReadout {
        PoseReadout::from_position_quaternion([x, 0.0, 0.0], &UnitQuaternion::identity())
    }

    #[test]
    fn memory_is_bounded_by_the_configuration_and_blocks_split_train_from_held_out() {
        let config = ReservoirConfig {
            train_capacity: 30,
            held_out_capacity: 10,
            block_s: 1.0,
            holdout_every: 4,
            min_spacing_s: 0.0,
        };
        let mut reservoir = PairReservoir::new(config);
        for i in 0..4000_u32 {
            let stamp_s = f64::from(i) * 0.01;
            assert!(reservoir.offer(stamp_s, &[stamp_s; 6], &readout(stamp_s)));
        }
        assert_eq!(reservoir.offered(), 4000);
        assert_eq!(reservoir.kept(), (30, 10));
        let batch = reservoir.batch();
        let block = |s: &PairedSample| (s.q_rad[0] + 1e-9).floor() as i64;
        assert!(batch.held_out.iter().all(|s| block(s) % 4 == 3));
        assert!(batch.train.iter().all(|s| block(s) % 4 != 3));
        // A uniform sample of 40 s spreads over it, not only over its start.
        assert!(batch.train.iter().any(|s| s.q_rad[0] > 30.0));
        assert!(batch.train.iter().any(|s| s.q_rad[0] < 10.0));
    }

    #[test]
    fn close_pairs_and_other_arms_are_skipped() {
        let mut reservoir = PairReservoir::new(ReservoirConfig::default());
        assert!(reservoir.offer(0.0, &[0.0; 6], &readout(0.0)));
        assert!(!reservoir.offer(0.002, &[0.0; 6], &readout(0.0)));
        assert!(!reservoir.offer(1.0, &[0.0; 7], &readout(0.0)));
        assert!(!reservoir.offer(f64::NAN, &[0.0; 6], &readout(0.0)));
        assert!(reservoir.offer(1.0, &[0.0; 6], &readout(0.0)));
        assert_eq!(reservoir.offered(), 2);
    }

    #[test]
    fn the_same_stream_keeps_the_same_pairs() {
        let run = || {
            let mut reservoir = PairReservoir::new(ReservoirConfig {
                train_capacity: 5,
                ..ReservoirConfig::default()
            });
            for i in 0..1000_u32 {
                let stamp_s = f64::from(i) * 0.01;
                reservoir.offer(stamp_s, &[stamp_s; 6], &readout(stamp_s));
            }
            reservoir.batch()
        };
        assert_eq!(run(), run());
    }
}
