//! The OPC UA server's read of the fleet ([`TwinSource`]): the twinned robots' ids, one robot's
//! state copied out under its lock when a client reads or monitors it, and every robot's alarm
//! flags at the server's sampling interval; never on the sample path.
//!
//! Must not keep anything between reads.

use std::sync::Arc;

use armtwin_opcua::{
    AlarmReading, ControllerReading, DeviationStats, IdentifiedPayload, PayloadReading,
    PoseReading, RobotReading, TwinSource,
};

use super::fleet::Fleet;
use armtwin_core::dynamics::Payload;
use armtwin_core::metrics::{Metric, StatsSet};
use armtwin_core::pipeline::RobotState;
use armtwin_core::sample::{JointQuantity, JointState};
use armtwin_mesh::controller::ControllerFacts;

/// The fleet as the OPC UA server reads it.
pub(super) struct OpcUaView {
    fleet: Arc<Fleet>,
}

impl OpcUaView {
    pub(super) fn new(fleet: Arc<Fleet>) -> Self {
        Self { fleet }
    }
}

impl TwinSource for OpcUaView {
    fn robot_ids(&self, ids: &mut Vec<Arc<str>>) {
        ids.clear();
        self.fleet.for_each_cell(|cell| {
            let guard = cell.lock();
            if !guard.is_retired() && guard.twin().is_some() {
                ids.push(Arc::clone(cell.robot().shared_id()));
            }
        });
    }

    fn read_robot(&self, id: &str) -> Option<RobotReading> {
        let cell = self.fleet.existing_cell_of(id)?;
        let guard = cell.lock();
        if guard.is_retired() {
            return None;
        }
        let twin = guard.twin()?;
        Some(reading_of(
            Arc::clone(cell.robot().shared_id()),
            &twin.state(),
            guard.controller(),
        ))
    }

    fn read_alarms(&self, visit: &mut dyn FnMut(&Arc<str>, AlarmReading)) {
        self.fleet.for_each_cell(|cell| {
            let alarms = {
                let guard = cell.lock();
                if guard.is_retired() {
                    return;
                }
                let Some(twin) = guard.twin() else {
                    return;
                };
                let state = twin.state();
                let effort = state.metrics.effort.as_deref();
                AlarmReading {
                    position: state.alarms_active.position,
                    angle: state.alarms_active.angle,
                    collision: effort.is_some_and(|effort| effort.collision.iter().any(|&on| on)),
                    payload: effort.is_some_and(|effort| effort.payload_mismatch),
                }
            };
            visit(cell.robot().shared_id(), alarms);
        });
    }
}

fn stats_of(set: &StatsSet) -> DeviationStats {
    let position = set.of(Metric::Position);
    let angle = set.of(Metric::Angle);
    DeviationStats {
        samples: set.n,
        position_rmse_m: position.rmse,
        position_max_m: position.max,
        angle_rmse_rad: angle.rmse,
        angle_max_rad: angle.max,
    }
}

fn payload_of(payload: &Payload) -> PayloadReading {
    PayloadReading {
        mass_kg: payload.mass_kg,
        cog_m: payload.cog_flange_m,
    }
}

/// One robot's reading, from its twin's state and what its gateway said of its controller.
fn reading_of(
    id: Arc<str>,
    state: &RobotState<'_>,
    facts: Option<&ControllerFacts>,
) -> RobotReading {
    let joint_state: Option<&JointState> = state.last_state.map(|(_, joint_state)| joint_state);
    let quantity = |quantity| {
        joint_state
            .and_then(|joint_state| joint_state.get(quantity))
            .map(<[f64]>::to_vec)
    };
    let effort = state.metrics.effort.as_deref();
    let model = state.model;
    RobotReading {
        id,
        model: model.arm().name.clone(),
        serial_number: facts.and_then(|facts| facts.serial.clone()),
        joint_count: model.joint_count(),
        stamp_s: state.metrics.stamp_s,
        positions_rad: state.last_joints.map(|(_, q)| q.to_vec()),
        velocities_rad_s: quantity(JointQuantity::Velocity),
        temperatures_c: quantity(JointQuantity::Temperature),
        currents_a: quantity(JointQuantity::Current),
        torques_nm: quantity(JointQuantity::Torque),
        controller: joint_state
            .and_then(|joint_state| joint_state.status)
            .map(|status| ControllerReading {
                robot_mode: status.robot_mode,
                safety_mode: status.safety_mode,
                speed_scaling: status.speed_scaling,
                program_running: status.program_running(),
                freedrive: status.freedrive(),
            }),
        // The effort monitor's view of the configured payload when it watches the robot, else
        // the controller's report.
        configured_payload: effort
            .and_then(|effort| effort.payload.configured.map(|(payload, _)| payload))
            .as_ref()
            .map(payload_of)
            .or_else(|| {
                joint_state
                    .and_then(|joint_state| joint_state.payload)
                    .map(|payload| PayloadReading {
                        mass_kg: payload.mass_kg,
                        cog_m: payload.cog_m,
                    })
            }),
        applied_payload: effort
            .and_then(|effort| effort.payload.applied)
            .as_ref()
            .map(payload_of),
        identified_payload: effort
            .and_then(|effort| effort.payload.estimate)
            .map(|estimate| IdentifiedPayload {
                mass_kg: estimate.mass_kg,
                mass_std_kg: estimate.mass_std_kg,
                samples: estimate.samples,
            }),
        twin_pose: state.last_twin_pose.map(|(_, pose)| PoseReading {
            position_m: pose.position_m,
            quaternion_xyzw: pose.quaternion_xyzw,
        }),
        cumulative: stats_of(&state.metrics.cumulative),
        window: stats_of(&state.metrics.window),
        window_s: state.metrics.window_s,
        position_alarm: state.alarms_active.position,
        angle_alarm: state.alarms_active.angle,
        collision: effort.map_or_else(Vec::new, |effort| effort.collision.to_vec()),
        collisions: effort.map_or(0, |effort| effort.collisions),
        calibration: model
            .calibration()
            .map_or_else(|| "nominal".to_owned(), |c| c.source_name.clone()),
    }
}
