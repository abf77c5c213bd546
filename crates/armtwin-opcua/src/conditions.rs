//! A robot's alarms as OPC UA Alarms & Conditions (OPC 10000-9): each alarm of each robot is one
//! condition, which a raise makes active and unacknowledged, an operator acknowledges and then
//! confirms, and a clear makes inactive. A condition is retained (kept, and sent again on
//! `ConditionRefresh`) while it is active, unacknowledged or unconfirmed; once it is none of
//! them it is forgotten, so the store holds at most one entry per robot and alarm that needs
//! attention.
//!
//! Pure: times and event ids come in as arguments, and what changed comes out as a
//! [`ConditionSnapshot`] for the server to notify.

use std::collections::BTreeMap;
use std::sync::Arc;

use opcua::types::DateTime;

use crate::alarms::Alarm;

/// Why a method call on a condition was refused (each maps to its OPC UA status code).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub(crate) enum ConditionRefusal {
    /// No retained condition has this id.
    #[error("no such condition")]
    UnknownCondition,
    /// The event id is not the condition's latest: the caller acts on an old state.
    #[error("the event id is not the condition's latest")]
    UnknownEventId,
    /// Acknowledged already.
    #[error("already acknowledged")]
    AlreadyAcked,
    /// Confirmed already.
    #[error("already confirmed")]
    AlreadyConfirmed,
    /// A confirmation before the acknowledgement.
    #[error("not acknowledged yet")]
    NotAcked,
}

/// What an operator does to a condition.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Operation {
    /// `Acknowledge`: seen.
    Acknowledge,
    /// `Confirm`: acknowledged, and the cause dealt with.
    Confirm,
}

/// The longest comment kept with a condition (characters).
const MAX_COMMENT_CHARS: usize = 256;

/// One condition's state, as its next event shows it.
#[derive(Debug, Clone, PartialEq)]
#[expect(
    clippy::struct_excessive_bools,
    reason = "OPC UA's own two-state variables, each set on its own"
)]
pub(crate) struct ConditionSnapshot {
    /// The robot the alarm is about.
    pub(crate) robot: Arc<str>,
    /// Which alarm.
    pub(crate) alarm: Alarm,
    /// The event's id: what `Acknowledge` and `Confirm` must name.
    pub(crate) event_id: [u8; 16],
    /// What happened, for people.
    pub(crate) message: String,
    /// When it happened.
    pub(crate) time: DateTime,
    /// The alarm is on.
    pub(crate) active: bool,
    /// An operator acknowledged it.
    pub(crate) acked: bool,
    /// An operator confirmed it.
    pub(crate) confirmed: bool,
    /// The condition still needs attention (the event says `Retain`).
    pub(crate) retain: bool,
    /// The current severity (1–1000).
    pub(crate) severity: u16,
    /// The severity before the last change.
    pub(crate) last_severity: u16,
    /// The last comment given with an acknowledgement or a confirmation.
    pub(crate) comment: String,
    /// Who acknowledged or confirmed last.
    pub(crate) client_user: String,
}

impl ConditionSnapshot {
    /// Whether the condition needs no one's attention any more.
    fn settled(&self) -> bool {
        !self.active && self.acked && self.confirmed
    }
}

/// Every retained condition, by robot and alarm.
#[derive(Debug, Default)]
pub(crate) struct Conditions {
    retained: BTreeMap<(Arc<str>, Alarm), ConditionSnapshot>,
}

impl Conditions {
    /// The alarm `alarm` of `robot` is now `active`: the condition's new state when that is a
    /// change (a raise of an inactive or unknown condition, or a clear of an active one).
    pub(crate) fn set_active(
        &mut self,
        robot: &Arc<str>,
        alarm: Alarm,
        active: bool,
        time: DateTime,
        event_id: [u8; 16],
    ) -> Option<ConditionSnapshot> {
        let key = (Arc::clone(robot), alarm);
        let was_active = self.retained.get(&key).is_some_and(|c| c.active);
        if was_active == active {
            return None;
        }
        let severity = alarm.severity(active);
        let how = if active { "raised" } else { "cleared" };
        let message = format!("{robot}: {} {how}", alarm.describe());
        let snapshot = match self.retained.get_mut(&key) {
            Some(condition) => {
                condition.last_severity = condition.severity;
                condition.severity = severity;
                condition.active = active;
                if active {
                    // A new occurrence needs a new acknowledgement and confirmation.
                    condition.acked = false;
                    condition.confirmed = false;
                }
                condition.event_id = event_id;
                condition.message = message;
                condition.time = time;
                condition.retain = !condition.settled();
                condition.clone()
            }
            None => ConditionSnapshot {
                robot: Arc::clone(robot),
                alarm,
                event_id,
                message,
                time,
                active: true,
                acked: false,
                confirmed: false,
                retain: true,
                severity,
                last_severity: alarm.severity(false),
                comment: String::new(),
                client_user: String::new(),
            },
        };
        self.keep(key, &snapshot);
        Some(snapshot)
    }

    /// `operation` by `user` (with `comment`) on the condition of `robot` and `alarm`, in the
    /// state of event `acting_on`: its new state, which the new event `event_id` at `time` shows.
    pub(crate) fn operate(
        &mut self,
        operation: Operation,
        (robot, alarm): (&str, Alarm),
        acting_on: &[u8],
        (user, comment): (&str, &str),
        (time, event_id): (DateTime, [u8; 16]),
    ) -> Result<ConditionSnapshot, ConditionRefusal> {
        let key = (Arc::<str>::from(robot), alarm);
        let condition = self
            .retained
            .get_mut(&key)
            .ok_or(ConditionRefusal::UnknownCondition)?;
        if condition.event_id.as_slice() != acting_on {
            return Err(ConditionRefusal::UnknownEventId);
        }
        let what = match operation {
            Operation::Acknowledge if condition.acked => {
                return Err(ConditionRefusal::AlreadyAcked);
            }
            Operation::Acknowledge => {
                condition.acked = true;
                "acknowledged"
            }
            Operation::Confirm if !condition.acked => return Err(ConditionRefusal::NotAcked),
            Operation::Confirm if condition.confirmed => {
                return Err(ConditionRefusal::AlreadyConfirmed);
            }
            Operation::Confirm => {
                condition.confirmed = true;
                "confirmed"
            }
        };
        condition.event_id = event_id;
        condition.time = time;
        condition.last_severity = condition.severity;
        condition.message = format!("{robot}: {} {what} by {user}", alarm.describe());
        condition.comment.clear();
        // A client's comment is kept with the condition: bounded, whatever the message allows.
        condition
            .comment
            .extend(comment.chars().take(MAX_COMMENT_CHARS));
        user.clone_into(&mut condition.client_user);
        condition.retain = !condition.settled();
        let snapshot = condition.clone();
        self.keep(key, &snapshot);
        Ok(snapshot)
    }

    /// Keeps the condition while it is retained, forgets it once it is not.
    fn keep(&mut self, key: (Arc<str>, Alarm), snapshot: &ConditionSnapshot) {
        if snapshot.retain {
            self.retained.insert(key, snapshot.clone());
        } else {
            self.retained.remove(&key);
        }
    }

    /// Every retained condition, for a refresh.
    pub(crate) fn retained(&self) -> impl Iterator<Item = &ConditionSnapshot> {
        self.retained.values()
    }

    /// Forgets the conditions of the robots `keep` says no (retired: their nodes are gone).
    pub(crate) fn retain_robots(&mut self, mut keep: impl FnMut(&str) -> bool) {
        self.retained.retain(|(robot, _), _| keep(robot));
    }

    /// How many conditions are retained.
    pub(crate) fn len(&self) -> usize {
        self.retained.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const OPERATOR: (&str, &str) = ("op", "seen");

    fn id(n: u8) -> [u8; 16] {
        [n; 16]
    }

    fn t(n: i64) -> DateTime {
        DateTime::from(n)
    }

    #[test]
    fn a_raised_alarm_is_retained_until_cleared_acknowledged_and_confirmed() {
        let robot: Arc<str> = Arc::from("r1");
        let mut conditions = Conditions::default();
        let raised = conditions
            .set_active(&robot, Alarm::Position, true, t(1), id(1))
            .expect("a raise is a change");
        assert!(raised.active && !raised.acked && !raised.confirmed && raised.retain);
        assert_eq!(raised.severity, Alarm::Position.severity(true));
        assert_eq!(
            conditions.set_active(&robot, Alarm::Position, true, t(2), id(2)),
            None,
            "still on: no change"
        );
        // Acting on an old event, or confirming first, is refused.
        let target = ("r1", Alarm::Position);
        assert_eq!(
            conditions.operate(
                Operation::Acknowledge,
                target,
                &id(9),
                OPERATOR,
                (t(3), id(3))
            ),
            Err(ConditionRefusal::UnknownEventId)
        );
        assert_eq!(
            conditions.operate(Operation::Confirm, target, &id(1), OPERATOR, (t(3), id(3))),
            Err(ConditionRefusal::NotAcked)
        );
        let acked = conditions
            .operate(
                Operation::Acknowledge,
                target,
                &id(1),
                OPERATOR,
                (t(3), id(3)),
            )
            .unwrap();
        assert!(acked.active && acked.acked && acked.retain);
        assert_eq!(
            (acked.client_user.as_str(), acked.comment.as_str()),
            OPERATOR
        );
        assert_eq!(
            conditions.operate(
                Operation::Acknowledge,
                target,
                &id(3),
                OPERATOR,
                (t(4), id(4))
            ),
            Err(ConditionRefusal::AlreadyAcked)
        );
        let cleared = conditions
            .set_active(&robot, Alarm::Position, false, t(5), id(5))
            .unwrap();
        assert!(
            !cleared.active && cleared.retain,
            "cleared, not yet confirmed"
        );
        let confirmed = conditions
            .operate(Operation::Confirm, target, &id(5), OPERATOR, (t(6), id(6)))
            .unwrap();
        assert!(
            !confirmed.retain,
            "settled: the last event says Retain false"
        );
        assert_eq!(conditions.len(), 0, "and the condition is forgotten");
        assert_eq!(
            conditions.operate(
                Operation::Acknowledge,
                target,
                &id(6),
                OPERATOR,
                (t(7), id(7))
            ),
            Err(ConditionRefusal::UnknownCondition)
        );
    }

    #[test]
    fn a_raise_after_an_acknowledgement_needs_a_new_one() {
        let robot: Arc<str> = Arc::from("r1");
        let mut conditions = Conditions::default();
        conditions.set_active(&robot, Alarm::Collision, true, t(1), id(1));
        conditions
            .operate(
                Operation::Acknowledge,
                ("r1", Alarm::Collision),
                &id(1),
                OPERATOR,
                (t(2), id(2)),
            )
            .unwrap();
        conditions.set_active(&robot, Alarm::Collision, false, t(3), id(3));
        let again = conditions
            .set_active(&robot, Alarm::Collision, true, t(4), id(4))
            .unwrap();
        assert!(again.active && !again.acked && !again.confirmed);
        assert_eq!(again.last_severity, Alarm::Collision.severity(false));
        let long = "x".repeat(10 * MAX_COMMENT_CHARS);
        let acked = conditions
            .operate(
                Operation::Acknowledge,
                ("r1", Alarm::Collision),
                &id(4),
                ("op", &long),
                (t(5), id(5)),
            )
            .unwrap();
        assert_eq!(
            acked.comment.chars().count(),
            MAX_COMMENT_CHARS,
            "a comment is bounded"
        );
        assert_eq!(conditions.retained().count(), 1);
        conditions.retain_robots(|robot| robot != "r1");
        assert_eq!(
            conditions.len(),
            0,
            "a retired robot's conditions go with it"
        );
    }
}
