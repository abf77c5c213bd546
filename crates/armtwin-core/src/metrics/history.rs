//! The history of a window: per second of source time, the count, sums, sums of squares and
//! maxima of the position and angle deviations, kept in rings of a fixed number of rows: the
//! newest seconds one by one, the rest of the span by the minute.
//!
//! Owns [`History`] (the two tiers) and [`WindowWithHistory`] (the deviation window that folds each
//! slice into the history as the slice closes). Must not keep samples, nor recompute anything
//! per sample: a second is the sum of its slices, and a slice's totals are the window's own.

use std::ops::RangeInclusive;

use thiserror::Error;

use super::stats::stats_from_sums;
use super::{METRIC_COUNT, Metric, Stats, StatsSet, WindowStats, WindowTotals, acceptable};

/// Seconds of history a robot keeps unless configured otherwise: an hour.
pub const DEFAULT_HISTORY_S: usize = 3600;

/// The metrics a history keeps, in the order of [`HistoryRow::stats`].
pub const HISTORY_METRICS: [Metric; 2] = [Metric::Position, Metric::Angle];

/// What one second holds: the totals of the [`HISTORY_METRICS`] over its pairs.
pub type SecondTotals = WindowTotals<{ HISTORY_METRICS.len() }>;

const EMPTY: SecondTotals = WindowTotals {
    n: 0,
    sums: [0.0; HISTORY_METRICS.len()],
    sums_of_squares: [0.0; HISTORY_METRICS.len()],
    maxima: [0.0; HISTORY_METRICS.len()],
};

/// One second of a [`History`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HistoryRow {
    /// The second (source time, s): the row holds the slices whose start falls in
    /// `[second, second + 1)`.
    pub second: i64,
    /// Its pairs' totals.
    pub totals: SecondTotals,
}

impl HistoryRow {
    /// Mean, RMS and maximum of each of the [`HISTORY_METRICS`]; all 0 when the row counts no
    /// pair.
    #[must_use]
    pub fn stats(&self) -> [Stats; 2] {
        stats_of(&self.totals)
    }
}

/// Mean, RMS and maximum of each of the [`HISTORY_METRICS`] from their totals.
#[must_use]
pub fn stats_of(totals: &SecondTotals) -> [Stats; 2] {
    stats_from_sums(
        totals.n,
        &totals.sums,
        &totals.sums_of_squares,
        &totals.maxima,
    )
}

/// The totals of the [`HISTORY_METRICS`] in `totals` of the nine metrics.
fn history_part(totals: &WindowTotals<METRIC_COUNT>) -> SecondTotals {
    let pick = |values: &[f64; METRIC_COUNT]| HISTORY_METRICS.map(|metric| values[metric.index()]);
    WindowTotals {
        n: totals.n,
        sums: pick(&totals.sums),
        sums_of_squares: pick(&totals.sums_of_squares),
        maxima: pick(&totals.maxima),
    }
}

/// Adds `part` to `row`.
fn merge(row: &mut SecondTotals, part: &SecondTotals) {
    row.n += part.n;
    for m in 0..HISTORY_METRICS.len() {
        row.sums[m] += part.sums[m];
        row.sums_of_squares[m] += part.sums_of_squares[m];
        row.maxima[m] = row.maxima[m].max(part.maxima[m]);
    }
}

/// Totals on a grid of whole units of source time (seconds, or minutes of 60 s): unit `u` lives
/// at `u mod len`, so the ring never grows and a unit without pairs costs nothing more than its
/// empty row.
#[derive(Debug, Clone)]
struct Ring {
    rows: Box<[SecondTotals]>,
    /// The newest unit holding anything; every row older than `len` before it is empty.
    newest: Option<i64>,
}

impl Ring {
    fn new(len: usize) -> Self {
        Self {
            rows: vec![EMPTY; len].into_boxed_slice(),
            newest: None,
        }
    }

    fn span(&self) -> i64 {
        // A ring of more than 2⁶³ rows could not be allocated.
        i64::try_from(self.rows.len()).unwrap_or(i64::MAX)
    }

    fn slot_of(&self, unit: i64) -> usize {
        ring_slot(unit, self.rows.len())
    }

    /// The row of `unit`, moving the ring on to it if it is newer than the newest; `None` if it
    /// is older than the ring keeps.
    fn row_mut(&mut self, unit: i64) -> Option<&mut SecondTotals> {
        match self.newest {
            Some(newest) if unit <= newest.saturating_sub(self.span()) => return None,
            Some(newest) if unit > newest => {
                let steps = unit.saturating_sub(newest);
                if steps >= self.span() {
                    self.rows.fill(EMPTY);
                } else {
                    for passed in newest + 1..=unit {
                        let slot = self.slot_of(passed);
                        self.rows[slot] = EMPTY;
                    }
                }
                self.newest = Some(unit);
            }
            Some(_) => {}
            None => self.newest = Some(unit),
        }
        let slot = self.slot_of(unit);
        Some(&mut self.rows[slot])
    }

    /// The units in `units` that hold pairs, oldest first, with their totals.
    fn rows(&self, units: RangeInclusive<i64>) -> impl Iterator<Item = (i64, SecondTotals)> + '_ {
        let (first, last) = match self.newest {
            Some(newest) => (
                (*units.start()).max(newest.saturating_sub(self.span()) + 1),
                (*units.end()).min(newest),
            ),
            None => (1, 0),
        };
        (first..=last).filter_map(move |unit| {
            let totals = self.rows[self.slot_of(unit)];
            (totals.n > 0).then_some((unit, totals))
        })
    }

    fn clear(&mut self) {
        self.rows.fill(EMPTY);
        self.newest = None;
    }
}

/// Seconds of source time in a row of the coarse tier.
pub const MINUTE_S: i64 = 60;

/// The seconds of one minute, second `s` at `s − 60·⌊s / 60⌋`.
pub type MinuteOfSeconds = [SecondTotals; 60];

/// Where a history keeps the seconds of its closed minutes, all but the newest minute's: in
/// memory ([`MemorySeconds`]), or where the caller chooses (the service's log on disk), so that
/// the seconds tier costs a robot one minute of rows in memory.
pub trait SecondsArchive: std::fmt::Debug + Send {
    /// Keeps `seconds`, those of `minute`, in place of what it held for that minute; it may
    /// forget minutes older than the newest [`History::archive_minutes`].
    fn keep(&mut self, minute: i64, seconds: &MinuteOfSeconds);
    /// Copies the seconds of `minute` into `seconds`; `false` when it does not hold them (never
    /// kept, forgotten, or lost), leaving `seconds` as it was.
    fn read(&self, minute: i64, seconds: &mut MinuteOfSeconds) -> bool;
    /// Forgets every minute.
    fn clear(&mut self);
}

/// Closed minutes of seconds in memory, the newest `minutes` of them: a history's archive unless
/// one is given.
#[derive(Debug)]
pub struct MemorySeconds {
    /// Minute `m` at `m mod len`, with its number.
    slots: Vec<Option<(i64, Box<MinuteOfSeconds>)>>,
}

impl MemorySeconds {
    /// An archive of `minutes` minutes (at least one).
    #[must_use]
    pub fn new(minutes: usize) -> Self {
        Self {
            slots: (0..minutes.max(1)).map(|_| None).collect(),
        }
    }

    fn slot_of(&self, minute: i64) -> usize {
        ring_slot(minute, self.slots.len())
    }
}

/// The slot of `unit` (a second, a minute) in a ring of `len` slots, unit `u` at `u mod len`:
/// in `0..len`.
///
/// # Panics
///
/// If `len` is 0.
#[must_use]
pub fn ring_slot(unit: i64, len: usize) -> usize {
    // A ring of more than 2⁶³ slots could not be allocated.
    let len = i64::try_from(len).unwrap_or(i64::MAX);
    unit.rem_euclid(len).unsigned_abs() as usize
}

impl SecondsArchive for MemorySeconds {
    fn keep(&mut self, minute: i64, seconds: &MinuteOfSeconds) {
        let slot = self.slot_of(minute);
        match &mut self.slots[slot] {
            Some((kept, rows)) => {
                *kept = minute;
                **rows = *seconds;
            }
            empty => *empty = Some((minute, Box::new(*seconds))),
        }
    }

    fn read(&self, minute: i64, seconds: &mut MinuteOfSeconds) -> bool {
        match &self.slots[self.slot_of(minute)] {
            Some((kept, rows)) if *kept == minute => {
                *seconds = **rows;
                true
            }
            _ => false,
        }
    }

    fn clear(&mut self) {
        self.slots.iter_mut().for_each(|slot| *slot = None);
    }
}

/// The seconds of the newest `span` seconds: the newest minute's in memory, the closed minutes'
/// in the archive.
#[derive(Debug)]
struct SecondsTier {
    span: i64,
    /// The newest second holding anything; every second `span` or more before it is forgotten.
    newest: Option<i64>,
    /// The newest minute holding anything, and its seconds.
    open_minute: Option<i64>,
    open: Box<MinuteOfSeconds>,
    archive: Box<dyn SecondsArchive>,
}

impl SecondsTier {
    fn new(span: usize, archive: Box<dyn SecondsArchive>) -> Self {
        Self {
            span: i64::try_from(span).unwrap_or(i64::MAX),
            newest: None,
            open_minute: None,
            open: Box::new([EMPTY; 60]),
            archive,
        }
    }

    /// Second `second`'s place in its minute.
    fn index_of(second: i64) -> usize {
        second.rem_euclid(MINUTE_S).unsigned_abs() as usize
    }

    fn add(&mut self, second: i64, part: &SecondTotals) {
        if self
            .newest
            .is_some_and(|newest| second <= newest.saturating_sub(self.span))
        {
            return;
        }
        self.newest = Some(self.newest.map_or(second, |newest| newest.max(second)));
        let minute = second.div_euclid(MINUTE_S);
        match self.open_minute {
            Some(open) if minute < open => {
                // Late into a closed minute: into the archive's copy (a new one if it has none).
                let mut seconds = [EMPTY; 60];
                self.archive.read(minute, &mut seconds);
                merge(&mut seconds[Self::index_of(second)], part);
                self.archive.keep(minute, &seconds);
                return;
            }
            Some(open) if minute > open => {
                self.archive.keep(open, &self.open);
                *self.open = [EMPTY; 60];
                self.open_minute = Some(minute);
            }
            Some(_) => {}
            None => self.open_minute = Some(minute),
        }
        merge(&mut self.open[Self::index_of(second)], part);
    }

    /// The seconds in `seconds` holding pairs, oldest first.
    fn rows(&self, seconds: RangeInclusive<i64>) -> Vec<HistoryRow> {
        let Some(newest) = self.newest else {
            return Vec::new();
        };
        let first = (*seconds.start()).max(newest.saturating_sub(self.span) + 1);
        let last = (*seconds.end()).min(newest);
        let mut rows = Vec::new();
        if first > last {
            return rows;
        }
        let mut archived = [EMPTY; 60];
        for minute in first.div_euclid(MINUTE_S)..=last.div_euclid(MINUTE_S) {
            let of_minute: &MinuteOfSeconds = if Some(minute) == self.open_minute {
                &self.open
            } else if self.archive.read(minute, &mut archived) {
                &archived
            } else {
                continue;
            };
            let start = minute.saturating_mul(MINUTE_S);
            for (second, totals) in (start..).zip(of_minute) {
                if (first..=last).contains(&second) && totals.n > 0 {
                    rows.push(HistoryRow {
                        second,
                        totals: *totals,
                    });
                }
            }
        }
        rows
    }

    fn clear(&mut self) {
        self.newest = None;
        self.open_minute = None;
        *self.open = [EMPTY; 60];
        self.archive.clear();
    }
}

/// Exact seconds a history keeps at most, its newest: older ones are kept by the minute only.
pub const SECONDS_TIER_S: usize = 600;

/// Why a snapshot's minutes are not taken ([`History::restore_minutes`]): none is then.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum MinutesError {
    /// A row whose second is not a minute's first.
    #[error("minute t = {second} is not a multiple of 60")]
    OffTheMinute {
        /// Its second.
        second: i64,
    },
    /// A row not after the one before it.
    #[error("minute t = {second} is not after the one before")]
    OutOfOrder {
        /// Its second.
        second: i64,
    },
    /// A row of no pair, or of a total that is negative or not finite.
    #[error("minute t = {second} holds no pair or a bad total")]
    BadTotals {
        /// Its second.
        second: i64,
    },
}

/// The totals of the last `history_s` seconds of source time in two tiers: each second of the
/// newest [`SECONDS_TIER_S`] (all of them when `history_s` is no longer), and each minute (on the
/// grid of whole minutes, `⌊second / 60⌋`) of the whole span. Both tiers take every slice and
/// late pair as it comes, so a minute's row is exactly the merge of its seconds (counts and sums
/// added, the maximum of the maxima) whether or not they are still kept. The minutes are what a
/// snapshot keeps ([`History::restore_minutes`]).
/// Memory fixed at construction, 56 bytes a row (`benches/README.md` gives the bytes).
#[derive(Debug)]
pub struct History {
    seconds: SecondsTier,
    minutes: Ring,
    /// The seconds it covers.
    span_s: usize,
}

impl History {
    /// An empty history of `history_s` seconds.
    ///
    /// # Panics
    ///
    /// If `history_s` is 0 (no history is `None`, not an empty ring: the configuration layer
    /// decides).
    #[must_use]
    pub fn new(history_s: usize) -> Self {
        let archive = MemorySeconds::new(Self::archive_minutes(history_s));
        Self::with_archive(history_s, Box::new(archive))
    }

    /// An empty history of `history_s` seconds whose closed minutes of seconds go to `archive`,
    /// which must keep the newest [`History::archive_minutes`] of them.
    ///
    /// # Panics
    ///
    /// If `history_s` is 0.
    #[must_use]
    pub fn with_archive(history_s: usize, archive: Box<dyn SecondsArchive>) -> Self {
        assert!(history_s > 0, "a history needs at least one second");
        let minute_s = MINUTE_S.unsigned_abs() as usize;
        Self {
            seconds: SecondsTier::new(history_s.min(SECONDS_TIER_S), archive),
            minutes: Ring::new(history_s.div_ceil(minute_s)),
            span_s: history_s,
        }
    }

    /// The closed minutes of seconds a history of `history_s` seconds reads from its archive:
    /// with the open minute, they cover its seconds wherever the newest falls in its minute.
    #[must_use]
    pub fn archive_minutes(history_s: usize) -> usize {
        history_s
            .min(SECONDS_TIER_S)
            .div_ceil(MINUTE_S.unsigned_abs() as usize)
    }

    /// Its archive of closed minutes becomes `archive` (what the old one held is not moved).
    pub fn set_archive(&mut self, archive: Box<dyn SecondsArchive>) {
        self.seconds.archive = archive;
    }

    /// The seconds it covers, by the second or by the minute.
    #[must_use]
    pub fn seconds(&self) -> usize {
        self.span_s
    }

    /// The newest seconds it keeps one by one.
    #[must_use]
    pub fn exact_seconds(&self) -> usize {
        self.span_s.min(SECONDS_TIER_S)
    }

    /// The newest second holding anything; `None` before any.
    #[must_use]
    pub fn newest_second(&self) -> Option<i64> {
        self.seconds.newest
    }

    /// Adds `part` to `second`'s row and to its minute's.
    fn merge_into(&mut self, second: i64, part: &SecondTotals) {
        self.seconds.add(second, part);
        if let Some(row) = self.minutes.row_mut(second.div_euclid(MINUTE_S)) {
            merge(row, part);
        }
    }

    /// Adds the totals of a closed slice (of the nine metrics) to `second`; nothing if it holds
    /// no pair or the second is older than the ring keeps.
    pub fn fold(&mut self, second: i64, totals: &WindowTotals<METRIC_COUNT>) {
        if totals.n == 0 {
            return;
        }
        self.merge_into(second, &history_part(totals));
    }

    /// Adds one pair's nine magnitudes to `second`: a pair that came late, into a slice already
    /// folded.
    pub fn add(&mut self, second: i64, magnitudes: &[f64; METRIC_COUNT]) {
        let part = history_part(&WindowTotals {
            n: 1,
            sums: *magnitudes,
            sums_of_squares: magnitudes.map(|x| x * x),
            maxima: *magnitudes,
        });
        self.merge_into(second, &part);
    }

    /// The rows of the seconds in `seconds` that hold pairs and are kept one by one, oldest
    /// first.
    pub fn rows(&self, seconds: RangeInclusive<i64>) -> impl Iterator<Item = HistoryRow> {
        self.seconds.rows(seconds).into_iter()
    }

    /// The rows of the minutes that hold pairs and start in `seconds`, oldest first, each
    /// [`HistoryRow::second`] the minute's first second.
    pub fn minute_rows(
        &self,
        seconds: RangeInclusive<i64>,
    ) -> impl Iterator<Item = HistoryRow> + '_ {
        let minutes = seconds.start().div_euclid(MINUTE_S)
            + i64::from(seconds.start().rem_euclid(MINUTE_S) != 0)
            ..=seconds.end().div_euclid(MINUTE_S);
        self.minutes
            .rows(minutes)
            .map(|(minute, totals)| HistoryRow {
                second: minute.saturating_mul(MINUTE_S),
                totals,
            })
    }

    /// Takes `rows` (minutes, oldest first, each [`HistoryRow::second`] a minute's first second,
    /// as [`History::minute_rows`] gave them) as its minutes, before any pair; the rows older than
    /// the span before the newest are left out. The seconds start empty.
    ///
    /// # Errors
    ///
    /// A row that is not on a minute, out of order, empty, or with a total that is negative or
    /// not finite: nothing is taken.
    pub fn restore_minutes(&mut self, rows: &[HistoryRow]) -> Result<(), MinutesError> {
        let mut previous: Option<i64> = None;
        for row in rows {
            let totals = &row.totals;
            let sound = |values: &[f64; 2]| values.iter().all(|x| x.is_finite() && *x >= 0.0);
            if row.second.rem_euclid(MINUTE_S) != 0 {
                return Err(MinutesError::OffTheMinute { second: row.second });
            }
            if previous.is_some_and(|previous| row.second <= previous) {
                return Err(MinutesError::OutOfOrder { second: row.second });
            }
            if totals.n == 0
                || !sound(&totals.sums)
                || !sound(&totals.sums_of_squares)
                || !sound(&totals.maxima)
            {
                return Err(MinutesError::BadTotals { second: row.second });
            }
            previous = Some(row.second);
        }
        self.clear();
        for row in rows {
            if let Some(slot) = self.minutes.row_mut(row.second.div_euclid(MINUTE_S)) {
                *slot = row.totals;
            }
        }
        Ok(())
    }

    /// Forgets every second.
    pub fn clear(&mut self) {
        self.seconds.clear();
        self.minutes.clear();
    }
}

/// The deviation window ([`WindowStats`]) and, when kept, its [`History`]: each slice of the
/// window is folded into the history when it closes (the window moves past it), into the second
/// its start falls in; a pair stamped late into a slice already folded is added to its second
/// directly. So the history's second `s` holds exactly the pairs of the slices starting in
/// `[s, s + 1)`, and a second is complete once the window's newest slice lies in a later second
/// ([`WindowWithHistory::open_second`]). With slices that do not divide a second (e.g. 0.3 s), a
/// row spans its slices: from the start of its first to the end of its last, up to a slice
/// beyond the second.
///
/// **Cost.** Per pair, beside the window's own work: a comparison of its slice with the newest
/// (the slice is computed once, for both). Per slice that closes: a division and a floor for its
/// second, and per kept metric an add, an add and a max. Per late pair into a folded slice: the
/// same into its row.
#[derive(Debug)]
pub struct WindowWithHistory {
    window: WindowStats,
    history: Option<History>,
}

impl WindowWithHistory {
    /// A window of `window_s` in `slices` ([`WindowStats::new`]), with a history of
    /// `history_s` seconds, none when 0.
    #[must_use]
    pub fn new(window_s: f64, slices: usize, history_s: usize) -> Self {
        Self::with_archive(window_s, slices, history_s, None)
    }

    /// [`WindowWithHistory::new`], the history's closed minutes of seconds in `archive` when
    /// given ([`History::with_archive`]), else in memory.
    #[must_use]
    pub fn with_archive(
        window_s: f64,
        slices: usize,
        history_s: usize,
        archive: Option<Box<dyn SecondsArchive>>,
    ) -> Self {
        let history = (history_s > 0).then(|| match archive {
            Some(archive) => History::with_archive(history_s, archive),
            None => History::new(history_s),
        });
        Self {
            window: WindowStats::new(window_s, slices),
            history,
        }
    }

    /// Its history's archive of closed minutes becomes `archive` ([`History::set_archive`]).
    pub fn set_archive(&mut self, archive: Box<dyn SecondsArchive>) {
        if let Some(history) = &mut self.history {
            history.set_archive(archive);
        }
    }

    /// The window.
    #[must_use]
    pub fn window(&self) -> &WindowStats {
        &self.window
    }

    /// The history, when kept.
    #[must_use]
    pub fn history(&self) -> Option<&History> {
        self.history.as_ref()
    }

    /// The second slice `slice` of the window is folded into: the one its start falls in.
    #[must_use]
    pub fn second_of_slice(&self, slice: i64) -> i64 {
        self.window.slice_start_s(slice).floor() as i64
    }

    /// The second whose slices are still coming in: that of the window's newest slice. Every
    /// earlier second of the history is complete (but for pairs paired late, into slices still
    /// in the window); `None` before any time.
    #[must_use]
    pub fn open_second(&self) -> Option<i64> {
        self.window
            .newest_slice()
            .map(|slice| self.second_of_slice(slice))
    }

    /// Adds a pair stamped `stamp_s` ([`WindowStats::add`]); `false` if it did not enter the
    /// window (nor the history).
    pub fn add(&mut self, stamp_s: f64, magnitudes: &[f64; METRIC_COUNT]) -> bool {
        if !stamp_s.is_finite() || !acceptable(magnitudes) {
            return false;
        }
        let slice = self.window.slice_of(stamp_s);
        let (Some(newest), true) = (self.window.newest_slice(), self.history.is_some()) else {
            return self.window.add_to_slice(slice, magnitudes);
        };
        if slice == newest {
            return self.window.add_to_slice(slice, magnitudes);
        }
        // The window moves on exactly when the sample enters a newer slice.
        if slice > newest {
            self.fold_newest();
        }
        let entered = self.window.add_to_slice(slice, magnitudes);
        if entered && slice < newest {
            let second = self.second_of_slice(slice);
            if let Some(history) = &mut self.history {
                history.add(second, magnitudes);
            }
        }
        entered
    }

    /// Moves the window's end to `now_s` ([`WindowStats::advance_to`]).
    pub fn advance_to(&mut self, now_s: f64) {
        if let Some(newest) = self.window.newest_slice()
            && now_s.is_finite()
            && self.window.slice_of(now_s) > newest
        {
            self.fold_newest();
        }
        self.window.advance_to(now_s);
    }

    /// The window starts afresh (a reset, a new epoch); the history keeps what the window held,
    /// as source time goes on.
    pub fn reset_window(&mut self) {
        self.fold_newest();
        self.window.reset();
    }

    /// Its history's minutes as a snapshot keeps them: every minute holding pairs, oldest first,
    /// the window's newest slice (not folded yet) included in its minute; empty when no history
    /// is kept.
    #[must_use]
    pub fn history_minutes_record(&self) -> Vec<HistoryRow> {
        let Some(history) = &self.history else {
            return Vec::new();
        };
        let mut rows: Vec<HistoryRow> = history.minute_rows(i64::MIN..=i64::MAX).collect();
        let Some(newest) = self.window.newest_slice() else {
            return rows;
        };
        let totals = self.window.newest_totals();
        if totals.n == 0 {
            return rows;
        }
        let part = history_part(&totals);
        let minute = self.second_of_slice(newest).div_euclid(MINUTE_S) * MINUTE_S;
        match rows.last_mut() {
            Some(row) if row.second == minute => merge(&mut row.totals, &part),
            Some(row) if row.second > minute => {}
            _ => rows.push(HistoryRow {
                second: minute,
                totals: part,
            }),
        }
        rows
    }

    /// Takes `rows` as its history's minutes ([`History::restore_minutes`]); nothing when no
    /// history is kept.
    ///
    /// # Errors
    ///
    /// Those of [`History::restore_minutes`].
    pub fn restore_history_minutes(&mut self, rows: &[HistoryRow]) -> Result<(), MinutesError> {
        match &mut self.history {
            Some(history) => history.restore_minutes(rows),
            None => Ok(()),
        }
    }

    /// Both start afresh: source time went back (a restart of the gateway's clock), and seconds
    /// of the new clock must not mix with those of the old.
    pub fn restart(&mut self) {
        self.window.reset();
        if let Some(history) = &mut self.history {
            history.clear();
        }
    }

    /// The window's statistics ([`WindowStats::readout`]).
    #[must_use]
    pub fn readout(&self) -> StatsSet {
        self.window.readout()
    }

    /// Folds the window's newest slice, which is about to close, into the history.
    fn fold_newest(&mut self) {
        let Some(newest) = self.window.newest_slice() else {
            return;
        };
        let second = self.second_of_slice(newest);
        if let Some(history) = &mut self.history {
            history.fold(second, &self.window.newest_totals());
        }
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "exact results are expected where tested")]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// The totals of `pairs` over the history's metrics, summed naively.
    fn naive(pairs: &[(f64, [f64; METRIC_COUNT])]) -> SecondTotals {
        let mut totals = EMPTY;
        for (_, magnitudes) in pairs {
            let mut one = EMPTY;
            one.n = 1;
            for (m, metric) in HISTORY_METRICS.iter().enumerate() {
                let x = magnitudes[metric.index()];
                one.sums[m] = x;
                one.sums_of_squares[m] = x * x;
                one.maxima[m] = x;
            }
            merge(&mut totals, &one);
        }
        totals
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-12 * a.abs().max(b.abs()) || a == b
    }

    fn assert_stats_agree(got: &[Stats; 2], expected: &[Stats; 2], what: &str) {
        for m in 0..2 {
            assert!(
                close(got[m].mae, expected[m].mae),
                "{what} mae {got:?} {expected:?}"
            );
            assert!(
                close(got[m].rmse, expected[m].rmse),
                "{what} rmse {got:?} {expected:?}"
            );
            assert_eq!(got[m].max, expected[m].max, "{what} max");
        }
    }

    /// Magnitudes with distinct position and angle values.
    fn magnitudes(position: f64, angle: f64) -> [f64; METRIC_COUNT] {
        let mut values = [0.5; METRIC_COUNT];
        values[Metric::Position.index()] = position;
        values[Metric::Angle.index()] = angle;
        values
    }

    #[test]
    fn seconds_hold_their_slices_and_late_pairs() {
        // Slices of 0.25 s.
        let mut window = WindowWithHistory::new(2.0, 8, 10);
        assert!(window.add(10.1, &magnitudes(1.0, 2.0)));
        assert!(window.add(10.6, &magnitudes(3.0, 1.0)));
        assert_eq!(window.open_second(), Some(10));
        assert_eq!(window.history().expect("kept").rows(0..=100).count(), 1);
        assert!(window.add(11.05, &magnitudes(5.0, 5.0)));
        // Late into second 10, whose slices are folded.
        assert!(window.add(10.9, &magnitudes(2.0, 0.0)));
        window.advance_to(12.0);
        let rows: Vec<HistoryRow> = window.history().expect("kept").rows(0..=100).collect();
        assert_eq!(rows.len(), 2);
        assert_eq!((rows[0].second, rows[0].totals.n), (10, 3));
        assert_eq!(rows[0].totals.sums, [6.0, 3.0]);
        assert_eq!(rows[0].totals.maxima, [3.0, 2.0]);
        assert_eq!((rows[1].second, rows[1].totals.n), (11, 1));
        assert_eq!(rows[1].stats()[0].rmse, 5.0);
    }

    #[test]
    fn a_reset_window_keeps_its_history_and_a_restart_clears_it() {
        let mut window = WindowWithHistory::new(10.0, 100, 60);
        assert!(window.add(5.5, &magnitudes(1.0, 1.0)));
        window.reset_window();
        assert!(window.add(5.7, &magnitudes(1.0, 1.0)));
        window.advance_to(6.0);
        let history = window.history().expect("kept");
        assert_eq!(history.rows(5..=5).next().map(|row| row.totals.n), Some(2));
        window.restart();
        assert_eq!(window.history().expect("kept").rows(0..=100).count(), 0);
        assert!(window.window().is_empty());
    }

    #[test]
    fn the_ring_keeps_its_seconds_and_no_more() {
        let mut history = History::new(3);
        let one = |x: f64| WindowTotals {
            n: 1,
            sums: [x; METRIC_COUNT],
            sums_of_squares: [x * x; METRIC_COUNT],
            maxima: [x; METRIC_COUNT],
        };
        for second in 0..5 {
            history.fold(
                second,
                &one(f64::from(u8::try_from(second).expect("small"))),
            );
        }
        let seconds: Vec<i64> = history
            .rows(i64::MIN..=i64::MAX)
            .map(|row| row.second)
            .collect();
        assert_eq!(seconds, [2, 3, 4]);
        // Too old: dropped; a long gap empties the ring.
        history.fold(1, &one(9.0));
        assert_eq!(history.rows(0..=1).count(), 0);
        history.fold(100, &one(1.0));
        assert_eq!(history.rows(0..=100).count(), 1);
        assert_eq!(history.seconds(), 3);
        assert!(WindowWithHistory::new(1.0, 10, 0).history().is_none());
    }

    #[test]
    fn minutes_are_the_exact_merge_of_their_seconds_and_cover_the_span() {
        let mut history = History::new(3600);
        assert_eq!(
            (history.seconds(), history.exact_seconds()),
            (3600, SECONDS_TIER_S)
        );
        // Two hours of pairs, a few a second, some of them late into their second.
        let mut pairs: Vec<(i64, [f64; METRIC_COUNT])> = Vec::new();
        for second in 0..7200_i64 {
            for k in 0..3_i64 {
                let x = f64::from(u32::try_from((second * 7 + k * 13) % 101).expect("small"));
                let values = magnitudes(x * 1e-4, x * 1e-3);
                history.add(second, &values);
                pairs.push((second, values));
            }
        }
        // Late into a second still kept, and into one only its minute keeps.
        history.add(7000, &magnitudes(0.5, 0.25));
        pairs.push((7000, magnitudes(0.5, 0.25)));
        history.add(6000, &magnitudes(0.75, 0.125));
        pairs.push((6000, magnitudes(0.75, 0.125)));
        let seconds: Vec<HistoryRow> = history.rows(i64::MIN..=i64::MAX).collect();
        assert_eq!(seconds.len(), SECONDS_TIER_S);
        assert_eq!(seconds[0].second, 7200 - 600);
        let minutes: Vec<HistoryRow> = history.minute_rows(i64::MIN..=i64::MAX).collect();
        assert_eq!(minutes.len(), 60);
        assert_eq!((minutes[0].second, minutes[59].second), (3600, 7140));
        for row in &minutes {
            let of_minute: Vec<_> = pairs
                .iter()
                .filter(|(second, _)| second.div_euclid(MINUTE_S) * MINUTE_S == row.second)
                .map(|&(second, values)| (second as f64, values))
                .collect();
            let expected = naive(&of_minute);
            assert_eq!(row.totals.n, expected.n);
            assert_stats_agree(&row.stats(), &stats_of(&expected), "minute");
            // The kept seconds of a minute merge to it exactly.
            let mut merged = EMPTY;
            let kept: Vec<_> = seconds
                .iter()
                .filter(|second| second.second.div_euclid(MINUTE_S) * MINUTE_S == row.second)
                .collect();
            if kept.len() == 60 {
                for second in kept {
                    merge(&mut merged, &second.totals);
                }
                assert_eq!(merged.n, row.totals.n);
                assert_stats_agree(&stats_of(&merged), &row.stats(), "merged seconds");
            }
        }
        // Minutes answered are those starting in the range.
        let starts: Vec<i64> = history
            .minute_rows(3601..=3720)
            .map(|row| row.second)
            .collect();
        assert_eq!(starts, [3660, 3720]);
        history.clear();
        assert_eq!(history.minute_rows(i64::MIN..=i64::MAX).count(), 0);
        // A restored history answers the same minutes, and goes on merging into the newest.
        let mut restored = History::new(3600);
        restored.restore_minutes(&minutes).expect("sound rows");
        let again: Vec<HistoryRow> = restored.minute_rows(i64::MIN..=i64::MAX).collect();
        assert_eq!(again, minutes);
        assert_eq!(restored.rows(i64::MIN..=i64::MAX).count(), 0);
        restored.add(7199, &magnitudes(0.5, 0.5));
        assert_eq!(
            restored
                .minute_rows(7140..=7140)
                .next()
                .map(|row| row.totals.n),
            Some(minutes[59].totals.n + 1)
        );
        let mut bad = minutes[3];
        bad.second += 1;
        assert!(restored.restore_minutes(&[bad]).is_err());
        let mut bad = minutes[3];
        bad.totals.sums[0] = f64::NAN;
        assert!(restored.restore_minutes(&[bad]).is_err());
        assert!(restored.restore_minutes(&[minutes[4], minutes[3]]).is_err());
        // A history of no more than the seconds tier keeps its minutes too.
        let mut short = History::new(120);
        short.add(61, &magnitudes(0.5, 0.5));
        assert_eq!(short.minute_rows(i64::MIN..=i64::MAX).count(), 1);
    }

    /// An archive that keeps nothing, as a log that lost its minutes.
    #[derive(Debug)]
    struct Forgetful;

    impl SecondsArchive for Forgetful {
        fn keep(&mut self, _: i64, _: &MinuteOfSeconds) {}
        fn read(&self, _: i64, _: &mut MinuteOfSeconds) -> bool {
            false
        }
        fn clear(&mut self) {}
    }

    #[test]
    fn seconds_lost_by_the_archive_leave_the_open_minute_and_every_minute() {
        let mut kept = History::new(600);
        let mut lossy = History::with_archive(600, Box::new(Forgetful));
        for second in 0..300_i64 {
            let x = f64::from(u32::try_from(second % 17).expect("small")) * 1e-4;
            kept.add(second, &magnitudes(x, x));
            lossy.add(second, &magnitudes(x, x));
        }
        let all = i64::MIN..=i64::MAX;
        assert_eq!(kept.rows(all.clone()).count(), 300);
        let open: Vec<i64> = lossy.rows(all.clone()).map(|row| row.second).collect();
        assert_eq!(open, (240..300).collect::<Vec<_>>());
        assert_eq!(
            kept.minute_rows(all.clone()).collect::<Vec<_>>(),
            lossy.minute_rows(all).collect::<Vec<_>>()
        );
        assert_eq!(History::archive_minutes(3600), 10);
        assert_eq!(History::archive_minutes(61), 2);
    }

    proptest! {
        /// Every second's totals equal those of its pairs summed naively, and the seconds a
        /// window covered add up to what the window read out then.
        #[test]
        fn seconds_agree_with_their_pairs_and_the_window(
            steps in prop::collection::vec((0.001..0.05_f64, 0.0..1.0_f64, 0.0..1.0_f64, any::<bool>()), 50..600),
            slices in prop::sample::select(vec![40_usize, 100, 30, 7]),
        ) {
            // 4-s window in `slices` slices (0.1 s, 0.04 s, 0.133 s, 0.571 s).
            let mut window = WindowWithHistory::new(4.0, slices, 100);
            let mut pairs: Vec<(f64, [f64; METRIC_COUNT])> = Vec::new();
            let mut newest_s = 100.0;
            for (step, position, angle, late) in steps {
                // A late pair: behind the newest, as when a measured pose pairs after the
                // joint sample past it.
                let stamp_s = if late {
                    newest_s - step
                } else {
                    newest_s += step;
                    newest_s
                };
                let values = magnitudes(position, angle);
                if window.add(stamp_s, &values) {
                    pairs.push((stamp_s, values));
                }
            }
            // The window now holds whole seconds' slices up to the newest only when its edge is
            // on a second: read it out at the end of the last slice before the next second.
            let slice_s = 4.0 / slices as f64;
            let open = window.open_second().expect("time");
            let end_s = (open + 1) as f64 - slice_s / 2.0;
            window.advance_to(end_s);
            let readout = window.readout();
            let newest_slice = window.window().newest_slice().expect("time");
            // Past every slice of `open`: every second with pairs is complete.
            window.advance_to((open + 2) as f64 + slice_s);
            prop_assert!(window.open_second() > Some(open));
            let history = window.history().expect("kept");
            prop_assert_eq!(
                history.rows(i64::MIN..=i64::MAX).map(|row| row.totals.n).sum::<u64>(),
                pairs.len() as u64
            );
            let slice_of = |stamp_s: f64| (stamp_s * (slices as f64 / 4.0)).floor() as i64;
            let second_of = |slice: i64| window.second_of_slice(slice);
            for row in history.rows(i64::MIN..=i64::MAX) {
                let of_second: Vec<_> = pairs
                    .iter()
                    .filter(|(stamp_s, _)| second_of(slice_of(*stamp_s)) == row.second)
                    .copied()
                    .collect();
                let expected = naive(&of_second);
                prop_assert_eq!(row.totals.n, expected.n);
                assert_stats_agree(&row.stats(), &stats_of(&expected), "second");
            }
            // The seconds whose slices were all in the window at `end_s`.
            let first_slice = newest_slice - i64::try_from(slices).expect("small") + 1;
            let first_second = second_of(first_slice) + i64::from(second_of(first_slice - 1) == second_of(first_slice));
            let mut span = EMPTY;
            for row in history.rows(first_second..=open) {
                merge(&mut span, &row.totals);
            }
            let in_window: Vec<_> = pairs
                .iter()
                .filter(|(stamp_s, _)| (first_slice..=newest_slice).contains(&slice_of(*stamp_s)))
                .filter(|(stamp_s, _)| second_of(slice_of(*stamp_s)) >= first_second)
                .copied()
                .collect();
            let expected = naive(&in_window);
            prop_assert_eq!(span.n, expected.n);
            assert_stats_agree(&stats_of(&span), &stats_of(&expected), "span");
            // When the window's edge fell on a second, the span is the window itself.
            if second_of(first_slice - 1) != second_of(first_slice) {
                prop_assert_eq!(span.n, readout.n);
                let window_stats = HISTORY_METRICS.map(|metric| *readout.of(metric));
                assert_stats_agree(&stats_of(&span), &window_stats, "window");
            }
        }
    }
}
