//! ROS 2 `sensor_msgs/msg/JointState`, `geometry_msgs/msg/PoseStamped` and `std_msgs/msg/String`
//! (a robot's description) in CDR: a decoded pose written back as CDR must decode to the same
//! pose, stamp and frame; a decoded joint state holds one finite angle per arm joint; a decoded
//! string is within its limit and inside the payload; every refusal must carry a known cause.

use crate::invariants::{assert_kind, assert_pose, assert_same_pose, assert_stamp};
use armtwin_codec::cdr::{self, JointNames};

const KINDS: &[&str] = &[
    "too_large",
    "no_header",
    "representation",
    "truncated",
    "count",
    "unterminated",
    "not_utf8",
    "nanosec",
    "length_mismatch",
    "missing_joint",
    "duplicate_joint",
    "non_finite",
    "quaternion_norm",
    "frame_id",
];

/// Runs every check of this decoder on one input; panics on a broken invariant.
pub fn check(payload: &[u8]) {
    assert_stamp(cdr::stamp_hint(payload));
    let arms = [
        JointNames::ur(""),
        JointNames::ur("alice_"),
        JointNames::new(vec!["a".to_owned(), "b".to_owned()]).expect("two names"),
    ];
    for joints in &arms {
        joint_state(payload, joints);
    }
    pose_stamped(payload);
    for limit in [0, 16, 4 << 20] {
        string(payload, limit);
    }
}

fn string(payload: &[u8], limit: usize) {
    match cdr::decode_string(payload, limit) {
        Ok(text) => {
            assert!(text.len() <= limit, "{} bytes over {limit}", text.len());
            // The 4-byte header and the 4-byte length before it (an empty string may omit its NUL).
            assert!(text.len() + 8 <= payload.len(), "more text than payload");
        }
        Err(error) => assert_kind(error.kind(), KINDS),
    }
}

fn joint_state(payload: &[u8], joints: &JointNames) {
    match cdr::decode_joint_state(payload, joints, Some(cdr::EffortMeaning::CurrentA)) {
        Ok(sample) => {
            assert_eq!(sample.q_rad.len(), joints.as_slice().len());
            assert!(sample.q_rad.iter().all(|q| q.is_finite()), "{sample:?}");
            assert_eq!(sample.stamp_s, cdr::stamp_hint(payload));
        }
        Err(error) => {
            assert_kind(error.kind(), KINDS);
            let _ = error.cause();
        }
    }
}

fn pose_stamped(payload: &[u8]) {
    let decoded = match cdr::decode_pose_stamped(payload) {
        Ok(decoded) => decoded,
        Err(error) => {
            assert_kind(error.kind(), KINDS);
            return;
        }
    };
    let sample = &decoded.sample;
    assert_eq!(sample.stamp_s, cdr::stamp_hint(payload));
    assert_stamp(sample.stamp_s);
    assert_pose(&sample.pose);
    let bytes = cdr::encode_pose_stamped(
        sample.stamp_s.unwrap_or(0.0),
        decoded.frame_id,
        &sample.pose,
    );
    let again =
        cdr::decode_pose_stamped_in(&bytes, decoded.frame_id).expect("a re-encoded PoseStamped");
    assert_eq!(
        again.sample.stamp_s, sample.stamp_s,
        "the stamp reads back to the bit"
    );
    assert_same_pose(&again.sample.pose, &sample.pose);
}
