//! Zenoh-serialized messages: armtwin's reader and writer against zenoh-ext's own
//! `z_serialize` / `z_deserialize`, every rejection class, and binary messages into the
//! pipeline. (The codec a sample's encoding selects is tested beside `armtwin_mesh::ingest`.)

use std::collections::HashMap;
use std::sync::Arc;

use armtwin_codec::PoseFields;
use armtwin_codec::gateway::{self, Codec};
use armtwin_codec::json::{self, Undecodable};
use armtwin_codec::zser::{self, Schema};
use armtwin_core::kinematics::{OutputFrame, PoseReadout};
use armtwin_core::metrics::Deviation;
use armtwin_core::model::RobotModel;
use armtwin_core::pipeline::{
    AlarmConfig, Event, EventDetail, MeasuredStream, MetricsReadout, Pipeline, PipelineConfig,
    Robot, RobotDirectory, RobotSettings, Sink,
};
use proptest::prelude::*;
use zenoh::bytes::ZBytes;
use zenoh_ext::{z_deserialize, z_serialize};

/// A joint message as zenoh-ext serializes it: `(t, q, seq, measured)`.
fn joints_bytes(t: f64, q: &[f64], seq: u64, measured: &[f64]) -> Vec<u8> {
    z_serialize(&(t, q.to_vec(), seq, measured.to_vec()))
        .to_bytes()
        .into_owned()
}

fn pose_bytes(t: f64, pose: &[f64]) -> Vec<u8> {
    z_serialize(&(t, pose.to_vec())).to_bytes().into_owned()
}

const MEASURED: [f64; 7] = [0.4, -0.2, 0.9, 0.0, 0.0, 0.6, 0.8];

/// The pose JSON's decoder makes of the same values: the reference for the binary one.
fn json_pose(values: [f64; 7]) -> PoseReadout {
    let [x, y, z, qx, qy, qz, qw] = values;
    let json = format!(
        r#"{{"t": 0, "x": {x}, "y": {y}, "z": {z}, "qx": {qx}, "qy": {qy}, "qz": {qz}, "qw": {qw}}}"#
    );
    json::decode_measured(json.as_bytes()).unwrap().pose
}

fn expect_refused<T: std::fmt::Debug>(
    result: Result<T, Undecodable>,
    kind: &str,
    field: &str,
) -> Undecodable {
    let refused = result.expect_err("must be rejected");
    assert_eq!(refused.error.kind(), kind, "{}", refused.error);
    assert!(
        refused.error.to_string().contains(field),
        "'{}' does not name '{field}'",
        refused.error
    );
    refused
}

#[test]
fn the_byte_example_of_the_protocol_reads_as_documented() {
    // docs/protocol/messages.md: t = 0.5, q = [0.0, -1.5707963267948966], seq = 7, measured empty.
    let bytes: Vec<u8> = [
        &[0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0xe0, 0x3f][..],
        &[0x02],
        &[0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00],
        &[0x18, 0x2d, 0x44, 0x54, 0xfb, 0x21, 0xf9, 0xbf],
        &[0x07, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00],
        &[0x00],
    ]
    .concat();
    assert_eq!(bytes.len(), 34);
    assert_eq!(
        bytes,
        joints_bytes(0.5, &[0.0, -std::f64::consts::FRAC_PI_2], 7, &[])
    );
    let decoded = zser::read_joints(&bytes, 2).unwrap();
    assert_eq!(decoded.sample.stamp_s, Some(0.5));
    assert_eq!(decoded.sample.seq, Some(7));
    assert_eq!(
        decoded.sample.q_rad[..],
        [0.0, -std::f64::consts::FRAC_PI_2]
    );
    assert_eq!(decoded.sample.measured, None);
    assert_eq!(decoded.measured_error, None);
}

#[test]
fn a_joint_message_with_measured_reads_as_its_json_twin() {
    let q = [0.1, -1.2, 1.3, -0.4, 1.5, 0.6];
    let decoded = zser::read_joints(&joints_bytes(12.5, &q, 99, &MEASURED), 6).unwrap();
    assert_eq!(decoded.measured_error, None);
    assert_eq!(decoded.sample.q_rad[..], q);
    assert_eq!(decoded.sample.measured, Some(json_pose(MEASURED)));
    let measured = zser::read_measured(&pose_bytes(3.25, &MEASURED)).unwrap();
    assert_eq!(measured.stamp_s, Some(3.25));
    assert_eq!(measured.pose, json_pose(MEASURED));
}

/// The twin pose of the output tests.
fn output_pose() -> PoseFields {
    PoseFields {
        x: 0.1,
        y: -0.2,
        z: 0.3,
        roll: 1.0,
        pitch: -0.5,
        yaw: 3.0,
        qx: 0.5,
        qy: 0.5,
        qz: -0.5,
        qw: 0.5,
    }
}

/// The deviation of the output tests.
fn output_deviation() -> Deviation {
    Deviation {
        dx_m: 1e-3,
        dy_m: -2e-3,
        dz_m: 3e-3,
        position_m: 3.7e-3,
        quat_distance: 1e-7,
        angle_rad: 9e-4,
        droll_rad: 1e-4,
        dpitch_rad: -2e-4,
        dyaw_rad: 3e-4,
    }
}

#[test]
fn outputs_deserialize_with_zenoh_ext() {
    let pose = output_pose();
    let bytes = zser::twin_pose_bytes(4.5, u64::MAX - 1, &pose);
    assert_eq!(bytes.len(), 97);
    let (t, seq, values): (f64, u64, Vec<f64>) = z_deserialize(&ZBytes::from(bytes)).unwrap();
    assert_eq!((t, seq), (4.5, u64::MAX - 1));
    assert_eq!(values, pose.values());

    let deviation = output_deviation();
    let bytes = zser::deviation_bytes(4.5, &deviation);
    assert_eq!(bytes.len(), 81);
    let (t, values): (f64, Vec<f64>) = z_deserialize(&ZBytes::from(bytes)).unwrap();
    assert_eq!(t, 4.5);
    assert_eq!(
        values,
        [1e-3, -2e-3, 3e-3, 3.7e-3, 1e-7, 9e-4, 1e-4, -2e-4, 3e-4]
    );
    assert_eq!(zser::DEVIATION_NAMES.len(), values.len());

    // The paired message: the twin pose's fields, then the deviation's values, or none.
    let bytes = zser::paired_bytes(4.5, 7, &pose, &deviation);
    assert_eq!(bytes.len(), 170);
    let (t, seq, pose_values, deviation_values): (f64, u64, Vec<f64>, Vec<f64>) =
        z_deserialize(&ZBytes::from(bytes)).unwrap();
    assert_eq!((t, seq), (4.5, 7));
    assert_eq!(pose_values, pose.values());
    assert_eq!(deviation_values, values);
    let bytes = zser::paired_pose_bytes(4.5, 7, &pose);
    assert_eq!(bytes.len(), 98);
    let (t, seq, pose_values, deviation_values): (f64, u64, Vec<f64>, Vec<f64>) =
        z_deserialize(&ZBytes::from(bytes)).unwrap();
    assert_eq!((t, seq), (4.5, 7));
    assert_eq!(pose_values, pose.values());
    assert!(deviation_values.is_empty());
}

#[test]
fn a_paired_json_message_holds_the_pose_and_deviation_messages_fields() {
    let pose = output_pose();
    let deviation = output_deviation();
    let parse = |bytes: &[u8]| -> serde_json::Map<String, serde_json::Value> {
        serde_json::from_slice(bytes).unwrap()
    };
    let mut expected = parse(&json::pose_json_bytes("r/1", 4.5, 7, "base", &pose));
    let alone = parse(&json::paired_json_bytes("r/1", 4.5, 7, "base", &pose, None));
    assert_eq!(alone, expected);
    for (name, value) in parse(&json::deviation_json_bytes("r/1", 4.5, &deviation)) {
        expected.insert(name, value);
    }
    let paired = parse(&json::paired_json_bytes(
        "r/1",
        4.5,
        7,
        "base",
        &pose,
        Some(&deviation),
    ));
    assert_eq!(paired, expected);
}

#[test]
fn damaged_framing_refuses_the_message_at_its_stamp() {
    let good = joints_bytes(2.0, &[0.1, 0.2], 1, &MEASURED);
    // Every cut inside the message: truncated, and never a panic.
    for cut in 0..good.len() {
        let refused = expect_refused(zser::read_joints(&good[..cut], 2), "truncated", "");
        assert_eq!(refused.stamp_s, (cut >= 8).then_some(2.0), "cut at {cut}");
    }
    let mut long = good.clone();
    long.push(0);
    let refused = expect_refused(zser::read_joints(&long, 2), "trailing_bytes", "1 bytes");
    assert_eq!(refused.stamp_s, Some(2.0));
    let mut long = pose_bytes(1.0, &MEASURED);
    long.extend([1, 2, 3]);
    expect_refused(zser::read_measured(&long), "trailing_bytes", "3 bytes");
    expect_refused(
        zser::read_joints(&good[..20], 2),
        "truncated",
        "field 'q[1]'",
    );
}

#[test]
fn absurd_lengths_are_refused_without_allocating() {
    // q claims 2^63 values in a 20-byte message: a joint count error, nothing read by it.
    let mut bytes = 1.0_f64.to_le_bytes().to_vec();
    bytes.extend([0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x01]);
    let error = expect_refused(zser::read_joints(&bytes, 6), "joint_count", "'q'").error;
    assert_eq!(
        error.to_string(),
        "field 'q': expected 6 joint angles, got 9223372036854775808"
    );
    // An 11-byte length, and a tenth byte beyond bit 63: not a 64-bit LEB128 number.
    for length in [
        &[0xff; 11][..],
        &[0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0x02],
    ] {
        let mut bytes = 1.0_f64.to_le_bytes().to_vec();
        bytes.extend(length);
        expect_refused(zser::read_joints(&bytes, 6), "malformed_length", "q.length");
        let mut bytes = 1.0_f64.to_le_bytes().to_vec();
        bytes.extend(length);
        expect_refused(
            zser::read_measured(&bytes),
            "malformed_length",
            "pose.length",
        );
    }
    // measured claims 2^56 values: its length cannot match the bytes left.
    let mut bytes = joints_bytes(1.0, &[0.0, 0.0], 0, &[]);
    bytes.pop();
    bytes.extend([0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x01]);
    let error = expect_refused(
        zser::read_joints(&bytes, 2),
        "sequence_length",
        "'measured'",
    )
    .error;
    assert!(
        error.to_string().contains("got 72057594037927936"),
        "{error}"
    );
    // zenoh-ext itself allocates by that length; armtwin's reader is what stands in its way.
    expect_refused(
        zser::read_measured(&pose_bytes(1.0, &[0.0; 6])),
        "sequence_length",
        "'pose'",
    );
}

#[test]
fn non_finite_values_are_named() {
    let refused_t = expect_refused(
        zser::read_joints(&joints_bytes(f64::NAN, &[0.0], 0, &[]), 1),
        "non_finite",
        "'t'",
    );
    assert_eq!(refused_t.stamp_s, None);
    let refused_q = expect_refused(
        zser::read_joints(&joints_bytes(1.0, &[0.0, f64::INFINITY], 0, &[]), 2),
        "non_finite",
        "'q[1]'",
    );
    assert_eq!(refused_q.stamp_s, Some(1.0));
    expect_refused(
        zser::read_measured(&pose_bytes(
            1.0,
            &[0.0, 0.0, f64::NEG_INFINITY, 0.0, 0.0, 0.0, 1.0],
        )),
        "non_finite",
        "'pose[2]'",
    );
}

#[test]
fn a_bad_measured_part_leaves_the_joint_sample_valid() {
    let q = [0.3, 0.4];
    let mut nan = MEASURED;
    nan[4] = f64::NAN;
    let cases: [(&[f64], &str, &str); 3] = [
        (&nan, "non_finite", "'measured[4]'"),
        (&[0.0, 0.0, 0.0], "sequence_length", "'measured'"),
        (
            &[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5],
            "quaternion_norm",
            "'measured[3..7]'",
        ),
    ];
    for (measured, kind, field) in cases {
        let decoded = zser::read_joints(&joints_bytes(5.0, &q, 3, measured), 2).unwrap();
        assert_eq!(decoded.sample.q_rad[..], q);
        assert_eq!(decoded.sample.measured, None);
        let error = decoded
            .measured_error
            .expect("the measured part is refused");
        assert_eq!(error.kind(), kind, "{error}");
        assert!(error.to_string().contains(field), "{error}");
    }
    // The same damage on the measured stream refuses the message.
    let error = zser::read_measured(&pose_bytes(1.0, &nan))
        .unwrap_err()
        .error;
    assert_eq!(error.kind(), "non_finite");
}

/// What the pipeline reports: poses (stamp, seq) and rejections (cause, stamp, sentence).
#[derive(Default)]
struct Recorded {
    poses: Vec<(f64, u64)>,
    deviations: usize,
    rejections: Vec<(String, f64, String)>,
}

impl Sink for Recorded {
    fn tracking(&mut self, _robot: &Robot) {}

    fn pose(&mut self, _: &Robot, stamp_s: f64, seq: u64, _: OutputFrame, _: &PoseReadout) {
        self.poses.push((stamp_s, seq));
    }

    fn deviation(&mut self, _: &Robot, _: f64, _: &PoseReadout, _: &Deviation) {
        self.deviations += 1;
    }

    fn event(&mut self, event: &Event<'_>) {
        if let EventDetail::Rejected { cause } = event.detail {
            self.rejections
                .push((cause.as_str().to_owned(), event.stamp_s, event.to_string()));
        }
    }

    fn metrics(&mut self, _: &Robot, _: &MetricsReadout) {}
}

#[test]
fn binary_messages_step_the_pipeline_and_a_wrong_schema_is_rejected_at_its_stamp() {
    // A service's `[robots.default] model = "ur10e"`.
    let settings = RobotSettings {
        model: Arc::new(RobotModel::nominal("ur10e").unwrap()),
        alarm: AlarmConfig::default(),
        sensors: Vec::new(),
        self_calibration: None,
        effort: None,
    };
    let mut robots = RobotDirectory::new(Some(settings), HashMap::new());
    let mut pipeline = Pipeline::new(PipelineConfig::default());
    let robot = robots.admit("r1").unwrap().clone();
    let mut sink = Recorded::default();
    let joints = Codec::ZenohSerialized(Some(Schema::Joints));
    let pose = Codec::ZenohSerialized(Some(Schema::Pose));
    let q = [0.1, -1.2, 1.3, -0.4, 1.5, 0.6];
    let mut nan = MEASURED;
    nan[0] = f64::NAN;
    let payloads = [
        (joints, joints_bytes(1.0, &q, 0, &[])),
        (joints, joints_bytes(1.5, &q, 1, &nan)),
        (pose, joints_bytes(2.0, &q, 2, &[])),
        (Codec::ZenohSerialized(None), joints_bytes(2.5, &q, 3, &[])),
    ];
    for (codec, payload) in &payloads {
        gateway::joint_message(
            &mut pipeline,
            &robot,
            "twin/joints/r1",
            *codec,
            payload,
            || 0.0,
            &mut sink,
        );
    }
    gateway::measured_message(
        &mut pipeline,
        &robot,
        "twin/measured/r1",
        MeasuredStream::Robot,
        joints,
        &pose_bytes(3.0, &MEASURED),
        || 0.0,
        &mut sink,
    );
    // The bad measured part costs the joints nothing: two poses; three rejections at their own
    // stamps, the schema ones naming what the key takes.
    assert_eq!(sink.poses, [(1.0, 0), (1.5, 1)]);
    let causes: Vec<(&str, f64)> = sink
        .rejections
        .iter()
        .map(|(cause, stamp_s, _)| (cause.as_str(), *stamp_s))
        .collect();
    assert_eq!(
        causes,
        [
            ("non_finite", 1.5),
            ("schema", 2.0),
            ("schema", 2.5),
            ("schema", 3.0)
        ]
    );
    assert!(
        sink.rejections[1].2.contains("'armtwin/joints/v1'"),
        "{}",
        sink.rejections[1].2
    );
    assert!(
        sink.rejections[3].2.contains("'armtwin/pose/v1'"),
        "{}",
        sink.rejections[3].2
    );
    assert_eq!(sink.deviations, 0);
}

/// A measured length byte damaged to 0 and the message cut after it: a valid message without a
/// measured pose, as zenoh-ext reads it too.
#[test]
fn a_measured_length_of_zero_leaves_a_message_without_a_measured_pose() {
    let mut bytes = joints_bytes(1.0, &[0.0; 6], 5, &MEASURED);
    bytes[65] = 0;
    bytes.truncate(66);
    let decoded = zser::read_joints(&bytes, 6).expect("valid");
    assert!(decoded.sample.measured.is_none() && decoded.measured_error.is_none());
    let (_, _, _, measured): (f64, Vec<f64>, u64, Vec<f64>) =
        z_deserialize(&ZBytes::from(bytes)).expect("zenoh-ext reads it");
    assert!(measured.is_empty());
}

proptest! {
    #[test]
    fn any_joint_message_reads_back(
        t in -1e9_f64..1e9,
        q in prop::collection::vec(-10.0_f64..10.0, 1..16),
        seq in any::<u64>(),
        with_measured in any::<bool>(),
    ) {
        let measured: &[f64] = if with_measured { &MEASURED } else { &[] };
        let decoded = zser::read_joints(&joints_bytes(t, &q, seq, measured), q.len()).unwrap();
        prop_assert_eq!(decoded.sample.stamp_s, Some(t));
        prop_assert_eq!(decoded.sample.seq, Some(seq));
        prop_assert_eq!(&decoded.sample.q_rad[..], &q);
        prop_assert_eq!(decoded.sample.measured.is_some(), with_measured);
    }

    #[test]
    fn damaged_messages_never_panic_and_what_is_read_agrees_with_zenoh_ext(
        q in prop::collection::vec(-10.0_f64..10.0, 6),
        at in 0_usize..200,
        byte in any::<u8>(),
        cut in 0_usize..200,
    ) {
        let mut bytes = joints_bytes(1.0, &q, 5, &MEASURED);
        let at = at % bytes.len();
        bytes[at] = byte;
        bytes.truncate(cut.max(at + 1));
        match zser::read_joints(&bytes, 6) {
            Ok(decoded) => {
                // Accepted: its lengths matched the schema, so zenoh-ext may read it (on
                // arbitrary bytes it would allocate by the length it finds).
                let (t, q, seq, measured): (f64, Vec<f64>, u64, Vec<f64>) =
                    z_deserialize(&ZBytes::from(bytes.clone())).expect("zenoh-ext reads it too");
                prop_assert_eq!(decoded.sample.stamp_s, Some(t));
                prop_assert_eq!(decoded.sample.q_rad.to_vec(), q);
                prop_assert_eq!(decoded.sample.seq, Some(seq));
                // A damaged length byte may leave a valid message without a measured pose;
                // a measured part refused on its own keeps whatever length it had.
                if decoded.measured_error.is_none() {
                    let expected = if decoded.sample.measured.is_some() { 7 } else { 0 };
                    prop_assert_eq!(measured.len(), expected);
                }
            }
            Err(refused) => prop_assert!(!refused.error.to_string().is_empty()),
        }
        let _ = zser::read_measured(&bytes);
    }
}

#[test]
fn joint_state_round_trips_and_its_bad_parts_refuse_only_the_state() {
    use armtwin_core::sample::{ControllerStatus, JointQuantity, JointState, Payload};
    let mut state = JointState::new(2);
    state.set(JointQuantity::Current, &[0.25, -1.5]);
    state.set(JointQuantity::Velocity, &[0.5, 0.0]);
    state.set(JointQuantity::Temperature, &[31.0, 33.5]);
    state.status = Some(ControllerStatus {
        robot_mode: 7,
        safety_mode: 1,
        status_bits: 5,
        speed_scaling: 0.75,
    });
    state.payload = Some(Payload {
        mass_kg: 2.5,
        cog_m: [0.0, 0.01, 0.05],
        inertia_kg_m2: Some([0.1, 0.2, 0.3, 0.0, 0.0, 0.01]),
    });
    let bytes = zser::joints_state_bytes(3.0, &[0.1, 0.2], 4, Some(&MEASURED), &state);
    let decoded = zser::read_joints_with_state(&bytes, 2).unwrap();
    assert_eq!(decoded.sample.state.as_deref(), Some(&state));
    assert!(decoded.sample.measured.is_some());
    // v1 of the same bytes: the state is trailing bytes.
    assert_eq!(
        zser::read_joints(&bytes, 2).unwrap_err().error.kind(),
        "trailing_bytes"
    );
    // A non-finite temperature refuses the state only.
    let mut hot = JointState::new(2);
    hot.set(JointQuantity::Temperature, &[f64::NAN, 30.0]);
    let bytes = zser::joints_state_bytes(3.0, &[0.1, 0.2], 4, None, &hot);
    let decoded = zser::read_joints_with_state(&bytes, 2).unwrap();
    assert_eq!(decoded.sample.state, None);
    assert_eq!(decoded.sample.q_rad[..], vec![0.1, 0.2]);
    let error = decoded.state_error.unwrap();
    assert_eq!(error.kind(), "non_finite");
    assert!(error.to_string().contains("temperature_c[0]"), "{error}");
    // A per-joint sequence of another length breaks the framing.
    let mut bytes = zser::joints_state_bytes(3.0, &[0.1, 0.2], 4, None, &JointState::new(2));
    let at = bytes.len() - 2 - 9; // the first of the nine empty per-joint sequences
    bytes[at] = 1;
    bytes.splice((at + 1)..=at, 0.5_f64.to_le_bytes());
    let refused = zser::read_joints_with_state(&bytes, 2).unwrap_err();
    assert_eq!(refused.error.kind(), "sequence_length");
    assert_eq!(refused.stamp_s, Some(3.0));
}

#[test]
fn json_state_is_read_by_the_general_decoder_and_its_bad_parts_refuse_only_the_state() {
    use armtwin_codec::json::read_joints;
    use armtwin_core::sample::JointQuantity;
    let decoded = read_joints(
        br#"{"t": 1, "q": [0, 0], "state": {"current_a": [1.5, -2], "robot_mode": 7, "safety_mode": 1, "status_bits": 4, "speed_scaling": 1, "payload": {"mass_kg": 1, "cog_m": [0, 0, 0.1]}, "future": 1}}"#,
        2,
    )
    .unwrap();
    let state = decoded.sample.state.unwrap();
    assert_eq!(state.get(JointQuantity::Current), Some(&[1.5, -2.0][..]));
    assert!(state.status.unwrap().freedrive());
    assert_eq!(state.payload.unwrap().cog_m, [0.0, 0.0, 0.1]);
    for (bad, field) in [
        (r#"{"qd": [1]}"#, "state.qd"),
        (r#"{"temperature_c": [1, "x"]}"#, "state.temperature_c[1]"),
        (r#"{"robot_mode": 7}"#, "state.safety_mode"),
        (
            r#"{"payload": {"mass_kg": -1, "cog_m": [0, 0, 0]}}"#,
            "state.payload.mass_kg",
        ),
        ("[1]", "state."),
    ] {
        let payload = format!(r#"{{"t": 1, "q": [0, 0], "state": {bad}}}"#);
        let decoded = read_joints(payload.as_bytes(), 2).unwrap();
        assert_eq!(decoded.sample.state, None, "{bad}");
        assert_eq!(decoded.sample.q_rad[..], vec![0.0, 0.0]);
        let error = decoded.state_error.unwrap();
        assert_eq!(error.kind(), "joint_state", "{bad}");
        assert!(error.to_string().contains(field), "{bad}: {error}");
    }
}
