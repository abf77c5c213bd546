//! Where the fleet's closed blocks go: one log of bounded size, written in a circle, on an
//! unnamed file (gone with the process) or, when no file can be made, in memory.
//!
//! A block is addressed by its absolute offset in the log (bytes ever appended before it); it
//! stays readable until the log has wrapped past it, so the oldest blocks of the whole fleet go
//! first and no per-block bookkeeping is kept anywhere. Appends are gathered in a write buffer;
//! a full buffer is handed to the log's own thread, which makes the file and writes to it, so
//! the thread that took a sample never waits on the disk. The file's pages are the kernel's
//! cache, not the service's memory.
//!
//! Must not know what a block holds ([`super::block`], [`super::ring`]).

use std::collections::VecDeque;
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;

use tracing::warn;

/// Bytes gathered before they go to the file in one write (a quarter of a smaller log's).
const WRITE_BUFFER_BYTES: usize = 256 << 10;

/// Full buffers waiting for the writer at most (4 MiB): past them (a disk slower than the
/// fleet, or a writer thread starved of CPU by a saturated machine), new blocks are dropped and
/// counted, not queued.
const MAX_SEALED: usize = 16;

/// The log.
#[derive(Debug)]
pub struct Spool {
    shared: Arc<Shared>,
    writer: Option<JoinHandle<()>>,
}

#[derive(Debug)]
struct Shared {
    capacity_bytes: u64,
    buffer_bytes: usize,
    log: Mutex<Log>,
    /// Wakes the writer (a buffer sealed, or stopping) and whoever waits for it to settle.
    wake: Condvar,
    write_failures: AtomicU64,
    dropped_blocks: AtomicU64,
}

#[derive(Debug)]
enum Backing {
    /// The directory the file will be made in.
    Unopened(PathBuf),
    File(Arc<File>),
    /// Grown to the capacity as it fills.
    Memory(Vec<u8>),
}

/// What writing a buffer came to.
enum Outcome {
    Written(Arc<File>),
    /// The log goes on in memory, from what the file held (all of it, unless `complete` is
    /// false).
    ToMemory {
        bytes: Vec<u8>,
        complete: bool,
    },
}
use Outcome::{ToMemory, Written};

#[derive(Debug)]
struct Log {
    backing: Backing,
    /// Absolute offset of the next append.
    head: u64,
    /// Absolute offset up to which the bytes are in `backing`; `[written, head)` are in
    /// `sealed`, then `pending`.
    written: u64,
    /// Offsets before this are lost (a file that could not be read back).
    valid_from: u64,
    /// Full buffers handed to the writer, oldest first.
    sealed: VecDeque<Arc<Vec<u8>>>,
    pending: Vec<u8>,
    stopping: bool,
}

impl Spool {
    /// A log of `capacity_bytes` on an unnamed file in `dir` (`dir` created if missing), made
    /// by the log's thread when the first buffer is full; in memory when that fails (with a
    /// warning: the blocks then cost the service's memory).
    #[must_use]
    pub fn in_dir(dir: &Path, capacity_bytes: u64) -> Arc<Self> {
        let shared = Shared::new(Backing::Unopened(dir.to_path_buf()), capacity_bytes);
        let writer = {
            let shared = Arc::clone(&shared);
            std::thread::Builder::new()
                .name("armtwin-recorder-log".to_owned())
                .spawn(move || shared.write_loop())
        };
        let writer = match writer {
            Ok(writer) => Some(writer),
            Err(error) => {
                warn!(%error, "the recorder cannot start its log's thread: the blocks stay in memory");
                shared.lock().backing = Backing::Memory(Vec::new());
                None
            }
        };
        Arc::new(Self { shared, writer })
    }

    /// A log of `capacity_bytes` in memory.
    #[must_use]
    pub fn in_memory(capacity_bytes: u64) -> Arc<Self> {
        Arc::new(Self {
            shared: Shared::new(Backing::Memory(Vec::new()), capacity_bytes),
            writer: None,
        })
    }

    /// Whether the blocks go to disk (before the first are written: whether they will try).
    #[must_use]
    pub fn on_disk(&self) -> bool {
        !matches!(self.shared.lock().backing, Backing::Memory(_))
    }

    /// Bytes the log holds now: what was appended, up to its capacity.
    #[must_use]
    pub fn used_bytes(&self) -> u64 {
        self.shared.lock().head.min(self.shared.capacity_bytes)
    }

    /// Bytes of the service's own memory the log takes (the write buffers, or the whole log
    /// when it is in memory).
    #[must_use]
    pub fn memory_bytes(&self) -> u64 {
        let log = self.shared.lock();
        let backing = match &log.backing {
            Backing::File(_) | Backing::Unopened(_) => 0,
            Backing::Memory(bytes) => bytes.capacity(),
        };
        let sealed: usize = log.sealed.iter().map(|buffer| buffer.capacity()).sum();
        (backing + sealed + log.pending.capacity()) as u64
    }

    /// Writes to the file that failed (the log went on in memory after the first).
    #[must_use]
    pub fn write_failures(&self) -> u64 {
        self.shared.write_failures.load(Ordering::Relaxed)
    }

    /// Blocks dropped because the writer was [`MAX_SEALED`] buffers behind.
    #[must_use]
    pub fn dropped_blocks(&self) -> u64 {
        self.shared.dropped_blocks.load(Ordering::Relaxed)
    }

    /// Appends `parts`, one after the other, as one entry; its absolute offset, or `None` when
    /// the entry is larger than the whole log or the writer is too far behind to take it.
    /// Never waits on the disk.
    #[must_use]
    pub fn append(&self, parts: &[&[u8]]) -> Option<u64> {
        let shared = &*self.shared;
        let len: usize = parts.iter().map(|part| part.len()).sum();
        if len as u64 > shared.capacity_bytes {
            return None;
        }
        let mut log = shared.lock();
        let offset = log.head;
        if let Backing::Memory(bytes) = &mut log.backing {
            let mut at = offset;
            for part in parts {
                shared.write_memory(bytes, at, part);
                at += part.len() as u64;
            }
            log.head = at;
            log.written = at;
            return Some(offset);
        }
        if !log.pending.is_empty() && log.pending.len() + len > shared.buffer_bytes {
            if log.sealed.len() >= MAX_SEALED {
                if shared.dropped_blocks.fetch_add(1, Ordering::Relaxed) == 0 {
                    warn!(
                        "the recorder's disk is slower than the fleet's records: blocks are dropped"
                    );
                }
                return None;
            }
            let full = std::mem::replace(&mut log.pending, Vec::with_capacity(shared.buffer_bytes));
            log.sealed.push_back(Arc::new(full));
            shared.wake.notify_all();
        }
        for part in parts {
            log.pending.extend_from_slice(part);
        }
        log.head += len as u64;
        Some(offset)
    }

    /// Copies the `out.len()` bytes at absolute `offset` into `out`; `false` when the log has
    /// wrapped past them (or they were never appended).
    pub fn read(&self, offset: u64, out: &mut [u8]) -> bool {
        let shared = &*self.shared;
        let log = shared.lock();
        let end = offset + out.len() as u64;
        let oldest = log
            .head
            .saturating_sub(shared.capacity_bytes)
            .max(log.valid_from);
        if end > log.head || offset < oldest {
            return false;
        }
        // The part not yet written: the sealed buffers, then the one filling.
        let mut chunk_start = log.written;
        for chunk in log
            .sealed
            .iter()
            .map(|b| b.as_slice())
            .chain([log.pending.as_slice()])
        {
            let chunk_end = chunk_start + chunk.len() as u64;
            let (from, to) = (offset.max(chunk_start), end.min(chunk_end));
            if from < to {
                let at = |position: u64, base: u64| usize::try_from(position - base).unwrap_or(0);
                out[at(from, offset)..at(to, offset)]
                    .copy_from_slice(&chunk[at(from, chunk_start)..at(to, chunk_start)]);
            }
            chunk_start = chunk_end;
        }
        if offset >= log.written {
            return true;
        }
        let in_backing = usize::try_from(end.min(log.written) - offset).unwrap_or(0);
        let (position, run) = shared.wrapped(offset, in_backing);
        let (first, rest) = out[..in_backing].split_at_mut(run);
        match &log.backing {
            Backing::Unopened(_) => false,
            Backing::File(file) => {
                file.read_exact_at(first, position).is_ok()
                    && (rest.is_empty() || file.read_exact_at(rest, 0).is_ok())
            }
            Backing::Memory(bytes) => {
                let at = usize::try_from(position).unwrap_or(usize::MAX);
                let (Some(a), Some(b)) = (bytes.get(at..at + first.len()), bytes.get(..rest.len()))
                else {
                    return false;
                };
                first.copy_from_slice(a);
                rest.copy_from_slice(b);
                true
            }
        }
    }

    /// Waits (at most `timeout`) until every sealed buffer is written; whether they were.
    #[cfg(test)]
    fn settle(&self, timeout: std::time::Duration) -> bool {
        let log = self.shared.lock();
        let (log, _) = self
            .shared
            .wake
            .wait_timeout_while(log, timeout, |log| !log.sealed.is_empty())
            .unwrap_or_else(PoisonError::into_inner);
        log.sealed.is_empty()
    }
}

impl Drop for Spool {
    fn drop(&mut self) {
        self.shared.lock().stopping = true;
        self.shared.wake.notify_all();
        if let Some(writer) = self.writer.take()
            && writer.join().is_err()
        {
            warn!("the recorder's log thread panicked");
        }
    }
}

impl Shared {
    fn new(backing: Backing, capacity_bytes: u64) -> Arc<Self> {
        let capacity_bytes = capacity_bytes.max(1);
        Arc::new(Self {
            capacity_bytes,
            buffer_bytes: usize::try_from(capacity_bytes / 4)
                .unwrap_or(usize::MAX)
                .clamp(1, WRITE_BUFFER_BYTES),
            log: Mutex::new(Log {
                backing,
                head: 0,
                written: 0,
                valid_from: 0,
                sealed: VecDeque::new(),
                pending: Vec::new(),
                stopping: false,
            }),
            wake: Condvar::new(),
            write_failures: AtomicU64::new(0),
            dropped_blocks: AtomicU64::new(0),
        })
    }

    fn lock(&self) -> MutexGuard<'_, Log> {
        self.log.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Where `len` bytes at absolute `offset` start in the backing, and how many of them run
    /// before its end (the rest continue at its start).
    fn wrapped(&self, offset: u64, len: usize) -> (u64, usize) {
        let position = offset % self.capacity_bytes;
        let until_end = usize::try_from(self.capacity_bytes - position).unwrap_or(usize::MAX);
        (position, len.min(until_end))
    }

    /// Copies `data` to absolute `at` in a memory log, grown (by doubling, up to the capacity)
    /// to hold it: a fleet that records little holds little.
    fn write_memory(&self, bytes: &mut Vec<u8>, at: u64, data: &[u8]) {
        let capacity = usize::try_from(self.capacity_bytes).unwrap_or(usize::MAX);
        let end = usize::try_from((at + data.len() as u64).min(self.capacity_bytes))
            .unwrap_or(usize::MAX);
        if bytes.len() < end {
            bytes.resize(end.max(bytes.len() * 2).min(capacity), 0);
        }
        let mut done = 0;
        while done < data.len() {
            let (position, run) = self.wrapped(at + done as u64, data.len() - done);
            let position = usize::try_from(position).unwrap_or(usize::MAX);
            bytes[position..position + run].copy_from_slice(&data[done..done + run]);
            done += run;
        }
    }

    /// The log's thread: makes the file, then writes each sealed buffer to it outside the lock.
    /// A file that refuses a write (a full disk) is read back into memory and the log goes on
    /// there: what the rings hold is not lost, it costs memory instead (with a warning).
    fn write_loop(&self) {
        let mut log = self.lock();
        loop {
            log = self
                .wake
                .wait_while(log, |log| log.sealed.is_empty() && !log.stopping)
                .unwrap_or_else(PoisonError::into_inner);
            if log.stopping {
                return;
            }
            let buffer = Arc::clone(&log.sealed[0]);
            let at = log.written;
            let backing = match &log.backing {
                Backing::Unopened(dir) => Err(dir.clone()),
                Backing::File(file) => Ok(Arc::clone(file)),
                Backing::Memory(_) => {
                    self.drain_to_memory(&mut log);
                    continue;
                }
            };
            drop(log);
            let outcome = self.write_buffer(backing, at, &buffer);
            log = self.lock();
            match outcome {
                Written(file) => {
                    log.backing = Backing::File(file);
                    log.sealed.pop_front();
                    log.written += buffer.len() as u64;
                }
                ToMemory { bytes, complete } => {
                    if !complete {
                        warn!(
                            "the recorder cannot read its blocks back: the records before now are lost"
                        );
                        log.valid_from = log.written;
                    }
                    log.backing = Backing::Memory(bytes);
                    self.drain_to_memory(&mut log);
                }
            }
            self.wake.notify_all();
        }
    }

    /// Writes `buffer` at absolute `at` to the file (made first in the directory, when not yet
    /// made); on failure, what the file holds, read back for the memory log.
    fn write_buffer(&self, backing: Result<Arc<File>, PathBuf>, at: u64, buffer: &[u8]) -> Outcome {
        let file = match backing {
            Ok(file) => file,
            Err(dir) => {
                match std::fs::create_dir_all(&dir).and_then(|()| tempfile::tempfile_in(&dir)) {
                    Ok(file) => Arc::new(file),
                    Err(error) => {
                        warn!(dir = %dir.display(), %error, "the recorder cannot keep its blocks on disk: they stay in memory");
                        return ToMemory {
                            bytes: Vec::new(),
                            complete: at == 0,
                        };
                    }
                }
            }
        };
        let (position, run) = self.wrapped(at, buffer.len());
        let written = file
            .write_all_at(&buffer[..run], position)
            .and_then(|()| file.write_all_at(&buffer[run..], 0));
        match written {
            Ok(()) => Written(file),
            Err(error) => {
                self.write_failures.fetch_add(1, Ordering::Relaxed);
                warn!(%error, "the recorder cannot write its blocks to disk: they stay in memory from now on");
                let held = usize::try_from(at.min(self.capacity_bytes)).unwrap_or(0);
                let mut bytes = vec![0; held];
                let complete = file.read_exact_at(&mut bytes, 0).is_ok();
                ToMemory { bytes, complete }
            }
        }
    }

    /// Writes every buffer not yet written into the memory log.
    fn drain_to_memory(&self, log: &mut Log) {
        let Log {
            backing: Backing::Memory(bytes),
            written,
            sealed,
            pending,
            ..
        } = log
        else {
            return;
        };
        for buffer in sealed.drain(..) {
            self.write_memory(bytes, *written, &buffer);
            *written += buffer.len() as u64;
        }
        self.write_memory(bytes, *written, pending);
        *written += pending.len() as u64;
        *pending = Vec::new();
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::{Backing, Shared, Spool};

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
            // The writer keeps up (a block past MAX_SEALED buffers would be dropped).
            assert!(spool.settle(Duration::from_secs(10)));
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
        assert_eq!(spool.dropped_blocks(), 0);
    }

    #[test]
    fn a_memory_log_does_the_same_and_counts_its_bytes() {
        let spool = Spool::in_memory(10_000);
        assert!(!spool.on_disk());
        check_wraps(&spool);
        assert!(spool.memory_bytes() >= 10_000);
    }

    #[test]
    fn a_writer_that_falls_behind_drops_new_blocks_and_counts_them() {
        // No writer thread: every sealed buffer stays.
        let spool = Spool {
            shared: Shared::new(Backing::Unopened("unused".into()), 64 << 20),
            writer: None,
        };
        let bytes = entry(1, 1000);
        let kept: Vec<u64> = (0..6000).filter_map(|_| spool.append(&[&bytes])).collect();
        assert!(spool.dropped_blocks() > 0);
        // MAX_SEALED sealed buffers of 256 KiB and a full one filling, every entry in them
        // readable.
        assert_eq!(kept.len() as u64 + spool.dropped_blocks(), 6000);
        assert!(
            spool.memory_bytes() <= (super::MAX_SEALED as u64 + 2) * (256 << 10),
            "{}",
            spool.memory_bytes()
        );
        let mut out = vec![0; 1000];
        assert!(
            kept.iter()
                .all(|&offset| spool.read(offset, &mut out) && out == bytes)
        );
    }

    #[test]
    fn a_file_that_refuses_writes_hands_the_log_to_memory_and_loses_nothing() {
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("log");
        std::fs::write(&path, b"").expect("file");
        let read_only = std::fs::File::open(&path).expect("open");
        let shared = Shared::new(Backing::File(read_only.into()), 1 << 20);
        let writer = {
            let shared = shared.clone();
            std::thread::spawn(move || shared.write_loop())
        };
        let spool = Spool {
            shared,
            writer: Some(writer),
        };
        let mut entries = Vec::new();
        for i in 0..600_u16 {
            let bytes = entry(i as u8, 1000);
            entries.push((spool.append(&[&bytes]).expect("kept"), bytes));
            assert!(spool.settle(Duration::from_secs(10)));
        }
        assert!(!spool.on_disk());
        assert_eq!(spool.write_failures(), 1);
        for (offset, bytes) in &entries {
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
            assert!(spool.settle(Duration::from_secs(10)));
        }
        assert!(!spool.on_disk());
        let mut out = [0; 5];
        assert!(spool.read(495, &mut out) && &out == b"entry");
    }
}
