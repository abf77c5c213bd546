//! The `armtwin` binary end to end, as one test binary: Cargo builds the binary for this package's
//! tests (`CARGO_BIN_EXE_armtwin`), and armtwin-bench's smoke test finds it beside its own.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]

mod cli;
mod ik;
mod validate;
