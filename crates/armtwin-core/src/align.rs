//! Time alignment of measured poses with joint samples: a bounded history of recent joint samples
//! (stamps and angles; their twin poses are recomputed when needed, which costs less than keeping
//! 80 bytes per sample) and a bounded queue of measured poses waiting for a later joint sample.
//!
//! Owns where a measured stamp falls among the joint stamps — exactly on one, between two (to be
//! interpolated), or nowhere usable — and when a waiting measurement gives up. It computes no
//! kinematics and knows no robots: the pipeline evaluates the pose it is pointed to.
//!
//! Rules (all in source time, so offline and live runs decide alike):
//! - a measured pose at `t` pairs with the joint sample stamped exactly `t`, else with the joint
//!   angles interpolated linearly between the two samples around `t`, provided they are at most
//!   `max_gap_s` apart;
//! - one newer than every joint sample (or arriving before any) waits for the next joint sample;
//!   it gives up (unpaired)
//!   when a measured pose more than `max_wait_s` newer arrives, when more than `max_pending`
//!   wait, or when the stream ends;
//! - one older than the kept history (`history_s`, at most `max_history` samples) is unpaired.

use std::collections::VecDeque;

/// Alignment limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlignConfig {
    /// Largest spacing (s) of two joint samples that a measured pose may be interpolated between.
    pub max_gap_s: f64,
    /// How much newer (s) a later measured pose may be before a waiting one gives up.
    pub max_wait_s: f64,
    /// Joint history kept (s of source time behind the newest joint sample).
    pub history_s: f64,
    /// Most joint samples kept, whatever their spacing (bounds memory).
    pub max_history: usize,
    /// Most measured poses waiting at once (bounds memory).
    pub max_pending: usize,
    /// A stamp this much (s) behind its stream's previous one is taken as the gateway restarting
    /// its clock (alignment and the metrics window start afresh), not as an out-of-order sample.
    pub restart_s: f64,
}

impl Default for AlignConfig {
    fn default() -> Self {
        Self {
            max_gap_s: 0.25,
            max_wait_s: 0.5,
            history_s: 2.0,
            max_history: 64,
            max_pending: 1024,
            restart_s: 5.0,
        }
    }
}

/// Where a measured stamp falls in the joint history.
#[derive(Debug, Clone, PartialEq)]
pub enum Bracket<'a> {
    /// A joint sample has exactly this stamp: the twin pose at its joint angles (rad) applies.
    Exact(&'a [f64]),
    /// Between two joint samples: interpolate `q = q0 + fraction · (q1 − q0)`.
    Between {
        /// Joint angles (rad) before.
        q0: &'a [f64],
        /// Joint angles (rad) after.
        q1: &'a [f64],
        /// Position of the stamp between them, in (0, 1).
        fraction: f64,
    },
    /// Newer than every joint sample: must wait.
    Later,
    /// Cannot be paired.
    Unpaired(UnpairedReason),
}

/// Why a measured pose could not be paired.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum UnpairedReason {
    /// Older than the oldest joint sample kept.
    BeforeHistory {
        /// The oldest joint stamp kept (s).
        oldest_joint_s: f64,
    },
    /// The joint samples around it are too far apart.
    JointGap {
        /// Their spacing (s).
        gap_s: f64,
    },
    /// It waited for a later joint sample until a measured pose `max_wait_s` newer arrived.
    WaitExpired,
    /// Too many measured poses were waiting; the oldest gave up.
    PendingOverflow,
    /// The stream ended (shutdown or end of file) while it waited.
    StreamEnded,
}

impl UnpairedReason {
    /// Stable snake-case name, used in events.
    #[must_use]
    pub fn kind(&self) -> &'static str {
        match self {
            Self::BeforeHistory { .. } => "before_joint_history",
            Self::JointGap { .. } => "joint_gap",
            Self::WaitExpired => "wait_expired",
            Self::PendingOverflow => "pending_overflow",
            Self::StreamEnded => "stream_ended",
        }
    }

    /// A sentence for the event's reason.
    #[must_use]
    pub fn describe(&self, config: &AlignConfig) -> String {
        match self {
            Self::BeforeHistory { oldest_joint_s } => {
                format!(
                    "older than the joint history (oldest joint sample at t = {oldest_joint_s} s)"
                )
            }
            Self::JointGap { gap_s } => format!(
                "the joint samples around it are {gap_s} s apart (max_gap_s = {})",
                config.max_gap_s
            ),
            Self::WaitExpired => format!(
                "no joint sample at or after it arrived before a measured pose {} s newer",
                config.max_wait_s
            ),
            Self::PendingOverflow => format!(
                "more than {} measured poses were waiting for joint samples",
                config.max_pending
            ),
            Self::StreamEnded => "the stream ended before a joint sample at or after it".to_owned(),
        }
    }
}

/// A measured pose waiting for a joint sample at or after its stamp.
#[derive(Debug, Clone, PartialEq)]
pub struct Pending<T> {
    /// Source time (s).
    pub stamp_s: f64,
    /// Whatever the caller keeps with it (the pose, its key).
    pub item: T,
}

/// The joint history and the waiting measured poses of one robot.
#[derive(Debug, Clone)]
pub struct Aligner<T> {
    config: AlignConfig,
    stamps_s: VecDeque<f64>,
    /// Joint angles of every kept sample, oldest first.
    angles_rad: AngleRing,
    pending: VecDeque<Pending<T>>,
}

/// Joint angles of a run of samples, oldest first, in one buffer of fixed-size slots (one per
/// sample, never split at the buffer's end): no allocation per sample and no per-sample header,
/// unlike a ring of `Vec`s (24 bytes and an allocation each).
#[derive(Debug, Clone, Default)]
struct AngleRing {
    /// `slots · joint_count` angles (rad).
    values_rad: Vec<f64>,
    /// Angles per sample, set by the first sample (the caller keeps it constant).
    joint_count: usize,
    slots: usize,
    /// Slot of the oldest sample.
    head: usize,
    len: usize,
}

impl AngleRing {
    /// The `index`-th oldest sample's angles (rad); `index < len`.
    fn get(&self, index: usize) -> &[f64] {
        let start = (self.head + index) % self.slots * self.joint_count;
        &self.values_rad[start..start + self.joint_count]
    }

    /// Appends a sample's angles, growing by doubling, up to `most_slots`, when every slot is
    /// taken. Angles beyond the first sample's count are dropped and missing ones read as 0
    /// (callers check the count).
    fn push_back(&mut self, q_rad: &[f64], most_slots: usize) {
        if self.len == 0 {
            self.joint_count = q_rad.len();
            self.head = 0;
        }
        if self.len == self.slots || self.values_rad.len() != self.slots * self.joint_count {
            self.grow(most_slots);
        }
        let start = (self.head + self.len) % self.slots * self.joint_count;
        let slot = &mut self.values_rad[start..start + self.joint_count];
        slot.fill(0.0);
        for (angle, &q) in slot.iter_mut().zip(q_rad) {
            *angle = q;
        }
        self.len += 1;
    }

    /// Room for at least one more sample (and slots of the current joint count), oldest first:
    /// twice the slots, but no more than `most_slots` unless the samples held need them.
    #[cold]
    fn grow(&mut self, most_slots: usize) {
        let slots = (2 * self.slots).max(4).min(most_slots).max(self.len + 1);
        let mut values_rad = Vec::with_capacity(slots * self.joint_count);
        for index in 0..self.len {
            values_rad.extend_from_slice(self.get(index));
        }
        values_rad.resize(slots * self.joint_count, 0.0);
        *self = Self {
            values_rad,
            joint_count: self.joint_count,
            slots,
            head: 0,
            len: self.len,
        };
    }

    fn pop_front(&mut self) {
        if self.len > 0 {
            self.head = (self.head + 1) % self.slots;
            self.len -= 1;
        }
    }
}

impl<T> Aligner<T> {
    /// An empty aligner; the arm's joint count is taken from the first joint sample.
    #[must_use]
    pub fn new(config: AlignConfig) -> Self {
        Self {
            config,
            stamps_s: VecDeque::new(),
            angles_rad: AngleRing::default(),
            pending: VecDeque::new(),
        }
    }

    /// The limits in force.
    #[must_use]
    pub fn config(&self) -> &AlignConfig {
        &self.config
    }

    /// Stamp of the newest joint sample, if any.
    #[must_use]
    pub fn newest_joint_s(&self) -> Option<f64> {
        self.stamps_s.back().copied()
    }

    /// Number of measured poses waiting.
    #[must_use]
    pub fn pending_len(&self) -> usize {
        self.pending.len()
    }

    /// Records a joint sample's stamp and angles (stamps must increase; the caller enforces it),
    /// dropping history older than `history_s` or beyond `max_history`.
    pub fn push_joints(&mut self, stamp_s: f64, q_rad: &[f64]) {
        // Room first, so the buffers never hold more than `max_history` samples (at least two).
        let most = self.config.max_history.max(2);
        while self.stamps_s.len() >= most {
            self.stamps_s.pop_front();
            self.angles_rad.pop_front();
        }
        self.stamps_s.push_back(stamp_s);
        self.angles_rad.push_back(q_rad, most);
        // Keep at least the two newest samples, so a measured pose between them can pair.
        while let Some(&oldest) = self.stamps_s.front() {
            let too_old = oldest < stamp_s - self.config.history_s;
            let too_many = self.stamps_s.len() > self.config.max_history;
            if !(too_old || too_many) || self.stamps_s.len() <= 2 {
                break;
            }
            self.stamps_s.pop_front();
            self.angles_rad.pop_front();
        }
    }

    /// Where `stamp_s` falls in the joint history.
    #[must_use]
    pub fn bracket(&self, stamp_s: f64) -> Bracket<'_> {
        let (Some(&oldest), Some(&newest)) = (self.stamps_s.front(), self.stamps_s.back()) else {
            // No joint sample yet (or since a restart): wait for one, like any newer pose.
            return Bracket::Later;
        };
        if stamp_s > newest {
            return Bracket::Later;
        }
        if stamp_s < oldest {
            return Bracket::Unpaired(UnpairedReason::BeforeHistory {
                oldest_joint_s: oldest,
            });
        }
        // First joint sample at or after the stamp: the newest one for nearly every measured
        // pose (its own joint sample, or just before it), so looked at first; a search of the
        // history would read a cache line per step.
        let len = self.stamps_s.len();
        let after = if len < 2 || stamp_s > self.stamps_s[len - 2] {
            len - 1
        } else {
            self.stamps_s.partition_point(|&s| s < stamp_s)
        };
        #[allow(
            clippy::float_cmp,
            reason = "an exact stamp match is the defined pairing"
        )]
        if self.stamps_s[after] == stamp_s {
            return Bracket::Exact(self.angles_rad.get(after));
        }
        let before = after - 1;
        let (t0, t1) = (self.stamps_s[before], self.stamps_s[after]);
        if t1 - t0 > self.config.max_gap_s {
            return Bracket::Unpaired(UnpairedReason::JointGap { gap_s: t1 - t0 });
        }
        Bracket::Between {
            q0: self.angles_rad.get(before),
            q1: self.angles_rad.get(after),
            fraction: (stamp_s - t0) / (t1 - t0),
        }
    }

    /// Queues a measured pose newer than every joint sample. Returns the poses that gave up to
    /// make room or because this one is more than `max_wait_s` newer.
    pub fn wait(&mut self, stamp_s: f64, item: T) -> Vec<(Pending<T>, UnpairedReason)> {
        let mut given_up = self.expire(stamp_s - self.config.max_wait_s);
        // Streams of one robot (controller, sensors) have their own stamps: keep the queue sorted.
        let position = self.pending.partition_point(|p| p.stamp_s <= stamp_s);
        self.pending.insert(position, Pending { stamp_s, item });
        while self.pending.len() > self.config.max_pending {
            if let Some(oldest) = self.pending.pop_front() {
                given_up.push((oldest, UnpairedReason::PendingOverflow));
            }
        }
        given_up
    }

    /// Measured poses now bracketed by the newest joint sample (stamp at or before it), oldest
    /// first, for the caller to pair with [`Self::bracket`].
    pub fn take_ready(&mut self) -> Vec<Pending<T>> {
        let Some(newest) = self.newest_joint_s() else {
            return Vec::new();
        };
        let ready = self.pending.partition_point(|p| p.stamp_s <= newest);
        self.pending.drain(..ready).collect()
    }

    /// Every waiting measured pose older than `stamp_s` gives up.
    pub fn expire(&mut self, stamp_s: f64) -> Vec<(Pending<T>, UnpairedReason)> {
        let expired = self.pending.partition_point(|p| p.stamp_s < stamp_s);
        self.pending
            .drain(..expired)
            .map(|p| (p, UnpairedReason::WaitExpired))
            .collect()
    }

    /// Every waiting measured pose gives up: the stream ended.
    pub fn finish(&mut self) -> Vec<(Pending<T>, UnpairedReason)> {
        self.pending
            .drain(..)
            .map(|p| (p, UnpairedReason::StreamEnded))
            .collect()
    }
}

/// Linear interpolation of joint angles: `q0 + fraction · (q1 − q0)`, into `out`.
pub fn interpolate(q0: &[f64], q1: &[f64], fraction: f64, out: &mut Vec<f64>) {
    out.clear();
    out.extend(q0.iter().zip(q1).map(|(a, b)| a + fraction * (b - a)));
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "angles are stored, not computed")]
mod tests {
    use super::*;

    fn angles(sample: u32) -> [f64; 6] {
        std::array::from_fn(|joint| f64::from(sample) + joint as f64 / 10.0)
    }

    #[test]
    fn angle_ring_keeps_samples_in_order_across_wrap_and_growth() {
        let mut ring = AngleRing::default();
        let (mut oldest, mut next) = (0, 0);
        // Uneven pushes and pops: the head wraps round while the ring grows to 16 slots.
        for round in 0..40u32 {
            for _ in 0..=(round % 4) {
                ring.push_back(&angles(next), usize::MAX);
                next += 1;
            }
            for _ in 0..(round % 3) {
                ring.pop_front();
                oldest += 1;
            }
            assert_eq!(ring.len, (next - oldest) as usize);
            for (index, sample) in (oldest..next).enumerate() {
                assert_eq!(ring.get(index), angles(sample));
            }
        }
        assert!(ring.slots >= ring.len && ring.slots.is_power_of_two());
    }

    #[test]
    fn the_joint_history_holds_max_history_samples_and_no_more_slots() {
        for most in [64, 100] {
            let mut aligner: Aligner<()> = Aligner::new(AlignConfig {
                max_history: most,
                history_s: 1e9,
                ..AlignConfig::default()
            });
            for sample in 0..5_000_u32 {
                aligner.push_joints(f64::from(sample) * 0.002, &angles(sample));
            }
            assert_eq!(aligner.stamps_s.len(), most);
            assert_eq!(
                (aligner.angles_rad.len, aligner.angles_rad.slots),
                (most, most)
            );
            assert_eq!(aligner.angles_rad.get(0), angles(5_000 - most as u32));
            assert!(matches!(
                aligner.bracket(4_999.0 * 0.002),
                Bracket::Exact(_)
            ));
        }
    }

    #[test]
    fn aligner_interpolates_between_stored_angles() {
        let mut aligner = Aligner::<()>::new(AlignConfig::default());
        for i in 0..300 {
            let t = f64::from(i) * 0.01;
            aligner.push_joints(t, &angles(i));
        }
        // 2 s of history at 100 Hz are kept, so the ring never holds more than 256 slots.
        assert!(
            aligner.angles_rad.slots <= 256,
            "{}",
            aligner.angles_rad.slots
        );
        let Bracket::Between { q0, q1, fraction } = aligner.bracket(2.905) else {
            panic!("between two joint samples");
        };
        assert_eq!((q0, q1), (&angles(290)[..], &angles(291)[..]));
        assert!((fraction - 0.5).abs() < 1e-9);
    }
}
