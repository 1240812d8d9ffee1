//! Pinhole cameras with optional plumb_bob distortion, and the three-camera rig.
//!
//! A [`Camera`] is built from a 3x4 projection `P` or from `K, R, t`, and is validated on the
//! way in (finite, rank 3, positive focal lengths, a proper rotation, a sane image size), so
//! the rest of the pipeline never sees a degenerate camera. `P` is stored normalised: the
//! third row of its left 3x3 block has unit norm, so the `w` of `P·X` is the depth of `X`
//! along the optical axis, in metres.

use nalgebra::{Matrix3, Matrix3x4, Point2, Point3, Vector3};
use thiserror::Error;

/// Largest accepted image side, pixels.
pub const MAX_IMAGE_SIDE: u32 = 65_536;
/// Smallest accepted ratio of the smallest to the largest singular value of `P`'s 3x3 block.
const MIN_SINGULAR_RATIO: f64 = 1e-9;
/// Tolerance on `RᵀR = I` and `K[2][2] = 1` for user-supplied `K, R, t`.
const ROTATION_TOLERANCE: f64 = 1e-5;

/// OpenCV / ROS `plumb_bob` lens distortion, on normalised image coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Distortion {
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
}

impl Distortion {
    pub fn is_zero(&self) -> bool {
        self.k1 == 0.0 && self.k2 == 0.0 && self.p1 == 0.0 && self.p2 == 0.0 && self.k3 == 0.0
    }

    /// Distorts normalised coordinates `(x, y)`.
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    /// Inverts [`Distortion::apply`] by fixed-point iteration (OpenCV's scheme), which
    /// converges for the distortions real lenses have.
    pub fn remove(&self, xd: f64, yd: f64) -> (f64, f64) {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..30 {
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
            let dx = 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
            let dy = self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
            let (nx, ny) = ((xd - dx) / radial, (yd - dy) / radial);
            let step = (nx - x).abs() + (ny - y).abs();
            x = nx;
            y = ny;
            if step < 1e-12 {
                break;
            }
        }
        (x, y)
    }

    fn is_finite(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
            .iter()
            .all(|v| v.is_finite())
    }
}

/// What is wrong with one camera. `field()` names the offending field of the schema's
/// `Camera` message, so the service can report `calibration.cameras[i].<field>`.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CameraError {
    #[error("{field} has a non-finite value")]
    NonFinite { field: &'static str },
    #[error("image size {width}x{height} is outside 1..={MAX_IMAGE_SIDE} pixels")]
    ImageSize { width: u32, height: u32 },
    #[error("{field} is rank-deficient (singular value ratio {ratio:.2e})")]
    RankDeficient { field: &'static str, ratio: f64 },
    #[error(
        "projection's left 3x3 block has a negative determinant: points in front of the \
         camera would get w < 0 (is P mirrored or scaled by a negative factor?)"
    )]
    NegativeDeterminant,
    #[error("focal lengths must be positive, got fx = {fx}, fy = {fy}")]
    NonPositiveFocal { fx: f64, fy: f64 },
    #[error("intrinsics must be upper triangular with K[2][2] = 1, got row 3 = {row3:?}")]
    NotIntrinsic { row3: [f64; 3] },
    #[error("rotation is not a rotation matrix (max |RᵀR − I| = {deviation:.2e}, det = {det:.4})")]
    NotRotation { deviation: f64, det: f64 },
}

impl CameraError {
    /// The schema field at fault.
    pub fn field(&self) -> &'static str {
        match self {
            CameraError::NonFinite { field } | CameraError::RankDeficient { field, .. } => field,
            CameraError::ImageSize { .. } => "width",
            CameraError::NegativeDeterminant => "projection",
            CameraError::NonPositiveFocal { .. } | CameraError::NotIntrinsic { .. } => "intrinsics",
            CameraError::NotRotation { .. } => "rotation",
        }
    }
}

/// A validated pinhole camera. Fields are private so that every `Camera` is a valid one.
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    name: String,
    width: u32,
    height: u32,
    /// `P` scaled so that `‖P[2][0..3]‖ = 1` and `det(P[:, 0..3]) > 0`.
    projection: Matrix3x4<f64>,
    intrinsics: Matrix3<f64>,
    intrinsics_inv: Matrix3<f64>,
    /// rig_to_cam rotation.
    rotation: Matrix3<f64>,
    translation: Vector3<f64>,
    centre: Point3<f64>,
    distortion: Option<Distortion>,
}

fn check_size(width: u32, height: u32) -> Result<(), CameraError> {
    if width == 0 || height == 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(CameraError::ImageSize { width, height });
    }
    Ok(())
}

fn check_distortion(distortion: Option<Distortion>) -> Result<Option<Distortion>, CameraError> {
    match distortion {
        Some(d) if !d.is_finite() => Err(CameraError::NonFinite {
            field: "distortion",
        }),
        Some(d) if d.is_zero() => Ok(None),
        other => Ok(other),
    }
}

/// RQ decomposition of a 3x3 matrix with a positive determinant: `m = k·r`, `k` upper
/// triangular with a positive diagonal, `r` a rotation.
fn rq3(m: &Matrix3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    // Flip rows/columns so a QR of the transpose yields an RQ.
    let flip = Matrix3::new(0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0);
    let qr = (flip * m).transpose().qr();
    let (q, r) = (qr.q(), qr.r());
    let mut k = flip * r.transpose() * flip;
    let mut rot = flip * q.transpose();
    for i in 0..3 {
        if k[(i, i)] < 0.0 {
            // K·D and D·R with D = diag(±1) leave the product unchanged.
            k.column_mut(i).neg_mut();
            rot.row_mut(i).neg_mut();
        }
    }
    (k, rot)
}

impl Camera {
    /// Builds a camera from a 3x4 projection matrix (any positive scale).
    pub fn from_projection(
        name: impl Into<String>,
        width: u32,
        height: u32,
        projection: Matrix3x4<f64>,
        distortion: Option<Distortion>,
    ) -> Result<Camera, CameraError> {
        check_size(width, height)?;
        if projection.iter().any(|v| !v.is_finite()) {
            return Err(CameraError::NonFinite {
                field: "projection",
            });
        }
        let distortion = check_distortion(distortion)?;
        let m: Matrix3<f64> = projection.fixed_view::<3, 3>(0, 0).into_owned();
        let singular = m.singular_values();
        let (smax, smin) = (singular.max(), singular.min());
        if smax <= 0.0 || smin / smax < MIN_SINGULAR_RATIO {
            return Err(CameraError::RankDeficient {
                field: "projection",
                ratio: if smax > 0.0 { smin / smax } else { 0.0 },
            });
        }
        if m.determinant() <= 0.0 {
            return Err(CameraError::NegativeDeterminant);
        }
        let (k, rotation) = rq3(&m);
        let scale = k[(2, 2)];
        let intrinsics = k / scale;
        let projection = projection / scale;
        let p4 = projection.column(3).into_owned();
        let translation =
            intrinsics
                .try_inverse()
                .map(|ki| ki * p4)
                .ok_or(CameraError::RankDeficient {
                    field: "projection",
                    ratio: 0.0,
                })?;
        Self::assemble(
            name.into(),
            width,
            height,
            intrinsics,
            rotation,
            translation,
            distortion,
        )
    }

    /// Builds a camera from `K`, `R` (rig_to_cam) and `t`, with `P = K [R | t]`.
    pub fn from_krt(
        name: impl Into<String>,
        width: u32,
        height: u32,
        intrinsics: Matrix3<f64>,
        rotation: Matrix3<f64>,
        translation: Vector3<f64>,
        distortion: Option<Distortion>,
    ) -> Result<Camera, CameraError> {
        check_size(width, height)?;
        for (field, finite) in [
            ("intrinsics", intrinsics.iter().all(|v| v.is_finite())),
            ("rotation", rotation.iter().all(|v| v.is_finite())),
            ("translation", translation.iter().all(|v| v.is_finite())),
        ] {
            if !finite {
                return Err(CameraError::NonFinite { field });
            }
        }
        let distortion = check_distortion(distortion)?;
        let row3 = [intrinsics[(2, 0)], intrinsics[(2, 1)], intrinsics[(2, 2)]];
        if row3[0].abs() > ROTATION_TOLERANCE
            || row3[1].abs() > ROTATION_TOLERANCE
            || intrinsics[(1, 0)].abs() > ROTATION_TOLERANCE
            || (row3[2] - 1.0).abs() > ROTATION_TOLERANCE
        {
            return Err(CameraError::NotIntrinsic { row3 });
        }
        let (fx, fy) = (intrinsics[(0, 0)], intrinsics[(1, 1)]);
        if fx <= 0.0 || fy <= 0.0 {
            return Err(CameraError::NonPositiveFocal { fx, fy });
        }
        let deviation = (rotation.transpose() * rotation - Matrix3::identity()).amax();
        let det = rotation.determinant();
        if deviation > ROTATION_TOLERANCE || (det - 1.0).abs() > ROTATION_TOLERANCE {
            return Err(CameraError::NotRotation { deviation, det });
        }
        Self::assemble(
            name.into(),
            width,
            height,
            intrinsics,
            rotation,
            translation,
            distortion,
        )
    }

    fn assemble(
        name: String,
        width: u32,
        height: u32,
        intrinsics: Matrix3<f64>,
        rotation: Matrix3<f64>,
        translation: Vector3<f64>,
        distortion: Option<Distortion>,
    ) -> Result<Camera, CameraError> {
        let (fx, fy) = (intrinsics[(0, 0)], intrinsics[(1, 1)]);
        if !(fx > 0.0 && fy > 0.0) {
            return Err(CameraError::NonPositiveFocal { fx, fy });
        }
        let intrinsics_inv = intrinsics.try_inverse().ok_or(CameraError::RankDeficient {
            field: "intrinsics",
            ratio: 0.0,
        })?;
        let mut rt = Matrix3x4::zeros();
        rt.fixed_view_mut::<3, 3>(0, 0).copy_from(&rotation);
        rt.set_column(3, &translation);
        let projection = intrinsics * rt;
        let centre = Point3::from(-(rotation.transpose() * translation));
        Ok(Camera {
            name,
            width,
            height,
            projection,
            intrinsics,
            intrinsics_inv,
            rotation,
            translation,
            centre,
            distortion,
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }
    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
    /// Normalised `P`: `w` of `P·X` is the depth of `X` in metres.
    pub fn projection(&self) -> &Matrix3x4<f64> {
        &self.projection
    }
    pub fn intrinsics(&self) -> &Matrix3<f64> {
        &self.intrinsics
    }
    /// rig_to_cam rotation `R`.
    pub fn rotation(&self) -> &Matrix3<f64> {
        &self.rotation
    }
    pub fn translation(&self) -> &Vector3<f64> {
        &self.translation
    }
    /// Optical centre `C = −Rᵀt`, rig frame.
    pub fn centre(&self) -> Point3<f64> {
        self.centre
    }
    /// Unit optical axis (camera +z) in the rig frame.
    pub fn axis(&self) -> Vector3<f64> {
        self.rotation.row(2).transpose()
    }
    pub fn distortion(&self) -> Option<&Distortion> {
        self.distortion.as_ref()
    }
    /// Mean focal length, pixels.
    pub fn focal_px(&self) -> f64 {
        0.5 * (self.intrinsics[(0, 0)] + self.intrinsics[(1, 1)])
    }

    /// Projects a rig-frame point to (distorted) pixels; `None` behind or on the camera plane.
    pub fn project(&self, point: &Point3<f64>) -> Option<Point2<f64>> {
        let cam = self.rotation * point.coords + self.translation;
        if cam.z <= 1e-12 {
            return None;
        }
        let (mut x, mut y) = (cam.x / cam.z, cam.y / cam.z);
        if let Some(d) = &self.distortion {
            (x, y) = d.apply(x, y);
        }
        let p = self.intrinsics * Vector3::new(x, y, 1.0);
        Some(Point2::new(p.x, p.y))
    }

    /// The undistorted pixel where the ideal pinhole (`P`) images a rig-frame point, the
    /// frame the matcher works in; `None` behind or on the camera plane.
    pub fn pinhole(&self, point: &Point3<f64>) -> Option<Point2<f64>> {
        let x = self.projection * point.to_homogeneous();
        (x.z > 0.0).then(|| Point2::new(x.x / x.z, x.y / x.z))
    }

    /// Depth of a rig-frame point along the optical axis, metres.
    pub fn depth(&self, point: &Point3<f64>) -> f64 {
        (self.rotation * point.coords + self.translation).z
    }

    /// Removes lens distortion from a pixel: the pixel where the ideal pinhole would image
    /// the same ray. Identity for a camera without distortion.
    pub fn undistort(&self, pixel: Point2<f64>) -> Point2<f64> {
        self.in_normalised(pixel, Distortion::remove)
    }

    /// `f` applied to a pixel's normalised image coordinates (identity without distortion).
    fn in_normalised(
        &self,
        pixel: Point2<f64>,
        f: impl Fn(&Distortion, f64, f64) -> (f64, f64),
    ) -> Point2<f64> {
        match &self.distortion {
            None => pixel,
            Some(d) => {
                let n = self.intrinsics_inv * Vector3::new(pixel.x, pixel.y, 1.0);
                let (x, y) = f(d, n.x / n.z, n.y / n.z);
                let p = self.intrinsics * Vector3::new(x, y, 1.0);
                Point2::new(p.x, p.y)
            }
        }
    }

    /// Applies lens distortion to an ideal (undistorted) pixel: the inverse of
    /// [`Camera::undistort`]. Identity for a camera without distortion.
    pub fn distort(&self, pixel: Point2<f64>) -> Point2<f64> {
        self.in_normalised(pixel, Distortion::apply)
    }

    /// Direction (rig frame, not normalised) of the ray through an *undistorted* pixel.
    pub fn ray(&self, pixel: Point2<f64>) -> Vector3<f64> {
        self.rotation.transpose() * (self.intrinsics_inv * Vector3::new(pixel.x, pixel.y, 1.0))
    }
}

/// Why three cameras do not make a rig.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RigError {
    #[error(
        "cameras {first} and {second} have coincident optical centres ({distance_m:.2e} m apart)"
    )]
    CoincidentCentres {
        first: usize,
        second: usize,
        distance_m: f64,
    },
}

/// Shortest baseline accepted, metres.
pub const MIN_BASELINE_M: f64 = 1e-4;

/// Three validated cameras whose optical centres are distinct.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    cameras: [Camera; 3],
}

impl Rig {
    pub fn new(cameras: [Camera; 3]) -> Result<Rig, RigError> {
        for (first, second) in [(0, 1), (0, 2), (1, 2)] {
            let distance_m = (cameras[first].centre() - cameras[second].centre()).norm();
            if distance_m < MIN_BASELINE_M {
                return Err(RigError::CoincidentCentres {
                    first,
                    second,
                    distance_m,
                });
            }
        }
        Ok(Rig { cameras })
    }

    pub fn cameras(&self) -> &[Camera; 3] {
        &self.cameras
    }

    pub fn camera(&self, i: usize) -> &Camera {
        &self.cameras[i]
    }

    /// The centroid of the three optical centres: where "distance from the rig" is measured.
    pub fn centroid(&self) -> Point3<f64> {
        Point3::from(
            self.cameras
                .iter()
                .map(|c| c.centre().coords)
                .sum::<Vector3<f64>>()
                / 3.0,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    fn sample_camera() -> Camera {
        let k = Matrix3::new(600.0, 0.5, 257.3, 0.0, 601.2, 253.8, 0.0, 0.0, 1.0);
        let r = *Rotation3::from_euler_angles(0.1, -0.2, 0.05).matrix();
        Camera::from_krt("c", 512, 512, k, r, Vector3::new(0.1, -0.2, 0.3), None).unwrap()
    }

    #[test]
    fn projection_round_trips_through_rq() {
        let cam = sample_camera();
        let scaled = cam.projection() * 3.7;
        let back = Camera::from_projection("c", 512, 512, scaled, None).unwrap();
        assert!((back.intrinsics() - cam.intrinsics()).amax() < 1e-9);
        assert!((back.rotation() - cam.rotation()).amax() < 1e-12);
        assert!((back.centre() - cam.centre()).norm() < 1e-12);
        let x = Point3::new(0.3, 0.2, 2.0);
        let (a, b) = (cam.project(&x), back.project(&x));
        assert!((a.unwrap() - b.unwrap()).norm() < 1e-9);
    }

    #[test]
    fn w_is_depth_after_normalisation() {
        let cam = sample_camera();
        let x = Point3::new(0.3, 0.2, 2.0);
        let w = (cam.projection() * x.to_homogeneous()).z;
        assert!((w - cam.depth(&x)).abs() < 1e-12);
    }

    #[test]
    fn rejects_degenerate_projections() {
        let cam = sample_camera();
        let mut flat = *cam.projection();
        flat.set_column(2, &flat.column(0).clone_owned());
        assert!(matches!(
            Camera::from_projection("c", 512, 512, flat, None),
            Err(CameraError::RankDeficient { .. })
        ));
        assert_eq!(
            Camera::from_projection("c", 512, 512, -cam.projection(), None),
            Err(CameraError::NegativeDeterminant)
        );
        let mut nan = *cam.projection();
        nan[(1, 2)] = f64::NAN;
        assert_eq!(
            Camera::from_projection("c", 512, 512, nan, None)
                .unwrap_err()
                .field(),
            "projection"
        );
        assert!(matches!(
            Camera::from_projection("c", 0, 512, *cam.projection(), None),
            Err(CameraError::ImageSize { .. })
        ));
    }

    #[test]
    fn rejects_bad_krt() {
        let cam = sample_camera();
        let mut k = *cam.intrinsics();
        k[(0, 0)] = -5.0;
        let err = Camera::from_krt("c", 512, 512, k, *cam.rotation(), Vector3::zeros(), None);
        assert_eq!(err.unwrap_err().field(), "intrinsics");
        let r = cam.rotation() * 1.01;
        let err = Camera::from_krt("c", 512, 512, *cam.intrinsics(), r, Vector3::zeros(), None);
        assert_eq!(err.unwrap_err().field(), "rotation");
    }

    #[test]
    fn distortion_removal_inverts_application() {
        let d = Distortion {
            k1: -0.28,
            k2: 0.07,
            p1: 0.001,
            p2: -0.0005,
            k3: 0.0,
        };
        for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.4, 0.35), (0.1, 0.45)] {
            let (xd, yd) = d.apply(x, y);
            let (xu, yu) = d.remove(xd, yd);
            assert!((xu - x).abs() < 1e-9 && (yu - y).abs() < 1e-9, "{x} {y}");
        }
    }

    #[test]
    fn pixels_distort_and_undistort_back() {
        let k = Matrix3::new(600.0, 0.0, 256.0, 0.0, 600.0, 250.0, 0.0, 0.0, 1.0);
        let d = Distortion {
            k1: -0.28,
            k2: 0.07,
            p1: 0.001,
            p2: -0.0005,
            k3: 0.0,
        };
        let cam = Camera::from_krt(
            "c",
            512,
            512,
            k,
            Matrix3::identity(),
            Vector3::zeros(),
            Some(d),
        )
        .unwrap();
        let point = Point3::new(0.3, -0.2, 2.0);
        let observed = cam.project(&point).unwrap();
        let ideal = cam.undistort(observed);
        assert!((ideal - Point2::new(256.0 + 90.0, 250.0 - 60.0)).norm() < 1e-6);
        assert!((cam.distort(ideal) - observed).norm() < 1e-9);
        assert_eq!(sample_camera().distort(observed), observed);
    }

    #[test]
    fn rig_rejects_coincident_centres() {
        let cam = sample_camera();
        let err = Rig::new([cam.clone(), cam.clone(), cam]).unwrap_err();
        assert!(matches!(
            err,
            RigError::CoincidentCentres {
                first: 0,
                second: 1,
                ..
            }
        ));
    }
}
