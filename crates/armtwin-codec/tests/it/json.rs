//! Gateway messages in JSON: every accepted form and every rejection class, of joint messages
//! and of measured poses. (The messages armtwin publishes are `json_messages`'.)

use armtwin_codec::json::{MAX_PAYLOAD_BYTES, WireError, decode_joints, decode_measured};
use armtwin_core::kinematics::PoseReadout;
use nalgebra::{UnitQuaternion, Vector3};

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

pub(crate) fn assert_same_pose(a: &PoseReadout, b: &PoseReadout) {
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
