//! armtwin's pure twin core: everything between "a decoded joint sample" and "a pose plus
//! updated metrics", shared by every mode (the live service, offline validation, replay and the
//! FMU).
//!
//! Nothing here touches the network, the filesystem, tokio, zenoh or `serde_json`, or reads a
//! clock: text comes in as `&str`, time as arguments, results go to a [`pipeline::Sink`]. The
//! compiler holds it to that: the crate's dependencies exclude them, and `clippy.toml` beside it
//! forbids `std::fs` and the system clocks.
//!
//! Layout:
//! - [`orientation`]: rotation matrix, quaternion, roll/pitch/yaw and UR rotation vector
//!   conversions, and the orientation error measures.
//! - [`trig`]: batched, vectorisable sine and cosine for the kinematics hot path.
//! - [`kinematics`]: DH tables, tool and output frame, compiled chains, forward kinematics.
//! - [`dynamics`]: inverse dynamics (recursive Newton–Euler), gravity torques, mass matrix and
//!   generalized momentum, the UR controller's torque model by mode, payload identification; the
//!   published inertial parameters and drive data of the UR arms.
//! - [`identify`]: a UR arm's `calibration.conf` deltas (and tool) fitted to its own paired
//!   joint and pose samples.
//! - [`ik`]: inverse kinematics of Universal Robots arms (closed form, Newton on calibrated
//!   chains).
//! - [`model`]: the Universal Robots catalog, custom arms, factory calibration
//!   (`calibration.conf`, `ur_calibration` YAML) and [`model::RobotModel`].
//! - [`inertia`]: arms' inertial parameters and the published UR tables the model carries and
//!   the dynamics use.
//! - [`pose_fields`]: a pose as the named output fields every mode writes.
//! - [`sample`]: decoded joint and measured-pose samples, whatever their source.
//! - [`metrics`]: deviation of one paired sample; cumulative statistics and a sliding window of
//!   source time kept in time slices.
//! - [`align`]: pairing measured poses with joint samples in source time.
//! - [`self_calibration`]: a live robot's reservoir of pairs and the re-fit of its kinematics
//!   from them, judged on held-out time blocks.
//! - [`pipeline`]: the per-robot twin core every mode runs: samples in, poses, deviations,
//!   metrics and events out to a [`pipeline::Sink`].
//! - [`fmi`]: the FMI 2.0 FMU's interface contract (variables, resource file), shared by
//!   `armtwin fmu build` and the FMU library.

pub mod align;
pub mod dynamics;
pub mod fmi;
pub mod identify;
pub mod ik;
pub mod inertia;
pub mod kinematics;
pub mod metrics;
pub mod model;
pub mod orientation;
pub mod pipeline;
pub mod pose_fields;
pub mod sample;
pub mod self_calibration;
pub mod trig;
