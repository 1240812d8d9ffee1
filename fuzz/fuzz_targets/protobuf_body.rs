//! libFuzzer's entry point for `trinocular_fuzz::protobuf_body` (crates/fuzz/src/protobuf_body.rs says what it checks).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| trinocular_fuzz::protobuf_body::run(data));
