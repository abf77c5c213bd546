//! Wire messages: every accepted gateway form, every rejection class, and the exact field sets of
//! the messages armtwin publishes.

use std::collections::BTreeSet;

use armtwin_codec::json::{
    DeviationMessage, EventMessage, MAX_PAYLOAD_BYTES, MetricsMessage, PoseMessage, StateMessage,
    StatsSetJson, WireError, decode_joints, decode_measured, to_json_bytes,
};
use armtwin_core::kinematics::PoseReadout;
use armtwin_core::metrics::{Deviation, METRIC_NAMES, Stats, StatsSet};
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::{
    Alarms, Event, EventDetail, EventKind, MetricsReadout, Reason, RejectCause, RobotState,
};
use nalgebra::{UnitQuaternion, Vector3};
use serde_json::Value;

/// The joint sample, or the message's error, or the error of its `measured` part.
fn joints(json: &str, joint_count: usize) -> Result<armtwin_core::sample::JointSample, WireError> {
    let decoded = decode_joints(json.as_bytes(), joint_count)?;
    match decoded.measured_error {
        Some(error) => Err(error),
        None => Ok(decoded.sample),
    }
}

#[test]
fn an_invalid_measured_part_leaves_the_joint_sample_valid() {
    let decoded = decode_joints(
        br#"{"t": 3.5, "q": [0.1, 0.2], "measured": {"x": 0, "y": 0, "z": 0, "qx": 0, "qy": 0, "qz": "8.506,978", "qw": 1}}"#,
        2,
    )
    .expect("the joint sample is valid");
    assert_eq!(decoded.sample.q_rad[..], [0.1, 0.2]);
    assert_eq!(decoded.sample.stamp_s, Some(3.5));
    assert_eq!(decoded.sample.measured, None);
    let error = decoded
        .measured_error
        .expect("the measured part is refused");
    assert_eq!(error.kind(), "wrong_type");
    assert!(error.to_string().contains("measured.qz"), "{error}");
    assert_eq!(
        armtwin_codec::json::stamp_hint(br#"{"t": 3.5, "q": "x"}"#),
        Some(3.5)
    );
    assert_eq!(armtwin_codec::json::stamp_hint(b"not json"), None);
}

fn measured(json: &str) -> Result<armtwin_core::sample::MeasuredSample, WireError> {
    decode_measured(json.as_bytes())
}

/// The error, after checking its kind and that its message names `field`.
fn rejected<T: std::fmt::Debug>(
    result: Result<T, WireError>,
    kind: &str,
    field: &str,
) -> WireError {
    let error = result.expect_err("must be rejected");
    assert_eq!(error.kind(), kind, "{error}");
    assert!(
        error.to_string().contains(&format!("'{field}'")),
        "'{error}' does not name '{field}'"
    );
    error
}

fn keys(value: &Value) -> BTreeSet<&str> {
    value
        .as_object()
        .expect("an object")
        .keys()
        .map(String::as_str)
        .collect()
}

fn set(names: &[&'static str]) -> BTreeSet<&'static str> {
    names.iter().copied().collect()
}

fn parse(bytes: &[u8]) -> Value {
    serde_json::from_slice(bytes).expect("valid JSON")
}

// ----- Joint messages: accepted forms ------------------------------------------------------------

#[test]
fn array_form_with_t() {
    let sample = joints(r#"{"t": 12.5, "q": [0.1, -0.2, 0.3, 0, 1, -1]}"#, 6).expect("valid");
    assert_eq!(sample.stamp_s, Some(12.5));
    assert_eq!(sample.seq, None);
    assert_eq!(sample.q_rad[..], [0.1, -0.2, 0.3, 0.0, 1.0, -1.0]);
    assert_eq!(sample.measured, None);
}

#[test]
fn flat_form_with_time_in_any_key_order() {
    let sample = joints(
        r#"{"q3": 3, "time": 7, "q1": 1.5, "q2": -2, "q6": 6, "q5": 5, "q4": 4}"#,
        6,
    )
    .expect("valid");
    assert_eq!(sample.stamp_s, Some(7.0));
    assert_eq!(sample.q_rad[..], [1.5, -2.0, 3.0, 4.0, 5.0, 6.0]);
}

#[test]
fn stamp_is_optional() {
    let sample = joints(r#"{"q": [1, 2]}"#, 2).expect("valid");
    assert_eq!(sample.stamp_s, None);
}

#[test]
fn seq_is_read() {
    let sample = joints(r#"{"seq": 18446744073709551615, "q": [1]}"#, 1).expect("valid");
    assert_eq!(sample.seq, Some(u64::MAX));
    assert_eq!(
        joints(r#"{"seq": 0, "q": [1]}"#, 1).expect("valid").seq,
        Some(0)
    );
}

#[test]
fn degrees_are_converted_and_radians_are_the_default() {
    let deg = joints(r#"{"unit": "deg", "q": [180, -90, 0, 45]}"#, 4).expect("valid");
    let expected = [
        std::f64::consts::PI,
        -std::f64::consts::FRAC_PI_2,
        0.0,
        std::f64::consts::FRAC_PI_4,
    ];
    for (got, want) in deg.q_rad.iter().zip(expected) {
        assert!((got - want).abs() < 1e-15, "{got} vs {want}");
    }
    let deg_flat = joints(r#"{"unit": "deg", "q1": 180, "q2": 90}"#, 2).expect("valid");
    assert!((deg_flat.q_rad[0] - std::f64::consts::PI).abs() < 1e-15);
    let rad = joints(r#"{"unit": "rad", "q": [180]}"#, 1).expect("valid");
    assert_eq!(rad.q_rad[..], [180.0]);
    assert_eq!(
        joints(r#"{"q": [180]}"#, 1).expect("valid").q_rad[..],
        [180.0]
    );
}

#[test]
fn measured_pose_inside_a_joint_message_takes_the_joint_stamp() {
    let sample = joints(
        r#"{"t": 3.0, "q": [0, 0],
            "measured": {"t": 99, "time": 98, "x": 0.1, "y": 0.2, "z": 0.3,
                         "qx": 0, "qy": 0, "qz": 0, "qw": 1}}"#,
        2,
    )
    .expect("valid: the nested stamps are ignored, even both at once");
    assert_eq!(sample.stamp_s, Some(3.0));
    let pose = sample.measured.expect("measured");
    assert_eq!(pose.position_m, [0.1, 0.2, 0.3]);
    assert_eq!(pose.quaternion_xyzw, [0.0, 0.0, 0.0, 1.0]);
}

#[test]
fn unknown_fields_are_ignored() {
    let sample = joints(
        r#"{"q": [1, 2], "gateway": "rtde", "extra": {"nested": [1e999, "x"]}, "q0": "?",
            "Q1": 5, "qx": 7, "measured": {"x": 0, "y": 0, "z": 0, "rx": 0, "ry": 0, "rz": 0,
            "note": true}}"#,
        2,
    )
    .expect("valid");
    assert_eq!(sample.q_rad[..], [1.0, 2.0]);
}

#[test]
fn null_optional_fields_count_as_absent() {
    let sample = joints(
        r#"{"t": null, "seq": null, "unit": null, "measured": null, "q": [1]}"#,
        1,
    )
    .expect("valid");
    assert_eq!(
        (sample.stamp_s, sample.seq, sample.measured),
        (None, None, None)
    );
    assert_eq!(sample.q_rad[..], [1.0]);
}

#[test]
fn exactly_max_payload_bytes_is_accepted() {
    let mut payload = br#"{"q": [1]}"#.to_vec();
    payload.resize(MAX_PAYLOAD_BYTES, b' ');
    assert!(decode_joints(&payload, 1).is_ok());
}

// ----- Joint messages: rejections ------------------------------------------------------------------

#[test]
fn too_large_is_rejected_before_parsing() {
    // Not JSON at all: the size check comes first.
    let payload = vec![b'x'; MAX_PAYLOAD_BYTES + 1];
    let error = decode_joints(&payload, 6).expect_err("too large");
    assert_eq!(error.kind(), "too_large");
    assert_eq!(
        error,
        WireError::TooLarge {
            bytes: 65537,
            limit: 65536
        }
    );
    assert!(error.to_string().contains("65537"), "{error}");
    assert_eq!(
        decode_measured(&payload).expect_err("too large").kind(),
        "too_large"
    );
}

#[test]
fn non_utf8_is_rejected() {
    let error = decode_joints(b"{\"q\": [1], \"name\": \"\xff\xfe\"}", 1).expect_err("not UTF-8");
    assert_eq!(error.kind(), "not_utf8");
    assert_eq!(error, WireError::NotUtf8 { valid_up_to: 20 });
    assert_eq!(
        decode_measured(b"\xc3\x28").expect_err("bad").kind(),
        "not_utf8"
    );
}

#[test]
fn malformed_json_is_rejected() {
    for payload in [
        "",
        "{",
        "{q: [1]}",
        r#"{"q": [1],}"#,
        r#"{"q": [1]} {}"#,
        "NaN",
    ] {
        let error = joints(payload, 1).expect_err(payload);
        assert_eq!(error.kind(), "not_json", "{payload}: {error}");
        assert!(
            error.to_string().starts_with("payload is not JSON"),
            "{error}"
        );
    }
}

#[test]
fn non_objects_are_rejected() {
    for (payload, got) in [
        ("[1, 2]", "an array"),
        ("3", "a number"),
        (r#""q""#, "a string"),
        ("null", "null"),
        ("true", "a boolean"),
    ] {
        let error = joints(payload, 2).expect_err(payload);
        assert_eq!(error, WireError::NotObject { got });
        assert_eq!(error.kind(), "not_object");
        assert_eq!(measured(payload).expect_err(payload).kind(), "not_object");
    }
    // An array of overflowing numbers is still just an array.
    assert_eq!(
        joints("[1e400]", 1).expect_err("array").kind(),
        "not_object"
    );
}

#[test]
fn angle_strings_are_not_coerced() {
    let error = rejected(
        joints(r#"{"q1": 1, "q2": 2, "q3": "1.2"}"#, 3),
        "wrong_type",
        "q3",
    );
    assert_eq!(
        error.to_string(),
        "field 'q3': expected a number, got the string \"1.2\""
    );
    rejected(joints(r#"{"q": [1, "2"]}"#, 2), "wrong_type", "q[1]");
    rejected(joints(r#"{"q": [1, null]}"#, 2), "wrong_type", "q[1]");
    rejected(joints(r#"{"q": [1, [2]]}"#, 2), "wrong_type", "q[1]");
}

#[test]
fn other_wrong_types_are_rejected() {
    rejected(joints(r#"{"q": {"1": 0}}"#, 1), "wrong_type", "q");
    rejected(joints(r#"{"q": [1], "t": "12.5"}"#, 1), "wrong_type", "t");
    rejected(
        joints(r#"{"q": [1], "time": true}"#, 1),
        "wrong_type",
        "time",
    );
    rejected(joints(r#"{"q": [1], "unit": 1}"#, 1), "wrong_type", "unit");
    rejected(
        joints(r#"{"q": [1], "measured": [1, 2]}"#, 1),
        "wrong_type",
        "measured",
    );
    let error = rejected(joints(r#"{"q": [1], "seq": -1}"#, 1), "wrong_type", "seq");
    assert_eq!(
        error.to_string(),
        "field 'seq': expected a non-negative integer, got the number -1"
    );
    rejected(joints(r#"{"q": [1], "seq": 1.5}"#, 1), "wrong_type", "seq");
    rejected(joints(r#"{"q": [1], "seq": "7"}"#, 1), "wrong_type", "seq");
    rejected(joints(r#"{"q": [1], "seq": 1e30}"#, 1), "wrong_type", "seq");
}

#[test]
fn overflowing_numbers_are_non_finite() {
    let error = rejected(joints(r#"{"q1": 0, "q2": 1e400}"#, 2), "non_finite", "q2");
    assert_eq!(
        error,
        WireError::NonFinite {
            field: "q2".to_owned()
        }
    );
    rejected(joints(r#"{"q": [0, -1e400]}"#, 2), "non_finite", "q[1]");
    rejected(joints(r#"{"t": 1e309, "q": [0]}"#, 1), "non_finite", "t");
    rejected(
        joints(
            r#"{"q": [0], "measured": {"x": 0, "y": 0, "z": 0, "qx": 1e400, "qy": 0, "qz": 0, "qw": 1}}"#,
            1,
        ),
        "non_finite",
        "measured.qx",
    );
    rejected(
        measured(r#"{"x": 0, "y": 0, "z": 0, "roll": 0, "pitch": 0, "yaw": 2e308}"#),
        "non_finite",
        "yaw",
    );
    // Underflow is not an error: 1e-400 reads as 0.
    assert_eq!(
        joints(r#"{"q": [1e-400]}"#, 1).expect("valid").q_rad[..],
        [0.0]
    );
}

#[test]
fn joint_count_must_match() {
    let error = rejected(joints(r#"{"q": [1, 2, 3, 4, 5]}"#, 6), "joint_count", "q");
    assert_eq!(
        error,
        WireError::JointCount {
            field: "q".to_owned(),
            expected: 6,
            got: 5
        }
    );
    assert_eq!(
        error.to_string(),
        "field 'q': expected 6 joint angles, got 5"
    );
    rejected(joints(r#"{"q": [1, 2, 3]}"#, 2), "joint_count", "q");
    rejected(joints(r#"{"q": []}"#, 2), "joint_count", "q");
    rejected(joints(r#"{"q1": 1, "q2": 2}"#, 3), "joint_count", "q1..q3");
    // q{n+1} present.
    let error = rejected(
        joints(r#"{"q1": 1, "q2": 2, "q3": 3}"#, 2),
        "joint_count",
        "q1..q2",
    );
    assert!(matches!(error, WireError::JointCount { got: 3, .. }));
}

#[test]
fn missing_fields_are_named() {
    // As many q<n> fields as joints, but one of them is beyond the arm.
    let error = rejected(
        joints(r#"{"q1": 1, "q2": 2, "q4": 4}"#, 3),
        "missing_field",
        "q3",
    );
    assert_eq!(error.to_string(), "field 'q3': missing");
    rejected(joints(r#"{"t": 1}"#, 3), "missing_field", "q");
    rejected(
        joints(
            r#"{"q": [0], "measured": {"x": 0, "y": 0, "qw": 1, "qx": 0, "qy": 0, "qz": 0}}"#,
            1,
        ),
        "missing_field",
        "measured.z",
    );
}

#[test]
fn ambiguous_fields_are_rejected() {
    let error = rejected(
        joints(r#"{"t": 1, "time": 1, "q": [0]}"#, 1),
        "ambiguous_fields",
        "t",
    );
    assert_eq!(
        error.to_string(),
        "fields 't' and 'time' are both present; send only one"
    );
    let error = rejected(
        joints(r#"{"q": [0, 0], "q2": 0, "q1": 0}"#, 2),
        "ambiguous_fields",
        "q1",
    );
    assert!(error.to_string().contains("'q'"), "{error}");
    rejected(
        measured(r#"{"t": 1, "time": 2, "x": 0, "y": 0, "z": 0, "rx": 0, "ry": 0, "rz": 0}"#),
        "ambiguous_fields",
        "time",
    );
}

#[test]
fn repeated_fields_are_rejected() {
    rejected(joints(r#"{"q": [0], "q": [1]}"#, 1), "duplicate_field", "q");
    rejected(
        joints(r#"{"q": [0], "measured": {"x": 0, "x": 1}}"#, 1),
        "duplicate_field",
        "measured.x",
    );
}

#[test]
fn unknown_units_are_rejected() {
    let error = rejected(joints(r#"{"q": [0], "unit": "grad"}"#, 1), "unit", "unit");
    assert_eq!(
        error.to_string(),
        r#"field 'unit': expected "rad" or "deg", got "grad""#
    );
    rejected(joints(r#"{"q": [0], "unit": "DEG"}"#, 1), "unit", "unit");
}

// ----- Measured poses ------------------------------------------------------------------------------

/// A measured message with position `[0.4, -0.2, 0.9]` and the given orientation fields.
fn measured_with(orientation: &str) -> Result<armtwin_core::sample::MeasuredSample, WireError> {
    measured(&format!(
        r#"{{"t": 4.25, "x": 0.4, "y": -0.2, "z": 0.9, {orientation}}}"#
    ))
}

fn quaternion_fields(q: &UnitQuaternion<f64>) -> String {
    format!(
        r#""qx": {:?}, "qy": {:?}, "qz": {:?}, "qw": {:?}"#,
        q.i, q.j, q.k, q.w
    )
}

fn assert_same_pose(a: &PoseReadout, b: &PoseReadout) {
    assert_eq!(a.position_m, b.position_m);
    for (x, y) in a.quaternion_xyzw.iter().zip(b.quaternion_xyzw) {
        assert!((x - y).abs() < 1e-12, "{a:?} vs {b:?}");
    }
    for (x, y) in [
        (a.rpy.roll_rad, b.rpy.roll_rad),
        (a.rpy.pitch_rad, b.rpy.pitch_rad),
        (a.rpy.yaw_rad, b.rpy.yaw_rad),
    ] {
        assert!((x - y).abs() < 1e-12, "{a:?} vs {b:?}");
    }
}

#[test]
fn quaternion_form() {
    let sample = measured_with(r#""qx": 0, "qy": 0, "qz": 0.6, "qw": 0.8"#).expect("valid");
    assert_eq!(sample.stamp_s, Some(4.25));
    assert_eq!(sample.pose.position_m, [0.4, -0.2, 0.9]);
    assert_eq!(sample.pose.quaternion_xyzw, [0.0, 0.0, 0.6, 0.8]);
    let yaw = 2.0 * 0.6f64.atan2(0.8);
    assert!((sample.pose.rpy.yaw_rad - yaw).abs() < 1e-15);
    // `time` and no stamp work too; a negative-w quaternion is canonicalised.
    let sample = measured(
        r#"{"time": 1, "x": 0, "y": 0, "z": 0, "qx": 0, "qy": 0, "qz": -0.6, "qw": -0.8}"#,
    )
    .expect("valid");
    assert_eq!(sample.stamp_s, Some(1.0));
    assert_eq!(sample.pose.quaternion_xyzw, [0.0, 0.0, 0.6, 0.8]);
    let sample = measured(r#"{"x": 0, "y": 0, "z": 0, "rx": 0, "ry": 0, "rz": 0}"#).expect("valid");
    assert_eq!(sample.stamp_s, None);
}

#[test]
fn rotation_vector_and_rpy_give_the_pose_of_the_equivalent_quaternion() {
    for (roll, pitch, yaw) in [
        (0.0, 0.0, 0.0),
        (0.3, -0.7, 2.1),
        (-2.9, 1.2, -0.4),
        (1.0, 0.0, 3.0),
        (0.01, -1.5, 0.2),
    ] {
        // nalgebra's Euler angles are applied roll, then pitch, then yaw: Rz · Ry · Rx.
        let q = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
        let reference = measured_with(&quaternion_fields(&q)).expect("quaternion");
        let from_rpy = measured_with(&format!(
            r#""roll": {roll:?}, "pitch": {pitch:?}, "yaw": {yaw:?}"#
        ))
        .expect("rpy");
        assert_same_pose(&from_rpy.pose, &reference.pose);
        let [rx, ry, rz]: [f64; 3] = q.scaled_axis().into();
        let from_rotation_vector =
            measured_with(&format!(r#""rx": {rx:?}, "ry": {ry:?}, "rz": {rz:?}"#))
                .expect("rotation vector");
        assert_same_pose(&from_rotation_vector.pose, &reference.pose);
    }
    // A UR pendant value, checked against nalgebra's own axis-angle conversion.
    let r = Vector3::new(2.2214, -2.2214, 0.0);
    let reference = measured_with(&quaternion_fields(&UnitQuaternion::from_scaled_axis(r)))
        .expect("quaternion");
    let from_rotation_vector =
        measured_with(r#""rx": 2.2214, "ry": -2.2214, "rz": 0.0"#).expect("rotation vector");
    assert_same_pose(&from_rotation_vector.pose, &reference.pose);
}

#[test]
fn rounded_quaternions_are_normalised_within_five_percent() {
    let q = [0.0, 0.0, 0.6, 0.8];
    for scale in [0.951, 0.99, 1.0001, 1.049] {
        let fields = format!(
            r#""qx": {}, "qy": {}, "qz": {}, "qw": {}"#,
            q[0] * scale,
            q[1] * scale,
            q[2] * scale,
            q[3] * scale
        );
        let sample = measured_with(&fields).expect("within 5 %");
        let [x, y, z, w] = sample.pose.quaternion_xyzw;
        assert!(((x * x + y * y + z * z + w * w).sqrt() - 1.0).abs() < 1e-15);
        assert!((z - 0.6).abs() < 1e-15 && (w - 0.8).abs() < 1e-15);
    }
    for scale in [0.949, 1.051, 2.0] {
        let fields = format!(
            r#""qx": {}, "qy": {}, "qz": {}, "qw": {}"#,
            q[0] * scale,
            q[1] * scale,
            q[2] * scale,
            q[3] * scale
        );
        let error = rejected(measured_with(&fields), "quaternion_norm", "qx..qw");
        assert!(
            matches!(error, WireError::QuaternionNorm { norm, .. } if (norm - scale).abs() < 1e-12)
        );
    }
    rejected(
        measured_with(r#""qx": 0, "qy": 0, "qz": 0, "qw": 0"#),
        "quaternion_norm",
        "qx..qw",
    );
    rejected(
        measured_with(r#""qx": 1e300, "qy": 0, "qz": 0, "qw": 1"#),
        "quaternion_norm",
        "qx..qw",
    );
    rejected(
        joints(
            r#"{"q": [0], "measured": {"x": 0, "y": 0, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 0.5}}"#,
            1,
        ),
        "quaternion_norm",
        "measured.qx..qw",
    );
}

#[test]
fn a_partial_orientation_form_names_the_missing_field() {
    let error = rejected(
        measured_with(r#""qx": 0, "qy": 0, "qz": 0"#),
        "missing_field",
        "qw",
    );
    assert_eq!(error.to_string(), "field 'qw': missing");
    rejected(
        measured_with(r#""roll": 0, "yaw": 0"#),
        "missing_field",
        "pitch",
    );
    rejected(measured_with(r#""rz": 0"#), "missing_field", "rx");
}

#[test]
fn orientation_needs_exactly_one_form() {
    let error =
        measured_with(r#""qx": 0, "qy": 0, "qz": 0, "qw": 1, "roll": 0, "pitch": 0, "yaw": 0"#)
            .expect_err("two forms");
    assert_eq!(error.kind(), "orientation_forms");
    assert_eq!(
        error,
        WireError::OrientationForms {
            found: vec!["qx".to_owned(), "roll".to_owned()]
        }
    );
    assert!(error.to_string().contains("'qx', 'roll'"), "{error}");
    // A stray field of a second form counts as a second form.
    let error = rejected(
        measured_with(r#""rx": 0, "ry": 0, "rz": 0, "qw": 1"#),
        "orientation_forms",
        "rx",
    );
    assert!(error.to_string().contains("'qw'"), "{error}");
    let error = measured(r#"{"x": 0, "y": 0, "z": 0}"#).expect_err("no orientation");
    assert_eq!(error, WireError::OrientationForms { found: vec![] });
    assert!(error.to_string().contains("no orientation"), "{error}");
}

#[test]
fn measured_position_fields_are_required_numbers() {
    rejected(
        measured(r#"{"y": 0, "z": 0, "rx": 0, "ry": 0, "rz": 0}"#),
        "missing_field",
        "x",
    );
    rejected(
        measured(r#"{"x": "0", "y": 0, "z": 0, "rx": 0, "ry": 0, "rz": 0}"#),
        "wrong_type",
        "x",
    );
    rejected(
        measured(r#"{"x": 0, "y": 0, "z": 0, "rx": 0, "ry": null, "rz": 0}"#),
        "wrong_type",
        "ry",
    );
}

// ----- Encoded messages -------------------------------------------------------------------------------

fn readout() -> PoseReadout {
    PoseReadout::from_position_quaternion(
        [0.5, -0.25, 1.0],
        &UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
    )
}

fn stats_set(n: u64, offset: f64) -> StatsSet {
    StatsSet {
        n,
        stats: std::array::from_fn(|m| Stats {
            mae: offset + m as f64,
            rmse: offset + m as f64 + 0.5,
            max: offset + m as f64 + 0.75,
        }),
    }
}

fn metrics_readout() -> MetricsReadout {
    MetricsReadout {
        robot: "ur10e_1".to_owned(),
        stamp_s: 12.5,
        paired: 10,
        unpaired: 2,
        rejected: 1,
        cumulative: stats_set(10, 0.0),
        window: stats_set(4, 100.0),
        window_s: 5.0,
        epoch: 0,
        effort: None,
    }
}

const POSE_FIELDS: [&str; 10] = [
    "x", "y", "z", "roll", "pitch", "yaw", "qx", "qy", "qz", "qw",
];

fn stats_set_fields() -> BTreeSet<&'static str> {
    let mut fields = set(&METRIC_NAMES);
    fields.insert("n");
    fields
}

/// `value` as `serde_json` reads it back: its default parser may be one unit in the last place off.
fn assert_number(json: &Value, value: f64) {
    let got = json.as_f64().expect("a number");
    assert!(
        (got - value).abs() <= 2.0 * f64::EPSILON * value.abs(),
        "{got} vs {value}"
    );
}

#[test]
fn pose_message_fields() {
    let pose = readout();
    let bytes = to_json_bytes(&PoseMessage::new("ur10e_1", 2.5, 7, "base", &pose));
    let json = parse(&bytes);
    let mut expected = set(&["robot", "t", "seq", "frame"]);
    expected.extend(POSE_FIELDS);
    assert_eq!(keys(&json), expected);
    assert_eq!(json["robot"], "ur10e_1");
    assert_eq!(json["t"], 2.5);
    assert_eq!(json["seq"], 7);
    assert_eq!(json["frame"], "base");
    assert_eq!(json["x"], 0.5);
    assert_number(&json["roll"], pose.rpy.roll_rad);
    assert_number(&json["qw"], pose.quaternion_xyzw[3]);
    // Written in shortest round-trip form.
    let text = String::from_utf8(bytes).expect("UTF-8");
    assert!(
        text.contains(&format!(r#""roll":{:?}"#, pose.rpy.roll_rad)),
        "{text}"
    );
}

#[test]
fn a_published_pose_without_its_rpy_decodes_to_the_same_pose() {
    let pose = readout();
    let mut json = parse(&to_json_bytes(&PoseMessage::new(
        "r", 2.5, 7, "base", &pose,
    )));
    // A pose message carries two orientation forms; a measured message must carry one.
    assert_eq!(
        decode_measured(&to_json_bytes(&json))
            .expect_err("two forms")
            .kind(),
        "orientation_forms"
    );
    for key in ["roll", "pitch", "yaw"] {
        json.as_object_mut().expect("object").remove(key);
    }
    let back = decode_measured(&to_json_bytes(&json)).expect("valid");
    assert_eq!(back.stamp_s, Some(2.5));
    assert_same_pose(&back.pose, &pose);
}

#[test]
fn deviation_message_fields() {
    let twin = readout();
    let measured =
        PoseReadout::from_position_quaternion([0.4, -0.25, 1.0], &UnitQuaternion::identity());
    let deviation = Deviation::between(&twin, &measured);
    let json = parse(&to_json_bytes(&DeviationMessage::new(
        "ur10e_1", 3.0, &deviation,
    )));
    assert_eq!(
        keys(&json),
        set(&[
            "robot",
            "t",
            "dx",
            "dy",
            "dz",
            "position",
            "quat_distance",
            "angle",
            "droll",
            "dpitch",
            "dyaw"
        ])
    );
    assert_number(&json["dx"], deviation.dx_m);
    assert_number(&json["position"], deviation.position_m);
    assert_number(&json["angle"], deviation.angle_rad);
    assert_number(&json["dyaw"], deviation.dyaw_rad);
}

#[test]
fn event_message_fields() {
    let error = WireError::WrongType {
        field: "q3".to_owned(),
        expected: "a number",
        got: "a string".to_owned(),
    };
    let event = Event {
        robot: "ur10e_1",
        index: None,
        stamp_s: 4.0,
        kind: EventKind::Rejected,
        reason: Reason::Error(&error),
        key: Some("armtwin/joints/ur10e_1"),
        detail: EventDetail::Rejected {
            cause: RejectCause::Decode("wrong_type"),
        },
    };
    let json = parse(&to_json_bytes(&EventMessage::new(&event)));
    assert_eq!(
        keys(&json),
        set(&["robot", "t", "kind", "reason", "key", "detail"])
    );
    assert_eq!(json["kind"], "rejected");
    assert_eq!(json["key"], "armtwin/joints/ur10e_1");
    assert_eq!(json["detail"], serde_json::json!({"cause": "wrong_type"}));

    let details = [
        (
            EventKind::Alarm,
            EventDetail::Alarm {
                metric: "position",
                value: 0.02,
                threshold: 0.01,
            },
            vec!["metric", "value", "threshold"],
        ),
        (
            EventKind::Gap,
            EventDetail::StampGap { gap_s: 1.5 },
            vec!["gap_s"],
        ),
        (
            EventKind::Gap,
            EventDetail::SeqGap {
                expected: 4,
                got: 9,
            },
            vec!["expected", "got"],
        ),
        (
            EventKind::Unpaired,
            EventDetail::Unpaired {
                cause: "wait_expired",
                measured_s: 3.5,
            },
            vec!["cause", "measured_s"],
        ),
        (
            EventKind::Epoch,
            EventDetail::Epoch { epoch: 1 },
            vec!["epoch"],
        ),
    ];
    for (kind, detail, detail_fields) in details {
        let event = Event {
            kind,
            key: None,
            detail,
            ..event
        };
        let json = parse(&to_json_bytes(&EventMessage::new(&event)));
        assert_eq!(
            keys(&json),
            set(&["robot", "t", "kind", "reason", "detail"])
        );
        assert_eq!(json["kind"], kind.as_str());
        assert_eq!(keys(&json["detail"]), detail_fields.into_iter().collect());
    }

    let bare = EventMessage {
        detail: Value::Null,
        key: None,
        ..EventMessage::new(&event)
    };
    let json = parse(&to_json_bytes(&bare));
    assert_eq!(keys(&json), set(&["robot", "t", "kind", "reason"]));
}

#[test]
fn metrics_message_fields() {
    let json = parse(&to_json_bytes(&MetricsMessage::new(&metrics_readout())));
    assert_eq!(
        keys(&json),
        set(&[
            "robot",
            "t",
            "paired",
            "unpaired",
            "rejected",
            "epoch",
            "cumulative",
            "window"
        ])
    );
    assert_eq!(json["t"], 12.5);
    assert_eq!(
        (json["paired"].as_u64(), json["unpaired"].as_u64()),
        (Some(10), Some(2))
    );
    assert_eq!(json["rejected"], 1);
    assert_eq!(keys(&json["cumulative"]), stats_set_fields());
    let mut window_fields = stats_set_fields();
    window_fields.insert("seconds");
    assert_eq!(keys(&json["window"]), window_fields);
    assert_eq!(json["window"]["seconds"], 5.0);
    assert_eq!(json["window"]["n"], 4);
    // Each metric lands under its own name.
    for (m, name) in METRIC_NAMES.iter().enumerate() {
        let cumulative = &json["cumulative"][name];
        assert_eq!(keys(cumulative), set(&["mae", "rmse", "max"]));
        assert_eq!(cumulative["mae"], m as f64, "{name}");
        assert_eq!(cumulative["rmse"], m as f64 + 0.5, "{name}");
        assert_eq!(cumulative["max"], m as f64 + 0.75, "{name}");
        assert_eq!(json["window"][name]["mae"], 100.0 + m as f64, "{name}");
    }
    // The window's `seconds` comes first.
    let text =
        String::from_utf8(to_json_bytes(&MetricsMessage::new(&metrics_readout()))).expect("UTF-8");
    assert!(text.contains(r#""window":{"seconds":5.0,"n":4,"#), "{text}");
}

#[test]
fn stats_set_json_keeps_metric_order() {
    let json = serde_json::to_value(StatsSetJson::from(&stats_set(3, 0.0))).expect("serialises");
    assert_eq!(json["n"], 3);
    assert_eq!(json["yaw"]["mae"], 8.0);
    assert_eq!(json["position"]["max"], 0.75);
}

#[test]
fn state_message_fields() {
    let model = RobotModel::nominal("ur10e").expect("catalog model");
    let twin = readout();
    let q = [0.0, -1.0, 1.0, 0.0, 0.5, 0.0];
    let state = RobotState {
        robot: "ur10e_1",
        model: &model,
        last_joints: Some((2.0, &q)),
        last_twin_pose: Some((2.0, &twin)),
        last_measured: None,
        metrics: metrics_readout(),
        alarms_active: Alarms {
            position: true,
            angle: false,
        },
        last_state: None,
    };
    let json = parse(&to_json_bytes(&StateMessage::new(&state)));
    assert_eq!(
        keys(&json),
        set(&[
            "robot",
            "model",
            "calibration",
            "tool",
            "frame",
            "joints",
            "joint_state",
            "twin",
            "measured",
            "alarms",
            "metrics"
        ])
    );
    assert_eq!(json["model"], "ur10e");
    assert_eq!(json["calibration"], Value::Null);
    assert_eq!(json["frame"], "base");
    assert_eq!(
        json["tool"],
        serde_json::json!([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    );
    assert_eq!(keys(&json["joints"]), set(&["t", "q"]));
    assert_eq!(json["joints"]["q"][1], -1.0);
    let mut twin_fields = set(&["t"]);
    twin_fields.extend(POSE_FIELDS);
    assert_eq!(keys(&json["twin"]), twin_fields);
    assert_eq!(json["measured"], Value::Null);
    assert_eq!(
        json["alarms"],
        serde_json::json!({"position": true, "angle": false})
    );
    assert_eq!(
        json["metrics"],
        parse(&to_json_bytes(&MetricsMessage::new(&metrics_readout())))
    );
}

mod fixed_layout {
    //! The frequent messages' own writer against `serde_json` writing the same structs: the
    //! same bytes, for any values and any robot id.
    use armtwin_codec::PoseFields;
    use armtwin_codec::json::{
        DeviationMessage, MetricsMessage, PoseMessage, StatsJson, StatsSetJson, WindowJson,
        to_json_bytes,
    };
    use proptest::prelude::*;

    /// Any double, the awkward ones much more often than uniform bits would give them.
    fn any_f64() -> impl Strategy<Value = f64> {
        prop_oneof![
            any::<f64>(),
            -10.0..10.0f64,
            Just(0.0),
            Just(-0.0),
            Just(f64::NAN),
            Just(f64::INFINITY),
            Just(f64::NEG_INFINITY),
            Just(f64::MIN_POSITIVE / 8.0),
            Just(1e21),
            Just(1e-7),
            Just(f64::MAX),
        ]
    }

    /// Robot ids, including those that need escaping and non-ASCII ones.
    fn any_robot() -> impl Strategy<Value = String> {
        prop_oneof![
            "[a-z0-9_/-]{1,24}",
            any::<String>(),
            Just("quote\"back\\slash\u{1}tab\t".to_owned()),
            Just("unit\u{1f}separator\u{7f}delete".to_owned()),
            Just("zelle-3/roboter-ä/😀".to_owned()),
        ]
    }

    fn any_stats() -> impl Strategy<Value = StatsJson> {
        (any_f64(), any_f64(), any_f64()).prop_map(|(mae, rmse, max)| StatsJson { mae, rmse, max })
    }

    fn any_stats_set() -> impl Strategy<Value = StatsSetJson> {
        (any::<u64>(), prop::array::uniform9(any_stats())).prop_map(|(n, stats)| {
            let [position, x, y, z, quat_distance, angle, roll, pitch, yaw] = stats;
            StatsSetJson {
                n,
                position,
                x,
                y,
                z,
                quat_distance,
                angle,
                roll,
                pitch,
                yaw,
            }
        })
    }

    proptest! {
        #[test]
        fn a_metrics_message_is_written_as_serde_json_writes_it(
            robot in any_robot(),
            t in any_f64(),
            counts in prop::array::uniform4(any::<u64>()),
            cumulative in any_stats_set(),
            seconds in any_f64(),
            window in any_stats_set(),
        ) {
            let [paired, unpaired, rejected, epoch] = counts;
            let message = MetricsMessage {
                robot,
                t,
                paired,
                unpaired,
                rejected,
                epoch,
                cumulative,
                window: WindowJson { seconds, stats: window },
                // Both with and without a watched robot's effort object.
                effort: (paired % 2 == 0)
                    .then(|| serde_json::json!({ "n": unpaired, "rms_nm": [t, seconds] })),
            };
            let fixed = message.to_json_bytes();
            let serde = to_json_bytes(&message);
            prop_assert_eq!(String::from_utf8_lossy(&fixed), String::from_utf8_lossy(&serde));
        }

        #[test]
        fn a_pose_message_is_written_as_serde_json_writes_it(
            robot in any_robot(),
            t in any_f64(),
            seq in any::<u64>(),
            base_link in any::<bool>(),
            values in prop::array::uniform10(any_f64()),
        ) {
            let [x, y, z, roll, pitch, yaw, qx, qy, qz, qw] = values;
            let message = PoseMessage {
                robot,
                t,
                seq,
                frame: if base_link { "base_link" } else { "base" },
                pose: PoseFields { x, y, z, roll, pitch, yaw, qx, qy, qz, qw },
            };
            let fixed = message.to_json_bytes();
            let serde = to_json_bytes(&message);
            prop_assert_eq!(String::from_utf8_lossy(&fixed), String::from_utf8_lossy(&serde));
        }

        #[test]
        fn a_deviation_message_is_written_as_serde_json_writes_it(
            robot in any_robot(),
            t in any_f64(),
            values in prop::array::uniform9(any_f64()),
        ) {
            let [dx, dy, dz, position, quat_distance, angle, droll, dpitch, dyaw] = values;
            let message = DeviationMessage {
                robot, t, dx, dy, dz, position, quat_distance, angle, droll, dpitch, dyaw,
            };
            let fixed = message.to_json_bytes();
            let serde = to_json_bytes(&message);
            prop_assert_eq!(String::from_utf8_lossy(&fixed), String::from_utf8_lossy(&serde));
        }
    }
}
