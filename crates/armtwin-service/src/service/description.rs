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

/// A robot's descriptions are read [`BURST`] at once and one per this interval after (a token
/// bucket): each parse of an untrusted text of up to [`MAX_URDF_BYTES`] costs milliseconds, and
/// a robot's description changes when it is rebuilt, not at a sample's rate. Refusals are said
/// once per interval at most.
pub(super) const MIN_INTERVAL: Duration = Duration::from_secs(1);

/// Descriptions a robot may send at once: a start's query racing a gateway's put, a driver
/// restarted, without losing the newest.
const BURST: f64 = 4.0;

/// The most joints of a description taken: a ROS 2 `JointState` of more is refused anyway.
const MAX_JOINTS: usize = 32;

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
                tokens: BURST,
                refilled: now,
                refusal_said: None,
            })
        });
        match gate(seen, text, origin, now) {
            Gate::Same => {}
            Gate::Read(payload) => read = Some(payload),
            Gate::Refused(why, detail) => {
                fleet.description_refused();
                // Counted always; said once a second at most, so a flood cannot push a robot's
                // alarms out of its recent events.
                if seen
                    .refusal_said
                    .is_none_or(|said| now.duration_since(said) >= MIN_INTERVAL)
                {
                    seen.refusal_said = Some(now);
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

/// Whether `text` is read, given what `seen` keeps of the robot's descriptions (its tokens
/// refilled to `now`).
fn gate<'t>(
    seen: &mut DescriptionSeen,
    text: &'t Result<&'t [u8], String>,
    origin: &str,
    now: Instant,
) -> Gate<'t> {
    seen.tokens = (seen.tokens
        + now.duration_since(seen.refilled).as_secs_f64() / MIN_INTERVAL.as_secs_f64())
    .min(BURST);
    seen.refilled = now;
    let payload = match text {
        Err(error) => {
            return Gate::Refused(
                error.clone(),
                json!({"origin": origin, "in_use": false, "error": error}),
            );
        }
        Ok(payload) => *payload,
    };
    if payload.len() > MAX_URDF_BYTES {
        return Gate::Refused(
            format!("{} bytes, over {MAX_URDF_BYTES}", payload.len()),
            json!({"origin": origin, "in_use": false, "bytes": payload.len()}),
        );
    }
    let digest = digest_of(payload);
    if seen.digest == Some(digest) {
        return Gate::Same;
    }
    if seen.tokens < 1.0 {
        let why = format!(
            "more than {BURST} descriptions at once, and one a second after: this one is not read"
        );
        let detail = json!({"origin": origin, "in_use": false, "error": why});
        return Gate::Refused(why, detail);
    }
    seen.tokens -= 1.0;
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
    if joints > MAX_JOINTS {
        return Err(format!("its chain has {joints} joints, over {MAX_JOINTS}"));
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
