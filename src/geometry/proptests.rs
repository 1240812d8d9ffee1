//! Property tests: project → rectify → transfer → triangulate ≈ identity, over random rigs
//! (rotated, with different intrinsics and distortion, collinear ones included).

use nalgebra::{Matrix3, Point2, Point3, Rotation3, Vector3};
use proptest::prelude::*;

use super::{triangulate_line, Camera, Distortion, Rectification, Rig};

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

    #[test]
    fn line_triangulation_round_trips(rig in arb_rig(), p in arb_point(), q in arb_point()) {
        prop_assume!((p - q).norm() > 0.2);
        let cams = [rig.camera(0), rig.camera(1), rig.camera(2)];
        prop_assume!(cams.iter().all(|c| seen(c, &p).is_some() && seen(c, &q).is_some()));
        let segs: Vec<(Point2<f64>, Point2<f64>)> = cams
            .iter()
            .map(|c| (c.undistort(c.project(&p).unwrap()), c.undistort(c.project(&q).unwrap())))
            .collect();
        // A line in an epipolar plane of every pair is undetermined: skip those.
        let Some(fit) = triangulate_line(&cams, &segs) else {
            return Ok(());
        };
        prop_assert!(fit.residual_px < 1e-5, "residual {}", fit.residual_px);
        prop_assert!((fit.start - p).norm() < 1e-5, "{} vs {}", fit.start, p);
        prop_assert!((fit.end - q).norm() < 1e-5, "{} vs {}", fit.end, q);
    }
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
    let rect = Rectification::new(&r).unwrap();
    let sigma = |a: Point3<f64>, b: Point3<f64>| rect.direction_sigma(&a, &b, 0.1);
    let long = sigma(Point3::new(-0.5, 3.0, 0.3), Point3::new(0.5, 3.0, 0.3));
    let short = sigma(Point3::new(-0.05, 3.0, 0.3), Point3::new(0.05, 3.0, 0.3));
    let far = sigma(Point3::new(-0.5, 6.0, 0.3), Point3::new(0.5, 6.0, 0.3));
    assert!(
        short > 5.0 * long && far > 2.0 * long,
        "{long} {short} {far}"
    );
}
