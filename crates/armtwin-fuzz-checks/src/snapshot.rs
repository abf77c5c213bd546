//! The service's snapshot file (`twin-state.json`): records read from a file written back and
//! read again must be the same records; a damaged or foreign file is an error, never a panic.

use std::path::Path;

use crate::snapshot_file::{SnapshotError, SnapshotStore};

/// Runs every check of this decoder on one input; panics on a broken invariant.
pub fn check(bytes: &[u8]) {
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
}
