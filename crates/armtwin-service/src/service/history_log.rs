//! Where the robots' histories keep the seconds of their closed minutes: one log for the
//! service, beside the flight recorder's, so that a robot keeps only its open minute of seconds
//! in memory ([`armtwin_core::metrics::SecondsArchive`]).
//!
//! Owns a minute's bytes in the log and which minutes a robot can read back. Must not know what
//! a history answers (the core's) nor hold a robot's lock itself: each archive is a robot's, used
//! under that robot's lock.

use std::sync::Arc;

use armtwin_core::metrics::{History, MinuteOfSeconds, SecondTotals, SecondsArchive, ring_slot};
use armtwin_core::pipeline::Twin;
use armtwin_recorder::Spool;

use crate::config::ServiceConfig;

/// Values of a second: its count, then two sums, two sums of squares and two maxima.
const SECOND_VALUES: usize = 7;

/// Bytes of a minute of seconds in the log: 60 seconds of 7 little-endian 8-byte values.
const MINUTE_BYTES: usize = 60 * SECOND_VALUES * 8;

/// The service's log of closed minutes of seconds, and the histories' length; none when no
/// history is kept.
#[derive(Debug)]
pub(super) struct HistoryLog {
    log: Option<Arc<Spool>>,
    history_s: usize,
}

impl HistoryLog {
    /// The log of `config`: an unnamed file in the recorder's folder, of `[recorder]
    /// history_bytes`, written in a circle (in memory when no file can be made there).
    pub(super) fn new(config: &ServiceConfig) -> Self {
        let history_s = config.pipeline.history_s;
        Self {
            log: (history_s > 0)
                .then(|| Spool::in_dir(&config.recorder.store.dir, config.recorder.history_bytes)),
            history_s,
        }
    }

    /// What the log holds, and what it lost (all 0 without one).
    pub(super) fn totals(&self) -> armtwin_view::HistoryLogTotals {
        self.log
            .as_ref()
            .map_or_else(armtwin_view::HistoryLogTotals::default, |log| {
                armtwin_view::HistoryLogTotals {
                    bytes: log.used_bytes(),
                    dropped: log.dropped_blocks(),
                    write_failures: log.write_failures(),
                }
            })
    }

    /// No log: the histories keep their seconds in memory.
    pub(super) fn none() -> Self {
        Self {
            log: None,
            history_s: 0,
        }
    }

    /// `twin`, its history keeping the seconds of closed minutes in the log (as it was when
    /// there is none).
    pub(super) fn attach(&self, twin: Twin) -> Twin {
        match &self.log {
            Some(log) => twin.with_seconds_archive(Box::new(LoggedSeconds::new(
                Arc::clone(log),
                self.history_s,
            ))),
            None => twin,
        }
    }
}

/// A robot's closed minutes of seconds: the log's offset of each of its newest minutes' blocks.
/// A minute the log has wrapped past, or dropped (a disk slower than the fleet), is read as
/// absent: its seconds are not answered, while its minute's row, kept in memory, still is.
#[derive(Debug)]
pub(super) struct LoggedSeconds {
    log: Arc<Spool>,
    /// Minute `m` at `m mod len`, with its number and offset.
    slots: Box<[Option<(i64, u64)>]>,
}

impl LoggedSeconds {
    /// The archive of a history of `history_s` seconds in `log`.
    pub(super) fn new(log: Arc<Spool>, history_s: usize) -> Self {
        Self {
            log,
            slots: vec![None; History::archive_minutes(history_s).max(1)].into_boxed_slice(),
        }
    }

    fn slot_of(&self, minute: i64) -> usize {
        ring_slot(minute, self.slots.len())
    }
}

impl SecondsArchive for LoggedSeconds {
    fn keep(&mut self, minute: i64, seconds: &MinuteOfSeconds) {
        let mut bytes = [0_u8; MINUTE_BYTES];
        for (second, out) in seconds
            .iter()
            .zip(bytes.chunks_exact_mut(SECOND_VALUES * 8))
        {
            let values = [
                second.n,
                second.sums[0].to_bits(),
                second.sums[1].to_bits(),
                second.sums_of_squares[0].to_bits(),
                second.sums_of_squares[1].to_bits(),
                second.maxima[0].to_bits(),
                second.maxima[1].to_bits(),
            ];
            for (value, out) in values.iter().zip(out.chunks_exact_mut(8)) {
                out.copy_from_slice(&value.to_le_bytes());
            }
        }
        let slot = self.slot_of(minute);
        self.slots[slot] = self.log.append(&[&bytes]).map(|offset| (minute, offset));
    }

    fn read(&self, minute: i64, seconds: &mut MinuteOfSeconds) -> bool {
        let Some((kept, offset)) = self.slots[self.slot_of(minute)] else {
            return false;
        };
        let mut bytes = [0_u8; MINUTE_BYTES];
        if kept != minute || !self.log.read(offset, &mut bytes) {
            return false;
        }
        for (second, of_second) in seconds
            .iter_mut()
            .zip(bytes.chunks_exact(SECOND_VALUES * 8))
        {
            let mut values = of_second
                .chunks_exact(8)
                .map(|b| u64::from_le_bytes(b.try_into().unwrap_or_default()));
            let mut next = || values.next().unwrap_or_default();
            let n = next();
            let mut value = || f64::from_bits(next());
            *second = SecondTotals {
                n,
                sums: [value(), value()],
                sums_of_squares: [value(), value()],
                maxima: [value(), value()],
            };
        }
        true
    }

    fn clear(&mut self) {
        self.slots.fill(None);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minutes_read_back_bit_for_bit_until_the_log_wraps_past_them() {
        // A log of three minutes' blocks, in memory.
        let log = Spool::in_memory(3 * MINUTE_BYTES as u64);
        let mut archive = LoggedSeconds::new(Arc::clone(&log), 600);
        let minute_of = |k: u32| -> MinuteOfSeconds {
            std::array::from_fn(|s| SecondTotals {
                n: u64::from(k) * 100 + s as u64,
                sums: [f64::from(k) + 0.1, 1e-300],
                sums_of_squares: [f64::from(k) * 1e-7, 5e-324],
                maxima: [0.1 + 0.2, f64::from(k)],
            })
        };
        for k in 0..3 {
            archive.keep(i64::from(k) - 1, &minute_of(k));
        }
        let mut read = [SecondTotals {
            n: 0,
            sums: [0.0; 2],
            sums_of_squares: [0.0; 2],
            maxima: [0.0; 2],
        }; 60];
        for k in 0..3 {
            assert!(archive.read(i64::from(k) - 1, &mut read));
            assert_eq!(read, minute_of(k));
        }
        assert!(!archive.read(5, &mut read), "never kept");
        // A fourth block wraps the log past the first minute's.
        archive.keep(2, &minute_of(3));
        assert!(!archive.read(-1, &mut read));
        assert!(archive.read(2, &mut read) && read == minute_of(3));
        archive.clear();
        assert!(!archive.read(2, &mut read));
    }
}
