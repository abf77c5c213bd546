//! The twin's effort glue: its effort monitor built from the robot's settings and stepped with
//! each accepted joint sample (the readout to the sink, alarm changes as event details). Must
//! not know the twin: the twin holds the monitor and publishes the events. The monitoring itself is
//! [`crate::dynamics::monitor`]'s.

use super::{EventDetail, EventKind, PipelineConfig, Robot, Sink};
use crate::dynamics::monitor::{EffortAlarm, EffortMonitor};
use crate::sample::{JointSample, JointState};

/// Steps `monitor` with an accepted joint sample of `robot`: its readout to the sink; its alarm
/// changes returned as events' kinds and details (at most one per joint and one of the payload),
/// for the twin to publish as its own events.
pub(super) fn step_effort(
    monitor: &mut EffortMonitor,
    robot: &Robot,
    stamp_s: f64,
    sample: &JointSample,
    sink: &mut impl Sink,
) -> [Option<(EventKind, EventDetail)>; 8] {
    let empty = JointState::default();
    let state = sample.state.as_deref().unwrap_or(&empty);
    let mut alarms = [None; 8];
    let mut count = 0;
    let readout = monitor.step(stamp_s, &sample.q_rad, state, |alarm| {
        if let Some(slot) = alarms.get_mut(count) {
            *slot = Some(alarm);
            count += 1;
        }
    });
    if let Some(readout) = readout {
        sink.effort(robot, &readout);
    }
    alarms.map(|alarm| {
        let alarm = alarm?;
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
        Some((kind, detail))
    })
}

/// The effort monitor `robot`'s settings ask for. The configuration checked the arm when it was
/// loaded; an arm that still cannot be watched (a model replaced by one of another size) is
/// watched by none.
pub(super) fn effort_monitor(robot: &Robot, config: &PipelineConfig) -> Option<Box<EffortMonitor>> {
    let effort = robot.settings().effort.as_ref()?;
    EffortMonitor::new(robot.settings().model.arm(), effort, config.window_s)
        .ok()
        .map(Box::new)
}
