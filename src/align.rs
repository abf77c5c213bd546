//! Time alignment of measured poses with joint samples: a bounded history of recent joint samples
//! (with their twin poses) and a bounded queue of measured poses waiting for a later joint sample.
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

use crate::kinematics::PoseReadout;

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
            max_history: 4096,
            max_pending: 1024,
            restart_s: 5.0,
        }
    }
}

/// Where a measured stamp falls in the joint history.
#[derive(Debug, Clone, PartialEq)]
pub enum Bracket<'a> {
    /// A joint sample has exactly this stamp: its twin pose applies.
    Exact(&'a PoseReadout),
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
    angles_rad: VecDeque<Vec<f64>>,
    twins: VecDeque<PoseReadout>,
    /// Angle buffers of dropped samples, reused so that steady state allocates nothing.
    spare: Vec<Vec<f64>>,
    pending: VecDeque<Pending<T>>,
}

impl<T> Aligner<T> {
    /// An empty aligner for an arm of `joint_count` joints.
    #[must_use]
    pub fn new(config: AlignConfig) -> Self {
        Self {
            config,
            stamps_s: VecDeque::new(),
            angles_rad: VecDeque::new(),
            twins: VecDeque::new(),
            spare: Vec::new(),
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

    /// Records a joint sample (stamps must increase; the caller enforces it) and its twin pose,
    /// dropping history older than `history_s` or beyond `max_history`.
    pub fn push_joints(&mut self, stamp_s: f64, q_rad: &[f64], twin: PoseReadout) {
        let mut angles = self.spare.pop().unwrap_or_default();
        angles.clear();
        angles.extend_from_slice(q_rad);
        self.stamps_s.push_back(stamp_s);
        self.angles_rad.push_back(angles);
        self.twins.push_back(twin);
        // Keep at least the two newest samples, so a measured pose between them can pair.
        while let Some(&oldest) = self.stamps_s.front() {
            let too_old = oldest < stamp_s - self.config.history_s;
            let too_many = self.stamps_s.len() > self.config.max_history;
            if !(too_old || too_many) || self.stamps_s.len() <= 2 {
                break;
            }
            self.stamps_s.pop_front();
            self.twins.pop_front();
            if let Some(angles) = self.angles_rad.pop_front() {
                self.spare.push(angles);
            }
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
        // First joint sample at or after the stamp.
        let after = self.stamps_s.partition_point(|&s| s < stamp_s);
        #[allow(
            clippy::float_cmp,
            reason = "an exact stamp match is the defined pairing"
        )]
        if self.stamps_s[after] == stamp_s {
            return Bracket::Exact(&self.twins[after]);
        }
        let before = after - 1;
        let (t0, t1) = (self.stamps_s[before], self.stamps_s[after]);
        if t1 - t0 > self.config.max_gap_s {
            return Bracket::Unpaired(UnpairedReason::JointGap { gap_s: t1 - t0 });
        }
        Bracket::Between {
            q0: &self.angles_rad[before],
            q1: &self.angles_rad[after],
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
