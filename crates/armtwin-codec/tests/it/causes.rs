//! Every rejection cause keeps its wire name: the core's own and the codecs' together are exactly
//! the names events, reports and counters have always carried, and each codec error's cause is
//! one of them.

use std::collections::BTreeSet;

use armtwin_codec::cdr::CdrError;
use armtwin_codec::decoded::{CodecError, DECODE_CAUSES};
use armtwin_codec::json::WireError;
use armtwin_codec::ros2_attachment::AttachmentError;
use armtwin_core::pipeline::RejectCause;

/// Every cause name the events, reports and `/metrics` carry, written out here on their own so that
/// a cause renamed or dropped by either the core or a codec fails this test.
const WIRE_NAMES: [&str; 32] = [
    "too_large",
    "not_utf8",
    "not_json",
    "not_object",
    "missing_field",
    "wrong_type",
    "non_finite",
    "joint_count",
    "ambiguous_fields",
    "duplicate_field",
    "unit",
    "orientation_forms",
    "quaternion_norm",
    "truncated",
    "trailing_bytes",
    "malformed_length",
    "sequence_length",
    "schema",
    "joint_limits",
    "out_of_order",
    "duplicate_stamp",
    "out_of_range",
    "unknown_robot",
    "fleet_full",
    "cdr_header",
    "cdr_truncated",
    "cdr_malformed",
    "missing_joint",
    "duplicate_joint",
    "frame_id",
    "attachment",
    "joint_state",
];

#[test]
fn the_core_and_the_codecs_name_exactly_the_old_causes() {
    let core = [
        RejectCause::NonFinite,
        RejectCause::JointCount,
        RejectCause::JointLimits,
        RejectCause::OutOfOrder,
        RejectCause::DuplicateStamp,
        RejectCause::OutOfRange,
        RejectCause::UnknownRobot,
        RejectCause::FleetFull,
    ];
    let names: Vec<&str> = core
        .iter()
        .map(|cause| cause.as_str())
        .chain(DECODE_CAUSES)
        .collect();
    let unique: BTreeSet<&str> = names.iter().copied().collect();
    assert_eq!(unique.len(), names.len(), "a name twice: {names:?}");
    assert_eq!(unique, WIRE_NAMES.into_iter().collect::<BTreeSet<_>>());
}

#[test]
fn each_codec_error_has_a_known_cause() {
    let known: BTreeSet<&str> = WIRE_NAMES.into_iter().collect();
    let field = || "f".to_owned();
    let wire = [
        WireError::TooLarge { bytes: 1, limit: 0 },
        WireError::NotUtf8 { valid_up_to: 0 },
        WireError::NotJson { detail: field() },
        WireError::NotObject { got: "a number" },
        WireError::MissingField { field: field() },
        WireError::NonFinite { field: field() },
        WireError::JointCount {
            field: field(),
            expected: 6,
            got: 5,
        },
        WireError::Schema { expected: "s" },
        WireError::JointState {
            field: field(),
            detail: field(),
        },
    ];
    let cdr = [
        CdrError::NoHeader { bytes: 2 },
        CdrError::Truncated {
            field: field(),
            needed: 8,
            offset: 0,
            body: 0,
        },
        CdrError::Unterminated { field: field() },
        CdrError::NonFinite { field: field() },
        CdrError::FrameId {
            frame_id: field(),
            expected: field(),
        },
    ];
    let causes = wire
        .iter()
        .map(CodecError::reject_cause)
        .chain(cdr.iter().map(CodecError::reject_cause))
        .chain([AttachmentError::Trailing { extra: 1 }.reject_cause()]);
    for cause in causes {
        assert!(known.contains(cause.as_str()), "{cause}");
    }
    // A class both sides have is the core's cause, so it is counted once.
    assert_eq!(
        WireError::NonFinite { field: field() }.cause(),
        RejectCause::NonFinite
    );
    assert!(matches!(
        CdrError::NonFinite { field: field() }.cause(),
        RejectCause::NonFinite
    ));
}
