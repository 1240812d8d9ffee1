//! Matching benchmarks (criterion, release):
//! - `match/600` and `match/10000`: one triplet with that many segments per image (20%
//!   clutter, 0.3 px endpoint noise) matched, validated and reconstructed end to end, on one
//!   thread; throughput in segments per image, so time per segment compares across sizes;
//! - `window/600` and `window/10000`: the same with a depth range of 1.4–15 m, whose
//!   disparity window (≈ 130 px) fits the 512-px image: at the default 0.3 m the window
//!   (≈ 600 px) is wider than the 600-segment image and clipped by it, so part of the growth of
//!   `match/10000` over `match/600` is the larger window searched, not the number of segments;
//! - `threads/N`: the 10,000-segment triplet on a rayon pool of N threads;
//! - `room`: the standard synthetic room on one thread, its lists with `Defects::noisy` (0.5 px
//!   at every endpoint: the generator's "realistic" defects when this figure was first
//!   measured, kept so that it compares across versions; the name stays `room/realistic`).
//!
//! Per-stage times of one match are in its `MatchStats` (`rectify_ms`, `predict_ms`,
//! `validate_ms`, `reconstruct_ms`).
//!
//!     cargo bench --bench matching

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use trinocular::matching::MatchParams;
use trinocular::pipeline::{self, Input, Options};
use trinocular::synth::{scattered_capture, standard_capture, Defects};

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
}

/// One group: the 600- and 10,000-segment triplets on one thread with `params`.
fn bench_size_group(c: &mut Criterion, name: &str, params: &MatchParams) {
    let one = pool(1);
    let mut group = c.benchmark_group(name);
    for n in [600usize, 10_000] {
        let (rig, lists) = scattered_capture(n, 0.3, 0.2, 1);
        group.throughput(Throughput::Elements(n as u64));
        if n > 1000 {
            group.sample_size(20);
        }
        let options = Options::with(params.clone());
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            one.install(|| {
                b.iter(|| pipeline::run(&rig, Input::lists(&lists), &options).expect("valid"))
            })
        });
    }
    group.finish();
}

fn bench_sizes(c: &mut Criterion) {
    bench_size_group(c, "match", &MatchParams::default());
}

fn bench_window(c: &mut Criterion) {
    let params = MatchParams {
        depth_min_m: 1.4,
        ..MatchParams::default()
    };
    bench_size_group(c, "window", &params);
}

fn bench_threads(c: &mut Criterion) {
    let options = Options::default();
    let (rig, lists) = scattered_capture(10_000, 0.3, 0.2, 1);
    let mut group = c.benchmark_group("threads");
    group.sample_size(20);
    for threads in [1usize, 2] {
        let p = pool(threads);
        group.bench_with_input(BenchmarkId::from_parameter(threads), &threads, |b, _| {
            p.install(|| {
                b.iter(|| pipeline::run(&rig, Input::lists(&lists), &options).expect("valid"))
            })
        });
    }
    group.finish();
}

fn bench_room(c: &mut Criterion) {
    let options = Options::default();
    let (_, rig, obs) = standard_capture(1, Defects::noisy(), false);
    let one = pool(1);
    let n = obs.lists[0].segments.len() as u64;
    let mut group = c.benchmark_group("room");
    group.throughput(Throughput::Elements(n));
    group.bench_function("realistic", |b| {
        one.install(|| {
            b.iter(|| pipeline::run(&rig, Input::lists(&obs.lists), &options).expect("valid"))
        })
    });
    group.finish();
}

criterion_group!(
    benches,
    bench_sizes,
    bench_window,
    bench_threads,
    bench_room
);
criterion_main!(benches);
