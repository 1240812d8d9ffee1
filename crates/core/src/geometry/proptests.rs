//! Property tests: project → rectify → transfer → triangulate ≈ identity, over random rigs
//! (rotated, with different intrinsics and distortion, collinear ones included).

use nalgebra::{Matrix3, Point2, Point3, Rotation3, Vector3};
use proptest::prelude::*;

use super::{
    estimate_line, estimate_line_constrained, estimate_line_through, Camera, DirectionOfLine,
    Distortion, KnownDirection, LineObservation, PointOnLine, Rectification, Rig, RigFrames,
};
use crate::segment::LineNoise;

/// A rig looking along rig +y (z up), cameras at the given centres with small rotations.
fn rig(centres: [Vector3<f64>; 3], angles: [[f64; 3]; 3], focals: [f64; 3], k1: f64) -> Rig {
    // Camera frame: x right, y down, z forward = rig +y.
    let base = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0);
    let cams = std::array::from_fn(|i| {
        let [a, b, c] = angles[i];
        let r = Rotation3::from_euler_angles(a, b, c).matrix() * base;
        let t = -(r * centres[i]);
        let k = Matrix3::new(
            focals[i],
            0.0,
            320.0,
            0.0,
            focals[i] * 1.01,
            240.0,
            0.0,
            0.0,
            1.0,
        );
        let d = (k1 != 0.0).then_some(Distortion {
            k1,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
        });
        Camera::from_krt(format!("cam{i}"), 640, 480, k, r, t, d).expect("valid camera")
    });
    Rig::new(cams).expect("distinct centres")
}

fn arb_rig() -> impl Strategy<Value = Rig> {
    let angle = -0.06..0.06f64;
    let angles = prop::array::uniform3(prop::array::uniform3(angle));
    let focals = prop::array::uniform3(400.0..900.0f64);
    (
        any::<bool>(),
        0.05..0.5f64,
        0.05..0.5f64,
        -0.3..0.3f64,
        angles,
        focals,
        -0.2..0.0f64,
    )
        .prop_map(|(collinear, b2, b3, tilt, angles, focals, k1)| {
            let c2 = Vector3::new(b2, 0.01 * b2, 0.0);
            let c3 = if collinear {
                c2 * (1.0 + b3 / b2)
            } else {
                Vector3::new(b3 * tilt, 0.0, b3)
            };
            rig([Vector3::zeros(), c2, c3], angles, focals, k1)
        })
}

/// The pixel where `cam` sees `x`, when it lies inside the image (beyond it, strong barrel
/// distortion folds over and no camera would report the point).
fn seen(cam: &Camera, x: &Point3<f64>) -> Option<Point2<f64>> {
    let p = cam.project(x)?;
    let inside = p.x >= 0.0
        && p.y >= 0.0
        && p.x <= cam.width() as f64 - 1.0
        && p.y <= cam.height() as f64 - 1.0;
    inside.then_some(p)
}

fn arb_point() -> impl Strategy<Value = Point3<f64>> {
    (-0.6..0.6f64, 1.0..8.0f64, -0.5..0.5f64).prop_map(|(x, y, z)| Point3::new(x * y, y, z * y))
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 300,
        max_global_rejects: 100_000,
        ..ProptestConfig::default()
    })]

    #[test]
    fn point_transfer_round_trips(rig in arb_rig(), x in arb_point()) {
        let rect = Rectification::new(&rig).unwrap();
        prop_assume!((0..3).all(|i| seen(rig.camera(i), &x).is_some()));
        let mut rects = Vec::new();
        for i in 0..3 {
            let cam = rig.camera(i);
            let pixel = cam.project(&x).unwrap();
            let a = rect.to_rect(i, cam.undistort(pixel)).unwrap();
            let (expected, _) = rect.project(i, &x).unwrap();
            prop_assert!((a - expected).norm() < 1e-6, "view {i}: {a} vs {expected}");
            let back = rect.from_rect(i, a).unwrap();
            prop_assert!((back - cam.undistort(pixel)).norm() < 1e-6);
            rects.push(a);
        }
        let delta = rect.disparity(0, rects[0], 1, rects[1]);
        let predicted = rect.transfer(0, rects[0], delta, 2);
        prop_assert!((predicted - rects[2]).norm() < 1e-6);
        let back = rect.point(0, rects[0], delta);
        prop_assert!((back - x).norm() < 1e-6 * x.coords.norm().max(1.0));
    }

    /// Any rig shape — the third camera ahead, behind, above or beside the first two: each
    /// pair found in its frame transfers exactly into the third view's.
    #[test]
    fn every_rig_shape_transfers_exactly(
        third in (-0.4..0.4f64, -0.4..0.4f64, -0.4..0.4f64),
        b2 in 0.1..0.5f64,
        angles in prop::array::uniform3(prop::array::uniform3(-0.06..0.06f64)),
        focals in prop::array::uniform3(400.0..900.0f64),
        x in arb_point(),
    ) {
        let c3 = Vector3::new(third.0, third.1, third.2);
        prop_assume!(c3.norm() > 0.05 && (c3 - Vector3::new(b2, 0.0, 0.0)).norm() > 0.05);
        let rig = rig([Vector3::zeros(), Vector3::new(b2, 0.0, 0.0), c3], angles, focals, 0.0);
        let Ok(frames) = RigFrames::new(&rig) else {
            return Ok(()); // a pair looking along its own baseline: refused, said elsewhere
        };
        prop_assume!((0..3).all(|i| seen(rig.camera(i), &x).is_some()));
        prop_assume!((0..3).all(|i| rig.camera(i).depth(&x) > 0.5));
        let in_frame = |frame: &Rectification, i: usize| {
            frame.to_rect(i, rig.camera(i).undistort(rig.camera(i).project(&x).unwrap()))
        };
        // A rig whose centres are within COLLINEAR_SPREAD of one line is the documented
        // collinear case: one frame whose plane holds the longest baseline, the others' small
        // offsets off that line neglected, so no pair is exact there (its own tests:
        // `collinear_rig_is_detected`). Found by this test: a third centre 2 mm off the line.
        if frames.shared && frames.pair_frames[0].collinear() {
            return Ok(());
        }
        for (f, (j, k)) in [(1usize, 2usize), (2, 1)].into_iter().enumerate() {
            let frame = &frames.pair_frames[f];
            let (Some(a1), Some(aj)) = (in_frame(frame, 0), in_frame(frame, j)) else {
                continue;
            };
            // The pair's epipolar lines are parallel in its frame: the two images share a row.
            let e = frame.epipolar(0, j).normalize();
            prop_assert!((aj - a1).perp(&e).abs() < 1e-6 * (1.0 + (aj - a1).norm()));
            let delta = frame.disparity(0, a1, j, aj);
            let Some(expected) = in_frame(frames.frame_of(k), k) else {
                continue;
            };
            let predicted = frames.transfer(f, a1, delta, k).unwrap();
            prop_assert!(
                (predicted - expected).norm() < 1e-6 * (1.0 + expected.coords.norm()),
                "pair (1, {}) to view {}: {predicted} vs {expected}", j + 1, k + 1
            );
        }
    }

    /// The maximum-likelihood estimate of exact images of a segment is that segment, with a
    /// zero χ², and a covariance that is symmetric and positive semi-definite.
    #[test]
    fn ml_line_round_trips(rig in arb_rig(), p in arb_point(), q in arb_point()) {
        prop_assume!((p - q).norm() > 0.2);
        let cams = [rig.camera(0), rig.camera(1), rig.camera(2)];
        prop_assume!(cams.iter().all(|c| seen(c, &p).is_some() && seen(c, &q).is_some()));
        let obs: Vec<LineObservation> = (0..3)
            .map(|v| {
                let c = cams[v];
                let (a, b) = (c.undistort(c.project(&p).unwrap()), c.undistort(c.project(&q).unwrap()));
                LineObservation { view: v, start: a, end: b, noise: LineNoise::for_list(0.3, (b - a).norm()), systematic_px: 0.0 }
            })
            .collect();
        prop_assume!(obs.iter().all(|o| (o.end - o.start).norm() > 5.0));
        let Some(est) = estimate_line(&cams, &obs, 1.0) else {
            return Ok(()); // undetermined (an epipolar plane of every pair)
        };
        prop_assert!(est.chi2 < 1e-6, "chi2 {}", est.chi2);
        prop_assert!((est.start - p).norm() < 1e-5 * p.coords.norm().max(1.0), "{} vs {}", est.start, p);
        prop_assert!((est.end - q).norm() < 1e-5 * q.coords.norm().max(1.0), "{} vs {}", est.end, q);
        let c = est.covariance;
        prop_assert!((c - c.transpose()).amax() <= 1e-9 * c.amax());
        let eig = nalgebra::SymmetricEigen::new(c).eigenvalues;
        prop_assert!(eig.iter().all(|&e| e >= -1e-9 * c.amax()), "{eig}");
    }
}

/// A facing triangle whose cameras differ a little in focal length and tilt, as real ones do.
fn uneven_triangle() -> Rig {
    rig(
        [
            Vector3::zeros(),
            Vector3::new(0.3, 0.01, 0.0),
            Vector3::new(0.15, 0.02, 0.25),
        ],
        [[0.0, 0.02, 0.0], [0.01, -0.02, 0.0], [0.0, 0.0, 0.03]],
        [520.0, 500.0, 540.0],
        0.0,
    )
}

/// A segment centred in the box `|x| ≤ half[0]`, `depth[0] ≤ y ≤ depth[1]`, `|z| ≤ half[1]`
/// (the rig looks along +y), of a length in `length`, in any direction.
fn random_segment(
    rng: &mut trinocular_synth::Rng,
    half: [f64; 2],
    depth: [f64; 2],
    length: [f64; 2],
) -> (Point3<f64>, Point3<f64>) {
    let centre = Point3::new(
        rng.range(-half[0], half[0]),
        rng.range(depth[0], depth[1]),
        rng.range(-half[1], half[1]),
    );
    let u = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
    let half_length = 0.5 * rng.range(length[0], length[1]);
    (centre - u * half_length, centre + u * half_length)
}

/// The squared normalised errors of `est`'s direction and of its midpoint across the line
/// (two degrees of freedom each) against the true segment `(p, q)`, under its covariance.
fn normalised_errors(est: &super::Line3Estimate, (p, q): (Point3<f64>, Point3<f64>)) -> (f64, f64) {
    let e = est.direction();
    let (e1, e2) = super::across_basis(&e);
    let basis = nalgebra::Matrix2x3::from_rows(&[e1.transpose(), e2.transpose()]);
    let u = (q - p).normalize();
    let truth = if u.dot(&e) < 0.0 { -u } else { u };
    let mid = nalgebra::center(&est.start, &est.end);
    let foot = p + truth * (mid - p).dot(&truth);
    let chi2 = |err: Vector3<f64>, cov: Matrix3<f64>| {
        let e2 = basis * err;
        let c2 = basis * cov * basis.transpose();
        (e2.transpose() * c2.try_inverse().unwrap() * e2)[(0, 0)]
    };
    (
        chi2(truth - e, est.direction_covariance()),
        chi2(foot - mid, est.midpoint_covariance()),
    )
}

/// The images of segment `(p, q)` in the three cameras, each line moved by exactly the noise
/// it states (a line fitted to a point per 2 px, each off by 0.4 px): offset at the midpoint,
/// turned about it. `None` when a camera does not see it or sees it under 15 px.
fn noisy_images(
    cams: &[&Camera; 3],
    (p, q): (Point3<f64>, Point3<f64>),
    rng: &mut trinocular_synth::Rng,
) -> Option<Vec<LineObservation>> {
    let mut obs = Vec::with_capacity(3);
    for (v, cam) in cams.iter().enumerate() {
        let (a, b) = (seen(cam, &p)?, seen(cam, &q)?);
        let len = (b - a).norm();
        if len < 15.0 {
            return None;
        }
        let noise = LineNoise::from_point_fit(0.4, len / 2.0, len);
        let dir = (b - a) / len;
        let normal = nalgebra::Vector2::new(-dir.y, dir.x);
        let m = nalgebra::center(&a, &b) + normal * (noise.offset_px * rng.normal());
        let d = nalgebra::Rotation2::new(noise.angle_rad * rng.normal()) * dir;
        obs.push(LineObservation {
            view: v,
            start: m - d * len / 2.0,
            end: m + d * len / 2.0,
            noise,
            systematic_px: 0.0,
        });
    }
    Some(obs)
}

/// χ²'s 95% and 99% quantiles for two degrees of freedom (a direction, or a point across a
/// line): the calibration goal's bounds.
const CHI2_2DOF_Q95: f64 = 5.991_464_547;
const CHI2_2DOF_Q99: f64 = 9.210_340_372;
/// Segments each calibration test scores, and draws it may take to find them.
const CALIBRATION_SAMPLES: usize = 2000;
const CALIBRATION_DRAWS: usize = 200_000;
/// `for_each_estimate`'s box of short segments (8–25 cm, 2–4 m away): the ones whose
/// direction the gate refuses, which a vertex, a direction or a plane is there to narrow.
const SHORT_SEGMENTS: ([f64; 2], [f64; 2], [f64; 2]) = ([0.8, 0.6], [2.0, 4.0], [0.08, 0.25]);
/// The variance of a known direction, or a plane's tilt, in the tests that give one: 0.3°
/// squared, radians².
fn known_variance() -> f64 {
    0.3f64.to_radians().powi(2)
}

/// The calibration goal: of the squared normalised errors, >= 93% within χ²'s 95%
/// quantile and >= 98% within its 99% (`within95`, `within99`: the shares measured).
fn assert_calibrated(what: &str, within95: f64, within99: f64) {
    assert!(
        within95 >= 0.93 && within99 >= 0.98,
        "{what} {within95} {within99}"
    );
}

/// How many estimates' direction and position errors (squared, normalised: two degrees of
/// freedom each) fell within χ²'s 95% and 99% quantiles.
#[derive(Debug, Default)]
struct WithinQuantiles {
    direction: [usize; 2],
    position: [usize; 2],
}

impl WithinQuantiles {
    fn count(&mut self, (direction, position): (f64, f64)) {
        for (counts, chi2) in [
            (&mut self.direction, direction),
            (&mut self.position, position),
        ] {
            counts[0] += usize::from(chi2 <= CHI2_2DOF_Q95);
            counts[1] += usize::from(chi2 <= CHI2_2DOF_Q99);
        }
    }

    /// The shares of `n` estimates: direction within q95, q99; position within q95, q99.
    fn shares(&self, n: usize) -> [f64; 4] {
        let share = |k: usize| k as f64 / n as f64;
        [
            share(self.direction[0]),
            share(self.direction[1]),
            share(self.position[0]),
            share(self.position[1]),
        ]
    }

    /// Prints the shares (the position called `position`) after `label`, and asserts both
    /// calibrated; returns them.
    fn assert_calibrated(&self, n: usize, position: &str, label: &str) -> [f64; 4] {
        let [d95, d99, p95, p99] = self.shares(n);
        println!(
            "direction {d95:.3} / {d99:.3}, {position} {p95:.3} / {p99:.3} within chi2 q95 / \
             q99; {label}"
        );
        assert_calibrated("direction", d95, d99);
        assert_calibrated(position, p95, p99);
        [d95, d99, p95, p99]
    }
}

/// Draws segments from `random_segment`'s box (`half`, `depth`, `length`), images them with
/// [`noisy_images`] and estimates each from its three lines, until `visit` has counted
/// [`CALIBRATION_SAMPLES`] of them (it returns whether it counted one) or the draws run out;
/// returns how many it counted. `visit` gets the generator to draw more of its own, in order.
fn for_each_estimate(
    cams: &[&Camera; 3],
    rng: &mut trinocular_synth::Rng,
    (half, depth, length): ([f64; 2], [f64; 2], [f64; 2]),
    mut visit: impl FnMut(
        &mut trinocular_synth::Rng,
        (Point3<f64>, Point3<f64>),
        &[LineObservation],
        super::Line3Estimate,
    ) -> bool,
) -> usize {
    let mut n = 0;
    for _ in 0..CALIBRATION_DRAWS {
        if n == CALIBRATION_SAMPLES {
            break;
        }
        let (p, q) = random_segment(rng, half, depth, length);
        let Some(obs) = noisy_images(cams, (p, q), rng) else {
            continue;
        };
        let Some(est) = estimate_line(cams, &obs, 1.0) else {
            continue;
        };
        n += usize::from(visit(rng, (p, q), &obs, est));
    }
    n
}

/// Checks that [`for_each_estimate`] counted every sample it was asked for (`n`), and returns
/// the median of `ratios`, one per sample.
fn all_counted_and_median(n: usize, mut ratios: Vec<f64>) -> f64 {
    assert_eq!(
        n, CALIBRATION_SAMPLES,
        "too few segments seen by all three cameras"
    );
    ratios.sort_by(f64::total_cmp);
    ratios[n / 2]
}

/// When the image lines carry exactly the noise they state, the reported covariance describes
/// the true errors: squared normalised errors of the direction and of the midpoint (2 degrees
/// of freedom each) fall within χ²'s 95% and 99% quantiles as often as they should. This is
/// the first-order propagation the accuracy goal relies on, checked on its own.
#[test]
fn ml_covariance_is_calibrated_when_the_noise_is_as_stated() {
    use trinocular_synth::Rng;
    let r = uneven_triangle();
    let cams = [r.camera(0), r.camera(1), r.camera(2)];
    let mut rng = Rng::new(7);
    let mut within = WithinQuantiles::default();
    // Segments 2–5 m in front (the rig looks along +y), 0.2–1.2 m long, any direction.
    let n = for_each_estimate(
        &cams,
        &mut rng,
        ([1.0, 0.8], [2.0, 5.0], [0.2, 1.2]),
        |_, truth, _, est| {
            within.count(normalised_errors(&est, truth));
            true
        },
    );
    assert_eq!(
        n, CALIBRATION_SAMPLES,
        "too few segments seen by all three cameras"
    );
    let [d95, _, p95, _] = within.assert_calibrated(n, "position", "the images alone");
    // ...and not by inflating it: no more than 99.5% within the 95% quantile.
    assert!(d95 <= 0.995 && p95 <= 0.995, "too wide: {d95} {p95}");
}

#[test]
fn collinear_rig_is_detected() {
    let r = rig(
        [
            Vector3::zeros(),
            Vector3::new(0.12, 0.0, 0.0),
            Vector3::new(0.24, 0.0, 0.0),
        ],
        [[0.0; 3]; 3],
        [600.0; 3],
        0.0,
    );
    let rect = Rectification::new(&r).unwrap();
    assert!(rect.collinear());
    assert!(rect.out_of_plane_m() < 1e-12);
    let r = rig(
        [
            Vector3::zeros(),
            Vector3::new(0.3, 0.0, 0.0),
            Vector3::new(0.15, 0.0, 0.25),
        ],
        [[0.0; 3]; 3],
        [600.0; 3],
        0.0,
    );
    assert!(!Rectification::new(&r).unwrap().collinear());
    assert!(RigFrames::new(&r).unwrap().shared);
    // The third camera ahead, all at one height: the plane of centres is level, at right
    // angles to the view, so each pair gets its own frame; the forward pair is not searched.
    let r = rig(
        [
            Vector3::zeros(),
            Vector3::new(0.3, 0.0, 0.0),
            Vector3::new(0.15, 0.25, 0.0),
        ],
        [[0.0; 3]; 3],
        [600.0; 3],
        0.0,
    );
    let frames = RigFrames::new(&r).unwrap();
    assert!(!frames.shared);
    assert_eq!(frames.searched, [true, false]);
    assert!(!frames.pair_frames[0].collinear());
}

#[test]
fn direction_uncertainty_grows_for_short_and_receding_segments() {
    let r = rig(
        [
            Vector3::zeros(),
            Vector3::new(0.3, 0.0, 0.0),
            Vector3::new(0.15, 0.0, 0.25),
        ],
        [[0.0; 3]; 3],
        [600.0; 3],
        0.0,
    );
    let cams = [r.camera(0), r.camera(1), r.camera(2)];
    let sigma = |a: Point3<f64>, b: Point3<f64>| {
        let obs: Vec<LineObservation> = (0..3)
            .map(|v| {
                let (p, q) = (cams[v].project(&a).unwrap(), cams[v].project(&b).unwrap());
                let noise = LineNoise::for_list(0.3, (q - p).norm());
                LineObservation {
                    view: v,
                    start: p,
                    end: q,
                    noise,
                    systematic_px: 0.0,
                }
            })
            .collect();
        let est = estimate_line(&cams, &obs, 1.0).expect("determined");
        est.direction_covariance().trace().sqrt()
    };
    let long = sigma(Point3::new(-0.5, 3.0, 0.3), Point3::new(0.5, 3.0, 0.3));
    let short = sigma(Point3::new(-0.05, 3.0, 0.3), Point3::new(0.05, 3.0, 0.3));
    let far = sigma(Point3::new(-0.5, 6.0, 0.3), Point3::new(0.5, 6.0, 0.3));
    assert!(
        short > 5.0 * long && far > 2.0 * long,
        "{long} {short} {far}"
    );
}

/// A known point the line passes through (a vertex another segment measured) is an
/// observation like the images: with none the estimate is [`estimate_line`]'s to the bit; with
/// one at an end of a short segment the direction narrows, and the narrower covariance still
/// describes the true errors when the point carries exactly its stated noise.
#[test]
fn a_known_vertex_narrows_a_short_segments_direction_and_stays_calibrated() {
    use trinocular_synth::Rng;
    let r = uneven_triangle();
    let cams = [r.camera(0), r.camera(1), r.camera(2)];
    let mut rng = Rng::new(11);
    let (mut dir95, mut dir99, mut narrower) = (0, 0, 0);
    let mut sigma_ratios = Vec::new();
    // Short segments (8–25 cm, 2–4 m away): the ones whose direction the gate refuses.
    let n = for_each_estimate(
        &cams,
        &mut rng,
        SHORT_SEGMENTS,
        |rng, (p, q), obs, alone| {
            assert_eq!(
                estimate_line_through(&cams, obs, 1.0, &[]),
                Some(alone),
                "no vertex: the same estimate to the bit"
            );
            // The vertex at p, measured to 5 mm across and 1 cm along an arbitrary axis, and
            // off by exactly that noise.
            let axis = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
            let covariance = Matrix3::identity() * 0.005f64.powi(2)
                + axis * axis.transpose() * 0.0075f64.powi(2);
            let draw = covariance.cholesky().unwrap().l()
                * Vector3::new(rng.normal(), rng.normal(), rng.normal());
            let vertex = PointOnLine {
                point: p + draw,
                covariance,
            };
            let Some(est) = estimate_line_through(&cams, obs, 1.0, &[vertex]) else {
                return false;
            };
            let chi2 = normalised_errors(&est, (p, q)).0;
            let sigma = |c: nalgebra::Matrix3<f64>| c.trace().sqrt();
            let ratio = sigma(est.direction_covariance()) / sigma(alone.direction_covariance());
            sigma_ratios.push(ratio);
            narrower += usize::from(ratio < 1.0);
            dir95 += usize::from(chi2 <= CHI2_2DOF_Q95);
            dir99 += usize::from(chi2 <= CHI2_2DOF_Q99);
            assert_eq!(
                est.dof,
                alone.dof + 2,
                "a point adds two degrees of freedom"
            );
            true
        },
    );
    let median_ratio = all_counted_and_median(n, sigma_ratios);
    let share = |k: usize| k as f64 / n as f64;
    println!(
        "direction {:.3} / {:.3} within chi2 q95 / q99; direction sigma with the vertex / \
         without, median {median_ratio:.2}; narrower for {:.3}",
        share(dir95),
        share(dir99),
        share(narrower)
    );
    assert_calibrated("direction", share(dir95), share(dir99));
    // A vertex 5 mm across at one end of a 8–25 cm segment is worth a good deal of its
    // direction: at the median, at least a fifth narrower.
    assert!(median_ratio < 0.8, "median ratio {median_ratio}");
    assert!(share(narrower) > 0.95, "narrower for {}", share(narrower));
}

/// A known direction of the line (the scene's dominant one it lies along) is an observation
/// like a known point: it narrows a short segment's direction to about its own spread, and
/// the estimate's direction and midpoint covariances still describe the true errors when
/// the direction is off by exactly its stated variance.
#[test]
fn a_known_direction_narrows_a_short_segment_and_stays_calibrated() {
    use trinocular_synth::Rng;
    let r = uneven_triangle();
    let cams = [r.camera(0), r.camera(1), r.camera(2)];
    let mut rng = Rng::new(17);
    let mut within = WithinQuantiles::default();
    let mut sigma_ratios = Vec::new();
    let n = for_each_estimate(
        &cams,
        &mut rng,
        SHORT_SEGMENTS,
        |rng, (p, q), obs, alone| {
            // The direction known to 0.3° per axis across it, and off by exactly that.
            let variance = known_variance();
            let u = (q - p).normalize();
            let (e1, e2) = super::across_basis(&u);
            let known = (u + (e1 * rng.normal() + e2 * rng.normal()) * variance.sqrt()).normalize();
            let along = KnownDirection::Along(DirectionOfLine {
                direction: -known,
                variance,
            });
            let Some(est) = estimate_line_constrained(&cams, obs, 1.0, &[], Some(&along)) else {
                return false;
            };
            assert_eq!(
                est.dof,
                alone.dof + 2,
                "a direction adds two degrees of freedom"
            );
            within.count(normalised_errors(&est, (p, q)));
            let sigma = |c: Matrix3<f64>| c.trace().sqrt();
            sigma_ratios
                .push(sigma(est.direction_covariance()) / sigma(alone.direction_covariance()));
            true
        },
    );
    let median_ratio = all_counted_and_median(n, sigma_ratios);
    within.assert_calibrated(
        n,
        "midpoint",
        &format!("direction sigma along the known direction / alone, median {median_ratio:.2}"),
    );
    // 0.3° against the several degrees that 8–25 cm at 2–4 m leave a short segment.
    assert!(median_ratio < 0.3, "median ratio {median_ratio}");
    // With no direction it is the estimate through no point, to the bit.
    let segment = (Point3::new(-0.1, 3.0, 0.2), Point3::new(0.1, 3.1, 0.3));
    let obs = noisy_images(&cams, segment, &mut rng).expect("seen by all three");
    assert_eq!(
        estimate_line_constrained(&cams, &obs, 1.0, &[], None),
        estimate_line(&cams, &obs, 1.0)
    );
}

/// A plane the line is known to lie in (a room's horizontal, its vertical known) is one
/// observation of the line's tilt out of it: the tilt's σ falls to about the plane's, the
/// turn within the plane keeps what the images say given the tilt (linear Gaussian fusion of
/// one degree of freedom), and the covariances still describe the true errors when the plane
/// is off by exactly its stated variance.
#[test]
fn a_known_plane_of_directions_is_one_observation_of_the_tilt_and_stays_calibrated() {
    use trinocular_synth::Rng;
    let r = uneven_triangle();
    let cams = [r.camera(0), r.camera(1), r.camera(2)];
    let mut rng = Rng::new(23);
    let mut within = WithinQuantiles::default();
    let (mut out_ratios, mut in_ratios) = (Vec::new(), Vec::new());
    let n = for_each_estimate(
        &cams,
        &mut rng,
        SHORT_SEGMENTS,
        |rng, (p, q), obs, alone| {
            // A plane of directions through the true one: its normal any unit vector
            // across the line, tilted by exactly the stated 0.3°.
            let variance = known_variance();
            let u = (q - p).normalize();
            let (e1, e2) = super::across_basis(&u);
            let turn = rng.uniform() * std::f64::consts::TAU;
            let normal = e1 * turn.cos() + e2 * turn.sin();
            let tilted = (normal + u * rng.normal() * variance.sqrt()).normalize();
            let across = KnownDirection::Across(DirectionOfLine {
                direction: tilted,
                variance,
            });
            let Some(est) = estimate_line_constrained(&cams, obs, 1.0, &[], Some(&across)) else {
                return false;
            };
            assert_eq!(est.dof, alone.dof + 1, "a plane adds one degree of freedom");
            within.count(normalised_errors(&est, (p, q)));
            // The estimate's direction across the line, in the plane's terms (its normal,
            // and the line's turn within it), against the images alone conditioned on one
            // observation of the tilt: linear Gaussian fusion, which the fit should match.
            let in_plane = u.cross(&normal);
            let basis = nalgebra::Matrix3x2::from_columns(&[normal, in_plane]);
            let project = |c: Matrix3<f64>| basis.transpose() * c * basis;
            let with_plane = project(est.direction_covariance());
            let alone_2 = project(alone.direction_covariance());
            let predicted = alone_2.try_inverse().and_then(|info| {
                (info + nalgebra::Matrix2::new(1.0 / variance, 0.0, 0.0, 0.0)).try_inverse()
            });
            let Some(predicted) = predicted else {
                return false;
            };
            out_ratios.push((with_plane[(0, 0)] / alone_2[(0, 0)]).sqrt());
            in_ratios.push((with_plane[(1, 1)] / predicted[(1, 1)]).sqrt());
            true
        },
    );
    let out_median = all_counted_and_median(n, out_ratios);
    let in_median = all_counted_and_median(n, in_ratios);
    within.assert_calibrated(
        n,
        "midpoint",
        &format!(
            "direction sigma out of the plane, with it / alone, median {out_median:.2}; within \
             it, against one observation of the tilt fused with the images' covariance, median \
             {in_median:.3}"
        ),
    );
    // Out of the plane the 0.3° replaces the several degrees a short segment has alone;
    // within it what is left is what the images say once the tilt is known: one degree of
    // freedom, not two.
    assert!(
        out_median < 0.3,
        "out of the plane, median ratio {out_median}"
    );
    assert!(
        (0.9..1.1).contains(&in_median),
        "within the plane, median ratio {in_median}"
    );
}

/// Each view's line shifted across itself by an independent N(0, δ²), and by nothing else:
/// the spread of the estimates' midpoints is what `systematic_covariance` says it is.
#[test]
fn the_systematic_covariance_describes_independent_shifts_of_the_views() {
    use trinocular_synth::Rng;
    let r = uneven_triangle();
    let cams = [r.camera(0), r.camera(1), r.camera(2)];
    let mut rng = Rng::new(5);
    let (a, b) = (Point3::new(-0.3, 0.2, 3.0), Point3::new(0.4, 0.1, 3.4));
    let delta = 0.2;
    let exact: Vec<LineObservation> = (0..3)
        .map(|v| {
            let (p, q) = (cams[v].project(&a).unwrap(), cams[v].project(&b).unwrap());
            LineObservation {
                view: v,
                start: p,
                end: q,
                noise: LineNoise::for_list(0.3, (q - p).norm()),
                systematic_px: delta,
            }
        })
        .collect();
    let reference = estimate_line(&cams, &exact, 1.0).expect("determined");
    let mut scatter = Matrix3::<f64>::zeros();
    let trials = 4000;
    let mid = nalgebra::center(&reference.start, &reference.end);
    for _ in 0..trials {
        let obs: Vec<LineObservation> = exact
            .iter()
            .map(|o| {
                let d = (o.end - o.start).normalize();
                let shift = nalgebra::Vector2::new(-d.y, d.x) * (delta * rng.normal());
                LineObservation {
                    start: o.start + shift,
                    end: o.end + shift,
                    ..*o
                }
            })
            .collect();
        let est = estimate_line(&cams, &obs, 1.0).expect("determined");
        let m = nalgebra::center(&est.start, &est.end) - mid;
        scatter += m * m.transpose() / trials as f64;
    }
    let u = reference.direction();
    let across = super::line::across_projector(&u);
    let measured = across * scatter * across;
    let predicted = super::line::midpoint_covariance(
        &reference.start,
        &reference.end,
        &reference.systematic_covariance(),
    );
    let (m, p) = (measured.trace(), predicted.trace());
    assert!((m / p - 1.0).abs() < 0.1, "measured {m:e}, predicted {p:e}");
}

/// The exact images of `(p, q)` in every camera of `cams`, the view `short` (if any) seeing
/// only its part from `p` to `p + share·(q − p)`.
fn exact_images(
    cams: &[&Camera; 3],
    (p, q): (Point3<f64>, Point3<f64>),
    short: &[(usize, f64)],
) -> Vec<LineObservation> {
    (0..3)
        .map(|v| {
            let share = short.iter().find(|s| s.0 == v).map_or(1.0, |s| s.1);
            let end = p + (q - p) * share;
            let (a, b) = (seen(cams[v], &p).unwrap(), seen(cams[v], &end).unwrap());
            LineObservation {
                view: v,
                start: a,
                end: b,
                noise: LineNoise::for_list(0.3, (b - a).norm()),
                systematic_px: 0.0,
            }
        })
        .collect()
}

#[test]
fn an_end_is_known_along_the_line_as_the_views_place_it_wherever_the_line_runs() {
    // A vertical segment 3 m ahead, its middle more than a metre above the point of its line
    // nearest the rig (where the estimate starts from): along the line each end is known to
    // about a pixel's worth (1 px at 3 m through a 520-px focal length: 6 mm), not to the
    // distance between those two points.
    let rig = uneven_triangle();
    let cams = [rig.camera(0), rig.camera(1), rig.camera(2)];
    let segment = (Point3::new(0.4, 3.0, 1.0), Point3::new(0.4, 3.0, 1.3));
    let est = estimate_line(&cams, &exact_images(&cams, segment, &[]), 1.0).expect("determined");
    let u = est.direction();
    for block in [0, 3] {
        let along = (u.transpose() * est.covariance.fixed_view::<3, 3>(block, block) * u)[(0, 0)];
        assert!(along.sqrt() < 0.01, "{} m along", along.sqrt());
    }
    // Every view saw the whole segment: no end reaches past what they all saw.
    assert!(est.reach_m.iter().all(|&r| r < 1e-9), "{:?}", est.reach_m);
}

#[test]
fn two_views_carrying_an_end_past_the_third_say_how_far() {
    let rig = uneven_triangle();
    let cams = [rig.camera(0), rig.camera(1), rig.camera(2)];
    let (p, q) = (Point3::new(-0.3, 3.0, 0.2), Point3::new(0.5, 3.2, 0.1));
    // The third view sees 80% of it: the segment is the part all three saw, and the other two
    // carry its end on by the rest.
    let est =
        estimate_line(&cams, &exact_images(&cams, (p, q), &[(2, 0.8)]), 1.0).expect("determined");
    let short_end = p + (q - p) * 0.8;
    assert!((est.end - short_end).norm() < 1e-6, "{}", est.end);
    assert!(est.reach_m[0] < 1e-9, "{:?}", est.reach_m);
    assert!(
        (est.reach_m[1] - 0.2 * (q - p).norm()).abs() < 1e-6,
        "{:?}",
        est.reach_m
    );
    // Two views stopping short: the end reaches to the middle one, not to the one that runs
    // on.
    let est = estimate_line(
        &cams,
        &exact_images(&cams, (p, q), &[(1, 0.8), (2, 0.7)]),
        1.0,
    )
    .expect("determined");
    assert!(
        (est.reach_m[1] - 0.1 * (q - p).norm()).abs() < 1e-6,
        "{:?}",
        est.reach_m
    );
}
