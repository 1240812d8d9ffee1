//! The whole chain (`pipeline::run`) on scattered synthetic captures: copies and piles of
//! segments, faint segments, segments that do not stand out from their image, and stopping at
//! every checkpoint.

use nalgebra::{Point2, Vector2};
use trinocular_core::checkpoint::Checkpoint;
use trinocular_core::geometry::Rig;
use trinocular_core::matching::{self, MatchParams};
use trinocular_core::pipeline::{run, Input, MatchError, MatchOutput, Options};
use trinocular_core::segment::{Segment2, SegmentList};
use trinocular_synth::{scattered_capture, Rng};

/// [`run`] on three lists with `params`, as most tests ask.
fn match_segments(
    rig: &Rig,
    lists: &[SegmentList; 3],
    params: &MatchParams,
) -> Result<MatchOutput, MatchError> {
    run(rig, Input::lists(lists), &Options::with(params.clone())).map(|m| m.output)
}

#[test]
fn copies_of_segments_are_dropped_and_repetitive_lists_stay_bounded() {
    let (rig, lists) = scattered_capture(200, 0.3, 0.2, 3);
    let params = MatchParams::default();
    let once = match_segments(&rig, &lists, &params).unwrap();
    // Every segment sent three times, exactly: the copies are dropped, the answer is the
    // same.
    let thrice = lists.clone().map(|mut l| {
        let copies = l.segments.clone();
        l.segments.extend(copies.iter().chain(&copies).copied());
        l
    });
    let out = match_segments(&rig, &thrice, &params).unwrap();
    assert_eq!(
        out.stats.duplicates_dropped,
        once.stats.segments_used.map(|n| 2 * n),
        "the copies of every segment used (a short one is dropped before)"
    );
    assert_eq!(out.triplets, once.triplets);
    // A thousand copies of one matched triplet's segments, each end jittered by up to 2 px:
    // n³ candidate triplets, but each segment's hypotheses are bounded.
    let [a, b, c] = once.triplets[0].segments;
    let mut rng = Rng::new(7);
    let mut jitter = |s: Segment2| {
        let mut d = || Vector2::new(rng.symmetric(2.0), rng.symmetric(2.0));
        Segment2 {
            start: s.start + d(),
            end: s.end + d(),
            ..s
        }
    };
    let pile: [SegmentList; 3] = std::array::from_fn(|v| SegmentList {
        segments: (0..1000)
            .map(|_| jitter(lists[v].segments[[a, b, c][v] as usize]))
            .collect(),
        oriented: lists[v].oriented,
        background_gradient: None,
    });
    let out = match_segments(&rig, &pile, &params).unwrap();
    let used = out.stats.segments_used[0] as usize;
    assert!(used > 300, "many jittered copies are distinct: {used}");
    assert!(out.stats.hypotheses as usize <= used * matching::predict::MAX_HYPOTHESES_PER_SEGMENT);
    // Far more segments than that, spread over the image: past the total, an error.
    let mut rng = Rng::new(11);
    let crowd: [SegmentList; 3] = std::array::from_fn(|v| {
        let cam = rig.camera(v);
        let (w, h) = (f64::from(cam.width()), f64::from(cam.height()));
        SegmentList {
            segments: (0..20_000)
                .map(|_| {
                    let p = Point2::new(rng.range(0.0, w), rng.range(0.0, h));
                    let d = Vector2::new(rng.symmetric(80.0), rng.symmetric(80.0));
                    Segment2::new(p, p + d)
                })
                .collect(),
            oriented: false,
            background_gradient: None,
        }
    });
    assert_eq!(
        match_segments(&rig, &crowd, &params).unwrap_err(),
        MatchError::TooManyHypotheses {
            limit: matching::predict::MAX_HYPOTHESES
        }
    );
}

/// The lists with every other segment faint (gradient 4) and the others strong (40).
fn every_other_faint(lists: &[SegmentList; 3]) -> [SegmentList; 3] {
    lists.clone().map(|mut l| {
        for (i, s) in l.segments.iter_mut().enumerate() {
            s.gradient = Some(if i % 2 == 0 { 4.0 } else { 40.0 });
        }
        l
    })
}

#[test]
fn faint_segments_are_left_out_when_asked_and_lists_without_gradients_never() {
    let (rig, lists) = scattered_capture(200, 0.3, 0.2, 3);
    let graded = every_other_faint(&lists);
    let params = MatchParams {
        min_gradient: 10.0,
        ..MatchParams::default()
    };
    let out = match_segments(&rig, &graded, &params).unwrap();
    let all = match_segments(&rig, &graded, &MatchParams::default()).unwrap();
    for (v, list) in graded.iter().enumerate() {
        // Every faint one that was otherwise usable (long enough, not a copy, in view).
        let faint = list.segments.iter().step_by(2).count() as u32;
        let unusable = all.stats.segments_in[v] - all.stats.segments_used[v];
        let dropped = out.stats.low_contrast_dropped[v];
        assert!(dropped <= faint && dropped + unusable >= faint, "view {v}");
        assert_eq!(
            out.stats.segments_used[v],
            all.stats.segments_used[v] - dropped
        );
    }
    assert!(!out.triplets.is_empty());
    for t in &out.triplets {
        assert!(t.segments.iter().all(|&s| s % 2 == 1), "{t:?}");
    }
    // No gradients given: nothing is known to be faint.
    let out = match_segments(&rig, &lists, &params).unwrap();
    assert_eq!(out.stats.low_contrast_dropped, [0, 0, 0]);
    assert!(MatchParams {
        min_gradient: -1.0,
        ..MatchParams::default()
    }
    .check()
    .is_err());
}

/// The angle (degrees, 0–90) between view `k`'s segment `s` and the epipolar line of the pair
/// (1, `k`) through its midpoint, in view `k`.
fn angle_to_epipolar_line(rig: &Rig, s: &Segment2, k: usize) -> f64 {
    let (c1, ck) = (rig.camera(0), rig.camera(k));
    let mid = Point2::from((s.start.coords + s.end.coords) / 2.0);
    let x = ck.centre() + ck.ray(mid).normalize() * 3.0;
    let moved = x + (c1.centre() - ck.centre()) * 0.05;
    let along = ck.project(&moved).expect("in front") - ck.project(&x).expect("in front");
    let d = s.end - s.start;
    let cos = (along.dot(&d) / (along.norm() * d.norm())).abs().min(1.0);
    cos.acos().to_degrees()
}

#[test]
fn where_the_verifying_view_cannot_check_the_depth_the_gradients_must_agree_closely() {
    let (rig, lists) = scattered_capture(300, 0.0, 0.0, 5);
    // Views 1 and 2 at one gradient; view 3 at `gain` times it, and every third of its
    // segments at `odd` times that again (a ghost's edge, seen at another strength).
    let graded = |gain: f64, odd: f64| -> [SegmentList; 3] {
        let mut out = lists.clone();
        for (v, l) in out.iter_mut().enumerate() {
            for (i, s) in l.segments.iter_mut().enumerate() {
                let g = match v {
                    2 if i % 3 == 0 => 20.0 * gain * odd,
                    2 => 20.0 * gain,
                    _ => 20.0,
                };
                s.gradient = Some(g);
            }
        }
        out
    };
    // Every verified hypothesis, so that what is refused is seen directly, not through the
    // rivals and supports that validation weighs.
    let params = MatchParams {
        validate: false,
        include_uncertain: true,
        ..MatchParams::default()
    };
    let even = match_segments(&rig, &graded(1.0, 1.0), &params).unwrap();
    let uneven = match_segments(&rig, &graded(1.0, 2.0), &params).unwrap();
    // Twice the gradient is within the general ratio (3): with the depth-blind ratio as
    // loose, nothing is refused for it.
    let loose = MatchParams {
        depth_blind_gradient_ratio_max: params.gradient_ratio_max,
        ..params.clone()
    };
    let loose = match_segments(&rig, &graded(1.0, 2.0), &loose).unwrap();
    assert_eq!(loose.stats.depth_blind_refused, 0);
    // What the tighter ratio refuses is a triplet whose view-3 segment is one of the
    // stronger ones and whose segment in the verifying view runs along that pair's epipolar
    // lines — it confirms the line at any depth; what it keeps either runs across them or
    // agrees in gradient.
    let kept: Vec<[u32; 3]> = uneven.triplets.iter().map(|t| t.segments).collect();
    let all: Vec<[u32; 3]> = loose.triplets.iter().map(|t| t.segments).collect();
    let lost: Vec<[u32; 3]> = all.into_iter().filter(|t| !kept.contains(t)).collect();
    assert!(!lost.is_empty() && !kept.is_empty(), "lost {lost:?}");
    assert!(lost.len() <= uneven.stats.depth_blind_refused as usize);
    let nearest_pair_angle = |t: &[u32; 3]| {
        let angle = |k: usize| angle_to_epipolar_line(&rig, &lists[k].segments[t[k] as usize], k);
        angle(1).min(angle(2))
    };
    // 15° in the verifying view's rectified frame, within a degree of it in its image.
    for t in &lost {
        let a = nearest_pair_angle(t);
        assert!(t[2] % 3 == 0, "{t:?} refused, its gradients agreeing");
        assert!(
            a < 16.0,
            "{t:?} refused at {a:.1}° from a pair's epipolar lines"
        );
    }
    for t in kept.iter().filter(|t| t[2] % 3 == 0) {
        let a = nearest_pair_angle(t);
        assert!(
            a > 14.0,
            "{t:?} kept at {a:.1}° from a pair's epipolar lines"
        );
    }
    // A third camera at twice the others' gain throughout: measured and divided out, so
    // nothing is refused for it.
    let brighter = match_segments(&rig, &graded(2.0, 1.0), &params).unwrap();
    let gain = brighter.stats.gradient_gains[2];
    assert!((gain - 2.0).abs() < 1e-9, "third gain measured {gain}");
    assert_eq!(brighter.stats.depth_blind_refused, 0);
    assert_eq!(brighter.triplets, even.triplets);
    assert!(MatchParams {
        depth_blind_gradient_ratio_max: 0.9,
        ..MatchParams::default()
    }
    .check()
    .is_err());
}

#[test]
fn segments_that_do_not_stand_out_from_their_images_background_are_left_out() {
    let (rig, lists) = scattered_capture(200, 0.3, 0.2, 3);
    // On images whose typical pixel has 2 grey levels per pixel, the faint ones (4) are
    // under 2.5 times that.
    let textured = every_other_faint(&lists).map(|mut l| {
        l.background_gradient = Some(2.0);
        l
    });
    let out = match_segments(&rig, &textured, &MatchParams::default()).unwrap();
    let off = MatchParams {
        min_gradient_to_background: 0.0,
        ..MatchParams::default()
    };
    let all = match_segments(&rig, &textured, &off).unwrap();
    assert_eq!(all.stats.low_contrast_dropped, [0, 0, 0]);
    for v in 0..3 {
        let dropped = out.stats.low_contrast_dropped[v];
        assert!(dropped > 0, "view {v}");
        assert_eq!(
            out.stats.segments_used[v],
            all.stats.segments_used[v] - dropped
        );
    }
    assert!(!out.triplets.is_empty());
    for t in &out.triplets {
        assert!(t.segments.iter().all(|&s| s % 2 == 1), "{t:?}");
    }
    // The same lists from a clean image (background 0.4): nothing is faint.
    let clean = textured.map(|mut l| {
        l.background_gradient = Some(0.4);
        l
    });
    let out = match_segments(&rig, &clean, &MatchParams::default()).unwrap();
    assert_eq!(out.stats.low_contrast_dropped, [0, 0, 0]);
    assert!(MatchParams {
        min_gradient_to_background: f64::NAN,
        ..MatchParams::default()
    }
    .check()
    .is_err());
}

#[test]
fn a_checkpoint_stops_the_pipeline_before_each_stage_in_turn() {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let (rig, lists) = scattered_capture(200, 0.3, 0.2, 3);
    let full = match_segments(&rig, &lists, &MatchParams::default()).unwrap();
    assert!(!full.triplets.is_empty());
    let mut stages = Vec::new();
    for allowed in 0.. {
        let asked = AtomicUsize::new(0);
        let stop = || asked.fetch_add(1, Ordering::Relaxed) >= allowed;
        let checkpoint = Checkpoint::new(&stop);
        let options = Options {
            checkpoint,
            ..Options::default()
        };
        match run(&rig, Input::lists(&lists), &options) {
            Err(MatchError::Stopped { stage }) => stages.push(stage),
            Ok(matched) => {
                // Let through every checkpoint, it gives what an unstoppable call gives.
                assert_eq!(matched.output.triplets, full.triplets);
                break;
            }
            Err(e) => panic!("{e}"),
        }
    }
    // Long stages ask inside their loops too: one stop per question, stage by stage.
    let asked = stages.len();
    stages.dedup();
    assert!(asked > stages.len(), "prediction asks per segment");
    assert_eq!(
        stages[..4],
        ["rectify", "predict", "validate", "reconstruct"]
    );
    assert_eq!(stages.last(), Some(&"assemble"));
}
