//! The exchange as a controller answers it (bytes built here from UR's RTDE guide, not by the
//! module's own encoders), and every way a controller's bytes can be wrong.

use super::frame::{self, Frame, FrameSplitter, PackageType};
use super::handshake::{Handshake, Progress, Started};
use super::recipe::{self, RtdeSample, VARIABLES, VariableType};
use super::{ProtocolVersion, RtdeError, record};
use crate::recording;

/// A package as a controller sends it.
fn package(kind: u8, payload: &[u8]) -> Vec<u8> {
    let size = u16::try_from(3 + payload.len()).unwrap();
    [&size.to_be_bytes()[..], &[kind], payload].concat()
}

fn one_frame(bytes: &[u8]) -> (u8, Vec<u8>) {
    let mut splitter = FrameSplitter::new();
    splitter.extend(bytes).unwrap();
    let taken = {
        let frame = splitter.next_frame().unwrap().unwrap();
        (frame.kind, frame.payload.to_vec())
    };
    assert_eq!(splitter.pending_bytes(), 0);
    taken
}

fn feed(handshake: &mut Handshake, bytes: &[u8]) -> Result<Progress, RtdeError> {
    let (kind, payload) = one_frame(bytes);
    handshake.on_frame(Frame {
        kind,
        payload: &payload,
    })
}

fn sent(progress: Result<Progress, RtdeError>) -> (u8, Vec<u8>) {
    match progress {
        Ok(Progress::Send(bytes)) => one_frame(&bytes),
        other => panic!("expected bytes to send, got {other:?}"),
    }
}

const CONTROLLER_5_21: [u8; 16] = [0, 0, 0, 5, 0, 0, 0, 21, 0, 0, 0, 0, 0, 0, 0, 9];

/// The names of an output setup's payload, after the frequency under protocol 2.
fn setup_names(payload: &[u8], version: ProtocolVersion) -> Vec<String> {
    let names = match version {
        ProtocolVersion::V2 => {
            assert_eq!(payload[..8], 500.0_f64.to_be_bytes());
            &payload[8..]
        }
        ProtocolVersion::V1 => payload,
    };
    std::str::from_utf8(names)
        .unwrap()
        .split(',')
        .map(str::to_owned)
        .collect()
}

/// A controller that knows only `known`: the answer to a setup of `names`.
fn setup_answer(id: Option<u8>, names: &[String], known: &[&str]) -> Vec<u8> {
    let types: Vec<&str> = names
        .iter()
        .map(|name| {
            if known.contains(&name.as_str()) {
                recipe::variable_named(name).unwrap().kind.as_str()
            } else {
                "NOT_FOUND"
            }
        })
        .collect();
    let mut payload: Vec<u8> = id.into_iter().collect();
    payload.extend_from_slice(types.join(",").as_bytes());
    package(b'O', &payload)
}

/// Runs the exchange to its start with a controller of protocol `version` that knows `known`.
fn started(version: ProtocolVersion, known: &[&str]) -> (Handshake, Started) {
    let (mut handshake, first) = Handshake::new(500.0).unwrap();
    assert_eq!(one_frame(&first), (b'V', vec![0, 2]));
    let mut next = feed(
        &mut handshake,
        &package(b'V', &[u8::from(version == ProtocolVersion::V2)]),
    );
    if version == ProtocolVersion::V1 {
        assert_eq!(sent(next), (b'V', vec![0, 1]));
        next = feed(&mut handshake, &package(b'V', &[1]));
    }
    assert_eq!(sent(next), (b'v', vec![]));
    let (kind, payload) = sent(feed(&mut handshake, &package(b'v', &CONTROLLER_5_21)));
    assert_eq!(kind, b'O');
    let mut names = setup_names(&payload, version);
    assert_eq!(names.len(), VARIABLES.len());
    let id = (version == ProtocolVersion::V2).then_some(3);
    let mut answer = feed(&mut handshake, &setup_answer(id, &names, known));
    if names.iter().any(|name| !known.contains(&name.as_str())) {
        let (kind, payload) = sent(answer);
        assert_eq!(kind, b'O');
        names = setup_names(&payload, version);
        assert!(
            names.iter().all(|name| known.contains(&name.as_str())),
            "{names:?}"
        );
        answer = feed(&mut handshake, &setup_answer(id, &names, known));
    }
    assert_eq!(sent(answer), (b'S', vec![]));
    assert!(!handshake.is_streaming());
    match feed(&mut handshake, &package(b'S', &[1])) {
        Ok(Progress::Started(started)) => {
            assert!(handshake.is_streaming());
            (handshake, started)
        }
        other => panic!("expected the start, got {other:?}"),
    }
}

fn sample() -> RtdeSample {
    RtdeSample {
        timestamp_s: 1234.002,
        actual_q_rad: [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739],
        actual_tcp_pose: Some([-0.807, 0.436, 0.42, 0.92, 2.03, 0.03]),
        robot_mode: Some(7),
        safety_mode: Some(-1),
        robot_status_bits: Some(0xffff_fffe),
        payload_cog_m: Some([0.0, -0.0, 1e-300]),
        ..RtdeSample::default()
    }
}

#[test]
fn a_full_controller_streams_every_variable() {
    let every: Vec<&str> = VARIABLES.iter().map(|v| v.name).collect();
    let (mut handshake, started) = started(ProtocolVersion::V2, &every);
    assert!(started.dropped.is_empty());
    assert_eq!(started.controller.major, 5);
    assert_eq!(started.controller.minor, 21);
    assert_eq!(started.recipe.variables.len(), VARIABLES.len());
    let full = RtdeSample {
        actual_qd_rad_s: Some([0.1; 6]),
        joint_temperatures_c: Some([30.5; 6]),
        speed_scaling: Some(1.0),
        payload_kg: Some(2.5),
        target_q_rad: Some([0.0; 6]),
        target_qd_rad_s: Some([0.0; 6]),
        target_qdd_rad_s2: Some([0.0; 6]),
        actual_current_a: Some([0.25; 6]),
        target_current_a: Some([0.5; 6]),
        target_moment_nm: Some([1.5; 6]),
        tcp_offset: Some([0.0, 0.0, 0.2, 0.0, 0.0, 1.5]),
        ..sample()
    };
    let payload = recipe::encode(&started.recipe, &full);
    // 1 id byte, 11 vectors of 6 doubles, 3 doubles, a VECTOR3D, 2 INT32 and a UINT32.
    assert_eq!(payload.len(), 1 + 11 * 48 + 3 * 8 + 24 + 3 * 4);
    assert_eq!(payload.len(), started.recipe.payload_bytes);
    match feed(&mut handshake, &package(b'U', &payload)) {
        Ok(Progress::Sample(got)) => assert_eq!(got, full),
        other => panic!("{other:?}"),
    }
}

#[test]
fn variables_not_found_are_dropped_and_named() {
    let known = [
        "timestamp",
        "actual_q",
        "actual_TCP_pose",
        "robot_mode",
        "safety_mode",
        "robot_status_bits",
        "payload_cog",
    ];
    let (mut handshake, started) = started(ProtocolVersion::V2, &known);
    assert_eq!(started.dropped.len(), VARIABLES.len() - known.len());
    assert!(started.dropped.contains(&"joint_temperatures"));
    assert!(!started.recipe.has("actual_qd") && started.recipe.has("actual_TCP_pose"));
    // Values laid out by hand, big-endian, in the recipe's order.
    let mut payload = vec![3];
    payload.extend(1234.002_f64.to_be_bytes());
    for value in sample()
        .actual_q_rad
        .iter()
        .chain(&sample().actual_tcp_pose.unwrap())
    {
        payload.extend(value.to_be_bytes());
    }
    payload.extend(7_i32.to_be_bytes());
    payload.extend((-1_i32).to_be_bytes());
    payload.extend(0xffff_fffe_u32.to_be_bytes());
    for value in [0.0_f64, -0.0, 1e-300] {
        payload.extend(value.to_be_bytes());
    }
    assert_eq!(recipe::encode(&started.recipe, &sample()), payload);
    match feed(&mut handshake, &package(b'U', &payload)) {
        Ok(Progress::Sample(got)) => {
            assert_eq!(got, sample());
            assert_eq!(
                got.payload_cog_m.unwrap()[1].to_bits(),
                (-0.0_f64).to_bits()
            );
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_cb3_controller_speaks_protocol_1() {
    let (mut handshake, started) = started(ProtocolVersion::V1, &["timestamp", "actual_q"]);
    assert_eq!(started.version, ProtocolVersion::V1);
    assert_eq!(started.recipe.id, None);
    let mut payload = 5.5_f64.to_be_bytes().to_vec();
    for q in [1.0_f64; 6] {
        payload.extend(q.to_be_bytes());
    }
    match feed(&mut handshake, &package(b'U', &payload)) {
        Ok(Progress::Sample(got)) => {
            assert_eq!((got.timestamp_s, got.actual_q_rad), (5.5, [1.0; 6]));
            assert_eq!(got.actual_tcp_pose, None);
        }
        other => panic!("{other:?}"),
    }
    // Protocol 1's text message: level, then the text.
    match feed(&mut handshake, &package(b'M', b"\x02careful")) {
        Ok(Progress::Text(text)) => assert_eq!((text.level, text.message.as_str()), (2, "careful")),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_controller_without_either_protocol_is_an_error() {
    let (mut handshake, _) = Handshake::new(125.0).unwrap();
    sent(feed(&mut handshake, &package(b'V', &[0])));
    assert_eq!(
        feed(&mut handshake, &package(b'V', &[0])),
        Err(RtdeError::NoProtocol)
    );
}

#[test]
fn required_variables_must_be_known() {
    let (mut handshake, _) = Handshake::new(125.0).unwrap();
    sent(feed(&mut handshake, &package(b'V', &[1])));
    sent(feed(&mut handshake, &package(b'v', &CONTROLLER_5_21)));
    let names: Vec<String> = VARIABLES.iter().map(|v| v.name.to_owned()).collect();
    let error = feed(
        &mut handshake,
        &setup_answer(Some(1), &names, &["timestamp"]),
    )
    .unwrap_err();
    assert_eq!(
        error,
        RtdeError::Required {
            variable: "actual_q"
        }
    );
}

/// A handshake waiting for the output setup answer.
fn at_setup() -> (Handshake, Vec<String>) {
    let (mut handshake, _) = Handshake::new(500.0).unwrap();
    sent(feed(&mut handshake, &package(b'V', &[1])));
    let (_, payload) = sent(feed(&mut handshake, &package(b'v', &CONTROLLER_5_21)));
    let names = setup_names(&payload, ProtocolVersion::V2);
    (handshake, names)
}

#[test]
fn bad_setup_answers_are_named() {
    let every: Vec<String> = VARIABLES.iter().map(|v| v.name.to_owned()).collect();
    let types = |edit: &dyn Fn(&mut Vec<&str>)| {
        let mut types: Vec<&str> = VARIABLES.iter().map(|v| v.kind.as_str()).collect();
        edit(&mut types);
        let mut payload = vec![1];
        payload.extend(types.join(",").as_bytes());
        package(b'O', &payload)
    };
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (types(&|t| t[1] = "VECTOR3D"), "type_mismatch"),
        (types(&|t| t[0] = "FLOAT128"), "unknown_type"),
        (
            types(&|t| {
                t.pop();
            }),
            "variable_count",
        ),
        (types(&|t| t[2] = "IN_USE"), "setup_refused"),
        (package(b'O', &[]), "truncated"),
        (package(b'O', &[1, 0xff, 0xfe]), "not_utf8"),
        (package(b'U', &[1]), "unexpected_package"),
        (package(b'x', &[]), "unexpected_package"),
    ];
    for (bytes, kind) in cases {
        let (mut handshake, names) = at_setup();
        assert_eq!(names, every);
        let error = feed(&mut handshake, &bytes).unwrap_err();
        assert_eq!(error.kind(), kind, "{error}");
    }
    let (mut handshake, _) = at_setup();
    let mut refused = vec![0];
    refused.extend(
        VARIABLES
            .iter()
            .map(|v| v.kind.as_str())
            .collect::<Vec<_>>()
            .join(",")
            .as_bytes(),
    );
    assert_eq!(
        feed(&mut handshake, &package(b'O', &refused))
            .unwrap_err()
            .kind(),
        "setup_refused"
    );
}

#[test]
fn bad_answers_before_the_setup_are_named() {
    let (mut handshake, _) = Handshake::new(125.0).unwrap();
    let error = feed(&mut handshake, &package(b'V', &[1, 1])).unwrap_err();
    assert_eq!(
        error.to_string(),
        "REQUEST_PROTOCOL_VERSION payload of 2 bytes, expected 1"
    );
    let (mut handshake, _) = Handshake::new(125.0).unwrap();
    sent(feed(&mut handshake, &package(b'V', &[1])));
    let error = feed(&mut handshake, &package(b'v', &[0; 15])).unwrap_err();
    assert_eq!(error.kind(), "payload_size");
    assert_eq!(Handshake::new(0.0).unwrap_err().kind(), "frequency");
}

#[test]
fn bad_data_packages_are_named() {
    let (mut handshake, started) = started(ProtocolVersion::V2, &["timestamp", "actual_q"]);
    let good = recipe::encode(&started.recipe, &sample());
    assert_eq!(good.len(), 1 + 8 + 48);
    let error = feed(&mut handshake, &package(b'U', &good[..good.len() - 1])).unwrap_err();
    assert_eq!(
        error.to_string(),
        "DATA_PACKAGE payload of 56 bytes, expected 57"
    );
    let mut other = good.clone();
    other[0] = 4;
    assert_eq!(
        feed(&mut handshake, &package(b'U', &other)).unwrap_err(),
        RtdeError::RecipeId {
            expected: 3,
            got: 4
        }
    );
    assert_eq!(
        feed(&mut handshake, &package(b'S', &[1]))
            .unwrap_err()
            .kind(),
        "unexpected_package"
    );
    // Still streaming after each refusal: the caller decides what a bad package costs.
    assert!(matches!(
        feed(&mut handshake, &package(b'U', &good)),
        Ok(Progress::Sample(_))
    ));
}

#[test]
fn text_messages_are_read_and_checked() {
    let (mut handshake, _) = started(ProtocolVersion::V2, &["timestamp", "actual_q"]);
    let good = [&[5][..], b"hello", &[3], b"ctl", &[3]].concat();
    match feed(&mut handshake, &package(b'M', &good)) {
        Ok(Progress::Text(text)) => {
            assert_eq!(
                (text.level, text.message.as_str(), text.source.as_str()),
                (3, "hello", "ctl")
            );
        }
        other => panic!("{other:?}"),
    }
    for cut in 0..good.len() {
        let error = feed(&mut handshake, &package(b'M', &good[..cut])).unwrap_err();
        assert_eq!(error.kind(), "truncated", "{cut}: {error}");
    }
    let long = [&good[..], &[0]].concat();
    assert_eq!(
        feed(&mut handshake, &package(b'M', &long))
            .unwrap_err()
            .kind(),
        "payload_size"
    );
}

#[test]
fn a_recording_reads_back_as_an_rtde_recording() {
    let (_, started) = started(
        ProtocolVersion::V2,
        &["timestamp", "actual_q", "actual_TCP_pose", "robot_mode"],
    );
    let header = record::header(&started.recipe);
    assert!(
        header.starts_with("timestamp,actual_q_0,actual_q_1,"),
        "{header}"
    );
    assert!(header.ends_with("actual_TCP_pose_5,robot_mode"), "{header}");
    let mut text = header + "\n";
    let mut second = sample();
    second.timestamp_s += 0.002;
    second.actual_q_rad[0] = 0.1 + 0.2;
    for row in [sample(), second] {
        record::write_row(&started.recipe, &row, &mut text);
        text.push('\n');
    }
    let recording = recording::read(&text).unwrap();
    assert_eq!(recording.format, recording::Format::Rtde);
    assert!(recording.has_pose);
    let rows: Vec<_> = recording
        .entries
        .iter()
        .map(|e| e.as_ref().unwrap())
        .collect();
    assert_eq!(rows.len(), 2);
    assert_eq!(rows[1].stamp_s, Some(1234.004));
    let line: Vec<&str> = text.lines().nth(2).unwrap().split(',').collect();
    assert_eq!(
        line[1].parse::<f64>().unwrap().to_bits(),
        (0.1_f64 + 0.2).to_bits()
    );
    assert_eq!(*line.last().unwrap(), "7");
}

#[test]
fn variable_types_have_the_sizes_of_the_guide() {
    for (kind, bytes) in [
        (VariableType::Double, 8),
        (VariableType::Vector6D, 48),
        (VariableType::Vector3D, 24),
        (VariableType::Vector6Int32, 24),
        (VariableType::Vector6Uint32, 24),
        (VariableType::Int32, 4),
        (VariableType::Uint32, 4),
        (VariableType::Uint64, 8),
        (VariableType::Uint8, 1),
        (VariableType::Bool, 1),
    ] {
        assert_eq!(kind.size_bytes(), bytes);
        assert_eq!(VariableType::from_name(kind.as_str()), Some(kind));
    }
    assert_eq!(PackageType::from_byte(b'U'), Some(PackageType::DataPackage));
    assert_eq!(frame::start(), package(b'S', &[]));
}
