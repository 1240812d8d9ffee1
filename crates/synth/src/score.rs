//! Accuracy metrics of reconstructed 3D segments against exact ground truth.
//!
//! A re-implementation of `shared/eval/score.py` (single capture), so tests and benches can
//! score without Python and get the same numbers:
//!
//! - tolerance at a point P: `max(0.02 m, 0.01·|P − c|)`, `c` the rig centre (centroid of
//!   the optical centres);
//! - a segment is **correct** when both endpoints and its midpoint are within tolerance
//!   (point-to-segment distance) of the same ground-truth edge and its direction is within 5°
//!   of that edge's; among qualifying edges the one with the smallest summed distance is the
//!   match;
//! - **completeness**: correct segments are projected onto their matched edge (and onto every
//!   edge exactly collinear with it, i.e. duplicate ground truth), and the covered share of
//!   the eligible length is reported. Eligible: the part visible in all three cameras, for
//!   edges whose part projects to at least 20 px in every image ([`eligible_intervals`]);
//! - **accuracy**: distance of the endpoints of correct segments to the infinite line of their
//!   matched edge, median and 90th percentile (linear interpolation, as numpy), millimetres.

use nalgebra::{Point3, Vector3};

use super::defects::Observation;
use super::visibility::{intersect_intervals, total_length, union_intervals, Interval};
use trinocular_core::segment::Segment3;

pub const TOL_ABS_M: f64 = 0.02;
pub const TOL_REL: f64 = 0.01;
pub const MAX_ANGLE_DEG: f64 = 5.0;
/// Eligible edges project to at least this in every image, pixels.
pub const MIN_ELIGIBLE_PX: f64 = 20.0;

/// The metrics of one set of 3D segments. Ratios are `None` when undefined (no segments,
/// nothing eligible, nothing correct).
#[derive(Debug, Clone, PartialEq)]
pub struct Score {
    pub n_segments: usize,
    pub n_correct: usize,
    pub error_rate: Option<f64>,
    pub completeness: Option<f64>,
    pub acc_median_mm: Option<f64>,
    pub acc_p90_mm: Option<f64>,
    /// Per segment: the matched ground-truth edge, `None` when wrong.
    pub matches: Vec<Option<usize>>,
    pub n_eligible_edges: usize,
    pub eligible_length_m: f64,
    pub covered_length_m: f64,
}

/// Eligible sub-intervals per ground-truth edge: the part visible in all three cameras when
/// it projects to at least [`MIN_ELIGIBLE_PX`] in each image, else none.
pub fn eligible_intervals(obs: &Observation) -> Vec<Vec<Interval>> {
    eligible_intervals_with(obs, MIN_ELIGIBLE_PX, None)
}

/// [`eligible_intervals`] with another pixel threshold, optionally also requiring a contrast
/// of at least `min_contrast` grey levels in all three images (the evaluation's
/// `completeness_contrast10` uses 10).
pub fn eligible_intervals_with(
    obs: &Observation,
    min_px: f64,
    min_contrast: Option<f64>,
) -> Vec<Vec<Interval>> {
    obs.visibility
        .iter()
        .map(|v| {
            let long_enough = !v.all3.is_empty() && v.all3_px.iter().all(|&px| px >= min_px);
            let contrasted =
                min_contrast.is_none_or(|m| v.contrast.iter().all(|c| c.is_some_and(|c| c >= m)));
            if long_enough && contrasted {
                v.all3.clone()
            } else {
                Vec::new()
            }
        })
        .collect()
}

fn point_line_distance(p: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> f64 {
    let Some(u) = (b - a).try_normalize(0.0) else {
        return (p - a).norm();
    };
    let w = p - a;
    (w - u * w.dot(&u)).norm()
}

/// numpy's default (linear) percentile of sorted values.
fn percentile(sorted: &[f64], q: f64) -> Option<f64> {
    if sorted.is_empty() {
        return None;
    }
    let pos = q / 100.0 * (sorted.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    Some(sorted[lo] + (sorted[hi] - sorted[lo]) * (pos - lo as f64))
}

/// A ground-truth edge as plain arrays: matching tests every segment against every edge.
#[derive(Debug, Clone, Copy)]
struct FlatEdge {
    a: [f64; 3],
    d: [f64; 3],
    /// |d|², and the unit direction (zero for a degenerate edge).
    dd: f64,
    u: [f64; 3],
    mid: [f64; 3],
    half_length: f64,
}

fn dot(x: &[f64; 3], y: &[f64; 3]) -> f64 {
    x[0] * y[0] + x[1] * y[1] + x[2] * y[2]
}

fn sub(x: &[f64; 3], y: &[f64; 3]) -> [f64; 3] {
    [x[0] - y[0], x[1] - y[1], x[2] - y[2]]
}

impl FlatEdge {
    fn new(e: &Segment3) -> FlatEdge {
        let a: [f64; 3] = e.start.coords.into();
        let d = sub(&e.end.coords.into(), &a);
        let dd = dot(&d, &d);
        let len = dd.sqrt();
        let u = if len > 0.0 {
            d.map(|v| v / len)
        } else {
            [0.0; 3]
        };
        FlatEdge {
            a,
            d,
            dd,
            u,
            mid: std::array::from_fn(|k| a[k] + 0.5 * d[k]),
            half_length: 0.5 * len,
        }
    }

    fn distance(&self, p: &[f64; 3]) -> f64 {
        let w = sub(p, &self.a);
        let t = if self.dd > 0.0 {
            (dot(&w, &self.d) / self.dd).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let r: [f64; 3] = std::array::from_fn(|k| w[k] - t * self.d[k]);
        dot(&r, &r).sqrt()
    }
}

/// The matched edge of a segment, if it is correct.
fn match_segment(seg: &Segment3, truth: &[FlatEdge], centre: &Point3<f64>) -> Option<usize> {
    let d = seg.end - seg.start;
    let length = d.norm();
    if !(length > 0.0 && length.is_finite()) {
        return None;
    }
    let su: [f64; 3] = (d / length).into();
    let cos_min = MAX_ANGLE_DEG.to_radians().cos();
    let mid = seg.start + d * 0.5;
    let points: [[f64; 3]; 3] = [
        seg.start.coords.into(),
        seg.end.coords.into(),
        mid.coords.into(),
    ];
    let c: [f64; 3] = centre.coords.into();
    let tols = points.map(|p| {
        let r = sub(&p, &c);
        TOL_ABS_M.max(TOL_REL * dot(&r, &r).sqrt())
    });
    let mut best: Option<(usize, f64)> = None;
    for (j, e) in truth.iter().enumerate() {
        if dot(&su, &e.u).abs() < cos_min {
            continue;
        }
        // Cheap rejection: the midpoint must be near the edge's bounding sphere.
        let r = sub(&points[2], &e.mid);
        let reach = e.half_length + tols[2];
        if dot(&r, &r) > reach * reach {
            continue;
        }
        let mut total = 0.0;
        let mut ok = true;
        for (p, tol) in points.iter().zip(tols) {
            let dist = e.distance(p);
            if dist > tol {
                ok = false;
                break;
            }
            total += dist;
        }
        if ok && best.is_none_or(|(_, t)| total < t) {
            best = Some((j, total));
        }
    }
    best.map(|(j, _)| j)
}

/// Ground-truth edges exactly collinear with edge `j` (including `j`).
fn collinear_with(truth: &[Segment3], j: usize) -> Vec<usize> {
    let e = &truth[j];
    let Some(u) = (e.end - e.start).try_normalize(0.0) else {
        return vec![j];
    };
    truth
        .iter()
        .enumerate()
        .filter(|(_, f)| {
            let Some(fu) = (f.end - f.start).try_normalize(0.0) else {
                return false;
            };
            let w: Vector3<f64> = f.start - e.start;
            (fu.dot(&u).abs() - 1.0).abs() < 1e-9 && (w - u * w.dot(&u)).norm() < 1e-6
        })
        .map(|(i, _)| i)
        .collect()
}

/// Scores `segments` against `truth` (same frame), given the eligible intervals per truth
/// edge (missing entries count as not eligible) and the rig centre in that frame.
pub fn score(
    segments: &[Segment3],
    truth: &[Segment3],
    eligible: &[Vec<Interval>],
    rig_centre: Point3<f64>,
) -> Score {
    let flat: Vec<FlatEdge> = truth.iter().map(FlatEdge::new).collect();
    let matches: Vec<Option<usize>> = segments
        .iter()
        .map(|s| match_segment(s, &flat, &rig_centre))
        .collect();
    summarise(segments, matches, truth, eligible)
}

/// Why the wrong segments of a [`score`] are wrong, as counts (the classes of the accuracy
/// figures): on an edge but more than 5° off its direction; not on one but within three
/// tolerances of one (imprecise depth, or a neighbouring edge); near no edge at all.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ErrorClasses {
    pub direction_only: usize,
    pub near: usize,
    pub far: usize,
}

/// Scores pooled over several captures (seeds): the error and completeness of all their
/// segments together, as the rig figures and tests quote them, and the wrong ones' classes.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Pooled {
    pub segments: usize,
    pub correct: usize,
    pub eligible_m: f64,
    pub covered_m: f64,
    pub classes: ErrorClasses,
}

impl Pooled {
    pub fn add(&mut self, s: &Score) {
        self.segments += s.n_segments;
        self.correct += s.n_correct;
        self.eligible_m += s.eligible_length_m;
        self.covered_m += s.covered_length_m;
    }

    pub fn add_classes(&mut self, c: &ErrorClasses) {
        self.classes.direction_only += c.direction_only;
        self.classes.near += c.near;
        self.classes.far += c.far;
    }

    /// Share of the segments that are wrong; 1 when there are none, so that a rig that
    /// answers nothing does not pass for an accurate one.
    pub fn error(&self) -> f64 {
        1.0 - self.correct as f64 / self.segments.max(1) as f64
    }

    /// Share of the eligible length covered (NaN when nothing is eligible).
    pub fn completeness(&self) -> f64 {
        self.covered_m / self.eligible_m
    }

    /// The rig tables' cells: `segments | error | dir / near / far | completeness`.
    pub fn cells(&self) -> String {
        format!(
            "{} | {:.1}% | {} / {} / {} | {:.1}%",
            self.segments,
            100.0 * self.error(),
            self.classes.direction_only,
            self.classes.near,
            self.classes.far,
            100.0 * self.completeness(),
        )
    }
}

/// Classifies the segments that `matches` (from [`score`]) says are wrong.
pub fn error_classes(
    segments: &[Segment3],
    matches: &[Option<usize>],
    truth: &[Segment3],
    rig_centre: Point3<f64>,
) -> ErrorClasses {
    let flat: Vec<FlatEdge> = truth.iter().map(FlatEdge::new).collect();
    let c: [f64; 3] = rig_centre.coords.into();
    let mut classes = ErrorClasses::default();
    for (seg, m) in segments.iter().zip(matches) {
        if m.is_some() {
            continue;
        }
        let mid = seg.start + (seg.end - seg.start) * 0.5;
        let points: [[f64; 3]; 3] = [
            seg.start.coords.into(),
            seg.end.coords.into(),
            mid.coords.into(),
        ];
        // The worst of the three points' distances, in tolerances, to the closest edge.
        let nearest = flat
            .iter()
            .map(|e| {
                points
                    .iter()
                    .map(|p| {
                        let r = sub(p, &c);
                        e.distance(p) / TOL_ABS_M.max(TOL_REL * dot(&r, &r).sqrt())
                    })
                    .fold(0.0, f64::max)
            })
            .fold(f64::INFINITY, f64::min);
        if nearest <= 1.0 {
            classes.direction_only += 1;
        } else if nearest <= 3.0 {
            classes.near += 1;
        } else {
            classes.far += 1;
        }
    }
    classes
}

/// The paper's criterion: a segment is right when the image segments it was reconstructed
/// from are images of one ground-truth edge, whatever the precision of its 3D position.
/// `labels[i]` is that edge (`None`: a wrong match). Completeness then counts the eligible
/// length covered by right segments projected onto their edge.
pub fn score_labelled(
    segments: &[Segment3],
    labels: &[Option<usize>],
    truth: &[Segment3],
    eligible: &[Vec<Interval>],
) -> Score {
    summarise(segments, labels.to_vec(), truth, eligible)
}

fn summarise(
    segments: &[Segment3],
    matches: Vec<Option<usize>>,
    truth: &[Segment3],
    eligible: &[Vec<Interval>],
) -> Score {
    let n_segments = segments.len();
    let n_correct = matches.iter().flatten().count();

    let mut cover: Vec<Vec<Interval>> = vec![Vec::new(); truth.len()];
    let mut dup_cache: Vec<Option<Vec<usize>>> = vec![None; truth.len()];
    for (seg, m) in segments.iter().zip(&matches) {
        let Some(j) = *m else { continue };
        let dups = dup_cache[j].get_or_insert_with(|| collinear_with(truth, j));
        for &k in dups.iter() {
            let e = &truth[k];
            let d = e.end - e.start;
            let dd = d.norm_squared();
            let s1 = (seg.start - e.start).dot(&d) / dd;
            let s2 = (seg.end - e.start).dot(&d) / dd;
            let (lo, hi) = (s1.min(s2).max(0.0), s1.max(s2).min(1.0));
            if hi > lo {
                cover[k].push((lo, hi));
            }
        }
    }

    let (mut eligible_length_m, mut covered_length_m, mut n_eligible_edges) = (0.0, 0.0, 0);
    for (j, e) in truth.iter().enumerate() {
        let Some(ivs) = eligible.get(j) else { continue };
        let ivs = union_intervals(ivs);
        if ivs.is_empty() {
            continue;
        }
        n_eligible_edges += 1;
        let length = e.length();
        eligible_length_m += total_length(&ivs) * length;
        covered_length_m +=
            total_length(&intersect_intervals(&ivs, &union_intervals(&cover[j]))) * length;
    }

    let mut dists: Vec<f64> = segments
        .iter()
        .zip(&matches)
        .filter_map(|(s, m)| m.map(|j| (s, j)))
        .flat_map(|(s, j)| {
            let e = &truth[j];
            [s.start, s.end].map(|p| point_line_distance(&p, &e.start, &e.end))
        })
        .collect();
    dists.sort_by(f64::total_cmp);

    Score {
        n_segments,
        n_correct,
        error_rate: (n_segments > 0).then(|| 1.0 - n_correct as f64 / n_segments as f64),
        completeness: (eligible_length_m > 0.0).then(|| covered_length_m / eligible_length_m),
        acc_median_mm: percentile(&dists, 50.0).map(|v| v * 1000.0),
        acc_p90_mm: percentile(&dists, 90.0).map(|v| v * 1000.0),
        matches,
        n_eligible_edges,
        eligible_length_m,
        covered_length_m,
    }
}

/// Two edges no camera can tell apart: parallel within 1° and within 1 cm of each other's
/// line, like the front and back edges of a 2 mm poster, or collinear pieces of one line.
fn indistinguishable(a: &Segment3, b: &Segment3) -> bool {
    let (Some(ua), Some(ub)) = (
        (a.end - a.start).try_normalize(0.0),
        (b.end - b.start).try_normalize(0.0),
    ) else {
        return false;
    };
    if ua.dot(&ub).abs() < 1f64.to_radians().cos() {
        return false;
    }
    let off = |p: Point3<f64>| {
        let w: Vector3<f64> = p - a.start;
        (w - ua * w.dot(&ua)).norm()
    };
    off(b.start) < 0.01 && off(b.end) < 0.01
}

/// The ground-truth edge each output segment was matched on, by the labels of its image
/// segments: `Some(edge)` when every segment of every triplet behind it is an image of that
/// edge (or of one indistinguishable from it), `None` for a wrong match.
pub fn match_labels(
    output: &trinocular_core::pipeline::MatchOutput,
    obs: &super::Observation,
) -> Vec<Option<usize>> {
    let truth = &obs.ground_truth;
    output
        .segments_3d
        .iter()
        .map(|r| {
            let mut label: Option<usize> = None;
            for &t in &r.triplets {
                let triplet = output.triplets.get(t as usize)?;
                for (v, &s) in triplet.segments.iter().enumerate() {
                    let l = (*obs.truth[v].get(s as usize)?)?;
                    match label {
                        None => label = Some(l),
                        Some(first) if first == l => {}
                        Some(first) => {
                            if !indistinguishable(&truth[first], &truth[l]) {
                                return None;
                            }
                        }
                    }
                }
            }
            label
        })
        .collect()
}

/// How many of the ground-truth image segments of camera `camera` an extractor found: the
/// segments of the observation's (clean) list for that camera at least `min_length_px` long,
/// of edges whose contrast there is at least `min_contrast` grey levels, for which some
/// extracted segment has both endpoints within `tolerance_px` of theirs, in the same order
/// (so the same contrast orientation). Returns `(found, total)`.
pub fn edge_recall(
    extracted: &trinocular_core::segment::SegmentList,
    obs: &Observation,
    camera: usize,
    min_length_px: f64,
    min_contrast: f64,
    tolerance_px: f64,
) -> (usize, usize) {
    let mut found = 0;
    let mut total = 0;
    for (g, label) in obs.lists[camera].segments.iter().zip(&obs.truth[camera]) {
        let Some(edge) = *label else { continue };
        let contrast = obs
            .visibility
            .get(edge)
            .and_then(|v| v.contrast[camera])
            .unwrap_or(0.0);
        if g.length() < min_length_px || contrast < min_contrast {
            continue;
        }
        total += 1;
        if extracted.segments.iter().any(|e| {
            (e.start - g.start).norm() <= tolerance_px && (e.end - g.end).norm() <= tolerance_px
        }) {
            found += 1;
        }
    }
    (found, total)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seg(a: [f64; 3], b: [f64; 3]) -> Segment3 {
        Segment3 {
            start: Point3::from(a),
            end: Point3::from(b),
        }
    }

    #[test]
    fn pooled_scores_weigh_each_capture_by_its_segments_and_its_eligible_length() {
        let capture = |n_segments, n_correct, eligible_length_m, covered_length_m| Score {
            n_segments,
            n_correct,
            error_rate: None,
            completeness: None,
            acc_median_mm: None,
            acc_p90_mm: None,
            matches: Vec::new(),
            n_eligible_edges: 0,
            eligible_length_m,
            covered_length_m,
        };
        let mut pooled = Pooled::default();
        pooled.add(&capture(10, 9, 4.0, 1.0));
        pooled.add(&capture(30, 15, 1.0, 1.0));
        // 16 of 40 wrong, not the mean of 10% and 50%; 2 m of 5, not the mean of 25% and 100%.
        assert!((pooled.error() - 0.4).abs() < 1e-12);
        assert!((pooled.completeness() - 0.4).abs() < 1e-12);
        pooled.add_classes(&ErrorClasses {
            direction_only: 1,
            near: 2,
            far: 3,
        });
        pooled.add_classes(&ErrorClasses {
            direction_only: 1,
            near: 0,
            far: 1,
        });
        assert_eq!(
            pooled.classes,
            ErrorClasses {
                direction_only: 2,
                near: 2,
                far: 4
            }
        );
        assert_eq!(Pooled::default().error(), 1.0, "no segments: none correct");
    }

    fn truth() -> Vec<Segment3> {
        vec![
            seg([-1.0, 3.0, 0.0], [1.0, 3.0, 0.0]),
            seg([-1.0, 3.0, 0.0], [-1.0, 3.0, 1.0]),
            seg([0.5, 2.0, -0.5], [0.5, 4.0, -0.5]),
        ]
    }

    #[test]
    fn wrong_segments_are_classed_by_how_far_they_are_from_an_edge() {
        // One edge along x, 2 m from the rig centre (tolerance 2 cm).
        let truth = vec![seg([0.0, 2.0, 0.0], [1.0, 2.0, 0.0])];
        let segments = [
            seg([0.1, 2.0, 0.0], [0.9, 2.0, 0.0]),     // right
            seg([0.45, 2.0, 0.0], [0.55, 2.0, 0.015]), // within 1.5 cm, but 8.5° off
            seg([0.1, 2.04, 0.0], [0.9, 2.04, 0.0]),   // 4 cm beside it: near
            seg([0.1, 2.5, 0.0], [0.9, 2.5, 0.0]),     // 50 cm away: far
        ];
        let centre = Point3::origin();
        let s = score(&segments, &truth, &[vec![(0.0, 1.0)]], centre);
        assert_eq!(s.matches, vec![Some(0), None, None, None]);
        let classes = error_classes(&segments, &s.matches, &truth, centre);
        assert_eq!(
            classes,
            ErrorClasses {
                direction_only: 1,
                near: 1,
                far: 1
            }
        );
    }

    #[test]
    fn ground_truth_against_itself_is_perfect() {
        let t = truth();
        let eligible = vec![
            vec![(0.0, 1.0)],
            vec![(0.2, 0.7)],
            vec![(0.0, 0.5), (0.6, 1.0)],
        ];
        let s = score(&t, &t, &eligible, Point3::origin());
        assert_eq!(s.n_correct, 3);
        assert_eq!(s.error_rate, Some(0.0));
        assert!((s.completeness.unwrap() - 1.0).abs() < 1e-12);
        assert_eq!(s.acc_median_mm, Some(0.0));
        assert_eq!(s.matches, vec![Some(0), Some(1), Some(2)]);
    }

    #[test]
    fn shifted_segment_is_wrong_and_partial_cover_counts() {
        let t = truth();
        let eligible = vec![vec![(0.0, 1.0)], vec![], vec![]];
        // 10 cm off: beyond max(2 cm, 1% of ~3 m).
        let shifted = seg([-1.0, 3.0, 0.1], [1.0, 3.0, 0.1]);
        let s = score(&[shifted], &t, &eligible, Point3::origin());
        assert_eq!(s.n_correct, 0);
        assert_eq!(s.error_rate, Some(1.0));
        assert_eq!(s.completeness, Some(0.0));
        assert_eq!(s.acc_median_mm, None);
        // Half of edge 0, 1 cm off and slightly tilted: correct, covers half.
        let half = seg([-1.0, 3.0, 0.01], [0.0, 3.0, 0.012]);
        let s = score(&[half, shifted], &t, &eligible, Point3::origin());
        assert_eq!(s.matches, vec![Some(0), None]);
        assert_eq!(s.error_rate, Some(0.5));
        assert!((s.completeness.unwrap() - 0.5).abs() < 1e-9);
        assert!((s.acc_median_mm.unwrap() - 11.0).abs() < 1e-6);
        // Turned by 10°: wrong even though its midpoint is on the edge.
        let turned = seg([-0.05, 3.0, -0.0088], [0.05, 3.0, 0.0088]);
        assert_eq!(
            score(&[turned], &t, &eligible, Point3::origin()).n_correct,
            0
        );
    }

    #[test]
    fn duplicate_ground_truth_edges_are_covered_together() {
        let mut t = truth();
        t.push(seg([0.0, 3.0, 0.0], [2.0, 3.0, 0.0]));
        let eligible = vec![vec![(0.0, 1.0)], vec![], vec![], vec![(0.0, 1.0)]];
        let s = score(&[t[0]], &t, &eligible, Point3::origin());
        // Edge 0 fully, edge 3 on its first half: 3 m of 4 m.
        assert!((s.completeness.unwrap() - 0.75).abs() < 1e-12);
    }

    #[test]
    fn percentiles_match_numpy() {
        let v = [1.0, 2.0, 3.0, 4.0];
        assert_eq!(percentile(&v, 50.0), Some(2.5));
        assert!((percentile(&v, 90.0).unwrap() - 3.7).abs() < 1e-12);
        assert_eq!(percentile(&[], 50.0), None);
    }
}

/// χ² quantiles of two degrees of freedom, 95% and 99%.
pub const CHI2_2DOF: [f64; 2] = [5.991_464_547, 9.210_340_372];

/// Squared normalised errors of a 3D segment's direction and of its midpoint across the line
/// (two degrees of freedom each) under its reported covariance, against the true `edge` —
/// what `tools/eval_rooms.py --calibration` measures on the rendered rooms. `None` when a
/// covariance cannot be inverted across the line.
pub fn normalised_errors(
    r: &trinocular_core::pipeline::Reconstructed,
    edge: &Segment3,
) -> Option<[f64; 2]> {
    let (a, b) = (r.segment.start, r.segment.end);
    let u = (b - a).normalize();
    let mut truth = (edge.end - edge.start).normalize();
    if truth.dot(&u) < 0.0 {
        truth = -truth;
    }
    let (e1, e2) = trinocular_core::geometry::across_basis(&u);
    let basis = nalgebra::Matrix2x3::from_rows(&[e1.transpose(), e2.transpose()]);
    let mid = nalgebra::center(&a, &b);
    let foot = edge.start + truth * (mid - edge.start).dot(&truth);
    let mut out = [0.0; 2];
    let errors = [
        (truth - u, r.direction_covariance()),
        (foot - mid, r.midpoint_covariance()),
    ];
    for (k, (error, covariance)) in errors.into_iter().enumerate() {
        let e = basis * error;
        out[k] = e.dot(&((basis * covariance * basis.transpose()).try_inverse()? * e));
    }
    Some(out)
}

/// How well reported covariances describe the true errors: of the 3D segments whose match
/// is right ([`match_labels`]: every image segment an image of one true edge), however far
/// off in 3D, how many have their direction and their position within χ²'s 95% and 99%
/// quantiles ([`normalised_errors`]). Issue 12's goal: ≥ 93% and ≥ 98% of each.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Calibration {
    pub segments: usize,
    /// Within q95, within q99.
    pub direction: [usize; 2],
    pub position: [usize; 2],
}

impl Calibration {
    /// Adds a match's segments on their true edge.
    pub fn add(&mut self, output: &trinocular_core::pipeline::MatchOutput, obs: &Observation) {
        self.add_labelled(output, obs, &match_labels(output, obs));
    }

    /// [`Calibration::add`] with the match's [`match_labels`] already at hand.
    pub fn add_labelled(
        &mut self,
        output: &trinocular_core::pipeline::MatchOutput,
        obs: &Observation,
        labels: &[Option<usize>],
    ) {
        for (r, label) in output.segments_3d.iter().zip(labels) {
            let Some([direction, position]) =
                label.and_then(|e| normalised_errors(r, &obs.ground_truth[e]))
            else {
                continue;
            };
            self.segments += 1;
            for (k, q) in CHI2_2DOF.iter().enumerate() {
                self.direction[k] += usize::from(direction <= *q);
                self.position[k] += usize::from(position <= *q);
            }
        }
    }

    /// Shares within q95 and q99: (direction, position).
    pub fn shares(&self) -> ([f64; 2], [f64; 2]) {
        let n = self.segments.max(1) as f64;
        (
            self.direction.map(|c| c as f64 / n),
            self.position.map(|c| c as f64 / n),
        )
    }
}
