//! The client certificates the server refused, kept within bounds. The OPC UA stack stores every
//! unknown client certificate in `<pki_dir>/rejected/` so that an administrator can move the
//! one they mean to trust to `trusted/`; a client that presents a fresh certificate on every try
//! would otherwise fill the disk before anyone has signed in. The oldest go first.

use std::path::Path;
use std::time::SystemTime;

/// Rejected certificates kept at most.
pub const MAX_REJECTED_FILES: usize = 64;
/// Bytes of rejected certificates kept at most.
pub const MAX_REJECTED_BYTES: u64 = 1 << 20;

/// Removes the oldest files of `dir` until at most `max_files` and `max_bytes` remain; the number
/// removed. A folder that does not exist (no certificate refused yet) is not an error.
pub(crate) fn prune(dir: &Path, max_files: usize, max_bytes: u64) -> std::io::Result<usize> {
    let entries = match std::fs::read_dir(dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    let mut files: Vec<(SystemTime, u64, std::path::PathBuf)> = entries
        .flatten()
        .filter_map(|entry| {
            let metadata = entry.metadata().ok()?;
            metadata.is_file().then(|| {
                let modified = metadata.modified().unwrap_or(SystemTime::UNIX_EPOCH);
                (modified, metadata.len(), entry.path())
            })
        })
        .collect();
    // Newest first: keep from the front while both bounds hold.
    files.sort_unstable_by(|a, b| b.0.cmp(&a.0).then_with(|| b.2.cmp(&a.2)));
    let mut kept_bytes = 0_u64;
    let mut removed = 0;
    for (index, (_, bytes, path)) in files.iter().enumerate() {
        kept_bytes = kept_bytes.saturating_add(*bytes);
        if index >= max_files || kept_bytes > max_bytes {
            match std::fs::remove_file(path) {
                Ok(()) => removed += 1,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => return Err(e),
            }
        }
    }
    Ok(removed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn write_aged(dir: &Path, name: &str, bytes: usize, age_s: u64) {
        let path = dir.join(name);
        std::fs::write(&path, vec![b'x'; bytes]).expect("written");
        let file = std::fs::File::options()
            .write(true)
            .open(&path)
            .expect("opened");
        file.set_modified(SystemTime::now() - Duration::from_secs(age_s))
            .expect("aged");
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .expect("listed")
            .flatten()
            .map(|entry| entry.file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn the_oldest_go_first_by_count_and_by_bytes() {
        let dir = tempfile::tempdir().expect("a folder");
        for (i, age) in [50, 10, 40, 20, 30].iter().enumerate() {
            write_aged(dir.path(), &format!("c{i}.der"), 100, *age);
        }
        assert_eq!(prune(dir.path(), 3, 10_000).expect("pruned"), 2);
        assert_eq!(names(dir.path()), ["c1.der", "c3.der", "c4.der"]);
        // 250 bytes hold two of the three.
        assert_eq!(prune(dir.path(), 10, 250).expect("pruned"), 1);
        assert_eq!(names(dir.path()), ["c1.der", "c3.der"]);
        assert_eq!(prune(dir.path(), 10, 10_000).expect("pruned"), 0);
    }

    #[test]
    fn a_missing_folder_is_nothing_to_prune() {
        let dir = tempfile::tempdir().expect("a folder");
        assert_eq!(
            prune(&dir.path().join("rejected"), 1, 1).expect("no error"),
            0
        );
    }
}
