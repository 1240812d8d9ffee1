//! 3D lines from two or three views (DESIGN §2.6).
//!
//! Each image line `lᵢ` (normalised so its normal is a unit vector) back-projects to the
//! plane `πᵢ = Pᵢᵀ lᵢ` through optical centre i. With `P` normalised (see [`Camera`]),
//! `πᵢ·X = depth·(pixel distance of X's image from lᵢ)`, and the cameras of a rig see a point
//! at nearly the same depth, so the unweighted least-squares intersection of the planes is
//! the reprojection-error fit up to a common scale. The 3D segment is the part of that line
//! which all views' segments cover (their back-projected endpoints, intersected).

use nalgebra::{Matrix3, Point2, Point3, SymmetricEigen, Vector3, Vector4};

use super::camera::Camera;

/// Smallest ratio of the middle to the largest eigenvalue of the plane normals' scatter: below
/// it the planes (nearly) coincide and the line is not determined.
const MIN_PLANE_SPREAD: f64 = 1e-8;
/// Smallest sine between a back-projected ray and the 3D line for the ray to locate an endpoint.
const MIN_RAY_LINE_SIN: f64 = 1e-3;

/// A triangulated 3D segment, rig frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Line3Fit {
    /// Endpoint on the side of the first view's segment start.
    pub start: Point3<f64>,
    pub end: Point3<f64>,
    /// RMS distance, over views and both endpoints, between the reprojected 3D endpoints and
    /// the image lines, pixels.
    pub residual_px: f64,
}

fn image_line(start: Point2<f64>, end: Point2<f64>) -> Option<Vector3<f64>> {
    let l = Vector3::new(start.x, start.y, 1.0).cross(&Vector3::new(end.x, end.y, 1.0));
    let n = l.x.hypot(l.y);
    (n > 1e-12).then(|| l / n)
}

/// Intersects the back-projection planes of 2 or 3 views' (undistorted) segments.
///
/// Returns `None` when the line is undetermined (planes coincide), when it passes through an
/// optical centre, or when the views' segments do not overlap along it.
pub fn triangulate_line(
    cameras: &[&Camera],
    segments: &[(Point2<f64>, Point2<f64>)],
) -> Option<Line3Fit> {
    if cameras.len() != segments.len() || cameras.len() < 2 {
        return None;
    }
    let mut lines = Vec::with_capacity(cameras.len());
    let mut scatter = Matrix3::zeros();
    let mut planes = Vec::with_capacity(cameras.len());
    for (cam, &(s, e)) in cameras.iter().zip(segments) {
        let l = image_line(s, e)?;
        let pi: Vector4<f64> = cam.projection().transpose() * l;
        let n = Vector3::new(pi.x, pi.y, pi.z);
        scatter += n * n.transpose();
        planes.push((n, pi.w));
        lines.push(l);
    }
    // 1. Direction: the direction most orthogonal to every plane normal.
    let eig = SymmetricEigen::new(scatter);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let (lmin, lmid, lmax) = (
        eig.eigenvalues[order[0]],
        eig.eigenvalues[order[1]],
        eig.eigenvalues[order[2]],
    );
    if !lmax.is_finite() || lmax <= 0.0 || lmid < MIN_PLANE_SPREAD * lmax || !lmin.is_finite() {
        return None;
    }
    let dir: Vector3<f64> = eig.eigenvectors.column(order[0]).into_owned().normalize();

    // 2. A point: least squares on the planes, pinned along the line to the rig's centroid.
    let centroid: Vector3<f64> = cameras
        .iter()
        .map(|c| c.centre().coords)
        .sum::<Vector3<f64>>()
        / cameras.len() as f64;
    let pin = scatter.trace();
    let mut rhs = dir * (pin * dir.dot(&centroid));
    for (n, d) in &planes {
        rhs -= n * *d;
    }
    let normal_matrix = scatter + dir * dir.transpose() * pin;
    let x0 = normal_matrix.lu().solve(&rhs)?;

    // 3. Extent: each view's endpoints back-projected onto the line; keep the common part.
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    let mut first_sign = 1.0;
    for (v, (cam, &(s, e))) in cameras.iter().zip(segments).enumerate() {
        let mut ts = [0.0; 2];
        for (slot, p) in ts.iter_mut().zip([s, e]) {
            let ray = cam.ray(p).normalize();
            let w0 = x0 - cam.centre().coords;
            let b = dir.dot(&ray);
            let denom = 1.0 - b * b;
            if denom < MIN_RAY_LINE_SIN * MIN_RAY_LINE_SIN {
                return None;
            }
            let (d, ee) = (dir.dot(&w0), ray.dot(&w0));
            *slot = (b * ee - d) / denom;
        }
        if v == 0 && ts[1] < ts[0] {
            first_sign = -1.0;
        }
        lo = lo.max(ts[0].min(ts[1]));
        hi = hi.min(ts[0].max(ts[1]));
    }
    if hi.is_nan() || lo.is_nan() || hi <= lo {
        return None;
    }
    let (t_start, t_end) = if first_sign > 0.0 { (lo, hi) } else { (hi, lo) };
    let start = Point3::from(x0 + dir * t_start);
    let end = Point3::from(x0 + dir * t_end);

    // 4. Residual: reprojected endpoints against the observed image lines.
    let mut sum = 0.0;
    for (cam, l) in cameras.iter().zip(&lines) {
        for p in [start, end] {
            let h = cam.projection() * p.to_homogeneous();
            if h.z <= 0.0 {
                return None;
            }
            let dist = (l.x * h.x / h.z + l.y * h.y / h.z + l.z).abs();
            sum += dist * dist;
        }
    }
    let residual_px = (sum / (2 * cameras.len()) as f64).sqrt();
    Some(Line3Fit {
        start,
        end,
        residual_px,
    })
}
