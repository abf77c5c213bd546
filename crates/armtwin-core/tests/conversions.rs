//! Property tests: every orientation conversion round-trips, and the comparison measures agree
//! with their textbook definitions; plus the singular cases named one by one.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]
#![allow(clippy::float_cmp, reason = "the singular cases have exact answers")]

use std::f64::consts::{FRAC_PI_2, PI, TAU};

use armtwin_core::orientation::{
    Rpy, canonical, matrix_from_quaternion, matrix_from_rotation_vector, matrix_from_rpy,
    quaternion_distance, quaternion_from_matrix, quaternion_from_rotation_vector,
    quaternion_from_xyzw, quaternion_to_xyzw, rotation_angle_between, rotation_vector_from_matrix,
    rotation_vector_from_quaternion, rpy_difference, rpy_from_matrix, wrap_angle,
};
use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};
use proptest::prelude::*;

fn unit_quaternion() -> impl Strategy<Value = UnitQuaternion<f64>> {
    (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64)
        .prop_filter("non-degenerate", |(w, x, y, z)| {
            (w * w + x * x + y * y + z * z) > 1e-3
        })
        .prop_map(|(w, x, y, z)| UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)))
}

fn is_rotation(m: &Matrix3<f64>) -> bool {
    (m.transpose() * m - Matrix3::identity()).norm() < 1e-13
        && (m.determinant() - 1.0).abs() < 1e-13
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4000))]

    #[test]
    fn rpy_round_trips_away_from_gimbal_lock(
        roll in -PI..PI, pitch in (-FRAC_PI_2 + 1e-3)..(FRAC_PI_2 - 1e-3), yaw in -PI..PI
    ) {
        let m = matrix_from_rpy(Rpy { roll_rad: roll, pitch_rad: pitch, yaw_rad: yaw });
        prop_assert!(is_rotation(&m));
        let back = rpy_from_matrix(&m);
        let diff = rpy_difference(back, Rpy { roll_rad: roll, pitch_rad: pitch, yaw_rad: yaw });
        prop_assert!(diff.roll_rad.abs() < 1e-12, "{diff:?}");
        prop_assert!(diff.pitch_rad.abs() < 1e-12, "{diff:?}");
        prop_assert!(diff.yaw_rad.abs() < 1e-12, "{diff:?}");
        prop_assert!(back.roll_rad > -PI && back.roll_rad <= PI);
        prop_assert!(back.yaw_rad > -PI && back.yaw_rad <= PI);
    }

    #[test]
    fn rpy_keeps_the_rotation_near_gimbal_lock(
        roll in -PI..PI, offset in -1e-6..1e-6f64, yaw in -PI..PI, sign in prop::bool::ANY
    ) {
        let pitch = if sign { FRAC_PI_2 - offset.abs() } else { -FRAC_PI_2 + offset.abs() };
        let m = matrix_from_rpy(Rpy { roll_rad: roll, pitch_rad: pitch, yaw_rad: yaw });
        let rebuilt = matrix_from_rpy(rpy_from_matrix(&m));
        // Within 1e-12 of the lock yaw is set to 0, which moves the rotation by ~2·cos(pitch).
        prop_assert!((rebuilt - m).norm() < 1e-11, "{}", (rebuilt - m).norm());
    }

    #[test]
    fn quaternion_matrix_round_trip(q in unit_quaternion()) {
        let m = matrix_from_quaternion(&q);
        prop_assert!(is_rotation(&m));
        let back = quaternion_from_matrix(&m);
        prop_assert!(back.w >= 0.0);
        let c = canonical(q);
        let same = (back.coords - c.coords).norm() < 1e-14 || (back.coords + c.coords).norm() < 1e-14;
        prop_assert!(same, "{back:?} vs {c:?}");
    }

    #[test]
    fn rotation_vector_round_trip(axis in (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64), angle in 0.0..(PI - 1e-6)) {
        let axis = Vector3::new(axis.0, axis.1, axis.2);
        prop_assume!(axis.norm() > 1e-3);
        let r = axis.normalize() * angle;
        let q = quaternion_from_rotation_vector(&r);
        prop_assert!(q.w >= 0.0);
        prop_assert!((q.norm() - 1.0).abs() < 1e-15);
        let back = rotation_vector_from_quaternion(&q);
        prop_assert!((back - r).norm() < 1e-12, "{back} vs {r}");
        let via_matrix = rotation_vector_from_matrix(&matrix_from_rotation_vector(&r));
        prop_assert!((via_matrix - r).norm() < 1e-12, "{via_matrix} vs {r}");
    }

    #[test]
    fn rotation_vector_of_any_quaternion_is_at_most_a_half_turn(q in unit_quaternion()) {
        let r = rotation_vector_from_quaternion(&q);
        prop_assert!(r.norm() <= PI + 1e-15);
        let back = matrix_from_rotation_vector(&r);
        prop_assert!((back - matrix_from_quaternion(&q)).norm() < 1e-13);
    }

    #[test]
    fn xyzw_round_trip_normalises_and_canonicalises(q in unit_quaternion(), scale in 0.5..2.0f64) {
        let [x, y, z, w] = quaternion_to_xyzw(&q);
        let parsed = quaternion_from_xyzw([x * scale, y * scale, z * scale, w * scale]).expect("valid");
        prop_assert!(parsed.w >= 0.0);
        prop_assert!((matrix_from_quaternion(&parsed) - matrix_from_quaternion(&q)).norm() < 1e-14);
    }

    #[test]
    fn distance_and_angle_match_their_definitions(a in unit_quaternion(), b in unit_quaternion(), flip in prop::bool::ANY) {
        let b = if flip { UnitQuaternion::new_unchecked(-b.into_inner()) } else { b };
        let dot = a.coords.dot(&b.coords).abs().min(1.0);
        let distance = quaternion_distance(&a, &b);
        let angle = rotation_angle_between(&a, &b);
        prop_assert!((0.0..=1.0).contains(&distance));
        prop_assert!((0.0..=PI).contains(&angle));
        prop_assert!((distance - (1.0 - dot)).abs() < 1e-12, "{distance} vs {}", 1.0 - dot);
        // The acos form is only accurate away from dot = 1.
        if dot < 0.999 {
            prop_assert!((angle - 2.0 * dot.acos()).abs() < 1e-10);
        }
        prop_assert!((quaternion_distance(&b, &a) - distance).abs() < 1e-15);
    }

    #[test]
    fn wrap_angle_lands_in_range_and_keeps_the_angle(angle in -100.0..100.0f64) {
        let w = wrap_angle(angle);
        prop_assert!(w > -PI && w <= PI);
        let turns = (angle - w) / TAU;
        prop_assert!((turns - turns.round()).abs() < 1e-12);
    }
}

#[test]
fn named_singularities() {
    // Zero rotation vector, both ways.
    let zero = quaternion_from_rotation_vector(&Vector3::zeros());
    assert_eq!(quaternion_to_xyzw(&zero), [0.0, 0.0, 0.0, 1.0]);
    assert_eq!(rotation_vector_from_quaternion(&zero), Vector3::zeros());
    // Tiny rotation vectors keep their digits.
    let tiny = Vector3::new(3e-12, -1e-12, 2e-12);
    let back = rotation_vector_from_quaternion(&quaternion_from_rotation_vector(&tiny));
    assert!((back - tiny).norm() < 1e-26);
    // Half turns: w = 0, angle π, distance 1 from identity.
    let half = quaternion_from_rotation_vector(&Vector3::new(PI, 0.0, 0.0));
    assert!(half.w.abs() < 1e-16);
    assert!((rotation_vector_from_quaternion(&half).norm() - PI).abs() < 1e-15);
    assert!((quaternion_distance(&UnitQuaternion::identity(), &half) - 1.0).abs() < 1e-15);
    assert!((rotation_angle_between(&UnitQuaternion::identity(), &half) - PI).abs() < 1e-15);
    // Gimbal lock exactly: yaw defined as 0, the rotation kept.
    for pitch in [FRAC_PI_2, -FRAC_PI_2] {
        let m = matrix_from_rpy(Rpy {
            roll_rad: 1.0,
            pitch_rad: pitch,
            yaw_rad: 0.25,
        });
        let rpy = rpy_from_matrix(&m);
        assert_eq!(rpy.yaw_rad, 0.0);
        assert!((matrix_from_rpy(rpy) - m).norm() < 1e-15);
    }
    // Euler differences across the ±π seam are small.
    let a = Rpy {
        roll_rad: PI - 0.01,
        pitch_rad: 0.0,
        yaw_rad: -PI + 0.02,
    };
    let b = Rpy {
        roll_rad: -PI + 0.01,
        pitch_rad: 0.0,
        yaw_rad: PI - 0.02,
    };
    let d = rpy_difference(a, b);
    assert!((d.roll_rad + 0.02).abs() < 1e-12 && (d.yaw_rad - 0.04).abs() < 1e-12);
    // A quaternion of zero norm is refused.
    assert!(quaternion_from_xyzw([0.0; 4]).is_none());
}
