//! The twin's effort glue: its effort monitor built from the robot's settings, stepped with each
//! accepted joint sample (the readout to the sink, alarm changes as events), and what the
//! monitor shows or is told through the twin. The monitoring itself is
//! [`crate::dynamics::monitor`]'s.

use super::twin::Twin;
use super::{EventDetail, EventKind, Reason, Sink};
use crate::dynamics::Payload;
use crate::dynamics::monitor::{EffortAlarm, EffortMonitor, EffortSummary, MAX_EFFORT_JOINTS};
use crate::sample::{JointSample, JointState};

impl Twin {
    /// Steps the effort monitor, if the robot has one: its readout to the sink, its alarms as
    /// events.
    pub(super) fn step_effort(
        &mut self,
        key: &str,
        stamp_s: f64,
        sample: &JointSample,
        sink: &mut impl Sink,
    ) {
        let Some(monitor) = &mut self.effort else {
            return;
        };
        let empty = JointState::default();
        let state = sample.state.as_deref().unwrap_or(&empty);
        // At most one change per joint and one of the payload per sample.
        let mut alarms = [None; MAX_EFFORT_JOINTS + 1];
        let mut count = 0;
        let readout = monitor.step(stamp_s, &sample.q_rad, state, |alarm| {
            if let Some(slot) = alarms.get_mut(count) {
                *slot = Some(alarm);
                count += 1;
            }
        });
        if let Some(readout) = readout {
            sink.effort(&self.robot, &readout);
        }
        for alarm in alarms.into_iter().flatten() {
            let (kind, detail) = match alarm {
                EffortAlarm::Collision {
                    joint,
                    value_nm,
                    threshold_nm,
                    on,
                } => (
                    on,
                    EventDetail::Collision {
                        joint: joint + 1,
                        value_nm,
                        threshold_nm,
                    },
                ),
                EffortAlarm::Payload {
                    estimated_kg,
                    std_kg,
                    modelled_kg,
                    tolerance_kg,
                    on,
                } => (
                    on,
                    EventDetail::Payload {
                        estimated_kg,
                        std_kg,
                        modelled_kg,
                        tolerance_kg,
                    },
                ),
            };
            let kind = if kind {
                EventKind::Alarm
            } else {
                EventKind::Recovered
            };
            sink.event(&self.event(stamp_s, kind, Some(key), detail, Reason::Effort));
        }
    }

    /// What its effort monitor shows, if it has one.
    #[must_use]
    pub fn effort(&self) -> Option<EffortSummary> {
        self.effort.as_ref().map(EffortMonitor::summary)
    }

    /// Applies the identified payload to its effort model; `None` without an effort monitor or
    /// an estimate.
    pub fn apply_payload_estimate(&mut self) -> Option<Payload> {
        self.dirty = true;
        self.effort.as_mut()?.apply_estimate()
    }

    /// Drops an applied payload; `false` without an effort monitor.
    pub fn discard_applied_payload(&mut self) -> bool {
        self.dirty = true;
        self.effort
            .as_mut()
            .map(EffortMonitor::discard_applied)
            .is_some()
    }
}
