//! The `state` object of a joint message (per-joint quantities, the controller's status, the
//! payload), decoded from a `serde_json::Value`: it is rarer than the angles, so the one pass
//! keeps it whole and this reads it again field by field.

use armtwin_core::sample::{ControllerStatus, JointQuantity, JointState, Payload};
use serde_json::Value;

use super::WireError;

/// The joint state of a joint message's `state` object: per-joint arrays named by
/// [`JointQuantity::name`], `robot_mode`, `safety_mode`, `status_bits` and `speed_scaling`
/// (together or none), and `payload` (`mass_kg`, `cog_m`, optional `inertia_kg_m2`). Fields it does
/// not know are skipped, as at the top level; `null` counts as absent.
pub(super) fn joint_state(value: &Value, joint_count: usize) -> Result<JointState, WireError> {
    let bad = |field: &str, detail: String| WireError::JointState {
        field: format!("state.{field}"),
        detail,
    };
    let Value::Object(fields) = value else {
        return Err(bad(
            "",
            format!("expected an object, got {}", json_type(value)),
        ));
    };
    let number = |field: &str, value: &Value| -> Result<f64, WireError> {
        value.as_f64().ok_or_else(|| {
            bad(
                field,
                format!("expected a number, got {}", json_type(value)),
            )
        })
    };
    let numbers = |field: &str, value: &Value, count: usize| -> Result<Vec<f64>, WireError> {
        let Value::Array(items) = value else {
            return Err(bad(
                field,
                format!("expected an array, got {}", json_type(value)),
            ));
        };
        if items.len() != count {
            return Err(bad(
                field,
                format!("expected {count} values, got {}", items.len()),
            ));
        }
        items
            .iter()
            .enumerate()
            .map(|(index, item)| {
                // The field's name is written only for an error.
                item.as_f64().ok_or_else(|| {
                    bad(
                        &format!("{field}[{index}]"),
                        format!("expected a number, got {}", json_type(item)),
                    )
                })
            })
            .collect()
    };
    let mut state = JointState::new(joint_count);
    for quantity in JointQuantity::ALL {
        if let Some(value) = fields.get(quantity.name()).filter(|value| !value.is_null()) {
            state.set(quantity, &numbers(quantity.name(), value, joint_count)?);
        }
    }
    let status_fields = ["robot_mode", "safety_mode", "status_bits", "speed_scaling"]
        .map(|name| (name, fields.get(name).filter(|value| !value.is_null())));
    if status_fields.iter().any(|(_, value)| value.is_some()) {
        let [robot_mode, safety_mode, status_bits, speed_scaling] =
            status_fields.map(|(name, value)| {
                value.ok_or_else(|| {
                    bad(
                        name,
                        "missing: robot_mode, safety_mode, status_bits and speed_scaling come together"
                            .to_owned(),
                    )
                })
            });
        let int = |name: &str, value: &Value| -> Result<i32, WireError> {
            value
                .as_i64()
                .and_then(|value| i32::try_from(value).ok())
                .ok_or_else(|| bad(name, format!("expected a 32-bit integer, got {value}")))
        };
        state.status = Some(ControllerStatus {
            robot_mode: int("robot_mode", robot_mode?)?,
            safety_mode: int("safety_mode", safety_mode?)?,
            status_bits: status_bits?
                .as_u64()
                .and_then(|value| u32::try_from(value).ok())
                .ok_or_else(|| {
                    bad(
                        "status_bits",
                        "expected a 32-bit unsigned integer".to_owned(),
                    )
                })?,
            speed_scaling: number("speed_scaling", speed_scaling?)?,
        });
    }
    if let Some(value) = fields.get("payload").filter(|value| !value.is_null()) {
        state.payload = Some(payload_json(value)?);
    }
    Ok(state)
}

/// The `payload` of a `state` object: `mass_kg` (not negative), `cog_m` and optionally
/// `inertia_kg_m2`.
fn payload_json(value: &Value) -> Result<Payload, WireError> {
    let bad = |field: &str, detail: String| WireError::JointState {
        field: format!("state.payload.{field}"),
        detail,
    };
    let Value::Object(payload) = value else {
        return Err(bad(
            "",
            format!("expected an object, got {}", json_type(value)),
        ));
    };
    let numbers = |field: &str, count: usize| -> Result<Option<Vec<f64>>, WireError> {
        let Some(value) = payload.get(field).filter(|value| !value.is_null()) else {
            return Ok(None);
        };
        let values = match value {
            Value::Array(items) if items.len() == count => items
                .iter()
                .map(Value::as_f64)
                .collect::<Option<Vec<f64>>>(),
            _ => None,
        };
        values
            .map(Some)
            .ok_or_else(|| bad(field, format!("expected {count} numbers, got {value}")))
    };
    let mass_kg = match payload.get("mass_kg") {
        Some(value) => value
            .as_f64()
            .ok_or_else(|| bad("mass_kg", format!("expected a number, got {value}")))?,
        None => return Err(bad("mass_kg", "missing".to_owned())),
    };
    if mass_kg < 0.0 {
        return Err(bad(
            "mass_kg",
            format!("a mass of {mass_kg} kg: a mass is not negative"),
        ));
    }
    let cog = numbers("cog_m", 3)?.ok_or_else(|| bad("cog_m", "missing".to_owned()))?;
    let inertia = numbers("inertia_kg_m2", 6)?;
    Ok(Payload {
        mass_kg,
        cog_m: [cog[0], cog[1], cog[2]],
        inertia_kg_m2: inertia.map(|values| std::array::from_fn(|index| values[index])),
    })
}

fn json_type(value: &Value) -> &'static str {
    match value {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}
