//! The codecs' tests, one binary: each module one codec or concern.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]
#![allow(clippy::float_cmp, reason = "decoded values are copied, not computed")]

mod causes;
mod json;
mod json_messages;
mod json_paths;
mod ros2_cdr;
mod zser;
