//! armtwin on the Zenoh mesh: what every process that speaks armtwin's protocol shares.

pub mod keys;
