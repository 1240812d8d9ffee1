//! libFuzzer's entry point for `trinocular_fuzz::session_whole` (crates/fuzz/src/session_whole.rs
//! says what it checks). The bytes go in as they come and are read as a structured input
//! there, so that `cargo test`'s corpus replay runs exactly what libFuzzer runs.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| trinocular_fuzz::session_whole::run(data));
