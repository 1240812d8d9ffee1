//! Accuracy of the matcher on synthetic rooms, over seeds, rigs and defect levels: the
//! figures quoted in the README.
//!
//!     cargo run --release --example accuracy [-- SEEDS [param=value ...]]
//!
//! Each seed's room is seen as the shared rendered rooms are scored: from a turntable of
//! `poses` captures (default 12) around the room's centre (`synth::turntable_captures`);
//! `poses=1` is the one capture facing the bookshelf that the figures used until 2026-11-29.
//! e.g. `-- 5 include_uncertain=1` for every segment, not only those that meet the gate;
//! `defects.FIELD=value` changes one field of the realistic defects (`synth::Defects`), e.g.
//! `-- 5 defects.disturbed_share=0 defects.neighbour_shift=0` for lists without the measured
//! tail; `wrong` lists the realistic lists' wrong 3D segments (class, whether the match was
//! right, and per view the image segment's edge, its length, how far its ends lie off that
//! edge's image and the nearest listed parallel segment beside it).
//!
//! Two views of the same output, pooled over the seeds and poses:
//! - *match*: the paper's criterion — a 3D segment is wrong when its image segments are not
//!   images of one ground-truth edge; completeness is the eligible length its right segments
//!   cover;
//! - *3D*: the strict geometric criterion of `shared/eval` — both endpoints and the midpoint
//!   within max(2 cm, 1% of range) of one edge and the direction within 5°, which input
//!   noise alone can fail for short segments.
//!
//! Eligible length: the part of each edge visible in all three cameras that projects to at
//! least 20 px in each, and (`c10`) that also has at least 10 grey levels of contrast in each.
//!
//! And the covariance's calibration, as `tools/eval_rooms.py --calibration` measures it on the
//! rendered rooms: of the segments whose match is right, the share whose direction's and
//! midpoint's squared normalised errors (two degrees of freedom each) fall within χ²'s 95% and
//! 99% quantiles (`include_uncertain=1` for every segment, as the goal is measured).

use trinocular::matching::MatchParams;
use trinocular::pipeline::{self, Input, Options};
use trinocular::segment::{Segment2, Segment3};
use trinocular::synth::{
    eligible_intervals, eligible_intervals_with, error_classes, match_labels, rig_centre, score,
    score_labelled, turntable_captures, Calibration, Defects, Pooled,
};

/// `error … compl …` of a pool: the share of its segments that are wrong (0 for none) and of
/// its eligible length covered.
fn show(p: &Pooled) -> String {
    format!(
        "error {:.4} compl {:.4}",
        (p.segments - p.correct) as f64 / p.segments.max(1) as f64,
        p.covered_m / p.eligible_m.max(1e-12)
    )
}

/// How far a listed segment's ends lie across its true edge's image, the larger, pixels.
fn ends_off_px(rig: &trinocular::geometry::Rig, view: usize, edge: &Segment3, s: &Segment2) -> f64 {
    let cam = rig.camera(view);
    let (Some(a), Some(b)) = (cam.project(&edge.start), cam.project(&edge.end)) else {
        return f64::NAN;
    };
    let u = (b - a).normalize();
    let across = |p: nalgebra::Point2<f64>| u.perp(&(p - a)).abs();
    across(s.start).max(across(s.end))
}

/// The nearest other segment of the list parallel to segment `i` (within 4°) and alongside it
/// within 8 px, its distance across `i`'s line at `i`'s middle, pixels.
fn nearest_parallel_px(list: &[Segment2], i: usize) -> Option<f64> {
    let s = &list[i];
    let d = (s.end - s.start).normalize();
    let mid = nalgebra::center(&s.start, &s.end);
    list.iter()
        .enumerate()
        .filter(|&(j, o)| {
            j != i && (o.end - o.start).normalize().perp(&d).abs() < 4f64.to_radians().sin()
        })
        .filter_map(|(_, o)| {
            let e = (o.end - o.start).normalize();
            let across = e.perp(&(mid - o.start)).abs();
            let along = (mid - o.start).dot(&e);
            (along >= 0.0 && along <= (o.end - o.start).norm() && across < 8.0).then_some(across)
        })
        .min_by(f64::total_cmp)
}

fn main() {
    let seeds: u64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(5);
    let mut params = MatchParams::default();
    let mut realistic = Defects::realistic();
    let mut poses = 12usize;
    let wrong = std::env::args().any(|a| a == "wrong");
    for (key, value) in std::env::args().skip(2).filter_map(|a| {
        let (k, v) = a.split_once('=')?;
        Some((k.to_string(), v.parse::<f64>().ok()?))
    }) {
        match key.as_str() {
            "tolerance_px" => params.tolerance_px = value,
            "line_noise_px" => params.line_noise_px = value,
            "max_direction_sigma_deg" => params.max_direction_sigma_deg = value,
            "max_residual_px" => params.max_residual_px = value,
            "angle_tolerance_deg" => params.angle_tolerance_deg = value,
            "gradient_ratio_max" => params.gradient_ratio_max = value,
            "depth_blind_gradient_ratio_max" => params.depth_blind_gradient_ratio_max = value,
            "min_length_px" => params.min_length_px = value,
            "include_uncertain" => params.include_uncertain = value != 0.0,
            "gate_confidence" => params.gate_confidence = value,
            "neighbour_radius_px" => params.neighbour_radius_px = value,
            "defects.endpoint_noise_px" => realistic.endpoint_noise_px = value,
            "defects.shift_shared_px" => realistic.shift_shared_px = value,
            "defects.shift_view_px" => realistic.shift_view_px = value,
            "defects.turn_px" => realistic.turn_px = value,
            "defects.neighbour_shift" => realistic.neighbour_shift = value,
            "defects.neighbour_turn_share" => realistic.neighbour_turn_share = value,
            "defects.merge_same_contrast_px" => realistic.merge_same_contrast_px = value,
            "defects.disturbed_share" => realistic.disturbed_share = value,
            "defects.disturbed_view_prob" => realistic.disturbed_view_prob = value,
            "defects.disturbed_noise_px" => realistic.disturbed_noise_px = value,
            "defects.disturbed_view_px" => realistic.disturbed_view_px = value,
            "defects.disturbed_turn_px" => realistic.disturbed_turn_px = value,
            "defects.end_noise_px" => realistic.end_noise_px = value,
            "defects.end_shortfall_px" => realistic.end_shortfall_px = value,
            "defects.fragment_prob" => realistic.fragment_prob = value,
            "defects.miss_prob" => realistic.miss_prob = value,
            "defects.faint_share" => realistic.faint_share = value,
            "defects.faint_miss_prob" => realistic.faint_miss_prob = value,
            "defects.clutter_fraction" => realistic.clutter_fraction = value,
            "defects.states_noise" => realistic.states_noise = value != 0.0,
            "list_push_px" => params.list_push_px = value,
            "list_shift_px" => params.list_shift_px = value,
            "poses" => poses = value.max(1.0) as usize,
            other => panic!("unknown parameter {other}"),
        }
    }
    let configs = [
        ("clean", Defects::clean(), false),
        ("realistic", realistic, false),
        ("noisy", Defects::noisy(), false),
        ("clean, collinear", Defects::clean(), true),
        ("realistic, collinear", realistic, true),
    ];
    println!("{seeds} seeds x {poses} poses; {params:?}");
    for (name, defects, collinear) in configs {
        let (mut matched, mut matched_c10, mut strict, mut strict_c10) = (
            Pooled::default(),
            Pooled::default(),
            Pooled::default(),
            Pooled::default(),
        );
        let mut ms = Vec::new();
        let mut calibration = Calibration::default();
        let captures = (1..=seeds).flat_map(|seed| {
            turntable_captures(seed, poses, &defects, collinear)
                .into_iter()
                .enumerate()
                .map(move |(k, (rig, obs))| (seed, k, rig, obs))
        });
        for (seed, pose, rig, obs) in captures {
            let out = pipeline::run(
                &rig,
                Input::lists(&obs.lists),
                &Options::with(params.clone()),
            )
            .map(|m| m.output)
            .expect("valid input");
            let segs: Vec<Segment3> = out.segments();
            let labels = match_labels(&out, &obs);
            let (elig, elig_c10) = (
                eligible_intervals(&obs),
                eligible_intervals_with(&obs, 20.0, Some(10.0)),
            );
            let truth = &obs.ground_truth;
            calibration.add_labelled(&out, &obs, &labels);
            matched.add(&score_labelled(&segs, &labels, truth, &elig));
            matched_c10.add(&score_labelled(&segs, &labels, truth, &elig_c10));
            let strict_score = score(&segs, truth, &elig, rig_centre(&rig));
            if wrong && name == "realistic" {
                for (k, r) in out.segments_3d.iter().enumerate() {
                    if strict_score.matches[k].is_some() {
                        continue;
                    }
                    let t = &out.triplets[r.triplet as usize];
                    let views: Vec<String> = (0..3)
                        .map(|v| {
                            let i = t.segments[v] as usize;
                            let s = &obs.lists[v].segments[i];
                            let off = obs.truth[v][i]
                                .map(|e| ends_off_px(&rig, v, &obs.ground_truth[e], s));
                            format!(
                                "{:?} {:.0}px off {} nb {}",
                                obs.truth[v][i],
                                (s.end - s.start).norm(),
                                off.map_or("-".into(), |o| format!("{o:.2}")),
                                nearest_parallel_px(&obs.lists[v].segments, i)
                                    .map_or("-".into(), |d| format!("{d:.1}")),
                            )
                        })
                        .collect();
                    let class =
                        error_classes(&[r.segment], &[None], &obs.ground_truth, rig_centre(&rig));
                    let class = if class.far > 0 {
                        "far"
                    } else if class.near > 0 {
                        "near"
                    } else {
                        "dir"
                    };
                    println!(
                        "seed {seed} pose {pose}: wrong ({class}) {:.3} m, match label {:?}, dir σ {:.2}°, pos σ {:.3} m, views {views:?}",
                        r.segment.length(),
                        labels[k],
                        r.direction_sigma_deg,
                        r.position_sigma_m,
                    );
                }
            }
            strict.add_classes(&error_classes(
                &segs,
                &strict_score.matches,
                truth,
                rig_centre(&rig),
            ));
            strict.add(&strict_score);
            strict_c10.add(&score(&segs, truth, &elig_c10, rig_centre(&rig)));
            ms.push(out.stats.total_ms);
        }
        ms.sort_by(f64::total_cmp);
        let (dir, pos) = calibration.shares();
        println!(
            "{name:21} n {:5} | match: {} (c10 {:.4}) | 3D: {} (c10 {:.4}; dir / near / far {} / {} / {}) | within q95 / q99: direction {:.3} / {:.3}, position {:.3} / {:.3} | median {:.2} ms",
            matched.segments,
            show(&matched),
            matched_c10.covered_m / matched_c10.eligible_m.max(1e-12),
            show(&strict),
            strict_c10.covered_m / strict_c10.eligible_m.max(1e-12),
            strict.classes.direction_only,
            strict.classes.near,
            strict.classes.far,
            dir[0],
            dir[1],
            pos[0],
            pos[1],
            ms[ms.len() / 2],
        );
    }
}
