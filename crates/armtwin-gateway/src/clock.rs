//! Stamps for a controller's samples: the controller's own clock (`timestamp`, seconds since it
//! started) plus an offset to wall time, fixed when a connection's first sample arrives. Pure:
//! the caller hands in the wall time. Must not read a clock or know the network.
//!
//! Stamps only move forward. On a new connection to a controller whose clock ran on, the offset
//! is the wall clock's or the previous one, whichever is later: a controller that was out of
//! reach for a while shows that while as a gap in its stamps, measured by its own clock, and a
//! controller whose rows arrived faster than real time never has its stamps pulled back. A
//! controller whose clock went back (it rebooted) gets an offset that puts its next stamp one
//! period after the last one published.

/// What a stamp's offset change means, for the log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OffsetChange {
    /// The first sample of a connection fixed the offset (s).
    Fixed {
        /// Wall time minus controller time.
        offset_s: f64,
    },
    /// The controller's clock went back from `from_s` to `to_s`: it restarted.
    Restarted {
        /// The controller's previous `timestamp`.
        from_s: f64,
        /// Its new one.
        to_s: f64,
        /// The new offset.
        offset_s: f64,
    },
}

/// One controller's stamps, across its connections.
#[derive(Debug, Clone)]
pub struct StampClock {
    period_s: f64,
    offset_s: Option<f64>,
    /// The next sample opens a connection.
    connection_opened: bool,
    last_controller_s: Option<f64>,
    last_stamp_s: Option<f64>,
}

impl StampClock {
    /// A clock for samples `period_s` apart.
    #[must_use]
    pub fn new(period_s: f64) -> Self {
        Self {
            period_s,
            offset_s: None,
            connection_opened: true,
            last_controller_s: None,
            last_stamp_s: None,
        }
    }

    /// A new connection: its first sample fixes the offset again.
    pub fn reconnected(&mut self) {
        self.connection_opened = true;
    }

    /// The stamp (s since the Unix epoch) of a sample the controller stamped `controller_s`,
    /// arrived at wall time `wall_s`; with the offset's change, if it changed.
    pub fn stamp(&mut self, controller_s: f64, wall_s: f64) -> (f64, Option<OffsetChange>) {
        let went_back = self
            .last_controller_s
            .is_some_and(|last_s| controller_s <= last_s);
        let mut change = None;
        if self.connection_opened || went_back || self.offset_s.is_none() {
            let wall_offset_s = wall_s - controller_s;
            let offset_s = match (self.offset_s, self.last_stamp_s) {
                (Some(_), Some(last_stamp_s)) if went_back => {
                    wall_offset_s.max(last_stamp_s + self.period_s - controller_s)
                }
                (Some(previous_s), _) => wall_offset_s.max(previous_s),
                (None, _) => wall_offset_s,
            };
            change = Some(match (went_back, self.last_controller_s) {
                (true, Some(from_s)) => OffsetChange::Restarted {
                    from_s,
                    to_s: controller_s,
                    offset_s,
                },
                _ => OffsetChange::Fixed { offset_s },
            });
            self.offset_s = Some(offset_s);
            self.connection_opened = false;
        }
        let stamp_s = controller_s + self.offset_s.unwrap_or_default();
        self.last_controller_s = Some(controller_s);
        self.last_stamp_s = Some(stamp_s);
        (stamp_s, change)
    }
}

#[cfg(test)]
#[allow(
    clippy::float_cmp,
    reason = "stamps of these tests are sums exact in binary: equality is what is meant"
)]
mod tests {
    use super::*;

    #[test]
    fn the_first_sample_fixes_the_offset_to_wall_time() {
        let mut clock = StampClock::new(0.002);
        let (stamp_s, change) = clock.stamp(10.0, 1000.0);
        assert_eq!(stamp_s, 1000.0);
        assert_eq!(change, Some(OffsetChange::Fixed { offset_s: 990.0 }));
        // Fixed for the connection: the wall clock no longer matters.
        assert_eq!(clock.stamp(10.5, 1000.1), (1000.5, None));
    }

    #[test]
    fn a_reconnection_keeps_the_controllers_gap_and_never_goes_back() {
        let mut clock = StampClock::new(0.002);
        clock.stamp(10.0, 1000.0);
        // Rows arrived faster than real time: the wall clock lags the controller's.
        assert_eq!(clock.stamp(20.0, 1001.0).0, 1010.0);
        clock.reconnected();
        // The controller's clock ran on 0.5 s while the link was down.
        let (stamp_s, change) = clock.stamp(20.5, 1001.2);
        assert_eq!(stamp_s, 1010.5);
        assert_eq!(change, Some(OffsetChange::Fixed { offset_s: 990.0 }));
        // At real pace, a later reconnection follows the wall clock again.
        clock.reconnected();
        let (stamp_s, _) = clock.stamp(21.0, 1020.0);
        assert_eq!(stamp_s, 1020.0);
    }

    #[test]
    fn a_controller_restart_continues_forward() {
        let mut clock = StampClock::new(0.002);
        clock.stamp(100.0, 1000.0);
        clock.stamp(200.0, 1001.0);
        let (stamp_s, change) = clock.stamp(0.004, 1001.5);
        assert!((stamp_s - 1100.002).abs() < 1e-9, "{stamp_s}");
        assert!(matches!(
            change,
            Some(OffsetChange::Restarted { from_s, to_s, .. }) if from_s == 200.0 && to_s == 0.004
        ));
        assert!(clock.stamp(0.006, 1001.5).0 > stamp_s);
    }
}
