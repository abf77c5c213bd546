//! Fuzz target `urdf`: generated inputs through the decoder's check
//! (`armtwin_fuzz_checks::urdf`, which says what it keeps); `cargo test` runs the same check on
//! this target's committed corpus.
#![no_main]

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| armtwin_fuzz_checks::urdf::check(bytes));
