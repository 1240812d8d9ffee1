//! Extraction and whole-pipeline benchmarks on rendered rooms (criterion, release):
//! - `extract/512`, `extract/1024`: one image, one thread, segments out (all stages);
//! - `stage/...`: the stages of `extract/512` alone (`edge_points` is `gradient` and `nms`
//!   fused into one pass, as `extract` runs them);
//! - `peer_lsdetect/512`, `peer_lsdetect/1024`: the pure-Rust LSD (`lsdetect`) on the same
//!   images, one thread — a peer measured in the same run;
//! - `images/512`, `images/1024`: a whole image triplet (extract ×3, match, reconstruct) on a
//!   pool of 1 and 2 threads.
//!
//! The 1024 images are the same room seen by the same rig with every focal length and
//! principal point doubled (same field of view, four times the pixels).
//!
//!     cargo bench --bench extract
//!
//! OpenCV's LSD and GaussianBlur + Canny are the other peers: `tools/bench_extract.sh` runs
//! them (Python) on the very images this bench uses, written by `--example bench_images`.

use criterion::{criterion_group, criterion_main, BatchSize, BenchmarkId, Criterion, Throughput};
use trinocular::extract::{self, edges, gradient, GreyImage, Params};
use trinocular::geometry::Rig;
use trinocular::pipeline::{self, Input, Options};
use trinocular::synth::{bench_capture, render_triplet, RenderParams};

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
}

fn captures() -> Vec<(u32, Rig, [GreyImage; 3])> {
    [1u32, 2]
        .into_iter()
        .map(|scale| {
            let (scene, rig) = bench_capture(1, f64::from(scale));
            let images = render_triplet(&scene, &rig, &RenderParams::default(), 1);
            (512 * scale, rig, images)
        })
        .collect()
}

fn bench_extract(c: &mut Criterion) {
    let params = Params::default();
    let one = pool(1);
    let all = captures();
    let mut group = c.benchmark_group("extract");
    for (size, rig, images) in &all {
        group.throughput(Throughput::Elements(u64::from(size * size)));
        group.bench_with_input(BenchmarkId::from_parameter(size), size, |b, _| {
            one.install(|| b.iter(|| extract::extract(&images[0], Some(rig.camera(0)), &params)))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("peer_lsdetect");
    for (size, _, images) in &all {
        let bytes = images[0].to_u8();
        let (w, h) = (images[0].width() as usize, images[0].height() as usize);
        group.throughput(Throughput::Elements(u64::from(size * size)));
        group.bench_with_input(BenchmarkId::from_parameter(size), size, |b, _| {
            one.install(|| b.iter(|| lsdetect::detect(&bytes[..], w, h, lsdetect::SCALE)))
        });
    }
    group.finish();

    let (_, _, images) = &all[0];
    let img = &images[0];
    let (w, h) = (img.width() as usize, img.height() as usize);
    // The stages at the smoothing the default chooses for this image.
    let sigma = params
        .smoothing_sigma_px
        .unwrap_or_else(|| extract::scale::choose(img, params.gradient_high).smoothing_sigma_px);
    let smoothed = gradient::smooth(img, sigma);
    let grad = gradient::gradient(&smoothed, w, h);
    let candidates = edges::non_maximum_suppression(&grad, params.gradient_low as f32);
    let map = edges::hysteresis(candidates.clone(), params.gradient_high as f32);
    let mut group = c.benchmark_group("stage");
    group.bench_function("choose_smoothing", |b| {
        b.iter(|| extract::scale::choose(img, params.gradient_high))
    });
    group.bench_function("smooth", |b| b.iter(|| gradient::smooth(img, sigma)));
    group.bench_function("gradient", |b| {
        b.iter(|| gradient::gradient(&smoothed, w, h))
    });
    group.bench_function("nms", |b| {
        b.iter(|| edges::non_maximum_suppression(&grad, params.gradient_low as f32))
    });
    group.bench_function("edge_points", |b| {
        b.iter(|| edges::edge_points(&smoothed, w, h, params.gradient_low as f32))
    });
    group.bench_function("hysteresis", |b| {
        b.iter_batched(
            || candidates.clone(),
            |c| edges::hysteresis(c, params.gradient_high as f32),
            BatchSize::LargeInput,
        )
    });
    group.bench_function("chain", |b| b.iter(|| extract::chain::link(&map)));
    group.finish();
}

fn bench_images(c: &mut Criterion) {
    let options = Options::default();
    let mut group = c.benchmark_group("images");
    group.sample_size(30);
    for (size, rig, images) in captures() {
        for threads in [1usize, 2] {
            let p = pool(threads);
            group.bench_function(format!("{size}/{threads}-threads"), |b| {
                p.install(|| {
                    b.iter(|| {
                        pipeline::run(
                            &rig,
                            Input::Images([&images[0], &images[1], &images[2]]),
                            &options,
                        )
                        .expect("valid")
                    })
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_extract, bench_images);
criterion_main!(benches);
