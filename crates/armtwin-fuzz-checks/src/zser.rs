//! armtwin's Zenoh-serialized gateway messages (`armtwin/joints/v1` and `v2`, `armtwin/pose/v1`): a decoded
//! message written back in the same format must decode to the same sample, and every refusal
//! must carry a known cause.

use crate::invariants::{assert_kind, assert_pose, assert_same_pose, assert_stamp, push_leb128};
use armtwin_codec::json::DecodedJoints;
use armtwin_codec::zser;
use armtwin_core::kinematics::PoseReadout;

const KINDS: &[&str] = &[
    "too_large",
    "non_finite",
    "joint_count",
    "quaternion_norm",
    "truncated",
    "trailing_bytes",
    "malformed_length",
    "sequence_length",
    "joint_state",
];

/// Runs every check of this decoder on one input; panics on a broken invariant.
pub fn check(payload: &[u8]) {
    assert_stamp(zser::stamp_hint(payload));
    for joint_count in [6, 2] {
        joints(payload, joint_count);
        joints_with_state(payload, joint_count);
    }
    measured(payload);
}

fn joints(payload: &[u8], joint_count: usize) {
    let decoded = match zser::read_joints(payload, joint_count) {
        Ok(decoded) => decoded,
        Err(refused) => {
            assert_kind(refused.error.kind(), KINDS);
            assert_eq!(refused.stamp_s, zser::stamp_hint(payload));
            return;
        }
    };
    let DecodedJoints {
        sample,
        measured_error,
        ..
    } = &decoded;
    assert_eq!(sample.q_rad.len(), joint_count);
    assert!(sample.q_rad.iter().all(|q| q.is_finite()), "{sample:?}");
    assert_eq!(sample.stamp_s, zser::stamp_hint(payload));
    if let Some(pose) = &sample.measured {
        assert_pose(pose);
    }
    if let Some(error) = measured_error {
        assert_kind(error.kind(), KINDS);
    }
    let mut bytes = Vec::new();
    bytes.extend_from_slice(&sample.stamp_s.expect("a binary message's t").to_le_bytes());
    push_f64s(&mut bytes, &sample.q_rad);
    bytes.extend_from_slice(&sample.seq.expect("a binary message's seq").to_le_bytes());
    match &sample.measured {
        Some(pose) => push_f64s(&mut bytes, &pose_values(pose)),
        None => push_leb128(&mut bytes, 0),
    }
    let again = zser::read_joints(&bytes, joint_count).expect("a re-encoded joint message");
    assert_eq!(again.measured_error, None);
    assert_eq!(again.sample.stamp_s, sample.stamp_s);
    assert_eq!(again.sample.seq, sample.seq);
    assert_eq!(again.sample.q_rad, sample.q_rad);
    match (&again.sample.measured, &sample.measured) {
        (Some(again), Some(pose)) => assert_same_pose(again, pose),
        (again, pose) => assert_eq!(again.is_some(), pose.is_some()),
    }
}

fn measured(payload: &[u8]) {
    let sample = match zser::read_measured(payload) {
        Ok(sample) => sample,
        Err(refused) => {
            assert_kind(refused.error.kind(), KINDS);
            assert_eq!(refused.stamp_s, zser::stamp_hint(payload));
            return;
        }
    };
    assert_eq!(sample.stamp_s, zser::stamp_hint(payload));
    assert_pose(&sample.pose);
    let mut bytes = Vec::new();
    bytes.extend_from_slice(&sample.stamp_s.expect("a binary message's t").to_le_bytes());
    push_f64s(&mut bytes, &pose_values(&sample.pose));
    let again = zser::read_measured(&bytes).expect("a re-encoded measured pose");
    assert_eq!(again.stamp_s, sample.stamp_s);
    assert_same_pose(&again.pose, &sample.pose);
}

fn push_f64s(bytes: &mut Vec<u8>, values: &[f64]) {
    push_leb128(bytes, values.len() as u64);
    for value in values {
        bytes.extend_from_slice(&value.to_le_bytes());
    }
}

/// `armtwin/joints/v2`: the joints as in v1; a state decoded and written back decodes to the
/// same state, bit for bit.
fn joints_with_state(payload: &[u8], joint_count: usize) {
    let decoded = match zser::read_joints_with_state(payload, joint_count) {
        Ok(decoded) => decoded,
        Err(refused) => {
            assert_kind(refused.error.kind(), KINDS);
            assert_eq!(refused.stamp_s, zser::stamp_hint(payload));
            return;
        }
    };
    let sample = &decoded.sample;
    assert_eq!(sample.q_rad.len(), joint_count);
    if let Some(error) = &decoded.state_error {
        assert_kind(error.kind(), KINDS);
        assert!(sample.state.is_none());
    }
    let Some(state) = &sample.state else {
        return;
    };
    assert!(!state.is_empty());
    for (_, values) in state.quantities() {
        assert_eq!(values.len(), joint_count);
        assert!(values.iter().all(|value| value.is_finite()));
    }
    let measured = sample.measured.as_ref().map(pose_values);
    let bytes = zser::joints_state_bytes(
        sample.stamp_s.expect("a binary message's t"),
        &sample.q_rad,
        sample.seq.expect("a binary message's seq"),
        measured.as_ref(),
        state,
    );
    let again = zser::read_joints_with_state(&bytes, joint_count).expect("a re-encoded message");
    assert_eq!(again.sample.state.as_ref(), Some(state));
}

fn pose_values(pose: &PoseReadout) -> [f64; 7] {
    let [x, y, z] = pose.position_m;
    let [qx, qy, qz, qw] = pose.quaternion_xyzw;
    [x, y, z, qx, qy, qz, qw]
}
