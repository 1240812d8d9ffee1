//! Exact visibility of ground-truth edges, and their contrast in the noise-free image.
//!
//! For an edge `A→B` (point = `A + s·(B − A)`, `s ∈ [0, 1]`) and a camera, the visible part
//! is the set of `s` whose point is (1) at least [`MIN_DEPTH_M`] in front of the camera,
//! (2) projected inside the image `[-0.5, W-0.5] x [-0.5, H-0.5]` (pixel-centre convention),
//! and (3) not occluded: the segment from the optical centre to the point crosses the
//! interior of no box. Boxes are shrunk by [`OCCLUSION_SHRINK_M`] for (3) so that a point on
//! a box's own surface is not hidden by that box, while an edge whose two faces both face
//! away from the camera is (the ray crosses its own box first).
//!
//! (1) and, for cameras without distortion, (2) are linear in `s` and solved exactly; with
//! distortion, (2) is first bounded by the undistorted image border (linear too), then
//! tested per sample. The rest is sampled densely along the edge (every
//! [`SAMPLE_SPACING_PX`] of projected length, at least [`MIN_SAMPLES`]) and each transition
//! is refined by bisection to [`REFINE_TOL_M`]. A visible or hidden stretch shorter than the
//! sample spacing can be missed; at 2 px it is below what any segment extractor reports.
//!
//! Contrast is what an edge detector would see: the grey level at 1.5 px on the left of the
//! projected edge minus the one at 1.5 px on its right (left as seen on screen when walking
//! from the projection of A to that of B), both rendered by ray casting. A positive contrast
//! means the segment oriented A→B follows the DESIGN §1 convention.
//!
//! Interval lists are sorted, disjoint `(s0, s1)` pairs with `s0 < s1`.

use nalgebra::{Point2, Point3, Vector3, Vector4};

use super::bvh::SceneIndex;
use super::scene::{slab, Scene, Tracer};
use trinocular_core::geometry::{Camera, Rig};
use trinocular_core::segment::Segment3;

/// A closed interval of an edge parameter.
pub type Interval = (f64, f64);

/// Points closer than this to a camera's image plane are not visible (as in the evaluation
/// scripts), metres.
pub const MIN_DEPTH_M: f64 = 0.05;
/// Boxes shrink by this for occlusion tests, metres.
pub const OCCLUSION_SHRINK_M: f64 = 1e-6;
/// Sampling step along the projected edge, pixels.
pub const SAMPLE_SPACING_PX: f64 = 2.0;
pub const MIN_SAMPLES: usize = 64;
/// Bounds the work on edges that project to huge lengths (near the image plane).
pub const MAX_SAMPLES: usize = 4096;
/// Bisection stops when the transition is bracketed this tightly, metres along the edge.
pub const REFINE_TOL_M: f64 = 1e-5;
/// Visible pieces shorter than this are dropped (slivers at corners), metres.
pub const MIN_VISIBLE_M: f64 = 1e-3;
/// Distance of the two contrast probes from the projected edge, pixels.
pub const CONTRAST_OFFSET_PX: f64 = 1.5;
/// Edges with less contrast than this (grey levels) are photometrically invisible.
pub const MIN_CONTRAST: f64 = 4.0;
/// Number of contrast probes along the visible part for [`EdgeVisibility::contrast`].
pub const CONTRAST_SAMPLES: usize = 5;

/// Visibility of one ground-truth edge in the three cameras of a rig.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EdgeVisibility {
    /// Visible intervals per camera.
    pub cameras: [Vec<Interval>; 3],
    /// Part visible in all three cameras.
    pub all3: Vec<Interval>,
    /// Projected length of `all3` in each image, pixels.
    pub all3_px: [f64; 3],
    /// Median |contrast| over probes spread along the visible part, per camera; `None` when
    /// not visible.
    pub contrast: [Option<f64>; 3],
}

pub fn total_length(intervals: &[Interval]) -> f64 {
    intervals.iter().map(|(a, b)| b - a).sum()
}

/// Union of intervals in any order, as a sorted disjoint list.
pub fn union_intervals(intervals: &[Interval]) -> Vec<Interval> {
    let mut v: Vec<Interval> = intervals
        .iter()
        .map(|&(a, b)| (a.min(b), a.max(b)))
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .collect();
    v.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut out: Vec<Interval> = Vec::with_capacity(v.len());
    for (a, b) in v {
        match out.last_mut() {
            Some(last) if a <= last.1 => last.1 = last.1.max(b),
            _ => out.push((a, b)),
        }
    }
    out
}

/// Intersection of two sorted disjoint lists.
pub fn intersect_intervals(x: &[Interval], y: &[Interval]) -> Vec<Interval> {
    let (mut i, mut j) = (0, 0);
    let mut out = Vec::new();
    while i < x.len() && j < y.len() {
        let a = x[i].0.max(y[j].0);
        let b = x[i].1.min(y[j].1);
        if b > a {
            out.push((a, b));
        }
        if x[i].1 < y[j].1 {
            i += 1;
        } else {
            j += 1;
        }
    }
    out
}

fn point_at(edge: &Segment3, s: f64) -> Point3<f64> {
    edge.start + (edge.end - edge.start) * s
}

/// `[s0, s1]` of `s ∈ [0, 1]` where the linear function `f(s) = fa + s·(fb − fa)` is `>= 0`
/// for every `(fa, fb)` given; `None` when empty.
fn linear_clip(constraints: &[(f64, f64)]) -> Option<Interval> {
    let (mut s0, mut s1) = (0.0f64, 1.0f64);
    for &(fa, fb) in constraints {
        let df = fb - fa;
        if df > 0.0 {
            s0 = s0.max(-fa / df);
        } else if df < 0.0 {
            s1 = s1.min(-fa / df);
        } else if fa < 0.0 {
            return None;
        }
    }
    (s1 > s0).then_some((s0, s1))
}

/// Border samples per image side for [`undistorted_bounds`].
const BORDER_SAMPLES: usize = 32;
/// Relative margin added to [`undistorted_bounds`]: the undistorted border bulges a little
/// between samples.
const BORDER_MARGIN: f64 = 0.02;

/// Bounding box `[x_min, x_max, y_min, y_max]` of the image in undistorted normalised
/// coordinates. The undistorted image border encloses every point whose distorted
/// projection is in the image (within the radius where the distortion is monotonic), so
/// this bounds the visible part by linear constraints before any sampling.
fn undistorted_bounds(camera: &Camera) -> [f64; 4] {
    let flat = FlatCamera::new(camera);
    let (w, h) = (camera.width() as f64, camera.height() as f64);
    let mut b = [
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ];
    for k in 0..=BORDER_SAMPLES {
        let f = k as f64 / BORDER_SAMPLES as f64;
        let (u, v) = (-0.5 + f * w, -0.5 + f * h);
        for pixel in [[u, -0.5], [u, h - 0.5], [-0.5, v], [w - 0.5, v]] {
            let (x, y) = flat.normalised(pixel);
            b = [b[0].min(x), b[1].max(x), b[2].min(y), b[3].max(y)];
        }
    }
    let (mx, my) = (BORDER_MARGIN * (b[1] - b[0]), BORDER_MARGIN * (b[3] - b[2]));
    [b[0] - mx, b[1] + mx, b[2] - my, b[3] + my]
}

/// The part of the edge in front of the camera and inside the image: exact without
/// distortion, a superset (see [`undistorted_bounds`]) with.
fn frustum_clip(camera: &Camera, edge: &Segment3) -> Option<Interval> {
    let (xa, xb) = (edge.start.to_homogeneous(), edge.end.to_homogeneous());
    let rows: [Vector4<f64>; 5] = if camera.distortion().is_none() {
        let p = camera.projection();
        let (w, h) = (camera.width() as f64, camera.height() as f64);
        let row = |i: usize| -> Vector4<f64> { p.row(i).transpose() };
        let (r0, r1, r2) = (row(0), row(1), row(2));
        // P is normalised so that row 2 gives the depth.
        [
            r2 - Vector4::new(0.0, 0.0, 0.0, MIN_DEPTH_M),
            r0 + r2 * 0.5,
            r2 * (w - 0.5) - r0,
            r1 + r2 * 0.5,
            r2 * (h - 0.5) - r1,
        ]
    } else {
        // Rows of [R | t]: camera coordinates, where the bounds are x/z and y/z ranges.
        let (r, t) = (camera.rotation(), camera.translation());
        let row = |i: usize| Vector4::new(r[(i, 0)], r[(i, 1)], r[(i, 2)], t[i]);
        let (r0, r1, r2) = (row(0), row(1), row(2));
        let b = undistorted_bounds(camera);
        [
            r2 - Vector4::new(0.0, 0.0, 0.0, MIN_DEPTH_M),
            r0 - r2 * b[0],
            r2 * b[1] - r0,
            r1 - r2 * b[2],
            r2 * b[3] - r1,
        ]
    };
    let constraints = rows.map(|r| (r.dot(&xa), r.dot(&xb)));
    linear_clip(&constraints)
}

/// A box, shrunk for occlusion tests, as plain arrays for the slab test.
#[derive(Debug, Clone, Copy)]
struct Occluder {
    lo: [f64; 3],
    hi: [f64; 3],
}

/// The shrunk boxes that may cross the triangle (centre, a, b): the only ones that can hide
/// a point of the edge between `a` and `b`. Culls by bounding boxes and by the triangle's
/// plane, which keeps a handful of boxes out of a hundred.
fn occluders(
    scene: &Scene,
    centre: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
) -> Vec<Occluder> {
    let tlo = centre.inf(&a.inf(b));
    let thi = centre.sup(&a.sup(b));
    let normal = (a - centre).cross(&(b - centre));
    let mut out = Vec::new();
    for bx in &scene.boxes {
        let lo = bx.min.coords.add_scalar(OCCLUSION_SHRINK_M);
        let hi = bx.max.coords.add_scalar(-OCCLUSION_SHRINK_M);
        if (0..3).any(|k| lo[k] >= hi[k] || lo[k] > thi[k] || hi[k] < tlo[k]) {
            continue;
        }
        let mid = (lo + hi) * 0.5;
        let half = (hi - lo) * 0.5;
        let reach = normal.abs().dot(&half);
        if normal.dot(&(mid - centre.coords)).abs() > reach + 1e-12 {
            continue;
        }
        out.push(Occluder {
            lo: [lo.x, lo.y, lo.z],
            hi: [hi.x, hi.y, hi.z],
        });
    }
    out
}

/// Whether the open segment from `centre` to `x` crosses the interior of an occluder.
fn occluded(occluders: &[Occluder], centre: &[f64; 3], x: &[f64; 3]) -> bool {
    let d = [x[0] - centre[0], x[1] - centre[1], x[2] - centre[2]];
    occluders.iter().any(|b| {
        slab(centre, &d, &b.lo, &b.hi).is_some_and(|(tn, tf, _, _)| tn < tf && tn < 1.0 && tf > 0.0)
    })
}

/// Visible intervals of `edge` in `camera` (module doc).
pub fn visible_intervals(scene: &Scene, camera: &Camera, edge: &Segment3) -> Vec<Interval> {
    let length = edge.length();
    if !(length > 0.0 && length.is_finite()) {
        return Vec::new();
    }
    let Some((s0, s1)) = frustum_clip(camera, edge) else {
        return Vec::new();
    };
    let centre = camera.centre();
    let (a, b) = (point_at(edge, s0), point_at(edge, s1));
    let occ = occluders(scene, &centre, &a, &b);
    let flat = FlatCamera::new(camera);
    let check_frame = camera.distortion().is_some();
    // Plain arrays: this closure runs a hundred times per edge and camera.
    let c = [centre.x, centre.y, centre.z];
    let (e0, e1) = (edge.start, edge.end);
    let visible = |s: f64| {
        let x = [
            e0.x + s * (e1.x - e0.x),
            e0.y + s * (e1.y - e0.y),
            e0.z + s * (e1.z - e0.z),
        ];
        (!check_frame || flat.in_image(&x)) && !occluded(&occ, &c, &x)
    };
    let px = match (
        flat.project(&a.coords.into()),
        flat.project(&b.coords.into()),
    ) {
        (Some((pa, _)), Some((pb, _))) => (pb[0] - pa[0]).hypot(pb[1] - pa[1]),
        _ => f64::INFINITY,
    };
    let n = if px.is_finite() {
        ((px / SAMPLE_SPACING_PX).ceil() as usize + 1).clamp(MIN_SAMPLES, MAX_SAMPLES)
    } else {
        MAX_SAMPLES
    };
    let sample = |k: usize| s0 + (s1 - s0) * k as f64 / (n - 1) as f64;
    // Refines a transition between `lo` (state `state_lo`) and `hi`.
    let refine = |mut lo: f64, mut hi: f64, state_lo: bool| {
        let mut iterations = 0;
        while (hi - lo) * length > REFINE_TOL_M && iterations < 60 {
            let mid = 0.5 * (lo + hi);
            if visible(mid) == state_lo {
                lo = mid;
            } else {
                hi = mid;
            }
            iterations += 1;
        }
        0.5 * (lo + hi)
    };
    let mut out = Vec::new();
    let mut prev = visible(s0);
    let mut start = if prev { Some(s0) } else { None };
    for k in 1..n {
        let s = sample(k);
        let now = visible(s);
        if now != prev {
            let t = refine(sample(k - 1), s, prev);
            match start.take() {
                Some(a) => out.push((a, t)),
                None => start = Some(t),
            }
        }
        prev = now;
    }
    if let Some(a) = start {
        out.push((a, s1));
    }
    out.retain(|(a, b)| (b - a) * length >= MIN_VISIBLE_M);
    out
}

/// Grey level seen by `camera` through the (distorted) pixel `pixel`.
pub fn pixel_radiance<T: Tracer>(tracer: &T, camera: &Camera, pixel: Point2<f64>) -> f64 {
    let dir = camera.ray(camera.undistort(pixel));
    tracer.radiance(&camera.centre(), &dir)
}

/// A camera's numbers as plain arrays, for the inner loops of contrast probing (tens of
/// thousands of projections and rays per observation, where generic matrix code dominates
/// the run time of unoptimised test builds). Same model as [`Camera`].
#[derive(Debug, Clone)]
pub(crate) struct FlatCamera {
    /// rig_to_cam rotation rows, then translation.
    r: [[f64; 3]; 3],
    t: [f64; 3],
    fx: f64,
    fy: f64,
    skew: f64,
    cx: f64,
    cy: f64,
    centre: Point3<f64>,
    distortion: Option<trinocular_core::geometry::Distortion>,
    width: f64,
    height: f64,
}

impl FlatCamera {
    pub(crate) fn new(camera: &Camera) -> FlatCamera {
        let (r, t, k) = (camera.rotation(), camera.translation(), camera.intrinsics());
        FlatCamera {
            r: std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)])),
            t: [t.x, t.y, t.z],
            fx: k[(0, 0)],
            fy: k[(1, 1)],
            skew: k[(0, 1)],
            cx: k[(0, 2)],
            cy: k[(1, 2)],
            centre: camera.centre(),
            distortion: camera.distortion().copied(),
            width: camera.width() as f64,
            height: camera.height() as f64,
        }
    }

    fn to_cam(&self, x: &[f64; 3]) -> [f64; 3] {
        std::array::from_fn(|i| {
            self.r[i][0] * x[0] + self.r[i][1] * x[1] + self.r[i][2] * x[2] + self.t[i]
        })
    }

    /// As [`Camera::project`], with the depth.
    fn project(&self, x: &[f64; 3]) -> Option<([f64; 2], f64)> {
        let c = self.to_cam(x);
        if c[2] <= 1e-12 {
            return None;
        }
        let (mut u, mut v) = (c[0] / c[2], c[1] / c[2]);
        if let Some(d) = &self.distortion {
            (u, v) = d.apply(u, v);
        }
        Some((
            [self.fx * u + self.skew * v + self.cx, self.fy * v + self.cy],
            c[2],
        ))
    }

    /// Whether a point is at least [`MIN_DEPTH_M`] in front and projects inside the image.
    /// With distortion, also that it lies where the radial distortion is still monotonic:
    /// beyond that radius the lens model folds far-off points back into the image, which no
    /// real lens does.
    fn in_image(&self, x: &[f64; 3]) -> bool {
        let c = self.to_cam(x);
        if c[2] < MIN_DEPTH_M {
            return false;
        }
        if let Some(d) = &self.distortion {
            let r2 = (c[0] * c[0] + c[1] * c[1]) / (c[2] * c[2]);
            if 1.0 + r2 * (3.0 * d.k1 + r2 * (5.0 * d.k2 + r2 * 7.0 * d.k3)) <= 0.0 {
                return false;
            }
        }
        self.project(x).is_some_and(|(p, _)| {
            p[0] >= -0.5 && p[0] <= self.width - 0.5 && p[1] >= -0.5 && p[1] <= self.height - 0.5
        })
    }

    /// Undistorted normalised coordinates `(x/z, y/z)` of a (distorted) pixel.
    fn normalised(&self, pixel: [f64; 2]) -> (f64, f64) {
        let y = (pixel[1] - self.cy) / self.fy;
        let x = (pixel[0] - self.cx - self.skew * y) / self.fx;
        match &self.distortion {
            Some(d) => d.remove(x, y),
            None => (x, y),
        }
    }

    /// Rig-frame direction of the ray through a (distorted) pixel.
    fn ray(&self, pixel: [f64; 2]) -> Vector3<f64> {
        let (x, y) = self.normalised(pixel);
        let r = &self.r;

        Vector3::new(
            r[0][0] * x + r[1][0] * y + r[2][0],
            r[0][1] * x + r[1][1] * y + r[2][1],
            r[0][2] * x + r[1][2] * y + r[2][2],
        )
    }

    /// [`contrast_at`] on this camera.
    pub(crate) fn contrast<T: Tracer>(&self, tracer: &T, edge: &Segment3, s: f64) -> Option<f64> {
        let (a, b) = (edge.start, edge.end);
        let d = [b.x - a.x, b.y - a.y, b.z - a.z];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if len.is_nan() || len <= 1e-15 {
            return None;
        }
        let x = [a.x + s * d[0], a.y + s * d[1], a.z + s * d[2]];
        let (p, depth) = self.project(&x)?;
        if depth < MIN_DEPTH_M {
            return None;
        }
        // About half a pixel at f = 600 px: the local tangent of the (possibly distorted)
        // image of the edge.
        let h = 1e-3 * depth / len;
        let (ahead, _) = self.project(&std::array::from_fn(|k| x[k] + h * d[k]))?;
        let (behind, _) = self.project(&std::array::from_fn(|k| x[k] - h * d[k]))?;
        let (tu, tv) = (ahead[0] - behind[0], ahead[1] - behind[1]);
        let norm = (tu * tu + tv * tv).sqrt();
        if norm < 1e-9 {
            return None;
        }
        let (lu, lv) = (
            tv * CONTRAST_OFFSET_PX / norm,
            -tu * CONTRAST_OFFSET_PX / norm,
        );
        let left = tracer.radiance(&self.centre, &self.ray([p[0] + lu, p[1] + lv]));
        let right = tracer.radiance(&self.centre, &self.ray([p[0] - lu, p[1] - lv]));
        Some(left - right)
    }
}

/// Signed contrast across the edge at parameter `s`: grey level 1.5 px on the left of the
/// projected edge minus 1.5 px on its right, walking from A to B as seen on screen (v down;
/// left is along `(dv, −du)`). `None` when the point or its neighbourhood is not in front of
/// the camera, or the edge projects to a point.
pub fn contrast_at<T: Tracer>(tracer: &T, camera: &Camera, edge: &Segment3, s: f64) -> Option<f64> {
    FlatCamera::new(camera).contrast(tracer, edge, s)
}

/// Median |contrast| over [`CONTRAST_SAMPLES`] probes spread evenly over the visible length.
pub fn edge_contrast<T: Tracer>(
    tracer: &T,
    camera: &Camera,
    edge: &Segment3,
    visible: &[Interval],
) -> Option<f64> {
    let total = total_length(visible);
    if total <= 0.0 {
        return None;
    }
    let flat = FlatCamera::new(camera);
    let mut values = Vec::with_capacity(CONTRAST_SAMPLES);
    for k in 0..CONTRAST_SAMPLES {
        let mut along = total * (k as f64 + 0.5) / CONTRAST_SAMPLES as f64;
        for &(a, b) in visible {
            if along <= b - a {
                if let Some(c) = flat.contrast(tracer, edge, a + along) {
                    values.push(c.abs());
                }
                break;
            }
            along -= b - a;
        }
    }
    median(&mut values)
}

/// Median (mean of the two middle values for an even count); `None` when empty.
pub(crate) fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    Some(if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    })
}

/// Projected length of intervals of an edge, summed, pixels (chords: exact without
/// distortion).
pub fn projected_length(camera: &Camera, edge: &Segment3, intervals: &[Interval]) -> f64 {
    intervals
        .iter()
        .filter_map(|&(a, b)| {
            let pa = camera.project(&point_at(edge, a))?;
            let pb = camera.project(&point_at(edge, b))?;
            Some((pb - pa).norm())
        })
        .sum()
}

/// Visibility of every edge in the three cameras of `rig`.
pub fn rig_visibility(scene: &Scene, rig: &Rig, edges: &[Segment3]) -> Vec<EdgeVisibility> {
    let cams = rig.cameras();
    let index = SceneIndex::new(scene);
    edges
        .iter()
        .map(|edge| {
            let cameras: [Vec<Interval>; 3] =
                std::array::from_fn(|c| visible_intervals(scene, &cams[c], edge));
            let all3 =
                intersect_intervals(&intersect_intervals(&cameras[0], &cameras[1]), &cameras[2]);
            let all3_px = std::array::from_fn(|c| projected_length(&cams[c], edge, &all3));
            let contrast =
                std::array::from_fn(|c| edge_contrast(&index, &cams[c], edge, &cameras[c]));
            EdgeVisibility {
                cameras,
                all3,
                all3_px,
                contrast,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::{Pose, RigSpec};
    use crate::scene::Box3;

    /// Camera 1 of a collinear rig: at the origin, looking along +y, pitched down ~5°.
    fn camera() -> Camera {
        let rig = RigSpec::collinear(0).build(&Pose::identity()).unwrap();
        rig.cameras()[0].clone()
    }

    fn wall_and_block() -> Scene {
        Scene {
            boxes: vec![
                // A wall 4 m ahead and a block 2 m ahead hiding its middle.
                Box3::new(
                    Point3::new(-5.0, 4.0, -5.0),
                    Point3::new(5.0, 4.2, 5.0),
                    [0.8; 6],
                ),
                Box3::new(
                    Point3::new(-0.2, 2.0, -0.2),
                    Point3::new(0.2, 2.4, 0.2),
                    [0.1; 6],
                ),
            ],
            light: Point3::new(0.0, 1.0, 1.0),
        }
    }

    #[test]
    fn interval_algebra() {
        let u = union_intervals(&[(0.5, 0.7), (0.0, 0.2), (0.6, 0.9), (0.1, 0.15)]);
        assert_eq!(u, vec![(0.0, 0.2), (0.5, 0.9)]);
        let i = intersect_intervals(&u, &[(0.1, 0.6), (0.8, 1.0)]);
        assert_eq!(i, vec![(0.1, 0.2), (0.5, 0.6), (0.8, 0.9)]);
        assert!((total_length(&i) - 0.3).abs() < 1e-12);
    }

    #[test]
    fn unobstructed_edge_in_view_is_fully_visible() {
        let scene = wall_and_block();
        let cam = camera();
        // The block's front-top edge, in plain view.
        let edge = Segment3 {
            start: Point3::new(-0.2, 2.0, 0.2),
            end: Point3::new(0.2, 2.0, 0.2),
        };
        assert_eq!(visible_intervals(&scene, &cam, &edge), vec![(0.0, 1.0)]);
    }

    #[test]
    fn edge_behind_a_box_is_hidden() {
        let scene = wall_and_block();
        let cam = camera();
        let c = cam.centre();
        // A short vertical segment on the wall right behind the block.
        let target = |z: f64| {
            let d = Point3::new(0.0, 2.2, 0.0) - c;
            c + d * ((4.0 - c.y) / d.y) + Vector3::new(0.0, 0.0, z)
        };
        let edge = Segment3 {
            start: target(-0.05),
            end: target(0.05),
        };
        assert!(visible_intervals(&scene, &cam, &edge).is_empty());
        // The block's back edges face away: hidden by the block itself.
        let back = Segment3 {
            start: Point3::new(-0.2, 2.4, -0.2),
            end: Point3::new(0.2, 2.4, -0.2),
        };
        assert!(visible_intervals(&scene, &cam, &back).is_empty());
    }

    #[test]
    fn partly_hidden_edge_has_sharp_transitions() {
        let scene = wall_and_block();
        let cam = camera();
        let c = cam.centre();
        // A horizontal edge on the wall at the camera's height, through the block's shadow.
        let edge = Segment3 {
            start: Point3::new(-1.0, 4.0, c.z),
            end: Point3::new(1.0, 4.0, c.z),
        };
        let vis = visible_intervals(&scene, &cam, &edge);
        assert_eq!(vis.len(), 2, "{vis:?}");
        // Silhouette of the block's front face (y = 2) from the centre, on the wall (y = 4).
        let x_at_wall = |x: f64| c.x + (x - c.x) * (4.0 - c.y) / (2.0 - c.y);
        let s_lo = (x_at_wall(-0.2) + 1.0) / 2.0;
        let s_hi = (x_at_wall(0.2) + 1.0) / 2.0;
        assert!((vis[0].1 - s_lo).abs() < 1e-4, "{} vs {s_lo}", vis[0].1);
        assert!((vis[1].0 - s_hi).abs() < 1e-4, "{} vs {s_hi}", vis[1].0);
        assert_eq!((vis[0].0, vis[1].1), (0.0, 1.0));
    }

    #[test]
    fn edges_out_of_frame_or_behind_are_invisible() {
        let scene = wall_and_block();
        let cam = camera();
        let behind = Segment3 {
            start: Point3::new(-0.2, -2.0, 0.0),
            end: Point3::new(0.2, -2.0, 0.0),
        };
        assert!(visible_intervals(&scene, &cam, &behind).is_empty());
        // Crossing the frame: clipped where it leaves the image.
        let wide = Segment3 {
            start: Point3::new(-3.0, 3.9, 0.5),
            end: Point3::new(3.0, 3.9, 0.5),
        };
        let vis = visible_intervals(&scene, &cam, &wide);
        assert_eq!(vis.len(), 1);
        for s in [vis[0].0, vis[0].1] {
            let p = cam.project(&point_at(&wide, s)).unwrap();
            assert!(
                (p.x + 0.5).abs() < 1e-6 || (p.x - 511.5).abs() < 1e-6,
                "{p}"
            );
        }
    }

    #[test]
    fn contrast_sign_follows_the_brighter_side() {
        let scene = wall_and_block();
        let cam = camera();
        // Top front edge of the dark block against the bright wall above it: walking left to
        // right on screen (−x to +x), the left side is up, i.e. the wall: brighter.
        let edge = Segment3 {
            start: Point3::new(-0.2, 2.0, 0.2),
            end: Point3::new(0.2, 2.0, 0.2),
        };
        let c = contrast_at(&scene, &cam, &edge, 0.5).unwrap();
        assert!(c > MIN_CONTRAST, "contrast {c}");
        let reversed = Segment3 {
            start: edge.end,
            end: edge.start,
        };
        let r = contrast_at(&scene, &cam, &reversed, 0.5).unwrap();
        assert!((r + c).abs() < 1e-9);
    }
}
