//! What the fuzz targets share: the invariants checked on every decoded value beyond "no panic"
//! (finite numbers, unit quaternions, stable error names) and the small writers that re-encode a
//! decoded message so that it can be decoded again.
//!
//! Must not hide a failure: every check panics, which is how libFuzzer records a finding.

use armtwin_core::kinematics::PoseReadout;

/// Asserts that `kind`, an error's stable name, is one of `names` (a counter or an event keyed
/// by it would otherwise gain a name no dashboard knows).
pub fn assert_kind(kind: &str, names: &[&str]) {
    assert!(
        names.contains(&kind),
        "error kind '{kind}' is not one of {names:?}"
    );
}

/// Asserts that a stamp offered by a decoder is a finite number.
pub fn assert_stamp(stamp_s: Option<f64>) {
    if let Some(stamp_s) = stamp_s {
        assert!(stamp_s.is_finite(), "stamp {stamp_s}");
    }
}

/// Asserts that a decoded pose holds finite numbers and a unit quaternion with `qw ≥ 0`.
pub fn assert_pose(pose: &PoseReadout) {
    let rpy = [pose.rpy.roll_rad, pose.rpy.pitch_rad, pose.rpy.yaw_rad];
    for value in pose
        .position_m
        .iter()
        .chain(&pose.quaternion_xyzw)
        .chain(&rpy)
    {
        assert!(value.is_finite(), "pose {pose:?}");
    }
    let norm = pose
        .quaternion_xyzw
        .iter()
        .map(|q| q * q)
        .sum::<f64>()
        .sqrt();
    assert!(
        (norm - 1.0).abs() < 1e-9,
        "quaternion norm {norm} in {pose:?}"
    );
    assert!(pose.quaternion_xyzw[3] >= 0.0, "qw < 0 in {pose:?}");
}

/// Asserts that two decodings of one pose agree: position exactly, orientation to rounding (a
/// normalised quaternion normalised again may move in its last bits).
pub fn assert_same_pose(first: &PoseReadout, second: &PoseReadout) {
    assert_eq!(first.position_m, second.position_m);
    for (a, b) in first.quaternion_xyzw.iter().zip(&second.quaternion_xyzw) {
        assert!((a - b).abs() < 1e-12, "{first:?} against {second:?}");
    }
}

/// Appends `value` as a LEB128 length (Zenoh's serialization of a sequence length).
pub fn push_leb128(out: &mut Vec<u8>, mut value: u64) {
    loop {
        let byte = (value & 0x7f) as u8;
        value >>= 7;
        if value == 0 {
            out.push(byte);
            return;
        }
        out.push(byte | 0x80);
    }
}
