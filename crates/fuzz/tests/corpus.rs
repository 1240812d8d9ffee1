//! Every input of the checked-in fuzz corpus (`fuzz/corpus/<target>/`), run once through the
//! target's own function: the crashes and hangs fuzzing found, and the seeds, stay fixed in
//! every `cargo test` (whose profile checks overflow and debug assertions, as the fuzz
//! build does), with no libFuzzer build. (`.ci/fuzz replay` does the same under libFuzzer;
//! `.ci/fuzz` fuzzes.)

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The inputs of one target's corpus, in name order (so a failure reproduces in order).
fn corpus(target: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../fuzz/corpus")
        .join(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|entry| entry.expect("a directory entry").path())
        .filter(|path| path.is_file())
        .collect();
    files.sort();
    files
}

/// Runs every input of `target`'s corpus.
fn replay(target: &str, run: fn(&[u8])) {
    let files = corpus(target);
    // Each target's corpus holds its hand-made seeds at least (fuzz/seedgen).
    let is_seed = |f: &PathBuf| {
        f.file_name()
            .is_some_and(|n| n.to_string_lossy().starts_with("seed-"))
    };
    assert!(
        files.iter().any(is_seed),
        "{target}: no seeds in its corpus"
    );
    run_each(target, &files, run);
}

/// Runs each file through `run`, and fails naming each one that panicked.
fn run_each(target: &str, files: &[PathBuf], run: fn(&[u8])) {
    let mut failed = Vec::new();
    let mut slowest = (Duration::ZERO, None);
    for file in files {
        let data = std::fs::read(file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let start = Instant::now();
        if catch_unwind(AssertUnwindSafe(|| run(&data))).is_err() {
            failed.push(file.display().to_string());
        }
        let took = start.elapsed();
        if took > slowest.0 {
            slowest = (took, Some(file));
        }
    }
    // What libFuzzer's -timeout would watch: printed, not asserted (a slow machine is not a
    // failure; a hang would keep this test from finishing at all).
    if let (took, Some(file)) = slowest {
        println!(
            "{target}: {} inputs, slowest {:.1} ms ({})",
            files.len(),
            took.as_secs_f64() * 1e3,
            file.display()
        );
    }
    assert!(
        failed.is_empty(),
        "{target}: {} of {} inputs panicked: {failed:#?}",
        failed.len(),
        files.len()
    );
}

#[test]
fn json_body() {
    replay("json_body", trinocular_fuzz::json_body::run);
}

#[test]
fn protobuf_body() {
    replay("protobuf_body", trinocular_fuzz::protobuf_body::run);
}

#[test]
fn image_decode() {
    replay("image_decode", trinocular_fuzz::image_decode::run);
}

#[test]
fn multipart_body() {
    replay("multipart_body", trinocular_fuzz::multipart_body::run);
}

#[test]
fn match_whole() {
    replay("match_whole", trinocular_fuzz::match_whole::run);
}

#[test]
fn session_whole() {
    replay("session_whole", trinocular_fuzz::session_whole::run);
}

/// The replay fails when a target panics: a test of the test.
#[test]
fn a_panicking_input_fails_the_replay() {
    let files = &corpus("json_body")[..2];
    let outcome = catch_unwind(|| run_each("json_body", files, |_| panic!("every input")));
    assert!(outcome.is_err());
}
