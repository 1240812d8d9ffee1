//! How each stage's time grows with the number of segments per image, on one call each
//! (`stats` of the pipeline; the criterion bench gives the medians):
//!
//!     RAYON_NUM_THREADS=1 cargo run --release --example scale

use trinocular::matching::MatchParams;
use trinocular::pipeline::{self, Input, Options};
use trinocular::synth::scattered_capture;

fn main() {
    let params = MatchParams::default();
    for n in [600usize, 2500, 10000] {
        let (rig, lists) = scattered_capture(n, 0.3, 0.2, 1);
        let out = pipeline::run(&rig, Input::lists(&lists), &Options::with(params.clone()))
            .map(|m| m.output)
            .unwrap();
        let s = &out.stats;
        println!(
            "n={n} hyp={} trip={} predict {:.2} reconstruct {:.2} validate {:.2} total {:.2} ms",
            s.hypotheses, s.triplets, s.predict_ms, s.reconstruct_ms, s.validate_ms, s.total_ms
        );
    }
}
