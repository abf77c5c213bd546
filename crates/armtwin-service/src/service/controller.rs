//! What gateways read of the robots' controllers ([`ControllerFacts`], on
//! `<prefix>/controller/<robot>`), taken into the twins: the controller's TCP becomes the twin's
//! tool unless the configuration sets one (a new metrics epoch, as any model change), a model
//! that disagrees with the configured one and a dashboard server that could not be read are
//! events on the robot's events key, and the facts are kept for the state answer and the
//! dashboard.
//!
//! Must not block beyond the robot's own lock and its outputs' puts.

use serde_json::json;
use tracing::{debug, warn};

use super::fleet::{Fleet, Lookup, Stepping};
use std::sync::Arc;

use armtwin_core::kinematics::TcpOffset;
use armtwin_core::model::{RobotModel, catalog};
use armtwin_core::pipeline::Robot;
use armtwin_mesh::controller::ControllerFacts;

/// Who gives a tool taken from the controller, in the epoch event's sentence.
const TOOL_SOURCE: &str = "the controller";

/// Takes a facts message of robot `id` (`payload` as it arrived, untrusted).
pub(super) fn take_facts(fleet: &Fleet, id: &str, payload: &[u8]) {
    let facts = match ControllerFacts::from_json(payload) {
        Ok(facts) => facts,
        Err(error) => {
            warn!(robot = id, %error, "controller facts refused");
            return;
        }
    };
    // A robot retired between its look-up and its lock is looked up again (as a sample is).
    loop {
        match fleet.lookup(id) {
            Lookup::Found(cell) => {
                let robot = cell.robot().clone();
                let taken = Taken {
                    tool: !fleet.tool_configured(id),
                    // The robot's own description, once taken, says more than its model's name.
                    model: fleet.model_from_controller(id) && fleet.taken_description(id).is_none(),
                };
                let facts = facts.clone();
                if fleet.step(&cell, |stepping| {
                    apply(&robot, taken, facts, stepping);
                }) {
                    return;
                }
            }
            Lookup::Foreign | Lookup::Refused(_) => {
                debug!(
                    robot = id,
                    "controller facts of a robot not twinned here: ignored"
                );
                return;
            }
        }
    }
}

/// What of the controller's a robot's twin takes: its TCP (unless the configuration sets one),
/// its model (for a robot `serve` streams with no model of its own).
#[derive(Debug, Clone, Copy)]
struct Taken {
    tool: bool,
    model: bool,
}

/// The facts into `robot`'s twin, with an event for each that changed and matters.
fn apply(robot: &Robot, taken: Taken, facts: ControllerFacts, stepping: Stepping<'_>) {
    let Stepping {
        twin,
        mut sink,
        controller,
        ..
    } = stepping;
    let id = robot.id();
    let previous = controller.replace(facts).unwrap_or_default();
    let Some(facts) = controller.as_ref() else {
        return;
    };
    if let Some(tcp_offset) = facts.tcp_offset
        && previous.tcp_offset != facts.tcp_offset
    {
        let in_use = taken.tool;
        let reason = if in_use {
            format!("the controller's TCP is tcp_offset {tcp_offset:?}: the twin uses it")
        } else {
            format!(
                "the controller's TCP is tcp_offset {tcp_offset:?}; the configured tcp {:?} \
                 stays in use",
                twin.model().tool().to_ur_pose()
            )
        };
        let detail = json!({"fact": "tcp_offset", "tcp_offset": tcp_offset, "in_use": in_use});
        sink.controller_event(id, &reason, &detail);
        if in_use && let Some(tool) = TcpOffset::from_ur_pose(tcp_offset) {
            match twin.replace_tool(tool, TOOL_SOURCE, &mut sink) {
                Ok(Some(_)) => sink.model_replaced(robot, twin.model()),
                Ok(None) => {}
                Err(error) => {
                    warn!(robot = id, %error, "the controller's TCP cannot be the twin's tool");
                }
            }
        }
    }
    let configured = &robot.settings().model.arm().name;
    let model_news = facts.catalog_model() != previous.catalog_model();
    if facts.model_agrees(configured) == Some(false)
        && let Some(model) = facts.catalog_model()
    {
        let serial = facts.serial.as_deref().unwrap_or("unknown");
        // Taken once per twin: a twin made again (after a retirement) takes it again.
        let take = taken.model && twin.model().arm().name != model;
        let detail = |in_use: bool| {
            json!({
                "fact": "model",
                "configured": configured,
                "controller": model,
                "serial": facts.serial,
                "in_use": in_use,
            })
        };
        if take {
            let reason = format!(
                "the controller is a {model} (serial number {serial}); the robot names no model \
                 of its own: the twin computes with {model}"
            );
            sink.controller_event(id, &reason, &detail(true));
            take_model(id, &model, twin, &mut sink);
            sink.model_replaced(robot, twin.model());
        } else if model_news && !taken.model {
            let reason = format!(
                "the controller is a {model} (serial number {serial}), the configuration says \
                 {configured}: the twin computes with {configured}"
            );
            sink.controller_event(id, &reason, &detail(false));
        }
    }
    if let Some(error) = &facts.dashboard_error
        && previous.dashboard_error.as_ref() != Some(error)
    {
        let reason = format!(
            "the controller's dashboard server could not be read ({error}): its model and \
             serial number are unknown, the model is not checked"
        );
        sink.controller_event(id, &reason, &json!({"fact": "dashboard", "error": error}));
    }
}

/// `twin` computes with the catalog's `model` from now on, its tool and output frame kept: a new
/// metrics epoch, as any model replaced.
fn take_model(
    id: &str,
    model: &str,
    twin: &mut armtwin_core::pipeline::Twin,
    sink: &mut impl armtwin_core::pipeline::Sink,
) {
    let current = twin.model();
    let replaced = catalog::arm(model)
        .and_then(|arm| RobotModel::new(arm, None, *current.tool(), current.frame()))
        .map_err(|e| e.to_string())
        .and_then(|model| {
            twin.replace_model(Arc::new(model), sink)
                .map_err(|e| e.to_string())
        });
    if let Err(error) = replaced {
        warn!(robot = id, model, %error, "the controller's model cannot be the twin's");
    }
}
