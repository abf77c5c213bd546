//! A robot's recent streams at full rate: fixed-size records of `f64`s, kept for a span of
//! source time, at most a number of records of the robot's own, in blocks the whole fleet's log
//! bounds in bytes.
//!
//! The newest records wait in an open block of a few kilobytes, the only memory a ring holds
//! whatever its rate and span; a full block is compressed ([`super::block`]) and appended to the
//! [`Spool`] with a header naming the block before it, so the ring keeps one offset and reads
//! its past by walking back. Must stay cheap per record: a push copies the record's values and,
//! once a block, compresses it.

use std::sync::Arc;

use super::block;
use super::spool::Spool;

/// Raw bytes of an open block: what a ring holds in memory.
pub const OPEN_BLOCK_BYTES: usize = 2048;

/// What precedes a block's bytes in the log: the previous block's offset (`u64::MAX` for
/// none), its records, the compressed length, and its first and last stamps.
const HEADER_BYTES: usize = 8 + 4 + 4 + 8 + 8;

/// No previous block.
const NONE: u64 = u64::MAX;

/// A closed block's header, as written before its bytes.
#[derive(Debug, Clone, Copy)]
struct Header {
    previous: u64,
    records: u32,
    compressed_len: u32,
    first_s: f64,
    last_s: f64,
}

impl Header {
    fn to_bytes(self) -> [u8; HEADER_BYTES] {
        let mut bytes = [0; HEADER_BYTES];
        bytes[..8].copy_from_slice(&self.previous.to_le_bytes());
        bytes[8..12].copy_from_slice(&self.records.to_le_bytes());
        bytes[12..16].copy_from_slice(&self.compressed_len.to_le_bytes());
        bytes[16..24].copy_from_slice(&self.first_s.to_le_bytes());
        bytes[24..32].copy_from_slice(&self.last_s.to_le_bytes());
        bytes
    }

    fn from_bytes(bytes: &[u8; HEADER_BYTES]) -> Self {
        let u64_at = |at: usize| {
            let mut word = [0; 8];
            word.copy_from_slice(&bytes[at..at + 8]);
            u64::from_le_bytes(word)
        };
        let u32_at = |at: usize| {
            let mut word = [0; 4];
            word.copy_from_slice(&bytes[at..at + 4]);
            u32::from_le_bytes(word)
        };
        Self {
            previous: u64_at(0),
            records: u32_at(8),
            compressed_len: u32_at(12),
            first_s: f64::from_bits(u64_at(16)),
            last_s: f64::from_bits(u64_at(24)),
        }
    }
}

/// Records of `stride` values each, the first of them the record's source stamp (s), in the
/// order they were pushed.
#[derive(Debug)]
pub struct RecordRing {
    stride: usize,
    span_s: f64,
    max_records: usize,
    /// Records per block.
    block_records: usize,
    /// The open block's records (allocated on the first push, never grown).
    open: Vec<f64>,
    /// Offset of the newest closed block in the spool.
    newest_block: u64,
    newest_s: Option<f64>,
    spool: Arc<Spool>,
}

impl RecordRing {
    /// An empty ring of records of `stride` values (`stride ≥ 1`), kept for `span_s` of source
    /// time before the newest, at most `max_bytes` of them (as raw values), its closed blocks in
    /// `spool`.
    #[must_use]
    pub fn new(stride: usize, span_s: f64, max_bytes: usize, spool: Arc<Spool>) -> Self {
        let stride = stride.max(1);
        let record_bytes = stride * size_of::<f64>();
        Self {
            stride,
            span_s,
            max_records: max_bytes / record_bytes,
            block_records: (OPEN_BLOCK_BYTES / record_bytes).max(1),
            open: Vec::new(),
            newest_block: NONE,
            newest_s: None,
            spool,
        }
    }

    /// Values per record.
    #[must_use]
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// Whether no record was pushed since the ring started (or started afresh).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.newest_s.is_none()
    }

    /// Bytes the ring holds in memory (its open block's allocation).
    #[must_use]
    pub fn held_bytes(&self) -> usize {
        self.open.capacity() * size_of::<f64>()
    }

    /// Appends `record` (`stride` values, the stamp first; a shorter one is padded with NaN, a
    /// longer one cut). A record stamped before the newest starts the ring afresh: a clock that
    /// went back.
    pub fn push(&mut self, record: &[f64]) {
        let stamp_s = record.first().copied().unwrap_or(f64::NAN);
        if self.newest_s.is_some_and(|newest_s| {
            matches!(
                stamp_s.partial_cmp(&newest_s),
                None | Some(std::cmp::Ordering::Less)
            )
        }) {
            self.open.clear();
            self.newest_block = NONE;
        }
        if self.open.capacity() == 0 {
            self.open.reserve_exact(self.block_records * self.stride);
        }
        let take = record.len().min(self.stride);
        self.open.extend(&record[..take]);
        self.open
            .extend(std::iter::repeat_n(f64::NAN, self.stride - take));
        self.newest_s = Some(stamp_s);
        if self.open.len() >= self.block_records * self.stride {
            self.close_block();
        }
    }

    /// Compresses the open block into the spool (a block that cannot be kept breaks the chain:
    /// the ring then holds only what follows it).
    fn close_block(&mut self) {
        let records = self.open.len() / self.stride;
        let header = |compressed_len: usize| {
            Some(Header {
                previous: self.newest_block,
                records: u32::try_from(records).ok()?,
                compressed_len: u32::try_from(compressed_len).ok()?,
                first_s: self.open[0],
                last_s: self.open[self.open.len() - self.stride],
            })
        };
        let header_and_block = block::encode_with(&self.open, self.stride, |compressed| {
            let header = header(compressed.len())?;
            self.spool.append(&[&header.to_bytes(), compressed])
        })
        .ok()
        .flatten();
        self.newest_block = header_and_block.unwrap_or(NONE);
        self.open.clear();
    }

    /// Appends to `out` every record stamped in `[from_s, until_s]` still kept (in the span
    /// before the newest, among the newest `max_bytes`, not overwritten in the spool), oldest
    /// first; how many.
    pub fn copy_range(&self, from_s: f64, until_s: f64, out: &mut Vec<f64>) -> usize {
        let Some(newest_s) = self.newest_s else {
            return 0;
        };
        let oldest_s = newest_s - self.span_s;
        // Blocks newest first, then copied oldest first.
        let mut blocks: Vec<(Header, Vec<u8>)> = Vec::new();
        let mut records = self.open.len() / self.stride;
        let mut offset = self.newest_block;
        while offset != NONE && records < self.max_records {
            let mut bytes = [0; HEADER_BYTES];
            if !self.spool.read(offset, &mut bytes) {
                break;
            }
            let header = Header::from_bytes(&bytes);
            // A header is this ring's own, but it is read from a file: nothing is sized by it
            // past what a block of this ring can be.
            let raw_bytes = self.block_records * self.stride * size_of::<f64>();
            if header.last_s < oldest_s.max(from_s)
                || header.records as usize > self.block_records
                || header.compressed_len as usize > block::max_encoded_bytes(raw_bytes)
            {
                break;
            }
            let mut compressed = vec![0; header.compressed_len as usize];
            if !self
                .spool
                .read(offset + HEADER_BYTES as u64, &mut compressed)
            {
                break;
            }
            records += header.records as usize;
            offset = header.previous;
            blocks.push((header, compressed));
        }
        // The newest `max_records` records: the oldest block may be cut.
        let mut skip = records.saturating_sub(self.max_records);
        let select = |values: &[f64], skip: &mut usize, out: &mut Vec<f64>| {
            let mut copied = 0;
            for record in values.chunks_exact(self.stride) {
                if *skip > 0 {
                    *skip -= 1;
                    continue;
                }
                let stamp_s = record[0];
                if stamp_s >= oldest_s && (from_s..=until_s).contains(&stamp_s) {
                    out.extend_from_slice(record);
                    copied += 1;
                }
            }
            copied
        };
        let start = out.len();
        let mut copied = 0;
        let mut values = Vec::new();
        for (header, compressed) in blocks.iter().rev() {
            values.clear();
            if block::decode(
                compressed,
                header.records as usize,
                self.stride,
                &mut values,
            )
            .is_err()
            {
                // A block not as written: what precedes it is of no use either.
                out.truncate(start);
                copied = 0;
                continue;
            }
            copied += select(&values, &mut skip, out);
        }
        copied + select(&self.open, &mut skip, out)
    }

    /// The newest record's stamp, if any.
    #[must_use]
    pub fn newest_s(&self) -> Option<f64> {
        self.newest_s
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::float_cmp, reason = "records are copied, not computed")]
    use std::sync::Arc;

    use super::{RecordRing, Spool};

    fn records(ring: &RecordRing) -> Vec<f64> {
        let mut out = Vec::new();
        ring.copy_range(f64::NEG_INFINITY, f64::INFINITY, &mut out);
        out
    }

    fn spool() -> Arc<Spool> {
        Spool::in_memory(1 << 24)
    }

    #[test]
    fn keeps_the_span_before_the_newest_record_and_no_more() {
        let mut ring = RecordRing::new(2, 1.0, 1 << 20, spool());
        for i in 0..500 {
            let stamp_s = f64::from(i) * 0.01;
            ring.push(&[stamp_s, f64::from(i)]);
        }
        // 4.99 back to 3.99: 101 records.
        let held = records(&ring);
        assert_eq!(held.len(), 2 * 101);
        assert_eq!(held[1], 399.0);
        assert_eq!(held[held.len() - 1], 499.0);
        assert_eq!(ring.newest_s(), Some(4.99));
        // Its memory is the open block, whatever the span holds.
        assert!(
            ring.held_bytes() <= super::OPEN_BLOCK_BYTES,
            "{}",
            ring.held_bytes()
        );
    }

    #[test]
    fn the_robots_bound_keeps_the_newest_records_and_the_oldest_go() {
        // 64 records of two values in 1 KiB.
        let mut ring = RecordRing::new(2, 100.0, 1024, spool());
        for i in 0..1000 {
            ring.push(&[f64::from(i), f64::from(i)]);
        }
        let held = records(&ring);
        assert_eq!(held.len(), 2 * 64);
        assert_eq!(held[0], 936.0);
    }

    #[test]
    fn the_fleets_log_bounds_every_ring_and_the_oldest_blocks_go_first() {
        let shared = Spool::in_memory(64 << 10);
        let mut first = RecordRing::new(4, 1000.0, 1 << 20, shared.clone());
        let mut second = RecordRing::new(4, 1000.0, 1 << 20, shared.clone());
        let noise = |i: u32| f64::from(i.wrapping_mul(2_654_435_761));
        for i in 0..20_000 {
            first.push(&[f64::from(i), noise(i), noise(i + 1), noise(i + 2)]);
            second.push(&[f64::from(i), noise(i), 0.0, 0.0]);
        }
        assert_eq!(shared.used_bytes(), 64 << 10);
        for ring in [&first, &second] {
            let held = records(ring);
            assert!(
                !held.is_empty() && held.len() < 4 * 20_000,
                "{}",
                held.len()
            );
            assert_eq!(held[held.len() - 4], 19_999.0);
            // Every record held is a run up to the newest, none missing in it.
            let stamps: Vec<f64> = held.chunks_exact(4).map(|r| r[0]).collect();
            assert!(stamps.windows(2).all(|w| w[1] == w[0] + 1.0));
        }
        assert_eq!(first.newest_s(), Some(19_999.0));
    }

    #[test]
    fn a_clock_that_goes_back_starts_afresh_and_ranges_select_by_stamp() {
        let mut ring = RecordRing::new(1, 10.0, 1 << 20, spool());
        for stamp_s in [100.0, 101.0, 102.0, 103.0] {
            ring.push(&[stamp_s]);
        }
        let mut out = Vec::new();
        assert_eq!(ring.copy_range(101.0, 102.5, &mut out), 2);
        assert_eq!(out, [101.0, 102.0]);
        ring.push(&[5.0]);
        assert_eq!(records(&ring), [5.0]);
    }

    #[test]
    fn records_across_many_blocks_come_back_bit_for_bit() {
        let mut ring = RecordRing::new(27, 20.0, 8 << 20, spool());
        let mut pushed = Vec::new();
        for i in 0..5000_u32 {
            let t = f64::from(i) * 0.002;
            let record: Vec<f64> = (0..27)
                .map(|k| match k {
                    0 => 1.7e9 + t,
                    1 => 3.0,
                    _ => (t * f64::from(k)).sin() + f64::from(k),
                })
                .collect();
            ring.push(&record);
            pushed.extend(record);
        }
        let bits = |values: &[f64]| values.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&records(&ring)), bits(&pushed));
        let mut out = Vec::new();
        let from_s = 1.7e9 + 3.0;
        let until_s = 1.7e9 + 4.0;
        let copied = ring.copy_range(from_s, until_s, &mut out);
        let expected: Vec<f64> = pushed
            .chunks_exact(27)
            .filter(|r| (from_s..=until_s).contains(&r[0]))
            .flatten()
            .copied()
            .collect();
        assert_eq!(copied * 27, expected.len());
        assert_eq!(bits(&out), bits(&expected));
    }

    #[test]
    fn short_records_are_padded_and_long_ones_cut() {
        let mut ring = RecordRing::new(3, 10.0, 1 << 20, spool());
        ring.push(&[1.0]);
        ring.push(&[2.0, 3.0, 4.0, 5.0]);
        let held = records(&ring);
        assert_eq!(held[0], 1.0);
        assert!(held[1].is_nan() && held[2].is_nan());
        assert_eq!(&held[3..], [2.0, 3.0, 4.0]);
    }
}
