//! libFuzzer's entry point for `trinocular_fuzz::multipart_body` (crates/fuzz/src/multipart_body.rs
//! says what it checks). The service starts before the first input, outside its timing.
#![no_main]

libfuzzer_sys::fuzz_target!(init: { trinocular_fuzz::Http::get(); }, |data: &[u8]| {
    trinocular_fuzz::multipart_body::run(data)
});
