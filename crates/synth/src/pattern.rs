//! The calibration pattern as a renderable scene, and rigs looking at it: the ground truth
//! for calibration tests and benches (render a triplet, detect, estimate, compare with the
//! cameras that rendered it).
//!
//! Boards are thin white boxes; each printed square is a dark box whose front face lies in
//! exactly the board's front plane, placed *before* the board in the box list: the renderer
//! gives ties to the lowest box index, so the square is flush with the board (no side faces,
//! no parallax) and its outline is exactly the pattern's square. A grey floor and two grey
//! walls behind the boards give the board outlines a contrast without a black void.

use nalgebra::{Point3, Rotation3, Vector3};

use super::rig::{Pose, RigSpec};
use super::rng::Rng;
use super::scene::{Box3, Scene};
use trinocular_core::calibrate::detect::printed_side;
use trinocular_core::calibrate::{CalibrationPattern, GridBoard};
use trinocular_core::geometry::Rig;

/// Albedos: white paper, black toner, grey surroundings.
const BOARD_ALBEDO: f64 = 0.6;
const SQUARE_ALBEDO: f64 = 0.08;
const SURROUND_ALBEDO: f64 = 0.3;
/// Board thickness (behind its printed face), square thickness (into the board), metres.
const BOARD_THICKNESS: f64 = 0.01;
const SQUARE_THICKNESS: f64 = 0.001;
/// White margin around the outermost squares, metres.
const BOARD_MARGIN: f64 = 0.02;
/// Focal lengths of [`RigSpec::non_collinear`] times this: about 450 px, a 59° field, so the
/// whole two-board pattern fits every camera of a 0.3 m rig from about a metre.
const FOCAL_SCALE: f64 = 0.75;
/// Every reference point stays this far inside every image of [`pattern_views`], pixels.
const VIEW_MARGIN_PX: f64 = 12.0;

/// Axis-aligned box spanning the points (the pattern's default boards are axis-aligned; a
/// tilted board would need a renderer with oriented boxes).
fn span(points: &[Point3<f64>], albedo: f64) -> Box3 {
    let mut lo = points[0];
    let mut hi = points[0];
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    Box3::new(lo, hi, [albedo; 6])
}

fn board_boxes(board: &GridBoard, front: Vector3<f64>) -> (Vec<Box3>, Box3) {
    let squares = board
        .squares()
        .map(|(r, c)| {
            let corners = board.corners(r, c);
            let mut pts = corners.to_vec();
            pts.extend(corners.iter().map(|p| p - front * SQUARE_THICKNESS));
            span(&pts, SQUARE_ALBEDO)
        })
        .collect();
    let first = board.corners(0, 0)[0];
    let last = board.corners(board.rows - 1, board.cols - 1)[2];
    let out = |p: Point3<f64>, du: f64, dv: f64| p + board.u_axis * du + board.v_axis * dv;
    let m = BOARD_MARGIN;
    let face = [
        out(first, -m, -m),
        out(last, m, m),
        out(first, -m, -m) - front * BOARD_THICKNESS,
        out(last, m, m) - front * BOARD_THICKNESS,
    ];
    (squares, span(&face, BOARD_ALBEDO))
}

/// The pattern as boxes: squares first (they win ties with their board's face), then
/// boards, floor and two walls. Boards must be axis-aligned (the default pattern is).
pub fn pattern_scene(pattern: &CalibrationPattern) -> Scene {
    let mut squares = Vec::new();
    let mut boards = Vec::new();
    for (i, board) in pattern.boards.iter().enumerate() {
        let (s, b) = board_boxes(board, printed_side(pattern, i));
        squares.extend(s);
        boards.push(b);
    }
    let mut boxes = squares;
    boxes.extend(boards);
    let grey = [SURROUND_ALBEDO; 6];
    // Floor under everything, walls well behind the default boards (x < 0, y < 0).
    boxes.push(Box3::new(
        Point3::new(-0.6, -0.6, -0.05),
        Point3::new(3.0, 3.0, 0.0),
        grey,
    ));
    boxes.push(Box3::new(
        Point3::new(-0.65, -0.6, 0.0),
        Point3::new(-0.6, 3.0, 2.0),
        grey,
    ));
    boxes.push(Box3::new(
        Point3::new(-0.6, -0.65, 0.0),
        Point3::new(3.0, -0.6, 2.0),
        grey,
    ));
    Scene {
        boxes,
        light: Point3::new(1.2, 1.2, 1.4),
    }
}

/// Whether every reference point of `pattern` is inside every image of `rig`, with margin.
fn sees_all(rig: &Rig, pattern: &CalibrationPattern) -> bool {
    rig.cameras().iter().all(|cam| {
        let (w, h) = (f64::from(cam.width()), f64::from(cam.height()));
        pattern.reference_points().iter().all(|(_, p)| {
            cam.project(p).is_some_and(|q| {
                q.x >= VIEW_MARGIN_PX
                    && q.y >= VIEW_MARGIN_PX
                    && q.x <= w - 1.0 - VIEW_MARGIN_PX
                    && q.y <= h - 1.0 - VIEW_MARGIN_PX
            })
        })
    })
}

/// A rig of `spec` whose centre is `distance` from `target` at azimuth `azimuth` (from +x,
/// about z) and elevation `elevation`, aimed at `target`, rolled by `roll` (radians).
fn aimed_rig(
    spec: &RigSpec,
    target: Point3<f64>,
    distance: f64,
    azimuth: f64,
    elevation: f64,
    roll: f64,
) -> Option<Rig> {
    let dir = Vector3::new(
        azimuth.cos() * elevation.cos(),
        azimuth.sin() * elevation.cos(),
        elevation.sin(),
    );
    let centre_world = target + dir * distance;
    // Rig frame at rest looks along +y; the cameras' mean pitch is compensated so that the
    // mean optical axis, not the rig's y axis, points at the target.
    let mean_pitch = spec.cameras.iter().map(|c| c.pitch_rad).sum::<f64>() / 3.0;
    let fwd = -dir;
    let yaw = (-fwd.x).atan2(fwd.y);
    let pitch = fwd.z.atan2(fwd.x.hypot(fwd.y)) - mean_pitch;
    let rotation = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw)
        * Rotation3::from_axis_angle(&Vector3::x_axis(), pitch)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), roll);
    let centre_rig = spec
        .cameras
        .iter()
        .fold(Vector3::zeros(), |s, c| s + c.centre.coords)
        / 3.0;
    let pose = Pose {
        rotation,
        translation: centre_world.coords - rotation * centre_rig,
    };
    spec.build(&pose).ok()
}

/// The default pattern's scene and a non-collinear rig (focal lengths scaled to about
/// 450 px) 0.95–1.2 m from the pattern's centre, on the side both boards face, looking at
/// the corner between them, with a pose drawn from `seed` (azimuth 45° ± 12°, elevation
/// 12–28°, roll ±4°). Every reference point is at least 12 px inside all three 512 × 512
/// images: draws that miss that are redrawn, and the nominal pose (checked by the tests)
/// is the fallback.
pub fn pattern_views(seed: u64) -> (Scene, Rig, CalibrationPattern) {
    let pattern = CalibrationPattern::default();
    let mut spec = RigSpec::non_collinear(seed);
    for c in &mut spec.cameras {
        c.fx *= FOCAL_SCALE;
        c.fy *= FOCAL_SCALE;
    }
    let points = pattern.reference_points();
    let target = Point3::from(
        points
            .iter()
            .fold(Vector3::zeros(), |s, (_, p)| s + p.coords)
            / points.len() as f64,
    );
    let mut rng = Rng::new(seed).fork(0xCA11B);
    let drawn = (0..32).find_map(|_| {
        let rig = aimed_rig(
            &spec,
            target,
            rng.range(0.95, 1.2),
            (45.0 + rng.symmetric(12.0)).to_radians(),
            rng.range(12.0, 28.0).to_radians(),
            rng.symmetric(4.0).to_radians(),
        )?;
        sees_all(&rig, &pattern).then_some(rig)
    });
    let rig = drawn
        .or_else(|| {
            aimed_rig(
                &spec,
                target,
                1.1,
                45f64.to_radians(),
                20f64.to_radians(),
                0.0,
            )
        })
        .expect("the nominal pattern view is a valid rig");
    (pattern_scene(&pattern), rig, pattern)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_view_sees_the_whole_pattern() {
        let pattern = CalibrationPattern::default();
        let (_, spec_rig, _) = pattern_views(0);
        assert!(sees_all(&spec_rig, &pattern));
        for seed in 0..40 {
            let (_, rig, _) = pattern_views(seed);
            assert!(sees_all(&rig, &pattern), "seed {seed}");
        }
    }

    #[test]
    fn the_default_boards_are_printed_towards_each_other() {
        // (printed_side lives with detection, which relies on it.)
        let p = CalibrationPattern::default();
        assert!((printed_side(&p, 0) - Vector3::y()).norm() < 1e-12);
        assert!((printed_side(&p, 1) - Vector3::x()).norm() < 1e-12);
    }
}
