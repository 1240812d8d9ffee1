//! Shared by the `resolutions` and `rigs` examples: every wrong 3D segment of a match listed
//! with the ground-truth edge nearest it (the distance of its start, midpoint and end from
//! that edge, the angle) and its three image segments beside the edge's and its own
//! projections — what docs/RIGS.md's analyses of wrong segments were read from.

use nalgebra::Point3;
use trinocular::extract::Extraction;
use trinocular::geometry::Rig;
use trinocular::pipeline::MatchOutput;
use trinocular::synth::{rig_centre, Observation};

/// Distance of `p` from the segment `a`–`b`.
fn to_segment(p: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> f64 {
    let ab = b - a;
    let t = ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
    (a + ab * t - p).norm()
}

pub fn list_wrong(
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
