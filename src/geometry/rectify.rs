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
    /// `R*`: rect_from_rig rotation (rows: x*, y*, z*).
    rect_from_rig: Matrix3<f64>,
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
    pub fn new(rig: &Rig) -> Result<Rectification, RectifyError> {
        let cams = rig.cameras();
        let c: Vec<Vector3<f64>> = cams.iter().map(|cam| cam.centre().coords).collect();
        let axis = cams
            .iter()
            .map(|cam| cam.axis())
            .sum::<Vector3<f64>>()
            .normalize();
        let (b12, b13, b23) = (c[1] - c[0], c[2] - c[0], c[2] - c[1]);
        let longest = [b12, b13, b23]
            .into_iter()
            .max_by(|a, b| a.norm().total_cmp(&b.norm()))
            .unwrap_or(b12);
        let normal = b12.cross(&b13);
        let spread = normal.norm() / longest.norm_squared();
        let mut collinear = spread < COLLINEAR_SPREAD;
        let mut z = normal.normalize();
        if !collinear {
            if z.dot(&axis) < 0.0 {
                z = -z;
            }
            if z.dot(&axis) < MAX_NORMAL_TO_AXIS_DEG.to_radians().cos() {
                collinear = true;
            }
        }
        if collinear {
            let line = longest.normalize();
            let off = axis - line * axis.dot(&line);
            if off.norm() < 1e-3 {
                return Err(RectifyError::LookingAlongBaseline);
            }
            z = off.normalize();
        }
        let x = (b12 - z * b12.dot(&z)).normalize();
        let y = z.cross(&x);
        let rect_from_rig = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);

        for (camera, cam) in cams.iter().enumerate() {
            let angle_deg = cam.axis().dot(&z).clamp(-1.0, 1.0).acos().to_degrees();
            if angle_deg > MAX_AXIS_TILT_DEG {
                return Err(RectifyError::AxisTilted { camera, angle_deg });
            }
        }

        let origin = cams[0].centre();
        let mut centres = [Vector2::zeros(); 3];
        let mut out_of_plane_m: f64 = 0.0;
        for (i, ci) in c.iter().enumerate() {
            let r = rect_from_rig * (ci - origin.coords);
            centres[i] = Vector2::new(r.x, r.y);
            out_of_plane_m = out_of_plane_m.max(r.z.abs());
        }
        let focal_px = cams.iter().map(|cam| cam.focal_px()).sum::<f64>() / 3.0;
        let k_star = Matrix3::new(focal_px, 0.0, 0.0, 0.0, focal_px, 0.0, 0.0, 0.0, 1.0);
        let homographies = std::array::from_fn(|i| {
            let k_inv = cams[i]
                .intrinsics()
                .try_inverse()
                .unwrap_or_else(Matrix3::identity);
            k_star * rect_from_rig * cams[i].rotation().transpose() * k_inv
        });
        Ok(Rectification {
            rect_from_rig,
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

    pub fn rect_from_rig(&self) -> &Matrix3<f64> {
        &self.rect_from_rig
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
        self.origin + self.rect_from_rig.transpose() * rect
    }

    /// The rectified image of a rig-frame point in view `i`, with its disparity.
    pub fn project(&self, i: usize, point: &Point3<f64>) -> Option<(Point2<f64>, f64)> {
        let r = self.rect_from_rig * (point - self.origin);
        if r.z <= 1e-12 {
            return None;
        }
        let c = self.centres[i];
        let delta = self.focal_px / r.z;
        Some((Point2::new((r.x - c.x) * delta, (r.y - c.y) * delta), delta))
    }
}
