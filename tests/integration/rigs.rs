//! Rig shapes (`synth::RigShape`): a rig whose plane of centres does not face the scene —
//! its third camera ahead of or behind the other two, all at one height — is matched in one
//! rectified frame per searched pair and verified in the third view by exact transfer, so it
//! keeps its third camera. `cargo run --release --example rigs` prints every shape's figures
//! (docs/RIGS.md).

use trinocular::matching::MatchParams;
use trinocular::pipeline::{self, Input, Options};
use trinocular::segment::Segment3;
use trinocular::synth::{
    eligible_intervals_with, render_triplet, rig_centre, score, score_capture, shaped_capture,
    with_exposure, Defects, Pooled, RenderParams, RigShape,
};

use crate::accuracy::{matched_lists, COLLINEAR_MIN_COMPLETENESS, EXACT_MAX_ERROR};

const SEEDS: [u64; 2] = [1, 2];

/// Pooled 3D error and completeness of every match of exact segment lists, and whether the
/// rig was matched in per-pair frames.
fn exact(shape: RigShape) -> (f64, f64, bool) {
    let params = MatchParams {
        include_uncertain: true,
        // Exact lines: no detector pushed them.
        list_push_px: 0.0,
        ..MatchParams::default()
    };
    let mut pooled = Pooled::default();
    let mut per_pair = false;
    for seed in SEEDS {
        let (_, rig, obs) = shaped_capture(seed, Defects::clean(), shape);
        let out = matched_lists(&rig, &obs.lists, &params);
        per_pair = out.stats.per_pair_rectification;
        let segs: Vec<Segment3> = out.segments();
        let e = eligible_intervals_with(&obs, 20.0, Some(10.0));
        pooled.add(&score(&segs, &obs.ground_truth, &e, rig_centre(&rig)));
    }
    let (n, error, completeness) = (pooled.segments, pooled.error(), pooled.completeness());
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

/// Pooled 3D error and completeness of the default answer from rendered images, the third
/// camera's grey levels (signal and noise) scaled by `third_gain` — an exposure of its own —
/// and the third view's gain as the matcher measured it (the median over the seeds).
fn rendered_with_gain(
    shape: RigShape,
    seeds: std::ops::RangeInclusive<u64>,
    third_gain: f32,
) -> (f64, f64, f64) {
    let mut pooled = Pooled::default();
    let mut gains = Vec::new();
    for seed in seeds {
        let (scene, rig, obs) = shaped_capture(seed, Defects::clean(), shape);
        let mut images = render_triplet(&scene, &rig, &RenderParams::default(), seed);
        images[2] = with_exposure(&images[2], third_gain);
        let out = pipeline::run(
            &rig,
            Input::Images([&images[0], &images[1], &images[2]]),
            &Options::default(),
        )
        .expect("valid input")
        .output;
        gains.push(out.stats.gradient_gains[2]);
        pooled.add(&score_capture(&out.segments(), &obs, &rig));
    }
    let (n, error, completeness) = (pooled.segments, pooled.error(), pooled.completeness());
    gains.sort_by(f64::total_cmp);
    let gain = gains[gains.len() / 2];
    println!(
        "{} (images, third gain {third_gain}): {n} segments, error {error:.4}, completeness \
         {completeness:.4}, third gain measured {gain:.3}",
        shape.name()
    );
    (error, completeness, gain)
}

/// [`rendered_with_gain`] with the three cameras at one gain.
fn rendered(shape: RigShape, seeds: std::ops::RangeInclusive<u64>) -> (f64, f64) {
    let (error, completeness, _) = rendered_with_gain(shape, seeds, 1.0);
    (error, completeness)
}

/// Issue 14's goal, for the shapes that meet it: from rendered images, the default answer of
/// an L-shaped, a wide and a converging rig is within 1.25x of the facing triangle's error
/// and completeness on the same scenes. (The L-shape met it only once a ghost — two views on
/// one edge, the searched view on another — had to agree in gradient where its verification
/// cannot check the depth: `MatchParams::depth_blind_gradient_ratio_max`, docs/RIGS.md. The
/// other shapes miss it for want of parallax or overlap, not of matching: docs/RIGS.md.)
#[test]
fn an_l_shaped_wide_or_converging_rig_is_as_good_as_a_facing_triangle() {
    const SEEDS: std::ops::RangeInclusive<u64> = 1..=8;
    const WITHIN: f64 = 1.25;
    let (facing_error, facing_completeness) = rendered(RigShape::FacingTriangle, SEEDS);
    for shape in [RigShape::LShape, RigShape::Wide, RigShape::Converging] {
        let (error, completeness) = rendered(shape, SEEDS);
        assert!(
            error <= WITHIN * facing_error,
            "{}: error {error:.4} against the facing triangle's {facing_error:.4}",
            shape.name()
        );
        assert!(
            completeness >= facing_completeness / WITHIN,
            "{}: completeness {completeness:.4} against the facing triangle's {facing_completeness:.4}",
            shape.name()
        );
    }
}

/// A third camera with an exposure of its own (its grey levels at 0.6 of the others'): the
/// matcher measures the gain and divides it out of the gradient test of the triplets whose
/// depth that camera alone fixes, so the facing triangle keeps its accuracy. With the gains
/// taken as 1 it was 22.8% complete and 14.5% wrong against 52.9% and 3.7% (docs/RIGS.md).
#[test]
fn a_camera_with_its_own_exposure_keeps_its_triplets() {
    const SEEDS: std::ops::RangeInclusive<u64> = 1..=8;
    const WITHIN: f64 = 1.25;
    let (error, completeness) = rendered(RigShape::FacingTriangle, SEEDS);
    let (darker_error, darker_completeness, gain) =
        rendered_with_gain(RigShape::FacingTriangle, SEEDS, 0.6);
    assert!(
        (gain / 0.6 - 1.0).abs() < 0.05,
        "third gain measured {gain}"
    );
    assert!(
        darker_error <= WITHIN * error,
        "{darker_error} against {error}"
    );
    assert!(
        darker_completeness >= completeness / WITHIN,
        "{darker_completeness} against {completeness}"
    );
}
