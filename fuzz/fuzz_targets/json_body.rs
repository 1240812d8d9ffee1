//! libFuzzer's entry point for `trinocular_fuzz::json_body` (crates/fuzz/src/json_body.rs says what it checks).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| trinocular_fuzz::json_body::run(data));
