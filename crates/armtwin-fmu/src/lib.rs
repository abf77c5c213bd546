//! armtwin's forward kinematics as an FMI 2.0 co-simulation FMU: the shared library inside the
//! `.fmu` archive that `armtwin fmu build` writes.
//!
//! The library is model-agnostic: which robot it computes (catalog model, calibration, tool,
//! output frame, GUID) comes from `resources/armtwin-fmu.toml` in the unpacked FMU, read at
//! `fmi2Instantiate`. Inputs `q1..q6` (value references 0–5), outputs `x, y, z, roll, pitch, yaw,
//! qx, qy, qz, qw` (6–15) and tunable tool parameters `tcp_x..tcp_rz` (16–21), as
//! [`armtwin_core::fmi::VARIABLES`] lists them; the pose is the core's, exactly as `armtwin fk` prints
//! it.
//!
//! Layout:
//! - [`resources`]: the resource URI and the files it names (the library's only file access).
//! - [`instance`]: one instance as a state machine in safe Rust.
//! - [`ffi`]: the exported `fmi2*` C functions (the only `unsafe` code).

pub mod ffi;
pub mod instance;
pub mod resources;
