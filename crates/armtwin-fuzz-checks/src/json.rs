//! armtwin's JSON gateway messages (`twin/joints/<robot>`, `twin/measured/<robot>`) as the service
//! decodes them: the fast path must agree with the general decoder, a decoded message written
//! back as JSON must decode to the same sample, and every refusal must carry a known cause.

use crate::invariants::{assert_kind, assert_pose, assert_same_pose, assert_stamp};
use armtwin_codec::json::{self, paths};
use armtwin_core::kinematics::PoseReadout;
use serde_json::{Value, json};

const KINDS: &[&str] = &[
    "too_large",
    "not_utf8",
    "not_json",
    "not_object",
    "missing_field",
    "wrong_type",
    "non_finite",
    "joint_count",
    "joint_state",
    "ambiguous_fields",
    "duplicate_field",
    "unit",
    "orientation_forms",
    "quaternion_norm",
];

/// Runs every check of this decoder on one input; panics on a broken invariant.
pub fn check(payload: &[u8]) {
    assert_stamp(json::stamp_hint(payload));
    for joint_count in [6, 2] {
        joints(payload, joint_count);
    }
    measured(payload);
}

fn joints(payload: &[u8], joint_count: usize) {
    let general = paths::general_joints(payload, joint_count);
    if let Some(fast) = paths::fast_joints(payload, joint_count) {
        assert_eq!(
            general.as_ref().ok(),
            Some(&fast),
            "fast path against general"
        );
    }
    let decoded = match json::read_joints(payload, joint_count) {
        Ok(decoded) => decoded,
        Err(refused) => {
            assert_kind(refused.error.kind(), KINDS);
            assert_stamp(refused.stamp_s);
            return;
        }
    };
    let sample = &decoded.sample;
    assert_eq!(sample.q_rad.len(), joint_count);
    assert!(sample.q_rad.iter().all(|q| q.is_finite()), "{sample:?}");
    assert_stamp(sample.stamp_s);
    if let Some(pose) = &sample.measured {
        assert_pose(pose);
    }
    if let Some(error) = &decoded.measured_error {
        assert_kind(error.kind(), KINDS);
    }
    let mut message = json!({ "q": sample.q_rad.to_vec() });
    if let Some(stamp_s) = sample.stamp_s {
        message["t"] = json!(stamp_s);
    }
    if let Some(seq) = sample.seq {
        message["seq"] = json!(seq);
    }
    if let Some(pose) = &sample.measured {
        message["measured"] = pose_object(pose);
    }
    let bytes = serde_json::to_vec(&message).expect("a JSON object");
    let again = json::decode_joints(&bytes, joint_count).expect("a re-encoded joint message");
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
    let general = paths::general_measured(payload);
    if let Some(fast) = paths::fast_measured(payload) {
        assert_eq!(
            general.as_ref().ok(),
            Some(&fast),
            "fast path against general"
        );
    }
    let sample = match json::read_measured(payload) {
        Ok(sample) => sample,
        Err(refused) => {
            assert_kind(refused.error.kind(), KINDS);
            assert_stamp(refused.stamp_s);
            return;
        }
    };
    assert_stamp(sample.stamp_s);
    assert_pose(&sample.pose);
    let mut message = pose_object(&sample.pose);
    if let Some(stamp_s) = sample.stamp_s {
        message["t"] = json!(stamp_s);
    }
    let bytes = serde_json::to_vec(&message).expect("a JSON object");
    let again = json::decode_measured(&bytes).expect("a re-encoded measured pose");
    assert_eq!(again.stamp_s, sample.stamp_s);
    assert_same_pose(&again.pose, &sample.pose);
}

fn pose_object(pose: &PoseReadout) -> Value {
    let [x, y, z] = pose.position_m;
    let [qx, qy, qz, qw] = pose.quaternion_xyzw;
    json!({ "x": x, "y": y, "z": z, "qx": qx, "qy": qy, "qz": qz, "qw": qw })
}
