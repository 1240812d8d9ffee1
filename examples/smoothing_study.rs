//! Image matching on the library's synthetic rooms rendered at several lens blurs and sensor
//! noises, for several smoothings: the figures behind the smoothing chosen per image
//! (docs/ACCURACY.md, "Smoothing chosen from the image").
//!
//!     cargo run --release --example smoothing_study [-- SEEDS BLURS SMOOTHINGS NOISE]
//!
//! e.g. `-- 12 0.7 -1,1.0 5`: 12 rooms rendered with 0.7 px of blur and noise of 5 grey
//! levels, matched with the smoothing chosen per image (`-1`) and with 1 px. Strict 3D scoring
//! (the shared scorer's criterion), pooled over the seeds.

use trinocular::extract;
use trinocular::matching::MatchParams;
use trinocular::pipeline::{self, Input, Options};
use trinocular::synth::{render_triplet, score_capture, standard_capture, Defects, RenderParams};

fn list(arg: Option<&String>, default: &[f64]) -> Vec<f64> {
    arg.map(|s| {
        s.split(',')
            .map(|x| x.parse().expect("a comma-separated list of numbers"))
            .collect()
    })
    .unwrap_or_else(|| default.to_vec())
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seeds: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(4);
    let blurs = list(args.get(2), &[0.7]);
    let smoothings = list(args.get(3), &[-1.0, 1.0]);
    let noise: f64 = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(2.0);
    for &blur in &blurs {
        for &smoothing in &smoothings {
            let (mut n, mut wrong, mut eligible, mut covered) = (0, 0, 0.0, 0.0);
            for seed in 1..=seeds {
                let (scene, rig, obs) = standard_capture(seed, Defects::clean(), false);
                let render = RenderParams {
                    blur_sigma_px: blur,
                    noise_sigma: noise,
                    ..RenderParams::default()
                };
                let images = render_triplet(&scene, &rig, &render, seed);
                let params = extract::Params {
                    smoothing_sigma_px: (smoothing >= 0.0).then_some(smoothing),
                    ..extract::Params::default()
                };
                let result = pipeline::run(
                    &rig,
                    Input::Images([&images[0], &images[1], &images[2]]),
                    &Options {
                        params: MatchParams::default(),
                        extract: params.clone(),
                        ..Options::default()
                    },
                )
                .expect("a rendered room matches");
                let s = score_capture(&result.output.segments(), &obs, &rig);
                n += s.n_segments;
                wrong += s.n_segments - s.n_correct;
                eligible += s.eligible_length_m;
                covered += s.covered_length_m;
            }
            let name = if smoothing < 0.0 {
                "chosen".to_string()
            } else {
                format!("{smoothing:.2}")
            };
            println!(
                "blur {blur:.2} noise {noise:.1} smoothing {name:>6}: {n:5} segments, {wrong:4} wrong ({:.2}%), completeness {:.1}%",
                100.0 * wrong as f64 / n.max(1) as f64,
                100.0 * covered / eligible.max(1e-12)
            );
        }
    }
}
