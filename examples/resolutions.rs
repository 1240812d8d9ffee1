//! Accuracy of the facing triangle at other image sizes and baselines: the rooms our figures
//! are tuned on are 512×512 with a 0.3 m baseline, and what lands is also checked on rooms of
//! 640×480 with a 0.2 m baseline and of 1024×768. Each variant is the rig of
//! `RigSpec::non_collinear` with its focal lengths scaled (the principal point kept where it
//! is relative to the image centre) and its centres scaled about camera 1, in the standard
//! room; 3D error and completeness by the strict scorer (`synth::score_capture`), pooled over
//! seeds, default answer or (`all`) everything.
//!
//!     cargo run --release --example resolutions [-- SEEDS] [all] [wrong]
//!
//! `wrong` lists every wrong 3D segment with the ground-truth edge nearest it (the distance of
//! its start, midpoint and end from that edge, the angle) and its three image segments beside
//! the edge's and its own projections: what docs/RIGS.md's analysis of the facing triangle's
//! wrong segments was read from.

#[path = "common/wrong.rs"]
mod wrong;

use nalgebra::Point3;
use trinocular::geometry::Rig;
use trinocular::matching::MatchParams;
use trinocular::pipeline::{self, Input, Options};
use trinocular::synth::{
    observe, render_triplet, Defects, Pooled, Pose, RenderParams, RigSpec, Scene,
    STANDARD_RIG_POSITION,
};

/// One rig variant: image size, focal length scale, baseline scale.
struct Variant {
    name: &'static str,
    width: u32,
    height: u32,
    focal_scale: f64,
    baseline_scale: f64,
}

const VARIANTS: [Variant; 4] = [
    Variant {
        name: "512×512, 0.30 m (the rooms')",
        width: 512,
        height: 512,
        focal_scale: 1.0,
        baseline_scale: 1.0,
    },
    Variant {
        name: "640×480, 0.20 m",
        width: 640,
        height: 480,
        focal_scale: 1.25,
        baseline_scale: 2.0 / 3.0,
    },
    Variant {
        name: "1024×768, 0.30 m",
        width: 1024,
        height: 768,
        focal_scale: 2.0,
        baseline_scale: 1.0,
    },
    Variant {
        name: "1024×768, 0.30 m, wider view (f × 1.5)",
        width: 1024,
        height: 768,
        focal_scale: 1.5,
        baseline_scale: 1.0,
    },
];

fn rig_of(variant: &Variant, seed: u64) -> Rig {
    let mut spec = RigSpec::non_collinear(seed);
    let (w0, h0) = (f64::from(spec.width), f64::from(spec.height));
    let (w, h) = (f64::from(variant.width), f64::from(variant.height));
    spec.width = variant.width;
    spec.height = variant.height;
    for c in &mut spec.cameras {
        let s = variant.focal_scale;
        c.fx *= s;
        c.fy *= s;
        // Pixel centres at integers: the image centre is (size − 1) / 2.
        c.cx = (w - 1.0) / 2.0 + (c.cx - (w0 - 1.0) / 2.0) * s;
        c.cy = (h - 1.0) / 2.0 + (c.cy - (h0 - 1.0) / 2.0) * s;
        c.centre = Point3::from(c.centre.coords * variant.baseline_scale);
    }
    let pose = Pose::from_position_yaw(Point3::from(STANDARD_RIG_POSITION), 0.0);
    spec.build(&pose).expect("the scaled rigs are valid")
}

fn main() {
    let seeds: u64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(8);
    let all = std::env::args().any(|a| a == "all");
    let wrong = std::env::args().any(|a| a == "wrong");
    let mut table = vec![
        "| rig | segments | 3D error | dir / near / far | completeness |".to_string(),
        "|---|---|---|---|---|".to_string(),
    ];
    for variant in &VARIANTS {
        let mut pooled = Pooled::default();
        for seed in 1..=seeds {
            let rig = rig_of(variant, seed);
            let scene = Scene::room(seed);
            let obs = observe(&scene, &rig, &Defects::clean(), seed);
            let images = render_triplet(&scene, &rig, &RenderParams::default(), seed);
            let matched = pipeline::run(
                &rig,
                Input::Images([&images[0], &images[1], &images[2]]),
                &Options::with(MatchParams {
                    include_uncertain: all,
                    ..MatchParams::default()
                }),
            )
            .expect("match");
            let out = &matched.output;
            let s = pooled.add_capture(&out.segments(), &obs, &rig);
            if wrong {
                let extracted = matched.extracted.as_ref().expect("images in");
                wrong::list_wrong(variant.name, seed, &rig, &obs, out, extracted, &s.matches);
            }
        }
        table.push(format!("| {} | {} |", variant.name, pooled.cells()));
    }
    for line in table {
        println!("{line}");
    }
}
