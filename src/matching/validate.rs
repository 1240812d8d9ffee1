//! Local-consistency validation (DESIGN §2.5, the paper's "validation").
//!
//! 1. **Support.** Segments of view 1 whose endpoints lie within `neighbour_radius_px` of each
//!    other share a vertex. A hypothesis is supported by each such neighbour that has a
//!    hypothesis whose disparity agrees with its own at the shared vertex: the two 3D lines
//!    then meet there, as the edges of a real object do. (Agreement in view 1 at one
//!    disparity means the vertex is shared in views 2 and 3 too.)
//! 2. **Uniqueness.** Hypotheses are taken best first — most support, then smallest residual
//!    — and one is dropped when it reuses a segment of an already accepted one, except when
//!    the two are fragments of one line: in every view where their segments differ, those are
//!    collinear and do not overlap. So an unsupported hypothesis that has a better-supported
//!    rival is dropped, and one with no rival is kept.

use std::collections::HashMap;

use nalgebra::Point2;

use super::{predict::Hypothesis, MatchParams, RectSegment, Views};
use crate::geometry::Rectification;

/// Disparity agreement at a shared vertex, in pixels of the longest epipolar shift, as a
/// multiple of `tolerance_px`.
const VERTEX_AGREEMENT: f64 = 1.0;
/// How far two collinear fragments may overlap and still count as distinct, as a multiple of
/// `tolerance_px`.
const FRAGMENT_OVERLAP: f64 = 1.0;
const NONE: u32 = u32::MAX;

/// Returns the indices (into `hypotheses`) of the accepted ones, in input order.
pub fn validate(
    rect: &Rectification,
    views: &Views,
    hypotheses: &[Hypothesis],
    params: &MatchParams,
) -> Vec<usize> {
    let support = support(rect, views, hypotheses, params);
    let mut order: Vec<usize> = (0..hypotheses.len()).collect();
    order.sort_by(|&a, &b| {
        let (ha, hb) = (&hypotheses[a], &hypotheses[b]);
        support[b]
            .cmp(&support[a])
            .then(ha.residual_px.total_cmp(&hb.residual_px))
            .then(ha.segments.cmp(&hb.segments))
    });

    // Accepted hypotheses per segment, as linked lists (head per segment, next per accepted).
    let mut head: [Vec<u32>; 3] = std::array::from_fn(|v| vec![NONE; views.segments[v].len()]);
    let mut next: [Vec<u32>; 3] = std::array::from_fn(|_| vec![NONE; hypotheses.len()]);
    let mut accepted = Vec::new();
    for h in order {
        let hyp = &hypotheses[h];
        let mut ok = true;
        'views: for v in 0..3 {
            let mut g = head[v][hyp.segments[v] as usize];
            while g != NONE {
                if !fragments(views, hyp, &hypotheses[g as usize], params) {
                    ok = false;
                    break 'views;
                }
                g = next[v][g as usize];
            }
        }
        if ok {
            for v in 0..3 {
                let s = hyp.segments[v] as usize;
                next[v][h] = head[v][s];
                head[v][s] = h as u32;
            }
            accepted.push(h);
        }
    }
    accepted.sort_unstable();
    accepted
}

/// True when `a` and `b` are fragments of one line: wherever their segments differ, those
/// are collinear and disjoint.
fn fragments(views: &Views, a: &Hypothesis, b: &Hypothesis, params: &MatchParams) -> bool {
    let tol = params.tolerance_px;
    let mut differ = false;
    for v in 0..3 {
        if a.segments[v] == b.segments[v] {
            continue;
        }
        differ = true;
        let sa = &views.segments[v][a.segments[v] as usize];
        let sb = &views.segments[v][b.segments[v] as usize];
        if sa.dir.dot(&sb.dir) < 0.0 && views.oriented {
            return false;
        }
        let collinear = |x: &RectSegment, y: &RectSegment| {
            x.line_distance(y.a).abs() <= tol && x.line_distance(y.b).abs() <= tol
        };
        if !(collinear(sa, sb) || collinear(sb, sa)) {
            return false;
        }
        let (ta, tb) = (sa.along(sb.a), sa.along(sb.b));
        let overlap = ta.max(tb).min(sa.len) - ta.min(tb).max(0.0);
        if overlap > FRAGMENT_OVERLAP * tol {
            return false;
        }
    }
    differ
}

/// Number of supporting neighbours of each hypothesis.
fn support(
    rect: &Rectification,
    views: &Views,
    hypotheses: &[Hypothesis],
    params: &MatchParams,
) -> Vec<u32> {
    let s1 = views.segments[0];
    let radius = params.neighbour_radius_px;
    let mut support = vec![0u32; hypotheses.len()];
    if s1.is_empty() || hypotheses.is_empty() || radius <= 0.0 {
        return support;
    }
    // Hypotheses come in S1 order: the range of each S1.
    let mut range = vec![(0usize, 0usize); s1.len()];
    let mut i = 0;
    while i < hypotheses.len() {
        let s = hypotheses[i].segments[0] as usize;
        let mut j = i;
        while j < hypotheses.len() && hypotheses[j].segments[0] as usize == s {
            j += 1;
        }
        range[s] = (i, j);
        i = j;
    }
    let baseline_px = rect.epipolar(0, 1).norm().max(rect.epipolar(0, 2).norm());
    let max_diff = VERTEX_AGREEMENT * params.tolerance_px / baseline_px;

    for (a, b, vertex) in vertex_pairs(s1, radius) {
        let (ra, rb) = (range[a as usize], range[b as usize]);
        if ra.0 == ra.1 || rb.0 == rb.1 {
            continue;
        }
        let (sa, sb) = (&s1[a as usize], &s1[b as usize]);
        let (ta, tb) = (sa.along(vertex), sb.along(vertex));
        for ha in ra.0..ra.1 {
            let da = hypotheses[ha].disparity_at(ta);
            let agrees =
                (rb.0..rb.1).any(|hb| (hypotheses[hb].disparity_at(tb) - da).abs() <= max_diff);
            if agrees {
                support[ha] += 1;
            }
        }
        for hb in rb.0..rb.1 {
            let db = hypotheses[hb].disparity_at(tb);
            let agrees =
                (ra.0..ra.1).any(|ha| (hypotheses[ha].disparity_at(ta) - db).abs() <= max_diff);
            if agrees {
                support[hb] += 1;
            }
        }
    }
    support
}

/// Pairs of distinct segments with endpoints within `radius`, each pair once, with the
/// shared vertex (the midpoint of the two closest endpoints). A grid of `radius`-sized cells
/// keeps this linear in the number of segments.
fn vertex_pairs(segments: &[RectSegment], radius: f64) -> Vec<(u32, u32, Point2<f64>)> {
    let key = |p: Point2<f64>| ((p.x / radius).floor() as i64, (p.y / radius).floor() as i64);
    type Cell = Vec<(u32, Point2<f64>)>;
    let mut cells: HashMap<(i64, i64), Cell> = HashMap::new();
    for (i, s) in segments.iter().enumerate() {
        for p in [s.a, s.b] {
            cells.entry(key(p)).or_default().push((i as u32, p));
        }
    }
    let mut best: HashMap<(u32, u32), (f64, Point2<f64>)> = HashMap::new();
    for (i, s) in segments.iter().enumerate() {
        for p in [s.a, s.b] {
            let (cx, cy) = key(p);
            for dx in -1..=1 {
                for dy in -1..=1 {
                    let Some(list) = cells.get(&(cx + dx, cy + dy)) else {
                        continue;
                    };
                    for &(j, q) in list {
                        if j <= i as u32 {
                            continue;
                        }
                        let d = (q - p).norm();
                        if d <= radius {
                            let mid = nalgebra::center(&p, &q);
                            let e = best.entry((i as u32, j)).or_insert((f64::INFINITY, mid));
                            if d < e.0 {
                                *e = (d, mid);
                            }
                        }
                    }
                }
            }
        }
    }
    let mut pairs: Vec<(u32, u32, Point2<f64>)> =
        best.into_iter().map(|((a, b), (_, v))| (a, b, v)).collect();
    pairs.sort_unstable_by_key(|&(a, b, _)| (a, b));
    pairs
}
