//! What every decoder of bytes armtwin did not write must keep, beyond "no panic": one `check`
//! per decoder, which panics on a broken invariant. The fuzz targets (`fuzz/`, run by
//! `scripts/fuzz.sh`) call them on generated inputs; this crate's `tests/corpus.rs` calls them on
//! every committed corpus and regression input, so a decoder change that breaks one fails
//! `cargo test`.
//!
//! - [`invariants`]: the checks the decoders share (finite numbers, unit quaternions, known error
//!   kinds) and the small writers that re-encode a decoded message.
//! - one module per decoder, named as its fuzz target: [`json`], [`zser`], [`cdr`],
//!   [`ros2_attachment`], [`calibration`], [`snapshot`], [`csv`], [`rtde`], [`urdf`]; and
//!   [`certificate_names`], the names `armtwin certs` writes; [`fleet`], the fleet description.
//!
//! Must not depend on the runtime or the service: the fuzz build instruments all of this crate's
//! dependencies.

// Every check panics on purpose: a panic is how libFuzzer and the corpus test record a finding.
#![allow(clippy::missing_panics_doc, clippy::expect_used)]
// Decoded values are compared exactly on purpose: a message read twice must give the same bits.
#![allow(clippy::float_cmp)]

pub mod calibration;
pub mod cdr;
pub mod certificate_names;
pub mod csv;
pub mod fleet;
pub mod invariants;
pub mod json;
pub mod ros2_attachment;
pub mod rtde;
pub mod snapshot;
pub mod urdf;
pub mod zser;

// The service's snapshot file, compiled from its source (it names only the core): depending on
// the service's crate would bring zenoh and tokio into the instrumented fuzz build for one pure
// function.
#[allow(dead_code, unused_imports, clippy::pedantic)]
#[path = "../../armtwin-service/src/snapshot.rs"]
mod snapshot_file;

// The names `armtwin certs` writes, compiled from their source for the same reason: the access
// crate would bring zenoh, rcgen and ring along.
#[path = "../../armtwin-access/src/certs/names.rs"]
mod certificate_names_file;
/// One decoder's checks on one input; panics on a broken invariant.
pub type Check = fn(&[u8]);

/// Every decoder's check, by its fuzz target's name (the folder of its corpus under
/// `fuzz/corpus/` and of its regression inputs under `fuzz/regressions/`).
pub const CHECKS: &[(&str, Check)] = &[
    ("calibration", calibration::check),
    ("cdr", cdr::check),
    ("certificate_names", certificate_names::check),
    ("csv", csv::check),
    ("fleet", fleet::check),
    ("json", json::check),
    ("ros2_attachment", ros2_attachment::check),
    ("rtde", rtde::check),
    ("snapshot", snapshot::check),
    ("urdf", urdf::check),
    ("zser", zser::check),
];
