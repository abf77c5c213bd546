//! A robot's alarms as OPC UA sees them: which changed between two readings, and what each
//! alarm is called and how severe it is. [`crate::conditions`] makes conditions of them.
//!
//! Pure.

use crate::reading::AlarmReading;
#[cfg(test)]
use crate::reading::RobotReading;

/// Severity of a raised deviation alarm (OPC 10000-5: 601–800, medium high).
const SEVERITY_DEVIATION: u16 = 700;
/// Severity of a raised payload alarm (401–600, medium): the twin's dynamics are off, not the arm.
const SEVERITY_PAYLOAD: u16 = 500;
/// Severity of a raised collision alarm (801–1000, high).
const SEVERITY_COLLISION: u16 = 900;
/// Severity of an alarm that cleared (1–200, low).
const SEVERITY_CLEARED: u16 = 100;

/// One of a robot's alarms.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub(crate) enum Alarm {
    /// The twin's position deviation.
    Position,
    /// The twin's orientation deviation.
    Angle,
    /// A collision on any joint.
    Collision,
    /// The identified payload differs from the modelled one.
    Payload,
}

impl Alarm {
    /// Every alarm, in the order of their condition names.
    pub(crate) const ALL: [Self; 4] = [Self::Position, Self::Angle, Self::Collision, Self::Payload];

    /// The condition's name, also the last part of its node id.
    pub(crate) fn name(self) -> &'static str {
        match self {
            Self::Position => "PositionDeviation",
            Self::Angle => "OrientationDeviation",
            Self::Collision => "Collision",
            Self::Payload => "Payload",
        }
    }

    /// The alarm named `name`.
    pub(crate) fn named(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|alarm| alarm.name() == name)
    }

    /// The alarm, for people.
    pub(crate) fn describe(self) -> &'static str {
        match self {
            Self::Position => "position deviation alarm",
            Self::Angle => "orientation deviation alarm",
            Self::Collision => "collision alarm",
            Self::Payload => "payload alarm",
        }
    }

    /// Its severity (1–1000) when `active`, and once cleared.
    pub(crate) fn severity(self, active: bool) -> u16 {
        match (active, self) {
            (false, _) => SEVERITY_CLEARED,
            (true, Self::Collision) => SEVERITY_COLLISION,
            (true, Self::Position | Self::Angle) => SEVERITY_DEVIATION,
            (true, Self::Payload) => SEVERITY_PAYLOAD,
        }
    }
}

/// Which of a robot's alarms are on.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[expect(
    clippy::struct_excessive_bools,
    reason = "independent alarms, any of them on"
)]
pub(crate) struct AlarmStates {
    position: bool,
    angle: bool,
    collision: bool,
    payload: bool,
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
            payload: false,
        }
    }

    /// The alarms on in `reading`.
    pub(crate) fn from_alarms(reading: AlarmReading) -> Self {
        Self {
            position: reading.position,
            angle: reading.angle,
            collision: reading.collision,
            payload: reading.payload,
        }
    }

    /// Whether any alarm is on.
    pub(crate) fn any(self) -> bool {
        self.position || self.angle || self.collision || self.payload
    }

    /// What changed from `self` to `next`.
    pub(crate) fn changes(self, next: Self) -> impl Iterator<Item = AlarmChange> {
        [
            (Alarm::Position, self.position, next.position),
            (Alarm::Angle, self.angle, next.angle),
            (Alarm::Collision, self.collision, next.collision),
            (Alarm::Payload, self.payload, next.payload),
        ]
        .into_iter()
        .filter(|(_, before, after)| before != after)
        .map(|(alarm, _, raised)| AlarmChange { alarm, raised })
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
        assert!(cleared.iter().all(|change| !change.raised));
        assert!(
            Alarm::Collision.severity(true) > Alarm::Position.severity(true)
                && Alarm::Position.severity(false) == SEVERITY_CLEARED
        );
        assert!(
            Alarm::ALL
                .into_iter()
                .all(|alarm| Alarm::named(alarm.name()) == Some(alarm))
        );
    }
}
