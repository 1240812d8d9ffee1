//! 3D lines from three views (DESIGN §2.6): the maximum-likelihood line of image-line
//! observations, with its covariance.
//!
//! Each image line `lᵢ` back-projects to the plane `πᵢ = Pᵢᵀ lᵢ` through optical centre i;
//! where two of those planes meet is the linear start. Gauss–Newton then minimises the image
//! distances of each observation, weighted by its noise ([`LineNoise`]), over the line's four
//! parameters; the inverse normal matrix at the optimum is its covariance (first order), and
//! the χ² at the optimum says whether the observations are one line at all. The 3D segment is
//! the part of the line every view saw (the overlap of their ends, a view holding only a
//! fragment of the line aside).

use nalgebra::{Matrix3, Matrix6, Point2, Point3, Vector3, Vector4, Vector6};

use super::camera::Camera;
use crate::segment::LineNoise;

/// Smallest ratio of the middle to the largest eigenvalue of the plane normals' scatter: below
/// it the planes (nearly) coincide and the line is not determined.
const MIN_PLANE_SPREAD: f64 = 1e-8;
/// A view whose segment covers less than this share of the longest view's holds a fragment
/// of the line: its ends do not cut the 3D segment's extent.
const FRAGMENT_SHARE: f64 = 0.25;
/// Smallest sine between a back-projected ray and the 3D line for the ray to locate an endpoint.
const MIN_RAY_LINE_SIN: f64 = 1e-3;

fn image_line(start: Point2<f64>, end: Point2<f64>) -> Option<Vector3<f64>> {
    let l = Vector3::new(start.x, start.y, 1.0).cross(&Vector3::new(end.x, end.y, 1.0));
    let n = crate::segment::root_sum_square(l.x, l.y);
    (n > 1e-12).then(|| l / n)
}

/// One image line seen by camera `view` (undistorted pixels), with how well it is known.
/// A view may contribute several observations (collinear pieces of one line).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineObservation {
    pub view: usize,
    pub start: Point2<f64>,
    pub end: Point2<f64>,
    pub noise: LineNoise,
    /// σ of a shift of this line across itself that `noise` leaves out, pixels: a detector's
    /// systematic error, which no number of points along the line averages away. The χ² and
    /// `covariance` ignore it (the views' consistency is judged by their noise alone);
    /// [`Line3Estimate::systematic_shifts`] carries it, each view's shift independent.
    pub systematic_px: f64,
}

/// A maximum-likelihood 3D segment with its first-order uncertainty, rig frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Line3Estimate {
    /// Endpoint on the side of the first observation's start.
    pub start: Point3<f64>,
    pub end: Point3<f64>,
    /// Covariance of `(start, end)` stacked (metres²). Across the line it is the propagated
    /// image-line noise; along it, the endpoints' own spread (see [`estimate_line`]).
    pub covariance: Matrix6<f64>,
    /// How `(start, end)` move when each view's lines shift by their
    /// [`LineObservation::systematic_px`] (1σ, first order), one column per view: the
    /// covariance they add is Σ uᵥ·uᵥᵀ, the views' shifts being independent ([`Self::
    /// systematic_covariance`]). Not in `covariance`, which the tests between segments (a
    /// rival's place, a shared vertex) compare by; what is reported adds it. Zero when no
    /// observation has a systematic shift. Three vectors, not a 6x6 matrix: the estimate is
    /// copied often.
    pub systematic_shifts: [Vector6<f64>; 3],
    /// Sum of squared normalised image residuals at the optimum, and its degrees of freedom
    /// (2 per observation, less the line's 4): a χ² variable when the observations are images
    /// of one line with the stated noise.
    pub chi2: f64,
    pub dof: usize,
    /// RMS image distance of the observations from the reprojected line, pixels.
    pub residual_px: f64,
    /// 1σ of where each end (start, end) lies along the line from the image ends' own noise
    /// alone, metres: large for a line receding from the cameras. (The covariance adds the
    /// spread of the views' ends, which occlusion makes large without making the end wrong.)
    pub end_along_sigma_m: [f64; 2],
    /// How well the views agree on where the segment ends: for each end, the spread (largest
    /// less smallest) of the views' ends along the line in units of that end's
    /// `end_along_sigma_m`; the smaller of the two (one end may be hidden in some view). A
    /// triplet of three different edges that happen to be one 3D line can place their ends
    /// anywhere; the images of one edge agree, where nothing hides an end.
    pub ends_disagreement: f64,
    /// How far past each end (start, end) the middle of the three views' ends lies along the
    /// line, metres, 0 where it does not: two views of three carry the line on beyond the
    /// part every view saw, the third stopping short (an extractor's end, a junction, an
    /// occluder in that view alone). The extent stays the overlap; how far to trust the two
    /// views is the caller's, who knows the tolerance the answer promises. 0 with fewer than
    /// three views' ends.
    pub reach_m: [f64; 2],
}

impl Line3Estimate {
    pub fn direction(&self) -> Vector3<f64> {
        (self.end - self.start).normalize()
    }

    /// Covariance of the unit direction (rank 2, across the line).
    pub fn direction_covariance(&self) -> Matrix3<f64> {
        direction_covariance(&self.start, &self.end, &self.covariance)
    }

    /// Covariance of the midpoint's position across the line (rank 2).
    pub fn midpoint_covariance(&self) -> Matrix3<f64> {
        midpoint_covariance(&self.start, &self.end, &self.covariance)
    }

    /// The covariance of `(start, end)` the views' systematic shifts add
    /// ([`Self::systematic_shifts`]).
    pub fn systematic_covariance(&self) -> Matrix6<f64> {
        let mut out = Matrix6::zeros();
        for u in &self.systematic_shifts {
            out.ger(1.0, u, u, 1.0);
        }
        out
    }

    /// `covariance` with each view's own shift ([`Self::systematic_covariance`]): all the
    /// uncertainty of this line that its views do not share.
    pub fn covariance_with_own_shifts(&self) -> Matrix6<f64> {
        self.covariance + self.systematic_covariance()
    }
}

/// Covariance of the unit direction of the segment `start`–`end` whose endpoints, stacked,
/// have `covariance` (rank 2, across the line).
pub fn direction_covariance(
    start: &Point3<f64>,
    end: &Point3<f64>,
    covariance: &Matrix6<f64>,
) -> Matrix3<f64> {
    let l = (end - start).norm().max(1e-12);
    let mut j = nalgebra::Matrix3x6::zeros();
    let across = across_projector(&(end - start).normalize());
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-across / l));
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(across / l));
    j * covariance * j.transpose()
}

/// Covariance of the midpoint of the segment `start`–`end` across the line, its endpoints'
/// stacked covariance `covariance` (rank 2).
pub fn midpoint_covariance(
    start: &Point3<f64>,
    end: &Point3<f64>,
    covariance: &Matrix6<f64>,
) -> Matrix3<f64> {
    let mut j = nalgebra::Matrix3x6::zeros();
    let across = across_projector(&(end - start).normalize()) * 0.5;
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&across);
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&across);
    j * covariance * j.transpose()
}

/// The projector across the unit direction `u`: a vector's part perpendicular to the line.
pub(crate) fn across_projector(u: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::identity() - u * u.transpose()
}

/// Largest Gauss–Newton steps; the linear start is close, two or three suffice.
const MAX_ML_ITERATIONS: usize = 4;
/// Converged when the step, measured in the estimate's own standard deviations (its squared
/// Mahalanobis length under the normal matrix), is below this: a hundredth of a σ, which
/// nothing downstream can tell from the optimum. An absolute bound (metres, radians) was
/// almost never met within the iterations, so every estimate paid for all of them.
const ML_STEP_SIGMA2: f64 = 1e-4;

/// `f` of each observation, in `stack` when they are a triplet (one per view, the rule: every
/// hypothesis fitted comes here, so the rule allocates nothing), else in `heap` (pieces of a
/// line); `None` when `f` is `None` for any. The caller owns both, so the answer is a plain
/// slice (a small-vector type measured 2% slower on the fits, its every access a branch).
fn per_observation<'a, T: Copy>(
    obs: &[LineObservation],
    f: impl Fn(&LineObservation) -> Option<T>,
    stack: &'a mut [T; 3],
    heap: &'a mut Vec<T>,
) -> Option<&'a [T]> {
    if obs.len() <= stack.len() {
        for (slot, o) in stack.iter_mut().zip(obs) {
            *slot = f(o)?;
        }
        Some(&stack[..obs.len()])
    } else {
        *heap = obs.iter().map(f).collect::<Option<_>>()?;
        Some(heap)
    }
}

/// Two pixels on an observed line, each with its σ across the line.
type VirtualPoints = [(Point2<f64>, f64); 2];

/// Two points on each observed line that carry all it says: at its midpoint ± h along it,
/// each off the line by an independent σ, give the line's offset and direction variances.
fn virtual_points(o: &LineObservation) -> Option<VirtualPoints> {
    let d = o.end - o.start;
    let len = d.norm();
    if len < 1e-9 || !(o.noise.offset_px > 0.0 && o.noise.angle_rad > 0.0) {
        return None;
    }
    let u = d / len;
    let mid = nalgebra::center(&o.start, &o.end);
    let h = o.noise.offset_px / o.noise.angle_rad;
    let sigma = std::f64::consts::SQRT_2 * o.noise.offset_px;
    Some([(mid - u * h, sigma), (mid + u * h, sigma)])
}

/// The image of the 3D line through `x0` along `d` in the camera of projection `p`, with
/// what the distance of a pixel from it and its gradient need: computed once per
/// observation, used for each of its virtual points.
struct ImageOfLine {
    a: Vector3<f64>,
    b: Vector3<f64>,
    l: Vector3<f64>,
    /// 1/n and 1/n³, n the norm of the line's normal (l₀, l₁): each point multiplies by
    /// them, a division per coordinate being several times the cost of a product.
    inv_n: f64,
    inv_n3: f64,
    /// The image motions (homogeneous) of moving a point of the line along `e1` and `e2`.
    m_e1: Vector3<f64>,
    m_e2: Vector3<f64>,
}

impl ImageOfLine {
    /// `None` when the line's image degenerates (the line passes through the centre).
    fn new(
        p: &nalgebra::Matrix3x4<f64>,
        x0: &Vector3<f64>,
        d: &Vector3<f64>,
        (e1, e2): (&Vector3<f64>, &Vector3<f64>),
    ) -> Option<ImageOfLine> {
        let m = p.fixed_view::<3, 3>(0, 0);
        let a = m * x0 + p.column(3);
        let b = m * d;
        let l = a.cross(&b);
        let n2 = l.x * l.x + l.y * l.y;
        if n2 < 1e-24 {
            return None;
        }
        let inv_n = 1.0 / n2.sqrt();
        Some(ImageOfLine {
            a,
            b,
            l,
            inv_n,
            inv_n3: inv_n / n2,
            m_e1: m * e1,
            m_e2: m * e2,
        })
    }

    /// Signed distance of pixel `q` from the line's image, and its gradient with respect to
    /// the line's four parameters: the point moved along `e1`, `e2`, the direction turned
    /// towards `e1`, `e2`.
    fn distance_and_gradient(&self, q: Point2<f64>) -> (f64, Vector4<f64>) {
        let (l, inv_n) = (&self.l, self.inv_n);
        let qh = Vector3::new(q.x, q.y, 1.0);
        let dot = l.dot(&qh);
        // dr/dl = q̃/n − dot·(l₀, l₁, 0)/n³; l = a × b, so gᵀ(δa × b) = δaᵀ(b × g) and
        // gᵀ(a × δb) = δbᵀ(g × a), with δa = M·δx0 and δb = M·δd.
        let g = qh * inv_n - Vector3::new(l.x, l.y, 0.0) * (dot * self.inv_n3);
        let grad_a = self.b.cross(&g);
        let grad_b = g.cross(&self.a);
        let j = Vector4::new(
            grad_a.dot(&self.m_e1),
            grad_a.dot(&self.m_e2),
            grad_b.dot(&self.m_e1),
            grad_b.dot(&self.m_e2),
        );
        (dot * inv_n, j)
    }
}

/// Two unit vectors across `d`, forming a right-handed frame with it.
pub fn across_basis(d: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let helper = if d.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = d.cross(&helper).normalize();
    (e1, d.cross(&e1))
}

/// The linear start of [`estimate_line`]: the line where the back-projection planes of the
/// two most different observations meet (their normals' cross product), through the
/// least-squares point of all the planes, pinned near the cameras' centroid along the line.
/// Gauss–Newton then weighs every observation by its noise, so the start only needs to be
/// close.
fn linear_start(
    cameras: &[&Camera; 3],
    obs: &[LineObservation],
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let plane = |o: &LineObservation| {
        let l = image_line(o.start, o.end)?;
        let pi: Vector4<f64> = cameras[o.view].projection().transpose() * l;
        let n = Vector3::new(pi.x, pi.y, pi.z);
        let norm = n.norm();
        (norm > 0.0 && norm.is_finite()).then(|| (n / norm, pi.w / norm, o.view))
    };
    let (mut stack, mut heap) = ([(Vector3::zeros(), 0.0, 0); 3], Vec::new());
    let planes = per_observation(obs, plane, &mut stack, &mut heap)?;
    let mut best: Option<(f64, Vector3<f64>)> = None;
    for (i, a) in planes.iter().enumerate() {
        for b in &planes[i + 1..] {
            if a.2 == b.2 {
                continue;
            }
            let c = a.0.cross(&b.0);
            let sin = c.norm();
            if best.is_none_or(|(s, _)| sin > s) {
                best = Some((sin, c));
            }
        }
    }
    let (sin, cross) = best?;
    // The planes (nearly) coincide: the line is not determined.
    if sin * sin < MIN_PLANE_SPREAD {
        return None;
    }
    let dir = cross / sin;
    let centroid: Vector3<f64> = cameras
        .iter()
        .map(|c| c.centre().coords)
        .sum::<Vector3<f64>>()
        / 3.0;
    let mut normal_matrix = dir * dir.transpose();
    let mut rhs = dir * dir.dot(&centroid);
    for (n, d, _) in planes {
        normal_matrix += n * n.transpose();
        rhs -= n * *d;
    }
    let x0 = normal_matrix.lu().solve(&rhs)?;
    Some((x0, dir))
}

/// The maximum-likelihood 3D line of image-line observations in the three views, with its
/// covariance, its χ² and its extent.
///
/// 1. **Line**: Gauss–Newton on the 4 parameters of a 3D line (a point moved across the
///    line, the direction turned), minimising the squared image distances of each
///    observation's two virtual points (see [`LineNoise`]) divided by their σ, started from
///    the linear intersection of the back-projection planes.
/// 2. **Covariance**: the inverse of the normal matrix at the optimum (first order),
///    mapped onto the two endpoints; along the line each endpoint gets the spread of the
///    views' own ends around it (at least `end_sigma_px` back-projected), since where a
///    segment stops is decided by occlusion and contrast as much as by noise.
/// 3. **Extent**: each view's observed ends back-projected onto the line; the 3D segment is
///    their overlap, the part every view saw. Only there did the third view verify the match:
///    a view whose segment runs on past the edge (merged with a collinear neighbour, a
///    shadow) would otherwise extend it where nothing confirms it. A view whose segment is a
///    fragment (under `FRAGMENT_SHARE` of the longest view's) does not cut it: a line broken
///    by extraction in one view would shrink to the piece. Measured against the median of
///    the views' ends in docs/ACCURACY.md.
///
/// `None` when the line is undetermined, passes behind a camera, or the views share no part.
pub fn estimate_line(
    cameras: &[&Camera; 3],
    obs: &[LineObservation],
    end_sigma_px: f64,
) -> Option<Line3Estimate> {
    estimate_line_through(cameras, obs, end_sigma_px, &[])
}

/// A 3D point the line is known to pass through, with its covariance (metres²): where
/// another, better measured segment ends at a vertex the two share.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointOnLine {
    pub point: Point3<f64>,
    pub covariance: Matrix3<f64>,
}

/// A direction the line is known to run along (either sense), with the variance of the
/// angle between them per axis across it (radians²): the scene's dominant direction the line
/// lies along.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DirectionOfLine {
    pub direction: Vector3<f64>,
    pub variance: f64,
}

/// [`estimate_line`] with `through`, points the line passes through within their
/// covariance, as observations of the line besides the images: each adds the squared
/// normalised distance of its point from the line (two degrees of freedom) to the χ²
/// minimised. With none, it is [`estimate_line`] to the bit.
pub fn estimate_line_through(
    cameras: &[&Camera; 3],
    obs: &[LineObservation],
    end_sigma_px: f64,
    through: &[PointOnLine],
) -> Option<Line3Estimate> {
    estimate_line_constrained(cameras, obs, end_sigma_px, through, None)
}

/// What is known of a line's direction besides its images: it runs along a direction (two
/// degrees of freedom), or it lies across one, in the plane of directions normal to it (one:
/// a horizontal line of a room whose vertical is known, whichever way it turns).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum KnownDirection {
    Along(DirectionOfLine),
    /// `direction` is the plane's normal, `variance` that of the line's angle to the plane
    /// (radians²).
    Across(DirectionOfLine),
}

impl KnownDirection {
    fn degrees_of_freedom(&self) -> usize {
        match self {
            KnownDirection::Along(_) => 2,
            KnownDirection::Across(_) => 1,
        }
    }
}

/// [`estimate_line_through`] with, besides, what is known of the line's direction: for a
/// direction it runs along, its angle to the line across it, squared and normalised by its
/// variance (two degrees of freedom); for a plane it lies in, the line's angle to the plane
/// (one).
pub fn estimate_line_constrained(
    cameras: &[&Camera; 3],
    obs: &[LineObservation],
    end_sigma_px: f64,
    through: &[PointOnLine],
    known: Option<&KnownDirection>,
) -> Option<Line3Estimate> {
    let (mut x0, mut d) = linear_start(cameras, obs)?;
    let observed = |o: &LineObservation| virtual_points(o).map(|v| (o.view, v, o.systematic_px));
    let (mut stack, mut heap) = ([(0, [(Point2::origin(), 0.0); 2], 0.0); 3], Vec::new());
    let points = per_observation(obs, observed, &mut stack, &mut heap)?;
    let systematic = obs.iter().any(|o| o.systematic_px > 0.0);
    let normal = |x0: &Vector3<f64>, d: &Vector3<f64>| {
        let (e1, e2) = across_basis(d);
        let mut h = nalgebra::Matrix4::<f64>::zeros();
        let mut g = Vector4::<f64>::zeros();
        // Per view, Σ jᵢ·δ/σᵢ² over its virtual points: a shift δ of the view's lines moves
        // each point's residual by δ, and the optimum by −H⁻¹ times this (first order).
        let mut shifted = [Vector4::<f64>::zeros(); 3];
        let mut chi2 = 0.0;
        let mut sum_px = 0.0;
        for (view, pts, systematic_px) in points {
            let image = ImageOfLine::new(cameras[*view].projection(), x0, d, (&e1, &e2))?;
            for &(q, sigma) in pts {
                let (r, j) = image.distance_and_gradient(q);
                let inv_sigma = 1.0 / sigma;
                let j = j * inv_sigma;
                let rn = r * inv_sigma;
                h.ger(1.0, &j, &j, 1.0);
                g += j * rn;
                if systematic {
                    shifted[*view] += j * (systematic_px / sigma);
                }
                chi2 += rn * rn;
                sum_px += r * r;
            }
        }
        for known in through {
            // The point's offset from the line across it, and how it moves with the line's
            // parameters: the line's point moved by (a, b) along (e1, e2), its direction
            // turned by (c, f) at the pivot, which at `t` along the line moves it t·(c, f).
            let w = known.point.coords - x0;
            let t = w.dot(d);
            let r = nalgebra::Vector2::new(e1.dot(&w), e2.dot(&w));
            let basis = nalgebra::Matrix3x2::from_columns(&[e1, e2]);
            let weight = (basis.transpose() * known.covariance * basis).try_inverse()?;
            let mut a = nalgebra::Matrix2x4::<f64>::zeros();
            a[(0, 0)] = -1.0;
            a[(0, 2)] = -t;
            a[(1, 1)] = -1.0;
            a[(1, 3)] = -t;
            h += a.transpose() * weight * a;
            g += a.transpose() * weight * r;
            chi2 += r.dot(&(weight * r));
        }
        match known {
            Some(KnownDirection::Along(along)) => {
                // The known direction's components across the line: the angle to turn it
                // by, which turning it by (c, f) takes away.
                let toward = along.direction * along.direction.dot(d).signum();
                let r = nalgebra::Vector2::new(e1.dot(&toward), e2.dot(&toward));
                let weight = 1.0 / along.variance;
                let mut a = nalgebra::Matrix2x4::<f64>::zeros();
                a[(0, 2)] = -1.0;
                a[(1, 3)] = -1.0;
                h += a.transpose() * a * weight;
                g += a.transpose() * r * weight;
                chi2 += r.norm_squared() * weight;
            }
            Some(KnownDirection::Across(plane)) => {
                // The line's component along the plane's normal (the sine of its angle to
                // the plane), which turning it by (c, f) changes by c·(e1·n) + f·(e2·n).
                let n = plane.direction;
                let r = d.dot(&n);
                let weight = 1.0 / plane.variance;
                let a = Vector4::new(0.0, 0.0, e1.dot(&n), e2.dot(&n));
                h += a * a.transpose() * weight;
                g += a * r * weight;
                chi2 += r * r * weight;
            }
            None => {}
        }
        Some((h, g, shifted, chi2, sum_px, e1, e2))
    };
    // The normal equations at the optimum: a step below the tolerance is not taken, and the
    // last evaluation serves for the covariance.
    let mut at_optimum = None;
    for _ in 0..MAX_ML_ITERATIONS {
        let (h, g, shifted, chi2, sum_px, e1, e2) = normal(&x0, &d)?;
        let step = h.cholesky()?.solve(&(-g));
        // stepᵀ·H·step = −stepᵀ·g, since H·step = −g.
        if -step.dot(&g) < ML_STEP_SIGMA2 {
            at_optimum = Some((h, shifted, chi2, sum_px, e1, e2));
            break;
        }
        x0 += e1 * step[0] + e2 * step[1];
        d = (d + e1 * step[2] + e2 * step[3]).normalize();
    }
    let (h, shifted, chi2, sum_px, e1, e2) = match at_optimum {
        Some(found) => found,
        None => {
            let (h, _, shifted, chi2, sum_px, e1, e2) = normal(&x0, &d)?;
            (h, shifted, chi2, sum_px, e1, e2)
        }
    };
    // Extent: each view's ends along the line (a view's pieces together), then their overlap.
    let mut ends_of_views = [(0.0, 0.0); 3];
    let mut n_ends = 0;
    let mut first_sign = 0.0;
    for (view, cam) in cameras.iter().enumerate() {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for o in obs.iter().filter(|o| o.view == view) {
            let mut ts = [0.0; 2];
            for (slot, p) in ts.iter_mut().zip([o.start, o.end]) {
                let ray = cam.ray(p).normalize();
                let w0 = x0 - cam.centre().coords;
                let b = d.dot(&ray);
                let denom = 1.0 - b * b;
                if denom < MIN_RAY_LINE_SIN * MIN_RAY_LINE_SIN {
                    return None;
                }
                *slot = (b * ray.dot(&w0) - d.dot(&w0)) / denom;
            }
            if first_sign == 0.0 {
                first_sign = if ts[1] >= ts[0] { 1.0 } else { -1.0 };
            }
            lo = lo.min(ts[0].min(ts[1]));
            hi = hi.max(ts[0].max(ts[1]));
        }
        if lo.is_finite() && hi.is_finite() {
            ends_of_views[n_ends] = (lo, hi);
            n_ends += 1;
        }
    }
    let ends = &ends_of_views[..n_ends];
    if ends.len() < 2 {
        return None;
    }
    // The part every view saw, which is what the third view verified; a view that holds only
    // a fragment of the line says where the fragment stops, not the line.
    let longest = ends.iter().map(|e| e.1 - e.0).fold(0.0, f64::max);
    let whole = || {
        ends.iter()
            .filter(move |e| e.1 - e.0 >= FRAGMENT_SHARE * longest)
    };
    let lo = whole().map(|e| e.0).fold(f64::NEG_INFINITY, f64::max);
    let hi = whole().map(|e| e.1).fold(f64::INFINITY, f64::min);
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let (reach_lo, reach_hi) = match ends {
        [a, b, c] => (
            (lo - middle_of(a.0, b.0, c.0)).max(0.0),
            (middle_of(a.1, b.1, c.1) - hi).max(0.0),
        ),
        _ => (0.0, 0.0),
    };
    let reach_m = if first_sign >= 0.0 {
        [reach_lo, reach_hi]
    } else {
        [reach_hi, reach_lo]
    };
    // Re-centre the line's point on the segment. The ends' covariance needs no re-evaluation:
    // it maps the fit's own parameters, through the ends placed along the line from the
    // fit's pivot.
    let mid = 0.5 * (lo + hi);
    let ends_of_line = EndsOfLine {
        basis: nalgebra::Matrix3x2::from_columns(&[e1, e2]),
        along: if first_sign >= 0.0 {
            [lo, hi]
        } else {
            [hi, lo]
        },
    };
    x0 += d * mid;
    let (lo, hi) = (lo - mid, hi - mid);
    // A normal matrix too ill-conditioned for its inverse to come out positive definite
    // (a line lying nearly in an epipolar plane of a collinear rig, known to metres: found by
    // `ml_line_round_trips`) is a line the views do not determine.
    let h_inv = h.try_inverse()?;
    h_inv.cholesky()?;
    let [t_start, t_end] = ends_of_line.along.map(|t| t - mid);
    let start = Point3::from(x0 + d * t_start);
    let end = Point3::from(x0 + d * t_end);
    for cam in cameras {
        for p in [start, end] {
            let hz = cam.projection() * p.to_homogeneous();
            if hz.z <= 0.0 {
                return None;
            }
        }
    }
    // With more observations than the line's 4 parameters, their scatter says whether the
    // stated noise was too small for this line: scale up (never down) by the χ² per degree
    // of freedom.
    let n_obs = points.len() * 2;
    let dof =
        (n_obs + 2 * through.len() + known.map_or(0, |k| k.degrees_of_freedom())).saturating_sub(4);
    let posterior = if dof > 0 {
        (chi2 / dof as f64).max(1.0)
    } else {
        1.0
    };
    let mut covariance = ends_of_line.covariance(&h_inv) * posterior;
    // Each view's shift moves the parameters by H⁻¹·sᵥ, mapped onto the ends as the
    // covariance is.
    let systematic_shifts = if systematic {
        shifted.map(|s| ends_of_line.moved(&(h_inv * s)))
    } else {
        [Vector6::zeros(); 3]
    };
    // Along the line: how far an end moves when its image end moves by end_sigma_px — far
    // for a line that recedes from the camera, whose rays meet it at a grazing angle (the
    // middle view of three, as the median takes the middle end) — and the spread of the
    // views' ends around it.
    let measured = |t: f64| {
        let p = x0 + d * t;
        let per_view: [f64; 3] = std::array::from_fn(|v| {
            let c = cameras[v];
            let ray = p - c.centre().coords;
            let range = ray.norm();
            let sin = (1.0 - (ray.dot(&d) / range).powi(2)).max(0.0).sqrt();
            end_sigma_px * range / c.focal_px() / sin.max(MIN_RAY_LINE_SIN)
        });
        middle_of(per_view[0], per_view[1], per_view[2])
    };
    let (measured_lo, measured_hi) = (measured(lo), measured(hi));
    // The views' ends were found before the line's point moved to the segment's middle.
    let along = |t: f64, floor: f64, pick: fn(&(f64, f64)) -> f64| {
        let spread = ends
            .iter()
            .map(|e| (pick(e) - mid - t).powi(2))
            .sum::<f64>()
            / ends.len() as f64;
        (spread + floor * floor).max(1e-12)
    };
    let (var_lo, var_hi) = (
        along(lo, measured_lo, |e| e.0),
        along(hi, measured_hi, |e| e.1),
    );
    let end_along_sigma_m = if first_sign >= 0.0 {
        [measured_lo, measured_hi]
    } else {
        [measured_hi, measured_lo]
    };
    let (var_start, var_end) = if first_sign >= 0.0 {
        (var_lo, var_hi)
    } else {
        (var_hi, var_lo)
    };
    let spread_of = |pick: fn(&(f64, f64)) -> f64| {
        let (lo, hi) = ends
            .iter()
            .map(pick)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), t| {
                (a.min(t), b.max(t))
            });
        hi - lo
    };
    let ends_disagreement = (spread_of(|e| e.0) / measured_lo.max(1e-12))
        .min(spread_of(|e| e.1) / measured_hi.max(1e-12));
    let ddt = d * d.transpose();
    let mut block = covariance.fixed_view_mut::<3, 3>(0, 0);
    block += ddt * var_start;
    let mut block = covariance.fixed_view_mut::<3, 3>(3, 3);
    block += ddt * var_end;
    // Symmetric by construction; make it so to the last bit, for clients that check.
    let covariance = (covariance + covariance.transpose()) * 0.5;
    Some(Line3Estimate {
        start,
        end,
        covariance,
        systematic_shifts,
        chi2,
        dof,
        residual_px: (sum_px / n_obs as f64).sqrt(),
        end_along_sigma_m,
        ends_disagreement,
        reach_m,
    })
}

/// The two ends of a fitted line as functions of the fit's four parameters (the pivot moved
/// by (a, b) along (e1, e2), the direction turned by (c, f)): an end `along` the line from the
/// pivot moves by e1·(a + along·c) + e2·(b + along·f), so its Jacobian is the 3×2 `basis`
/// [e1 e2] times [[1, 0, along, 0], [0, 1, 0, along]]. Every fit maps its parameters'
/// covariance through it; spelled out, each 3×3 block of J·P·Jᵀ is `basis`·(2×2)·`basisᵀ`,
/// a fraction of the dense 6×4 products (docs/PERFORMANCE.md).
struct EndsOfLine {
    basis: nalgebra::Matrix3x2<f64>,
    /// Start and end, from the pivot.
    along: [f64; 2],
}

impl EndsOfLine {
    /// The 2×2 core of the (a, b) block of J·P·Jᵀ, a and b ends: T_a·P·T_bᵀ.
    fn core(&self, p: &nalgebra::Matrix4<f64>, a: usize, b: usize) -> nalgebra::Matrix2<f64> {
        let (ta, tb) = (self.along[a], self.along[b]);
        nalgebra::Matrix2::from_fn(|i, j| {
            p[(i, j)] + ta * p[(i + 2, j)] + tb * (p[(i, j + 2)] + ta * p[(i + 2, j + 2)])
        })
    }

    /// J·P·Jᵀ: the ends' covariance (start, end stacked) of parameters of covariance `p`.
    fn covariance(&self, p: &nalgebra::Matrix4<f64>) -> Matrix6<f64> {
        let mut out = Matrix6::zeros();
        for (a, b) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
            let block = self.basis * self.core(p, a, b) * self.basis.transpose();
            out.fixed_view_mut::<3, 3>(3 * a, 3 * b).copy_from(&block);
        }
        out
    }

    /// J·v: how the ends move when the parameters move by `v`.
    fn moved(&self, v: &Vector4<f64>) -> Vector6<f64> {
        let end = |t: f64| self.basis * nalgebra::Vector2::new(v[0] + t * v[2], v[1] + t * v[3]);
        let (start, end) = (end(self.along[0]), end(self.along[1]));
        Vector6::new(start.x, start.y, start.z, end.x, end.y, end.z)
    }
}

/// The middle one of three numbers (the median of three views' ends, or of their noise).
pub(crate) fn middle_of(a: f64, b: f64, c: f64) -> f64 {
    a.max(b).min(a.min(b).max(c))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// The block form of J·P·Jᵀ and of J·v is the dense product's, to rounding.
        #[test]
        fn ends_of_line_is_the_dense_jacobian(
            d in prop::array::uniform3(-1.0f64..1.0),
            along in prop::array::uniform2(-5.0f64..5.0),
            root in prop::array::uniform16(-1.0f64..1.0),
            v in prop::array::uniform4(-1.0f64..1.0),
        ) {
            let d = Vector3::from(d);
            prop_assume!(d.norm() > 0.1);
            let (e1, e2) = across_basis(&d.normalize());
            let ends = EndsOfLine {
                basis: nalgebra::Matrix3x2::from_columns(&[e1, e2]),
                along,
            };
            let r = nalgebra::Matrix4::from_row_slice(&root);
            let p = r * r.transpose();
            let mut j = nalgebra::Matrix6x4::<f64>::zeros();
            for (row, t) in [(0, along[0]), (3, along[1])] {
                for k in 0..3 {
                    j[(row + k, 0)] = e1[k];
                    j[(row + k, 1)] = e2[k];
                    j[(row + k, 2)] = t * e1[k];
                    j[(row + k, 3)] = t * e2[k];
                }
            }
            let dense = j * p * j.transpose();
            let scale = 1.0 + dense.amax();
            prop_assert!((ends.covariance(&p) - dense).amax() <= 1e-12 * scale);
            let v = Vector4::from(v);
            prop_assert!((ends.moved(&v) - j * v).amax() <= 1e-12 * (1.0 + (j * v).amax()));
        }
    }
}
