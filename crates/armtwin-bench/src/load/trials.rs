//! Trials at a fixed rate: the warm-up that waits for every robot's first answer, one trial on
//! schedule with its replies awaited, the latency run and the search for the highest sustained
//! rate.

use std::sync::PoisonError;
use std::sync::atomic::Ordering;
use std::thread;
use std::time::{Duration, Instant};

use super::{Counts, Latency, Load, LoadError, Search, Trial};
use crate::procfs;

/// Pause between trials, so one trial's tail never overlaps the next.
const PAUSE: Duration = Duration::from_millis(300);
/// How long the warm-up waits without any new reply before it sends again.
const STALL: Duration = Duration::from_secs(10);
/// How long a failed trial's stragglers are awaited before the next trial starts.
pub(super) const SETTLE: Duration = Duration::from_secs(10);
/// Slack on a trial's completion for the last replies' own latency.
const COMPLETION_SLACK_S: f64 = 0.01;

pub(super) fn percentile_us(sorted_ns: &[u64], fraction: f64) -> f64 {
    if sorted_ns.is_empty() {
        return f64::NAN;
    }
    let rank = ((fraction * sorted_ns.len() as f64).ceil() as usize).clamp(1, sorted_ns.len());
    sorted_ns[rank - 1] as f64 / 1e3
}

impl Load {
    /// Sends one sample per robot of `robots` until every one is answered. The system under
    /// test may take long to start tracking thousands of robots (Zenoh's declarations cost
    /// O(robots) each), so this waits as long as answers keep coming; a round that stalls for
    /// [`STALL`] is sent again (its first samples may have crossed our subscribers' declaration).
    pub(super) fn warm_up(&mut self, robots: std::ops::Range<usize>) -> Result<(), LoadError> {
        let count = robots.len() as u64;
        for _ in 0..3 {
            let base = self.replies.counts();
            for robot in robots.clone() {
                self.send(robot)?;
            }
            let mut answered = 0;
            let mut progress = Instant::now();
            loop {
                let got = self.replies.counts().since(base);
                if got.poses >= count && got.deviations >= count * self.deviations_per_sample() {
                    thread::sleep(PAUSE);
                    self.accounted = self.replies.counts();
                    return Ok(());
                }
                let now = Instant::now();
                if got.poses + got.deviations > answered {
                    answered = got.poses + got.deviations;
                    progress = now;
                } else if now - progress >= STALL {
                    break;
                }
                thread::sleep(Duration::from_millis(5));
            }
            eprintln!(
                "load: warm-up stalled at {answered} of {} replies, sending again",
                2 * count
            );
        }
        Err(LoadError::NoAnswer(format!(
            "the system under test did not answer all of {count} robots' first samples"
        )))
    }

    pub(super) fn sut_cpu_s(&self) -> Option<f64> {
        self.args.sut_pid.and_then(|pid| procfs::cpu_s(pid).ok())
    }

    /// Sends `rate × duration_s` samples on schedule and waits for their replies.
    pub(super) fn trial(
        &mut self,
        rate: f64,
        duration_s: f64,
        record: bool,
    ) -> Result<Trial, LoadError> {
        let samples = (rate * duration_s).round().max(1.0) as u64;
        let base = self.accounted;
        let cpu_before = self.sut_cpu_s();
        if record {
            self.replies
                .latencies_ns
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .clear();
            self.replies.recording.store(true, Ordering::Relaxed);
        }
        let start = Instant::now();
        let start_ns = self.replies.elapsed_ns();
        // A system that falls this far behind the schedule is not keeping up: stop offering.
        let give_up_lag = Duration::from_secs_f64(duration_s.max(1.0));
        let mut sent = 0;
        while sent < samples {
            let due = start + Duration::from_secs_f64(sent as f64 / rate);
            let now = Instant::now();
            if due > now {
                // Never spin: the system under test needs the cores.
                thread::sleep(due - now);
            } else if now - due > give_up_lag {
                break;
            }
            let robot = self.cursor;
            self.cursor = (self.cursor + 1) % self.robots.len();
            self.send(robot)?;
            sent += 1;
        }
        let abandoned = sent < samples;
        let samples = sent;
        let send_s = start.elapsed().as_secs_f64();
        let deadline_s = duration_s * (1.0 + self.args.tolerance) + COMPLETION_SLACK_S;
        let wait_until = start + Duration::from_secs_f64(deadline_s.max(send_s) + 1.0);
        let deviations = samples * self.deviations_per_sample();
        let complete = |replies: Counts| {
            let got = replies.since(base);
            got.poses >= samples && got.deviations >= deviations
        };
        let mut complete_s = None;
        while Instant::now() < wait_until {
            if complete(self.replies.counts()) {
                let last_ns = self.replies.last_ns.load(Ordering::Acquire);
                complete_s = Some(last_ns.saturating_sub(start_ns) as f64 / 1e9);
                break;
            }
            thread::sleep(Duration::from_millis(1));
        }
        self.replies.recording.store(false, Ordering::Relaxed);
        let cpu_after = self.sut_cpu_s();
        if complete_s.is_none() {
            // Let the stragglers arrive, so that they do not count for the next trial.
            let settle_until = Instant::now() + SETTLE;
            while Instant::now() < settle_until && !complete(self.replies.counts()) {
                thread::sleep(Duration::from_millis(10));
            }
        }
        let now = self.replies.counts();
        let replies = now.since(base);
        self.accounted = now;
        let last_reply_s = self
            .replies
            .last_ns
            .load(Ordering::Acquire)
            .saturating_sub(start_ns) as f64
            / 1e9;
        let delivered_rate =
            (replies.poses > 0 && last_reply_s > 0.0).then(|| replies.poses as f64 / last_reply_s);
        let lost =
            samples.saturating_sub(replies.poses) + deviations.saturating_sub(replies.deviations);
        let sustained = !abandoned && lost == 0 && complete_s.is_some_and(|s| s <= deadline_s);
        let trial = Trial {
            offered_rate: rate,
            samples,
            duration_s,
            send_s,
            complete_s,
            replies,
            lost,
            achieved_rate: complete_s.map(|s| samples as f64 / s),
            delivered_rate,
            sut_cpu_s: cpu_before.zip(cpu_after).map(|(b, a)| a - b),
            sustained,
        };
        eprintln!(
            "load: {rate:.0}/s × {duration_s} s to {robots} robots: {} (sent in {send_s:.3} s, complete {}, lost {lost})",
            if sustained {
                "sustained"
            } else {
                "NOT sustained"
            },
            complete_s.map_or_else(|| "never".to_owned(), |s| format!("{s:.3} s")),
            robots = self.robots.len(),
        );
        thread::sleep(PAUSE);
        Ok(trial)
    }

    pub(super) fn latency(&mut self) -> Result<Latency, LoadError> {
        let trial = self.trial(self.args.latency_rate, self.args.latency_duration, true)?;
        let mut sorted = std::mem::take(
            &mut *self
                .replies
                .latencies_ns
                .lock()
                .unwrap_or_else(PoisonError::into_inner),
        );
        sorted.sort_unstable();
        Ok(Latency {
            trial,
            count: sorted.len(),
            p50_us: percentile_us(&sorted, 0.5),
            p99_us: percentile_us(&sorted, 0.99),
            p999_us: percentile_us(&sorted, 0.999),
            max_us: percentile_us(&sorted, 1.0),
        })
    }

    /// Whether `rate` is sustained in one of `1 + retries` trials (stopping at the first that
    /// is); every trial run goes into `trials`.
    pub(super) fn search_trial(
        &mut self,
        rate: f64,
        duration_s: f64,
        trials: &mut Vec<Trial>,
    ) -> Result<bool, LoadError> {
        for _ in 0..=self.args.retries {
            let trial = self.trial(rate, duration_s, false)?;
            let sustained = trial.sustained;
            trials.push(trial);
            if sustained {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Doubles the rate until a trial fails (halves it while the first ones fail), then
    /// bisects between the best sustained rate and the lowest failing one.
    pub(super) fn search(&mut self) -> Result<Search, LoadError> {
        let duration_s = self.args.duration;
        let max_rate = self.args.max_rate;
        let mut trials = Vec::new();
        let mut sustained = 0.0_f64;
        let mut failed = f64::INFINITY;
        let mut rate = self.args.start_rate.min(max_rate);
        loop {
            if self.search_trial(rate, duration_s, &mut trials)? {
                sustained = rate;
                if rate >= max_rate || failed.is_finite() {
                    break;
                }
                rate = (rate * 2.0).min(max_rate);
            } else {
                failed = rate;
                if sustained > 0.0 || rate < 20.0 {
                    break;
                }
                rate /= 2.0;
            }
        }
        if failed.is_finite() && sustained > 0.0 {
            for _ in 0..self.args.bisect_steps {
                let rate = f64::midpoint(sustained, failed).round();
                if self.search_trial(rate, duration_s, &mut trials)? {
                    sustained = rate;
                } else {
                    failed = rate;
                }
            }
        }
        Ok(Search {
            max_sustained_rate: sustained,
            trials,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    pub(super) fn percentiles_are_nearest_rank() {
        let sorted: Vec<u64> = (1..=1000).map(|v| v * 1000).collect();
        assert!((percentile_us(&sorted, 0.5) - 500.0).abs() < 1e-9);
        assert!((percentile_us(&sorted, 0.99) - 990.0).abs() < 1e-9);
        assert!((percentile_us(&sorted, 0.999) - 999.0).abs() < 1e-9);
        assert!((percentile_us(&sorted, 1.0) - 1000.0).abs() < 1e-9);
        assert!(percentile_us(&[], 0.5).is_nan());
    }
}
