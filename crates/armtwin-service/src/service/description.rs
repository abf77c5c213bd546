//! A robot's own description (a URDF: on `<prefix>/description/<robot>`, or from a ROS 2
//! `/robot_description` through a `stream = "description"` source), taken into its twin as a
//! controller's TCP is: a robot whose own section sets its model has it checked against that
//! model, and a disagreement refused; any other computes with it from then on, in a new metrics
//! epoch. Each outcome is an event (`kind` `description`) on the robot's events key; each
//! refusal is counted too.
//!
//! The text is untrusted: at most [`MAX_URDF_BYTES`], parsed once per distinct text and at most
//! once per [`MIN_INTERVAL`] per robot, outside the robot's lock.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash as _, Hasher as _};
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde_json::json;
use tracing::debug;

use super::fleet::{DescriptionSeen, Fleet, Lookup, Stepping};
use armtwin_core::model::urdf::{self, MAX_URDF_BYTES};
use armtwin_core::model::{ArmDescription, RobotModel};

/// Two descriptions of a robot are at least this far apart: each parse of an untrusted text of
/// up to [`MAX_URDF_BYTES`] costs milliseconds, and a robot's description changes when it is
/// rebuilt, not at a sample's rate.
pub(super) const MIN_INTERVAL: Duration = Duration::from_secs(1);

/// A description agrees with a model when their poses agree to this (m, and per rotation
/// entry) at every probe: rounding of the file's decimal origins, far below any calibration.
const AGREEMENT: f64 = 1e-9;

/// Takes a description of robot `id` (`text` as it arrived, untrusted, or why its message held
/// none), from `origin` (its key, for the events).
pub(super) fn take_description(
    fleet: &Fleet,
    id: &str,
    origin: &str,
    text: &Result<&[u8], String>,
) {
    let cell = match fleet.lookup(id) {
        Lookup::Found(cell) => cell,
        Lookup::Foreign | Lookup::Refused(_) => {
            debug!(
                robot = id,
                "description of a robot not twinned here: ignored"
            );
            return;
        }
    };
    let robot = cell.robot().clone();
    let payload: &[u8] = text.as_ref().map_or(&[], |bytes| bytes);
    let digest = {
        let mut hasher = DefaultHasher::new();
        payload.hash(&mut hasher);
        hasher.finish()
    };
    // First, under the lock, whether to read it at all.
    let mut read = false;
    let stepped = fleet.step(&cell, |stepping| {
        let Stepping {
            mut sink,
            description,
            ..
        } = stepping;
        let now = Instant::now();
        let refusal = if let Err(error) = text {
            Some(format!(
                "the robot's description (on {origin}) is refused: {error}"
            ))
        } else if payload.len() > MAX_URDF_BYTES {
            Some(format!(
                "the robot's description ({} bytes, on {origin}) is refused: over {MAX_URDF_BYTES} \
                 bytes",
                payload.len()
            ))
        } else {
            match description.as_deref() {
                Some(seen) if seen.digest == digest => return,
                Some(seen) if now.duration_since(seen.at) < MIN_INTERVAL => Some(format!(
                    "the robot's description (on {origin}) is refused: another came {:.0} ms \
                     before, and a robot's description is read once a second at most",
                    now.duration_since(seen.at).as_secs_f64() * 1e3
                )),
                _ => None,
            }
        };
        if let Some(reason) = refusal {
            fleet.description_refused();
            let detail = json!({"origin": origin, "in_use": false, "bytes": payload.len()});
            sink.mesh_event(robot.id(), "description", &reason, &detail);
        } else {
            *description = Some(Box::new(DescriptionSeen { digest, at: now }));
            read = true;
        }
    });
    if !stepped || !read {
        return;
    }
    // Parsed outside the lock: the robot's samples do not wait for it.
    let ends = fleet.descriptions().ends(id);
    let arm = std::str::from_utf8(payload)
        .map_err(|e| format!("not UTF-8 text: {e}"))
        .and_then(|text| {
            urdf::arm_from_urdf(
                text,
                origin,
                ends.base_link.as_deref(),
                ends.tip_link.as_deref(),
            )
            .map_err(|e| e.to_string())
        });
    let own_model = fleet.descriptions().has_own_model(id);
    // A robot retired since is looked up again, as a sample's would be.
    let mut cell = cell;
    loop {
        let arm = arm.clone();
        if fleet.step(&cell, |stepping| {
            apply(fleet, &robot, origin, own_model, arm, stepping);
        }) {
            return;
        }
        match fleet.lookup(id) {
            Lookup::Found(again) => cell = again,
            Lookup::Foreign | Lookup::Refused(_) => return,
        }
    }
}

/// The description's arm into `robot`'s twin, with its event.
fn apply(
    fleet: &Fleet,
    robot: &armtwin_core::pipeline::Robot,
    origin: &str,
    own_model: bool,
    arm: Result<ArmDescription, String>,
    stepping: Stepping<'_>,
) {
    let Stepping { twin, mut sink, .. } = stepping;
    let id = robot.id();
    let current = Arc::clone(twin.model());
    let candidate = arm.and_then(|arm| {
        RobotModel::new(arm, None, *current.tool(), current.frame()).map_err(|e| e.to_string())
    });
    let candidate = match candidate {
        Ok(model) => model,
        Err(error) => {
            refuse(
                fleet,
                &mut sink,
                id,
                &format!("the robot's description (on {origin}) is refused: {error}"),
                &json!({"origin": origin, "in_use": false, "error": error}),
            );
            return;
        }
    };
    let name = candidate.arm().name.clone();
    let joints = candidate.joint_count();
    // Checked against the robot's own model, else against the one in use.
    let against = if own_model {
        Arc::clone(&robot.settings().model)
    } else {
        Arc::clone(&current)
    };
    let difference = against.pose_difference(&candidate);
    let detail = |in_use: bool| {
        json!({
            "origin": origin,
            "in_use": in_use,
            "joints": joints,
            "name": name,
            "position_difference_m": difference.map(|d| d.position_m),
            "rotation_difference": difference.map(|d| d.rotation),
        })
    };
    let apart = match difference {
        Some(d) => format!("by up to {:.6} m", d.position_m),
        None => format!("in its joints ({joints} against {})", against.joint_count()),
    };
    if let Some(d) = difference.filter(|d| d.within(AGREEMENT)) {
        let reason = format!(
            "the robot's description (on {origin}, '{name}') agrees with the model {} ({} m at \
             most): nothing changes",
            against.arm().name,
            d.position_m
        );
        sink.mesh_event(id, "description", &reason, &detail(!own_model));
        return;
    }
    if own_model {
        refuse(
            fleet,
            &mut sink,
            id,
            &format!(
                "the robot's description (on {origin}, '{name}') differs from its configured \
                 model {} {apart}: the twin keeps the configured model",
                against.arm().name
            ),
            &detail(false),
        );
        return;
    }
    let reason = format!(
        "the robot's description (on {origin}, '{name}', {joints} joints) differs from {} \
         {apart}: the twin computes with the description",
        current.arm().name
    );
    let candidate = Arc::new(candidate);
    match twin.replace_model(Arc::clone(&candidate), &mut sink) {
        Ok(_) => {
            sink.model_replaced(robot, &candidate);
            sink.mesh_event(id, "description", &reason, &detail(true));
        }
        // The effort monitor or the self-calibration rides on the old joints.
        Err(error) => refuse(
            fleet,
            &mut sink,
            id,
            &format!("the robot's description (on {origin}, '{name}') is refused: {error}"),
            &detail(false),
        ),
    }
}

/// A refused description: counted, and said on the robot's events key.
fn refuse(
    fleet: &Fleet,
    sink: &mut super::sink::ZenohSink<'_>,
    id: &str,
    reason: &str,
    detail: &serde_json::Value,
) {
    fleet.description_refused();
    sink.mesh_event(id, "description", reason, detail);
}
