//! A robot's two alarms, on its position and its angle deviation: their thresholds, which of them
//! are active, and the hold timers that decide when one fires or recovers.
//!
//! Owns the alarm state machine, stepped by one paired deviation at a time in source time. Must
//! not send events or know sinks: the twin turns each change it returns into an event.

use crate::metrics::{Deviation, Metric};

/// Alarm thresholds of one robot; a threshold of `None` disables that alarm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlarmConfig {
    /// Position deviation (m) above which the position alarm arms.
    pub position_m: Option<f64>,
    /// Rotation angle (rad) above which the orientation alarm arms.
    pub angle_rad: Option<f64>,
    /// How long (s of source time) a deviation must stay above (or, to recover, at or below) its
    /// threshold before the alarm fires (or recovers).
    pub hold_s: f64,
}

impl Default for AlarmConfig {
    fn default() -> Self {
        Self {
            position_m: None,
            angle_rad: None,
            hold_s: 0.0,
        }
    }
}

/// Which of a robot's alarms are active.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Alarms {
    /// The position alarm ([`AlarmConfig::position_m`]).
    pub position: bool,
    /// The angle alarm ([`AlarmConfig::angle_rad`]).
    pub angle: bool,
}

impl Alarms {
    /// Each alarm with the metric it watches, position first.
    #[must_use]
    pub fn by_metric(self) -> [(Metric, bool); 2] {
        [
            (Metric::Position, self.position),
            (Metric::Angle, self.angle),
        ]
    }

    /// How many are active.
    #[must_use]
    pub fn active_count(self) -> usize {
        usize::from(self.position) + usize::from(self.angle)
    }

    /// Whether any is active.
    #[must_use]
    pub fn any(self) -> bool {
        self.position || self.angle
    }
}

/// An alarm that fired (`active`) or recovered at the deviation that decided it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlarmChange {
    /// The metric the alarm watches.
    pub metric: Metric,
    /// Whether it is active from now on.
    pub active: bool,
    /// The deviation (in `unit`).
    pub value: f64,
    /// Its threshold (in `unit`).
    pub threshold: f64,
    /// The metric's unit, for the event's sentence.
    pub unit: &'static str,
}

/// One alarm's state.
#[derive(Debug, Clone, Copy, Default)]
struct AlarmState {
    active: bool,
    /// When the deviation started disagreeing with `active` (s), if it does.
    since_s: Option<f64>,
}

impl AlarmState {
    /// A deviation of `value` at `stamp_s` against `threshold`: whether the alarm changed state
    /// (the deviation disagreed with it for at least `hold_s`).
    fn update(&mut self, threshold: f64, value: f64, stamp_s: f64, hold_s: f64) -> bool {
        let disagrees = (value > threshold) != self.active;
        if !disagrees {
            self.since_s = None;
            return false;
        }
        let since_s = *self.since_s.get_or_insert(stamp_s);
        if stamp_s - since_s < hold_s {
            return false;
        }
        self.active = !self.active;
        self.since_s = None;
        true
    }
}

/// A robot's two alarms.
#[derive(Debug, Clone, Copy, Default)]
pub struct AlarmStates {
    position: AlarmState,
    angle: AlarmState,
}

impl AlarmStates {
    /// Alarms continued from a record: active as recorded, with no hold timer running.
    #[must_use]
    pub fn restored(active: Alarms) -> Self {
        let state = |active| AlarmState {
            active,
            since_s: None,
        };
        Self {
            position: state(active.position),
            angle: state(active.angle),
        }
    }

    /// Which are active.
    #[must_use]
    pub fn active(&self) -> Alarms {
        Alarms {
            position: self.position.active,
            angle: self.angle.active,
        }
    }

    /// Forgets the hold timers (the source clock restarted: a timer started on the old clock
    /// would wait for the new one to catch up); active alarms stay active.
    pub fn stop_hold_timers(&mut self) {
        self.position.since_s = None;
        self.angle.since_s = None;
    }

    /// One paired `deviation` at `stamp_s` against `config`: the alarms that changed state,
    /// position first.
    pub fn update(
        &mut self,
        config: &AlarmConfig,
        stamp_s: f64,
        deviation: &Deviation,
    ) -> [Option<AlarmChange>; 2] {
        let checks = [
            (
                Metric::Position,
                &mut self.position,
                config.position_m,
                deviation.position_m,
                "m",
            ),
            (
                Metric::Angle,
                &mut self.angle,
                config.angle_rad,
                deviation.angle_rad,
                "rad",
            ),
        ];
        checks.map(|(metric, state, threshold, value, unit)| {
            let threshold = threshold?;
            state
                .update(threshold, value, stamp_s, config.hold_s)
                .then_some(AlarmChange {
                    metric,
                    active: state.active,
                    value,
                    threshold,
                    unit,
                })
        })
    }
}
