//! A camera from 3D–2D correspondences: the "estimate" step of calibration.
//!
//! ```text
//! points_3d, points_2d ─▶ checks ─▶ Hartley normalisation ─▶ DLT (SVD) ─▶ sign (w > 0)
//!   ─▶ K, R, t (RQ, via Camera::from_projection) ─▶ Levenberg–Marquardt on pixel error ─▶ CameraFit
//! ```
//!
//! The DLT minimises an algebraic error and ignores lens distortion, so it only *starts* the
//! fit; Levenberg–Marquardt then minimises the sum of squared pixel reprojection errors,
//! which is the maximum-likelihood estimate under Gaussian pixel noise.
//!
//! Choices, and why:
//! - **Skew is fixed at 0** in the refinement. Sensors have rectangular pixel grids; a free
//!   skew is a poorly constrained parameter that trades off against rotation and `cx`, and
//!   fitting the noise with it makes the camera worse on points *off* the pattern — which is
//!   what a calibration is for. The DLT's skew is dropped when the refinement starts.
//! - **k3 stays 0** when distortion is estimated (OpenCV's `CALIB_FIX_K3` advice for
//!   ordinary lenses). Reference points on a pattern rarely reach the image corners, so k2
//!   and k3 are nearly collinear over the radii observed, and a free k3 extrapolates wildly
//!   beyond them. k1, k2, p1, p2 are estimated.
//! - **Analytic Jacobians**, accumulated straight into the normal equations (no 2n×p matrix):
//!   an iteration over 400 points costs tens of microseconds.
//! - The rotation is updated locally, `R ← exp([ω]×)·R`, so there is no singularity and no
//!   angle wrap-around.
//! - Coplanar points are refused (`Coplanar`): the DLT of a plane has a two-dimensional null
//!   space, so `P` is not determined. A planar method (Zhang) would need several views.
//!
//! Accuracy (tests, 50 random 512×512 cameras viewing the default pattern from 0.8–1.5 m,
//! σ = 0.2 px): a pinhole fit reprojects held-out scene points within 0.10 px RMS (median),
//! 0.21 px (worst). With distortion estimated the lens is pinned down where the pattern
//! was seen (median 0.17 px) but extrapolated beyond it (median 0.32 px over the whole
//! image): one view of one pattern does not constrain k1, k2 at radii it does not reach.

use nalgebra::{Matrix3, Matrix3x4, Point2, Point3, Rotation3, SMatrix, SVector, Vector2, Vector3};
use thiserror::Error;

use crate::geometry::camera::MAX_IMAGE_SIDE;
use crate::geometry::{Camera, CameraError, Distortion};

/// Fewest correspondences accepted: the DLT has 11 unknowns, two equations per point.
pub const MIN_POINTS: usize = 6;
/// Smallest accepted ratio of the smallest to the largest spread (singular value) of the
/// centred 3D points; below it the points are taken as lying on one plane (or a line).
pub const MIN_PLANARITY_RATIO: f64 = 1e-2;

/// How to fit.
#[derive(Debug, Clone, PartialEq)]
pub struct EstimateOptions {
    /// Also estimate plumb_bob distortion (k1, k2, p1, p2; k3 stays 0, see the module doc).
    pub distortion: bool,
    /// Most Levenberg–Marquardt iterations (Jacobian evaluations). 0 returns the DLT's
    /// camera with skew set to 0.
    pub max_iterations: u32,
}

impl Default for EstimateOptions {
    fn default() -> Self {
        EstimateOptions {
            distortion: false,
            max_iterations: 100,
        }
    }
}

/// The fitted camera and how well it explains the points.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFit {
    pub camera: Camera,
    /// Root mean square reprojection error over the points, pixels.
    pub rms_px: f64,
    /// Largest reprojection error over the points, pixels.
    pub max_px: f64,
    /// Correspondences used.
    pub points: usize,
    /// Levenberg–Marquardt iterations run.
    pub iterations: u32,
}

/// Why no camera could be estimated. [`EstimateError::field`] names the input at fault.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum EstimateError {
    #[error("points_3d has {points_3d} points but points_2d has {points_2d}; they must pair up")]
    LengthMismatch { points_3d: usize, points_2d: usize },
    #[error("needs at least {MIN_POINTS} correspondences, got {got}")]
    TooFewPoints { got: usize },
    #[error("{field}[{index}] has a non-finite coordinate")]
    NonFinite { field: &'static str, index: usize },
    #[error(
        "the 3D points lie (nearly) on one plane (thickness/extent {ratio:.1e}): a single view \
         of a planar target does not determine P; use a pattern with points on two or more \
         planes (e.g. the two-board default)"
    )]
    Coplanar { ratio: f64 },
    #[error("{field}: {message}")]
    Degenerate {
        field: &'static str,
        message: String,
    },
    #[error("estimated camera is invalid: {0}")]
    Camera(#[from] CameraError),
}

impl EstimateError {
    /// The input at fault: `points_3d`, `points_2d`, `width`, ...
    pub fn field(&self) -> &'static str {
        match self {
            EstimateError::LengthMismatch { .. } => "points_2d",
            EstimateError::TooFewPoints { .. } | EstimateError::Coplanar { .. } => "points_3d",
            EstimateError::NonFinite { field, .. } | EstimateError::Degenerate { field, .. } => {
                field
            }
            EstimateError::Camera(e) => e.field(),
        }
    }
}

/// Number of refined parameters: fx fy cx cy | ω (3) | t (3) | k1 k2 p1 p2.
const NP: usize = 14;
type Params = SVector<f64, NP>;
type Normal = SMatrix<f64, NP, NP>;
/// Points closer to the camera plane than this (metres) are treated as behind it.
const MIN_DEPTH: f64 = 1e-9;

/// Estimates a camera (`P = K[R|t]`, optional plumb_bob distortion) from correspondences
/// `points_3d[i] ↔ points_2d[i]` (rig frame metres ↔ observed, distorted pixels).
pub fn estimate_camera(
    name: &str,
    width: u32,
    height: u32,
    points_3d: &[Point3<f64>],
    points_2d: &[Point2<f64>],
    options: &EstimateOptions,
) -> Result<CameraFit, EstimateError> {
    check_inputs(width, height, points_3d, points_2d)?;
    let initial = dlt(name, width, height, points_3d, points_2d)?;

    let k = initial.intrinsics();
    let mut state = State {
        intr: [k[(0, 0)], k[(1, 1)], k[(0, 2)], k[(1, 2)]],
        rotation: *initial.rotation(),
        translation: *initial.translation(),
        dist: [0.0; 4],
    };
    let iterations = refine(&mut state, points_3d, points_2d, options);

    let [fx, fy, cx, cy] = state.intr;
    let intrinsics = Matrix3::new(fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0);
    let distortion = options.distortion.then(|| state.distortion());
    let camera = Camera::from_krt(
        name,
        width,
        height,
        intrinsics,
        state.rotation,
        state.translation,
        distortion,
    )?;

    let (mut sum2, mut max2) = (0.0_f64, 0.0_f64);
    for (i, (x, m)) in points_3d.iter().zip(points_2d).enumerate() {
        let p = camera.project(x).ok_or_else(|| EstimateError::Degenerate {
            field: "points_3d",
            message: format!("point {i} is behind the fitted camera"),
        })?;
        let e2 = (p - m).norm_squared();
        sum2 += e2;
        max2 = max2.max(e2);
    }
    Ok(CameraFit {
        camera,
        rms_px: (sum2 / points_3d.len() as f64).sqrt(),
        max_px: max2.sqrt(),
        points: points_3d.len(),
        iterations,
    })
}

fn check_inputs(
    width: u32,
    height: u32,
    points_3d: &[Point3<f64>],
    points_2d: &[Point2<f64>],
) -> Result<(), EstimateError> {
    if points_3d.len() != points_2d.len() {
        return Err(EstimateError::LengthMismatch {
            points_3d: points_3d.len(),
            points_2d: points_2d.len(),
        });
    }
    if points_3d.len() < MIN_POINTS {
        return Err(EstimateError::TooFewPoints {
            got: points_3d.len(),
        });
    }
    if let Some(index) = points_3d
        .iter()
        .position(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        return Err(EstimateError::NonFinite {
            field: "points_3d",
            index,
        });
    }
    if let Some(index) = points_2d
        .iter()
        .position(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        return Err(EstimateError::NonFinite {
            field: "points_2d",
            index,
        });
    }
    if width == 0 || height == 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(CameraError::ImageSize { width, height }.into());
    }
    // Spread of the centred 3D points along their principal axes: a plane (or a line)
    // leaves the smallest one near zero whatever the units.
    let n = points_3d.len() as f64;
    let mean = points_3d.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
    let scatter = points_3d
        .iter()
        .map(|p| (p.coords - mean) * (p.coords - mean).transpose())
        .sum::<Matrix3<f64>>();
    let eig = scatter.symmetric_eigenvalues();
    let (lo, hi) = (eig.min().max(0.0), eig.max());
    let ratio = if hi > 0.0 { (lo / hi).sqrt() } else { 0.0 };
    if ratio < MIN_PLANARITY_RATIO {
        return Err(EstimateError::Coplanar { ratio });
    }
    Ok(())
}

/// Hartley's similarity: centroid to the origin, mean distance to `sqrt(dim)`. Returns
/// (centroid, scale); `None` if all points coincide.
fn similarity<const D: usize>(
    points: impl Iterator<Item = SVector<f64, D>> + Clone,
) -> Option<(SVector<f64, D>, f64)> {
    let n = points.clone().count() as f64;
    let mean = points.clone().sum::<SVector<f64, D>>() / n;
    let spread = points.map(|p| (p - mean).norm()).sum::<f64>() / n;
    (spread > 0.0 && spread.is_finite()).then(|| (mean, (D as f64).sqrt() / spread))
}

/// The normalised direct linear transform: `P` minimising the algebraic error, then split
/// into K, R, t by the geometry module's RQ decomposition.
fn dlt(
    name: &str,
    width: u32,
    height: u32,
    points_3d: &[Point3<f64>],
    points_2d: &[Point2<f64>],
) -> Result<Camera, EstimateError> {
    let (m3, s3) =
        similarity(points_3d.iter().map(|p| p.coords)).ok_or(EstimateError::Degenerate {
            field: "points_3d",
            message: "all points coincide".into(),
        })?;
    let (m2, s2) =
        similarity(points_2d.iter().map(|p| p.coords)).ok_or(EstimateError::Degenerate {
            field: "points_2d",
            message: "all points coincide".into(),
        })?;
    let n = points_3d.len();
    let mut a = nalgebra::DMatrix::<f64>::zeros(2 * n, 12);
    for (i, (x, m)) in points_3d.iter().zip(points_2d).enumerate() {
        let xn = (x.coords - m3) * s3;
        let mn = (m.coords - m2) * s2;
        let xh = [xn.x, xn.y, xn.z, 1.0];
        for j in 0..4 {
            // Rows: Xᵀ p1 − u Xᵀ p3 = 0 and Xᵀ p2 − v Xᵀ p3 = 0.
            a[(2 * i, j)] = xh[j];
            a[(2 * i, 8 + j)] = -mn.x * xh[j];
            a[(2 * i + 1, 4 + j)] = xh[j];
            a[(2 * i + 1, 8 + j)] = -mn.y * xh[j];
        }
    }
    let svd = a.svd(false, true);
    let v_t = svd.v_t.ok_or_else(|| EstimateError::Degenerate {
        field: "points_3d",
        message: "the DLT's SVD did not converge".into(),
    })?;
    // The right singular vector of the smallest singular value.
    let (imin, _) =
        svd.singular_values
            .iter()
            .enumerate()
            .fold(
                (0, f64::INFINITY),
                |best, (i, &s)| {
                    if s < best.1 {
                        (i, s)
                    } else {
                        best
                    }
                },
            );
    let row = v_t.row(imin);
    let pn = Matrix3x4::from_fn(|r, c| row[4 * r + c]);
    // Undo the normalisations: P = T2⁻¹ · Pn · T3.
    let t2_inv = Matrix3::new(1.0 / s2, 0.0, m2.x, 0.0, 1.0 / s2, m2.y, 0.0, 0.0, 1.0);
    let mut t3 = nalgebra::Matrix4::<f64>::identity() * s3;
    t3[(3, 3)] = 1.0;
    t3.fixed_view_mut::<3, 1>(0, 3).copy_from(&(-m3 * s3));
    let mut p = t2_inv * pn * t3;

    // Sign: the points are in front (w > 0). A P that leaves some behind is no camera of
    // these points.
    let w = |p: &Matrix3x4<f64>, x: &Point3<f64>| (p * x.to_homogeneous()).z;
    let front = points_3d.iter().filter(|x| w(&p, x) > 0.0).count();
    if 2 * front < n {
        p = -p;
    }
    if let Some(i) = points_3d.iter().position(|x| w(&p, x) <= 0.0) {
        return Err(EstimateError::Degenerate {
            field: "points_3d",
            message: format!(
                "the DLT camera has point {i} behind it and others in front: the \
                 correspondences do not come from one camera (mismatched pairs?)"
            ),
        });
    }
    Camera::from_projection(name, width, height, p, None).map_err(|e| match e {
        CameraError::RankDeficient { ratio, .. } => EstimateError::Degenerate {
            field: "points_2d",
            message: format!(
                "the DLT's projection is rank-deficient (singular value ratio {ratio:.2e})"
            ),
        },
        CameraError::NegativeDeterminant => EstimateError::Degenerate {
            field: "points_2d",
            message: "the DLT's projection is mirrored (det < 0 with the points in front): \
                      are u and v swapped?"
                .into(),
        },
        other => other.into(),
    })
}

/// What Levenberg–Marquardt refines. `rotation` absorbs each accepted local update.
#[derive(Debug, Clone)]
struct State {
    intr: [f64; 4],
    rotation: Matrix3<f64>,
    translation: Vector3<f64>,
    dist: [f64; 4],
}

impl State {
    fn distortion(&self) -> Distortion {
        let [k1, k2, p1, p2] = self.dist;
        Distortion {
            k1,
            k2,
            p1,
            p2,
            k3: 0.0,
        }
    }

    /// The state moved by `delta` (layout of [`NP`]).
    fn step(&self, delta: &Params) -> State {
        let omega = Vector3::new(delta[4], delta[5], delta[6]);
        let rotation = Rotation3::new(omega).into_inner() * self.rotation;
        // Re-orthonormalise so that rounding never accumulates over iterations.
        let guess = Rotation3::from_matrix_unchecked(rotation);
        let rotation = Rotation3::from_matrix_eps(&rotation, 1e-15, 4, guess).into_inner();
        State {
            intr: std::array::from_fn(|i| self.intr[i] + delta[i]),
            rotation,
            translation: self.translation + Vector3::new(delta[7], delta[8], delta[9]),
            dist: std::array::from_fn(|i| self.dist[i] + delta[10 + i]),
        }
    }

    /// Residual (projected − observed) of one point, and optionally its 2×NP Jacobian.
    /// `None` if the point is not in front of the camera.
    fn residual(
        &self,
        x: &Point3<f64>,
        m: &Point2<f64>,
        jac: Option<&mut SMatrix<f64, 2, NP>>,
    ) -> Option<Vector2<f64>> {
        let rx = self.rotation * x.coords;
        let c = rx + self.translation;
        if c.z <= MIN_DEPTH {
            return None;
        }
        let iz = 1.0 / c.z;
        let (xn, yn) = (c.x * iz, c.y * iz);
        let [k1, k2, p1, p2] = self.dist;
        let r2 = xn * xn + yn * yn;
        let rad = 1.0 + r2 * (k1 + r2 * k2);
        let xd = xn * rad + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn);
        let yd = yn * rad + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn;
        let [fx, fy, cx, cy] = self.intr;
        let r = Vector2::new(fx * xd + cx - m.x, fy * yd + cy - m.y);
        if let Some(j) = jac {
            // Intrinsics.
            j[(0, 0)] = xd;
            j[(0, 2)] = 1.0;
            j[(1, 1)] = yd;
            j[(1, 3)] = 1.0;
            // Distortion: ∂(xd, yd)/∂(k1, k2, p1, p2), times the focal lengths.
            let r4 = r2 * r2;
            let dd = [
                [xn * r2, xn * r4, 2.0 * xn * yn, r2 + 2.0 * xn * xn],
                [yn * r2, yn * r4, r2 + 2.0 * yn * yn, 2.0 * xn * yn],
            ];
            for k in 0..4 {
                j[(0, 10 + k)] = fx * dd[0][k];
                j[(1, 10 + k)] = fy * dd[1][k];
            }
            // Pose: pixels ← distorted ← normalised ← camera frame ← (ω, t).
            let drad = k1 + 2.0 * k2 * r2; // ∂rad/∂(r²)
            let dxd_dx = rad + 2.0 * xn * xn * drad + 2.0 * p1 * yn + 6.0 * p2 * xn;
            let dxd_dy = 2.0 * xn * yn * drad + 2.0 * p1 * xn + 2.0 * p2 * yn;
            let dyd_dx = 2.0 * xn * yn * drad + 2.0 * p1 * xn + 2.0 * p2 * yn;
            let dyd_dy = rad + 2.0 * yn * yn * drad + 6.0 * p1 * yn + 2.0 * p2 * xn;
            // ∂(xn, yn)/∂c.
            let dn = nalgebra::Matrix2x3::new(iz, 0.0, -xn * iz, 0.0, iz, -yn * iz);
            let dpix = nalgebra::Matrix2::new(fx * dxd_dx, fx * dxd_dy, fy * dyd_dx, fy * dyd_dy);
            let dc = dpix * dn; // ∂pixel/∂c, also ∂pixel/∂t
                                // c = exp([ω]×)·R·x + t ⇒ ∂c/∂ω = −[R·x]× at ω = 0.
            let dw = dc * (-rx.cross_matrix());
            j.fixed_view_mut::<2, 3>(0, 4).copy_from(&dw);
            j.fixed_view_mut::<2, 3>(0, 7).copy_from(&dc);
        }
        Some(r)
    }

    /// Sum of squared residuals; `None` if any point is not in front.
    fn cost(&self, points_3d: &[Point3<f64>], points_2d: &[Point2<f64>]) -> Option<f64> {
        let mut sum = 0.0;
        for (x, m) in points_3d.iter().zip(points_2d) {
            sum += self.residual(x, m, None)?.norm_squared();
        }
        Some(sum)
    }

    /// Normal equations `JᵀJ`, `Jᵀr` and the cost.
    fn normal(
        &self,
        points_3d: &[Point3<f64>],
        points_2d: &[Point2<f64>],
    ) -> Option<(Normal, Params, f64)> {
        let mut jtj = Normal::zeros();
        let mut jtr = Params::zeros();
        let mut cost = 0.0;
        let mut j = SMatrix::<f64, 2, NP>::zeros();
        for (x, m) in points_3d.iter().zip(points_2d) {
            let r = self.residual(x, m, Some(&mut j))?;
            jtj += j.transpose() * j;
            jtr += j.transpose() * r;
            cost += r.norm_squared();
        }
        Some((jtj, jtr, cost))
    }
}

/// The damping Levenberg–Marquardt starts from: small, a nearly Gauss–Newton first step,
/// since the DLT's start is usually close.
const DAMPING_START: f64 = 1e-3;
/// Each refused step multiplies the damping by this, each accepted one divides it.
const DAMPING_FACTOR: f64 = 10.0;
/// The damping's range: below the floor it no longer changes the step; past the ceiling
/// every step is a vanishing gradient step, and the fit has converged as far as it can.
const DAMPING_FLOOR: f64 = 1e-12;
const DAMPING_CEILING: f64 = 1e12;
/// A parameter the normal equations say nothing about keeps this much of the diagonal, so
/// that Marquardt's scaling never divides by zero.
const DIAGONAL_FLOOR: f64 = 1e-12;
/// Converged when a step lowers the cost by less than `COST_TOLERANCE` of it, or moves every
/// parameter by less than `STEP_TOLERANCE` of the residual's scale (the root of the cost,
/// floored for an exact fit).
const COST_TOLERANCE: f64 = 1e-12;
const STEP_TOLERANCE: f64 = 1e-10;
const RESIDUAL_SCALE_FLOOR: f64 = 1e-12;

/// Levenberg–Marquardt with Marquardt's diagonal scaling (the parameters' units differ by
/// orders of magnitude: pixels, radians, metres). Returns the iterations run.
fn refine(
    state: &mut State,
    points_3d: &[Point3<f64>],
    points_2d: &[Point2<f64>],
    options: &EstimateOptions,
) -> u32 {
    let free = |i: usize| options.distortion || i < 10;
    let mut lambda = DAMPING_START;
    let mut iterations = 0;
    while iterations < options.max_iterations {
        let Some((mut jtj, mut jtr, cost)) = state.normal(points_3d, points_2d) else {
            // The DLT put every point in front, and steps that do not are refused, so
            // this is not reached; stop rather than loop.
            break;
        };
        iterations += 1;
        for i in (0..NP).filter(|&i| !free(i)) {
            jtj.row_mut(i).fill(0.0);
            jtj.column_mut(i).fill(0.0);
            jtj[(i, i)] = 1.0;
            jtr[i] = 0.0;
        }
        let diag = jtj.diagonal().map(|d| d.max(DIAGONAL_FLOOR));
        let mut improved = false;
        while lambda < DAMPING_CEILING {
            let mut a = jtj;
            for i in 0..NP {
                a[(i, i)] += lambda * diag[i];
            }
            let Some(chol) = a.cholesky() else {
                lambda *= DAMPING_FACTOR;
                continue;
            };
            let delta = -chol.solve(&jtr);
            let next = state.step(&delta);
            match next.cost(points_3d, points_2d) {
                Some(c) if c < cost => {
                    *state = next;
                    lambda = (lambda * (1.0 / DAMPING_FACTOR)).max(DAMPING_FLOOR);
                    improved = true;
                    // Converged: the cost no longer moves (relative), or the step is
                    // negligible against every parameter's scale.
                    let small_step = (0..NP).all(|i| {
                        delta[i].abs() * diag[i].sqrt()
                            <= STEP_TOLERANCE * cost.sqrt().max(RESIDUAL_SCALE_FLOOR)
                    });
                    if cost - c <= COST_TOLERANCE * cost || small_step {
                        return iterations;
                    }
                    break;
                }
                _ => lambda *= DAMPING_FACTOR,
            }
        }
        if !improved {
            break;
        }
    }
    iterations
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::{CalibrationPattern, GridBoard};
    use proptest::prelude::*;
    use trinocular_synth::Rng;

    const W: u32 = 512;
    const H: u32 = 512;
    const SIGMA: f64 = 0.2;

    fn pattern_points() -> Vec<Point3<f64>> {
        CalibrationPattern::default()
            .reference_points()
            .into_iter()
            .map(|(_, p)| p)
            .collect()
    }

    fn centroid(points: &[Point3<f64>]) -> Point3<f64> {
        Point3::from(points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / points.len() as f64)
    }

    /// A plausible camera looking at the default pattern from 0.8–1.5 m, from the side both
    /// boards face, optionally with plumb_bob distortion (k3 = 0).
    fn random_camera(rng: &mut Rng, distorted: bool) -> Camera {
        let target = centroid(&pattern_points())
            + Vector3::new(
                rng.symmetric(0.05),
                rng.symmetric(0.05),
                rng.symmetric(0.05),
            );
        let az = rng.range(25.0, 65.0).to_radians();
        let el = rng.range(-10.0, 30.0).to_radians();
        let d = rng.range(0.8, 1.5);
        let centre = target + d * Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
        let z = (target - centre).normalize();
        let x = (-Vector3::z()).cross(&z).normalize();
        let y = z.cross(&x);
        let look = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
        let roll =
            Rotation3::from_axis_angle(&Vector3::z_axis(), rng.symmetric(10f64.to_radians()));
        let rotation = roll.into_inner() * look;
        let translation = -(rotation * centre.coords);
        // Framed as a calibration is: the pattern fills most of the image (80–95 % of the
        // half-width at its farthest point), so that the fit sees the radii it is used at.
        let reach = pattern_points()
            .iter()
            .map(|x| {
                let c = rotation * x.coords + translation;
                (c.x / c.z).abs().max((c.y / c.z).abs())
            })
            .fold(0.0, f64::max);
        let fx = rng.range(0.8, 0.95) * 0.5 * f64::from(W) / reach;
        let fy = fx * (1.0 + rng.symmetric(0.02));
        let k = Matrix3::new(
            fx,
            0.0,
            255.5 + rng.symmetric(15.0),
            0.0,
            fy,
            255.5 + rng.symmetric(15.0),
            0.0,
            0.0,
            1.0,
        );
        let distortion = distorted.then(|| Distortion {
            k1: rng.range(-0.25, 0.1),
            k2: rng.symmetric(0.05),
            p1: rng.symmetric(1e-3),
            p2: rng.symmetric(1e-3),
            k3: 0.0,
        });
        Camera::from_krt("truth", W, H, k, rotation, translation, distortion).unwrap()
    }

    fn inside(p: &Point2<f64>) -> bool {
        p.x >= -0.5 && p.y >= -0.5 && p.x <= W as f64 - 0.5 && p.y <= H as f64 - 0.5
    }

    /// The pattern's reference points seen by `truth`, with Gaussian pixel noise.
    fn observe(truth: &Camera, rng: &mut Rng, sigma: f64) -> (Vec<Point3<f64>>, Vec<Point2<f64>>) {
        pattern_points()
            .into_iter()
            .filter_map(|x| {
                let p = truth.project(&x).filter(inside)?;
                Some((x, p + Vector2::new(rng.normal(), rng.normal()) * sigma))
            })
            .unzip()
    }

    /// Held-out error: RMS pixel distance between the true and the fitted camera's images
    /// of random points of a 1 m cube around the pattern, more than 0.3 m in front, that the
    /// true camera sees in its image: over the whole image, and over the part of it the
    /// pattern covered (the bounding box of `seen`), where the fit interpolates.
    #[derive(Debug, Clone, Copy)]
    struct HeldOut {
        image: f64,
        pattern: f64,
    }

    fn held_out(truth: &Camera, fit: &Camera, seen: &[Point2<f64>], rng: &mut Rng) -> HeldOut {
        let c = centroid(&pattern_points());
        let lo = seen
            .iter()
            .fold(Point2::new(f64::MAX, f64::MAX), |a, p| a.inf(p));
        let hi = seen
            .iter()
            .fold(Point2::new(f64::MIN, f64::MIN), |a, p| a.sup(p));
        let pinhole = Camera::from_krt(
            "pinhole",
            W,
            H,
            *truth.intrinsics(),
            *truth.rotation(),
            *truth.translation(),
            None,
        )
        .unwrap();
        let (mut image, mut pattern) = ((0.0, 0), (0.0, 0));
        while image.1 < 2000 || pattern.1 < 200 {
            let x = c + Vector3::new(rng.symmetric(0.5), rng.symmetric(0.5), rng.symmetric(0.5));
            if truth.depth(&x) < 0.3 {
                continue;
            }
            // Inside the image with and without the lens: a strong distortion folds points
            // from far outside the field of view back into the image (the polynomial is
            // only meaningful up to the image's radius), and those are no part of it.
            let Some(p) = truth.project(&x).filter(inside) else {
                continue;
            };
            if !pinhole.project(&x).is_some_and(|q| inside(&q)) {
                continue;
            }
            let q = fit
                .project(&x)
                .expect("held-out point behind the fitted camera");
            let e2 = (p - q).norm_squared();
            image = (image.0 + e2, image.1 + 1);
            if p.x >= lo.x && p.y >= lo.y && p.x <= hi.x && p.y <= hi.y {
                pattern = (pattern.0 + e2, pattern.1 + 1);
            }
        }
        HeldOut {
            image: (image.0 / image.1 as f64).sqrt(),
            pattern: (pattern.0 / pattern.1 as f64).sqrt(),
        }
    }

    fn rotation_error_deg(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
        Rotation3::from_matrix_unchecked(a.transpose() * b)
            .angle()
            .to_degrees()
    }

    fn options(distortion: bool) -> EstimateOptions {
        EstimateOptions {
            distortion,
            ..EstimateOptions::default()
        }
    }

    /// Fits a camera to a noisy view by `truth`; returns the fit and the held-out error.
    fn fit(truth: &Camera, rng: &mut Rng, distortion: bool) -> (CameraFit, HeldOut) {
        let (p3, p2) = observe(truth, rng, SIGMA);
        assert!(p3.len() >= 200, "only {} pattern points in view", p3.len());
        let fit = estimate_camera("fit", W, H, &p3, &p2, &options(distortion)).unwrap();
        let held_out = held_out(truth, &fit.camera, &p2, rng);
        (fit, held_out)
    }

    #[test]
    fn recovers_a_pinhole_camera() {
        let mut rng = Rng::new(1);
        for _ in 0..10 {
            let truth = random_camera(&mut rng, false);
            let (fit, held_out) = fit(&truth, &mut rng, false);
            assert!(held_out.image <= 0.3, "held-out RMS {held_out:?}");
            assert!(fit.rms_px < 0.3, "fit RMS {}", fit.rms_px);
            assert!(fit.iterations >= 1);
            let (k, kt) = (fit.camera.intrinsics(), truth.intrinsics());
            assert!(
                (k[(0, 0)] / kt[(0, 0)] - 1.0).abs() < 0.01,
                "fx {k} vs {kt}"
            );
            assert!(
                (k[(1, 1)] / kt[(1, 1)] - 1.0).abs() < 0.01,
                "fy {k} vs {kt}"
            );
            assert!((k[(0, 2)] - kt[(0, 2)]).abs() < 3.0, "cx {k} vs {kt}");
            assert!((k[(1, 2)] - kt[(1, 2)]).abs() < 3.0, "cy {k} vs {kt}");
            assert_eq!(k[(0, 1)], 0.0, "skew is fixed at 0");
            assert!(rotation_error_deg(fit.camera.rotation(), truth.rotation()) < 0.2);
            assert!((fit.camera.centre() - truth.centre()).norm() < 0.01);
            assert!(fit.camera.distortion().is_none());
        }
    }

    #[test]
    fn recovers_a_distorted_camera() {
        let mut rng = Rng::new(2);
        for _ in 0..10 {
            let truth = random_camera(&mut rng, true);
            let (fit, held_out) = fit(&truth, &mut rng, true);
            // Inside the pattern's footprint; beyond it the distortion is extrapolated (see
            // held_out_error_over_50_cameras).
            assert!(held_out.pattern <= 0.5, "held-out RMS {held_out:?}");
            assert!(held_out.image <= 1.0, "held-out RMS {held_out:?}");
            assert!(fit.rms_px < 0.3, "fit RMS {}", fit.rms_px);
            let (k, kt) = (fit.camera.intrinsics(), truth.intrinsics());
            assert!(
                (k[(0, 0)] / kt[(0, 0)] - 1.0).abs() < 0.02,
                "fx {k} vs {kt}"
            );
            assert!((k[(0, 2)] - kt[(0, 2)]).abs() < 8.0, "cx {k} vs {kt}");
            let angle = rotation_error_deg(fit.camera.rotation(), truth.rotation());
            let shift = (fit.camera.centre() - truth.centre()).norm();
            // Looser than the pinhole's: distortion trades off against cx, cy and the pose.
            assert!(
                angle < 1.0 && shift < 0.03,
                "R off by {angle}°, C by {shift} m"
            );
            let (d, dt) = (
                fit.camera.distortion().unwrap(),
                truth.distortion().unwrap(),
            );
            assert!((d.k1 - dt.k1).abs() < 0.03, "k1 {d:?} vs {dt:?}");
            assert_eq!(d.k3, 0.0);
        }
    }

    #[test]
    fn distortion_option_explains_a_distorted_lens() {
        // The point of the option: the pinhole model cannot absorb all of k1 = -0.2 (it
        // absorbs much of it into the focal length over the pattern's radii).
        let mut rng = Rng::new(3);
        let truth = random_camera(&mut rng, false);
        let distorted = Camera::from_krt(
            "truth",
            W,
            H,
            *truth.intrinsics(),
            *truth.rotation(),
            *truth.translation(),
            Some(Distortion {
                k1: -0.2,
                ..Distortion::default()
            }),
        )
        .unwrap();
        let (pinhole, pinhole_held_out) = fit(&distorted, &mut rng, false);
        let (full, held_out) = fit(&distorted, &mut rng, true);
        assert!(
            pinhole.rms_px > 1.25 * full.rms_px,
            "pinhole RMS {}, with distortion {}",
            pinhole.rms_px,
            full.rms_px
        );
        assert!(
            pinhole_held_out.image > held_out.image,
            "{pinhole_held_out:?} {held_out:?}"
        );
        assert!(full.rms_px < 0.3 && held_out.pattern <= 0.5);
    }

    #[test]
    fn exact_data_fits_exactly() {
        let mut rng = Rng::new(4);
        let truth = random_camera(&mut rng, true);
        let (p3, p2) = observe(&truth, &mut rng, 0.0);
        let fit = estimate_camera("exact", W, H, &p3, &p2, &options(true)).unwrap();
        assert!(
            fit.rms_px < 1e-6 && fit.max_px < 1e-5,
            "{} {}",
            fit.rms_px,
            fit.max_px
        );
        let held_out = held_out(&truth, &fit.camera, &p2, &mut rng);
        assert!(held_out.image < 1e-5, "{held_out:?}");
        assert_eq!(fit.points, p3.len());
        assert_eq!(fit.camera.name(), "exact");
    }

    #[test]
    fn analytic_jacobian_matches_central_differences() {
        let mut rng = Rng::new(5);
        let truth = random_camera(&mut rng, true);
        let k = truth.intrinsics();
        let d = truth.distortion().unwrap();
        let state = State {
            intr: [k[(0, 0)], k[(1, 1)], k[(0, 2)], k[(1, 2)]],
            rotation: *truth.rotation(),
            translation: *truth.translation(),
            dist: [d.k1 + 0.1, d.k2, d.p1 + 0.01, d.p2 - 0.01],
        };
        let m = Point2::new(100.0, 200.0);
        for x in pattern_points().iter().step_by(37) {
            let mut j = SMatrix::<f64, 2, NP>::zeros();
            state.residual(x, &m, Some(&mut j)).unwrap();
            for i in 0..NP {
                let h = if i < 4 { 1e-4 } else { 1e-7 };
                let mut e = Params::zeros();
                e[i] = h;
                let plus = state.step(&e).residual(x, &m, None).unwrap();
                let minus = state.step(&(-e)).residual(x, &m, None).unwrap();
                let numeric = (plus - minus) / (2.0 * h);
                let analytic = j.column(i);
                assert!(
                    (numeric - analytic).norm() <= 1e-5 * (1.0 + analytic.norm()),
                    "parameter {i}: numeric {numeric} vs analytic {analytic}"
                );
            }
        }
    }

    #[test]
    fn fit_matches_the_camera_it_returns() {
        // rms_px is measured with Camera::project, the model everyone else uses.
        let mut rng = Rng::new(6);
        let truth = random_camera(&mut rng, true);
        let (p3, p2) = observe(&truth, &mut rng, SIGMA);
        let fit = estimate_camera("fit", W, H, &p3, &p2, &options(true)).unwrap();
        let sum: f64 = p3
            .iter()
            .zip(&p2)
            .map(|(x, m)| (fit.camera.project(x).unwrap() - m).norm_squared())
            .sum();
        assert!(((sum / p3.len() as f64).sqrt() - fit.rms_px).abs() < 1e-12);
        assert!(fit.max_px >= fit.rms_px);
        // Noise σ = 0.2 px in each of u, v: RMS of the 2D error ≈ σ·√2·√(1 − 14/2n).
        assert!((0.2..0.32).contains(&fit.rms_px), "rms {}", fit.rms_px);
    }

    #[test]
    fn zero_iterations_is_the_dlt() {
        let mut rng = Rng::new(7);
        let truth = random_camera(&mut rng, false);
        let (p3, p2) = observe(&truth, &mut rng, SIGMA);
        let opts = EstimateOptions {
            distortion: false,
            max_iterations: 0,
        };
        let fit = estimate_camera("dlt", W, H, &p3, &p2, &opts).unwrap();
        assert_eq!(fit.iterations, 0);
        assert!(fit.rms_px < 1.0, "DLT RMS {}", fit.rms_px);
    }

    fn good_input() -> (Vec<Point3<f64>>, Vec<Point2<f64>>) {
        let mut rng = Rng::new(8);
        let truth = random_camera(&mut rng, false);
        observe(&truth, &mut rng, 0.0)
    }

    fn estimate(p3: &[Point3<f64>], p2: &[Point2<f64>]) -> Result<CameraFit, EstimateError> {
        estimate_camera("bad", W, H, p3, p2, &EstimateOptions::default())
    }

    #[test]
    fn too_few_points() {
        let (p3, p2) = good_input();
        let err = estimate(&p3[..5], &p2[..5]).unwrap_err();
        assert_eq!(err, EstimateError::TooFewPoints { got: 5 });
        assert_eq!(err.field(), "points_3d");
        assert!(estimate(&p3[..0], &p2[..0]).is_err());
    }

    #[test]
    fn mismatched_lengths() {
        let (p3, p2) = good_input();
        let err = estimate(&p3, &p2[1..]).unwrap_err();
        assert_eq!(
            err,
            EstimateError::LengthMismatch {
                points_3d: p3.len(),
                points_2d: p3.len() - 1
            }
        );
        assert_eq!(err.field(), "points_2d");
    }

    #[test]
    fn non_finite_coordinates_name_the_point() {
        let (mut p3, mut p2) = good_input();
        p2[3].y = f64::NAN;
        let err = estimate(&p3, &p2).unwrap_err();
        assert_eq!(
            err,
            EstimateError::NonFinite {
                field: "points_2d",
                index: 3
            }
        );
        assert_eq!(err.field(), "points_2d");
        p3[7].x = f64::INFINITY;
        let err = estimate(&p3, &p2).unwrap_err();
        assert_eq!(
            err,
            EstimateError::NonFinite {
                field: "points_3d",
                index: 7
            }
        );
        assert!(err.to_string().contains("points_3d[7]"));
    }

    #[test]
    fn one_board_is_coplanar() {
        let mut rng = Rng::new(9);
        let truth = random_camera(&mut rng, false);
        let one_board = CalibrationPattern {
            boards: vec![CalibrationPattern::default().boards[0].clone()],
        };
        let (p3, p2): (Vec<_>, Vec<_>) = one_board
            .reference_points()
            .into_iter()
            .filter_map(|(_, x)| Some((x, truth.project(&x)?)))
            .unzip();
        let err = estimate(&p3, &p2).unwrap_err();
        assert!(matches!(err, EstimateError::Coplanar { .. }), "{err}");
        assert_eq!(err.field(), "points_3d");
        assert!(err.to_string().contains("one plane"));
        // A board tilted off the axes is just as planar.
        let tilted = GridBoard {
            origin: Point3::new(0.1, 0.2, 0.3),
            u_axis: Vector3::new(0.6, 0.8, 0.0),
            v_axis: Vector3::new(0.0, 0.0, -1.0),
            ..one_board.boards[0].clone()
        };
        let p3: Vec<_> = CalibrationPattern {
            boards: vec![tilted],
        }
        .reference_points()
        .into_iter()
        .map(|(_, x)| x)
        .collect();
        let err = estimate(&p3, &p2[..p3.len()]).unwrap_err();
        assert!(matches!(err, EstimateError::Coplanar { .. }), "{err}");
    }

    #[test]
    fn other_degenerate_inputs() {
        let (p3, p2) = good_input();
        // Every observation at one pixel.
        let same = vec![Point2::new(10.0, 10.0); p3.len()];
        let err = estimate(&p3, &same).unwrap_err();
        assert_eq!(err.field(), "points_2d", "{err}");
        // A bad image size.
        let err = estimate_camera("bad", 0, H, &p3, &p2, &EstimateOptions::default()).unwrap_err();
        assert_eq!(err.field(), "width");
        // Shuffled correspondences: an error or a bad fit, never a panic.
        let mut shuffled = p2.clone();
        Rng::new(10).shuffle(&mut shuffled);
        if let Ok(fit) = estimate(&p3, &shuffled) {
            assert!(fit.rms_px > 10.0);
        }
    }

    /// The issue's goal: over 50 random cameras with σ = 0.2 px, the held-out error against
    /// the true camera. Prints the median and max (`--nocapture`).
    #[test]
    fn held_out_error_over_50_cameras() {
        for distortion in [false, true] {
            let mut rng = Rng::new(11 + distortion as u64);
            let (mut image, mut pattern): (Vec<f64>, Vec<f64>) = (0..50)
                .map(|_| {
                    let truth = random_camera(&mut rng, distortion);
                    let h = fit(&truth, &mut rng, distortion).1;
                    (h.image, h.pattern)
                })
                .unzip();
            image.sort_by(f64::total_cmp);
            pattern.sort_by(f64::total_cmp);
            println!(
                "held-out RMS, distortion {distortion}: whole image median {:.3} max {:.3} px; \
                 pattern's footprint median {:.3} max {:.3} px",
                image[25], image[49], pattern[25], pattern[49]
            );
            if distortion {
                // A single view pins the lens down where the pattern is; beyond it k1, k2
                // are extrapolated (measured in the 50-camera test).
                assert!(pattern[25] <= 0.2 && pattern[49] <= 0.5, "{pattern:?}");
                assert!(image[49] <= 1.0, "{image:?}");
            } else {
                assert!(image[25] <= 0.2 && image[49] <= 0.3, "{image:?}");
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(32))]
        #[test]
        fn random_cameras_round_trip(seed in any::<u64>(), distorted in any::<bool>()) {
            let mut rng = Rng::new(seed);
            let truth = random_camera(&mut rng, distorted);
            let (fit, held_out) = fit(&truth, &mut rng, distorted);
            // Per camera, not per study: the 50-camera study above holds the accuracy bounds
            // (pinhole: median 0.2, max 0.3 px over the image); one random camera can land
            // past the study's maximum (distorted: 0.63 px inside the pattern's footprint,
            // 0.87 px over the image; pinhole: 0.301 px, the seed saved in
            // proptest-regressions). Here: no gross failure.
            if distorted {
                prop_assert!(held_out.pattern <= 1.0 && held_out.image <= 2.0, "{:?}", held_out);
            } else {
                prop_assert!(held_out.image <= 0.5, "held-out RMS {:?}", held_out);
            }
            prop_assert!(fit.rms_px < 0.35);
        }
    }
}
