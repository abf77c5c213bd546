//! Where the fleet's closed blocks go: one log of bounded size, written in a circle, on an
//! unnamed file (gone with the process) or, when no file can be made, in memory.
//!
//! A block is addressed by its absolute offset in the log (bytes ever appended before it); it
//! stays readable until the log has wrapped past it, so the oldest blocks of the whole fleet go
//! first and no per-block bookkeeping is kept anywhere. Appends are gathered in a write buffer
//! and reach the file in large writes; the file's pages are the kernel's cache, not the
//! service's memory.
//!
//! Must not know what a block holds ([`super::block`], [`super::ring`]).

use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use tracing::warn;

/// Bytes gathered before they go to the file in one write (a quarter of a smaller log's).
const WRITE_BUFFER_BYTES: usize = 256 << 10;

/// The log.
#[derive(Debug)]
pub struct Spool {
    capacity_bytes: u64,
    buffer_bytes: usize,
    log: Mutex<Log>,
    write_failures: AtomicU64,
}

#[derive(Debug)]
enum Backing {
    /// The directory the file will be made in.
    Unopened(PathBuf),
    File(File),
    /// Grown to the capacity as it fills.
    Memory(Vec<u8>),
}

#[derive(Debug)]
struct Log {
    backing: Backing,
    /// Absolute offset of the next append.
    head: u64,
    /// Absolute offset up to which the bytes are in `backing`; `[written, head)` are in
    /// `pending`.
    written: u64,
    /// Offsets before this are lost (a file that could not be read back).
    valid_from: u64,
    pending: Vec<u8>,
}

impl Spool {
    /// A log of `capacity_bytes` on an unnamed file in `dir` (`dir` created if missing), made
    /// when the first blocks are written; in memory when that fails (with a warning: the
    /// blocks then cost the service's memory).
    #[must_use]
    pub fn in_dir(dir: &Path, capacity_bytes: u64) -> Arc<Self> {
        Self::with(Backing::Unopened(dir.to_path_buf()), capacity_bytes)
    }

    /// A log of `capacity_bytes` in memory.
    #[must_use]
    pub fn in_memory(capacity_bytes: u64) -> Arc<Self> {
        Self::with(Backing::Memory(Vec::new()), capacity_bytes)
    }

    fn with(backing: Backing, capacity_bytes: u64) -> Arc<Self> {
        let capacity_bytes = capacity_bytes.max(1);
        Arc::new(Self {
            capacity_bytes,
            buffer_bytes: usize::try_from(capacity_bytes / 4)
                .unwrap_or(usize::MAX)
                .min(WRITE_BUFFER_BYTES),
            log: Mutex::new(Log {
                backing,
                head: 0,
                written: 0,
                valid_from: 0,
                pending: Vec::new(),
            }),
            write_failures: AtomicU64::new(0),
        })
    }

    /// Whether the blocks go to disk (before the first are written: whether they will try).
    #[must_use]
    pub fn on_disk(&self) -> bool {
        matches!(self.lock().backing, Backing::File(_) | Backing::Unopened(_))
    }

    /// Bytes the log holds now: what was appended, up to its capacity.
    #[must_use]
    pub fn used_bytes(&self) -> u64 {
        self.lock().head.min(self.capacity_bytes)
    }

    /// Bytes of the service's own memory the log takes (the write buffer, or the whole log
    /// when it is in memory).
    #[must_use]
    pub fn memory_bytes(&self) -> u64 {
        let log = self.lock();
        let backing = match &log.backing {
            Backing::File(_) | Backing::Unopened(_) => 0,
            Backing::Memory(bytes) => bytes.capacity(),
        };
        (backing + log.pending.capacity()) as u64
    }

    /// Writes to the file that failed (the log went on in memory after the first).
    #[must_use]
    pub fn write_failures(&self) -> u64 {
        self.write_failures.load(Ordering::Relaxed)
    }

    /// Appends `parts`, one after the other, as one entry; its absolute offset, or `None` when
    /// the entry is larger than the whole log.
    pub fn append(&self, parts: &[&[u8]]) -> Option<u64> {
        let len: usize = parts.iter().map(|part| part.len()).sum();
        if len as u64 > self.capacity_bytes {
            return None;
        }
        let mut log = self.lock();
        let offset = log.head;
        if log.pending.len() + len > self.buffer_bytes {
            self.flush(&mut log);
        }
        for part in parts {
            log.pending.extend_from_slice(part);
        }
        log.head += len as u64;
        if log.pending.len() >= self.buffer_bytes || matches!(log.backing, Backing::Memory(_)) {
            self.flush(&mut log);
        }
        Some(offset)
    }

    /// Copies the `out.len()` bytes at absolute `offset` into `out`; `false` when the log has
    /// wrapped past them (or they were never appended).
    pub fn read(&self, offset: u64, out: &mut [u8]) -> bool {
        let log = self.lock();
        let end = offset + out.len() as u64;
        if end > log.head
            || offset
                < log
                    .head
                    .saturating_sub(self.capacity_bytes)
                    .max(log.valid_from)
        {
            return false;
        }
        // The part still in the write buffer.
        let mut in_backing = out.len();
        if end > log.written {
            let buffered_from = offset.max(log.written);
            let skip = usize::try_from(buffered_from - offset).unwrap_or(usize::MAX);
            let from = usize::try_from(buffered_from - log.written).unwrap_or(usize::MAX);
            let count = out.len() - skip;
            out[skip..].copy_from_slice(&log.pending[from..from + count]);
            in_backing = skip;
        }
        if in_backing == 0 {
            return true;
        }
        let (first, second) = self.wrapped(offset, in_backing);
        let out = &mut out[..in_backing];
        let (head, tail) = out.split_at_mut(first.1);
        match &log.backing {
            Backing::Unopened(_) => false,
            Backing::File(file) => {
                file.read_exact_at(head, first.0).is_ok()
                    && (tail.is_empty() || file.read_exact_at(tail, second).is_ok())
            }
            Backing::Memory(bytes) => {
                let at = |position: u64| usize::try_from(position).unwrap_or(usize::MAX);
                let (Some(a), Some(b)) = (
                    bytes.get(at(first.0)..at(first.0) + head.len()),
                    bytes.get(at(second)..at(second) + tail.len()),
                ) else {
                    return false;
                };
                head.copy_from_slice(a);
                tail.copy_from_slice(b);
                true
            }
        }
    }

    /// Where `len` bytes at absolute `offset` lie in the backing: the first run's position and
    /// length, and the position of the rest (at the start, when the run wraps).
    fn wrapped(&self, offset: u64, len: usize) -> ((u64, usize), u64) {
        let position = offset % self.capacity_bytes;
        let until_end = usize::try_from(self.capacity_bytes - position).unwrap_or(usize::MAX);
        ((position, len.min(until_end)), 0)
    }

    /// Writes the write buffer to the backing. A file that refuses a write (a full disk) is
    /// read back into memory and the log goes on there: what the rings hold is not lost, it
    /// costs memory instead (with a warning).
    fn flush(&self, log: &mut Log) {
        if let Backing::Unopened(dir) = &log.backing {
            let file = std::fs::create_dir_all(dir).and_then(|()| tempfile::tempfile_in(dir));
            log.backing = match file {
                Ok(file) => Backing::File(file),
                Err(error) => {
                    warn!(dir = %dir.display(), %error, "the recorder cannot keep its blocks on disk: they stay in memory");
                    Backing::Memory(Vec::new())
                }
            };
        }
        if let Backing::File(file) = &log.backing {
            let mut result = Ok(());
            let mut done = 0;
            while done < log.pending.len() && result.is_ok() {
                let ((position, run), _) =
                    self.wrapped(log.written + done as u64, log.pending.len() - done);
                result = file.write_all_at(&log.pending[done..done + run], position);
                done += run;
            }
            match result {
                Ok(()) => {
                    log.written += log.pending.len() as u64;
                    log.pending.clear();
                    return;
                }
                Err(error) => {
                    self.write_failures.fetch_add(1, Ordering::Relaxed);
                    let held = usize::try_from(log.written.min(self.capacity_bytes)).unwrap_or(0);
                    let mut bytes = vec![0; held];
                    if let Err(read_error) = file.read_exact_at(&mut bytes, 0) {
                        warn!(%read_error, "the recorder cannot read its blocks back: the records before now are lost");
                        log.valid_from = log.written;
                    }
                    warn!(%error, "the recorder cannot write its blocks to disk: they stay in memory from now on");
                    log.backing = Backing::Memory(bytes);
                }
            }
        }
        let Log {
            backing: Backing::Memory(bytes),
            written,
            pending,
            ..
        } = log
        else {
            return;
        };
        let end = usize::try_from((*written + pending.len() as u64).min(self.capacity_bytes))
            .unwrap_or(usize::MAX);
        if bytes.len() < end {
            // Grown by doubling up to the capacity: a fleet that records little holds little.
            let capacity = usize::try_from(self.capacity_bytes).unwrap_or(usize::MAX);
            bytes.resize(end.max(bytes.len() * 2).min(capacity), 0);
        }
        let mut done = 0;
        while done < pending.len() {
            let ((position, run), _) = self.wrapped(*written + done as u64, pending.len() - done);
            let at = usize::try_from(position).unwrap_or(usize::MAX);
            bytes[at..at + run].copy_from_slice(&pending[done..done + run]);
            done += run;
        }
        *written += pending.len() as u64;
        pending.clear();
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Log> {
        self.log.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

#[cfg(test)]
mod tests {
    use super::Spool;

    fn entry(i: u8, len: usize) -> Vec<u8> {
        (0..len).map(|k| i.wrapping_add(k as u8)).collect()
    }

    fn check_wraps(spool: &Spool) {
        let mut offsets = Vec::new();
        for i in 0..100_u8 {
            let bytes = entry(i, 300 + usize::from(i));
            offsets.push((
                spool.append(&[&bytes[..10], &bytes[10..]]).expect("fits"),
                bytes,
            ));
        }
        let mut readable = 0;
        for (offset, bytes) in &offsets {
            let mut out = vec![0; bytes.len()];
            if spool.read(*offset, &mut out) {
                assert_eq!(&out, bytes);
                readable += 1;
            }
        }
        // 10 000 bytes hold the newest entries (~390 bytes each), and every one of them reads.
        assert!((20..=30).contains(&readable), "{readable}");
        let (last, bytes) = offsets.last().expect("entries");
        let mut out = vec![0; bytes.len()];
        assert!(spool.read(*last, &mut out) && &out == bytes);
        assert!(!spool.read(0, &mut out), "the first entry was overwritten");
        assert!(!spool.read(*last + 1, &mut out), "past the head");
        assert!(spool.append(&[&vec![0; 10_001]]).is_none());
    }

    #[test]
    fn a_file_log_wraps_and_reads_only_what_it_still_holds() {
        let dir = tempfile::tempdir().expect("dir");
        let spool = Spool::in_dir(&dir.path().join("made"), 10_000);
        check_wraps(&spool);
        assert!(spool.on_disk() && dir.path().join("made").is_dir());
        assert_eq!(spool.used_bytes(), 10_000);
    }

    #[test]
    fn a_memory_log_does_the_same_and_counts_its_bytes() {
        let spool = Spool::in_memory(10_000);
        assert!(!spool.on_disk());
        check_wraps(&spool);
        assert!(spool.memory_bytes() >= 10_000);
    }

    #[test]
    fn a_file_that_refuses_writes_hands_the_log_to_memory_and_loses_nothing() {
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("log");
        std::fs::write(&path, b"").expect("file");
        let read_only = std::fs::File::open(&path).expect("open");
        let spool = Spool::with(super::Backing::File(read_only), 1 << 20);
        let entries: Vec<(u64, Vec<u8>)> = (0..600_u16)
            .map(|i| {
                let bytes = entry(i as u8, 1000);
                (spool.append(&[&bytes]).expect("fits"), bytes)
            })
            .collect();
        assert!(!spool.on_disk());
        assert_eq!(spool.write_failures(), 1);
        for (offset, bytes) in entries.iter().skip(100) {
            let mut out = vec![0; bytes.len()];
            assert!(spool.read(*offset, &mut out) && &out == bytes, "{offset}");
        }
    }

    #[test]
    fn a_directory_that_cannot_be_made_keeps_the_log_in_memory() {
        let dir = tempfile::tempdir().expect("dir");
        let file = dir.path().join("a-file");
        std::fs::write(&file, b"x").expect("file");
        let spool = Spool::in_dir(&file.join("below"), 1000);
        for _ in 0..100 {
            assert!(spool.append(&[b"entry"]).is_some());
        }
        assert!(!spool.on_disk());
        let mut out = [0; 5];
        assert!(spool.read(495, &mut out) && &out == b"entry");
    }
}
