//! The load's report: the reply counts, each trial, the latency run, the throughput search and
//! the memory measurement, and the whole report printed as one JSON object. Types only; the
//! measuring is in `trials` and `memory`.

use serde::{Deserialize, Serialize};

use super::{Soak, Target};

/// Reply counts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Counts {
    /// Twin poses (echo: republished joint samples).
    pub poses: u64,
    /// Deviations (echo: republished measured poses).
    pub deviations: u64,
    /// Metrics messages (armtwin).
    pub metrics: u64,
    /// Events (armtwin; none expected).
    pub events: u64,
}

impl Counts {
    pub(super) fn since(self, base: Self) -> Self {
        Self {
            poses: self.poses - base.poses,
            deviations: self.deviations - base.deviations,
            metrics: self.metrics - base.metrics,
            events: self.events - base.events,
        }
    }
}

/// One run at a fixed rate.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Trial {
    /// Samples per second offered (each sample: one joint and one measured message).
    pub offered_rate: f64,
    /// Samples sent (fewer than the schedule's when the system fell more than the trial's
    /// duration, at least a second, behind it and the trial was abandoned).
    pub samples: u64,
    /// Seconds the schedule lasts.
    pub duration_s: f64,
    /// Seconds sending took (more than `duration_s`: the load could not keep the schedule).
    pub send_s: f64,
    /// Seconds from the first send to the last expected reply, if they all arrived in time.
    pub complete_s: Option<f64>,
    /// Replies counted (after the settle time for an incomplete trial).
    pub replies: Counts,
    /// Expected poses and deviations that never arrived.
    pub lost: u64,
    /// `samples / complete_s`.
    pub achieved_rate: Option<f64>,
    /// Poses received / seconds from the first send to the last reply (after the settle time
    /// for an incomplete trial): what came through even when the trial was not sustained.
    pub delivered_rate: Option<f64>,
    /// CPU seconds the system under test used during the trial.
    pub sut_cpu_s: Option<f64>,
    /// Every reply arrived, within the tolerance of the schedule.
    pub sustained: bool,
}

/// Latency of the twin poses at a fixed rate (µs, nearest rank).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Latency {
    /// The run.
    pub trial: Trial,
    /// Poses timed.
    pub count: usize,
    /// Median.
    pub p50_us: f64,
    /// 99th percentile.
    pub p99_us: f64,
    /// 99.9th percentile.
    pub p999_us: f64,
    /// Largest.
    pub max_us: f64,
}

/// The throughput search.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Search {
    /// Highest offered rate sustained (samples per second; 0: none).
    pub max_sustained_rate: f64,
    /// Every trial, in order.
    pub trials: Vec<Trial>,
}

/// Resident memory of the system under test.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Memory {
    /// Robots tracked at the baseline.
    pub base_robots: usize,
    /// Robots tracked at the end.
    pub robots: usize,
    /// Samples each robot sent.
    pub samples_per_robot: u64,
    /// Source rate the samples after each robot's first were stamped at, streamed as fast as
    /// they were answered (null: a few samples in rounds, stamped as sent).
    pub stream_hz: Option<f64>,
    /// RSS before any sample (KiB).
    pub rss_start_kib: u64,
    /// RSS with `base_robots` tracked (KiB).
    pub rss_base_kib: u64,
    /// RSS with `robots` tracked (KiB).
    pub rss_full_kib: u64,
    /// `(rss_full − rss_base) / (robots − base_robots)`, bytes.
    pub bytes_per_robot: f64,
    /// armtwin: seconds from the first sample to the robots new after the baseline until every
    /// robot's liveliness token was visible (their first samples answered, then their tokens).
    pub declare_s: Option<f64>,
    /// Streamed samples (`stream_hz`) of the robots new after the baseline per second, from the
    /// first sent until the last answered: how fast the system under test fills a fleet's
    /// windows (null: samples in rounds).
    pub fill_samples_per_s: Option<f64>,
}

/// Everything a load run measured: its standard output.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LoadReport {
    /// The system under test.
    pub target: Target,
    /// Robots.
    pub robots: usize,
    /// Seconds until every robot's first sample was answered.
    pub warmup_s: f64,
    /// armtwin: seconds from the end of the warm-up until every robot's liveliness token was
    /// visible, i.e. armtwin tracked every robot.
    pub tracking_s: Option<f64>,
    /// The latency run.
    pub latency: Option<Latency>,
    /// The throughput search.
    pub search: Option<Search>,
    /// The check at a fixed rate.
    pub check: Option<Trial>,
    /// The memory measurement.
    pub memory: Option<Memory>,
    /// The first-contact trial.
    pub first_contact: Option<Trial>,
    /// `--await-tokens`: Unix time (s) when every robot's token was visible.
    pub tokens_unix_s: Option<f64>,
    /// Sessions the robots were split over.
    pub gateways: u16,
    /// Replies over the whole run.
    pub totals: Counts,
    /// Poses the slow subscriber received (`--slow-subscriber-ms`), of `totals.poses / robots`
    /// or so sent to it: the difference was dropped for it.
    pub slow_subscriber_poses: Option<u64>,
    /// The soak (`--soak-duration`).
    pub soak: Option<Soak>,
}
