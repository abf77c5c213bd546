//! The history answer (`<prefix>/history/<robot>`): a robot's per-second window statistics.
//!
//! Owns the answer's JSON field set. Must not choose the seconds: the service does.

use armtwin_core::metrics::{HISTORY_METRICS, HistoryRow, Metric};

// `HistoryRow::stats` is in this order.
const _: () = assert!(
    matches!(HISTORY_METRICS, [Metric::Position, Metric::Angle]),
    "the history keeps position, then angle"
);
use serde::Serialize;

use super::StatsJson;

/// One second: `{t, n, position, angle}`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SecondJson {
    /// The second (source time, s): its row holds the window slices starting in `[t, t + 1)`.
    pub t: i64,
    /// Pairs in it.
    pub n: u64,
    /// Position deviation (m): mean, RMS, maximum.
    pub position: StatsJson,
    /// Rotation angle (rad): mean, RMS, maximum.
    pub angle: StatsJson,
}

impl From<&HistoryRow> for SecondJson {
    fn from(row: &HistoryRow) -> Self {
        let [position, angle] = row.stats();
        Self {
            t: row.second,
            n: row.totals.n,
            position: StatsJson::from(&position),
            angle: StatsJson::from(&angle),
        }
    }
}

/// A robot's history: `{robot, t, history_s, seconds: [{t, n, position, angle}, …]}`, oldest
/// first, the seconds without pairs left out.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HistoryMessage {
    /// Robot id.
    pub robot: String,
    /// The robot's newest source time (s), which `now()` in a time range stands for; `null`
    /// before its first accepted sample.
    pub t: Option<f64>,
    /// The seconds the robot keeps (`[recorder] history_s`).
    pub history_s: usize,
    /// The completed seconds asked for.
    pub seconds: Vec<SecondJson>,
}

impl HistoryMessage {
    /// The answer of `robot` from its `rows`.
    #[must_use]
    pub fn new(robot: &str, newest_s: Option<f64>, history_s: usize, rows: &[HistoryRow]) -> Self {
        Self {
            robot: robot.to_owned(),
            t: newest_s,
            history_s,
            seconds: rows.iter().map(SecondJson::from).collect(),
        }
    }
}
