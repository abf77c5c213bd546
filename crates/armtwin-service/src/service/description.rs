//! A robot's own description (a URDF: on `<prefix>/description/<robot>`, or from a ROS 2
//! `/robot_description` through a `stream = "description"` source), taken into its twin as a
//! controller's TCP is: a robot whose own section sets its model has it checked against that
//! model, and a disagreement refused; any other computes with it from then on, in a new metrics
//! epoch. Each outcome is an event (`kind` `description`) on the robot's events key; each
//! refusal is counted too.
//!
//! The text is untrusted: at most [`MAX_URDF_BYTES`] and [`MAX_ARM_JOINTS`], read within a
//! robot's [`READS`] budget (the same text as the last one read is not read again), parsed
//! outside the robot's lock.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash as _, Hasher as _};
use std::sync::Arc;
use std::time::Instant;

use serde_json::json;
use tracing::debug;

use super::events::EventBucket;
use super::fleet::{DescriptionSeen, Fleet, Lookup, Stepping};
use crate::config::EventBudget;
use armtwin_codec::cdr::MAX_ARM_JOINTS;
use armtwin_core::model::urdf::{self, MAX_URDF_BYTES};
use armtwin_core::model::{ArmDescription, RobotModel};

/// The descriptions a robot's twin reads: a few at once (a start's query racing a gateway's
/// put, a driver restarted: the newest is not lost), then a slow trickle. Each is an untrusted
/// text of up to [`MAX_URDF_BYTES`] to parse, and a robot's description changes when it is
/// rebuilt, not at a sample's rate.
const READS: EventBudget = EventBudget {
    per_s: 1.0,
    burst: 4,
};

/// The refusals before reading a robot's events key says: few, so that a flood cannot
/// push the robot's alarms out of its recent events. Every one is counted.
const REFUSALS_SAID: EventBudget = EventBudget {
    per_s: 1.0,
    burst: 1,
};

/// A hash of a description's text: the same text again is not read again.
fn digest_of(text: &[u8]) -> u64 {
    let mut hasher = DefaultHasher::new();
    text.hash(&mut hasher);
    hasher.finish()
}

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
    // Hashed before the robot's lock: its samples do not wait for it.
    let digest = match text {
        Ok(payload) if payload.len() <= MAX_URDF_BYTES => Some(digest_of(payload)),
        _ => None,
    };
    // First, under the lock, whether to read it at all.
    let mut read: Option<&[u8]> = None;
    let stepped = fleet.step(&cell, |stepping| {
        let Stepping {
            mut sink,
            description,
            ..
        } = stepping;
        let now = Instant::now();
        let seen = description.get_or_insert_with(|| {
            Box::new(DescriptionSeen {
                digest: None,
                reads: EventBucket::full(READS, now),
                refusals: EventBucket::full(REFUSALS_SAID, now),
            })
        });
        match gate(seen, text, digest, origin, now) {
            Gate::Same => {}
            Gate::Read(payload) => read = Some(payload),
            Gate::Refused(why, detail) => {
                fleet.description_refused();
                if seen.refusals.pass(REFUSALS_SAID, now, false).is_ok() {
                    let reason = format!("the robot's description (on {origin}) is refused: {why}");
                    sink.mesh_event(robot.id(), "description", &reason, &detail);
                }
            }
        }
    });
    let Some(payload) = read.filter(|_| stepped) else {
        return;
    };
    // Parsed outside the lock: the robot's samples do not wait for it.
    let arm = arm_of(fleet, id, origin, payload);
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

/// What becomes of a description as it arrives.
enum Gate<'t> {
    /// The last text read, again.
    Same,
    /// To be read.
    Read(&'t [u8]),
    /// Refused: why, and the event's detail.
    Refused(String, serde_json::Value),
}

/// Whether `text` (whose hash is `digest`, if it is not too large) is read, given what `seen`
/// keeps of the robot's descriptions.
fn gate<'t>(
    seen: &mut DescriptionSeen,
    text: &'t Result<&'t [u8], String>,
    digest: Option<u64>,
    origin: &str,
    now: Instant,
) -> Gate<'t> {
    let payload = match text {
        Err(error) => {
            return Gate::Refused(
                error.clone(),
                json!({"origin": origin, "in_use": false, "error": error}),
            );
        }
        Ok(payload) => *payload,
    };
    let Some(digest) = digest else {
        return Gate::Refused(
            format!("{} bytes, over {MAX_URDF_BYTES}", payload.len()),
            json!({"origin": origin, "in_use": false, "bytes": payload.len()}),
        );
    };
    if seen.digest == Some(digest) {
        return Gate::Same;
    }
    if seen.reads.pass(READS, now, false).is_err() {
        let why = format!(
            "more than {} descriptions at once, and {} a second after: this one is not read",
            READS.burst, READS.per_s
        );
        let detail = json!({"origin": origin, "in_use": false, "error": why});
        return Gate::Refused(why, detail);
    }
    seen.digest = Some(digest);
    Gate::Read(payload)
}

/// The arm of a description's text, its chain between robot `id`'s configured links.
fn arm_of(fleet: &Fleet, id: &str, origin: &str, payload: &[u8]) -> Result<ArmDescription, String> {
    let ends = fleet.descriptions().ends(id);
    let text = std::str::from_utf8(payload).map_err(|e| format!("not UTF-8 text: {e}"))?;
    let arm = urdf::arm_from_urdf(
        text,
        origin,
        ends.base_link.as_deref(),
        ends.tip_link.as_deref(),
    )
    .map_err(|e| e.to_string())?;
    let joints = arm.joint_limits.len();
    if joints > MAX_ARM_JOINTS {
        return Err(format!(
            "its chain has {joints} joints, over {MAX_ARM_JOINTS}"
        ));
    }
    Ok(arm)
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
    // Checked against the robot's own model, else against the one in use; with that model's
    // tool and frame, so that only the arm is compared.
    let against = if own_model {
        Arc::clone(&robot.settings().model)
    } else {
        Arc::clone(&current)
    };
    let candidate = arm.and_then(|arm| {
        RobotModel::new(arm, None, *against.tool(), against.frame()).map_err(|e| e.to_string())
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
            fleet.remember_description(robot, &candidate);
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
