//! The attachment `rmw_zenoh` puts on every sample: zenoh-ext serialized (little-endian,
//! sequences with a LEB128 length) `i64 sequence_number, i64 source_timestamp, gid bytes`, read
//! with every length checked against the bytes there are, and written for the twin pose armtwin
//! publishes; and a robot's publisher sequence numbers as its gateway `seq`.
//!
//! Pure: bytes in, values out. The key layouts these samples arrive on are the service's
//! (`armtwin_mesh::ros2`).

use armtwin_core::pipeline::RejectCause;
use thiserror::Error;

use crate::decoded::CodecError;

/// Longest publisher gid accepted in an attachment (16 bytes since Iron, 24 in Humble).
pub const MAX_GID_BYTES: usize = 24;

/// Longest attachment read (the keyed form with a 24-byte gid takes 83 bytes).
const MAX_ATTACHMENT_BYTES: usize = 256;

/// Why an `rmw_zenoh` attachment was refused.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum AttachmentError {
    /// Longer than any attachment `rmw_zenoh` writes.
    #[error("attachment of {bytes} bytes exceeds the limit of {MAX_ATTACHMENT_BYTES} bytes")]
    TooLarge {
        /// Its size.
        bytes: usize,
    },
    /// It ends inside a field.
    #[error("attachment of {bytes} bytes ends inside '{field}'")]
    Truncated {
        /// The field.
        field: &'static str,
        /// Its size.
        bytes: usize,
    },
    /// A length that is not a LEB128 number of at most 64 bits.
    #[error("attachment '{field}': length is not a LEB128 number")]
    Length {
        /// The field.
        field: &'static str,
    },
    /// A gid longer than [`MAX_GID_BYTES`].
    #[error("attachment gid of {length} bytes exceeds {MAX_GID_BYTES} bytes")]
    GidLength {
        /// The length sent.
        length: u64,
    },
    /// The keyed form (`"sequence_number"`, …) with another key.
    #[error("attachment key '{found}' where '{expected}' belongs")]
    Key {
        /// The key expected.
        expected: &'static str,
        /// The key found (lossy UTF-8).
        found: String,
    },
    /// Bytes after the gid.
    #[error("attachment has {extra} bytes after the gid")]
    Trailing {
        /// How many.
        extra: usize,
    },
    /// A negative sequence number.
    #[error("attachment sequence number {sequence_number} is negative")]
    NegativeSequence {
        /// The value sent.
        sequence_number: i64,
    },
}

/// Every attachment that does not parse has one cause (the sample itself is still taken).
impl CodecError for AttachmentError {
    fn reject_cause(&self) -> RejectCause {
        RejectCause::Decode("attachment")
    }
}

/// An `rmw_zenoh` sample attachment: zenoh-ext serialized (little-endian, sequences with a
/// LEB128 length) `i64 sequence_number, i64 source_timestamp, gid bytes`. Also read: the keyed
/// form of early `rmw_zenoh` releases, each value preceded by its name as a string.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    /// The publisher's sequence number (counts from 1, never negative).
    pub sequence_number: u64,
    /// When the publisher sent the sample (ns since the Unix epoch, its clock).
    pub source_timestamp_ns: i64,
    gid: [u8; MAX_GID_BYTES],
    gid_len: u8,
}

/// A bounds-checked reader of zenoh-ext serialized values.
struct Serialized<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Serialized<'a> {
    fn take(&mut self, n: usize, field: &'static str) -> Result<&'a [u8], AttachmentError> {
        let taken = self
            .at
            .checked_add(n)
            .and_then(|end| self.bytes.get(self.at..end))
            .ok_or(AttachmentError::Truncated {
                field,
                bytes: self.bytes.len(),
            })?;
        self.at += n;
        Ok(taken)
    }

    fn i64(&mut self, field: &'static str) -> Result<i64, AttachmentError> {
        let mut value = [0; 8];
        value.copy_from_slice(self.take(8, field)?);
        Ok(i64::from_le_bytes(value))
    }

    fn length(&mut self, field: &'static str) -> Result<u64, AttachmentError> {
        let mut value = 0_u64;
        for shift in (0..64).step_by(7) {
            let &[byte] = self.take(1, field)? else {
                return Err(AttachmentError::Length { field });
            };
            let bits = u64::from(byte & 0x7f);
            if shift == 63 && bits > 1 {
                return Err(AttachmentError::Length { field });
            }
            value |= bits << shift;
            if byte & 0x80 == 0 {
                return Ok(value);
            }
        }
        Err(AttachmentError::Length { field })
    }

    /// A length-prefixed byte sequence of at most `limit` bytes (`too_long` builds the error).
    fn sequence(
        &mut self,
        field: &'static str,
        limit: usize,
        too_long: impl FnOnce(u64) -> AttachmentError,
    ) -> Result<&'a [u8], AttachmentError> {
        let length = self.length(field)?;
        match usize::try_from(length) {
            Ok(length) if length <= limit => self.take(length, field),
            _ => Err(too_long(length)),
        }
    }

    /// The keyed form's name of the next value.
    fn key(&mut self, expected: &'static str) -> Result<(), AttachmentError> {
        let found = self.sequence(expected, MAX_ATTACHMENT_BYTES, |_| {
            AttachmentError::Length { field: expected }
        })?;
        if found == expected.as_bytes() {
            Ok(())
        } else {
            Err(AttachmentError::Key {
                expected,
                found: String::from_utf8_lossy(found).into_owned(),
            })
        }
    }
}

/// How the keyed form starts: the string `sequence_number` with its length.
const KEYED_PREFIX: &[u8] = b"\x0fsequence_number";

impl Attachment {
    /// Parses an attachment; every length is checked against the bytes there are.
    pub fn parse(bytes: &[u8]) -> Result<Self, AttachmentError> {
        if bytes.len() > MAX_ATTACHMENT_BYTES {
            return Err(AttachmentError::TooLarge { bytes: bytes.len() });
        }
        let mut reader = Serialized { bytes, at: 0 };
        // A keyless attachment would start so only with a sequence number near 7e18.
        let keyed = bytes.starts_with(KEYED_PREFIX);
        if keyed {
            reader.key("sequence_number")?;
        }
        let sequence_number = reader.i64("sequence_number")?;
        if keyed {
            reader.key("source_timestamp")?;
        }
        let source_timestamp_ns = reader.i64("source_timestamp")?;
        if keyed {
            reader.key("source_gid")?;
        }
        let gid_bytes = reader.sequence("source_gid", MAX_GID_BYTES, |length| {
            AttachmentError::GidLength { length }
        })?;
        if reader.at != bytes.len() {
            return Err(AttachmentError::Trailing {
                extra: bytes.len() - reader.at,
            });
        }
        let sequence_number = u64::try_from(sequence_number)
            .map_err(|_| AttachmentError::NegativeSequence { sequence_number })?;
        let mut gid = [0; MAX_GID_BYTES];
        gid[..gid_bytes.len()].copy_from_slice(gid_bytes);
        Ok(Self {
            sequence_number,
            source_timestamp_ns,
            gid,
            // At most MAX_GID_BYTES, checked above.
            gid_len: u8::try_from(gid_bytes.len()).unwrap_or(u8::MAX),
        })
    }

    /// The publisher's gid.
    #[must_use]
    pub fn gid(&self) -> &[u8] {
        &self.gid[..usize::from(self.gid_len)]
    }

    /// The source timestamp in seconds since the epoch, if it is set (positive).
    #[must_use]
    pub fn source_timestamp_s(&self) -> Option<f64> {
        (self.source_timestamp_ns > 0).then(|| {
            let ns = self.source_timestamp_ns;
            (ns / 1_000_000_000) as f64 + (ns % 1_000_000_000) as f64 * 1e-9
        })
    }
}

/// The attachment `rmw_zenoh` puts on a sample: `sequence_number`, `source_timestamp_ns`, and
/// the 16-byte `gid` with its length (33 bytes).
#[must_use]
pub fn encode_attachment(
    sequence_number: i64,
    source_timestamp_ns: i64,
    gid: &[u8; 16],
) -> Vec<u8> {
    let mut out = Vec::with_capacity(33);
    out.extend_from_slice(&sequence_number.to_le_bytes());
    out.extend_from_slice(&source_timestamp_ns.to_le_bytes());
    out.push(16);
    out.extend_from_slice(gid);
    out
}

/// One robot's `rmw_zenoh` sequence numbers as the gateway `seq` of its joint samples.
///
/// A publisher counts from 1 again when it restarts (and gets another gid): numbers from a new
/// gid carry on from the last one passed on, so a restarted driver is neither refused as going
/// back nor reported as a gap. Within one publisher the numbers pass on with their spacing, so
/// skips raise `gap` events and repeats are refused, as for a JSON gateway's `seq`.
#[derive(Debug, Clone, Default)]
pub struct PublisherSeq {
    gid: Option<([u8; MAX_GID_BYTES], u8)>,
    /// Added to the publisher's numbers.
    offset: i128,
    last: u64,
}

impl PublisherSeq {
    /// The gateway `seq` of a sample with `attachment`, and whether it came from another
    /// publisher than the previous one.
    pub fn gateway_seq(&mut self, attachment: &Attachment) -> (u64, bool) {
        let gid = (attachment.gid, attachment.gid_len);
        let sequence_number = i128::from(attachment.sequence_number);
        let changed = self.gid.is_some_and(|last| last != gid);
        if changed {
            self.offset = i128::from(self.last) + 1 - sequence_number;
        }
        self.gid = Some(gid);
        // A number far below the one a publisher switched at maps below 0: a step back.
        let seq = u64::try_from((sequence_number + self.offset).max(0)).unwrap_or(u64::MAX);
        self.last = self.last.max(seq);
        (seq, changed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leb128_lengths_are_read_and_bounded() {
        let mut reader = Serialized {
            bytes: &[0x98, 0x00],
            at: 0,
        };
        assert_eq!(reader.length("x"), Ok(24), "a non-minimal LEB128 24");
        let mut reader = Serialized {
            bytes: &[0xff; 11],
            at: 0,
        };
        assert_eq!(
            reader.length("x"),
            Err(AttachmentError::Length { field: "x" })
        );
        let mut bytes = vec![0xff; 9];
        bytes.push(0x01);
        let mut reader = Serialized {
            bytes: &bytes,
            at: 0,
        };
        assert_eq!(reader.length("x"), Ok(u64::MAX));
    }

    fn from(gid: u8, sequence_number: u64) -> Attachment {
        let mut bytes = [0; MAX_GID_BYTES];
        bytes[0] = gid;
        Attachment {
            sequence_number,
            source_timestamp_ns: 0,
            gid: bytes,
            gid_len: 16,
        }
    }

    #[test]
    fn a_publishers_numbers_pass_on_and_a_new_publisher_carries_on_from_them() {
        let mut seq = PublisherSeq::default();
        let mapped: Vec<(u64, bool)> = [from(1, 10), from(1, 11), from(1, 13), from(1, 12)]
            .iter()
            .map(|attachment| seq.gateway_seq(attachment))
            .collect();
        // As sent: the pipeline sees the skip (gap) and the step back (refused).
        assert_eq!(mapped, [(10, false), (11, false), (13, false), (12, false)]);
        // A restart: numbers from 1 again under another gid continue from the highest, 13.
        assert_eq!(seq.gateway_seq(&from(2, 1)), (14, true));
        assert_eq!(seq.gateway_seq(&from(2, 2)), (15, false));
        assert_eq!(
            seq.gateway_seq(&from(2, 4)),
            (17, false),
            "a skip stays a skip"
        );
        // A publisher that starts high, and a number far below the one it switched at.
        assert_eq!(seq.gateway_seq(&from(3, 1000)), (18, true));
        assert_eq!(
            seq.gateway_seq(&from(3, 1)),
            (0, false),
            "a step back, as such"
        );
        assert_eq!(seq.gateway_seq(&from(3, 1001)), (19, false));
    }
}
