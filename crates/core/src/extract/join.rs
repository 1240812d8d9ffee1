//! Pieces of one straight edge that chaining left apart, joined back into one segment.
//!
//! A chain stops where edges meet: at a T-junction the bar's chain is cut by the pixels the
//! stem takes, at a crossing both are, and a dip in contrast breaks a long edge into runs.
//! Each piece is then a short segment whose direction the matcher's gate rightly doubts,
//! although the image holds the whole edge. Here two pieces are joined when they follow one
//! another along the same direction with the same contrast (their orientations agree), the
//! gap between them is a few pixels, and one line fitted to all their edge points passes
//! within `max_offset_px` of every piece's ends (the chains' own test for one line, on the
//! pieces' ends rather than on every point). Greedy, smallest gap first; each piece has at
//! most one successor and one predecessor, so a group is a run along one line.

use nalgebra::Point2;
use rustc_hash::FxHashMap;

use super::polygon::{MomentFit, Moments};

/// A piece to join: its ends, oriented by contrast (DESIGN §1), and its fitted points' sums.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Part {
    pub start: Point2<f64>,
    pub end: Point2<f64>,
    pub moments: Moments,
}

/// How far apart two pieces of one line may lie.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Largest gap along the line between one piece's end and the next one's start, pixels.
    pub max_gap_px: f64,
    /// Largest distance of any piece's end from the joined line, pixels.
    pub max_offset_px: f64,
}

/// Pieces may overlap by this much along the line (their ends were each projected from a
/// rounded junction); more is two edges side by side, not one edge cut.
const MAX_OVERLAP_PX: f64 = 1.0;
/// Pieces whose directions differ by more than this are not one line (cos 5°): a cheap test
/// before the joint fit decides.
const MIN_DIRECTION_COS: f64 = 0.996_194_698;
/// A part shorter than this has no direction to follow.
const MIN_LENGTH_PX: f64 = 1e-9;

/// A run of parts that are one line, in order along it.
#[derive(Debug, Clone, PartialEq)]
pub struct Group {
    pub members: Vec<u32>,
    /// The line fitted to all the members' points: `Some` for two or more members.
    pub fit: Option<MomentFit>,
}

impl Group {
    /// The joined segment's ends: the outer ends of its first and last parts projected onto
    /// its line (a single part's own ends).
    pub fn ends(&self, parts: &[Part]) -> (Point2<f64>, Point2<f64>) {
        let first = &parts[self.members[0] as usize];
        let last = &parts[self.members[self.members.len() - 1] as usize];
        match &self.fit {
            Some(fit) => (fit.line.project(first.start), fit.line.project(last.end)),
            None => (first.start, first.end),
        }
    }
}

/// The groups of `parts` that are one line, each in order along it; every part is in exactly
/// one group, groups in the order of their lowest part.
pub fn join(parts: &[Part], limits: Limits) -> Vec<Group> {
    let candidates = follow_ons(parts, limits);
    let n = parts.len();
    let mut next = vec![u32::MAX; n];
    let mut prev = vec![u32::MAX; n];
    // Union by relabelling: each group keeps its members in order along the line.
    let mut group_of: Vec<u32> = (0..n as u32).collect();
    let mut members: Vec<Vec<u32>> = (0..n as u32).map(|i| vec![i]).collect();
    let mut sums: Vec<Moments> = parts.iter().map(|p| p.moments).collect();
    let mut fits: Vec<Option<MomentFit>> = vec![None; n];
    for (_, i, j) in candidates {
        let (i, j) = (i as usize, j as usize);
        let (gi, gj) = (group_of[i] as usize, group_of[j] as usize);
        if next[i] != u32::MAX || prev[j] != u32::MAX || gi == gj {
            continue;
        }
        let joined = sums[gi].add(&sums[gj]);
        let Some(fit) = joined.fit(parts[i].end - parts[i].start) else {
            continue;
        };
        let within = |g: usize| {
            members[g].iter().all(|&k| {
                let p = &parts[k as usize];
                fit.line.distance(p.start).abs() <= limits.max_offset_px
                    && fit.line.distance(p.end).abs() <= limits.max_offset_px
            })
        };
        if !(within(gi) && within(gj)) {
            continue;
        }
        next[i] = j as u32;
        prev[j] = i as u32;
        let moved = std::mem::take(&mut members[gj]);
        for &k in &moved {
            group_of[k as usize] = gi as u32;
        }
        members[gi].extend(moved);
        sums[gi] = joined;
        fits[gi] = Some(fit);
    }
    let mut groups = Vec::new();
    for (head, &before) in prev.iter().enumerate() {
        if before != u32::MAX {
            continue;
        }
        let mut run = vec![head as u32];
        let mut k = head;
        while next[k] != u32::MAX {
            k = next[k] as usize;
            run.push(k as u32);
        }
        groups.push(Group {
            members: run,
            fit: fits[group_of[head] as usize],
        });
    }
    groups.sort_by_key(|g| g.members.iter().copied().min());
    groups
}

/// Every ordered pair (i, j) where j could continue i: j starts within the gap after i's end,
/// beside i's line and along its direction. Sorted by gap, then by the sideways offset.
fn follow_ons(parts: &[Part], limits: Limits) -> Vec<(f64, u32, u32)> {
    let reach = limits.max_gap_px.max(MAX_OVERLAP_PX) + 2.0 * limits.max_offset_px;
    let cell_px = reach.max(1.0);
    let cell = |p: Point2<f64>| {
        (
            (p.x / cell_px).floor() as i64,
            (p.y / cell_px).floor() as i64,
        )
    };
    let mut starts: FxHashMap<(i64, i64), Vec<u32>> = FxHashMap::default();
    for (k, part) in parts.iter().enumerate() {
        starts.entry(cell(part.start)).or_default().push(k as u32);
    }
    let mut pairs = Vec::new();
    for (i, part) in parts.iter().enumerate() {
        let Some(u) = (part.end - part.start).try_normalize(MIN_LENGTH_PX) else {
            continue;
        };
        let (cx, cy) = cell(part.end);
        for dx in -1..=1 {
            for dy in -1..=1 {
                let Some(list) = starts.get(&(cx + dx, cy + dy)) else {
                    continue;
                };
                for &j in list {
                    if j as usize == i {
                        continue;
                    }
                    let other = &parts[j as usize];
                    let Some(v) = (other.end - other.start).try_normalize(MIN_LENGTH_PX) else {
                        continue;
                    };
                    if u.dot(&v) < MIN_DIRECTION_COS {
                        continue;
                    }
                    let d = other.start - part.end;
                    let along = d.dot(&u);
                    let across = d.perp(&u).abs();
                    if along >= -MAX_OVERLAP_PX
                        && along <= limits.max_gap_px
                        && across <= 2.0 * limits.max_offset_px
                    {
                        pairs.push((along.max(0.0) + across, i as u32, j));
                    }
                }
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;

    fn part(points: &[(f64, f64)]) -> Part {
        let pts: Vec<Point2<f64>> = points.iter().map(|&(x, y)| Point2::new(x, y)).collect();
        Part {
            start: pts[0],
            end: pts[pts.len() - 1],
            moments: Moments::of(&pts),
        }
    }

    /// Points along v = slope·u + offset from u0 to u1, one per pixel.
    fn run(u0: f64, u1: f64, slope: f64, offset: f64) -> Part {
        let n = (u1 - u0).round() as usize;
        let pts: Vec<(f64, f64)> = (0..=n)
            .map(|k| {
                let u = u0 + (u1 - u0) * k as f64 / n as f64;
                (u, slope * u + offset)
            })
            .collect();
        part(&pts)
    }

    fn members(groups: &[Group]) -> Vec<Vec<u32>> {
        groups.iter().map(|g| g.members.clone()).collect()
    }

    const LIMITS: Limits = Limits {
        max_gap_px: 4.0,
        max_offset_px: 0.5,
    };

    #[test]
    fn pieces_of_one_line_cut_by_junctions_are_joined_in_order() {
        // One edge cut twice, listed out of order; and an unrelated piece.
        let parts = [
            run(23.0, 40.0, 0.1, 5.0),
            run(0.0, 10.0, 0.1, 5.0),
            run(50.0, 60.0, -3.0, 0.0),
            run(13.0, 20.0, 0.1, 5.0),
        ];
        let groups = join(&parts, LIMITS);
        assert_eq!(members(&groups), vec![vec![1, 3, 0], vec![2]]);
        let (start, end) = groups[0].ends(&parts);
        assert!((start - Point2::new(0.0, 5.0)).norm() < 1e-9);
        assert!((end - Point2::new(40.0, 9.0)).norm() < 1e-9);
        assert!(groups[0].fit.unwrap().across_px2 < 1e-18);
    }

    #[test]
    fn edges_that_are_not_one_line_stay_apart() {
        let base = run(0.0, 20.0, 0.0, 0.0);
        let cases = [
            // Beyond the gap.
            run(25.0, 45.0, 0.0, 0.0),
            // Parallel, a pixel and a half aside (a step of one pixel is within the
            // chains' own tolerance for one line).
            run(22.0, 42.0, 0.0, 1.5),
            // Opposite contrast: the same line walked the other way.
            part(&[(42.0, 0.0), (22.0, 0.0)]),
            // Side by side, overlapping.
            run(15.0, 35.0, 0.0, 0.3),
            // A bend of 5°: collinear at the gap, not over the length.
            run(22.0, 62.0, 0.0875, -22.0 * 0.0875),
        ];
        for (k, other) in cases.into_iter().enumerate() {
            let groups = join(&[base, other], LIMITS);
            assert_eq!(groups.len(), 2, "case {k}: {groups:?}");
        }
    }

    #[test]
    fn a_piece_continues_only_one_other() {
        // Two candidates for the same continuation: the nearer wins, the other stays alone.
        let parts = [
            run(0.0, 20.0, 0.0, 0.0),
            run(23.0, 40.0, 0.0, 0.1),
            run(21.0, 30.0, 0.0, 0.0),
        ];
        let groups = join(&parts, LIMITS);
        assert_eq!(members(&groups), vec![vec![0, 2], vec![1]]);
    }
}
