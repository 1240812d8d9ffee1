//! Rectification of the three views onto one plane (DESIGN §2.2).
//!
//! Segment *endpoints* (never images) are reprojected onto a plane parallel to the plane of
//! the three optical centres. The three virtual cameras share one rotation `R*` and one
//! intrinsic `K* = diag(f*, f*, 1)`, so a scene point seen at rectified `aᵢ` in view i obeys
//!
//! ```text
//!     aⱼ = aᵢ + δ·(cᵢ − cⱼ)        δ = f*/Z  (one generalised disparity for all views)
//! ```
//!
//! where `cᵢ` is the in-plane position of optical centre i (metres) and `Z` the depth of the
//! point along the plane's normal. Every epipolar line of the pair (i, j) in view j is
//! parallel to `cᵢ − cⱼ`, so predicting the third view from two is one scalar solve and one
//! multiply-add.
//!
//! Collinear rigs (all centres on one line) have no plane of centres: we pick the plane that
//! contains the baseline and whose normal is closest to the mean optical axis. Such a rig
//! cannot match segments parallel to its baseline: their epipolar planes contain them in
//! every pair of views.

use nalgebra::{Matrix3, Point2, Point3, Vector2, Vector3};
use thiserror::Error;

use super::camera::Rig;

/// A rig counts as collinear when twice the area of the triangle of centres is below this
/// fraction of the squared longest baseline (sine of the largest angle off the line).
pub const COLLINEAR_SPREAD: f64 = 1e-2;
/// The plane of centres is also abandoned for the collinear construction when its normal is
/// more than this far from the mean optical axis (a rig of centres stacked along the view).
const MAX_NORMAL_TO_AXIS_DEG: f64 = 60.0;
/// Cameras looking further than this from the rectified normal cannot be rectified usefully.
const MAX_AXIS_TILT_DEG: f64 = 75.0;
/// Rays closer than this (cosine) to the rectified plane are dropped: they map near infinity.
const MIN_RAY_COS: f64 = 0.05;

#[derive(Debug, Clone, PartialEq, Error)]
pub enum RectifyError {
    #[error(
        "camera {camera}'s optical axis is {angle_deg:.1}° from the rig's viewing direction \
         (at most {MAX_AXIS_TILT_DEG}° can be rectified)"
    )]
    AxisTilted { camera: usize, angle_deg: f64 },
    #[error("the cameras look along their common baseline: no rectification plane exists")]
    LookingAlongBaseline,
}

/// The shared rectified frame of a rig.
#[derive(Debug, Clone, PartialEq)]
pub struct Rectification {
    /// `R*`: rig_to_rect rotation (rows: x*, y*, z*).
    rig_to_rect: Matrix3<f64>,
    /// Origin of the rect frame: optical centre 1.
    origin: Point3<f64>,
    focal_px: f64,
    centres: [Vector2<f64>; 3],
    out_of_plane_m: f64,
    /// rect pixel from undistorted image pixel, per view.
    homographies: [Matrix3<f64>; 3],
    collinear: bool,
}

impl Rectification {
    /// The one frame of a rig whose plane of centres faces the scene (or of a collinear rig);
    /// for a rig whose plane of centres does not, the frame of the pair (1, 2) with the third
    /// camera out of its plane — [`RigFrames`] is what matching uses for those.
    pub fn new(rig: &Rig) -> Result<Rectification, RectifyError> {
        let cams = rig.cameras();
        let c: Vec<Vector3<f64>> = cams.iter().map(|cam| cam.centre().coords).collect();
        let axis = mean_axis(rig);
        let (b12, b13, b23) = (c[1] - c[0], c[2] - c[0], c[2] - c[1]);
        let longest = [b12, b13, b23]
            .into_iter()
            .max_by(|a, b| a.norm().total_cmp(&b.norm()))
            .unwrap_or(b12);
        let collinear = spread(rig) < COLLINEAR_SPREAD;
        if collinear {
            let z = normal_along(longest, axis).ok_or(RectifyError::LookingAlongBaseline)?;
            return Rectification::with_normal(rig, z, b12, [0, 1, 2], true);
        }
        match facing_normal(rig) {
            Some(z) => Rectification::with_normal(rig, z, b12, [0, 1, 2], false),
            None => Rectification::for_pair(rig, 1),
        }
    }

    /// The frame of the pair (1, `j`) alone: the plane through both centres whose normal is
    /// closest to the rig's viewing direction. Epipolar lines of that pair are parallel in
    /// it whatever the third camera; the third camera is not rectified in it.
    pub fn for_pair(rig: &Rig, j: usize) -> Result<Rectification, RectifyError> {
        let cams = rig.cameras();
        let baseline = cams[j].centre() - cams[0].centre();
        let z = normal_along(baseline, mean_axis(rig)).ok_or(RectifyError::LookingAlongBaseline)?;
        Rectification::with_normal(rig, z, baseline, [0, j, j], false)
    }

    /// The frame of normal `z`, x along `x_from` in the plane, checking the cameras `checked`.
    fn with_normal(
        rig: &Rig,
        z: Vector3<f64>,
        x_from: Vector3<f64>,
        checked: [usize; 3],
        collinear: bool,
    ) -> Result<Rectification, RectifyError> {
        let cams = rig.cameras();
        let c: Vec<Vector3<f64>> = cams.iter().map(|cam| cam.centre().coords).collect();
        let x = (x_from - z * x_from.dot(&z)).normalize();
        let y = z.cross(&x);
        let rig_to_rect = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);

        for camera in checked {
            let angle_deg = cams[camera]
                .axis()
                .dot(&z)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees();
            if angle_deg > MAX_AXIS_TILT_DEG {
                return Err(RectifyError::AxisTilted { camera, angle_deg });
            }
        }

        let origin = cams[0].centre();
        let mut centres = [Vector2::zeros(); 3];
        let mut out_of_plane_m: f64 = 0.0;
        for (i, ci) in c.iter().enumerate() {
            let r = rig_to_rect * (ci - origin.coords);
            centres[i] = Vector2::new(r.x, r.y);
            if checked.contains(&i) {
                out_of_plane_m = out_of_plane_m.max(r.z.abs());
            }
        }
        let focal_px = cams.iter().map(|cam| cam.focal_px()).sum::<f64>() / 3.0;
        let k_star = Matrix3::new(focal_px, 0.0, 0.0, 0.0, focal_px, 0.0, 0.0, 0.0, 1.0);
        let homographies = std::array::from_fn(|i| {
            let k_inv = cams[i]
                .intrinsics()
                .try_inverse()
                .unwrap_or_else(Matrix3::identity);
            k_star * rig_to_rect * cams[i].rotation().transpose() * k_inv
        });
        Ok(Rectification {
            rig_to_rect,
            origin,
            focal_px,
            centres,
            out_of_plane_m,
            homographies,
            collinear,
        })
    }

    /// Shared focal length `f*` of the rectified views, pixels.
    pub fn focal_px(&self) -> f64 {
        self.focal_px
    }

    /// True when the rig was treated as collinear.
    pub fn collinear(&self) -> bool {
        self.collinear
    }

    /// Largest distance of an optical centre from the rectification plane, metres (0 for a
    /// non-collinear rig; the deviation from a perfect line for a collinear one).
    pub fn out_of_plane_m(&self) -> f64 {
        self.out_of_plane_m
    }

    /// In-plane position of optical centre `i`, metres (centre 1 at the origin).
    pub fn centre(&self, i: usize) -> Vector2<f64> {
        self.centres[i]
    }

    /// Direction, in view `j`, along which the homologue of a view-`i` point moves as δ grows:
    /// `cᵢ − cⱼ`, metres (multiply by δ to get pixels).
    pub fn epipolar(&self, i: usize, j: usize) -> Vector2<f64> {
        self.centres[i] - self.centres[j]
    }

    pub fn rig_to_rect(&self) -> &Matrix3<f64> {
        &self.rig_to_rect
    }

    /// Disparity interval `[δmin, δmax]` (pixels per metre of baseline) for a depth range.
    pub fn disparity_range(&self, depth_min_m: f64, depth_max_m: f64) -> (f64, f64) {
        (self.focal_px / depth_max_m, self.focal_px / depth_min_m)
    }

    /// Maps an undistorted pixel of view `i` to rectified pixels; `None` for rays that point
    /// away from, or almost along, the rectified plane.
    pub fn to_rect(&self, i: usize, pixel: Point2<f64>) -> Option<Point2<f64>> {
        let h = self.homographies[i] * Vector3::new(pixel.x, pixel.y, 1.0);
        let ray_norm = Vector3::new(h.x / self.focal_px, h.y / self.focal_px, h.z).norm();
        if h.z.is_nan() || h.z <= MIN_RAY_COS * ray_norm {
            return None;
        }
        Some(Point2::new(h.x / h.z, h.y / h.z))
    }

    /// Maps rectified pixels of view `i` back to undistorted image pixels.
    pub fn from_rect(&self, i: usize, rect: Point2<f64>) -> Option<Point2<f64>> {
        let inv = self.homographies[i].try_inverse()?;
        let p = inv * Vector3::new(rect.x, rect.y, 1.0);
        (p.z.abs() > 1e-12).then(|| Point2::new(p.x / p.z, p.y / p.z))
    }

    /// Transfers a rectified point of view `i` with disparity `delta` to view `k`.
    pub fn transfer(&self, i: usize, a_i: Point2<f64>, delta: f64, k: usize) -> Point2<f64> {
        a_i + self.epipolar(i, k) * delta
    }

    /// The disparity shared by two homologous rectified points of views `i` and `j`
    /// (least squares along the epipolar direction).
    pub fn disparity(&self, i: usize, a_i: Point2<f64>, j: usize, a_j: Point2<f64>) -> f64 {
        let e = self.epipolar(i, j);
        (a_j - a_i).dot(&e) / e.norm_squared()
    }

    /// The rig-frame point seen at rectified `a_i` in view `i` with disparity `delta`.
    pub fn point(&self, i: usize, a_i: Point2<f64>, delta: f64) -> Point3<f64> {
        let depth = self.focal_px / delta;
        let c = self.centres[i];
        let rect = Vector3::new(
            c.x + a_i.x * depth / self.focal_px,
            c.y + a_i.y * depth / self.focal_px,
            depth,
        );
        self.origin + self.rig_to_rect.transpose() * rect
    }

    /// The rectified image of a rig-frame point in view `i`, with its disparity.
    pub fn project(&self, i: usize, point: &Point3<f64>) -> Option<(Point2<f64>, f64)> {
        let r = self.rig_to_rect * (point - self.origin);
        if r.z <= 1e-12 {
            return None;
        }
        let c = self.centres[i];
        let delta = self.focal_px / r.z;
        Some((Point2::new((r.x - c.x) * delta, (r.y - c.y) * delta), delta))
    }
}

/// The mean optical axis of the rig's cameras (the rig's viewing direction).
fn mean_axis(rig: &Rig) -> Vector3<f64> {
    rig.cameras()
        .iter()
        .map(|cam| cam.axis())
        .sum::<Vector3<f64>>()
        .normalize()
}

/// Twice the area of the triangle of centres over the squared longest baseline: the sine of
/// its largest angle off a line (0 for a collinear rig).
fn spread(rig: &Rig) -> f64 {
    let c: Vec<Vector3<f64>> = rig
        .cameras()
        .iter()
        .map(|cam| cam.centre().coords)
        .collect();
    let (b12, b13, b23) = (c[1] - c[0], c[2] - c[0], c[2] - c[1]);
    let longest = b12.norm().max(b13.norm()).max(b23.norm());
    b12.cross(&b13).norm() / (longest * longest)
}

/// The normal of the plane of centres, towards the scene, when that plane faces it: within
/// [`MAX_NORMAL_TO_AXIS_DEG`] of the viewing direction (and the rig is not collinear).
fn facing_normal(rig: &Rig) -> Option<Vector3<f64>> {
    if spread(rig) < COLLINEAR_SPREAD {
        return None;
    }
    let c: Vec<Vector3<f64>> = rig
        .cameras()
        .iter()
        .map(|cam| cam.centre().coords)
        .collect();
    let mut z = (c[1] - c[0]).cross(&(c[2] - c[0])).normalize();
    let axis = mean_axis(rig);
    if z.dot(&axis) < 0.0 {
        z = -z;
    }
    (z.dot(&axis) >= MAX_NORMAL_TO_AXIS_DEG.to_radians().cos()).then_some(z)
}

/// The unit normal closest to `axis` of the planes containing `baseline`, or `None` when the
/// cameras look along it.
fn normal_along(baseline: Vector3<f64>, axis: Vector3<f64>) -> Option<Vector3<f64>> {
    let line = baseline.try_normalize(1e-12)?;
    let off = axis - line * axis.dot(&line);
    (off.norm() >= 1e-3).then(|| off.normalize())
}

/// The rectified frames matching searches in: one shared by the three views when the plane
/// of centres faces the scene (or the rig is collinear), else one per searched pair.
///
/// Pair (1, 2) is searched in `pair_frames[0]`, pair (1, 3) in `pair_frames[1]`. View 1 is
/// rectified in both, view 2 in the first and view 3 in the second: every view only in frames
/// whose plane holds its centre, where the pair's epipolar lines are parallel. A hypothesis
/// found in one frame is verified in the other view through its 3D point
/// ([`RigFrames::transfer`]), the exact trifocal transfer.
#[derive(Debug, Clone, PartialEq)]
pub struct RigFrames {
    pub pair_frames: [Rectification; 2],
    /// One frame for all three views (then both entries are that frame).
    pub shared: bool,
    /// Whether each pair is searched ([`MIN_SEARCH_BASELINE_TO_AXIS_DEG`]); a pair that is
    /// not still verifies what the other finds.
    pub searched: [bool; 2],
}

/// Per-pair frames search only a pair whose baseline is at least this far from the viewing
/// direction. Closer, its epipole lies in or near image 1 (at f·tan of the angle from the
/// principal point: within one focal length below 45°), disparities shrink to nothing around
/// it and every segment pointing at it lies along its epipolar line: on the real facade of
/// `herzjesu_p25` (a pair 33° off the view) the matches that pair alone found were 16%
/// confirmed by a fourth photo, against 46% for the other pair, and with both searched the
/// forward pair's false matches displaced true ones.
pub const MIN_SEARCH_BASELINE_TO_AXIS_DEG: f64 = 45.0;

impl RigFrames {
    pub fn new(rig: &Rig) -> Result<RigFrames, RectifyError> {
        if spread(rig) < COLLINEAR_SPREAD || facing_normal(rig).is_some() {
            let shared = Rectification::new(rig)?;
            return Ok(RigFrames {
                pair_frames: [shared.clone(), shared],
                shared: true,
                searched: [true, true],
            });
        }
        let axis = mean_axis(rig);
        let across = |j: usize| {
            let baseline = (rig.camera(j).centre() - rig.camera(0).centre()).normalize();
            baseline.dot(&axis).abs() <= MIN_SEARCH_BASELINE_TO_AXIS_DEG.to_radians().sin()
        };
        let searched = match [across(1), across(2)] {
            [false, false] => [true, true],
            either => either,
        };
        Ok(RigFrames {
            pair_frames: [
                Rectification::for_pair(rig, 1)?,
                Rectification::for_pair(rig, 2)?,
            ],
            shared: false,
            searched,
        })
    }

    /// The frame view `v` is rectified in (view 1: the first of its two).
    pub fn frame_of(&self, v: usize) -> &Rectification {
        &self.pair_frames[usize::from(v == 2)]
    }

    /// Transfers the point at rectified `a` of view 1 in `pair_frames[from]`, with disparity
    /// `delta` there, to view `k`'s frame: `a + δ·(c₁ − c_k)` in a shared frame, through the
    /// 3D point otherwise. `None` when the point is behind view `k`'s frame.
    pub fn transfer(
        &self,
        from: usize,
        a: Point2<f64>,
        delta: f64,
        k: usize,
    ) -> Option<Point2<f64>> {
        if self.shared {
            return Some(self.pair_frames[0].transfer(0, a, delta, k));
        }
        let point = self.pair_frames[from].point(0, a, delta);
        self.frame_of(k).project(k, &point).map(|(q, _)| q)
    }
}

/// The angle between the epipolar lines of the pairs (1, 2) and (1, 3) through the principal
/// point of image 1, degrees in [0, 90]: how well the rig sees every direction there. An
/// image segment along one pair's epipolar line is matched by the other pair alone; one along
/// both (near 0°: a nearly collinear rig) by neither.
pub fn epipolar_angle_deg(rig: &Rig) -> f64 {
    let first = rig.camera(0);
    let k = first.intrinsics();
    let centre = Vector2::new(k[(0, 2)], k[(1, 2)]);
    let direction = |j: usize| {
        let epipole = first.projection() * rig.camera(j).centre().to_homogeneous();
        Vector2::new(epipole.x, epipole.y) - centre * epipole.z
    };
    let (d2, d3) = (direction(1), direction(2));
    let (n2, n3) = (d2.norm(), d3.norm());
    if n2 < 1e-12 || n3 < 1e-12 {
        return 0.0;
    }
    (d2.dot(&d3) / (n2 * n3)).abs().min(1.0).acos().to_degrees()
}
