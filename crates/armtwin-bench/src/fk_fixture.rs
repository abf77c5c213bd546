//! The FK benchmarks' configuration, shared by `benches/fk.rs` and `examples/fk_min_time.rs`
//! so both time the same poses under the same names.
#![allow(
    clippy::expect_used,
    reason = "the fixtures are the checkout's own constants and example files"
)]

use armtwin_core::kinematics::{OutputFrame, TcpOffset};
use armtwin_core::model::{Calibration, RobotModel, catalog};

/// The joint angles every FK benchmark evaluates (rad).
pub const Q: [f64; 6] = [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739];

/// The calibrated variant: the example `ur_calibration.yaml`, a tool, output in `base_link`.
#[must_use]
pub fn calibrated_ur10e() -> RobotModel {
    RobotModel::new(
        catalog::arm("ur10e").expect("catalog"),
        Some(
            Calibration::parse(
                include_str!("../../../config/examples/ur_calibration.yaml"),
                "ur_calibration.yaml",
            )
            .expect("example calibration"),
        ),
        TcpOffset::from_ur_pose([0.0, 0.02, 0.15, 0.0, 0.0, 0.5]).expect("finite"),
        OutputFrame::BaseLink,
    )
    .expect("model")
}
