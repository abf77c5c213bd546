//! ROS 2 CDR codec: decoding the fixtures written by independent serializers (`rosbags`,
//! `mcap-ros2-support`; `tests/data/ros2/messages.json` says what each holds), encoding the twin
//! pose byte for byte, and a property test against `cdr-encoding` as the oracle.

#![allow(
    clippy::disallowed_methods,
    reason = "the test reads its fixtures from files; the codec itself never does"
)]

use std::path::{Path, PathBuf};

use armtwin_codec::cdr::{self, CdrError, EffortMeaning, JointNames};
use armtwin_codec::json;
use armtwin_core::kinematics::{OutputFrame, PoseReadout};
use armtwin_core::orientation::Rpy;
use armtwin_core::sample::JointQuantity;
use proptest::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::Value;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/ros2")
}

fn manifest() -> Vec<Value> {
    let text = std::fs::read_to_string(fixtures().join("messages.json")).expect("manifest");
    serde_json::from_str(&text).expect("JSON")
}

fn numbers(value: &Value) -> Vec<f64> {
    value
        .as_array()
        .expect("array")
        .iter()
        .map(|v| v.as_f64().expect("number"))
        .collect()
}

#[test]
fn every_fixture_decodes_to_what_its_writer_put_in() {
    let entries = manifest();
    assert_eq!(entries.len(), 12);
    for entry in entries {
        let file = entry["file"].as_str().expect("file");
        let bytes = std::fs::read(fixtures().join(file)).expect("fixture");
        match entry["type"].as_str().expect("type") {
            "sensor_msgs/msg/JointState" => {
                let names = JointNames::ur(entry["tf_prefix"].as_str().expect("prefix"));
                let decoded = cdr::decode_joint_state(&bytes, &names, None);
                if let Some(kind) = entry["error"].as_str() {
                    let error = decoded.expect_err(file);
                    assert_eq!(error.kind(), kind, "{file}: {error}");
                    if let Some(message) = entry["message"].as_str() {
                        assert_eq!(error.to_string(), message, "{file}");
                    }
                    continue;
                }
                let sample = decoded.unwrap_or_else(|e| panic!("{file}: {e}"));
                assert_eq!(sample.stamp_s, entry["stamp_s"].as_f64(), "{file}");
                assert_eq!(sample.q_rad[..], numbers(&entry["q_rad"]), "{file}");
                assert_eq!(sample.seq, None);
                assert_eq!(sample.measured, None);
            }
            "geometry_msgs/msg/PoseStamped" => {
                let decoded = cdr::decode_pose_stamped(&bytes).unwrap_or_else(|e| panic!("{e}"));
                assert_eq!(decoded.frame_id, entry["frame_id"].as_str().expect("frame"));
                assert_eq!(decoded.sample.stamp_s, entry["stamp_s"].as_f64(), "{file}");
                let position = numbers(&entry["position_m"]);
                let xyzw = numbers(&entry["quaternion_xyzw"]);
                assert_eq!(decoded.sample.pose.position_m.to_vec(), position, "{file}");
                assert_eq!(decoded.xyzw_as_sent.to_vec(), xyzw, "{file}");
                // The pose is the one the JSON decoder makes of the same fields.
                let json = format!(
                    r#"{{"x":{},"y":{},"z":{},"qx":{},"qy":{},"qz":{},"qw":{}}}"#,
                    position[0], position[1], position[2], xyzw[0], xyzw[1], xyzw[2], xyzw[3]
                );
                let from_json = json::decode_measured(json.as_bytes()).expect("JSON pose");
                assert_eq!(decoded.sample.pose, from_json.pose, "{file}");
                if entry["encode"].as_bool() == Some(true) {
                    let pose = PoseReadout {
                        position_m: [position[0], position[1], position[2]],
                        rpy: decoded.sample.pose.rpy,
                        quaternion_xyzw: [xyzw[0], xyzw[1], xyzw[2], xyzw[3]],
                    };
                    let frame = cdr::frame_id("", OutputFrame::Base);
                    let stamp_s = entry["stamp_s"].as_f64().expect("stamp");
                    assert_eq!(
                        cdr::encode_pose_stamped(stamp_s, &frame, &pose),
                        bytes,
                        "{file}"
                    );
                }
            }
            other => panic!("{file}: unknown type {other}"),
        }
    }
}

/// Messages as real rclpy (ROS 2 Jazzy, `rmw_fastrtps_cpp`) serializes them, captured once by
/// `tools/capture_rclpy_fixtures.py`: alignment padding holds whatever was in memory and a
/// message with empty sequences has bytes after its end (`test_ros2_fixtures.py` shows both
/// against rosbags' bytes for the same values). Both are read past, never judged.
#[test]
fn messages_rclpy_serialized_decode_to_what_was_put_in() {
    let dir = fixtures().join("rclpy");
    let text = std::fs::read_to_string(dir.join("messages.json")).expect("manifest");
    let entries: Vec<Value> = serde_json::from_str(&text).expect("JSON");
    assert_eq!(entries.len(), 5);
    for entry in entries {
        let file = entry["file"].as_str().expect("file");
        let bytes = std::fs::read(dir.join(file)).expect("fixture");
        assert_eq!(Some(bytes.len() as u64), entry["bytes"].as_u64(), "{file}");
        let stamp_s = entry["stamp_s"].as_f64();
        if entry["type"] == "sensor_msgs/msg/JointState" {
            let names = JointNames::ur(entry["tf_prefix"].as_str().expect("prefix"));
            let sample = cdr::decode_joint_state(&bytes, &names, Some(EffortMeaning::CurrentA))
                .unwrap_or_else(|e| panic!("{file}: {e}"));
            assert_eq!(sample.stamp_s, stamp_s, "{file}");
            assert_eq!(sample.q_rad[..], numbers(&entry["q_rad"]), "{file}");
            let state = sample.state.as_deref();
            for (field, quantity) in [
                ("qd_rad_s", JointQuantity::Velocity),
                ("effort", JointQuantity::Current),
            ] {
                let want = (!entry[field].is_null()).then(|| numbers(&entry[field]));
                let got = state.and_then(|s| s.get(quantity)).map(<[f64]>::to_vec);
                assert_eq!(got, want, "{file}: {field}");
            }
        } else {
            let decoded = cdr::decode_pose_stamped(&bytes).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(decoded.frame_id, entry["frame_id"].as_str().expect("frame"));
            assert_eq!(decoded.sample.stamp_s, stamp_s, "{file}");
            assert_eq!(
                decoded.sample.pose.position_m.to_vec(),
                numbers(&entry["position_m"]),
                "{file}"
            );
            assert_eq!(
                decoded.xyzw_as_sent.to_vec(),
                numbers(&entry["quaternion_xyzw"]),
                "{file}"
            );
        }
    }
}

#[test]
fn errors_name_the_field() {
    let empty = std::fs::read(fixtures().join("joint_state_empty_velocity_effort.cdr")).unwrap();
    let names = JointNames::ur("");
    let error = cdr::decode_joint_state(&empty[..empty.len() - 12], &names, None).unwrap_err();
    assert_eq!(
        error.to_string(),
        "'JointState.position': needs 48 bytes at body offset 152, the body has 196"
    );
    let mut huge = empty.clone();
    huge[20..24].copy_from_slice(&0xFFFF_FFF0_u32.to_le_bytes());
    let error = cdr::decode_joint_state(&huge, &names, None).unwrap_err();
    assert_eq!(
        error.to_string(),
        "'JointState.name': count 4294967280 exceeds the limit of 256"
    );
    // A name whose length runs past the payload: name[3] starts after three 4-byte lengths
    // and their strings.
    let mut long_name = empty.clone();
    let third = 4 + 20 + (4 + 19) + 1 + (4 + 20) + (4 + 12);
    assert_eq!(
        &long_name[third + 4..third + 9],
        b"wrist",
        "name[3] is wrist_1_joint"
    );
    long_name[third..third + 4].copy_from_slice(&200_u32.to_le_bytes());
    let error = cdr::decode_joint_state(&long_name, &names, None).unwrap_err();
    assert!(
        matches!(&error, CdrError::Truncated { field, .. } if field == "JointState.name[3]"),
        "{error}"
    );
    let mut nan = empty;
    let last = nan.len() - 8 - 8;
    nan[last..last + 8].copy_from_slice(&f64::NAN.to_le_bytes());
    assert_eq!(
        cdr::decode_joint_state(&nan, &names, None).unwrap_err(),
        CdrError::NonFinite {
            field: "JointState.position[5]".to_owned()
        }
    );
    let pose = std::fs::read(fixtures().join("pose_stamped_base.cdr")).unwrap();
    let mut zero = pose.clone();
    let w = zero.len() - 32;
    zero[w..].fill(0);
    let error = cdr::decode_pose_stamped(&zero).unwrap_err();
    assert_eq!(error.kind(), "quaternion_norm");
    assert_eq!(
        error.to_string(),
        "'PoseStamped.pose.orientation': quaternion norm 0 is not within 5 % of 1"
    );
}

#[test]
fn a_duplicated_arm_joint_is_rejected_and_extra_ones_are_not() {
    let names = JointNames::ur("");
    let mut message = JointStateOracle::ur(1.0);
    message
        .name
        .push("robotiq_85_left_knuckle_joint".to_owned());
    message.position.push(f64::NAN);
    assert!(cdr::decode_joint_state(&oracle_bytes(&message, true), &names, None).is_ok());
    message.name.push("elbow_joint".to_owned());
    message.position.push(0.0);
    let error = cdr::decode_joint_state(&oracle_bytes(&message, true), &names, None).unwrap_err();
    assert_eq!(
        error.to_string(),
        "joint 'elbow_joint' appears more than once ('JointState.name[7]')"
    );
    message.name.pop();
    message.position.truncate(6);
    let error = cdr::decode_joint_state(&oracle_bytes(&message, true), &names, None).unwrap_err();
    assert_eq!(
        error.to_string(),
        "'JointState.position': 6 values for 7 names"
    );
}

// ---------------------------------------------------------------------------------------------
// The oracle: the same messages as serde structs, serialised by `cdr-encoding`.
// ---------------------------------------------------------------------------------------------

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct TimeOracle {
    sec: i32,
    nanosec: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct HeaderOracle {
    stamp: TimeOracle,
    frame_id: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct JointStateOracle {
    header: HeaderOracle,
    name: Vec<String>,
    position: Vec<f64>,
    velocity: Vec<f64>,
    effort: Vec<f64>,
}

impl JointStateOracle {
    fn ur(q: f64) -> Self {
        Self {
            header: HeaderOracle {
                stamp: TimeOracle {
                    sec: 10,
                    nanosec: 5,
                },
                frame_id: String::new(),
            },
            name: JointNames::ur("").as_slice().to_vec(),
            position: vec![q; 6],
            velocity: Vec::new(),
            effort: Vec::new(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct PoseStampedOracle {
    header: HeaderOracle,
    position: [f64; 3],
    orientation: [f64; 4],
}

/// The oracle's bytes with the encapsulation header.
fn oracle_bytes<T: Serialize>(message: &T, little_endian: bool) -> Vec<u8> {
    let (mut bytes, body) = if little_endian {
        (
            vec![0, 1, 0, 0],
            cdr_encoding::to_vec::<T, byteorder::LittleEndian>(message),
        )
    } else {
        (
            vec![0, 0, 0, 0],
            cdr_encoding::to_vec::<T, byteorder::BigEndian>(message),
        )
    };
    bytes.extend(body.expect("serialisable"));
    bytes
}

proptest! {
    /// Whatever the order, prefix, extra joints, frame id length and endianness, the decoder
    /// reads what the oracle wrote.
    #[test]
    fn joint_states_decode_as_the_oracle_wrote_them(
        q in proptest::array::uniform6(-6.3_f64..6.3),
        order in Just((0..6).collect::<Vec<usize>>()).prop_shuffle(),
        prefix in "[a-z]{0,3}_?",
        frame_id in "[a-z_/]{0,13}",
        extras in proptest::collection::vec(("[a-z_]{1,12}", -1e3_f64..1e3), 0..3),
        velocity_len in 0_usize..2,
        sec in any::<i32>(),
        nanosec in 0_u32..1_000_000_000,
        little_endian in any::<bool>(),
    ) {
        let names = JointNames::ur(&prefix);
        let mut message = JointStateOracle {
            header: HeaderOracle { stamp: TimeOracle { sec, nanosec }, frame_id },
            name: order.iter().map(|&j| names.as_slice()[j].clone()).collect(),
            position: order.iter().map(|&j| q[j]).collect(),
            velocity: Vec::new(),
            effort: Vec::new(),
        };
        for (name, value) in extras {
            message.name.push(format!("gripper_{name}"));
            message.position.push(value);
        }
        // Velocity and effort per name (distinct values), or none.
        let count = velocity_len * message.name.len();
        message.velocity = (0..count).map(|i| 0.5 + i as f64).collect();
        message.effort = (0..count).map(|i| -10.0 * (i as f64 + 1.0)).collect();
        let bytes = oracle_bytes(&message, little_endian);
        // Carried into the joint state in the arm's joint order; effort as what the source says
        // it is, or not at all.
        let arm_order = |values: &[f64]| -> Vec<f64> {
            (0..6)
                .map(|j| values[order.iter().position(|&o| o == j).expect("every joint")])
                .collect()
        };
        for effort in [None, Some(EffortMeaning::CurrentA), Some(EffortMeaning::TorqueNm)] {
            let sample = cdr::decode_joint_state(&bytes, &names, effort).expect("valid");
            prop_assert_eq!(&sample.q_rad[..], &q.to_vec());
            if let Some(state) = &sample.state {
                prop_assert_eq!(velocity_len, 1);
                prop_assert_eq!(
                    state.get(JointQuantity::Velocity).map(<[f64]>::to_vec),
                    Some(arm_order(&message.velocity))
                );
                for meaning in [EffortMeaning::CurrentA, EffortMeaning::TorqueNm] {
                    prop_assert_eq!(
                        state.get(meaning.quantity()).map(<[f64]>::to_vec),
                        (effort == Some(meaning)).then(|| arm_order(&message.effort))
                    );
                }
            } else {
                prop_assert_eq!(velocity_len, 0);
            }
        }
        let sample = cdr::decode_joint_state(&bytes, &names, None).expect("valid");
        let stamp = (sec != 0 || nanosec != 0)
            .then(|| f64::from(sec) + f64::from(nanosec) * 1e-9);
        prop_assert_eq!(sample.stamp_s, stamp);
        // Bytes after a complete message (rclpy's serializer may leave some) change nothing.
        let mut longer = bytes.clone();
        longer.extend_from_slice(&[0xA5; 11]);
        prop_assert_eq!(cdr::decode_joint_state(&longer, &names, None).expect("valid"), sample.clone());
        // Any cut short of the velocity arrays is refused, never read past.
        let cut = bytes.len() - 8 - 8 * message.effort.len() - 8 * message.velocity.len() - 1;
        for end in [4, 9, cut / 2, cut] {
            prop_assert!(cdr::decode_joint_state(&bytes[..end], &names, None).is_err());
        }
    }

    /// The encoder writes what the oracle reads back.
    #[test]
    fn encoded_poses_read_back_in_the_oracle(
        position in proptest::array::uniform3(-2.0_f64..2.0),
        angles in proptest::array::uniform3(-3.1_f64..3.1),
        stamp_s in 0.0_f64..2e9,
        frame_id in "[a-z_]{0,12}",
    ) {
        let [roll_rad, pitch_rad, yaw_rad] = angles;
        let rotation = armtwin_core::orientation::quaternion_from_matrix(
            &armtwin_core::orientation::matrix_from_rpy(Rpy { roll_rad, pitch_rad, yaw_rad }),
        );
        let pose = PoseReadout::from_position_quaternion(position, &rotation);
        let bytes = cdr::encode_pose_stamped(stamp_s, &frame_id, &pose);
        prop_assert_eq!(&bytes[..4], &[0, 1, 0, 0]);
        let (read, _): (PoseStampedOracle, usize) =
            cdr_encoding::from_bytes::<PoseStampedOracle, byteorder::LittleEndian>(&bytes[4..])
                .expect("oracle reads it");
        prop_assert_eq!(&read.header.frame_id, &frame_id);
        prop_assert_eq!(read.position, pose.position_m);
        prop_assert_eq!(read.orientation, pose.quaternion_xyzw);
        let back = f64::from(read.header.stamp.sec) + f64::from(read.header.stamp.nanosec) * 1e-9;
        prop_assert!((back - stamp_s).abs() < 1e-6, "{} vs {}", back, stamp_s);
        // And the decoder reads back the pose it came from.
        let decoded = cdr::decode_pose_stamped(&bytes).expect("valid");
        prop_assert_eq!(decoded.sample.pose.position_m, pose.position_m);
        for (a, b) in decoded.sample.pose.quaternion_xyzw.iter().zip(pose.quaternion_xyzw) {
            prop_assert!((a - b).abs() < 1e-15);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Damaged messages (bytes changed, cut, inserted) are refused or read, never a panic and
    /// never an allocation of a claimed size (the decoder allocates only the arm's angles).
    #[test]
    fn damaged_messages_never_panic(
        file in proptest::sample::select(vec![
            "joint_state_driver_order.cdr",
            "joint_state_tf_prefix_gripper.cdr",
            "joint_state_big_endian.cdr",
            "pose_stamped_base.cdr",
        ]),
        edits in proptest::collection::vec((0_usize..3, any::<usize>(), any::<u8>()), 1..6),
    ) {
        let mut bytes = std::fs::read(fixtures().join(file)).expect("fixture");
        for (kind, position, byte) in edits {
            let at = position % (bytes.len() + 1);
            match kind {
                0 if at < bytes.len() => bytes[at] = byte,
                1 => bytes.truncate(at),
                _ => bytes.insert(at, byte),
            }
        }
        let _ = cdr::decode_joint_state(&bytes, &JointNames::ur(""), None);
        let _ = cdr::decode_joint_state(&bytes, &JointNames::ur("alice_"), None);
        let _ = cdr::decode_pose_stamped(&bytes);
    }
}
