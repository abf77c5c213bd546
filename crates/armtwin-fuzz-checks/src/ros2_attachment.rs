//! The attachment `rmw_zenoh` puts on each sample: a parsed attachment written back (in the
//! keyless form) must parse to the same value; a refusal is an error, never a panic.

use crate::invariants::{assert_stamp, push_leb128};
use armtwin_codec::ros2_attachment::{Attachment, PublisherSeq};

/// Runs every check of this decoder on one input; panics on a broken invariant.
pub fn check(bytes: &[u8]) {
    let Ok(attachment) = Attachment::parse(bytes) else {
        return;
    };
    assert_stamp(attachment.source_timestamp_s());
    let sequence_number = i64::try_from(attachment.sequence_number).expect("parsed from an i64");
    let mut again = Vec::new();
    again.extend_from_slice(&sequence_number.to_le_bytes());
    again.extend_from_slice(&attachment.source_timestamp_ns.to_le_bytes());
    push_leb128(&mut again, attachment.gid().len() as u64);
    again.extend_from_slice(attachment.gid());
    // The keyless form of a sequence number and stamp that spell `\x0fsequence_number` reads as
    // the keyed form: the format's own ambiguity, which the parser documents.
    if !again.starts_with(b"\x0fsequence_number") {
        assert_eq!(Attachment::parse(&again), Ok(attachment));
    }
    // The mapping to a gateway `seq` across a publisher's restart must not overflow.
    let mut seq = PublisherSeq::default();
    seq.gateway_seq(&attachment);
    let mut other = again;
    let last = other.len() - 1;
    if !attachment.gid().is_empty() {
        other[last] ^= 0xff;
        if let Ok(restarted) = Attachment::parse(&other) {
            seq.gateway_seq(&restarted);
        }
    }
    seq.gateway_seq(&attachment);
}
