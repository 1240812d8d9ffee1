//! Accuracy of every rig shape of `synth::RigShape` on the standard room: 3D error and
//! completeness (strict scorer, as `tests/integration/rigs.rs`) of the default answer,
//! rendered images in, pooled over seeds.
//!
//!     cargo run --release --example rigs [-- SEEDS] [lists] [all] [wrong] [third-gain=G]
//!         [neighbour-radius=R] [min-length=L] [min-segment=S] [gradient-ratio=G]
//!         [only=NAME]
//!
//! `wrong` lists every wrong 3D segment of the images' answers as the `resolutions` example
//! does; `only=NAME` runs the shapes whose name starts with NAME (`only=third`).
//!
//! `third-gain=G` scales the third camera's image (signal and noise) by G, as a camera with an
//! exposure of its own would see the scene (docs/RIGS.md, "Cameras with their own exposure").

#[path = "common/wrong.rs"]
mod wrong;

use trinocular::extract::Params;
use trinocular::matching::MatchParams;
use trinocular::pipeline::{self, Input, Options};
use trinocular::synth::{
    render_triplet, shaped_capture, with_exposure, Defects, Pooled, RenderParams, RigShape,
};

/// The value of the command-line argument `PREFIXvalue`, if one is given and parses.
fn option<T: std::str::FromStr>(prefix: &str) -> Option<T> {
    std::env::args().find_map(|a| a.strip_prefix(prefix).and_then(|v| v.parse().ok()))
}

fn main() {
    let seeds: u64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(4);
    // `lists`: the exact projections as segment lists, every match (the geometry alone).
    let lists = std::env::args().any(|a| a == "lists");
    // `all`: every match of the images, not only what meets the accuracy gate.
    let all = std::env::args().any(|a| a == "all");
    let list_wrong = std::env::args().any(|a| a == "wrong");
    let only: Option<String> = option("only=");
    let third_gain: f32 = option("third-gain=").unwrap_or(1.0);
    let defaults = MatchParams::default();
    // Validation's vertex radius, the shortest segment matched, the largest ratio of a
    // triplet's gradients (`MatchParams`), the shortest segment extraction reports.
    let neighbour_radius_px = option("neighbour-radius=").unwrap_or(defaults.neighbour_radius_px);
    let min_length_px = option("min-length=").unwrap_or(defaults.min_length_px);
    let gradient_ratio_max = option("gradient-ratio=").unwrap_or(defaults.gradient_ratio_max);
    let min_segment_px = option("min-segment=").unwrap_or(Params::default().min_segment_px);
    println!(
        "| rig | segments | 3D error | dir / near / far | completeness | per-pair | epipolar angle |\n|---|---|---|---|---|---|---|"
    );
    for shape in RigShape::ALL {
        if only
            .as_ref()
            .is_some_and(|o| !shape.name().starts_with(o.as_str()))
        {
            continue;
        }
        let mut pooled = Pooled::default();
        let (mut per_pair, mut angle) = (false, 0.0);
        for seed in 1..=seeds {
            let (scene, rig, obs) = shaped_capture(seed, Defects::clean(), shape);
            let (out, extracted) = if lists {
                let params = MatchParams {
                    include_uncertain: true,
                    // Exact lines: no detector pushed them.
                    list_push_px: 0.0,
                    neighbour_radius_px,
                    min_length_px,
                    gradient_ratio_max,
                    ..MatchParams::default()
                };
                pipeline::run(
                    &rig,
                    Input::lists(&obs.lists),
                    &Options::with(params.clone()),
                )
                .map(|m| (m.output, None))
                .expect("match")
            } else {
                let mut images = render_triplet(&scene, &rig, &RenderParams::default(), seed);
                images[2] = with_exposure(&images[2], third_gain);
                let matched = pipeline::run(
                    &rig,
                    Input::Images([&images[0], &images[1], &images[2]]),
                    &Options {
                        params: MatchParams {
                            include_uncertain: all,
                            neighbour_radius_px,
                            min_length_px,
                            gradient_ratio_max,
                            ..MatchParams::default()
                        },
                        extract: Params {
                            min_segment_px,
                            ..Params::default()
                        },
                        ..Options::default()
                    },
                )
                .expect("match");
                (matched.output, matched.extracted)
            };
            let score = pooled.add_capture(&out.segments(), &obs, &rig);
            if let (true, Some(extracted)) = (list_wrong, &extracted) {
                let name = shape.name();
                wrong::list_wrong(name, seed, &rig, &obs, &out, extracted, &score.matches);
            }
            per_pair = out.stats.per_pair_rectification;
            angle = out.stats.epipolar_angle_deg;
        }
        println!(
            "| {} | {} | {per_pair} | {angle:.0}° |",
            shape.name(),
            pooled.cells()
        );
    }
}
