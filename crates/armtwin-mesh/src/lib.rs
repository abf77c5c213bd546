//! armtwin on a Zenoh mesh, apart from the twin: how every armtwin session (the service,
//! `replay`, the benchmarks) is configured, opened and torn down.
//!
//! Must not know the twin, the fleet or the codecs: it is the plumbing they share.

pub mod session;

pub use session::{
    MeshError, TEARDOWN_STEP, aggregate_publishers, bounded, close_session, transport_stamp_s,
    zenoh_config_of,
};
