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

/// One second (or minute): `{t, n, position, angle}`.
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

/// A robot's history: `{robot, t, history_s, seconds_s, seconds: [{t, n, position, angle}, …],
/// minutes: […]}`, each list oldest first, the rows without pairs left out.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HistoryMessage {
    /// Robot id.
    pub robot: String,
    /// The robot's newest source time (s), which `now()` in a time range stands for; `null`
    /// before its first accepted sample.
    pub t: Option<f64>,
    /// The seconds the robot's history covers (`[recorder] history_s`).
    pub history_s: usize,
    /// The newest of them it keeps one by one; the rest of `history_s` by the minute.
    pub seconds_s: usize,
    /// The completed seconds asked for.
    pub seconds: Vec<SecondJson>,
    /// The completed minutes asked for, each `t` its first second: the merge of its seconds,
    /// kept or not.
    pub minutes: Vec<SecondJson>,
}

impl HistoryMessage {
    /// The answer of `robot` from its rows of seconds and of minutes.
    #[must_use]
    pub fn new(robot: &str, newest_s: Option<f64>, spans: HistorySpans, rows: HistoryRows) -> Self {
        Self {
            robot: robot.to_owned(),
            t: newest_s,
            history_s: spans.history_s,
            seconds_s: spans.seconds_s,
            seconds: rows.seconds.iter().map(SecondJson::from).collect(),
            minutes: rows.minutes.iter().map(SecondJson::from).collect(),
        }
    }
}

/// What a robot's history covers: `history_s` seconds, the newest `seconds_s` one by one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HistorySpans {
    /// The seconds covered.
    pub history_s: usize,
    /// The newest of them kept one by one.
    pub seconds_s: usize,
}

/// The rows of a history answer.
#[derive(Debug, Clone, Copy)]
pub struct HistoryRows<'a> {
    /// Seconds, oldest first.
    pub seconds: &'a [HistoryRow],
    /// Minutes, oldest first.
    pub minutes: &'a [HistoryRow],
}
