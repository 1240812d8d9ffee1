//! Rig shapes (`synth::RigShape`): a rig whose plane of centres does not face the scene —
//! its third camera ahead of or behind the other two, all at one height — is matched in one
//! rectified frame per searched pair and verified in the third view by exact transfer, so it
//! keeps its third camera. `cargo run --release --example rigs` prints every shape's figures
//! (docs/RIGS.md).

use trinocular::matching::MatchParams;
use trinocular::pipeline::{self, Input, Options};
use trinocular::segment::Segment3;
use trinocular::synth::{
    eligible_intervals_with, rig_centre, score, shaped_capture, Defects, RigShape,
};

use crate::accuracy::{COLLINEAR_MIN_COMPLETENESS, EXACT_MAX_ERROR};

const SEEDS: [u64; 2] = [1, 2];

/// Pooled 3D error and completeness of every match of exact segment lists, and whether the
/// rig was matched in per-pair frames.
fn exact(shape: RigShape) -> (f64, f64, bool) {
    let params = MatchParams {
        include_uncertain: true,
        ..MatchParams::default()
    };
    let (mut n, mut correct, mut eligible, mut covered) = (0, 0, 0.0, 0.0);
    let mut per_pair = false;
    for seed in SEEDS {
        let (_, rig, obs) = shaped_capture(seed, Defects::clean(), shape);
        let out = pipeline::run(
            &rig,
            Input::lists(&obs.lists),
            &Options::with(params.clone()),
        )
        .map(|m| m.output)
        .expect("valid input");
        per_pair = out.stats.per_pair_rectification;
        let segs: Vec<Segment3> = out.segments();
        let e = eligible_intervals_with(&obs, 20.0, Some(10.0));
        let s = score(&segs, &obs.ground_truth, &e, rig_centre(&rig));
        n += s.n_segments;
        correct += s.n_correct;
        eligible += s.eligible_length_m;
        covered += s.covered_length_m;
    }
    let error = 1.0 - correct as f64 / n.max(1) as f64;
    let completeness = covered / eligible;
    println!(
        "{}: {n} segments, error {error:.4}, completeness {completeness:.4}, per-pair {per_pair}",
        shape.name()
    );
    (error, completeness, per_pair)
}

#[test]
fn a_third_camera_ahead_or_behind_is_kept_and_its_matches_are_exact() {
    let (_, _, facing_per_pair) = exact(RigShape::FacingTriangle);
    assert!(!facing_per_pair, "a facing triangle shares one frame");
    for shape in [RigShape::ThirdAhead, RigShape::ThirdBehind] {
        let (error, completeness, per_pair) = exact(shape);
        assert!(per_pair, "{}: matched in per-pair frames", shape.name());
        // Exact input, exact geometry: as few wrong 3D segments as the facing rig's bound
        // for exact input (tests/integration/accuracy.rs). Treated as collinear, as before,
        // these rigs lost every match to their third view.
        assert!(
            error <= EXACT_MAX_ERROR,
            "{}: error {error:.4}",
            shape.name()
        );
        // Only the lateral pair is searched (the forward one is not: rectify.rs,
        // MIN_SEARCH_BASELINE_TO_AXIS_DEG), so, like a collinear rig, everything but the
        // segments along its epipolar lines: the collinear rig's bound (accuracy.rs).
        // (The goal, 1.25x of the facing rig's completeness, is not met: docs/RIGS.md.)
        assert!(
            completeness >= COLLINEAR_MIN_COMPLETENESS,
            "{}: completeness {completeness:.4}",
            shape.name()
        );
    }
}
