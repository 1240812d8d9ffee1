//! How many ground-truth edges the extractor finds on rendered rooms, with precise ends: the
//! figure quoted in the README.
//!
//!     cargo run --release --example extract_recall [-- SEEDS]
//!
//! Ground truth: per camera, the exact image segments of the visible parts of the room's
//! edges (cut where the contrast changes sign or fades), at least 20 px long and of edges with
//! at least 10 grey levels of contrast. Found: an extracted segment has both endpoints within
//! the tolerance of the ground truth's, in the same order (so the same contrast orientation).

use trinocular::extract::{extract, Params};
use trinocular::synth::{edge_recall, render_image, standard_capture, Defects, RenderParams};

fn main() {
    let seeds: u64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(3);
    let tolerances = [1.0, 1.5, 3.0];
    let mut found = [0usize; 3];
    let mut total = 0;
    for seed in 1..=seeds {
        let (scene, rig, obs) = standard_capture(seed, Defects::clean(), false);
        for cam in 0..3 {
            let camera = &rig.cameras()[cam];
            let img = render_image(
                &scene,
                camera,
                &RenderParams::default(),
                seed * 10 + cam as u64,
            );
            let e = extract(&img, Some(camera), &Params::default());
            for (k, &tol) in tolerances.iter().enumerate() {
                let (f, t) = edge_recall(&e.segments, &obs, cam, 20.0, 10.0, tol);
                found[k] += f;
                if k == 0 {
                    total += t;
                }
            }
        }
    }
    println!("{seeds} rooms x 3 cameras, {total} ground-truth segments");
    for (k, tol) in tolerances.iter().enumerate() {
        println!(
            "  ends within {tol} px: {:.3}",
            found[k] as f64 / total as f64
        );
    }
}
