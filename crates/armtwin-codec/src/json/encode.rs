//! Encoding armtwin's JSON messages: [`to_json_bytes`] for any of them through `serde_json`, and
//! a fixed-layout object writer for the messages armtwin sends most often (twin pose and
//! deviation once per sample, metrics periodically per robot): keys known at compile time,
//! numbers in the shortest round-trip form, written straight into one buffer. It writes the bytes
//! `serde_json` writes for the same fields in the same order (the crate's `json` tests compare
//! them byte for byte), at less cost (`benches/ingest.rs` measures both): no serialiser state machine,
//! no escaping scan of constant keys, no small copies per token.
//!
//! Pure: bytes in memory, nothing else.

use serde::Serialize;

/// Serialises an output message to JSON bytes.
///
/// # Panics
///
/// If `value`'s `Serialize` implementation fails, which armtwin's message types never do (plain
/// structs, string keys, no custom implementations).
#[must_use]
#[allow(
    clippy::expect_used,
    reason = "serialising armtwin's plain message structs into a Vec cannot fail"
)]
pub fn to_json_bytes<T: Serialize>(value: &T) -> Vec<u8> {
    // Room for most messages at once: growing from serde_json's small default copied each
    // message twice.
    let mut bytes = Vec::with_capacity(512);
    serde_json::to_writer(&mut bytes, value).expect("armtwin's wire messages always serialise");
    bytes
}

/// One JSON object being written; [`Self::finish`] closes it.
pub(crate) struct FlatObject {
    bytes: Vec<u8>,
    empty: bool,
}

impl FlatObject {
    /// An object with room for `capacity` bytes before it grows.
    pub(crate) fn with_capacity(capacity: usize) -> Self {
        let mut bytes = Vec::with_capacity(capacity);
        bytes.push(b'{');
        Self { bytes, empty: true }
    }

    /// `"key":`, after a comma unless it is the first field. `key` is a constant that needs no
    /// escaping.
    fn key(&mut self, key: &'static str) {
        debug_assert!(!needs_escaping(key), "constant key {key:?}");
        if !self.empty {
            self.bytes.push(b',');
        }
        self.empty = false;
        self.bytes.push(b'"');
        self.bytes.extend_from_slice(key.as_bytes());
        self.bytes.extend_from_slice(b"\":");
    }

    /// A string field, escaped as `serde_json` escapes it.
    pub(crate) fn string(&mut self, key: &'static str, value: &str) {
        self.key(key);
        if needs_escaping(value) {
            // Writing to a `Vec` cannot fail, nor can serialising a `str`.
            let _ = serde_json::to_writer(&mut self.bytes, value);
        } else {
            self.bytes.push(b'"');
            self.bytes.extend_from_slice(value.as_bytes());
            self.bytes.push(b'"');
        }
    }

    /// A number field in shortest round-trip form; a non-finite value is `null`, as `serde_json`
    /// writes it.
    pub(crate) fn number(&mut self, key: &'static str, value: f64) {
        self.key(key);
        if value.is_finite() {
            let mut buffer = zmij::Buffer::new();
            self.bytes
                .extend_from_slice(buffer.format_finite(value).as_bytes());
        } else {
            self.bytes.extend_from_slice(b"null");
        }
    }

    /// An unsigned integer field.
    pub(crate) fn unsigned(&mut self, key: &'static str, value: u64) {
        self.key(key);
        let mut buffer = itoa::Buffer::new();
        self.bytes
            .extend_from_slice(buffer.format(value).as_bytes());
    }

    /// A field of any JSON value, written by `serde_json`.
    pub(crate) fn value(&mut self, key: &'static str, value: &serde_json::Value) {
        self.key(key);
        // Writing to a `Vec` cannot fail, nor can serialising a `Value`.
        let _ = serde_json::to_writer(&mut self.bytes, value);
    }

    /// Opens an object field: the following fields are its members until [`Self::close`].
    pub(crate) fn open(&mut self, key: &'static str) {
        self.key(key);
        self.bytes.push(b'{');
        self.empty = true;
    }

    /// Closes the innermost object opened by [`Self::open`].
    pub(crate) fn close(&mut self) {
        self.bytes.push(b'}');
        self.empty = false;
    }

    /// The object's bytes.
    pub(crate) fn finish(mut self) -> Vec<u8> {
        self.bytes.push(b'}');
        self.bytes
    }
}

/// Whether JSON needs an escape somewhere in `text`: a quote, a backslash or a control character
/// (what `serde_json` escapes; it writes everything else, non-ASCII included, as is).
fn needs_escaping(text: &str) -> bool {
    text.bytes()
        .any(|byte| byte < 0x20 || byte == b'"' || byte == b'\\')
}
