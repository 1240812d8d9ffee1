//! Calibration benchmarks (criterion, release): `estimate/pinhole` and `estimate/distortion`
//! fit one 512×512 camera to the default pattern's 368 reference points (two boards),
//! observed from 1.1 m with σ = 0.2 px noise, with and without plumb_bob distortion.
//!
//!     cargo bench --bench calibrate

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Matrix3, Point2, Point3, Vector3};
use trinocular::calibrate::{estimate_camera, CalibrationPattern, EstimateOptions};
use trinocular::geometry::{Camera, Distortion};
use trinocular::synth::rng::Rng;

/// A camera looking at the pattern's centre from the side both boards face.
fn camera(distortion: Option<Distortion>) -> Camera {
    let target = Point3::new(0.25, 0.25, 0.27);
    let centre = target + Vector3::new(0.75, 0.7, 0.3);
    let z = (target - centre).normalize();
    let x = (-Vector3::z()).cross(&z).normalize();
    let y = z.cross(&x);
    let rotation = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    let k = Matrix3::new(560.0, 0.0, 258.0, 0.0, 563.0, 250.0, 0.0, 0.0, 1.0);
    Camera::from_krt(
        "bench",
        512,
        512,
        k,
        rotation,
        -(rotation * centre.coords),
        distortion,
    )
    .unwrap()
}

fn observations(camera: &Camera) -> (Vec<Point3<f64>>, Vec<Point2<f64>>) {
    let mut rng = Rng::new(42);
    CalibrationPattern::default()
        .reference_points()
        .into_iter()
        .map(|(_, x)| {
            let p = camera.project(&x).unwrap();
            (
                x,
                p + 0.2 * nalgebra::Vector2::new(rng.normal(), rng.normal()),
            )
        })
        .unzip()
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("estimate");
    for (name, distortion) in [
        ("pinhole", None),
        (
            "distortion",
            Some(Distortion {
                k1: -0.2,
                k2: 0.03,
                p1: 5e-4,
                p2: -3e-4,
                k3: 0.0,
            }),
        ),
    ] {
        let (p3, p2) = observations(&camera(distortion));
        assert_eq!(p3.len(), 368);
        let options = EstimateOptions {
            distortion: distortion.is_some(),
            ..EstimateOptions::default()
        };
        group.bench_function(name, |b| {
            b.iter(|| estimate_camera("bench", 512, 512, &p3, &p2, &options).unwrap())
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
