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

use nalgebra::Point2;

use super::{predict::Hypothesis, MatchParams, RectSegment, Views};
use crate::checkpoint::{Checkpoint, Stopped};
use crate::geometry::Rectification;

/// Disparity agreement at a shared vertex, in pixels of the longest epipolar shift, as a
/// multiple of `tolerance_px`.
const VERTEX_AGREEMENT: f64 = 1.0;
/// How far two collinear fragments may overlap and still count as distinct, as a multiple of
/// `tolerance_px`.
const FRAGMENT_OVERLAP: f64 = 1.0;
const NONE: u32 = u32::MAX;
/// A vertex joins a handful of segment ends (a corner, a T, a Y); a list that piles many
/// ends onto one place would make the adjacency graph quadratic. Per end, at most this many
/// ends are looked at in each column of cells around it ...
const MAX_ENDS_SCANNED_PER_COLUMN: usize = 64;
/// ... and the nearest this many kept as its neighbours.
const MAX_NEIGHBOURS_PER_END: usize = 16;
/// Smallest cell of the adjacency grid, pixels.
const MIN_CELL_PX: f64 = 0.01;
/// Vertices between two questions to the checkpoint.
const CHECK_EVERY: usize = 4096;

/// Validation in one go: [`rank`], then [`select`] among all hypotheses. Returns the indices
/// (into `hypotheses`) of the accepted ones, in input order.
pub fn validate(
    rect: &Rectification,
    views: &Views,
    adjacency: &[(u32, u32, Point2<f64>)],
    hypotheses: &[Hypothesis],
    params: &MatchParams,
) -> Vec<usize> {
    let ranking = rank(rect, views, adjacency, hypotheses, params);
    select(
        views,
        hypotheses,
        &ranking,
        &vec![true; hypotheses.len()],
        params,
    )
}

/// The order in which hypotheses claim their segments: most support, then the larger share of
/// S1 covered (in quarters: a full-length match beats a fragment's accidental alignment), then
/// the smallest residual, then input order. Computed once: later rounds of [`select`] only
/// drop hypotheses, which does not change the order of the others.
pub fn rank(
    rect: &Rectification,
    views: &Views,
    adjacency: &[(u32, u32, Point2<f64>)],
    hypotheses: &[Hypothesis],
    params: &MatchParams,
) -> Vec<usize> {
    // Without a checkpoint nothing stops it.
    rank_until(
        rect,
        views,
        adjacency,
        hypotheses,
        params,
        Checkpoint::NEVER,
    )
    .unwrap_or_default()
}

/// [`rank`], asking `checkpoint` as it goes through the adjacency graph.
pub fn rank_until(
    rect: &Rectification,
    views: &Views,
    adjacency: &[(u32, u32, Point2<f64>)],
    hypotheses: &[Hypothesis],
    params: &MatchParams,
    checkpoint: Checkpoint,
) -> Result<Vec<usize>, Stopped> {
    let support = support(rect, views, adjacency, hypotheses, params, checkpoint)?;
    // Packed into one integer so the sort compares integers.
    let mut order: Vec<(u128, usize)> = (0..hypotheses.len())
        .map(|h| {
            let hyp = &hypotheses[h];
            let s1 = &views.segments[0][hyp.segments[0] as usize];
            let quarters = ((hyp.s1_span.1 - hyp.s1_span.0) / s1.len.max(1e-9) * 4.0)
                .round()
                .clamp(0.0, 4.0) as u128;
            // Residuals are finite and non-negative: their f32 bits sort like their values.
            let residual = (hyp.residual_px.max(0.0) as f32).to_bits() as u128;
            let key = (u128::from(u32::MAX - support[h]) << 96)
                | ((4 - quarters) << 64)
                | (residual << 32)
                | h as u128;
            (key, h)
        })
        .collect();
    order.sort_unstable_by_key(|&(key, _)| key);
    Ok(order.into_iter().map(|(_, h)| h).collect())
}

/// Uniqueness: hypotheses claim their segments in `ranking` order, those not `alive` skipped;
/// one is dropped when it reuses a segment of an already accepted one, except as a fragment
/// of the same line. Returns the indices of the accepted ones, in input order.
pub fn select(
    views: &Views,
    hypotheses: &[Hypothesis],
    ranking: &[usize],
    alive: &[bool],
    params: &MatchParams,
) -> Vec<usize> {
    // Accepted hypotheses per segment, as linked lists (head per segment, next per accepted).
    let mut head: [Vec<u32>; 3] = std::array::from_fn(|v| vec![NONE; views.segments[v].len()]);
    let mut next: [Vec<u32>; 3] = std::array::from_fn(|_| vec![NONE; hypotheses.len()]);
    let mut accepted = Vec::new();
    for &h in ranking {
        if !alive[h] {
            continue;
        }
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

/// True when `a` and `b` cannot both be accepted: they share a segment and are not fragments
/// of one line ([`select`]'s rule).
pub fn conflict(views: &Views, a: &Hypothesis, b: &Hypothesis, params: &MatchParams) -> bool {
    (0..3).any(|v| a.segments[v] == b.segments[v]) && !fragments(views, a, b, params)
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
    adjacency: &[(u32, u32, Point2<f64>)],
    hypotheses: &[Hypothesis],
    params: &MatchParams,
    checkpoint: Checkpoint,
) -> Result<Vec<u32>, Stopped> {
    let s1 = views.segments[0];
    let mut support = vec![0u32; hypotheses.len()];
    if s1.is_empty() || hypotheses.is_empty() {
        return Ok(support);
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

    // Per shared vertex: each side's disparities there, sorted, so "has an agreeing
    // hypothesis across the vertex" is one binary search instead of a scan of the other side.
    let (mut da, mut db): (Vec<f64>, Vec<f64>) = (Vec::new(), Vec::new());
    let agrees = |sorted: &[f64], d: f64| {
        let i = sorted.partition_point(|&x| x < d - max_diff);
        i < sorted.len() && sorted[i] <= d + max_diff
    };
    for (n, &(a, b, vertex)) in adjacency.iter().enumerate() {
        if n % CHECK_EVERY == 0 {
            checkpoint.before("validate")?;
        }
        let (ra, rb) = (range[a as usize], range[b as usize]);
        if ra.0 == ra.1 || rb.0 == rb.1 {
            continue;
        }
        let (ta, tb) = (s1[a as usize].along(vertex), s1[b as usize].along(vertex));
        da.clear();
        da.extend((ra.0..ra.1).map(|h| hypotheses[h].disparity_at(ta)));
        db.clear();
        db.extend((rb.0..rb.1).map(|h| hypotheses[h].disparity_at(tb)));
        let (mut sa, mut sb) = (da.clone(), db.clone());
        sa.sort_unstable_by(f64::total_cmp);
        sb.sort_unstable_by(f64::total_cmp);
        for (h, &d) in (ra.0..ra.1).zip(&da) {
            support[h] += u32::from(agrees(&sb, d));
        }
        for (h, &d) in (rb.0..rb.1).zip(&db) {
            support[h] += u32::from(agrees(&sa, d));
        }
    }
    Ok(support)
}

/// The adjacency graph of view 1: pairs of distinct segments with endpoints within
/// `radius` (a shared vertex), each pair once, with the vertex (the midpoint of the two
/// closest endpoints). Endpoints sorted into a grid of `radius`-sized cells, and the bounds on
/// the ends looked at and kept per end, keep this linear in the number of segments.
pub fn adjacency(segments: &[RectSegment], radius: f64) -> Vec<(u32, u32, Point2<f64>)> {
    if radius <= 0.0 || segments.is_empty() {
        return Vec::new();
    }
    // Cells no smaller than a hundredth of a pixel: a radius of 1e-17 px would put every end
    // in a cell at i64::MAX (found by fuzzing), and larger cells only make the 3 x 3 search
    // look at a few more ends. An end that far out all the same (a rectified coordinate
    // past 10¹⁶ px) has its neighbouring cells found with saturating steps.
    let size = radius.max(MIN_CELL_PX);
    let cell = |p: Point2<f64>| ((p.x / size).floor() as i64, (p.y / size).floor() as i64);
    let mut ends: Vec<CellEnd> = segments
        .iter()
        .enumerate()
        .flat_map(|(i, s)| [(cell(s.a), i as u32, s.a), (cell(s.b), i as u32, s.b)])
        .collect();
    ends.sort_unstable_by_key(|e| (e.0, e.1));
    // The ends of one column of three cells are contiguous in (x, y) order: nothing sorts
    // between (x, y − 1), (x, y) and (x, y + 1). Each column's first and last are found by
    // cursors that move on as the ends are walked in that order (the cells asked rise with
    // them), so the whole walk reads the list a few times over instead of looking cells up.
    let mut first = [Cursor::default(); 3];
    let mut past = [Cursor::default(); 3];
    let mut found: Vec<(u32, u32, f64, Point2<f64>)> = Vec::new();
    let mut near: Vec<(f64, u32, Point2<f64>)> = Vec::new();
    for &((cx, cy), i, p) in &ends {
        near.clear();
        for (column, dx) in (-1..=1).enumerate() {
            let x = cx.saturating_add(dx);
            let lo = first[column].seek(&ends, (x, cy.saturating_sub(1)), false);
            let hi = past[column].seek(&ends, (x, cy.saturating_add(1)), true);
            if lo >= hi {
                continue;
            }
            for &(_, j, q) in ends[lo..hi].iter().take(MAX_ENDS_SCANNED_PER_COLUMN) {
                if j <= i {
                    continue;
                }
                let d = (q - p).norm();
                if d <= radius {
                    near.push((d, j, q));
                }
            }
        }
        if near.len() > MAX_NEIGHBOURS_PER_END {
            near.select_nth_unstable_by(MAX_NEIGHBOURS_PER_END, |a, b| a.0.total_cmp(&b.0));
            near.truncate(MAX_NEIGHBOURS_PER_END);
        }
        found.extend(
            near.iter()
                .map(|&(d, j, q)| (i, j, d, nalgebra::center(&p, &q))),
        );
    }
    // Keep the closest pair of endpoints of each pair of segments.
    found.sort_unstable_by(|a, b| (a.0, a.1).cmp(&(b.0, b.1)).then(a.2.total_cmp(&b.2)));
    found.dedup_by_key(|e| (e.0, e.1));
    found.into_iter().map(|(a, b, _, v)| (a, b, v)).collect()
}

/// An end of a segment in [`adjacency`]'s grid: its cell, its segment, its point.
type CellEnd = ((i64, i64), u32, Point2<f64>);

/// A position in a list of ends sorted by cell, moved on from the last cell asked.
#[derive(Debug, Clone, Copy, Default)]
struct Cursor {
    at: usize,
    cell: Option<(i64, i64)>,
}

impl Cursor {
    /// The first position in `ends` (sorted by cell) at or past `cell` (`past`: after it).
    /// Cells asked in rising order move the cursor over the list once in all; one lower than
    /// the last (a cell index saturated at the edge of `i64`, where a step no longer rises)
    /// is searched for.
    fn seek(&mut self, ends: &[CellEnd], cell: (i64, i64), past: bool) -> usize {
        let before = |e: &CellEnd| if past { e.0 <= cell } else { e.0 < cell };
        if self.cell.is_some_and(|last| cell < last) {
            self.at = ends.partition_point(before);
        } else {
            while self.at < ends.len() && before(&ends[self.at]) {
                self.at += 1;
            }
        }
        self.cell = Some(cell);
        self.at
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seg(ax: f64, ay: f64, bx: f64, by: f64, index: u32) -> RectSegment {
        RectSegment::new(Point2::new(ax, ay), Point2::new(bx, by), f64::NAN, index)
    }

    fn hyp(segments: [u32; 3], residual_px: f64, len: f64, disparity: f64) -> Hypothesis {
        Hypothesis {
            segments,
            residual_px,
            s1_span: (0.0, len),
            disparity: (disparity, disparity),
            frame: 0,
            depth_blind: false,
        }
    }

    fn rect() -> Rectification {
        Rectification::new(&crate::testing::preset_rig()).expect("rectifiable")
    }

    #[test]
    fn a_segment_goes_to_its_best_hypothesis_and_to_a_rival_once_that_one_is_dropped() {
        // Two parallel segments 10 px apart: rivals, not fragments of one line.
        let view: Vec<RectSegment> = (0..2)
            .map(|i| seg(10.0 * i as f64, 0.0, 10.0 * i as f64, 40.0, i))
            .collect();
        let views = Views {
            segments: [&view[..1], &view, &view],
            oriented: true,
        };
        let hyps = [
            hyp([0, 0, 0], 0.5, 40.0, 100.0),
            hyp([0, 1, 1], 0.1, 40.0, 150.0),
        ];
        let params = MatchParams::default();
        let rect = rect();
        assert_eq!(validate(&rect, &views, &[], &hyps, &params), vec![1]);
        let ranking = rank(&rect, &views, &[], &hyps, &params);
        assert_eq!(
            select(&views, &hyps, &ranking, &[true, false], &params),
            vec![0]
        );
        assert!(select(&views, &hyps, &ranking, &[false, false], &params).is_empty());
    }

    #[test]
    fn support_at_a_shared_vertex_outranks_a_smaller_residual() {
        // S1 segments 0 and 1 meet at (0, 40); hypothesis 0 of segment 0 and hypothesis 2 of
        // segment 1 agree on the disparity there, hypothesis 1 does not.
        let s1 = [seg(0.0, 0.0, 0.0, 40.0, 0), seg(0.0, 40.0, 40.0, 40.0, 1)];
        let other: Vec<RectSegment> = (0..3)
            .map(|i| seg(9.0 * i as f64, 0.0, 9.0 * i as f64, 40.0, i))
            .collect();
        let views = Views {
            segments: [&s1, &other, &other],
            oriented: true,
        };
        let hyps = [
            hyp([0, 0, 0], 0.9, 40.0, 100.0),
            hyp([0, 1, 1], 0.1, 40.0, 200.0),
            hyp([1, 2, 2], 0.5, 40.0, 100.0),
        ];
        let adjacency = adjacency(&s1, 8.0);
        assert_eq!(adjacency.len(), 1);
        let accepted = validate(&rect(), &views, &adjacency, &hyps, &MatchParams::default());
        assert_eq!(accepted, vec![0, 2]);
    }

    #[test]
    fn collinear_disjoint_fragments_share_a_segment_but_overlapping_ones_do_not() {
        let s1 = [seg(0.0, 0.0, 0.0, 100.0, 0)];
        let pieces = [
            seg(5.0, 0.0, 5.0, 45.0, 0),
            seg(5.0, 50.0, 5.0, 100.0, 1),
            seg(5.0, 30.0, 5.0, 80.0, 2),
        ];
        let whole = [seg(7.0, 0.0, 7.0, 100.0, 0)];
        let views = Views {
            segments: [&s1, &pieces, &whole],
            oriented: true,
        };
        let params = MatchParams::default();
        let fragments = [
            hyp([0, 0, 0], 0.2, 100.0, 100.0),
            hyp([0, 1, 0], 0.3, 100.0, 100.0),
        ];
        assert_eq!(
            validate(&rect(), &views, &[], &fragments, &params),
            vec![0, 1]
        );
        let overlapping = [
            hyp([0, 0, 0], 0.2, 100.0, 100.0),
            hyp([0, 2, 0], 0.3, 100.0, 100.0),
        ];
        assert_eq!(
            validate(&rect(), &views, &[], &overlapping, &params),
            vec![0]
        );
    }

    #[test]
    fn a_vanishing_neighbour_radius_still_finds_shared_ends() {
        // Found by fuzzing: 1e-17 px made the grid cells overflow.
        let segments = [
            seg(100.0, 100.0, 200.0, 100.0, 0),
            seg(200.0, 100.0, 200.0, 200.0, 1),
            seg(300.0, 300.0, 400.0, 300.0, 2),
        ];
        let pairs = adjacency(&segments, 1e-17);
        assert_eq!(pairs.len(), 1);
        assert_eq!((pairs[0].0, pairs[0].1), (0, 1));
    }

    #[test]
    fn shared_ends_are_every_pair_of_ends_within_the_radius_however_far_out() {
        // Scattered segments and, at the edge of i64's cells, a few more: the cursors walk
        // the cells in order and must find what comparing every pair of ends finds.
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut uniform = |range: f64| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * range
        };
        let mut segments: Vec<RectSegment> = (0..300)
            .map(|i| {
                let (x, y) = (uniform(300.0), uniform(300.0));
                seg(x, y, x + uniform(40.0) - 20.0, y + uniform(40.0) - 20.0, i)
            })
            .collect();
        for (k, (x, y)) in [(1e30, 5.0), (1e30, 9.0), (-1e30, 1e30), (-1e30, 1e30 + 3.0)]
            .into_iter()
            .enumerate()
        {
            segments.push(seg(x, y, x + 50.0, y, 300 + k as u32));
        }
        let radius = 6.0;
        let mut expected = Vec::new();
        for i in 0..segments.len() {
            for j in i + 1..segments.len() {
                let (a, b) = (&segments[i], &segments[j]);
                let closest = [(a.a, b.a), (a.a, b.b), (a.b, b.a), (a.b, b.b)]
                    .into_iter()
                    .map(|(p, q)| ((q - p).norm(), nalgebra::center(&p, &q)))
                    .min_by(|x, y| x.0.total_cmp(&y.0))
                    .expect("four pairs");
                if closest.0 <= radius {
                    expected.push((i as u32, j as u32, closest.1));
                }
            }
        }
        let found = adjacency(&segments, radius);
        assert!(expected.len() > 100, "{} pairs", expected.len());
        assert_eq!(found.len(), expected.len());
        for (f, e) in found.iter().zip(&expected) {
            assert_eq!((f.0, f.1), (e.0, e.1));
            assert!((f.2 - e.2).norm() <= 1e-9 * (1.0 + e.2.coords.abs().max()));
        }
    }
}
