//! A UR controller's RTDE byte stream (`rtde`): cut into frames at any chunk size and fed through
//! the handshake. Every refusal carries a known cause, the splitter never holds more than its
//! bound, and a data package decoded under the agreed recipe encodes back to the same bytes.

use crate::invariants::assert_kind;
use armtwin_codec::rtde::frame::FrameSplitter;
use armtwin_codec::rtde::handshake::{Handshake, Progress};
use armtwin_codec::rtde::recipe::{self, Recipe};

const KINDS: &[&str] = &[
    "frame_size",
    "unexpected_package",
    "payload_size",
    "truncated",
    "not_utf8",
    "unknown_type",
    "type_mismatch",
    "variable_count",
    "recipe_id",
    "setup_refused",
    "required_variable",
    "no_protocol",
    "refused",
];

/// Runs every check of this decoder on one input; panics on a broken invariant.
pub fn check(input: &[u8]) {
    // The first byte picks the read size, as a socket hands over whatever has arrived.
    let Some((&chunk, stream)) = input.split_first() else {
        return;
    };
    let chunk = usize::from(chunk).max(1);
    let Ok((mut handshake, _)) = Handshake::new(500.0) else {
        panic!("500 Hz is a valid frequency");
    };
    let mut splitter = FrameSplitter::new();
    let mut recipe: Option<Recipe> = None;
    for bytes in stream.chunks(chunk) {
        assert!(
            splitter.extend(bytes).is_ok(),
            "the frames were taken, so the splitter cannot overflow"
        );
        assert!(splitter.pending_bytes() <= FrameSplitter::LIMIT);
        loop {
            let frame = match splitter.next_frame() {
                Ok(Some(frame)) => frame,
                Ok(None) => break,
                Err(error) => {
                    assert_kind(error.kind(), KINDS);
                    // A broken header ends the connection.
                    return;
                }
            };
            match handshake.on_frame(frame) {
                Ok(Progress::Started(started)) => {
                    assert!(started.recipe.has("timestamp") && started.recipe.has("actual_q"));
                    recipe = Some(started.recipe);
                }
                Ok(Progress::Sample(sample)) => {
                    let Some(recipe) = &recipe else {
                        panic!("a sample before the start");
                    };
                    assert_eq!(recipe::encode(recipe, &sample), frame.payload);
                }
                Ok(Progress::Send(_) | Progress::Text(_)) => {}
                Err(error) => assert_kind(error.kind(), KINDS),
            }
        }
    }
}
