//! Scenes of any size, for benchmarks: `n` axis-aligned 3D segments scattered in front of the
//! rig, projected exactly into its three views (no occlusion), each list shuffled and topped
//! up with clutter. The standard room has a few hundred segments per image; this reaches 600
//! or 10,000. The sensor grows with `n` (512x512 at 600 segments; same optics, so a wider
//! field of view), so the *density* of segments and the pixel extent of the disparity search
//! — the ambiguity a matcher faces per segment — stay those of a 512x512 image with 600
//! segments: how time grows with `n` then measures the algorithm, not the quadratic growth of
//! accidental alignments in an ever more crowded image. For the same reason segment lengths
//! are drawn in pixels, not metres: a wide sensor's off-axis segments would otherwise project
//! longer and crowd the image.

use nalgebra::{Point3, Vector3};

use super::rig::{Pose, RigSpec};
use super::rng::Rng;
use trinocular_core::geometry::Rig;
use trinocular_core::segment::{Segment2, SegmentList};

/// A rig (non-collinear preset) and three oriented segment lists with about `n` segments
/// each: `n / (1 + clutter_fraction)` projected scene segments plus clutter.
pub fn scattered_capture(
    n: usize,
    endpoint_noise_px: f64,
    clutter_fraction: f64,
    seed: u64,
) -> (Rig, [SegmentList; 3]) {
    let mut spec = RigSpec::non_collinear(seed);
    let scale = (n as f64 / 600.0).sqrt().max(1.0);
    spec.width = (spec.width as f64 * scale).round() as u32;
    spec.height = (spec.height as f64 * scale).round() as u32;
    for c in &mut spec.cameras {
        c.cx *= scale;
        c.cy *= scale;
    }
    let rig = spec
        .build(&Pose::identity())
        .expect("preset rigs scaled up stay valid");
    let mut rng = Rng::new(seed).fork(0x5ca7);
    let real = (n as f64 / (1.0 + clutter_fraction)).round() as usize;
    let mut lists: [SegmentList; 3] = std::array::from_fn(|_| SegmentList {
        segments: Vec::with_capacity(n),
        oriented: true,
        background_gradient: None,
    });
    let cam = rig.camera(0);
    let (w, h) = (cam.width() as f64, cam.height() as f64);
    let mut made = 0;
    let mut attempts = 0;
    while made < real && attempts < 50 * real.max(1) {
        attempts += 1;
        // A point in camera 1's field of view, 1.5–6 m away.
        let depth = rng.range(1.5, 6.0);
        let (u, v) = (rng.range(0.0, w), rng.range(0.0, h));
        let ray = cam.ray(nalgebra::Point2::new(u, v)).normalize();
        let a = cam.centre() + ray * depth;
        let axis = match rng.below(3) {
            0 => Vector3::x(),
            1 => Vector3::y(),
            _ => Vector3::z(),
        };
        // Length drawn in pixels of camera 1 (10–90 px, mean 50 as the 512x512 image had):
        // drawn in metres, segments off-axis in a wide sensor would project ever longer,
        // and the growing density of ink would measure the scene, not the matcher.
        let px_per_m = match cam.project(&(a + axis * 0.01)) {
            Some(p) => (p - cam.project(&a).unwrap_or(p)).norm() / 0.01,
            None => continue,
        };
        if px_per_m < 1.0 {
            continue;
        }
        let b: Point3<f64> = a + axis * (rng.range(10.0, 90.0) / px_per_m);
        let contrast_left = rng.chance(0.5);
        let mut images = Vec::with_capacity(3);
        for c in rig.cameras() {
            let (Some(p), Some(q)) = (c.project(&a), c.project(&b)) else {
                break;
            };
            let inside = |x: &nalgebra::Point2<f64>| {
                x.x >= 0.0 && x.y >= 0.0 && x.x <= w - 1.0 && x.y <= h - 1.0
            };
            if !inside(&p) || !inside(&q) || (q - p).norm() < 10.0 {
                break;
            }
            images.push(if contrast_left { (p, q) } else { (q, p) });
        }
        if images.len() < 3 {
            continue;
        }
        for (list, (p, q)) in lists.iter_mut().zip(images) {
            let mut jitter = |x: nalgebra::Point2<f64>| {
                nalgebra::Point2::new(
                    x.x + endpoint_noise_px * rng.normal(),
                    x.y + endpoint_noise_px * rng.normal(),
                )
            };
            let s = Segment2::new(jitter(p), jitter(q));
            list.segments.push(s);
        }
        made += 1;
    }
    for list in &mut lists {
        while list.segments.len() < n {
            let a = nalgebra::Point2::new(rng.range(0.0, w - 1.0), rng.range(0.0, h - 1.0));
            let angle = rng.range(0.0, std::f64::consts::TAU);
            let len = rng.range(10.0, 80.0);
            let b = a + nalgebra::Vector2::new(angle.cos(), angle.sin()) * len;
            let b = nalgebra::Point2::new(b.x.clamp(0.0, w - 1.0), b.y.clamp(0.0, h - 1.0));
            list.segments.push(Segment2::new(a, b));
        }
        rng.shuffle(&mut list.segments);
    }
    (rig, lists)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reaches_the_requested_density() {
        let (_, lists) = scattered_capture(600, 0.3, 0.2, 7);
        for l in &lists {
            assert_eq!(l.segments.len(), 600);
            assert!(l.segments.iter().all(|s| s.length() > 0.0));
        }
    }
}
