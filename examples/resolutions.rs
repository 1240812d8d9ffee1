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

use nalgebra::Point3;
use trinocular::extract::Extraction;
use trinocular::geometry::Rig;
use trinocular::matching::MatchParams;
use trinocular::pipeline::{self, Input, MatchOutput, Options};
use trinocular::synth::{
    observe, render_triplet, rig_centre, Defects, Observation, Pooled, Pose, RenderParams, RigSpec,
    Scene, STANDARD_RIG_POSITION,
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

/// Distance of `p` from the segment `a`–`b`.
fn to_segment(p: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> f64 {
    let ab = b - a;
    let t = ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
    (a + ab * t - p).norm()
}

fn list_wrong(
    name: &str,
    seed: u64,
    rig: &Rig,
    obs: &Observation,
    out: &MatchOutput,
    extracted: &[Extraction; 3],
    matches: &[Option<usize>],
) {
    let centre = rig_centre(rig);
    for (r, m) in out.segments_3d.iter().zip(matches) {
        if m.is_some() {
            continue;
        }
        let seg = r.segment;
        let mid = nalgebra::center(&seg.start, &seg.end);
        let u = (seg.end - seg.start).normalize();
        let Some((distances, angle, edge)) = obs
            .ground_truth
            .iter()
            .map(|g| {
                let d = [&seg.start, &mid, &seg.end].map(|p| to_segment(p, &g.start, &g.end));
                let cos = u.dot(&(g.end - g.start).normalize()).abs().min(1.0);
                (d, cos.acos().to_degrees(), *g)
            })
            .min_by(|a, b| a.0.iter().sum::<f64>().total_cmp(&b.0.iter().sum()))
        else {
            continue;
        };
        let tolerance = 0.02f64.max(0.01 * (mid - centre).norm());
        println!(
            "{name}, seed {seed}: {:.3} m long at {:.2} m; start / mid / end {:.3} / {:.3} / {:.3} m from the nearest edge (tolerance {tolerance:.3}), {angle:.1}°; direction σ {:.2}°{}",
            seg.length(),
            (mid - centre).norm(),
            distances[0],
            distances[1],
            distances[2],
            r.direction_sigma_deg,
            if r.uncertain { ", uncertain" } else { "" },
        );
        println!(
            "    3D {:.3?} → {:.3?}; edge {:.3?} → {:.3?}",
            seg.start.coords.as_slice(),
            seg.end.coords.as_slice(),
            edge.start.coords.as_slice(),
            edge.end.coords.as_slice()
        );
        let triplet = &out.triplets[r.triplet as usize];
        for (v, view) in extracted.iter().enumerate() {
            let s = &view.segments.segments[triplet.segments[v] as usize];
            let project = |p: &Point3<f64>| rig.camera(v).project(p).map(|q| (q.x, q.y));
            println!(
                "    view {}: image segment ({:.1}, {:.1}) → ({:.1}, {:.1}); edge {:.1?} → {:.1?}; 3D {:.1?} → {:.1?}",
                v + 1,
                s.start.x,
                s.start.y,
                s.end.x,
                s.end.y,
                project(&edge.start),
                project(&edge.end),
                project(&seg.start),
                project(&seg.end),
            );
        }
    }
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
                list_wrong(variant.name, seed, &rig, &obs, out, extracted, &s.matches);
            }
        }
        table.push(format!("| {} | {} |", variant.name, pooled.cells()));
    }
    for line in table {
        println!("{line}");
    }
}
