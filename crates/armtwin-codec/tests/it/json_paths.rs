//! The JSON decoder's two paths (the fast one for the usual shapes, the general one that names
//! every problem) agree; a refused message offers its own stamp; overflow, repetition and
//! quaternion edges.

use armtwin_codec::json::paths::{
    fast_joints, fast_measured, general_joints, general_measured, joint_index,
};
use armtwin_codec::json::{
    WireError, decode_joints, decode_measured, read_joints, read_measured, stamp_hint,
};
use serde_json::Value;

/// Both decoders agree on every message the fast one accepts, and the fast one accepts the
/// usual shapes.
fn assert_paths_agree(payload: &str, joint_count: usize) -> bool {
    let bytes = payload.as_bytes();
    let fast_joints = fast_joints(bytes, joint_count);
    if let Some(fast) = &fast_joints {
        assert_eq!(
            Ok(fast),
            general_joints(bytes, joint_count)
                .map_err(|refused| refused.error)
                .as_ref(),
            "{payload}"
        );
    }
    let fast_measured = fast_measured(bytes);
    if let Some(fast) = &fast_measured {
        assert_eq!(
            Ok(fast),
            general_measured(bytes)
                .map_err(|refused| refused.error)
                .as_ref(),
            "{payload}"
        );
    }
    fast_joints.is_some() || fast_measured.is_some()
}

#[test]
fn the_fast_path_takes_usual_messages_and_agrees_with_the_general_one() {
    let usual = [
        r#"{"t": 12.5, "q": [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739]}"#,
        r#"{"q":[1,2,3,-1,0,1e-3],"seq":7,"time":3}"#,
        r#"{"t":1,"unit":"deg","q":[90,-45,10,0,0,359.5],"extra":{"a":[1e400]}}"#,
        r#"{"t":2,"q":[0,0,0,0,0,0],"measured":{"t":9,"x":1,"y":2,"z":3,"qx":0,"qy":0,"qz":0,"qw":1.02}}"#,
        r#"{"t":2,"q":[0,0,0,0,0,0],"measured":{"x":1,"y":2,"z":3,"rx":0.1,"ry":2,"rz":0.3}}"#,
        r#"{"t": 12.5, "x": -0.807, "y": 0.436, "z": 0.42, "qx": -0.408, "qy": -0.9, "qz": -0.014, "qw": 0.152}"#,
        r#"{"time": 12.5, "x": -0.807, "y": 0.436, "z": 0.42, "roll": -3.038, "pitch": -0.289, "yaw": 2.275}"#,
        r#"{"x": -0.807, "y": 0.436, "z": 0.42, "rx": 0.92, "ry": 2.03, "rz": 0.03, "note": "x"}"#,
        r#"{"t":1,"q":[0,0,0,0,0,0],"note":"Zelle 3 · Roboter ä","flags":[true,false,null,[],{}],"n":-0.0e+0}"#,
        " \t\r\n{ \"t\" :\n1 , \"q\" : [ 0 ,0,0,0,0, 0 ] }\n ",
    ];
    for payload in usual {
        assert!(
            assert_paths_agree(payload, 6),
            "fast path refused {payload}"
        );
    }
    // Unusual or invalid: the general decoder decides (and names the problem).
    let unusual = [
        r#"{"t": null, "q": [0, 0, 0, 0, 0, 0]}"#,
        r#"{"t": 1, "time": 1, "q": [0, 0, 0, 0, 0, 0]}"#,
        r#"{"t": 1, "t": 2, "q": [0, 0, 0, 0, 0, 0]}"#,
        r#"{"t": 1, "q1": 0, "q2": 0, "q3": 0, "q4": 0, "q5": 0, "q6": 0}"#,
        r#"{"t": 1, "q": [0, 0, 0, 0, 0]}"#,
        r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0, 0]}"#,
        r#"{"t": 1, "q": [0, 0, "0", 0, 0, 0]}"#,
        r#"{"t": 1, "q": [0, 0, 0, 0, 0, 1e400]}"#,
        r#"{"t": 1, "seq": -1, "q": [0, 0, 0, 0, 0, 0]}"#,
        r#"{"t": 1, "seq": 1.5, "q": [0, 0, 0, 0, 0, 0]}"#,
        r#"{"t": 1, "unit": "grad", "q": [0, 0, 0, 0, 0, 0]}"#,
        r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0], "measured": {"x": 1, "y": 2, "z": 3}}"#,
        r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0], "measured": {"x": 1, "y": 2, "z": 3, "qx": 0, "qy": 0, "qz": 0, "qw": 2}}"#,
        r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0], "measured": null}"#,
        r#"{"t": 1, "x": 1, "y": 2, "z": 3, "qx": 0, "qy": 0, "qz": 0, "qw": 1, "roll": 0, "pitch": 0, "yaw": 0}"#,
        r#"{"t": 1, "x": 1, "y": 2, "z": 3, "qx": 0, "qy": 0, "qw": 1}"#,
        r#"{"t": 1, "x": 1, "y": 2, "z": 3, "rx": 1e200, "ry": 0, "rz": 0}"#,
        r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0]} trailing"#,
        "[1, 2]",
        // Escapes in a key or a string: rare, left to the general decoder.
        r#"{"\u0074": 1.5, "q": [1, 2, 3, 4, 5, 6]}"#,
        r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0], "note": "a \"quoted\" word"}"#,
        // Not JSON.
        r#"{"t": 01, "q": [0, 0, 0, 0, 0, 0]}"#,
        r#"{"t": 1., "q": [0, 0, 0, 0, 0, 0]}"#,
        r#"{"t": .5, "q": [0, 0, 0, 0, 0, 0]}"#,
        r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0], "note": tru}"#,
        r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0],}"#,
        r#"{"t": 1, "q": [0, 0, 0, 0, 0, 0,]}"#,
        "{\"t\": 1, \"q\": [0, 0, 0, 0, 0, 0], \"note\": \"\u{1}\"}",
    ];
    for payload in unusual {
        assert!(!assert_paths_agree(payload, 6), "fast path took {payload}");
    }
}

proptest::proptest! {
    #[test]
    fn both_paths_agree_on_generated_messages(
        q in proptest::collection::vec(-6.0_f64..6.0, 5..8),
        stamp in proptest::option::of(-1e3_f64..1e6),
        seq in proptest::option::of(0_u64..u64::MAX),
        degrees in proptest::option::of(proptest::bool::ANY),
        pose in proptest::array::uniform7(-2.0_f64..2.0),
        form in 0_usize..4,
        integers in proptest::bool::ANY,
    ) {
        let number = |v: f64| if integers { format!("{}", v.round()) } else { format!("{v:e}") };
        let mut fields = Vec::new();
        if let Some(stamp) = stamp {
            fields.push(format!(r#""t":{}"#, number(stamp)));
        }
        if let Some(seq) = seq {
            fields.push(format!(r#""seq":{seq}"#));
        }
        if let Some(degrees) = degrees {
            fields.push(format!(r#""unit":"{}""#, if degrees { "deg" } else { "rad" }));
        }
        let q_text: Vec<String> = q.iter().map(|&v| number(v)).collect();
        fields.push(format!(r#""q":[{}]"#, q_text.join(",")));
        let [x, y, z, a, b, c, d] = pose;
        let orientation = match form {
            0 => format!(r#""qx":{a},"qy":{b},"qz":{c},"qw":{d}"#),
            1 => format!(r#""roll":{a},"pitch":{b},"yaw":{c}"#),
            2 => format!(r#""rx":{a},"ry":{b},"rz":{c}"#),
            _ => String::new(),
        };
        let pose_text = format!(r#""x":{},"y":{y},"z":{z},{orientation}"#, number(x));
        fields.push(format!(r#""measured":{{{pose_text}}}"#));
        let joints = format!("{{{}}}", fields.join(","));
        assert_paths_agree(&joints, 6);
        let measured = match stamp {
            Some(stamp) => format!(r#"{{"time":{stamp},{pose_text}}}"#),
            None => format!("{{{pose_text}}}"),
        };
        assert_paths_agree(&measured, 6);
    }
}

/// One of four valid messages with `edits` applied: (0 remove, 1 replace, 2 insert; position,
/// byte).
fn damaged(message: usize, edits: Vec<(usize, usize, u8)>) -> Vec<u8> {
    let mut bytes = [
        r#"{"t":1.25,"seq":3,"unit":"deg","q":[0.5,-1e-3,2E2,0,-0,12],"note":{"a":[true,null,"b"]}}"#,
        r#"{"t":1.25,"q":[0.5,-1,2,0,0,1],"measured":{"t":1,"x":0.25,"y":-1,"z":3,"qx":0,"qy":0,"qz":0,"qw":1}}"#,
        r#"{"time":7,"x":0.25,"y":-1,"z":3,"roll":0.1,"pitch":-0.2,"yaw":3.1,"extra":[]}"#,
        r#"{"t":7,"x":0.25,"y":-1,"z":3,"rx":0.1,"ry":-0.2,"rz":1.5}"#,
    ][message]
        .as_bytes()
        .to_vec();
    for (kind, position, byte) in edits {
        let at = position % (bytes.len() + 1);
        match kind {
            0 if at < bytes.len() => {
                bytes.remove(at);
            }
            1 if at < bytes.len() => bytes[at] = byte,
            _ => bytes.insert(at, byte),
        }
    }
    bytes
}

proptest::proptest! {
    #![proptest_config(proptest::test_runner::Config::with_cases(4000))]

    /// Damaged messages: whatever the fast path still accepts, the general decoder reads the
    /// same (it must never take a message the general one refuses, nor read it differently).
    #[test]
    fn both_paths_agree_on_damaged_messages(
        message in 0_usize..4,
        edits in proptest::collection::vec(
            (0_usize..3, proptest::num::usize::ANY, proptest::sample::select(
                br#"{}[]:,".-+eE0159 tfnul\x"#.to_vec(),
            )),
            1..4,
        ),
    ) {
        let bytes = damaged(message, edits);
        if let Ok(text) = std::str::from_utf8(&bytes) {
            assert_paths_agree(text, 6);
        }
    }
}

/// The stamp a refused message offered before the decoder read it in one pass: `t` if
/// present (a `null` or non-number gives none), else `time`, of a payload that parses as a
/// JSON object.
fn stamp_of_parsed(payload: &[u8]) -> Result<Option<f64>, serde_json::Error> {
    let value: Value = serde_json::from_slice(payload)?;
    Ok(value.as_object().and_then(|object| {
        object
            .get("t")
            .or_else(|| object.get("time"))
            .and_then(Value::as_f64)
    }))
}

#[test]
fn a_refused_message_carries_its_own_stamp() {
    let stamp = |payload: &str| {
        read_joints(payload.as_bytes(), 2)
            .expect_err(payload)
            .stamp_s
    };
    assert_eq!(stamp(r#"{"t": 3.5, "q": "x"}"#), Some(3.5));
    assert_eq!(stamp(r#"{"time": 4, "q": [1, 2, 3]}"#), Some(4.0));
    assert_eq!(stamp(r#"{"t": 1, "time": 2, "q": [1, 2]}"#), Some(1.0));
    // A `t` that is no number hides `time`.
    assert_eq!(stamp(r#"{"t": null, "time": 2, "q": [1]}"#), None);
    assert_eq!(stamp(r#"{"t": "5", "time": 2, "q": [1, 2]}"#), None);
    // A repeated field: the last value counts, as in a parsed object.
    assert_eq!(stamp(r#"{"t": 1, "q": [1, 2], "t": 6}"#), Some(6.0));
    // Not JSON, overflowing, or not an object: no stamp.
    assert_eq!(stamp(r#"{"t": 3.5, "q": [1, 2]"#), None);
    assert_eq!(stamp(r#"{"t": 3.5, "q": [1, 1e400]}"#), None);
    assert_eq!(stamp(r#"[{"t": 3.5}]"#), None);
    let refused = read_measured(br#"{"time": 2.5, "x": 0, "y": 0, "z": 0}"#).expect_err("no form");
    assert_eq!(refused.stamp_s, Some(2.5));
    assert_eq!(refused.error.kind(), "orientation_forms");
    assert_eq!(stamp_hint(br#"{"q": 1e400, "t": 7}"#), Some(7.0));
    assert_eq!(stamp_hint(b"{\"t\": 7} x"), None);
}

proptest::proptest! {
    #![proptest_config(proptest::test_runner::Config::with_cases(4000))]

    /// Damaged messages: a refused message offers the stamp of the parsed object, and none
    /// when the payload is not JSON.
    #[test]
    fn damaged_messages_offer_the_stamp_of_the_parsed_object(
        message in 0_usize..4,
        edits in proptest::collection::vec(
            (0_usize..3, proptest::num::usize::ANY, proptest::sample::select(
                br#"{}[]:,".-+eE0159 tfnul\x"#.to_vec(),
            )),
            1..4,
        ),
    ) {
        let bytes = damaged(message, edits);
        let offered = [
            read_joints(&bytes, 6).err().map(|refused| (refused.error, refused.stamp_s)),
            read_measured(&bytes).err().map(|refused| (refused.error, refused.stamp_s)),
        ];
        for (error, stamp_s) in offered.into_iter().flatten() {
            match stamp_of_parsed(&bytes) {
                Ok(parsed) => proptest::prop_assert_eq!(stamp_s, parsed, "{:?}", error),
                Err(_) if matches!(error, WireError::NotJson { .. } | WireError::NonFinite { .. }) => {
                    proptest::prop_assert_eq!(stamp_s, None);
                }
                // Only a number beyond f64 in a field no decoder reads keeps such a payload
                // readable.
                Err(_) => {}
            }
        }
    }
}

#[test]
fn joint_index_accepts_only_plain_positive_numbers() {
    assert_eq!(joint_index("q1"), Some(1));
    assert_eq!(joint_index("q12"), Some(12));
    for key in ["q", "q0", "q01", "q-1", "q+1", "qx", "q1a", "Q1", "time"] {
        assert_eq!(joint_index(key), None, "{key}");
    }
}

#[test]
fn overflowing_numbers_are_located_and_unknown_ones_skipped() {
    let err = decode_joints(br#"{"q": [0, 1e400]}"#, 2).expect_err("overflow");
    assert_eq!(
        err,
        WireError::NonFinite {
            field: "q[1]".to_owned()
        }
    );
    let err = decode_joints(
        br#"{"q1": 0, "q2": 0, "measured": {"x": 0, "y": -1e999, "z": 0}}"#,
        2,
    )
    .expect_err("overflow");
    assert_eq!(
        err,
        WireError::NonFinite {
            field: "measured.y".to_owned()
        }
    );
    // Skipped: an unknown field, and the nested pose's own stamp.
    let sample = decode_joints(
        br#"{"extra": [1e400, {"a": -1e400}], "q": [0, 0],
             "measured": {"t": 1e400, "x": 0, "y": 0, "z": 0, "rx": 0, "ry": 0, "rz": 0}}"#,
        2,
    )
    .expect("unknown fields are skipped");
    assert_eq!(sample.sample.q_rad[..], [0.0, 0.0]);
}

#[test]
fn a_bare_overflowing_number_is_not_json() {
    let err = decode_measured(b"1e400").expect_err("not an object");
    assert_eq!(err.kind(), "not_json");
    assert!(err.to_string().contains("number out of range"), "{err}");
}

#[test]
fn syntax_errors_after_a_field_are_not_blamed_on_it() {
    let err = decode_joints(br#"{"q": [1, 2] "t": 1}"#, 2).expect_err("missing comma");
    assert_eq!(err.kind(), "not_json");
    let err = decode_joints(br#"{"q": [1, 2]} x"#, 2).expect_err("trailing characters");
    assert_eq!(err.kind(), "not_json");
}

#[test]
fn duplicate_known_fields_are_rejected() {
    let err = decode_joints(br#"{"q": [1], "t": 1, "t": 2}"#, 1).expect_err("duplicate");
    assert_eq!(
        err,
        WireError::DuplicateField {
            field: "t".to_owned()
        }
    );
    assert_eq!(err.to_string(), "field 't': appears more than once");
    // Unknown fields are not looked at, repeated or not.
    let sample = decode_joints(br#"{"q": [1], "v": 1, "v": 2}"#, 1).expect("valid");
    assert_eq!(sample.sample.q_rad[..], [1.0]);
}

#[test]
fn rotation_vector_overflow_names_the_largest_component() {
    let err = decode_measured(br#"{"x": 0, "y": 0, "z": 0, "rx": 1, "ry": -1e200, "rz": 0}"#)
        .expect_err("overflow");
    assert_eq!(
        err,
        WireError::NonFinite {
            field: "ry".to_owned()
        }
    );
}

#[test]
fn quaternion_norm_edges() {
    let pose = |q: [f64; 4]| {
        decode_measured(
            format!(
                r#"{{"x": 0, "y": 0, "z": 0, "qx": {}, "qy": {}, "qz": {}, "qw": {}}}"#,
                q[0], q[1], q[2], q[3]
            )
            .as_bytes(),
        )
    };
    assert!(pose([0.0, 0.0, 0.0, 1.0499]).is_ok());
    assert!(pose([0.0, 0.0, 0.0, 0.9501]).is_ok());
    assert!(pose([0.0, 0.0, 0.0, 1.051]).is_err());
    assert!(pose([0.0, 0.0, 0.0, 0.0]).is_err());
    let err = pose([1e200, 0.0, 0.0, 1.0]).expect_err("overflowing norm");
    assert!(matches!(err, WireError::QuaternionNorm { norm, .. } if norm.is_infinite()));
}
