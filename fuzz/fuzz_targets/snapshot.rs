//! The service's snapshot file (`twin-state.json`): records read from a file written back and
//! read again must be the same records; a damaged or foreign file is an error, never a panic.
//!
//! The file's module is compiled here from its source, beside the core modules it names as
//! `crate::…`: depending on the service crate instead would build zenoh, tokio and rusqlite with
//! coverage instrumentation for one pure function.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;

#[allow(dead_code, unused_imports)]
#[path = "../../crates/armtwin/src/snapshot.rs"]
mod snapshot;

// The paths `snapshot.rs` imports through its own crate's root.
use armtwin_core::{kinematics, metrics, model, pipeline};

use snapshot::{SnapshotError, SnapshotStore};

fuzz_target!(|bytes: &[u8]| {
    let store = SnapshotStore::new(Path::new("/nonexistent/state"), "twin");
    match store.decode(bytes) {
        Ok(records) => {
            let again = store
                .decode(&store.encode(&records))
                .expect("a snapshot written from records");
            assert_eq!(again, records);
        }
        Err(SnapshotError::Corrupt { .. } | SnapshotError::Foreign { .. }) => {}
        Err(error @ SnapshotError::Io { .. }) => panic!("decoding touched a file: {error}"),
    }
});
