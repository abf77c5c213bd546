//! A robot's alarms as OPC UA sees them: which changed between two readings, and the event
//! (message and severity) each change becomes.
//!
//! Pure: the server turns the changes into events and notifies them.

use crate::reading::AlarmReading;
#[cfg(test)]
use crate::reading::RobotReading;

/// Severity of a raised deviation alarm (OPC 10000-5: 601–800, medium high).
const SEVERITY_DEVIATION: u16 = 700;
/// Severity of a raised collision alarm (801–1000, high).
const SEVERITY_COLLISION: u16 = 900;
/// Severity of an alarm that cleared (1–200, low).
const SEVERITY_CLEARED: u16 = 100;

/// One of a robot's alarms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Alarm {
    /// The twin's position deviation.
    Position,
    /// The twin's orientation deviation.
    Angle,
    /// A collision on any joint.
    Collision,
}

/// Which of a robot's alarms are on.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct AlarmStates {
    position: bool,
    angle: bool,
    collision: bool,
}

/// An alarm raised or cleared.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct AlarmChange {
    pub(crate) alarm: Alarm,
    pub(crate) raised: bool,
}

impl AlarmStates {
    /// The alarms on in `reading`.
    #[cfg(test)]
    pub(crate) fn of(reading: &RobotReading) -> Self {
        Self {
            position: reading.position_alarm,
            angle: reading.angle_alarm,
            collision: reading.collision.iter().any(|&on| on),
        }
    }

    /// The alarms on in `reading`.
    pub(crate) fn from_alarms(reading: AlarmReading) -> Self {
        Self {
            position: reading.position,
            angle: reading.angle,
            collision: reading.collision,
        }
    }

    /// Whether any alarm is on.
    pub(crate) fn any(self) -> bool {
        self.position || self.angle || self.collision
    }

    /// What changed from `self` to `next`.
    pub(crate) fn changes(self, next: Self) -> impl Iterator<Item = AlarmChange> {
        [
            (Alarm::Position, self.position, next.position),
            (Alarm::Angle, self.angle, next.angle),
            (Alarm::Collision, self.collision, next.collision),
        ]
        .into_iter()
        .filter(|(_, before, after)| before != after)
        .map(|(alarm, _, raised)| AlarmChange { alarm, raised })
    }
}

impl AlarmChange {
    /// The event's message about `robot`.
    pub(crate) fn message(self, robot: &str) -> String {
        let what = match self.alarm {
            Alarm::Position => "position deviation alarm",
            Alarm::Angle => "orientation deviation alarm",
            Alarm::Collision => "collision alarm",
        };
        let how = if self.raised { "raised" } else { "cleared" };
        format!("{robot}: {what} {how}")
    }

    /// The event's severity (1–1000).
    pub(crate) fn severity(self) -> u16 {
        match (self.raised, self.alarm) {
            (false, _) => SEVERITY_CLEARED,
            (true, Alarm::Collision) => SEVERITY_COLLISION,
            (true, Alarm::Position | Alarm::Angle) => SEVERITY_DEVIATION,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raising_and_clearing_each_make_one_change() {
        let calm = AlarmStates::default();
        let deviating = AlarmStates::of(&RobotReading {
            position_alarm: true,
            collision: vec![false, true],
            ..RobotReading::default()
        });
        let raised: Vec<_> = calm.changes(deviating).collect();
        assert_eq!(
            raised,
            [
                AlarmChange {
                    alarm: Alarm::Position,
                    raised: true
                },
                AlarmChange {
                    alarm: Alarm::Collision,
                    raised: true
                },
            ]
        );
        assert_eq!(deviating.changes(deviating).count(), 0);
        let cleared: Vec<_> = deviating.changes(calm).collect();
        assert!(
            cleared
                .iter()
                .all(|change| !change.raised && change.severity() == SEVERITY_CLEARED)
        );
        assert_eq!(
            raised[0].message("ur10e-1"),
            "ur10e-1: position deviation alarm raised"
        );
        assert!(raised[1].severity() > raised[0].severity());
    }
}
