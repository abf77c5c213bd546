//! armtwin: a live digital twin for robot arms.
//!
//! Gateways stream joint angles (and the controller's measured tool pose); armtwin computes each
//! arm's calibrated forward kinematics and keeps running twin-vs-robot error metrics. One pure
//! core serves every mode: the command line, the live service, offline validation and the FMU.
//!
//! Layout, inner ring first (the inner ring never touches the network, the filesystem, tokio,
//! zenoh or `serde_json`):
//! - [`orientation`]: rotation matrix, quaternion, roll/pitch/yaw and UR rotation vector
//!   conversions, and the orientation error measures.
//! - [`kinematics`]: DH tables, tool and output frame, compiled chains, forward kinematics.
//! - [`trig`]: batched, vectorisable sine and cosine for the kinematics hot path.
//! - [`model`]: the Universal Robots catalog, custom arms, factory calibration
//!   (`calibration.conf`, `ur_calibration` YAML) and [`model::RobotModel`].
//! - [`sample`]: decoded joint and measured-pose samples, whatever their source.
//! - [`metrics`]: deviation of one paired sample; cumulative and exact sliding-window statistics.
//! - [`align`]: pairing measured poses with joint samples in source time.
//! - [`pipeline`]: the per-robot twin core every mode runs: samples in, poses, deviations,
//!   metrics and events out to a [`pipeline::Sink`].
//! - [`codec`]: the core's types to and from CSV and the service's JSON wire messages.
//! - [`ingest`]: a gateway message's bytes into the pipeline, shared by the service and
//!   `validate`.
//! - [`config`]: the service's TOML configuration and command-line overrides.
//! - [`fmi`]: the FMI 2.0 FMU's interface contract (variables, resource file), shared by
//!   `armtwin fmu build` and the FMU library (`fmu/`).
//! - [`service`]: `armtwin serve`, the pipeline on a Zenoh mesh.
//! - [`replay`]: `armtwin replay`, a recording published as a gateway would.
//! - [`validate`]: `armtwin validate`, a recording through the pipeline offline, with its report
//!   and plots.
//! - [`fmu_package`]: `armtwin fmu build`, the FMU archive.
//! - [`cli`]: the `armtwin` command line (the outer ring, with `main.rs`).

pub mod align;
#[cfg(feature = "cli")]
pub mod cli;
pub mod codec;
pub mod config;
pub mod fmi;
#[cfg(feature = "cli")]
pub mod fmu_package;
pub mod ingest;
pub mod kinematics;
pub mod metrics;
pub mod model;
pub mod orientation;
pub mod pipeline;
#[cfg(feature = "cli")]
pub mod replay;
pub mod sample;
#[cfg(feature = "cli")]
pub mod service;
pub mod trig;
pub mod validate;
