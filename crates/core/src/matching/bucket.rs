//! Buckets (DESIGN §2.3): a grid of square windows over one rectified view, in a frame
//! turned so that x runs along one pair's epipolar direction; each window lists the segments
//! crossing it sorted by orientation, so "segments near here with orientation in this range"
//! is two binary searches per window. Built in O(n log n).
//!
//! Aligning the grid with the epipolar direction makes the disparity search of a segment a
//! band of rows, and the window of each row an interval of columns.

use std::f64::consts::PI;

use nalgebra::{Point2, Vector2};

use super::RectSegment;
use crate::checkpoint::{never_stopped, Checkpoint, Stopped};

/// Target number of segments per window: small enough that a window's orientation range holds
/// a handful of candidates, large enough that a search touches few windows.
const SEGMENTS_PER_CELL: f64 = 3.0;
/// Bounds on the window side, rectified pixels.
const MIN_CELL_PX: f64 = 8.0;
const MAX_CELL_PX: f64 = 64.0;
/// Windows are this many times longer along the epipolar direction than across it: a
/// disparity search is a long band along it, which then crosses few windows.
const CELL_ASPECT: f64 = 4.0;
/// Bound on the number of windows, so a few far-flung segments cannot blow up memory.
const MAX_CELLS: usize = 1 << 16;
/// Bound on the windows a segment is registered in, on average over a view: 1.5–2.6 in the
/// rooms and on a 1536 × 1024 photograph, 35 for a crowd of long random segments (the windows
/// then grow until it holds).
const MAX_ENTRIES_PER_SEGMENT: usize = 8;

#[derive(Debug, Clone, Copy)]
struct Entry {
    angle: f64,
    segment: u32,
}

pub use crate::angle::{
    angle_diff, angle_key, approx_angle_key, approx_atan, APPROX_ANGLE_KEY_ERROR,
};

#[derive(Debug, Clone)]
pub struct Buckets {
    /// Unit x axis of the turned frame (the epipolar direction), in rectified pixels.
    axis: Vector2<f64>,
    x0: f64,
    y0: f64,
    /// Window size across the epipolar direction (y) and along it (x).
    cell: f64,
    cell_x: f64,
    nx: usize,
    ny: usize,
    offsets: Vec<u32>,
    entries: Vec<Entry>,
    /// Each entry's segment's line, beside `entries` (same index): its unit normal and its
    /// offset along it, so that a verification rejects a segment whose line is far from the
    /// prediction without reading the segment itself.
    lines: Vec<EntryLine>,
    period: f64,
}

/// A segment's line as n·p = offset, n = (dir.y, −dir.x): n·p − offset is
/// [`RectSegment::line_distance`] up to rounding.
#[derive(Debug, Clone, Copy)]
struct EntryLine {
    normal: Vector2<f64>,
    offset: f64,
}

impl EntryLine {
    fn of(s: &RectSegment) -> EntryLine {
        let normal = Vector2::new(s.dir.y, -s.dir.x);
        EntryLine {
            normal,
            offset: normal.dot(&s.a.coords),
        }
    }
}

/// Segments, entries or cells [`Buckets::build_until`] handles between two checkpoints.
const CHECK_EVERY: usize = 4096;

impl Buckets {
    /// Turned-frame coordinates of a rectified point.
    #[inline]
    pub fn frame(&self, p: Point2<f64>) -> (f64, f64) {
        frame(self.axis, p)
    }

    /// Builds the buckets of `segments`, each registered in every window its path, widened by
    /// `slack_px`, crosses.
    pub fn build(segments: &[RectSegment], axis: Vector2<f64>, slack_px: f64, period: f64) -> Self {
        never_stopped(Self::build_until(
            segments,
            axis,
            slack_px,
            period,
            Checkpoint::NEVER,
        ))
    }

    /// [`Buckets::build`], asking `checkpoint` every [`CHECK_EVERY`] segments and cells: a
    /// list of the most segments a request may send, long ones at that, takes a good part of a
    /// second to bucket in a test build (tests/hostile, a crowd at its deadline).
    pub fn build_until(
        segments: &[RectSegment],
        axis: Vector2<f64>,
        slack_px: f64,
        period: f64,
        checkpoint: Checkpoint,
    ) -> Result<Self, Stopped> {
        let check = |i: usize| {
            if i.is_multiple_of(CHECK_EVERY) {
                checkpoint.before("predict")
            } else {
                Ok(())
            }
        };
        let axis = axis.normalize();
        let (mut xmin, mut ymin, mut xmax, mut ymax) = (
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        );
        for s in segments {
            for p in [s.a, s.b] {
                let (x, y) = frame(axis, p);
                xmin = xmin.min(x);
                xmax = xmax.max(x);
                ymin = ymin.min(y);
                ymax = ymax.max(y);
            }
        }
        if segments.is_empty() {
            (xmin, ymin, xmax, ymax) = (0.0, 0.0, 1.0, 1.0);
        }
        let (x0, y0) = (xmin - slack_px - 1.0, ymin - slack_px - 1.0);
        let (w, h) = (xmax + slack_px + 1.0 - x0, ymax + slack_px + 1.0 - y0);
        let mut cell = (w * h * SEGMENTS_PER_CELL / segments.len().max(1) as f64)
            .sqrt()
            .clamp(MIN_CELL_PX, MAX_CELL_PX);
        let mut cell_x = cell * CELL_ASPECT;
        while (w / cell_x).ceil() * (h / cell).ceil() > MAX_CELLS as f64 {
            cell *= 1.5;
            cell_x *= 1.5;
        }
        // Each segment's path is walked once, its windows noted, and the notes then placed by
        // window (a counting sort) into one flat allocation. A crowd of long segments crosses
        // many windows each (a hundred thousand segments across a 512-px image: 35 windows
        // each, half a gigabyte of entries): past [`MAX_ENTRIES_PER_SEGMENT`] on average the
        // walk stops and the windows are made twice as large, so a request's memory grows with
        // its segments, not with their lengths. Which windows hold a segment changes what a
        // search reads, not what it finds.
        let cap = MAX_ENTRIES_PER_SEGMENT * (segments.len() + 1);
        let mut placed: Vec<(u32, u32)> = Vec::with_capacity(2 * segments.len());
        let mut grid = loop {
            let nx = ((w / cell_x).ceil() as usize).max(1);
            let ny = ((h / cell).ceil() as usize).max(1);
            let grid = Buckets {
                axis,
                x0,
                y0,
                cell,
                cell_x,
                nx,
                ny,
                offsets: Vec::new(),
                entries: Vec::new(),
                lines: Vec::new(),
                period,
            };
            placed.clear();
            for (i, s) in segments.iter().enumerate() {
                check(i)?;
                grid.for_each_cell_on_path(s.a, s.b, slack_px, |cx, cy| {
                    placed.push(((cy * nx + cx) as u32, i as u32));
                });
                if placed.len() > cap {
                    break;
                }
            }
            if placed.len() <= cap {
                break grid;
            }
            cell *= 2.0;
            cell_x *= 2.0;
        };
        let (nx, ny) = (grid.nx, grid.ny);
        let mut offsets = vec![0u32; nx * ny + 1];
        for &(c, _) in &placed {
            offsets[c as usize + 1] += 1;
        }
        for c in 0..nx * ny {
            offsets[c + 1] += offsets[c];
        }
        let mut cursor = offsets.clone();
        let mut entries = vec![
            Entry {
                angle: 0.0,
                segment: 0
            };
            placed.len()
        ];
        let angles: Vec<f64> = segments.iter().map(|s| angle_key(s.dir, period)).collect();
        for (n, &(c, i)) in placed.iter().enumerate() {
            check(n)?;
            let slot = &mut cursor[c as usize];
            entries[*slot as usize] = Entry {
                angle: angles[i as usize],
                segment: i,
            };
            *slot += 1;
        }
        for c in 0..nx * ny {
            check(c)?;
            entries[offsets[c] as usize..offsets[c + 1] as usize].sort_unstable_by(|a, b| {
                a.angle.total_cmp(&b.angle).then(a.segment.cmp(&b.segment))
            });
        }
        grid.lines = entries
            .iter()
            .map(|e| EntryLine::of(&segments[e.segment as usize]))
            .collect();
        grid.offsets = offsets;
        grid.entries = entries;
        Ok(grid)
    }

    /// Calls `visit(cx, cy)` for every window that the segment `a`–`b`, widened by `slack`,
    /// touches: per row band, the column interval the segment spans there.
    pub fn for_each_cell_on_path(
        &self,
        a: Point2<f64>,
        b: Point2<f64>,
        slack: f64,
        mut visit: impl FnMut(usize, usize),
    ) {
        let (ax, ay) = self.frame(a);
        let (bx, by) = self.frame(b);
        let (ylo, yhi) = (ay.min(by) - slack, ay.max(by) + slack);
        let Some((r0, r1)) = self.index_range(ylo, yhi, self.y0, self.cell, self.ny) else {
            return;
        };
        for cy in r0..=r1 {
            let band_lo = (self.y0 + cy as f64 * self.cell).max(ylo) - slack;
            let band_hi = (self.y0 + (cy + 1) as f64 * self.cell).min(yhi) + slack;
            let (xa, xb) = x_span(ax, ay, bx, by, band_lo, band_hi);
            if let Some((c0, c1)) =
                self.index_range(xa - slack, xb + slack, self.x0, self.cell_x, self.nx)
            {
                for cx in c0..=c1 {
                    visit(cx, cy);
                }
            }
        }
    }

    /// The window row range covering turned-frame y in `[lo, hi]`.
    pub fn rows(&self, lo: f64, hi: f64) -> Option<(usize, usize)> {
        self.index_range(lo, hi, self.y0, self.cell, self.ny)
    }

    /// The window column range covering turned-frame x in `[lo, hi]`.
    pub fn columns(&self, lo: f64, hi: f64) -> Option<(usize, usize)> {
        self.index_range(lo, hi, self.x0, self.cell_x, self.nx)
    }

    /// Turned-frame y interval of window row `cy`.
    pub fn row_span(&self, cy: usize) -> (f64, f64) {
        let lo = self.y0 + cy as f64 * self.cell;
        (lo, lo + self.cell)
    }

    fn index_range(
        &self,
        lo: f64,
        hi: f64,
        origin: f64,
        cell: f64,
        n: usize,
    ) -> Option<(usize, usize)> {
        let (lo, hi) = ((lo - origin) / cell, (hi - origin) / cell);
        if lo.is_nan() || hi.is_nan() {
            return None;
        }
        // In integers from here: a float's conversion to usize is several instructions
        // more than to i64, and every window walk makes two per row.
        let (a, b) = (floor_index(lo), floor_index(hi));
        if b < 0 || a >= n as i64 || b < a {
            return None;
        }
        Some((a.max(0) as usize, (b as usize).min(n - 1)))
    }

    /// Calls `visit(segment)` for the segments of window `(cx, cy)` whose angle key lies
    /// within `tolerance` of `angle` (wrapping around the period).
    #[inline]
    pub fn for_each_in_cell(
        &self,
        cx: usize,
        cy: usize,
        angle: f64,
        tolerance: f64,
        mut visit: impl FnMut(u32),
    ) {
        self.for_each_entry_in_cell(cy * self.nx + cx, angle, tolerance, |_, s| visit(s));
    }

    /// Calls `visit(i, segment)` for the entries of window `c` whose angle key lies within
    /// `tolerance` of `angle`, `i` the entry's index within the window.
    #[inline]
    fn for_each_entry_in_cell(
        &self,
        c: usize,
        angle: f64,
        tolerance: f64,
        mut visit: impl FnMut(usize, u32),
    ) {
        let cell = &self.entries[self.offsets[c] as usize..self.offsets[c + 1] as usize];
        if cell.is_empty() {
            return;
        }
        if tolerance * 2.0 >= self.period {
            cell.iter()
                .enumerate()
                .for_each(|(i, e)| visit(i, e.segment));
            return;
        }
        let lo = angle - tolerance;
        let hi = angle + tolerance;
        let mut scan = |lo: f64, hi: f64| {
            let start = cell.partition_point(|e| e.angle < lo);
            for (i, e) in cell[start..].iter().enumerate() {
                if e.angle > hi {
                    break;
                }
                visit(start + i, e.segment);
            }
        };
        if lo < 0.0 {
            scan(lo + self.period, self.period);
            scan(0.0, hi);
        } else if hi >= self.period {
            scan(lo, self.period);
            scan(0.0, hi - self.period);
        } else {
            scan(lo, hi);
        }
    }
}

impl Buckets {
    /// [`Buckets::for_each_in_cell`], skipping the segments whose line passes farther than
    /// `distance` from both `q0` and `q1` on the same side: no point of the segment `q0`–`q1`
    /// is then within `distance` of that line (the distance along it is affine). Exact up to a
    /// rounding margin in the skipping's favour of keeping, so a caller that tests the
    /// distances itself gets the same segments it would accept from `for_each_in_cell`.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub fn for_each_in_cell_near(
        &self,
        cx: usize,
        cy: usize,
        angle: f64,
        tolerance: f64,
        (q0, q1): (Point2<f64>, Point2<f64>),
        distance: f64,
        mut visit: impl FnMut(u32),
    ) {
        let c = cy * self.nx + cx;
        let start = self.offsets[c] as usize;
        let lines = &self.lines[start..self.offsets[c + 1] as usize];
        // The margin covers the difference between n·p − offset here and the caller's
        // n·(p − a): a few ulps of the coordinates.
        let limit = distance + 1e-9 * (1.0 + q0.coords.abs().max() + q1.coords.abs().max());
        self.for_each_entry_in_cell(c, angle, tolerance, |i, segment| {
            let line = &lines[i];
            let da = line.normal.dot(&q0.coords) - line.offset;
            let db = line.normal.dot(&q1.coords) - line.offset;
            if (da > limit && db > limit) || (da < -limit && db < -limit) {
                return;
            }
            visit(segment);
        });
    }
}

/// `x.floor()` as an integer, by a round trip through one: on x86-64 without SSE4.1 (the
/// baseline the service is built for) `f64::floor` is a library call, and the searches take
/// several per segment. Exact for |x| < 2⁶³; beyond it, saturated, on the same side of every
/// grid as the true floor. Not for NaN, which the caller rules out.
#[inline]
fn floor_index(x: f64) -> i64 {
    let t = x as i64;
    if t as f64 > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

#[inline]
fn frame(axis: Vector2<f64>, p: Point2<f64>) -> (f64, f64) {
    (axis.x * p.x + axis.y * p.y, -axis.y * p.x + axis.x * p.y)
}

/// The x interval of segment (ax, ay)–(bx, by) restricted to y in `[lo, hi]`.
fn x_span(ax: f64, ay: f64, bx: f64, by: f64, lo: f64, hi: f64) -> (f64, f64) {
    let dy = by - ay;
    if dy.abs() < 1e-12 {
        return (ax.min(bx), ax.max(bx));
    }
    let at = |y: f64| {
        let t = ((y - ay) / dy).clamp(0.0, 1.0);
        ax + t * (bx - ax)
    };
    let (p, q) = (at(lo), at(hi));
    (p.min(q), p.max(q))
}

/// Full turn for oriented segments, half turn for unoriented ones.
pub fn period(oriented: bool) -> f64 {
    if oriented {
        2.0 * PI
    } else {
        PI
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seg(ax: f64, ay: f64, bx: f64, by: f64) -> RectSegment {
        RectSegment::new(Point2::new(ax, ay), Point2::new(bx, by), f64::NAN, 0)
    }

    #[test]
    fn a_build_stops_when_its_result_is_no_longer_wanted() {
        let segments: Vec<RectSegment> = (0..3 * CHECK_EVERY)
            .map(|i| {
                let x = (i % 500) as f64;
                seg(x, (i / 500) as f64, x + 40.0, (i / 500) as f64 + 3.0)
            })
            .collect();
        let axis = Vector2::new(1.0, 0.0);
        let gone = || true;
        let stopped = Buckets::build_until(&segments, axis, 1.0, PI, Checkpoint::new(&gone));
        assert!(stopped.is_err());
        // Asked and wanted: the buckets `build` gives.
        let calls = std::sync::atomic::AtomicUsize::new(0);
        let wanted = || {
            calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            false
        };
        let built = Buckets::build_until(&segments, axis, 1.0, PI, Checkpoint::new(&wanted))
            .expect("wanted");
        let plain = Buckets::build(&segments, axis, 1.0, PI);
        assert_eq!(built.entries.len(), plain.entries.len());
        assert_eq!(built.offsets, plain.offsets);
        assert!(
            calls.into_inner() >= 6,
            "asked once per {CHECK_EVERY} segments and per {CHECK_EVERY} entries placed"
        );
    }

    #[test]
    fn floor_agrees_with_the_library() {
        for x in [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.999,
            -2.999,
            1e15 + 0.5,
            -1e15 - 0.5,
            4.5e18,
            -4.5e18,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
        ] {
            assert_eq!(floor_index(x) as f64, x.floor(), "{x}");
        }
        // Out of i64's range: saturated, on the right side of every grid.
        assert_eq!(floor_index(1e300), i64::MAX);
        assert_eq!(floor_index(-1e300), i64::MIN);
        assert_eq!(floor_index(f64::INFINITY), i64::MAX);
        assert_eq!(floor_index(f64::NEG_INFINITY), i64::MIN);
    }

    #[test]
    fn window_ranges_are_the_floors_of_their_bounds() {
        // The ranges as first written, in floats with the library's floor.
        let reference = |lo: f64, hi: f64, origin: f64, cell: f64, n: usize| {
            let (a, b) = (
                ((lo - origin) / cell).floor(),
                ((hi - origin) / cell).floor(),
            );
            if a.is_nan() || b.is_nan() || b < 0.0 || a >= n as f64 || b < a {
                None
            } else {
                Some((a.max(0.0) as usize, (b as usize).min(n - 1)))
            }
        };
        let grid = Buckets::build(&[seg(0.0, 0.0, 100.0, 50.0)], Vector2::x(), 1.0, PI);
        let mut bounds = vec![
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            1e300,
            -1e300,
            1e19,
            -1e19,
        ];
        // Around every window boundary of a 7-window axis, on it and either side of it.
        for k in -3..=10 {
            let at = -4.0 + 12.5 * k as f64;
            bounds.extend([at, at - 1e-9, at + 1e-9, at + 6.25]);
        }
        for &lo in &bounds {
            for &hi in &bounds {
                assert_eq!(
                    grid.index_range(lo, hi, -4.0, 12.5, 7),
                    reference(lo, hi, -4.0, 12.5, 7),
                    "[{lo}, {hi}]"
                );
            }
        }
    }

    /// A crowd of long segments (3,000 across a 512-px image, 35 windows each at the windows'
    /// first size) grows its windows until each segment is in at most eight on average, and
    /// every segment is still found where it lies.
    #[test]
    fn a_crowd_of_long_segments_grows_the_windows_not_the_entries() {
        let mut rng = trinocular_synth::Rng::new(0x2545_f491_4f6c_dd1d);
        let mut next = || rng.range(0.0, 511.0);
        let segs: Vec<RectSegment> = (0..3000)
            .map(|_| seg(next(), next(), next(), next()))
            .filter(|s| s.len > 1.0)
            .collect();
        let b = Buckets::build(&segs, Vector2::new(1.0, 0.0), 1.0, period(true));
        assert!(b.entries.len() <= MAX_ENTRIES_PER_SEGMENT * (segs.len() + 1));
        let grown = b.cell;
        for (i, s) in segs.iter().enumerate() {
            let mut found = false;
            b.for_each_cell_on_path(s.a, s.b, 0.0, |cx, cy| {
                b.for_each_in_cell(cx, cy, angle_key(s.dir, period(true)), 1e-9, |k| {
                    found |= k as usize == i
                });
            });
            assert!(found, "segment {i}");
        }
        // A scene's segments as many over the same image, a few windows each, keep the
        // windows' first size, about half the grown ones.
        let short: Vec<RectSegment> = (0..segs.len())
            .map(|_| {
                let (x, y) = (next(), next());
                seg(x, y, x + 20.0, y + 10.0)
            })
            .collect();
        let b = Buckets::build(&short, Vector2::new(1.0, 0.0), 1.0, period(true));
        assert!(b.entries.len() <= 3 * short.len());
        assert!(grown > 1.5 * b.cell, "{grown} against {}", b.cell);
    }

    #[test]
    fn finds_segments_by_place_and_orientation() {
        let segs = vec![
            seg(0.0, 0.0, 100.0, 0.0),
            seg(50.0, -40.0, 50.0, 40.0),
            seg(200.0, 200.0, 260.0, 260.0),
        ];
        let b = Buckets::build(&segs, Vector2::new(1.0, 0.0), 1.0, period(true));
        let mut found = Vec::new();
        b.for_each_cell_on_path(
            Point2::new(40.0, -5.0),
            Point2::new(60.0, 5.0),
            0.0,
            |cx, cy| {
                b.for_each_in_cell(cx, cy, PI / 2.0, 0.1, |s| found.push(s));
            },
        );
        found.sort();
        found.dedup();
        assert_eq!(found, vec![1]);
        let mut found = Vec::new();
        b.for_each_cell_on_path(
            Point2::new(230.0, 230.0),
            Point2::new(231.0, 231.0),
            0.0,
            |cx, cy| {
                b.for_each_in_cell(cx, cy, PI / 4.0, 0.1, |s| found.push(s));
            },
        );
        assert!(found.contains(&2) && !found.contains(&0));
    }

    #[test]
    fn the_near_windows_skip_only_lines_far_from_the_whole_query() {
        // Random segments and queries: `for_each_in_cell_near` gives what `for_each_in_cell`
        // gives less the segments whose line is beyond the distance at both ends of the query
        // on one side, computed as the matcher does (`line_distance`).
        let mut rng = trinocular_synth::Rng::new(11);
        let mut uniform = |lo: f64, hi: f64| rng.range(lo, hi);
        let segs: Vec<RectSegment> = (0..300)
            .map(|_| {
                let (x, y) = (uniform(0.0, 200.0), uniform(0.0, 200.0));
                let (dx, dy) = (uniform(-30.0, 30.0), uniform(-30.0, 30.0));
                seg(x, y, x + dx, y + dy)
            })
            .collect();
        let b = Buckets::build(&segs, Vector2::new(0.8, 0.6), 2.0, period(true));
        let mut skipped = 0;
        for _ in 0..300 {
            let q0 = Point2::new(uniform(0.0, 200.0), uniform(0.0, 200.0));
            let q1 = q0 + Vector2::new(uniform(-40.0, 40.0), uniform(-40.0, 40.0));
            let (angle, tolerance, distance) = (uniform(0.0, 2.0 * PI), uniform(0.0, 1.0), 2.0);
            let (mut all, mut near) = (Vec::new(), Vec::new());
            b.for_each_cell_on_path(q0, q1, distance, |cx, cy| {
                b.for_each_in_cell(cx, cy, angle, tolerance, |s| all.push(s));
                b.for_each_in_cell_near(cx, cy, angle, tolerance, (q0, q1), distance, |s| {
                    near.push(s)
                });
            });
            let expected: Vec<u32> = all
                .iter()
                .copied()
                .filter(|&s| {
                    let sk = &segs[s as usize];
                    let (da, db) = (sk.line_distance(q0), sk.line_distance(q1));
                    !((da > distance && db > distance) || (da < -distance && db < -distance))
                })
                .collect();
            skipped += all.len() - near.len();
            assert_eq!(near, expected);
        }
        assert!(
            skipped > 1000,
            "the test must exercise the skipping: {skipped}"
        );
    }

    #[test]
    fn angle_window_wraps() {
        let segs = vec![seg(0.0, 0.0, 10.0, -0.1), seg(0.0, 0.0, 10.0, 0.1)];
        let b = Buckets::build(&segs, Vector2::new(1.0, 0.0), 1.0, period(true));
        let mut found = Vec::new();
        b.for_each_cell_on_path(
            Point2::new(0.0, 0.0),
            Point2::new(10.0, 0.0),
            1.0,
            |cx, cy| {
                b.for_each_in_cell(cx, cy, 0.0, 0.05, |s| found.push(s));
            },
        );
        found.sort();
        found.dedup();
        assert_eq!(found, vec![0, 1]);
        assert!((angle_diff(0.01, 2.0 * PI - 0.01, 2.0 * PI) - 0.02).abs() < 1e-12);
    }
}
