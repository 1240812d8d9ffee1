//! Extracts the `extract/SIZE` benchmark's first image and runs its whole triplet
//! (`images/SIZE`) over and over on a pool of one thread and then of two, and prints the
//! median of each extraction stage (`ExtractStats`) and of the triplet's stages: where the
//! time of an image request goes, and what the second thread takes off it.
//!
//!     cargo run --release --example profile_extract -- [SIZE] [RUNS]
//!     cargo run --release --example profile_extract -- IMAGE_FILE [RUNS]
//!
//! SIZE is 512 (default) or 1024, as in `benches/extract.rs`; an image file (a photograph)
//! gets its extraction's stages alone, without a camera (no lens to undo).

use trinocular::extract::{self, GreyImage, Params};
use trinocular::pipeline::{self, Input, Options};
use trinocular::synth::{bench_capture, render_triplet, RenderParams};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("pool")
}

/// The medians of extraction's stages, as printed.
fn stage_medians(stages: [Vec<f64>; 5]) -> String {
    let [smooth, edges, chain, polygon, total] = stages.map(median);
    format!("extract smooth {smooth:.3} edges {edges:.3} chain {chain:.3} polygons {polygon:.3} total {total:.3} ms")
}

fn extract_stages(
    image: &GreyImage,
    camera: Option<&trinocular::geometry::Camera>,
    params: &Params,
    stages: &mut [Vec<f64>; 5],
) {
    let s = extract::extract(image, camera, params).stats;
    for (v, x) in stages.iter_mut().zip([
        s.smooth_ms,
        s.edges_ms,
        s.chain_ms,
        s.polygon_ms,
        s.total_ms,
    ]) {
        v.push(x);
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let first = args.next().unwrap_or_else(|| "512".into());
    let runs: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(300);
    if first.parse::<u32>().is_err() {
        let bytes = std::fs::read(&first).expect("the image file");
        let image = extract::decode(&bytes, &extract::DecodeLimits::default()).expect("an image");
        let once = extract::extract(&image, None, &Params::default()).stats;
        println!(
            "{first}: {} edge points, {} chains, smoothing {} px",
            once.edge_points, once.chains, once.smoothing_sigma_px
        );
        for threads in [1usize, 2] {
            let pool = pool(threads);
            let mut stages: [Vec<f64>; 5] = Default::default();
            pool.install(|| {
                for _ in 0..runs {
                    extract_stages(&image, None, &Params::default(), &mut stages);
                }
            });
            println!(
                "{first} ({}x{}), {threads} thread(s), {runs} runs, medians: {}",
                image.width(),
                image.height(),
                stage_medians(stages)
            );
        }
        return;
    }
    let size: u32 = first.parse().expect("a size");
    let (scene, rig) = bench_capture(1, f64::from(size) / 512.0);
    let images = render_triplet(&scene, &rig, &RenderParams::default(), 1);
    let params = Params::default();
    let options = Options::default();
    for threads in [1usize, 2] {
        let pool = pool(threads);
        let mut stages: [Vec<f64>; 5] = Default::default();
        let mut triplet: [Vec<f64>; 7] = Default::default();
        pool.install(|| {
            for _ in 0..runs {
                extract_stages(&images[0], Some(rig.camera(0)), &params, &mut stages);
                let matched = pipeline::run(
                    &rig,
                    Input::Images([&images[0], &images[1], &images[2]]),
                    &options,
                )
                .expect("matched");
                let s = matched.output.stats;
                let extract_ms = s.extract_ms.map_or(0.0, |e| e.iter().sum());
                let matching_ms = s.rectify_ms + s.predict_ms + s.validate_ms + s.reconstruct_ms;
                for (v, x) in triplet.iter_mut().zip([
                    extract_ms,
                    s.rectify_ms,
                    s.predict_ms,
                    s.validate_ms,
                    s.reconstruct_ms,
                    matching_ms,
                    s.total_ms,
                ]) {
                    v.push(x);
                }
            }
        });
        let [extract_sum, rectify, predict, validate, reconstruct, matching, whole] =
            triplet.map(median);
        println!(
            "{size}x{size}, {threads} thread(s), {runs} runs, medians: {}; triplet: extractions' sum {extract_sum:.3}, matching {matching:.3} (rectify {rectify:.3} predict {predict:.3} validate {validate:.3} reconstruct {reconstruct:.3}), end to end {whole:.3} ms",
            stage_medians(stages)
        );
    }
}
