//! What the receive callbacks share with the sender: reply counts, the arrival of the newest
//! reply and, while a trial records them, the twin poses' latencies from the stamps they carry
//! back. Runs on Zenoh's callback threads: counts and records, never blocks.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, OnceLock, PoisonError};
use std::time::Instant;

use serde::Deserialize;
use zenoh::sample::Sample;

use super::Counts;
use super::churn;
use armtwin_codec::zser;

/// What the receive callbacks share with the sender.
#[derive(Debug)]
pub(super) struct Replies {
    pub(super) start: Instant,
    /// Seconds from the clock origin to `start`.
    pub(super) start_s: f64,
    pub(super) poses: AtomicU64,
    pub(super) deviations: AtomicU64,
    pub(super) metrics: AtomicU64,
    pub(super) events: AtomicU64,
    /// Arrival of the newest pose or deviation (ns since `start`).
    pub(super) last_ns: AtomicU64,
    /// Whether twin poses' latencies are being recorded.
    pub(super) recording: AtomicBool,
    pub(super) latencies_ns: Mutex<Vec<u64>>,
    /// Replies are binary: the stamp is the first 8 bytes.
    pub(super) binary: bool,
    /// Every reply on the paired stream stands for a pose and its deviation (the echo's), rather
    /// than only those that carry a deviation (armtwin's).
    pub(super) paired_always_deviation: bool,
    /// The pose key whose latencies are not recorded (the slow subscriber's robot).
    pub(super) untimed_key: Option<String>,
    /// Poses the slow subscriber received.
    pub(super) slow_poses: AtomicU64,
    /// The soak's per-interval tally of poses, set when the soak starts.
    pub(super) soak: OnceLock<churn::Tally>,
}

/// What a subscriber does with a reply.
pub(super) type OnReply = fn(&Replies, &Sample);

/// The stamp of a reply.
#[derive(Deserialize)]
struct Stamp {
    t: f64,
}

impl Replies {
    pub(super) fn elapsed_ns(&self) -> u64 {
        self.start.elapsed().as_nanos() as u64
    }

    /// Now, in seconds since the clock origin: the stamp of a sample sent now.
    pub(super) fn now_s(&self) -> f64 {
        self.start_s + self.start.elapsed().as_secs_f64()
    }

    pub(super) fn counts(&self) -> Counts {
        Counts {
            poses: self.poses.load(Ordering::Acquire),
            deviations: self.deviations.load(Ordering::Acquire),
            metrics: self.metrics.load(Ordering::Relaxed),
            events: self.events.load(Ordering::Relaxed),
        }
    }

    /// The stamp a reply carries back.
    pub(super) fn stamp_of(&self, sample: &Sample) -> Option<f64> {
        let payload = sample.payload().to_bytes();
        if self.binary {
            payload.get(..8)?.try_into().ok().map(f64::from_le_bytes)
        } else {
            serde_json::from_slice::<Stamp>(&payload).ok().map(|s| s.t)
        }
    }

    pub(super) fn pose(&self, sample: &Sample) {
        let now_ns = self.elapsed_ns();
        let timed = self
            .untimed_key
            .as_deref()
            .is_none_or(|key| sample.key_expr().as_str() != key);
        let recording = self.recording.load(Ordering::Relaxed);
        let soak = self.soak.get();
        if timed
            && (recording || soak.is_some())
            && let Some(stamp_s) = self.stamp_of(sample)
        {
            let latency_s = self.start_s + now_ns as f64 / 1e9 - stamp_s;
            let latency_ns = (latency_s * 1e9).max(0.0) as u64;
            if let Some(tally) = soak {
                tally.record(stamp_s, latency_ns);
            }
            if recording {
                self.latencies_ns
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .push(latency_ns);
            }
        }
        self.last_ns.fetch_max(now_ns, Ordering::AcqRel);
        self.poses.fetch_add(1, Ordering::Release);
    }

    /// A reply on the paired stream: a pose, and its deviation if it carries one.
    pub(super) fn paired(&self, sample: &Sample) {
        let deviation = self.paired_always_deviation || {
            let payload = sample.payload().to_bytes();
            if self.binary {
                payload.len() == zser::PAIRED_BYTES
            } else {
                carries_dx(&payload)
            }
        };
        self.pose(sample);
        if deviation {
            self.deviation();
        }
    }

    pub(super) fn deviation(&self) {
        self.last_ns.fetch_max(self.elapsed_ns(), Ordering::AcqRel);
        self.deviations.fetch_add(1, Ordering::Release);
    }
}

/// Whether a JSON paired message carries a deviation (its `dx` field).
fn carries_dx(payload: &[u8]) -> bool {
    payload.windows(5).any(|window| window == b"\"dx\":")
}
