//! What the pipeline reports besides poses and metrics: events, with structured details for
//! machines and, only when a sink asks for it, a sentence for people.
//!
//! An [`Event`] holds numbers, causes and borrowed errors, never text: its [`Display`] writes
//! the sentence, so a sink that drops an event (a rate limit) formats nothing.
//!
//! [`Display`]: fmt::Display

use std::error::Error;
use std::fmt;

use super::RobotIndex;
use crate::align::{AlignConfig, UnpairedReason};

/// What an event reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EventKind {
    /// Input rejected.
    Rejected,
    /// A deviation stayed above its threshold.
    Alarm,
    /// An alarm's deviation came back to or below its threshold.
    Recovered,
    /// A gap in a stream (joint stamps or gateway sequence numbers).
    Gap,
    /// A measured pose that could not be paired with the twin.
    Unpaired,
    /// The gateway restarted: its clock went back by more than `restart_s` (alignment and the
    /// metrics window started afresh), or its `seq` went back while its stamps moved on (it
    /// counts afresh).
    Restart,
    /// The robot's model was replaced (a calibration applied): a new metrics epoch began.
    Epoch,
}

impl EventKind {
    /// The wire name.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Rejected => "rejected",
            Self::Alarm => "alarm",
            Self::Recovered => "recovered",
            Self::Gap => "gap",
            Self::Unpaired => "unpaired",
            Self::Restart => "restart",
            Self::Epoch => "epoch",
        }
    }
}

/// Why an input was rejected: the pipeline's own checks, or a decoder's refusal.
///
/// The core names only what it detects itself (joint count and limits, finiteness, stamp order,
/// `seq`, range, unknown robots). A codec's refusal is [`RejectCause::Decode`] with the codec's
/// own stable class name, so a new codec (RTDE, a joint-state extension) adds its classes in its
/// own crate, not here. A codec that refuses for a class the core also has (a non-finite
/// number, a wrong joint count) uses the core's variant.
///
/// Causes compare, hash and sort by their wire name ([`as_str`](Self::as_str)): a
/// `Decode("non_finite")` is the same cause as [`NonFinite`](Self::NonFinite), so a count by
/// cause never holds one name twice.
#[derive(Debug, Clone, Copy)]
pub enum RejectCause {
    /// A number, joint angle or stamp is not finite.
    NonFinite,
    /// Not as many joint angles as the arm has joints.
    JointCount,
    /// A joint angle lies outside the joint's limits.
    JointLimits,
    /// A stamp older than its stream's previous one.
    OutOfOrder,
    /// A stamp equal to its stream's previous one.
    DuplicateStamp,
    /// A measured pose too far from the twin to be one of this robot.
    OutOfRange,
    /// The robot is neither configured nor covered by a default.
    UnknownRobot,
    /// The robot is new and the fleet holds as many robots as it may.
    FleetFull,
    /// A decoder refused the payload: its stable `snake_case` class name, one of a fixed set
    /// its codec declares (the core knows none of them).
    Decode(&'static str),
}

impl RejectCause {
    /// The stable `snake_case` wire name (the events' `detail.cause`, the validation report's
    /// causes).
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::NonFinite => "non_finite",
            Self::JointCount => "joint_count",
            Self::JointLimits => "joint_limits",
            Self::OutOfOrder => "out_of_order",
            Self::DuplicateStamp => "duplicate_stamp",
            Self::OutOfRange => "out_of_range",
            Self::UnknownRobot => "unknown_robot",
            Self::FleetFull => "fleet_full",
            Self::Decode(kind) => kind,
        }
    }
}

impl PartialEq for RejectCause {
    fn eq(&self, other: &Self) -> bool {
        self.as_str() == other.as_str()
    }
}

impl Eq for RejectCause {}

impl std::hash::Hash for RejectCause {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.as_str().hash(state);
    }
}

impl PartialOrd for RejectCause {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for RejectCause {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.as_str().cmp(other.as_str())
    }
}

impl fmt::Display for RejectCause {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Machine-readable details of an event (the event message's `detail`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EventDetail {
    /// Input rejected for this cause.
    Rejected {
        /// Why.
        cause: RejectCause,
    },
    /// An alarm on a metric, or its recovery.
    Alarm {
        /// `position` or `angle`.
        metric: &'static str,
        /// The deviation that decided (m or rad).
        value: f64,
        /// The threshold (m or rad).
        threshold: f64,
    },
    /// Joint samples further apart than `max_gap_s`.
    StampGap {
        /// Spacing (s).
        gap_s: f64,
    },
    /// Gateway sequence numbers skipped.
    SeqGap {
        /// The sequence number expected.
        expected: u64,
        /// The one received.
        got: u64,
    },
    /// A stream's clock went back.
    Restart {
        /// The stream's previous stamp (s).
        from_s: f64,
        /// The new stamp (s).
        to_s: f64,
    },
    /// The gateway's `seq` went back while its stamps moved on.
    SeqRestart {
        /// The previous sequence number.
        from_seq: u64,
        /// The new one.
        to_seq: u64,
    },
    /// A measured pose left unpaired.
    Unpaired {
        /// The cause, e.g. `joint_gap`, `wait_expired`.
        cause: &'static str,
        /// The measured pose's stamp (s).
        measured_s: f64,
    },
    /// A metrics epoch began.
    Epoch {
        /// Its number (0 is the start).
        epoch: u64,
    },
    /// A collision alarm (the momentum observer on a joint), or its end.
    Collision {
        /// The joint, from 1.
        joint: usize,
        /// The observer's output less its baseline (N·m).
        value_nm: f64,
        /// The threshold (N·m); the alarm ends below half of it.
        threshold_nm: f64,
    },
    /// A payload mismatch alarm, or its end.
    Payload {
        /// The identified mass (kg).
        estimated_kg: f64,
        /// Its standard deviation (kg).
        std_kg: f64,
        /// The mass the model uses (kg).
        modelled_kg: f64,
        /// The tolerance (kg).
        tolerance_kg: f64,
    },
}

/// What an event's sentence says beyond its [`EventDetail`]: the settings and values that
/// explain it, or the error that refused an input.
#[derive(Debug, Clone, Copy)]
pub enum Reason<'a> {
    /// The input did not decode, or its joints are invalid: the error says why.
    Error(&'a dyn Error),
    /// A stream's stamp is not finite.
    StampNotFinite {
        /// `joint` or `measured`.
        stream: &'static str,
    },
    /// A stream's stamp does not come after its previous one.
    StampOrder {
        /// `joint` or `measured`.
        stream: &'static str,
        /// The previous stamp (s).
        last_s: f64,
    },
    /// A measured pose too far from the twin.
    OutOfRange {
        /// Its position (m, output frame).
        position_m: [f64; 3],
        /// Its distance from the twin's (m).
        distance_m: f64,
    },
    /// The robot may not be tracked.
    UnknownRobot,
    /// The robot is new and the fleet is full.
    FleetFull {
        /// The most robots the fleet holds.
        max_robots: usize,
    },
    /// The robot is new and its group (the robots of one prefix) is full.
    GroupFull {
        /// The most robots the group holds.
        max_robots: usize,
        /// The group's prefix is the robot id's first `prefix_len` bytes.
        prefix_len: usize,
    },
    /// An alarm or its recovery.
    Alarm {
        /// The metric's unit (`m`, `rad`).
        unit: &'static str,
        /// How long (s) the deviation had to stay on its side of the threshold.
        hold_s: f64,
    },
    /// Joint samples too far apart.
    StampGap {
        /// The largest spacing (s) taken as no gap.
        max_gap_s: f64,
    },
    /// Gateway sequence numbers skipped: the detail says it all.
    SeqGap,
    /// The gateway's `seq` went back while its stamps moved on: the detail says it all.
    SeqRestart,
    /// A stream's clock went back.
    Restart {
        /// `joint` or `measured`.
        stream: &'static str,
        /// How far back (s) a stamp must go to be a restart.
        restart_s: f64,
    },
    /// A measured pose left unpaired.
    Unpaired {
        /// Why.
        reason: UnpairedReason,
        /// The alignment limits the reason refers to.
        align: AlignConfig,
    },
    /// An effort alarm or its end: the detail says it all.
    Effort,
    /// The robot's model was replaced.
    ModelReplaced {
        /// The calibration's source name (a file, `self-calibration`).
        source: &'a str,
    },
    /// The robot's tool was replaced.
    ToolReplaced {
        /// Who gave the new tool (`the controller`).
        source: &'a str,
        /// The new tool: `x, y, z` (m), rotation vector (rad), flange frame.
        tool: [f64; 6],
    },
}

/// One event for a robot's events key.
#[derive(Debug, Clone, Copy)]
pub struct Event<'a> {
    /// Robot id.
    pub robot: &'a str,
    /// The robot's index, if it is tracked (`None` for a robot that may not be).
    pub index: Option<RobotIndex>,
    /// Source time (s) of the sample concerned.
    pub stamp_s: f64,
    /// What happened.
    pub kind: EventKind,
    /// The key the input arrived on, where an input is concerned.
    pub key: Option<&'a str>,
    /// Details for machines.
    pub detail: EventDetail,
    /// What the sentence for people is made of beyond `detail` (written by [`fmt::Display`]).
    pub reason: Reason<'a>,
}

impl Event<'_> {
    /// The sentence of an effort alarm or its end.
    fn effort_sentence(&self, f: &mut fmt::Formatter<'_>, detail: EventDetail) -> fmt::Result {
        let ended = self.kind == EventKind::Recovered;
        match detail {
            EventDetail::Collision {
                joint,
                value_nm,
                threshold_nm,
            } if ended => write!(
                f,
                "joint {joint} effort back within half its collision threshold of {threshold_nm} N·m ({value_nm:.3} N·m from its baseline)"
            ),
            EventDetail::Collision {
                joint,
                value_nm,
                threshold_nm,
            } => write!(
                f,
                "collision on joint {joint}: the drives spend {value_nm:.3} N·m beyond the model's baseline (threshold {threshold_nm} N·m)"
            ),
            EventDetail::Payload {
                estimated_kg,
                std_kg,
                modelled_kg,
                tolerance_kg,
            } => {
                let relation = if ended { "within" } else { "further than" };
                write!(
                    f,
                    "payload identified at rest {estimated_kg:.3} ± {std_kg:.3} kg, {relation} {tolerance_kg} kg of the {modelled_kg} kg modelled"
                )
            }
            _ => f.write_str(self.kind.as_str()),
        }
    }
}

impl Event<'_> {
    /// The sentence of a robot that may not be tracked.
    fn write_untracked(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.reason {
            Reason::FleetFull { max_robots } => write!(
                f,
                "robot '{}' is new and the fleet already holds {max_robots} robots (max_robots)",
                self.robot
            ),
            Reason::GroupFull {
                max_robots,
                prefix_len,
            } => write!(
                f,
                "robot '{}' is new and the robots of '{}/**' already number {max_robots} (the \
                 max_robots of its gateway's grant)",
                self.robot,
                self.robot
                    .get(..prefix_len)
                    .unwrap_or_default()
                    .trim_end_matches('/')
            ),
            _ => write!(
                f,
                "robot '{}' is not configured and unknown robots are rejected",
                self.robot
            ),
        }
    }
}

impl fmt::Display for Event<'_> {
    /// The sentence for people (the event message's `reason`).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let stamp_s = self.stamp_s;
        match (self.reason, self.detail) {
            (Reason::Error(error), _) => write!(f, "{error}"),
            (Reason::StampNotFinite { stream }, _) => {
                write!(f, "{stream} stamp {stamp_s} is not finite")
            }
            (Reason::StampOrder { stream, last_s }, _) => {
                let relation = if stamp_s < last_s {
                    "older than"
                } else {
                    "equal to"
                };
                write!(
                    f,
                    "{stream} stamp {stamp_s} s is {relation} the previous one ({last_s} s)"
                )
            }
            (
                Reason::OutOfRange {
                    position_m,
                    distance_m,
                },
                _,
            ) => write!(
                f,
                "measured pose {position_m:?} m is {distance_m} m from the twin: not a pose of this robot"
            ),
            (Reason::UnknownRobot | Reason::FleetFull { .. } | Reason::GroupFull { .. }, _) => {
                self.write_untracked(f)
            }
            (
                Reason::Alarm { unit, hold_s },
                EventDetail::Alarm {
                    metric,
                    value,
                    threshold,
                },
            ) => {
                let relation = if self.kind == EventKind::Recovered {
                    "back at or below"
                } else {
                    "above"
                };
                write!(
                    f,
                    "{metric} deviation {value} {unit} {relation} {threshold} {unit} for at least {hold_s} s"
                )
            }
            (Reason::StampGap { max_gap_s }, EventDetail::StampGap { gap_s }) => {
                write!(f, "no joint sample for {gap_s} s (max_gap_s = {max_gap_s})")
            }
            (Reason::SeqGap, EventDetail::SeqGap { expected, got }) => write!(
                f,
                "gateway seq jumped from {} to {got}: {} samples missing upstream",
                expected.saturating_sub(1),
                got.saturating_sub(expected)
            ),
            (Reason::Restart { stream, restart_s }, EventDetail::Restart { from_s, to_s }) => {
                write!(
                    f,
                    "{stream} stamp went back from {from_s} s to {to_s} s (more than restart_s = {restart_s} s): \
                     taken as a gateway clock restart; alignment and the metrics window start afresh"
                )
            }
            (Reason::SeqRestart, EventDetail::SeqRestart { from_seq, to_seq }) => write!(
                f,
                "gateway seq went back from {from_seq} to {to_seq} while its stamps moved on: \
                 taken as a gateway restart; its count starts afresh, the metrics continue"
            ),
            (Reason::Unpaired { reason, align }, EventDetail::Unpaired { measured_s, .. }) => {
                write!(
                    f,
                    "measured pose at t = {measured_s} s unpaired: {}",
                    reason.describe(&align)
                )
            }
            (Reason::ModelReplaced { source }, EventDetail::Epoch { epoch }) => write!(
                f,
                "model replaced by the calibration from {source}: metrics epoch {epoch} begins, \
                 counters and statistics start afresh"
            ),
            (Reason::ToolReplaced { source, tool }, EventDetail::Epoch { epoch }) => write!(
                f,
                "tool replaced by {source}'s tcp_offset {tool:?}: metrics epoch {epoch} begins, \
                 counters and statistics start afresh"
            ),
            (Reason::Effort, detail) => self.effort_sentence(f, detail),
            // A reason made for another kind of detail: the kind at least.
            (_, EventDetail::Rejected { cause }) => write!(f, "rejected: {cause}"),
            _ => f.write_str(self.kind.as_str()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::KinematicsError;

    fn event(kind: EventKind, detail: EventDetail, reason: Reason<'_>) -> Event<'_> {
        Event {
            robot: "r1",
            index: None,
            stamp_s: 2.5,
            kind,
            key: Some("twin/joints/r1"),
            detail,
            reason,
        }
    }

    /// Each sentence is the one the events key has always carried.
    #[test]
    #[allow(clippy::too_many_lines, reason = "one case per sentence, in a table")]
    fn sentences() {
        let rejected = |cause| EventDetail::Rejected { cause };
        let error = KinematicsError::JointCount {
            expected: 6,
            got: 5,
        };
        let align = AlignConfig::default();
        let cases = [
            (
                event(
                    EventKind::Rejected,
                    rejected(RejectCause::JointCount),
                    Reason::Error(&error),
                ),
                "expected 6 joint angles, got 5".to_owned(),
            ),
            (
                event(
                    EventKind::Rejected,
                    rejected(RejectCause::NonFinite),
                    Reason::StampNotFinite { stream: "joint" },
                ),
                "joint stamp 2.5 is not finite".to_owned(),
            ),
            (
                event(
                    EventKind::Rejected,
                    rejected(RejectCause::OutOfOrder),
                    Reason::StampOrder {
                        stream: "measured",
                        last_s: 3.0,
                    },
                ),
                "measured stamp 2.5 s is older than the previous one (3 s)".to_owned(),
            ),
            (
                event(
                    EventKind::Rejected,
                    rejected(RejectCause::DuplicateStamp),
                    Reason::StampOrder {
                        stream: "joint",
                        last_s: 2.5,
                    },
                ),
                "joint stamp 2.5 s is equal to the previous one (2.5 s)".to_owned(),
            ),
            (
                event(
                    EventKind::Restart,
                    EventDetail::SeqRestart {
                        from_seq: 99,
                        to_seq: 0,
                    },
                    Reason::SeqRestart,
                ),
                "gateway seq went back from 99 to 0 while its stamps moved on: taken as a gateway \
                 restart; its count starts afresh, the metrics continue"
                    .to_owned(),
            ),
            (
                event(
                    EventKind::Rejected,
                    rejected(RejectCause::OutOfRange),
                    Reason::OutOfRange {
                        position_m: [1.0, 2.0, 300.5],
                        distance_m: 300.25,
                    },
                ),
                "measured pose [1.0, 2.0, 300.5] m is 300.25 m from the twin: not a pose of this robot"
                    .to_owned(),
            ),
            (
                event(
                    EventKind::Rejected,
                    rejected(RejectCause::UnknownRobot),
                    Reason::UnknownRobot,
                ),
                "robot 'r1' is not configured and unknown robots are rejected".to_owned(),
            ),
            (
                event(
                    EventKind::Rejected,
                    rejected(RejectCause::FleetFull),
                    Reason::FleetFull { max_robots: 1000 },
                ),
                "robot 'r1' is new and the fleet already holds 1000 robots (max_robots)".to_owned(),
            ),
            (
                event(
                    EventKind::Alarm,
                    EventDetail::Alarm {
                        metric: "position",
                        value: 0.02,
                        threshold: 0.01,
                    },
                    Reason::Alarm {
                        unit: "m",
                        hold_s: 0.5,
                    },
                ),
                "position deviation 0.02 m above 0.01 m for at least 0.5 s".to_owned(),
            ),
            (
                event(
                    EventKind::Recovered,
                    EventDetail::Alarm {
                        metric: "angle",
                        value: 0.001,
                        threshold: 0.01,
                    },
                    Reason::Alarm {
                        unit: "rad",
                        hold_s: 0.0,
                    },
                ),
                "angle deviation 0.001 rad back at or below 0.01 rad for at least 0 s".to_owned(),
            ),
            (
                event(
                    EventKind::Gap,
                    EventDetail::StampGap { gap_s: 1.5 },
                    Reason::StampGap { max_gap_s: 0.25 },
                ),
                "no joint sample for 1.5 s (max_gap_s = 0.25)".to_owned(),
            ),
            (
                event(
                    EventKind::Gap,
                    EventDetail::SeqGap {
                        expected: 5,
                        got: 9,
                    },
                    Reason::SeqGap,
                ),
                "gateway seq jumped from 4 to 9: 4 samples missing upstream".to_owned(),
            ),
            (
                event(
                    EventKind::Restart,
                    EventDetail::Restart {
                        from_s: 1000.19,
                        to_s: 0.0,
                    },
                    Reason::Restart {
                        stream: "joint",
                        restart_s: 5.0,
                    },
                ),
                "joint stamp went back from 1000.19 s to 0 s (more than restart_s = 5 s): taken as a \
                 gateway clock restart; alignment and the metrics window start afresh"
                    .to_owned(),
            ),
            (
                event(
                    EventKind::Unpaired,
                    EventDetail::Unpaired {
                        cause: UnpairedReason::WaitExpired.kind(),
                        measured_s: 2.5,
                    },
                    Reason::Unpaired {
                        reason: UnpairedReason::WaitExpired,
                        align,
                    },
                ),
                format!(
                    "measured pose at t = 2.5 s unpaired: {}",
                    UnpairedReason::WaitExpired.describe(&align)
                ),
            ),
            (
                event(
                    EventKind::Epoch,
                    EventDetail::Epoch { epoch: 2 },
                    Reason::ModelReplaced {
                        source: "self-calibration",
                    },
                ),
                "model replaced by the calibration from self-calibration: metrics epoch 2 begins, \
                 counters and statistics start afresh"
                    .to_owned(),
            ),
            (
                event(
                    EventKind::Epoch,
                    EventDetail::Epoch { epoch: 1 },
                    Reason::ToolReplaced {
                        source: "the controller",
                        tool: [0.0, 0.0, 0.2, 0.0, 0.0, 1.5],
                    },
                ),
                "tool replaced by the controller's tcp_offset [0.0, 0.0, 0.2, 0.0, 0.0, 1.5]: \
                 metrics epoch 1 begins, counters and statistics start afresh"
                    .to_owned(),
            ),
        ];
        for (event, sentence) in cases {
            assert_eq!(event.to_string(), sentence);
        }
    }

    /// A decoder's class that the core also has is the core's cause: one name, one count.
    #[test]
    fn causes_compare_by_name() {
        assert_eq!(RejectCause::Decode("non_finite"), RejectCause::NonFinite);
        assert_ne!(RejectCause::Decode("not_json"), RejectCause::NonFinite);
        assert!(RejectCause::Decode("attachment") < RejectCause::JointCount);
        assert_eq!(RejectCause::Decode("cdr_header").to_string(), "cdr_header");
    }
}
