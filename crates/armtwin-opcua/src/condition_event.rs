//! A condition's state as an `AlarmConditionType` event (OPC 10000-9), and the refresh's start
//! and end events.
//!
//! Written by hand rather than with the stack's generated `AlarmConditionType`: that one cannot
//! answer a select clause for the `ConditionId` (the node id of the condition, an empty browse
//! path) nor the value of a two-state variable (`ActiveState` itself, beside its `Id`), both of
//! which clients read to show and acknowledge an alarm.

use opcua::nodes::{BaseEventType, Event};
use opcua::types::event_field::EventField;
use opcua::types::{
    AttributeId, ByteString, DateTime, LocalizedText, NodeId, NumericRange, ObjectTypeId,
    QualifiedName, StatusCode, UAString, Variant,
};

use crate::conditions::ConditionSnapshot;

/// The node id of `robot`'s condition `name`, in armtwin's namespace `armtwin`.
pub(crate) fn condition_id(armtwin: u16, robot: &str, name: &str) -> NodeId {
    NodeId::new(armtwin, format!("{robot}#Alarms/{name}"))
}

/// The robot and condition name of a condition's node id.
pub(crate) fn parse_condition_id(id: &str) -> Option<(&str, &str)> {
    let (robot, path) = id.rsplit_once('#')?;
    Some((robot, path.strip_prefix("Alarms/")?))
}

/// The type of a condition event and its supertypes: the types a select clause may name to read
/// its fields.
const CONDITION_TYPES: [ObjectTypeId; 4] = [
    ObjectTypeId::BaseEventType,
    ObjectTypeId::ConditionType,
    ObjectTypeId::AcknowledgeableConditionType,
    ObjectTypeId::AlarmConditionType,
];

/// One condition event.
#[derive(Debug)]
pub(crate) struct ConditionEvent {
    base: BaseEventType,
    condition_id: NodeId,
    condition_name: UAString,
    snapshot: ConditionSnapshot,
}

impl ConditionEvent {
    /// The event of `snapshot`, its condition's node in armtwin's namespace `armtwin`, raised
    /// from the robot's own node.
    pub(crate) fn new(armtwin: u16, snapshot: ConditionSnapshot) -> Self {
        let name = snapshot.alarm.name();
        let mut base = BaseEventType::new(
            ObjectTypeId::AlarmConditionType,
            ByteString::from(snapshot.event_id.to_vec()),
            snapshot.message.as_str(),
            snapshot.time,
        )
        .set_source_node(NodeId::new(armtwin, snapshot.robot.to_string()))
        .set_source_name(snapshot.robot.as_ref().into())
        .set_severity(snapshot.severity);
        // The deviation of a process from its model: a process condition, not a system one.
        base.condition_class_id = Some(ObjectTypeId::ProcessConditionClassType.into());
        base.condition_class_name = Some(LocalizedText::new("en", "ProcessConditionClassType"));
        Self {
            base,
            condition_id: condition_id(armtwin, &snapshot.robot, name),
            condition_name: name.into(),
            snapshot,
        }
    }

    /// The robot's node, which raised it.
    pub(crate) fn source(&self) -> &NodeId {
        &self.base.source_node
    }

    /// A `TwoStateVariableType` field: its text, or with `Id` its boolean.
    fn two_state(rest: &[QualifiedName], on: bool, texts: (&str, &str)) -> Variant {
        match rest {
            [] => LocalizedText::new("en", if on { texts.0 } else { texts.1 }).into(),
            [id] if id.name.as_ref() == "Id" => on.into(),
            _ => Variant::Empty,
        }
    }

    /// A `ConditionVariableType` field: its value, or with `SourceTimestamp` its time.
    fn condition_variable(&self, rest: &[QualifiedName], value: Variant) -> Variant {
        match rest {
            [] => value,
            [time] if time.name.as_ref() == "SourceTimestamp" => self.snapshot.time.into(),
            _ => Variant::Empty,
        }
    }
}

impl EventField for ConditionEvent {
    fn get_value(
        &self,
        attribute_id: AttributeId,
        index_range: &NumericRange,
        browse_path: &[QualifiedName],
    ) -> Variant {
        let Some((field, rest)) = browse_path.split_first() else {
            return Variant::Empty;
        };
        if attribute_id != AttributeId::Value || field.namespace_index != 0 {
            return Variant::Empty;
        }
        let snapshot = &self.snapshot;
        let value = match field.name.as_ref() {
            "ConditionName" => self.condition_name.clone().into(),
            "BranchId" => NodeId::null().into(),
            "Retain" => snapshot.retain.into(),
            "EnabledState" => Self::two_state(rest, true, ("Enabled", "Disabled")),
            "ActiveState" => Self::two_state(rest, snapshot.active, ("Active", "Inactive")),
            "AckedState" => {
                Self::two_state(rest, snapshot.acked, ("Acknowledged", "Unacknowledged"))
            }
            "ConfirmedState" => {
                Self::two_state(rest, snapshot.confirmed, ("Confirmed", "Unconfirmed"))
            }
            "Quality" => self.condition_variable(rest, StatusCode::Good.into()),
            "LastSeverity" => self.condition_variable(rest, snapshot.last_severity.into()),
            "Comment" => self.condition_variable(
                rest,
                LocalizedText::new("", snapshot.comment.as_str()).into(),
            ),
            "ClientUserId" => UAString::from(snapshot.client_user.as_str()).into(),
            "SuppressedOrShelved" => false.into(),
            _ => return self.base.get_value(attribute_id, index_range, browse_path),
        };
        value.range_of_owned(index_range).unwrap_or(Variant::Empty)
    }
}

impl Event for ConditionEvent {
    fn get_field(
        &self,
        type_definition_id: &NodeId,
        attribute_id: AttributeId,
        index_range: &NumericRange,
        browse_path: &[QualifiedName],
    ) -> Variant {
        // A clause of another type (an audit event's, say) selects nothing of a condition's.
        if !CONDITION_TYPES.iter().any(|t| type_definition_id == t) {
            return Variant::Empty;
        }
        // The `ConditionId`: the condition's own node id, named by an empty browse path.
        if browse_path.is_empty() && attribute_id == AttributeId::NodeId {
            return Variant::from(self.condition_id.clone())
                .range_of_owned(index_range)
                .unwrap_or(Variant::Empty);
        }
        self.get_value(attribute_id, index_range, browse_path)
    }

    fn time(&self) -> &DateTime {
        &self.base.time
    }

    fn event_type_id(&self) -> &NodeId {
        &self.base.event_type
    }
}

/// The event that starts (`start`) or ends a refresh, from the Server object.
pub(crate) fn refresh_event(start: bool, event_id: [u8; 16]) -> BaseEventType {
    let (type_id, message) = if start {
        (ObjectTypeId::RefreshStartEventType, "refresh started")
    } else {
        (ObjectTypeId::RefreshEndEventType, "refresh ended")
    };
    BaseEventType::new_now(type_id, ByteString::from(event_id.to_vec()), message)
        .set_source_node(ObjectTypeId::BaseObjectType.into())
        .set_severity(1)
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::alarms::Alarm;

    fn path(names: &[&str]) -> Vec<QualifiedName> {
        names
            .iter()
            .map(|name| QualifiedName::new(0, *name))
            .collect()
    }

    #[test]
    fn the_fields_clients_select_answer() {
        let snapshot = ConditionSnapshot {
            robot: Arc::from("cell/r1"),
            alarm: Alarm::Collision,
            event_id: [7; 16],
            message: "cell/r1: collision alarm raised".to_owned(),
            time: DateTime::now(),
            active: true,
            acked: false,
            confirmed: false,
            retain: true,
            severity: 900,
            last_severity: 100,
            comment: String::new(),
            client_user: String::new(),
        };
        let event = ConditionEvent::new(3, snapshot);
        let field = |names: &[&str]| {
            event.get_field(
                &ObjectTypeId::AlarmConditionType.into(),
                AttributeId::Value,
                &NumericRange::None,
                &path(names),
            )
        };
        assert_eq!(field(&["ActiveState", "Id"]), Variant::from(true));
        assert_eq!(
            field(&["ActiveState"]),
            Variant::from(LocalizedText::new("en", "Active"))
        );
        assert_eq!(field(&["AckedState", "Id"]), Variant::from(false));
        assert_eq!(field(&["Retain"]), Variant::from(true));
        assert_eq!(field(&["Severity"]), Variant::from(900_u16));
        assert_eq!(field(&["LastSeverity"]), Variant::from(100_u16));
        assert_eq!(field(&["ConditionName"]), Variant::from("Collision"));
        assert_eq!(
            field(&["EventId"]),
            Variant::from(ByteString::from(vec![7; 16]))
        );
        assert_eq!(field(&["NoSuchField"]), Variant::Empty);
        let id = event.get_field(
            &ObjectTypeId::ConditionType.into(),
            AttributeId::NodeId,
            &NumericRange::None,
            &[],
        );
        assert_eq!(
            id,
            Variant::from(NodeId::new(3, "cell/r1#Alarms/Collision"))
        );
        assert_eq!(
            parse_condition_id("cell/r1#Alarms/Collision"),
            Some(("cell/r1", "Collision"))
        );
        assert_eq!(parse_condition_id("cell/r1#MotionDevices/Arm"), None);
        // A clause of a type that is not the condition's nor a supertype selects nothing.
        let audit = event.get_field(
            &ObjectTypeId::AuditEventType.into(),
            AttributeId::Value,
            &NumericRange::None,
            &path(&["EventId"]),
        );
        assert_eq!(audit, Variant::Empty);
        let inherited = event.get_field(
            &ObjectTypeId::BaseEventType.into(),
            AttributeId::Value,
            &NumericRange::None,
            &path(&["Severity"]),
        );
        assert_eq!(inherited, Variant::from(900_u16));
    }
}
