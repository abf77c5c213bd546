//! The effort outputs' JSON: a joint sample's torques (`<prefix>/effort/<robot>`), the payload
//! message (`<prefix>/payload/<robot>`), and the effort object of the state answer and the
//! metrics message.
//!
//! Must not compute anything: the values are the core's ([`armtwin_core::dynamics::monitor`]),
//! written as they are.

use serde_json::{Value, json};

use armtwin_core::dynamics::Payload;
use armtwin_core::dynamics::monitor::{
    EffortReadout, EffortSummary, PayloadReadout, PayloadSource, ResidualStats,
};
use armtwin_core::dynamics::payload::{PayloadEstimate, PayloadIdentification};

use super::to_json_bytes;

/// A joint sample's effort: `{robot, t, mode, state, model_nm, measured_nm, residual_nm,
/// observer_nm}` (the last three `null` without a measured torque).
#[must_use]
pub fn effort_readout_json(robot: &str, readout: &EffortReadout) -> Value {
    json!({
        "robot": robot,
        "t": readout.stamp_s,
        "mode": readout.mode.as_str(),
        "state": readout.state_source.as_str(),
        "model_nm": readout.model_nm,
        "measured_nm": readout.measured_nm,
        "residual_nm": readout.residual_nm,
        "observer_nm": readout.observer_nm,
    })
}

/// [`effort_readout_json`]'s bytes.
#[must_use]
pub fn effort_readout_bytes(robot: &str, readout: &EffortReadout) -> Vec<u8> {
    to_json_bytes(&effort_readout_json(robot, readout))
}

fn payload_json(payload: &Payload) -> Value {
    json!({ "mass_kg": payload.mass_kg, "cog_m": payload.cog_flange_m })
}

fn estimate_json(estimate: &PayloadEstimate) -> Value {
    json!({
        "mass_kg": estimate.mass_kg,
        "cog_m": estimate.cog_flange_m,
        "mass_std_kg": estimate.mass_std_kg,
        "samples": estimate.samples,
        "cog_identified": estimate.cog_identified,
        "condition": estimate.condition,
    })
}

/// `null` while nothing is identified or an estimate is; else why this motion identifies none:
/// `{reason, condition, samples}` (`condition` null when the poses are singular).
fn not_identifiable_json(identification: Option<&PayloadIdentification>) -> Value {
    match identification {
        Some(PayloadIdentification::NotIdentifiable {
            reason,
            condition,
            samples,
        }) => json!({
            "reason": reason.as_str(),
            "condition": condition.is_finite().then_some(*condition),
            "samples": samples,
        }),
        _ => Value::Null,
    }
}

fn with_source(payload: &Payload, source: PayloadSource) -> Value {
    let mut value = payload_json(payload);
    value["source"] = json!(source.as_str());
    value
}

/// The payload as the monitor has it: `{configured, estimate, not_identifiable, applied,
/// in_use}`.
#[must_use]
pub fn payload_readout_json(payload: &PayloadReadout) -> Value {
    json!({
        "configured": payload.configured.map(|(payload, source)| with_source(&payload, source)),
        "estimate": payload.estimate.as_ref().map(estimate_json),
        "not_identifiable": not_identifiable_json(payload.identification.as_ref()),
        "applied": payload.applied.as_ref().map(payload_json),
        "in_use": with_source(&payload.in_use.0, payload.in_use.1),
    })
}

/// The payload message: `{robot, t, configured, estimate, applied, in_use, mismatch}`.
#[must_use]
pub fn payload_message_bytes(robot: &str, summary: &EffortSummary) -> Vec<u8> {
    let mut value = payload_readout_json(&summary.payload);
    value["robot"] = json!(robot);
    value["t"] = json!(summary.latest.map(|latest| latest.stamp_s));
    value["mismatch"] = json!(summary.payload_mismatch);
    to_json_bytes(&value)
}

fn stats_json(stats: &ResidualStats) -> Value {
    json!({ "n": stats.n, "rms_nm": stats.rms_nm, "max_nm": stats.max_nm })
}

/// The effort object of the state answer and the metrics message: `{latest, residual:
/// {cumulative, window}, friction, payload, collision: {threshold_nm, threshold_source, detection,
/// active, count}, payload_mismatch}`.
#[must_use]
pub fn effort_summary_json(robot: &str, summary: &EffortSummary) -> Value {
    let friction: Vec<Value> = summary
        .friction
        .iter()
        .map(|joint| {
            joint.map_or(Value::Null, |f| {
                json!({
                    "coulomb_nm": f.coulomb_nm,
                    "viscous_nm_s_rad": f.viscous_nm_s_rad,
                    "temperature_c": f.temperature_c,
                    "baseline_coulomb_nm": f.baseline_coulomb_nm,
                    "drift_nm": f.drift_nm,
                })
            })
        })
        .collect();
    json!({
        "latest": summary.latest.map(|latest| effort_readout_json(robot, &latest)),
        "residual": {
            "cumulative": stats_json(&summary.cumulative),
            "window": { "seconds": summary.window_s, "stats": stats_json(&summary.window) },
        },
        "friction": friction,
        "payload": payload_readout_json(&summary.payload),
        "collision": {
            "threshold_nm": summary.collision_threshold_nm,
            "threshold_source": summary.threshold_source.as_str(),
            "detection": summary.detection.as_str(),
            "active": summary.collision,
            "count": summary.collisions,
        },
        "payload_mismatch": summary.payload_mismatch,
    })
}
