//! The event budget: a token bucket per robot (and one for every robot that may not be
//! tracked) that keeps a flood of events from subscribers and logs.
//!
//! Pure: time comes in as an argument, so the budget is tested without waiting.

use std::time::Instant;

use crate::config::EventBudget;

/// A token bucket of events (wall-clock time: it protects subscribers and logs, not statistics).
#[derive(Debug, Clone, Copy)]
pub(super) struct EventBucket {
    tokens: f64,
    refilled: Instant,
    suppressed: u64,
}

impl EventBucket {
    pub(super) fn full(budget: EventBudget, now: Instant) -> Self {
        Self {
            tokens: f64::from(budget.burst),
            refilled: now,
            suppressed: 0,
        }
    }

    /// Whether an event may go out now (`always` for the ones that must: alarms, recoveries,
    /// restarts); if not, it is counted as suppressed.
    fn admit(&mut self, budget: EventBudget, now: Instant, always: bool) -> bool {
        let elapsed_s = now.saturating_duration_since(self.refilled).as_secs_f64();
        self.tokens = (self.tokens + elapsed_s * budget.per_s).min(f64::from(budget.burst));
        self.refilled = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else if always {
            true
        } else {
            self.suppressed += 1;
            false
        }
    }

    /// [`admit`](Self::admit), and what the event then says: `Ok` with the number of events
    /// suppressed since the last one that went out (which this one reports, and which starts
    /// over), `Err` with the number suppressed so far, this one included.
    pub(super) fn pass(
        &mut self,
        budget: EventBudget,
        now: Instant,
        always: bool,
    ) -> Result<u64, u64> {
        if self.admit(budget, now, always) {
            Ok(std::mem::take(&mut self.suppressed))
        } else {
            Err(self.suppressed)
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use super::EventBucket;
    use crate::config::EventBudget;

    const BUDGET: EventBudget = EventBudget {
        per_s: 2.0,
        burst: 3,
    };

    #[test]
    fn a_full_bucket_lets_its_burst_through_then_counts_what_it_keeps_back() {
        let start = Instant::now();
        let mut bucket = EventBucket::full(BUDGET, start);
        for _ in 0..3 {
            assert_eq!(bucket.pass(BUDGET, start, false), Ok(0));
        }
        assert_eq!(bucket.pass(BUDGET, start, false), Err(1));
        assert_eq!(bucket.pass(BUDGET, start, false), Err(2));
        // Half a second at 2 per second refills one token: the next event goes out and reports
        // the two kept back before it.
        let later = start + Duration::from_millis(500);
        assert_eq!(bucket.pass(BUDGET, later, false), Ok(2));
        assert_eq!(bucket.pass(BUDGET, later, false), Err(1));
    }

    #[test]
    fn events_that_must_go_out_pass_an_empty_bucket_without_resetting_the_count() {
        let start = Instant::now();
        let mut bucket = EventBucket::full(BUDGET, start);
        for _ in 0..3 {
            assert!(bucket.pass(BUDGET, start, false).is_ok());
        }
        assert_eq!(bucket.pass(BUDGET, start, false), Err(1));
        // An alarm goes out with the suppressed count so far.
        assert_eq!(bucket.pass(BUDGET, start, true), Ok(1));
        assert_eq!(bucket.pass(BUDGET, start, false), Err(1));
    }

    #[test]
    fn refill_stops_at_the_burst() {
        let start = Instant::now();
        let mut bucket = EventBucket::full(BUDGET, start);
        // An hour idle refills to the burst, not to 7 200 tokens.
        let later = start + Duration::from_secs(3600);
        for _ in 0..3 {
            assert_eq!(bucket.pass(BUDGET, later, false), Ok(0));
        }
        assert_eq!(bucket.pass(BUDGET, later, false), Err(1));
    }

    #[test]
    fn a_clock_that_goes_back_refills_nothing() {
        let earlier = Instant::now();
        let start = earlier + Duration::from_secs(5);
        let mut bucket = EventBucket::full(BUDGET, start);
        for _ in 0..3 {
            assert!(bucket.pass(BUDGET, start, false).is_ok());
        }
        assert_eq!(bucket.pass(BUDGET, earlier, false), Err(1));
    }
}
