//! libFuzzer's entry point for `trinocular_fuzz::image_decode` (crates/fuzz/src/image_decode.rs says what it checks).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| trinocular_fuzz::image_decode::run(data));
