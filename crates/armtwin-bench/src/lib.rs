//! armtwin's benchmarks: the parts shared by the `armtwin-bench` binary (the service next to a
//! plain-Zenoh echo under load), the criterion benches in `benches/` and the measuring examples
//! in `examples/`, so every one of them measures the same fleet, messages and configuration.
//!
//! Layout: [`fleet`] (robot ids, the service configuration), [`workload`] (the messages),
//! [`fk_fixture`] and [`ingest_fixture`] (the in-process benches' inputs), [`net`] (keys, Zenoh
//! peers), [`procfs`] (another process's memory and CPU time), [`http`] (a GET on loopback),
//! [`echo`] (the baseline), [`load`] (the load generator), [`run`] (the orchestrator), [`soak`]
//! (hours under load with churn).

#![allow(
    clippy::cast_sign_loss,
    reason = "rates, counts and durations convert between f64 and integers after clamping at zero"
)]
#![allow(
    clippy::missing_panics_doc,
    reason = "the fixtures panic only when the checkout's own example files are broken"
)]

pub mod echo;
pub mod fk_fixture;
pub mod fleet;
pub mod http;
pub mod ingest_fixture;
pub mod load;
pub mod net;
pub mod procfs;
pub mod run;
pub mod soak;
pub mod workload;
