//! The closed-form evaluation of UR-structured chains equals the link-by-link chain to 1e-15 for
//! every catalog model, with and without tool and `base_link`, and is taken only for an exact
//! UR structure.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]

use std::f64::consts::{SQRT_2, TAU};

use armtwin_core::kinematics::{Chain, OutputFrame, TcpOffset};
use armtwin_core::model::calibration::{CalibrationForm, MountingDeltas};
use armtwin_core::model::{Calibration, RobotModel, catalog};
use armtwin_core::orientation::wrap_angle;

/// Configurations per model and variant.
const CONFIGURATIONS: usize = 10_000;
const TOLERANCE: f64 = 1e-15;

/// A small deterministic generator (xorshift64*): uniform in [−1, 1).
struct Uniform(u64);

impl Uniform {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let bits = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11;
        bits as f64 / (1_u64 << 52) as f64 - 1.0
    }
}

/// Over random configurations, the largest differences of: position (m), rotation-matrix entries,
/// orientation (the angle between the two, rad), roll/pitch/yaw (rad, times cos(pitch)) and
/// quaternion components.
fn worst_differences(fast: &Chain, reference: &Chain, range_rad: f64, seed: u64) -> [f64; 5] {
    let mut uniform = Uniform(seed);
    let mut worst = [0.0_f64; 5];
    for _ in 0..CONFIGURATIONS {
        let q: [f64; 6] = std::array::from_fn(|_| range_rad * uniform.next());
        let (a, b) = (fast.pose_unchecked(&q), reference.pose_unchecked(&q));
        worst[0] = worst[0].max((a.position_m - b.position_m).amax());
        worst[1] = worst[1].max((a.rotation - b.rotation).amax());
        let (ra, rb) = (a.readout(), b.readout());
        // The angle between the two orientations (rad): for Rₐ = R_b · (I + [ω]ₓ) to first order,
        // |ω| = ‖Rₐ − R_b‖_F / √2 (taking it through quaternions would add their own rounding).
        worst[2] = worst[2].max((a.rotation - b.rotation).norm() / SQRT_2);
        // Roll and yaw near ±π may land on either side of the cut; near gimbal lock their split
        // is ill-conditioned (a rounding-sized change in R moves them by about that over
        // cos(pitch)), so they are compared scaled by cos(pitch).
        let cos_pitch = ra.rpy.pitch_rad.cos();
        for (x, y) in [
            (ra.rpy.roll_rad, rb.rpy.roll_rad),
            (ra.rpy.pitch_rad, rb.rpy.pitch_rad),
            (ra.rpy.yaw_rad, rb.rpy.yaw_rad),
        ] {
            worst[3] = worst[3].max(wrap_angle(x - y).abs() * cos_pitch);
        }
        for (x, y) in ra.quaternion_xyzw.iter().zip(rb.quaternion_xyzw) {
            worst[4] = worst[4].max((x - y).abs());
        }
    }
    worst
}

#[test]
fn closed_form_equals_the_link_by_link_chain_for_every_catalog_model() {
    let tool = TcpOffset::from_ur_pose([0.01, -0.02, 0.15, 0.3, -0.2, 1.1]).expect("finite");
    let variants = [
        (TcpOffset::FLANGE, OutputFrame::Base),
        (TcpOffset::FLANGE, OutputFrame::BaseLink),
        (tool, OutputFrame::Base),
        (tool, OutputFrame::BaseLink),
    ];
    let mut overall = [0.0_f64; 5];
    for (index, entry) in catalog::UNIVERSAL_ROBOTS.iter().enumerate() {
        for (variant, (tool, frame)) in variants.iter().enumerate() {
            let model = RobotModel::new(entry.arm(), None, *tool, *frame).expect("model");
            let fast = model.chain();
            assert!(fast.uses_closed_form(), "{} {frame:?}", entry.name);
            let reference = fast.to_link_by_link();
            assert!(!reference.uses_closed_form());
            // The joints' range (±2π), and far beyond it (unlimited wrist 3, custom arms).
            for (range_rad, seed) in [(TAU, 1), (60.0, 2)] {
                let seed = seed * 1000 + (index * 10 + variant) as u64;
                let worst = worst_differences(fast, &reference, range_rad, seed);
                assert!(
                    worst.iter().all(|&w| w <= TOLERANCE),
                    "{} {frame:?} ±{range_rad}: {worst:?}",
                    entry.name
                );
                for (o, w) in overall.iter_mut().zip(worst) {
                    *o = o.max(w);
                }
            }
        }
    }
    println!(
        "worst over all models and variants: position {:e} m, rotation entry {:e}, \
         orientation {:e} rad, roll/pitch/yaw × cos(pitch) {:e} rad, quaternion component {:e}",
        overall[0], overall[1], overall[2], overall[3], overall[4]
    );
}

#[test]
fn closed_form_is_taken_only_for_the_exact_ur_structure() {
    let arm = catalog::arm("ur10e").expect("catalog");
    // Zero deltas leave the table as it is: still the UR structure.
    let zero = MountingDeltas {
        delta_theta_rad: [0.0; 6],
        delta_a_m: [0.0; 6],
        delta_d_m: [0.0; 6],
        delta_alpha_rad: [0.0; 6],
    };
    let calibration = |deltas: MountingDeltas| Calibration {
        source_name: "test".to_owned(),
        form: CalibrationForm::MountingDeltas(deltas),
    };
    let model = |deltas| {
        RobotModel::new(
            arm.clone(),
            Some(calibration(deltas)),
            TcpOffset::FLANGE,
            OutputFrame::Base,
        )
        .expect("model")
    };
    assert!(model(zero).chain().uses_closed_form());
    // Any change to the structure (θ, α, a₁, a₄, a₅, a₆, d₂, d₃), however small, takes the chain
    // link by link; the six lengths d₁, a₂, a₃, d₄, d₅, d₆ are the closed form's own parameters.
    for joint in 0..6 {
        for field in 0..4 {
            let mut deltas = zero;
            let target = match field {
                0 => &mut deltas.delta_theta_rad,
                1 => &mut deltas.delta_a_m,
                2 => &mut deltas.delta_d_m,
                _ => &mut deltas.delta_alpha_rad,
            };
            target[joint] = 1e-12;
            let length = matches!((field, joint), (1, 1 | 2) | (2, 0 | 3 | 4 | 5));
            assert_eq!(
                model(deltas).chain().uses_closed_form(),
                length,
                "delta {field} on joint {joint}"
            );
        }
    }
    let yaml = Calibration::parse(
        include_str!("../../../config/examples/ur_calibration.yaml"),
        "ur_calibration.yaml",
    )
    .expect("example calibration");
    let calibrated =
        RobotModel::new(arm, Some(yaml), TcpOffset::FLANGE, OutputFrame::Base).expect("model");
    assert!(!calibrated.chain().uses_closed_form());
}

#[test]
fn short_joint_slices_still_end_the_chain_early() {
    let model = RobotModel::nominal("ur5e").expect("catalog model");
    let chain = model.chain();
    let q = [0.3, -1.1, 0.7];
    let a = chain.pose_unchecked(&q);
    let b = chain.to_link_by_link().pose_unchecked(&q);
    assert_eq!(a, b);
}
