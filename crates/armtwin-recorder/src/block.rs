//! A closed block of a ring's records, compressed without loss: each column's values combined by XOR
//! with the value above them, their bytes regrouped by significance (every record's top byte of
//! a column, then the next byte, …) and the result through zstd at its fastest level.
//!
//! Why this shape: a column of joint angles, poses or deviations changes little from one record
//! to the next, so the XOR's high bytes are mostly zero and, grouped, become long runs zstd
//! takes for almost nothing; the low bytes stay as they are (the values are not quantised, and
//! NaN payloads and signed zeros come back bit for bit).
//!
//! Pure: bytes in, bytes out. Must not know where a block is kept ([`super::spool`]).

use std::cell::RefCell;

use thiserror::Error;

/// zstd's fastest level: a block is a few kilobytes, compressed on the thread that took the
/// sample.
const LEVEL: i32 = 1;

/// A block that does not decompress to the records it claims.
#[derive(Debug, Error)]
pub enum BlockError {
    /// zstd refused the bytes.
    #[error("a recorder block does not decompress: {0}")]
    Zstd(#[from] std::io::Error),
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
    /// A compressor and its scratch per thread: setting a zstd context up costs more than
    /// compressing one small block with it.
    static CODEC: RefCell<Codec> = RefCell::new(Codec::default());
}

#[derive(Default)]
struct Codec {
    compressor: Option<zstd::bulk::Compressor<'static>>,
    decompressor: Option<zstd::bulk::Decompressor<'static>>,
    planes: Vec<u8>,
    compressed: Vec<u8>,
}

/// Hands the compressed form of `records` (whole records of `stride` values) to `keep`; what it
/// returns. The bytes live in the thread's scratch, not in each ring.
///
/// # Errors
///
/// If zstd fails (it does not on memory it was given room in).
pub fn encode_with<R>(
    records: &[f64],
    stride: usize,
    keep: impl FnOnce(&[u8]) -> R,
) -> Result<R, BlockError> {
    CODEC.with_borrow_mut(|codec| {
        let Codec {
            compressor,
            planes,
            compressed,
            ..
        } = codec;
        to_planes(records, stride, planes);
        let compressor = match compressor {
            Some(compressor) => compressor,
            None => compressor.insert(zstd::bulk::Compressor::new(LEVEL)?),
        };
        compressed.clear();
        compressed.resize(max_encoded_bytes(planes.len()), 0);
        let written = compressor.compress_to_buffer(planes, compressed.as_mut_slice())?;
        Ok(keep(&compressed[..written]))
    })
}

/// The most bytes [`encode_with`] hands over for `raw_bytes` of records.
#[must_use]
pub fn max_encoded_bytes(raw_bytes: usize) -> usize {
    zstd::zstd_safe::compress_bound(raw_bytes)
}

/// Appends the `count` records of `stride` values that `bytes` (from [`encode`]) hold to `out`.
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
    CODEC.with_borrow_mut(|codec| {
        let Codec {
            decompressor,
            planes,
            ..
        } = codec;
        let expected = count * stride * size_of::<f64>();
        let decompressor = match decompressor {
            Some(decompressor) => decompressor,
            None => decompressor.insert(zstd::bulk::Decompressor::new()?),
        };
        planes.clear();
        planes.resize(expected, 0);
        let got = decompressor.decompress_to_buffer(bytes, planes.as_mut_slice())?;
        if got != expected {
            return Err(BlockError::Size { expected, got });
        }
        from_planes(planes, count, stride, out);
        Ok(())
    })
}

/// `records`' columns combined by XOR down and their bytes grouped by significance, into `planes`.
fn to_planes(records: &[f64], stride: usize, planes: &mut Vec<u8>) {
    let count = records.len() / stride;
    planes.clear();
    planes.resize(count * stride * size_of::<f64>(), 0);
    for column in 0..stride {
        let mut above = 0_u64;
        for row in 0..count {
            let bits = records[row * stride + column].to_bits();
            let xored = (bits ^ above).to_be_bytes();
            above = bits;
            for (byte, value) in xored.into_iter().enumerate() {
                planes[(column * size_of::<f64>() + byte) * count + row] = value;
            }
        }
    }
}

/// The inverse of [`to_planes`], appended to `out`.
fn from_planes(planes: &[u8], count: usize, stride: usize, out: &mut Vec<f64>) {
    let start = out.len();
    out.resize(start + count * stride, 0.0);
    let records = &mut out[start..];
    for column in 0..stride {
        let mut above = 0_u64;
        for row in 0..count {
            let mut xored = [0_u8; size_of::<f64>()];
            for (byte, value) in xored.iter_mut().enumerate() {
                *value = planes[(column * size_of::<f64>() + byte) * count + row];
            }
            let bits = u64::from_be_bytes(xored) ^ above;
            above = bits;
            records[row * stride + column] = f64::from_bits(bits);
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
        assert!(out.is_empty());
    }
}
