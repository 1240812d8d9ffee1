//! Finding the pattern's reference points in one image: the 2D half of the 3D–2D
//! correspondences calibration needs.
//!
//! ```text
//! extract (oriented segments) ─▶ dark quadrilaterals ─▶ lattices (grow by prediction)
//!   ─▶ which board, which way round (layout + missing cells + handedness) ─▶ refined corners
//! ```
//!
//! - **Quadrilaterals.** Around a dark square every segment has the bright side on its left,
//!   so the outline is a loop walked one way round (turning right on screen). From each
//!   segment we follow the segment that starts nearest its end and turns right (or carries
//!   on straight: a side broken in two), and keep loops of four sides that close. Corners are
//!   intersections of the sides' lines, which the extractor fitted to edge points away from
//!   the corners' rounding: sub-pixel without looking at the pixels again.
//! - **Lattices.** A square's four corners give a homography from lattice coordinates (a
//!   square is `[0,1]²`, the pitch `p/s` squares) to the image; it predicts where the four
//!   neighbours' centres are, and the grid grows breadth-first, each new square predicting
//!   its own neighbours (perspective changes little from one square to the next).
//! - **Identity.** The 8 ways a lattice can map onto a board's (row, col) are tried with
//!   every shift that keeps the squares on the board; a placement must put every square on
//!   a printed cell (the missing cells break the rotation) and have the board's handedness:
//!   a board seen from its normal side shows (u, v) turning clockwise on screen, from the
//!   other side anticlockwise. That tells apart the default pattern's two boards, whose
//!   layouts are the same: each is printed on the side facing the other ([`printed_side`]).
//! - **Refinement.** The squares of one row share their top edge line (and bottom, and
//!   likewise columns): each corner is the intersection of lines fitted through every
//!   segment along the whole row and column, which averages the noise of up to 8 squares.
//!   Lens distortion bends those lines, so a refined corner that moved more than
//!   [`REFINE_MAX_SHIFT_PX`] from its square's own corner is not trusted and the square's
//!   corner is kept (the per-square lines are short enough that distortion barely bends
//!   them).
//!
//! Points are in the image's own (distorted) pixels.

use nalgebra::{Matrix3, Point2, SMatrix, SVector, Vector2, Vector3};
use thiserror::Error;

use super::pattern::{CalibrationPattern, CornerId, PatternError};
use crate::checkpoint::{Checkpoint, Stopped};
use crate::extract::{self, GreyImage, Params};
use crate::segment::Segment2;

/// The reference points found in one image.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Image coordinates, pixels, distortion not removed; sorted by id.
    pub points: Vec<(CornerId, Point2<f64>)>,
    pub boards_found: usize,
}

/// Why an image gives no usable points. The caller adds which image.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum DetectError {
    #[error("board {board} not found: {message}")]
    BoardNotFound { board: usize, message: String },
    #[error("board {board} is ambiguous: {message}")]
    Ambiguous { board: usize, message: String },
    /// No grid of squares in the image is a board of the pattern: a picture of something else.
    #[error("no calibration pattern found: {message}")]
    NoPattern { message: String },
    #[error(transparent)]
    Pattern(#[from] PatternError),
    #[error(transparent)]
    Stopped(#[from] Stopped),
}

/// Largest gap between one side's end and the next side's start, pixels (corners are
/// rounded by the smoothing, and the extractor drops pieces shorter than 6 px).
const GAP_PX: f64 = 4.5;
/// Turns sharper than this (sine) count as a corner; flatter ones continue a broken side.
const CORNER_SIN: f64 = 0.35;
/// Shortest side of a square, pixels.
const MIN_SIDE_PX: f64 = 4.0;
/// A predicted neighbour's centre must be this close, as a fraction of the square's size.
const PREDICT_TOLERANCE: f64 = 0.3;
/// ... and each of its corners this close.
const CORNER_TOLERANCE: f64 = 0.2;
/// Fewer squares than this in a lattice is clutter, not a board.
const MIN_SQUARES: usize = 6;
/// Row and column line fits: outliers, straightness (see [`straight_line`]).
const OUTLIER_PX: f64 = 0.6;
const STRAIGHT_RMS_PX: f64 = 0.4;
/// See the module doc.
pub const REFINE_MAX_SHIFT_PX: f64 = 0.75;

/// The side of board `board` its squares are printed on (unit vector): the side facing the
/// other boards (a concave pattern, like the paper's object), the normal for a lone board.
pub fn printed_side(pattern: &CalibrationPattern, board: usize) -> Vector3<f64> {
    let b = &pattern.boards[board];
    let n = b.normal();
    let mut sum = Vector3::zeros();
    let mut count = 0.0;
    for (i, o) in pattern.boards.iter().enumerate() {
        if i != board {
            for p in o
                .corners(0, 0)
                .iter()
                .chain(&o.corners(o.rows - 1, o.cols - 1))
            {
                sum += p.coords;
                count += 1.0;
            }
        }
    }
    if count > 0.0 && (sum / count - b.origin.coords).dot(&n) < 0.0 {
        -n
    } else {
        n
    }
}

/// A point and its weight in a line fit.
type Weighted = (Point2<f64>, f64);

/// A line through `point` along unit `dir`.
#[derive(Debug, Clone, Copy)]
struct Line {
    point: Point2<f64>,
    dir: Vector2<f64>,
}

impl Line {
    /// Total least squares through weighted points; `None` for fewer than two distinct.
    fn fit(points: &[(Point2<f64>, f64)]) -> Option<Line> {
        let w: f64 = points.iter().map(|p| p.1).sum();
        if w <= 0.0 {
            return None;
        }
        let c = points
            .iter()
            .fold(Vector2::zeros(), |s, (p, wi)| s + p.coords * *wi)
            / w;
        let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
        for (p, wi) in points {
            let d = p.coords - c;
            sxx += wi * d.x * d.x;
            sxy += wi * d.x * d.y;
            syy += wi * d.y * d.y;
        }
        if sxx + syy <= 1e-12 {
            return None;
        }
        let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
        Some(Line {
            point: Point2::from(c),
            dir: Vector2::new(angle.cos(), angle.sin()),
        })
    }

    fn intersect(&self, other: &Line) -> Option<Point2<f64>> {
        let det = cross(self.dir, other.dir);
        if det.abs() < 1e-6 {
            return None;
        }
        let t = cross(other.point - self.point, other.dir) / det;
        Some(self.point + self.dir * t)
    }
}

fn cross(a: Vector2<f64>, b: Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

fn dir(s: &Segment2) -> Vector2<f64> {
    (s.end - s.start) / s.length().max(1e-12)
}

/// The weighted end points standing for a group of segments in a line fit: each segment
/// weighs its length.
fn side_points(segments: &[Segment2], ids: &[usize], out: &mut Vec<(Point2<f64>, f64)>) {
    for &i in ids {
        let s = &segments[i];
        out.push((s.start, 0.5 * s.length()));
        out.push((s.end, 0.5 * s.length()));
    }
}

/// A dark quadrilateral: corners in walking order (clockwise on screen), side `k` from
/// corner `k` to corner `k + 1`, made of the segments `sides[k]`.
#[derive(Debug, Clone)]
struct Quad {
    corners: [Point2<f64>; 4],
    sides: [Vec<usize>; 4],
    centre: Point2<f64>,
    size: f64,
}

/// The segment that continues the dark-square loop after `s`: starting nearest the end of
/// `s`, turning right or going on straight.
fn successor(segments: &[Segment2], grid: &Grid, s: usize) -> Option<usize> {
    let a = &segments[s];
    let da = dir(a);
    let mut best: Option<(f64, usize)> = None;
    grid.near(a.end, GAP_PX, |t| {
        if t == s {
            return;
        }
        let b = &segments[t];
        let gap = (b.start - a.end).norm();
        if gap > GAP_PX {
            return;
        }
        let db = dir(b);
        let turn = cross(da, db);
        let ok = turn > CORNER_SIN || (turn.abs() <= CORNER_SIN && da.dot(&db) > 0.0);
        if ok && best.is_none_or(|(g, _)| gap < g) {
            best = Some((gap, t));
        }
    });
    best.map(|(_, t)| t)
}

/// Segment start points bucketed in square cells, for "starts near this point".
struct Grid {
    cell: f64,
    cols: usize,
    rows: usize,
    buckets: Vec<Vec<usize>>,
}

impl Grid {
    fn new(segments: &[Segment2], width: u32, height: u32, cell: f64) -> Grid {
        let cols = (f64::from(width) / cell).ceil() as usize + 1;
        let rows = (f64::from(height) / cell).ceil() as usize + 1;
        let mut buckets = vec![Vec::new(); cols * rows];
        for (i, s) in segments.iter().enumerate() {
            if let Some(k) = Self::index(cell, cols, rows, s.start) {
                buckets[k].push(i);
            }
        }
        Grid {
            cell,
            cols,
            rows,
            buckets,
        }
    }

    fn index(cell: f64, cols: usize, rows: usize, p: Point2<f64>) -> Option<usize> {
        let (c, r) = ((p.x / cell).floor(), (p.y / cell).floor());
        (c >= 0.0 && r >= 0.0 && (c as usize) < cols && (r as usize) < rows)
            .then(|| r as usize * cols + c as usize)
    }

    fn near(&self, p: Point2<f64>, radius: f64, mut f: impl FnMut(usize)) {
        let lo = |x: f64| ((x - radius) / self.cell).floor().max(0.0) as usize;
        let hi =
            |x: f64, n: usize| (((x + radius) / self.cell).floor().max(0.0) as usize).min(n - 1);
        for r in lo(p.y)..=hi(p.y, self.rows) {
            for c in lo(p.x)..=hi(p.x, self.cols) {
                for &i in &self.buckets[r * self.cols + c] {
                    f(i);
                }
            }
        }
    }
}

/// Every dark quadrilateral in the segments (each found once).
fn find_quads(segments: &[Segment2], width: u32, height: u32) -> Vec<Quad> {
    let grid = Grid::new(segments, width, height, 8.0);
    let next: Vec<Option<usize>> = (0..segments.len())
        .map(|s| successor(segments, &grid, s))
        .collect();
    let mut quads = Vec::new();
    for s0 in 0..segments.len() {
        // Walk at most 8 segments; keep the loop once, from its lowest index.
        let mut path = vec![s0];
        let mut closed = false;
        let mut cur = s0;
        for _ in 0..8 {
            match next[cur] {
                Some(t) if t == s0 => {
                    closed = true;
                    break;
                }
                Some(t) if t > s0 && !path.contains(&t) => {
                    path.push(t);
                    cur = t;
                }
                _ => break,
            }
        }
        if !closed || path.len() < 4 {
            continue;
        }
        if let Some(q) = quad_from_loop(segments, &path) {
            quads.push(q);
        }
    }
    quads
}

/// Groups a closed loop into four sides (corners where it turns) and checks the shape.
fn quad_from_loop(segments: &[Segment2], path: &[usize]) -> Option<Quad> {
    let n = path.len();
    let is_corner = |k: usize| {
        let a = dir(&segments[path[(k + n - 1) % n]]);
        let b = dir(&segments[path[k]]);
        cross(a, b) > CORNER_SIN
    };
    let starts: Vec<usize> = (0..n).filter(|&k| is_corner(k)).collect();
    if starts.len() != 4 {
        return None;
    }
    let sides: [Vec<usize>; 4] = std::array::from_fn(|k| {
        let (a, b) = (starts[k], starts[(k + 1) % 4]);
        let len = (b + n - a) % n;
        (0..len).map(|i| path[(a + i) % n]).collect()
    });
    let mut buf = Vec::new();
    let mut lines = Vec::with_capacity(4);
    for side in &sides {
        buf.clear();
        side_points(segments, side, &mut buf);
        lines.push(Line::fit(&buf)?);
    }
    // Corner k is where side k−1 meets side k.
    let mut corners = [Point2::origin(); 4];
    for k in 0..4 {
        corners[k] = lines[(k + 3) % 4].intersect(&lines[k])?;
        let end = segments[*sides[(k + 3) % 4].last()?].end;
        let start = segments[sides[k][0]].start;
        if (corners[k] - end).norm() > 2.0 * GAP_PX || (corners[k] - start).norm() > 2.0 * GAP_PX {
            return None;
        }
    }
    let mut size = 0.0;
    for k in 0..4 {
        let e = corners[(k + 1) % 4] - corners[k];
        let f = corners[(k + 2) % 4] - corners[(k + 1) % 4];
        if e.norm() < MIN_SIDE_PX || cross(e, f) <= 0.0 {
            return None;
        }
        size += 0.25 * e.norm();
    }
    let centre = Point2::from(corners.iter().fold(Vector2::zeros(), |s, c| s + c.coords) / 4.0);
    Some(Quad {
        corners,
        sides,
        centre,
        size,
    })
}

/// The homography taking `from[k]` to `to[k]` (4 points, DLT with h33 = 1).
fn homography(from: &[Point2<f64>; 4], to: &[Point2<f64>; 4]) -> Option<Matrix3<f64>> {
    let mut a = SMatrix::<f64, 8, 8>::zeros();
    let mut b = SVector::<f64, 8>::zeros();
    for k in 0..4 {
        let (x, y, u, v) = (from[k].x, from[k].y, to[k].x, to[k].y);
        let r = 2 * k;
        a.row_mut(r)
            .copy_from_slice(&[x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y]);
        a.row_mut(r + 1)
            .copy_from_slice(&[0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y]);
        b[r] = u;
        b[r + 1] = v;
    }
    let h = a.lu().solve(&b)?;
    Some(Matrix3::new(
        h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0,
    ))
}

fn apply(h: &Matrix3<f64>, p: Point2<f64>) -> Point2<f64> {
    let q = h * Vector3::new(p.x, p.y, 1.0);
    Point2::new(q.x / q.z, q.y / q.z)
}

/// One square of a lattice: the quad, its cell (i, j), and which of its corners sits at the
/// cell's lattice corner (0,0) (the others follow in walking order: (1,0), (1,1), (0,1)).
#[derive(Debug, Clone, Copy)]
struct Cell {
    quad: usize,
    i: i32,
    j: i32,
    first: usize,
}

/// Lattice corner `k` (0..4) of cell (i, j), in square units with the given pitch ratio.
fn lattice_corner(ratio: f64, i: i32, j: i32, k: usize) -> Point2<f64> {
    let (a, b) = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)][k];
    Point2::new(ratio * f64::from(j) + a, ratio * f64::from(i) + b)
}

fn cell_homography(quads: &[Quad], c: &Cell, ratio: f64) -> Option<Matrix3<f64>> {
    let from = std::array::from_fn(|k| lattice_corner(ratio, c.i, c.j, k));
    let to = std::array::from_fn(|k| quads[c.quad].corners[(c.first + k) % 4]);
    homography(&from, &to)
}

/// Groups quads into lattices by growing from each unassigned quad.
fn lattices(quads: &[Quad], ratio: f64) -> Vec<Vec<Cell>> {
    let mut taken = vec![false; quads.len()];
    let mut out = Vec::new();
    for seed in 0..quads.len() {
        if taken[seed] {
            continue;
        }
        taken[seed] = true;
        let mut cells = vec![Cell {
            quad: seed,
            i: 0,
            j: 0,
            first: 0,
        }];
        let mut k = 0;
        while k < cells.len() {
            let c = cells[k];
            k += 1;
            let Some(h) = cell_homography(quads, &c, ratio) else {
                continue;
            };
            for (di, dj) in [(0, 1), (0, -1), (1, 0), (-1, 0)] {
                let (i, j) = (c.i + di, c.j + dj);
                if cells.iter().any(|o| o.i == i && o.j == j) {
                    continue;
                }
                let predicted: [Point2<f64>; 4] =
                    std::array::from_fn(|m| apply(&h, lattice_corner(ratio, i, j, m)));
                let centre = Point2::from(
                    predicted.iter().fold(Vector2::zeros(), |s, p| s + p.coords) / 4.0,
                );
                let size = 0.25
                    * (0..4)
                        .map(|m| (predicted[(m + 1) % 4] - predicted[m]).norm())
                        .sum::<f64>();
                let found = (0..quads.len())
                    .filter(|&q| !taken[q])
                    .map(|q| (q, (quads[q].centre - centre).norm()))
                    .filter(|&(q, d)| {
                        d < PREDICT_TOLERANCE * size && (quads[q].size / size - 1.0).abs() < 0.35
                    })
                    .min_by(|a, b| a.1.total_cmp(&b.1));
                let Some((q, _)) = found else { continue };
                // Which of its corners is at lattice corner 0: the rotation that fits best.
                let first = (0..4)
                    .min_by(|&a, &b| {
                        let cost = |r: usize| {
                            (0..4)
                                .map(|m| (quads[q].corners[(r + m) % 4] - predicted[m]).norm())
                                .sum::<f64>()
                        };
                        cost(a).total_cmp(&cost(b))
                    })
                    .unwrap_or(0);
                // Every corner where predicted, not just the centre: a square across the
                // fold between two boards can sit near the predicted centre but is
                // foreshortened the other way.
                let worst = (0..4)
                    .map(|m| (quads[q].corners[(first + m) % 4] - predicted[m]).norm())
                    .fold(0.0, f64::max);
                if worst > CORNER_TOLERANCE * size {
                    continue;
                }
                taken[q] = true;
                cells.push(Cell {
                    quad: q,
                    i,
                    j,
                    first,
                });
            }
        }
        if cells.len() >= MIN_SQUARES {
            out.push(cells);
        }
    }
    out.sort_by_key(|c| std::cmp::Reverse(c.len()));
    out
}

/// How a lattice lies on a board: `(row, col) = (si·p + row0, sj·q + col0)` with
/// `(p, q) = (i, j)`, or `(j, i)` when `swap`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Placement {
    board: usize,
    swap: bool,
    si: i32,
    sj: i32,
    row0: i32,
    col0: i32,
}

impl Placement {
    fn cell(&self, i: i32, j: i32) -> (i32, i32) {
        let (p, q) = if self.swap { (j, i) } else { (i, j) };
        (self.si * p + self.row0, self.sj * q + self.col0)
    }

    /// The board corner index of lattice corner `k` (0..4).
    fn corner(&self, k: usize) -> usize {
        let (a, b) = [(0, 0), (1, 0), (1, 1), (0, 1)][k];
        // a runs along j, b along i.
        let (along_p, along_q) = if self.swap { (a, b) } else { (b, a) };
        let dv = if self.si > 0 { along_p } else { 1 - along_p };
        let du = if self.sj > 0 { along_q } else { 1 - along_q };
        match (du, dv) {
            (0, 0) => 0,
            (1, 0) => 1,
            (1, 1) => 2,
            _ => 3,
        }
    }
}

/// Every placement of `cells` on a board of `pattern` that puts each square on a printed
/// cell with the board's handedness.
fn placements(pattern: &CalibrationPattern, cells: &[Cell]) -> Vec<Placement> {
    let mut out = Vec::new();
    for (b, board) in pattern.boards.iter().enumerate() {
        let front = printed_side(pattern, b).dot(&board.normal()) > 0.0;
        for swap in [false, true] {
            for si in [1, -1] {
                for sj in [1, -1] {
                    // Lattice (x = j, y = i) maps to the image keeping orientation (quads
                    // and lattice squares both turn with positive cross products); a board
                    // seen from its normal side maps (u, v) = (col, row) reversing it
                    // (cross of the images of u and v = n · z_camera < 0).
                    let det = if swap { -si * sj } else { si * sj };
                    if (det < 0) != front {
                        continue;
                    }
                    let base = Placement {
                        board: b,
                        swap,
                        si,
                        sj,
                        row0: 0,
                        col0: 0,
                    };
                    let mapped: Vec<(i32, i32)> =
                        cells.iter().map(|c| base.cell(c.i, c.j)).collect();
                    let (rmin, rmax) = min_max(mapped.iter().map(|m| m.0));
                    let (cmin, cmax) = min_max(mapped.iter().map(|m| m.1));
                    for row0 in -rmin..=(board.rows as i32 - 1 - rmax) {
                        for col0 in -cmin..=(board.cols as i32 - 1 - cmax) {
                            let fits = mapped
                                .iter()
                                .all(|&(r, c)| board.has((r + row0) as u32, (c + col0) as u32));
                            if fits {
                                out.push(Placement { row0, col0, ..base });
                            }
                        }
                    }
                }
            }
        }
    }
    out
}

fn min_max(it: impl Iterator<Item = i32>) -> (i32, i32) {
    it.fold((i32::MAX, i32::MIN), |(lo, hi), x| (lo.min(x), hi.max(x)))
}

/// The reference points of `pattern` visible in `image`. Every board must be found, each
/// exactly once and in exactly one placement.
pub fn detect(image: &GreyImage, pattern: &CalibrationPattern) -> Result<Detection, DetectError> {
    detect_until(image, pattern, Checkpoint::NEVER)
}

/// Gaussian smoothing of the pattern's images before their segments are extracted, pixels.
const DETECTION_SMOOTHING_PX: f64 = 1.0;

/// [`detect`], asking `checkpoint` as it extracts and for each lattice it tries.
pub fn detect_until(
    image: &GreyImage,
    pattern: &CalibrationPattern,
    checkpoint: Checkpoint,
) -> Result<Detection, DetectError> {
    detect_with(image, pattern, &Params::default(), checkpoint)
}

/// [`detect_until`] with the segments extracted by `params` (a request's extraction options):
/// its thresholds, deviation and shortest segment as given. The detector's quads were tuned on
/// corners rounded by 1 px of smoothing, so where `params` leave the smoothing to be chosen
/// per image (as the matcher does) the detector keeps that scale instead.
pub fn detect_with(
    image: &GreyImage,
    pattern: &CalibrationPattern,
    params: &Params,
    checkpoint: Checkpoint,
) -> Result<Detection, DetectError> {
    pattern.check()?;
    let params = Params {
        smoothing_sigma_px: params.smoothing_sigma_px.or(Some(DETECTION_SMOOTHING_PX)),
        ..params.clone()
    };
    let extraction = extract::extract_until(image, None, &params, checkpoint)?;
    let segments = &extraction.segments.segments;
    let quads = find_quads(segments, image.width(), image.height());
    // Boards of one pattern may differ in pitch ratio; grow with each ratio in use.
    let mut ratios: Vec<f64> = pattern.boards.iter().map(|b| b.pitch / b.square).collect();
    ratios.sort_by(f64::total_cmp);
    ratios.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    let mut assigned: Vec<Option<(Vec<Cell>, Placement)>> = vec![None; pattern.boards.len()];
    // The first grid that fitted a board in several ways: which board, and why.
    let mut ambiguous: Option<(usize, String)> = None;
    let mut grids = 0;
    for &ratio in &ratios {
        for cells in lattices(&quads, ratio) {
            checkpoint.before("detect")?;
            let found: Vec<Placement> = placements(pattern, &cells)
                .into_iter()
                .filter(|p| {
                    let b = &pattern.boards[p.board];
                    (b.pitch / b.square - ratio).abs() < 1e-9
                })
                .collect();
            if found.is_empty() {
                continue;
            }
            grids += 1;
            let board = found[0].board;
            if found.len() > 1 {
                // Kept for the end: with a board found whole elsewhere this is an ambiguous
                // board; with none, the picture holds no pattern (a grid on a wall, texture).
                let mut boards: Vec<usize> = found.iter().map(|p| p.board).collect();
                boards.dedup();
                ambiguous.get_or_insert((
                    board,
                    format!(
                        "a grid of {} squares fits {} placements (boards {boards:?}); \
                         too few squares visible to tell which cells are missing",
                        cells.len(),
                        found.len()
                    ),
                ));
                continue;
            }
            if let Some((other, _)) = &assigned[board] {
                if other.len() >= cells.len() && cells.len() * 2 < other.len() {
                    continue; // a small fragment beside the board proper
                }
                return Err(DetectError::Ambiguous {
                    board,
                    message: format!(
                        "two grids ({} and {} squares) both fit it",
                        other.len(),
                        cells.len()
                    ),
                });
            }
            assigned[board] = Some((cells, found[0]));
        }
    }
    if assigned.iter().all(Option::is_none) {
        let message = match &ambiguous {
            Some((_, why)) => format!("no board found whole ({why})"),
            None => format!(
                "{} dark squares in {} segments, and no grid of them is a board of the pattern",
                quads.len(),
                segments.len()
            ),
        };
        return Err(DetectError::NoPattern { message });
    }
    for (board, a) in assigned.iter().enumerate() {
        if let (None, Some((which, message))) = (a, &ambiguous) {
            if *which == board {
                return Err(DetectError::Ambiguous {
                    board,
                    message: message.clone(),
                });
            }
        }
        if a.is_none() {
            return Err(DetectError::BoardNotFound {
                board,
                message: format!(
                    "{} dark squares in {} segments, {grids} grid(s) matched other boards",
                    quads.len(),
                    segments.len()
                ),
            });
        }
    }
    let mut points = Vec::new();
    for (board, a) in assigned.iter().enumerate() {
        if let Some((cells, placement)) = a {
            points.extend(board_points(segments, &quads, cells, placement, board));
        }
    }
    points.sort_by_key(|p| p.0);
    Ok(Detection {
        points,
        boards_found: pattern.boards.len(),
    })
}

/// The corners of one placed board, refined along rows and columns (module doc).
fn board_points(
    segments: &[Segment2],
    quads: &[Quad],
    cells: &[Cell],
    placement: &Placement,
    board: usize,
) -> Vec<(CornerId, Point2<f64>)> {
    use std::collections::HashMap;
    // Line keys: (false, 2·row + dv) for rows, (true, 2·col + du) for columns.
    let mut lines: HashMap<(bool, i32), Vec<Weighted>> = HashMap::new();
    let mut raw = Vec::new();
    let uv = |k: usize| [(0, 0), (1, 0), (1, 1), (0, 1)][k];
    for c in cells {
        let q = &quads[c.quad];
        let (row, col) = placement.cell(c.i, c.j);
        for k in 0..4 {
            let m = (c.first + k) % 4; // quad corner at lattice corner k
            let corner = placement.corner(k);
            let (du, dv) = uv(corner);
            raw.push((
                CornerId {
                    board,
                    row: row as u32,
                    col: col as u32,
                    corner,
                },
                q.corners[m],
                (2 * row + dv, 2 * col + du),
            ));
            // Side m runs from quad corner m to m+1 (lattice corners k, k+1).
            let (_, dv2) = uv(placement.corner((k + 1) % 4));
            let key = if dv == dv2 {
                (false, 2 * row + dv)
            } else {
                (true, 2 * col + du)
            };
            side_points(segments, &q.sides[m], lines.entry(key).or_default());
        }
    }
    let fitted: HashMap<(bool, i32), Line> = lines
        .into_iter()
        .filter_map(|(k, pts)| straight_line(pts).map(|l| (k, l)))
        .collect();
    raw.into_iter()
        .map(|(id, p, (h, v))| {
            let refined = fitted
                .get(&(false, h))
                .zip(fitted.get(&(true, v)))
                .and_then(|(a, b)| a.intersect(b))
                .filter(|r| (r - p).norm() <= REFINE_MAX_SHIFT_PX);
            (id, refined.unwrap_or(p))
        })
        .collect()
}

/// A row's or column's line through its segments' end points, robustly (points more than
/// [`OUTLIER_PX`] off are dropped and the line refitted), or `None` when the kept points
/// are not straight to [`STRAIGHT_RMS_PX`] — lens distortion bends long lines, and then
/// each square's own corners are better.
fn straight_line(mut points: Vec<(Point2<f64>, f64)>) -> Option<Line> {
    let total: f64 = points.iter().map(|p| p.1).sum();
    let line = Line::fit(&points)?;
    let dist = |l: &Line, p: &Point2<f64>| cross(l.dir, p - l.point).abs();
    points.retain(|(p, _)| dist(&line, p) <= OUTLIER_PX);
    let line = Line::fit(&points)?;
    let kept: f64 = points.iter().map(|p| p.1).sum();
    let rms = (points
        .iter()
        .map(|(p, w)| w * dist(&line, p).powi(2))
        .sum::<f64>()
        / kept)
        .sqrt();
    (kept >= 0.7 * total && rms <= STRAIGHT_RMS_PX).then_some(line)
}

// Tested on rendered patterns, whose scenes come from trinocular-synth: an integration test,
// crates/core/tests/synthetic/detect.rs.
