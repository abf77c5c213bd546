//! A Zenoh time range (`_time=[now(-10m)..]`) read as whole seconds of one robot's source time.
//!
//! `now()` stands for the robot's newest stamp, since its history is in the robot's own time,
//! not the service's clock; an absolute time (RFC 3339) is source time in seconds since
//! 1970-01-01 UTC (stamps of gateways that send Unix time). Must not read a clock.

use std::ops::RangeInclusive;
use std::time::{SystemTime, UNIX_EPOCH};

use zenoh::query::{TimeBound, TimeExpr, TimeRange};

/// The whole seconds `s` of source time with `s` in `range`, `now()` being `newest_s`; an empty
/// range when `range` names `now()` and the robot has no time yet.
pub(super) fn seconds_in(range: &TimeRange, newest_s: Option<f64>) -> RangeInclusive<i64> {
    #[allow(
        clippy::reversed_empty_ranges,
        reason = "no second: the range is meant to be empty"
    )]
    const EMPTY: RangeInclusive<i64> = 1..=0;
    let at = |expr: &TimeExpr| match expr {
        TimeExpr::Fixed(time) => Some(unix_s(*time)),
        TimeExpr::Now { offset_secs } => newest_s.map(|now_s| now_s + offset_secs),
    };
    // `as` saturates at the ends of `i64`.
    let first = match &range.start {
        TimeBound::Inclusive(expr) => at(expr).map(|s| s.ceil() as i64),
        TimeBound::Exclusive(expr) => at(expr).map(|s| s.floor() as i64 + 1),
        TimeBound::Unbounded => Some(i64::MIN),
    };
    let last = match &range.end {
        TimeBound::Inclusive(expr) => at(expr).map(|s| s.floor() as i64),
        TimeBound::Exclusive(expr) => at(expr).map(|s| s.ceil() as i64 - 1),
        TimeBound::Unbounded => Some(i64::MAX),
    };
    match (first, last) {
        (Some(first), Some(last)) => first..=last,
        _ => EMPTY,
    }
}

/// `time` in seconds since 1970-01-01 UTC, negative before.
fn unix_s(time: SystemTime) -> f64 {
    match time.duration_since(UNIX_EPOCH) {
        Ok(since) => since.as_secs_f64(),
        Err(before) => -before.duration().as_secs_f64(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seconds(text: &str, newest_s: Option<f64>) -> RangeInclusive<i64> {
        let range: TimeRange = text.parse().expect("a time range");
        seconds_in(&range, newest_s)
    }

    #[test]
    fn now_is_the_robots_newest_stamp() {
        assert_eq!(seconds("[now(-10m)..]", Some(1000.5)), 401..=i64::MAX);
        assert_eq!(seconds("[now(-10s)..now(-5s)]", Some(100.0)), 90..=95);
        assert_eq!(seconds("]now(-10s)..now(-5s)[", Some(100.0)), 91..=94);
        assert_eq!(seconds("[..]", None), i64::MIN..=i64::MAX);
        assert!(seconds("[now(-10m)..]", None).is_empty());
    }

    #[test]
    fn an_absolute_time_is_unix_time() {
        // 2023-11-14T22:13:20Z is 1 700 000 000 s after 1970.
        assert_eq!(
            seconds("[2023-11-14T22:13:20Z;10s]", None),
            1_700_000_000..=1_700_000_010
        );
        assert_eq!(
            seconds("]1970-01-01T00:00:10Z..1970-01-01T00:00:20Z[", Some(5.0)),
            11..=19
        );
        assert_eq!(
            seconds("[1970-01-01T00:00:10.5Z..]", Some(5.0)),
            11..=i64::MAX
        );
    }
}
