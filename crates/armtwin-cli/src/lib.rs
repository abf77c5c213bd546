//! The `armtwin` command line, over the `armtwin` library: `armtwin`'s clap, anyhow and indicatif
//! live here, so that the library knows no command line.
//!
//! - [`flags`]: every command's arguments (clap), and the zenohd-style mesh flags
//!   ([`flags::ZenohArgs`]) the benchmarks take too.
//! - [`cmd`]: one file per command (`fk`, `models`, `serve`, `replay`, `validate`, `fmu`, `ik`,
//!   `calibrate`), each reading what its flags name, calling the library and printing.
//! - `main.rs`: logging, then [`run`], then the exit status.
//!
//! Must not compute: every pose, metric, fit and message comes from the library, so that what the
//! command line prints is what the service and the FMU compute.

pub mod cmd;
pub mod flags;

pub use cmd::{EXIT_GATE_FAILED, GateFailed, run};
