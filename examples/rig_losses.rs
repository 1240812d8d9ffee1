//! Where each rig shape loses the eligible edges of the standard room, from exact segment
//! lists (the geometry and the contrast tests alone, no detector's noise):
//!
//!     cargo run --release --example rig_losses [-- SEEDS] [only=NAME] [no-contrast]
//!
//! Every eligible edge (visible in all three cameras, 20 px or more in each) is put in one
//! class by what the matcher did with the listed segments that come from it, and the classes
//! are summed as eligible length, pooled over the seeds (default 16): *matched* — one triplet
//! holds three of its own segments; *not listed in all three* — some view's list has no
//! segment of it (the generator's minimum length, collinear edges listed as one); *partly
//! matched* — some of its segments went to triplets of other edges; *unmatched* — none of its
//! segments is in any triplet, split by what its three segments' contrast does: the sign
//! differs between two views (the oriented lists' directions disagree with the edge's
//! projection), the strengths differ by more than `gradient_ratio_max`, or neither.
//!
//! `no-contrast` matches the same lists with the contrast tests out of the way (unoriented,
//! `angle_tolerance_deg` 60, `gradient_ratio_max` 100): the share the geometry alone would
//! match. docs/RIGS.md, "Views on either side of a line", quotes both.

use std::collections::{BTreeMap, HashMap};

use trinocular::matching::MatchParams;
use trinocular::pipeline::{self, Input, Options};
use trinocular::segment::{Segment2, SegmentList};
use trinocular::synth::{eligible_intervals, shaped_capture, Defects, RigShape};

const CLASSES: [&str; 6] = [
    "matched",
    "not listed in all three",
    "partly matched",
    "unmatched, contrast sign differs",
    "unmatched, strengths over the ratio",
    "unmatched, otherwise",
];

fn main() {
    let seeds: u64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(16);
    let only: Option<String> =
        std::env::args().find_map(|a| a.strip_prefix("only=").map(String::from));
    let no_contrast = std::env::args().any(|a| a == "no-contrast");
    let params = MatchParams {
        include_uncertain: true,
        // Exact lines: no detector pushed them.
        list_push_px: 0.0,
        ..MatchParams::default()
    };
    let params = if no_contrast {
        MatchParams {
            angle_tolerance_deg: 60.0,
            gradient_ratio_max: 100.0,
            ..params
        }
    } else {
        params
    };
    println!("| rig | {} |", CLASSES.join(" | "));
    println!("|---{}|", "|---".repeat(CLASSES.len()));
    for shape in RigShape::ALL {
        if only
            .as_ref()
            .is_some_and(|o| !shape.name().starts_with(o.as_str()))
        {
            continue;
        }
        let mut length: BTreeMap<usize, f64> = BTreeMap::new();
        for seed in 1..=seeds {
            let (_scene, rig, obs) = shaped_capture(seed, Defects::clean(), shape);
            let lists: [SegmentList; 3] = std::array::from_fn(|v| SegmentList {
                oriented: obs.lists[v].oriented && !no_contrast,
                ..obs.lists[v].clone()
            });
            let out = pipeline::run(&rig, Input::lists(&lists), &Options::with(params.clone()))
                .expect("match")
                .output;
            // Per edge and view, its listed segments; per view, the triplet each segment is in.
            let mut of_edge: Vec<[Vec<usize>; 3]> =
                vec![Default::default(); obs.ground_truth.len()];
            for (v, truth) in obs.truth.iter().enumerate() {
                for (i, edge) in truth.iter().enumerate() {
                    if let Some(e) = edge {
                        of_edge[*e][v].push(i);
                    }
                }
            }
            let mut triplet_of: [HashMap<usize, usize>; 3] = Default::default();
            for (k, t) in out.triplets.iter().enumerate() {
                for (v, map) in triplet_of.iter_mut().enumerate() {
                    map.insert(t.segments[v] as usize, k);
                }
            }
            for (e, intervals) in eligible_intervals(&obs).iter().enumerate() {
                let edge = &obs.ground_truth[e];
                let eligible = intervals.iter().map(|(a, b)| b - a).sum::<f64>()
                    * (edge.end - edge.start).norm();
                if eligible <= 0.0 {
                    continue;
                }
                let own = &of_edge[e];
                let class = if own.iter().any(Vec::is_empty) {
                    1
                } else if own[0]
                    .iter()
                    .filter_map(|i| triplet_of[0].get(i))
                    .any(|&k| {
                        let t = &out.triplets[k].segments;
                        own[1].contains(&(t[1] as usize)) && own[2].contains(&(t[2] as usize))
                    })
                {
                    0
                } else if (0..3).any(|v| own[v].iter().any(|i| triplet_of[v].contains_key(i))) {
                    2
                } else {
                    let first: [&Segment2; 3] =
                        std::array::from_fn(|v| &obs.lists[v].segments[own[v][0]]);
                    let along_edge = |v: usize| {
                        let cam = rig.camera(v);
                        match (cam.project(&edge.start), cam.project(&edge.end)) {
                            (Some(a), Some(b)) => {
                                (b - a).dot(&(first[v].end - first[v].start)) > 0.0
                            }
                            _ => true,
                        }
                    };
                    let gradients = first.map(|s| s.gradient.unwrap_or(1.0));
                    let (low, high) = gradients
                        .iter()
                        .fold((f64::INFINITY, 0.0_f64), |(l, h), &g| (l.min(g), h.max(g)));
                    if (0..3).any(|v| along_edge(v) != along_edge(0)) {
                        3
                    } else if high > params.gradient_ratio_max * low {
                        4
                    } else {
                        5
                    }
                };
                *length.entry(class).or_default() += eligible;
            }
        }
        let total: f64 = length.values().sum();
        let cells: Vec<String> = (0..CLASSES.len())
            .map(|c| {
                format!(
                    "{:.1}%",
                    100.0 * length.get(&c).copied().unwrap_or(0.0) / total
                )
            })
            .collect();
        println!("| {} | {} |", shape.name(), cells.join(" | "));
    }
}
