//! A closed block of a ring's records, compressed without loss: each column's values combined by XOR
//! with the value above them, their bytes regrouped by significance (every record's top byte of
//! a column, then the next byte, …) and the result through LZ4.
//!
//! Why this shape: a column of joint angles, poses or deviations changes little from one record
//! to the next, so the XOR's high bytes are mostly zero and, grouped, become long runs that LZ4
//! takes for a few bytes; the low bytes stay as they are (the values are not quantised, and NaN
//! payloads and signed zeros come back bit for bit). LZ4 rather than zstd: on blocks this small,
//! zstd spends most of its time building entropy tables per block, on the thread that took the
//! sample (crates/armtwin-recorder/benches/README.md has the figures of both).
//!
//! Pure: bytes in, bytes out. Must not know where a block is kept ([`super::spool`]).

use std::cell::RefCell;

use thiserror::Error;

/// A block that does not decompress to the records it claims.
#[derive(Debug, Error)]
pub enum BlockError {
    /// LZ4 refused the bytes.
    #[error("a recorder block does not decompress: {0}")]
    Decompress(#[from] lz4_flex::block::DecompressError),
    /// LZ4 found no room for the bytes (it is given the most they can take).
    #[error("a recorder block does not compress: {0}")]
    Compress(#[from] lz4_flex::block::CompressError),
    /// It decompressed to another size.
    #[error("a recorder block holds {got} bytes, not the {expected} of its records")]
    Size {
        /// Bytes of its records.
        expected: usize,
        /// Bytes it held.
        got: usize,
    },
}

thread_local! {
    /// The scratch of a block's bytes per thread, not per ring.
    static SCRATCH: RefCell<Scratch> = RefCell::new(Scratch::default());
}

#[derive(Default)]
struct Scratch {
    planes: Vec<u8>,
    compressed: Vec<u8>,
}

/// Hands the compressed form of `records` (whole records of `stride` values) to `keep`; what it
/// returns. The bytes live in the thread's scratch, not in each ring.
///
/// # Errors
///
/// If LZ4 finds no room (it does not: it is given the most it can need).
pub fn encode_with<R>(
    records: &[f64],
    stride: usize,
    keep: impl FnOnce(&[u8]) -> R,
) -> Result<R, BlockError> {
    SCRATCH.with_borrow_mut(|Scratch { planes, compressed }| {
        to_planes(records, stride, planes);
        compressed.clear();
        compressed.resize(max_encoded_bytes(planes.len()), 0);
        let written = lz4_flex::block::compress_into(planes, compressed)?;
        Ok(keep(&compressed[..written]))
    })
}

/// The most bytes [`encode_with`] hands over for `raw_bytes` of records.
#[must_use]
pub fn max_encoded_bytes(raw_bytes: usize) -> usize {
    lz4_flex::block::get_maximum_output_size(raw_bytes)
}

/// Appends the `count` records of `stride` values that `bytes` (from [`encode_with`]) hold to
/// `out`.
///
/// # Errors
///
/// If `bytes` are not such a block.
pub fn decode(
    bytes: &[u8],
    count: usize,
    stride: usize,
    out: &mut Vec<f64>,
) -> Result<(), BlockError> {
    SCRATCH.with_borrow_mut(|Scratch { planes, .. }| {
        let expected = count * stride * size_of::<f64>();
        planes.clear();
        planes.resize(expected, 0);
        let got = lz4_flex::block::decompress_into(bytes, planes)?;
        if got != expected {
            return Err(BlockError::Size { expected, got });
        }
        from_planes(planes, count, stride, out);
        Ok(())
    })
}

/// `records`' columns combined by XOR down and their bytes grouped by significance, into
/// `planes`. Each plane is written in order (a column's values read once): the transposition is
/// half of a block's cost otherwise.
fn to_planes(records: &[f64], stride: usize, planes: &mut Vec<u8>) {
    let count = records.len() / stride;
    planes.clear();
    planes.resize(count * stride * size_of::<f64>(), 0);
    if count == 0 {
        return;
    }
    let mut xored = vec![0_u64; count];
    for (column, column_planes) in planes
        .chunks_exact_mut(count * size_of::<f64>())
        .enumerate()
    {
        let mut above = 0_u64;
        for (row, x) in xored.iter_mut().enumerate() {
            let bits = records[row * stride + column].to_bits();
            *x = bits ^ above;
            above = bits;
        }
        for (byte, plane) in column_planes.chunks_exact_mut(count).enumerate() {
            let shift = 8 * (size_of::<f64>() - 1 - byte);
            for (value, x) in plane.iter_mut().zip(&xored) {
                *value = (x >> shift) as u8;
            }
        }
    }
}

/// The inverse of [`to_planes`], appended to `out`.
fn from_planes(planes: &[u8], count: usize, stride: usize, out: &mut Vec<f64>) {
    let start = out.len();
    out.resize(start + count * stride, 0.0);
    let records = &mut out[start..];
    if count == 0 {
        return;
    }
    let mut xored = vec![0_u64; count];
    for (column, column_planes) in planes.chunks_exact(count * size_of::<f64>()).enumerate() {
        xored.fill(0);
        for plane in column_planes.chunks_exact(count) {
            for (x, &value) in xored.iter_mut().zip(plane) {
                *x = (*x << 8) | u64::from(value);
            }
        }
        let mut above = 0_u64;
        for (row, x) in xored.iter().enumerate() {
            above ^= x;
            records[row * stride + column] = f64::from_bits(above);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{decode, encode_with};

    fn encode(records: &[f64], stride: usize, out: &mut Vec<u8>) {
        encode_with(records, stride, |bytes| out.extend_from_slice(bytes)).expect("encode");
    }

    fn round_trip(records: &[f64], stride: usize) -> (Vec<f64>, usize) {
        let mut bytes = vec![7_u8];
        encode(records, stride, &mut bytes);
        let mut out = vec![1.5];
        decode(&bytes[1..], records.len() / stride, stride, &mut out).expect("decode");
        (out[1..].to_vec(), bytes.len() - 1)
    }

    #[test]
    fn records_come_back_bit_for_bit_after_what_was_there() {
        let mut records = Vec::new();
        for i in 0..40_u32 {
            let t = f64::from(i) * 0.002;
            records.extend([
                1.7e9 + t,
                t.sin(),
                -0.0,
                f64::NAN,
                f64::from_bits(0x7ff8_dead_beef_0001),
            ]);
        }
        records[7] = f64::INFINITY;
        let (back, compressed) = round_trip(&records, 5);
        let bits = |values: &[f64]| values.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&back), bits(&records));
        assert!(compressed < records.len() * 8, "{compressed} bytes");
    }

    #[test]
    fn a_block_of_other_records_or_garbage_is_an_error() {
        let mut bytes = Vec::new();
        encode(&[1.0, 2.0, 3.0, 4.0], 2, &mut bytes);
        let mut out = Vec::new();
        assert!(decode(&bytes, 3, 2, &mut out).is_err());
        assert!(decode(&[1, 2, 3], 2, 2, &mut out).is_err());
        let mut empty = Vec::new();
        encode(&[], 3, &mut empty);
        assert!(decode(&empty, 0, 3, &mut out).is_ok());
        assert!(out.is_empty());
    }
}
