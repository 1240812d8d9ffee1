//! Noise-free grey images of a scene, one ray per pixel centre.
//!
//! For eyeballing synthetic data and for feeding the edge extractor an image whose every
//! edge has known 3D ground truth. No anti-aliasing, noise or blur: add them where a test
//! needs them, so this stays an exact function of the scene and camera.

use nalgebra::Point2;

use super::bvh::SceneIndex;
use super::scene::Scene;
use super::visibility::FlatCamera;
use crate::geometry::Camera;

/// The image `camera` sees, row-major (`v` rows of `u` columns), grey levels 0–255, pixel
/// `(u, v)` sampled along the ray through its centre (DESIGN §1).
pub fn render(scene: &Scene, camera: &Camera) -> Vec<u8> {
    let index = SceneIndex::new(scene);
    let flat = FlatCamera::new(camera);
    let (w, h) = (camera.width() as usize, camera.height() as usize);
    let mut out = Vec::with_capacity(w * h);
    for v in 0..h {
        for u in 0..w {
            let grey = flat.radiance(&index, Point2::new(u as f64, v as f64));
            out.push(grey.round().clamp(0.0, 255.0) as u8);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::rig::{Pose, RigSpec};
    use crate::synth::scene::{Box3, Tracer};
    use nalgebra::Point3;

    #[test]
    fn renders_a_box_where_it_projects() {
        let scene = Scene {
            boxes: vec![
                Box3::new(
                    Point3::new(-5.0, 4.0, -5.0),
                    Point3::new(5.0, 4.1, 5.0),
                    [0.9; 6],
                ),
                Box3::new(
                    Point3::new(-0.2, 2.0, -0.2),
                    Point3::new(0.2, 2.2, 0.2),
                    [0.1; 6],
                ),
            ],
            light: Point3::new(0.0, 0.0, 1.0),
        };
        // A small, wide-angle image: f = 60 px, principal point at the centre.
        let mut spec = RigSpec {
            width: 64,
            height: 48,
            ..RigSpec::collinear(0)
        };
        for c in &mut spec.cameras {
            (c.fx, c.fy, c.cx, c.cy) = (60.0, 60.0, 31.5, 23.5);
        }
        let rig = spec.build(&Pose::identity()).unwrap();
        let cam = &rig.cameras()[0];
        let img = render(&scene, cam);
        assert_eq!(img.len(), 64 * 48);
        let at = |p: Point3<f64>| {
            let q = cam.project(&p).unwrap();
            img[q.y.round() as usize * 64 + q.x.round() as usize]
        };
        // The dark box's front face, darker than the bright wall around it.
        let front = at(Point3::new(0.0, 2.0, 0.0));
        let wall = at(Point3::new(0.6, 4.0, 0.0));
        assert!(front + 50 < wall, "front {front}, wall {wall}");
        let expected = scene.radiance(&cam.centre(), &(Point3::new(0.6, 4.0, 0.0) - cam.centre()));
        assert!((f64::from(wall) - expected).abs() <= 1.0);
    }
}
