//! Property tests: project → rectify → transfer → triangulate ≈ identity, over random rigs
//! (rotated, with different intrinsics and distortion, collinear ones included).

use nalgebra::{Matrix3, Point2, Point3, Rotation3, Vector3};
use proptest::prelude::*;

use super::{estimate_line, Camera, Distortion, LineObservation, Rectification, Rig, RigFrames};
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
                LineObservation { view: v, start: a, end: b, noise: LineNoise::for_list(0.3, (b - a).norm()) }
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

/// When the image lines carry exactly the noise they state, the reported covariance describes
/// the true errors: squared normalised errors of the direction and of the midpoint (2 degrees
/// of freedom each) fall within χ²'s 95% and 99% quantiles as often as they should. This is
/// the first-order propagation the accuracy goal relies on, checked on its own.
#[test]
fn ml_covariance_is_calibrated_when_the_noise_is_as_stated() {
    use trinocular_synth::Rng;
    let r = rig(
        [
            Vector3::zeros(),
            Vector3::new(0.3, 0.01, 0.0),
            Vector3::new(0.15, 0.02, 0.25),
        ],
        [[0.0, 0.02, 0.0], [0.01, -0.02, 0.0], [0.0, 0.0, 0.03]],
        [520.0, 500.0, 540.0],
        0.0,
    );
    let cams = [r.camera(0), r.camera(1), r.camera(2)];
    let mut rng = Rng::new(7);
    let (mut n, mut dir95, mut dir99, mut pos95, mut pos99) = (0usize, 0, 0, 0, 0);
    let (q95, q99) = (5.991_464_547, 9.210_340_372);
    for _ in 0..200_000 {
        if n == 2000 {
            break;
        }
        // A segment 2–5 m in front (the rig looks along +y), 0.2–1.2 m long, any direction.
        let centre = Point3::new(
            rng.range(-1.0, 1.0),
            rng.range(2.0, 5.0),
            rng.range(-0.8, 0.8),
        );
        let u = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
        let half = 0.5 * rng.range(0.2, 1.2);
        let (p, q) = (centre - u * half, centre + u * half);
        let mut obs = Vec::new();
        for (v, cam) in cams.iter().enumerate() {
            let (Some(a), Some(b)) = (seen(cam, &p), seen(cam, &q)) else {
                break;
            };
            let len = (b - a).norm();
            if len < 15.0 {
                break;
            }
            let noise = LineNoise::from_point_fit(0.4, len / 2.0, len);
            // Move the line by its stated noise: offset at the midpoint, turn about it.
            let dir = (b - a) / len;
            let normal = nalgebra::Vector2::new(-dir.y, dir.x);
            let shift = normal * (noise.offset_px * rng.normal());
            let turn = noise.angle_rad * rng.normal();
            let m = nalgebra::center(&a, &b) + shift;
            let d = nalgebra::Rotation2::new(turn) * dir;
            obs.push(LineObservation {
                view: v,
                start: m - d * len / 2.0,
                end: m + d * len / 2.0,
                noise,
            });
        }
        if obs.len() < 3 {
            continue;
        }
        let Some(est) = estimate_line(&cams, &obs, 1.0) else {
            continue;
        };
        let (dir_cov, mid_cov) = (est.direction_covariance(), est.midpoint_covariance());
        let e = est.direction();
        let (e1, e2) = super::across_basis(&e);
        let basis = nalgebra::Matrix2x3::from_rows(&[e1.transpose(), e2.transpose()]);
        let truth = if u.dot(&e) < 0.0 { -u } else { u };
        let mid = nalgebra::center(&est.start, &est.end);
        let foot = p + truth * (mid - p).dot(&truth);
        let chi2 = |err: Vector3<f64>, cov: nalgebra::Matrix3<f64>| {
            let e2 = basis * err;
            let c2 = basis * cov * basis.transpose();
            (e2.transpose() * c2.try_inverse().unwrap() * e2)[(0, 0)]
        };
        let (cd, cp) = (chi2(truth - e, dir_cov), chi2(foot - mid, mid_cov));
        n += 1;
        dir95 += usize::from(cd <= q95);
        dir99 += usize::from(cd <= q99);
        pos95 += usize::from(cp <= q95);
        pos99 += usize::from(cp <= q99);
    }
    assert_eq!(n, 2000, "too few segments seen by all three cameras");
    let share = |k: usize| k as f64 / n as f64;
    println!(
        "direction {:.3} / {:.3}, position {:.3} / {:.3} within chi2 q95 / q99",
        share(dir95),
        share(dir99),
        share(pos95),
        share(pos99)
    );
    // The calibration goal: >= 93% within the 95% quantile, >= 98% within the 99%.
    assert!(
        share(dir95) >= 0.93 && share(dir99) >= 0.98,
        "direction {} {}",
        share(dir95),
        share(dir99)
    );
    assert!(
        share(pos95) >= 0.93 && share(pos99) >= 0.98,
        "position {} {}",
        share(pos95),
        share(pos99)
    );
    // ...and not by inflating it: no more than 99.5% within the 95% quantile.
    assert!(
        share(dir95) <= 0.995 && share(pos95) <= 0.995,
        "too wide: {} {}",
        share(dir95),
        share(pos95)
    );
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
