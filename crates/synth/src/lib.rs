//! Synthetic scenes with exact ground truth, and a scorer: Trinocular's test bench, for the
//! tests, benches, examples, fuzz seeds and the demo.
//!
//! A crate of its own, unpublished, over `trinocular-core`'s public API: the library a robot
//! embeds never compiles it, and whatever the scenes need from the core is the same API a
//! user has. The core's own unit tests take from here only what crosses as plain data, [`Rng`]
//! and the numbers of a preset rig (a dev-dependency, which links a second copy of the core:
//! its types are not theirs); its tests that need a scene are integration tests of the core
//! (`crates/core/tests/synthetic/`), which link the same core as this crate
//! (docs/ARCHITECTURE.md).
//!
//! The pieces, in the order data flows:
//!
//! ```text
//! Scene::room(seed) ──┐
//! RigSpec ─▶ Rig ─────┼─▶ observe(.., Defects, seed) ─▶ Observation ─▶ (pipeline) ─▶ score()
//! Pose (rig_to_world)┘      3 oriented segment lists + truth + visibility
//! ```
//!
//! - [`scene`]: axis-aligned boxes, a point light, ray casting and shading; the standard room.
//! - [`rig`]: rig presets (non-collinear like the rendered office data, collinear like a
//!   Bumblebee XB3, random for property tests) and rig poses.
//! - [`visibility`]: exact visible sub-intervals of every edge in every camera, and contrast.
//! - [`defects`]: segment lists as an extractor would report them (noise, fragments, misses,
//!   clutter), each segment labelled with its ground-truth edge.
//! - [`render`]: grey images of a scene, exact or camera-like (anti-aliased, blurred, noisy),
//!   to look at or to feed the extractor.
//! - [`score`]: the metrics of `shared/eval/score.py`, in Rust.
//! - [`bvh`]: a bounding-volume hierarchy that makes the many contrast probes cheap.
//! - [`pattern`]: the calibration pattern as a renderable scene, and rigs looking at it.
//! - [`scatter`]: scenes of any size for benchmarks, scattered segments projected exactly.
//! - [`rng`]: the seeded generator that makes all of it reproducible.
//!
//! Everything is a pure function of its arguments and a `u64` seed. Frames follow DESIGN §1.

pub mod bvh;
pub mod defects;
pub mod pattern;
pub mod render;
pub mod rig;
pub mod rng;
pub mod scatter;
pub mod scene;
pub mod score;
pub mod visibility;

pub use bvh::SceneIndex;
pub use defects::{observe, Defects, Observation};
pub use pattern::{pattern_scene, pattern_views};
pub use render::{render, render_image, render_triplet, with_exposure, RenderParams};
pub use rig::{cam_from_rig_rotation, CameraSpec, Pose, RigShape, RigSpec, SynthError};
pub use rng::Rng;
pub use scatter::scattered_capture;
pub use scene::{Box3, Face, Hit, Scene, Tracer};
pub use score::{
    edge_recall, eligible_intervals, eligible_intervals_with, error_classes, match_labels,
    normalised_errors, score, score_labelled, Calibration, ErrorClasses, Pooled, Score, CHI2_2DOF,
};
pub use visibility::{
    contrast_at, edge_contrast, intersect_intervals, rig_visibility, total_length, union_intervals,
    visible_intervals, EdgeVisibility, Interval,
};

use nalgebra::Point3;

use trinocular_core::geometry::Rig;
use trinocular_core::segment::Segment3;

/// Where [`standard_capture`] puts the rig origin (camera 1) in the room: 1.2 m high, a
/// little left of the room's centre line so the rig centre is on it, 2.65 m from the north
/// wall it looks at.
pub const STANDARD_RIG_POSITION: [f64; 3] = [2.85, 2.35, 1.2];

/// The standard room seen by a non-collinear (or collinear) rig near the room centre, looking
/// at the north wall: the scene, the rig (cameras mapping room points, i.e. the rig frame is
/// the room frame here) and the observation. Reproducible from `seed`.
pub fn standard_capture(seed: u64, defects: Defects, collinear: bool) -> (Scene, Rig, Observation) {
    let scene = Scene::room(seed);
    let spec = if collinear {
        RigSpec::collinear(seed)
    } else {
        RigSpec::non_collinear(seed)
    };
    let pose = Pose::from_position_yaw(Point3::from(STANDARD_RIG_POSITION), 0.0);
    // The presets draw every parameter from bounded ranges (f ≥ 560 px, rotations of a few
    // degrees, centres ≥ 0.1 m apart), so validation cannot fail whatever the seed; the
    // preset tests check this over many seeds.
    let rig = spec
        .build(&pose)
        .expect("preset rigs are valid for every seed");
    let obs = observe(&scene, &rig, &defects, seed);
    (scene, rig, obs)
}

/// The standard room of [`standard_capture`] seen by a rig of `shape` from the same place.
pub fn shaped_capture(seed: u64, defects: Defects, shape: RigShape) -> (Scene, Rig, Observation) {
    let scene = Scene::room(seed);
    let pose = Pose::from_position_yaw(Point3::from(STANDARD_RIG_POSITION), 0.0);
    let rig = RigSpec::shaped(shape, seed)
        .build(&pose)
        .expect("shaped rigs are valid for every seed");
    let obs = observe(&scene, &rig, &defects, seed);
    (scene, rig, obs)
}

/// The standard room and rig of [`standard_capture`] (seed `seed`) with every camera's
/// resolution multiplied by `scale`: same field of view, `scale²` times the pixels. For
/// benchmarks at several image sizes.
pub fn bench_capture(seed: u64, scale: f64) -> (Scene, Rig) {
    let mut spec = RigSpec::non_collinear(seed);
    spec.width = (f64::from(spec.width) * scale).round() as u32;
    spec.height = (f64::from(spec.height) * scale).round() as u32;
    for c in &mut spec.cameras {
        // Pixel centres at integers: the image's corner -0.5 stays at -0.5.
        c.fx *= scale;
        c.fy *= scale;
        c.cx = (c.cx + 0.5) * scale - 0.5;
        c.cy = (c.cy + 0.5) * scale - 0.5;
    }
    let pose = Pose::from_position_yaw(Point3::from(STANDARD_RIG_POSITION), 0.0);
    let rig = spec
        .build(&pose)
        .expect("preset rigs stay valid when scaled up");
    (Scene::room(seed), rig)
}

/// A panoramic session in the standard room: the rig of [`standard_capture`] turning about
/// the vertical through its origin, `poses` captures evenly spaced over a full turn. Returns
/// the scene, the rig in its own frame (what a session's calibration holds) and, per capture,
/// its pose (`rig_to_world`) and what the rig sees from there.
pub fn panoramic_session(
    seed: u64,
    poses: usize,
    defects: &Defects,
) -> (Scene, Rig, Vec<(Pose, Observation)>) {
    let scene = Scene::room(seed);
    let spec = RigSpec::non_collinear(seed);
    let rig = spec
        .build(&Pose::identity())
        .expect("preset rigs are valid for every seed");
    let captures = turntable_poses(poses)
        .enumerate()
        .map(|(k, pose)| {
            let placed = spec.build(&pose).expect("a turned preset rig stays valid");
            (pose, observe(&scene, &placed, defects, seed + k as u64))
        })
        .collect();
    (scene, rig, captures)
}

/// The standard room seen as the shared rendered rooms are scored: the rig of
/// [`standard_capture`] (non-collinear or collinear) at its standard place, turned about the
/// vertical through its origin to `poses` yaws evenly spaced over a full turn, so that every
/// wall is seen, not only the bookshelf's. Each capture's rig maps room points, as in
/// [`standard_capture`], which is the first capture here (yaw 0, same seed); capture `k` is
/// observed with seed `seed + k`.
pub fn turntable_captures(
    seed: u64,
    poses: usize,
    defects: &Defects,
    collinear: bool,
) -> Vec<(Rig, Observation)> {
    let scene = Scene::room(seed);
    let spec = if collinear {
        RigSpec::collinear(seed)
    } else {
        RigSpec::non_collinear(seed)
    };
    turntable_poses(poses)
        .enumerate()
        .map(|(k, pose)| {
            let rig = spec.build(&pose).expect("a turned preset rig stays valid");
            let observation = observe(&scene, &rig, defects, seed + k as u64);
            (rig, observation)
        })
        .collect()
}

/// `poses` poses of the rig at [`STANDARD_RIG_POSITION`], its yaw evenly spaced over a full
/// turn from 0.
fn turntable_poses(poses: usize) -> impl Iterator<Item = Pose> {
    (0..poses).map(move |k| {
        let yaw = std::f64::consts::TAU * k as f64 / poses.max(1) as f64;
        Pose::from_position_yaw(Point3::from(STANDARD_RIG_POSITION), yaw)
    })
}

/// The centroid of a rig's optical centres: the `rig_centre` of [`score()`].
pub fn rig_centre(rig: &Rig) -> Point3<f64> {
    let c = rig.cameras();
    Point3::from((c[0].centre().coords + c[1].centre().coords + c[2].centre().coords) / 3.0)
}

/// The strict score (the shared scorer's criterion) of 3D segments matched in the capture
/// `observation` of `rig`: its ground truth, its default eligible edges, tolerances from the
/// rig's centre.
pub fn score_capture(segments: &[Segment3], observation: &Observation, rig: &Rig) -> Score {
    score(
        segments,
        &observation.ground_truth,
        &eligible_intervals(observation),
        rig_centre(rig),
    )
}

impl Pooled {
    /// Scores one capture's answer ([`score_capture`]) and adds it, with the classes of its
    /// wrong segments; returns the capture's own score.
    pub fn add_capture(
        &mut self,
        segments: &[Segment3],
        observation: &Observation,
        rig: &Rig,
    ) -> Score {
        let s = score_capture(segments, observation, rig);
        self.add(&s);
        self.add_classes(&error_classes(
            segments,
            &s.matches,
            &observation.ground_truth,
            rig_centre(rig),
        ));
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trinocular_core::segment::Segment3;

    #[test]
    fn standard_capture_is_rich_and_scores_perfectly_against_itself() {
        let (scene, rig, obs) = standard_capture(1, Defects::clean(), false);
        let edges = scene.ground_truth_edges();
        assert_eq!(obs.ground_truth, edges);
        for c in 0..3 {
            let n = obs.lists[c].segments.len();
            assert!((150..=400).contains(&n), "camera {c}: {n} segments");
        }
        let eligible = eligible_intervals(&obs);
        let visible: Vec<Segment3> = obs
            .visible_all3
            .iter()
            .zip(&edges)
            .flat_map(|(ivs, e)| {
                ivs.iter().map(move |&(a, b)| Segment3 {
                    start: e.start + (e.end - e.start) * a,
                    end: e.start + (e.end - e.start) * b,
                })
            })
            .collect();
        let s = score(&visible, &edges, &eligible, rig_centre(&rig));
        assert_eq!(s.error_rate, Some(0.0));
        assert!((s.completeness.unwrap() - 1.0).abs() < 1e-9);
    }
}
