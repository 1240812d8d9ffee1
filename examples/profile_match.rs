//! Matches the `match/N` benchmark's triplet (N segments per image, default 600) over and
//! over on one thread, for a profiler to sample (`tools/perf_report.sh` runs it under
//! `perf record`); prints the median of each stage's time (`stats`) over the runs.
//!
//!     cargo run --release --example profile_match -- [N] [RUNS] [VERTEX_REACH_PX] [DOMINANT]
//!
//! `VERTEX_REACH_PX` (default: the default `MatchParams::vertex_reach_px`) compares a stage
//! with and without shared vertices in one build; 0 turns them off. `DOMINANT` (`true` or
//! `false`, default `true`) does the same for the scene's dominant directions
//! (`MatchParams::dominant_directions`).

use trinocular::matching::MatchParams;
use trinocular::pipeline::{self, Input, Options};
use trinocular::synth::scattered_capture;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(600);
    let runs: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(2000);
    let (rig, lists) = scattered_capture(n, 0.3, 0.2, 1);
    let vertex_reach_px: f64 = args
        .next()
        .and_then(|a| a.parse().ok())
        .unwrap_or(MatchParams::VERTEX_REACH_PX);
    let dominant_directions: bool = args.next().and_then(|a| a.parse().ok()).unwrap_or(true);
    let options = Options::with(MatchParams {
        vertex_reach_px,
        dominant_directions,
        ..MatchParams::default()
    });
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let mut stages: [Vec<f64>; 5] = Default::default();
    let (mut joined, mut along) = (0, 0);
    one.install(|| {
        for _ in 0..runs {
            let s = pipeline::run(&rig, Input::lists(&lists), &options)
                .expect("matched")
                .output
                .stats;
            joined = s.joined_at_vertices;
            along = s.along_dominant_directions;
            for (v, x) in stages.iter_mut().zip([
                s.rectify_ms,
                s.predict_ms,
                s.validate_ms,
                s.reconstruct_ms,
                s.total_ms,
            ]) {
                v.push(x);
            }
        }
    });
    let [rectify, predict, validate, reconstruct, total] = stages.map(median);
    println!(
        "match/{n}, {runs} runs, medians: rectify {rectify:.3} predict {predict:.3} validate {validate:.3} reconstruct {reconstruct:.3} total {total:.3} ms; {joined} joined at a vertex, {along} along a dominant direction"
    );
}
