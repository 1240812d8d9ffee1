//! Polygonal approximation of a chain: split-and-merge, then a least-squares refit.
//!
//! 1. **Split** (Ramer–Douglas–Peucker): a run of points is cut at the point farthest from its
//!    chord while that distance exceeds `max_deviation_px`.
//! 2. **Merge**: neighbouring pieces whose union a single line fits within
//!    `max_deviation_px` are joined, best fit first — splitting alone leaves extra breaks
//!    where noise pushed a point just over the threshold.
//! 3. **Refit**: each piece gets its total-least-squares line. Near a break the smoothed edge
//!    rounds the corner, so the points within `corner_trim` of a break are left out of the fit
//!    (when enough remain). The piece's ends are its extreme points projected onto the line,
//!    and where two pieces meet at a clear corner, both ends move to the lines' intersection,
//!    so that neighbours share the vertex exactly.

use nalgebra::{Point2, Vector2};

/// Pieces meeting at less than this angle keep their own projected ends: their lines'
/// intersection is ill-conditioned.
const MIN_CORNER_ANGLE_RAD: f64 = 0.26; // 15°
/// A corner intersection farther than this from the break point is not trusted, pixels.
const MAX_CORNER_SHIFT_PX: f64 = 3.0;

/// A total-least-squares line: through `centroid`, along unit `direction`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Line {
    pub centroid: Point2<f64>,
    pub direction: Vector2<f64>,
}

impl Line {
    /// Signed distance of `p` from the line (positive on the left of `direction`, v down).
    pub fn distance(&self, p: Point2<f64>) -> f64 {
        let w = p - self.centroid;
        w.x * self.direction.y - w.y * self.direction.x
    }

    /// Foot of `p` on the line.
    pub fn project(&self, p: Point2<f64>) -> Point2<f64> {
        self.centroid + self.direction * (p - self.centroid).dot(&self.direction)
    }

    /// Intersection with `other`, `None` when (nearly) parallel.
    pub fn intersect(&self, other: &Line) -> Option<Point2<f64>> {
        let cross = self.direction.perp(&other.direction);
        if cross.abs() < 1e-9 {
            return None;
        }
        let t = (other.centroid - self.centroid).perp(&other.direction) / cross;
        Some(self.centroid + self.direction * t)
    }
}

/// The total-least-squares line through `points`, directed from the first towards the last;
/// `None` for fewer than two distinct points.
pub fn fit_line(points: &[Point2<f64>]) -> Option<Line> {
    let n = points.len();
    if n < 2 {
        return None;
    }
    let centroid = points.iter().fold(Vector2::zeros(), |s, p| s + p.coords) / n as f64;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in points {
        let d = p.coords - centroid;
        sxx += d.x * d.x;
        sxy += d.x * d.y;
        syy += d.y * d.y;
    }
    Some(Line {
        centroid: Point2::from(centroid),
        direction: principal_direction(sxx, sxy, syy, points[n - 1] - points[0])?,
    })
}

/// The unit direction of largest spread of points with central second moments `xx`, `xy`,
/// `yy`, directed along `towards`; `None` when they do not spread at all.
fn principal_direction(xx: f64, xy: f64, yy: f64, towards: Vector2<f64>) -> Option<Vector2<f64>> {
    if xx + yy <= 1e-18 {
        return None;
    }
    let angle = 0.5 * (2.0 * xy).atan2(xx - yy);
    let direction = Vector2::new(angle.cos(), angle.sin());
    Some(if direction.dot(&towards) < 0.0 {
        -direction
    } else {
        direction
    })
}

fn max_deviation(points: &[Point2<f64>], line: &Line) -> f64 {
    points
        .iter()
        .map(|p| line.distance(*p).abs())
        .fold(0.0, f64::max)
}

/// Step 1: break indices (first and last included) of the recursive chord split.
pub fn split(points: &[Point2<f64>], max_deviation_px: f64) -> Vec<usize> {
    let n = points.len();
    if n < 3 {
        return if n == 2 { vec![0, 1] } else { vec![0] };
    }
    let mut breaks = vec![0, n - 1];
    let mut stack = vec![(0usize, n - 1)];
    while let Some((i, j)) = stack.pop() {
        if j <= i + 1 {
            continue;
        }
        let (a, b) = (points[i], points[j]);
        let chord = b - a;
        let len = chord.norm();
        let distance = |p: &Point2<f64>| {
            if len < 1e-9 {
                (p - a).norm()
            } else {
                (p - a).perp(&chord).abs() / len
            }
        };
        let (k, d) = (i + 1..j)
            .map(|k| (k, distance(&points[k])))
            .fold((i, -1.0), |best, x| if x.1 > best.1 { x } else { best });
        if d > max_deviation_px {
            breaks.push(k);
            stack.push((i, k));
            stack.push((k, j));
        }
    }
    breaks.sort_unstable();
    breaks
}

/// Step 2: joins neighbouring pieces (between consecutive `breaks`) while one line fits
/// their union within `max_deviation_px`, best fit first. Each merge changes only the costs
/// of the two pairs around it, so only those are refitted.
pub fn merge(points: &[Point2<f64>], breaks: &[usize], max_deviation_px: f64) -> Vec<usize> {
    let mut breaks = breaks.to_vec();
    // cost[m]: max deviation of the line through pieces m-1 and m joined at break m (interior
    // breaks only); infinite when no line fits within the bound.
    let cost_at = |breaks: &[usize], m: usize| -> f64 {
        let run = &points[breaks[m - 1]..=breaks[m + 1]];
        match fit_line(run) {
            Some(line) => {
                let dev = max_deviation(run, &line);
                if dev <= max_deviation_px {
                    dev
                } else {
                    f64::INFINITY
                }
            }
            None => f64::INFINITY,
        }
    };
    let mut cost: Vec<f64> = (0..breaks.len())
        .map(|m| {
            if m == 0 || m + 1 >= breaks.len() {
                f64::INFINITY
            } else {
                cost_at(&breaks, m)
            }
        })
        .collect();
    loop {
        let best = (1..breaks.len().saturating_sub(1))
            .filter(|&m| cost[m].is_finite())
            .min_by(|&a, &b| cost[a].total_cmp(&cost[b]));
        let Some(m) = best else {
            return breaks;
        };
        breaks.remove(m);
        cost.remove(m);
        for k in [m - 1, m] {
            if k >= 1 && k + 1 < breaks.len() {
                cost[k] = cost_at(&breaks, k);
            }
        }
    }
}

/// One fitted piece: its line and its ends, in chain order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Piece {
    /// Indices into the chain's points of its first and last point.
    pub first: usize,
    pub last: usize,
    pub line: Line,
    pub start: Point2<f64>,
    pub end: Point2<f64>,
    /// Whether `start` / `end` is the corner shared with the previous / next piece (the
    /// intersection of their lines); otherwise it is the projection of the extreme point.
    pub joined: (bool, bool),
    /// The points the line was fitted to: how many, their RMS distance from it, and the
    /// length they span along it (pixels). The segment's precision is measured from these.
    pub fit: FitSpread,
    /// The same points' sums, so that pieces of one line can be refitted together.
    pub moments: Moments,
}

/// Sums over a set of points, enough to refit their total-least-squares line exactly after
/// sets are combined ([`Moments::add`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Moments {
    pub count: f64,
    pub sum: Vector2<f64>,
    pub sum_xx: f64,
    pub sum_xy: f64,
    pub sum_yy: f64,
}

/// A line fitted from [`Moments`], with the points' second moments along and across it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MomentFit {
    /// Directed like the caller's `towards`.
    pub line: Line,
    /// Mean squared distance of the points from the line, pixels².
    pub across_px2: f64,
    /// Mean squared distance along the line from the centroid, pixels².
    pub along_px2: f64,
}

impl Moments {
    pub fn of(points: &[Point2<f64>]) -> Moments {
        points.iter().fold(Moments::default(), |m, p| Moments {
            count: m.count + 1.0,
            sum: m.sum + p.coords,
            sum_xx: m.sum_xx + p.x * p.x,
            sum_xy: m.sum_xy + p.x * p.y,
            sum_yy: m.sum_yy + p.y * p.y,
        })
    }

    pub fn add(&self, other: &Moments) -> Moments {
        Moments {
            count: self.count + other.count,
            sum: self.sum + other.sum,
            sum_xx: self.sum_xx + other.sum_xx,
            sum_xy: self.sum_xy + other.sum_xy,
            sum_yy: self.sum_yy + other.sum_yy,
        }
    }

    /// The total-least-squares line, directed along `towards`; `None` for fewer than two
    /// distinct points.
    pub fn fit(&self, towards: Vector2<f64>) -> Option<MomentFit> {
        if self.count < 2.0 {
            return None;
        }
        let c = self.sum / self.count;
        // Central second moments, per point.
        let xx = self.sum_xx / self.count - c.x * c.x;
        let xy = self.sum_xy / self.count - c.x * c.y;
        let yy = self.sum_yy / self.count - c.y * c.y;
        let direction = principal_direction(xx, xy, yy, towards)?;
        let (dx, dy) = (direction.x, direction.y);
        let along = xx * dx * dx + 2.0 * xy * dx * dy + yy * dy * dy;
        Some(MomentFit {
            line: Line {
                centroid: Point2::from(c),
                direction,
            },
            across_px2: (xx + yy - along).max(0.0),
            along_px2: along,
        })
    }
}

/// What a line fit saw of its points.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FitSpread {
    pub points: usize,
    pub rms_px: f64,
    pub span_px: f64,
}

/// The spread of `points` about `line`.
pub fn fit_spread(points: &[Point2<f64>], line: &Line) -> FitSpread {
    let (mut sum2, mut lo, mut hi) = (0.0, f64::INFINITY, f64::NEG_INFINITY);
    for &p in points {
        sum2 += line.distance(p).powi(2);
        let t = (p - line.centroid).dot(&line.direction);
        lo = lo.min(t);
        hi = hi.max(t);
    }
    let n = points.len();
    FitSpread {
        points: n,
        rms_px: if n > 0 { (sum2 / n as f64).sqrt() } else { 0.0 },
        span_px: if n > 0 { hi - lo } else { 0.0 },
    }
}

/// Steps 1–3 for one chain of points (undistorted pixels, in walking order).
///
/// `closed`: the chain is a loop (its last point neighbours its first); the caller should
/// start it at a corner. `corner_trim`: points left out of the fit at each break, counted in
/// points along the chain.
pub fn approximate(
    points: &[Point2<f64>],
    closed: bool,
    max_deviation_px: f64,
    corner_trim: usize,
) -> Vec<Piece> {
    let mut run: Vec<Point2<f64>> = points.to_vec();
    if closed && points.len() > 2 {
        run.push(points[0]);
    }
    let breaks = merge(&run, &split(&run, max_deviation_px), max_deviation_px);
    let mut pieces: Vec<Piece> = Vec::with_capacity(breaks.len());
    // Per piece, the run index of its last point (its break with the next piece).
    let mut break_at: Vec<usize> = Vec::with_capacity(breaks.len());
    let interior_break = |b: usize| closed || (b != 0 && b != run.len() - 1);
    for w in breaks.windows(2) {
        let (first, last) = (w[0], w[1]);
        let all = &run[first..=last];
        let lo = if interior_break(first) {
            corner_trim
        } else {
            0
        };
        let hi = if interior_break(last) { corner_trim } else { 0 };
        let core = if all.len() >= lo + hi + 3 {
            &all[lo..all.len() - hi]
        } else {
            all
        };
        let (line, fitted) = match fit_line(core) {
            Some(line) => (line, core),
            None => match fit_line(all) {
                Some(line) => (line, all),
                None => continue,
            },
        };
        break_at.push(last);
        pieces.push(Piece {
            first,
            last: last % points.len(),
            line,
            start: line.project(all[0]),
            end: line.project(all[all.len() - 1]),
            joined: (false, false),
            fit: fit_spread(fitted, &line),
            moments: Moments::of(fitted),
        });
    }
    // Corners: neighbours in the chain share the intersection of their lines.
    let count = pieces.len();
    let pairs = if closed && count > 2 {
        count
    } else {
        count.saturating_sub(1)
    };
    for i in 0..pairs {
        let j = (i + 1) % count;
        let (a, b) = (pieces[i], pieces[j]);
        let angle = a
            .line
            .direction
            .dot(&b.line.direction)
            .clamp(-1.0, 1.0)
            .acos();
        if angle < MIN_CORNER_ANGLE_RAD {
            continue;
        }
        let Some(x) = a.line.intersect(&b.line) else {
            continue;
        };
        if (x - run[break_at[i]]).norm() <= MAX_CORNER_SHIFT_PX {
            pieces[i].end = x;
            pieces[j].start = x;
            pieces[i].joined.1 = true;
            pieces[j].joined.0 = true;
        }
    }
    pieces
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(x: f64, y: f64) -> Point2<f64> {
        Point2::new(x, y)
    }

    #[test]
    fn moments_refit_the_union_of_two_point_sets() {
        let pts: Vec<_> = (0..30)
            .map(|i| {
                p(
                    i as f64,
                    0.5 * i as f64 + if i % 3 == 0 { 0.2 } else { -0.1 },
                )
            })
            .collect();
        let direct = fit_line(&pts).unwrap();
        let joined = Moments::of(&pts[..12]).add(&Moments::of(&pts[12..]));
        let fit = joined.fit(Vector2::new(1.0, 0.0)).unwrap();
        assert!((fit.line.centroid - direct.centroid).norm() < 1e-9);
        assert!((fit.line.direction - direct.direction).norm() < 1e-9);
        let spread = fit_spread(&pts, &direct);
        assert!((fit.across_px2 - spread.rms_px.powi(2)).abs() < 1e-9);
        let along = pts
            .iter()
            .map(|q| (q - direct.centroid).dot(&direct.direction).powi(2))
            .sum::<f64>()
            / 30.0;
        assert!((fit.along_px2 - along).abs() < 1e-6);
        // Directed as asked.
        let back = joined.fit(Vector2::new(-1.0, 0.0)).unwrap();
        assert!((back.line.direction + direct.direction).norm() < 1e-9);
        assert!(Moments::of(&[p(1.0, 1.0)]).fit(Vector2::x()).is_none());
    }

    #[test]
    fn fits_a_line_and_measures_distances() {
        let pts = [p(0.0, 1.0), p(1.0, 2.0), p(2.0, 3.0)];
        let l = fit_line(&pts).unwrap();
        assert!((l.direction - Vector2::new(1.0, 1.0).normalize()).norm() < 1e-9);
        assert!(l.distance(p(1.0, 2.0)).abs() < 1e-9);
        assert!((l.distance(p(0.0, 0.0)).abs() - 0.5f64.sqrt()).abs() < 1e-9);
        assert!(fit_line(&[p(1.0, 1.0), p(1.0, 1.0)]).is_none());
        let other = fit_line(&[p(0.0, 3.0), p(3.0, 0.0)]).unwrap();
        let x = l.intersect(&other).unwrap();
        assert!((x - p(1.0, 2.0)).norm() < 1e-9);
    }

    /// An L: 20 points right along v = 0, then 15 down along u = 20, with alternating noise.
    fn ell() -> Vec<Point2<f64>> {
        let mut pts: Vec<_> = (0..=20)
            .map(|i| p(i as f64, if i % 2 == 0 { 0.1 } else { -0.1 }))
            .collect();
        pts.extend((1..=15).map(|i| p(20.0 + if i % 2 == 0 { 0.1 } else { -0.1 }, i as f64)));
        pts
    }

    #[test]
    fn an_ell_becomes_two_pieces_meeting_at_the_corner() {
        let pieces = approximate(&ell(), false, 1.0, 1);
        assert_eq!(pieces.len(), 2, "{pieces:?}");
        assert!((pieces[0].start - p(0.0, 0.0)).norm() < 0.2);
        assert_eq!(pieces[0].end, pieces[1].start, "shared vertex");
        assert!(
            (pieces[0].end - p(20.0, 0.0)).norm() < 0.2,
            "{:?}",
            pieces[0].end
        );
        assert!((pieces[1].end - p(20.0, 15.0)).norm() < 0.2);
    }

    #[test]
    fn merge_undoes_splits_of_a_straight_run() {
        let pts: Vec<_> = (0..40).map(|i| p(i as f64, 0.0)).collect();
        // A split made at arbitrary points of a straight run is merged back.
        assert_eq!(merge(&pts, &[0, 10, 25, 39], 0.5), vec![0, 39]);
        assert_eq!(split(&pts, 0.5), vec![0, 39]);
    }

    #[test]
    fn a_closed_square_gives_four_sides() {
        let mut pts = Vec::new();
        for i in 0..10 {
            pts.push(p(i as f64, 0.0));
        }
        for i in 0..10 {
            pts.push(p(10.0, i as f64));
        }
        for i in 0..10 {
            pts.push(p(10.0 - i as f64, 10.0));
        }
        for i in 0..10 {
            pts.push(p(0.0, 10.0 - i as f64));
        }
        let pieces = approximate(&pts, true, 0.5, 0);
        assert_eq!(pieces.len(), 4, "{pieces:?}");
        for (k, corner) in [p(10.0, 0.0), p(10.0, 10.0), p(0.0, 10.0), p(0.0, 0.0)]
            .into_iter()
            .enumerate()
        {
            assert!(
                (pieces[k].end - corner).norm() < 1e-6,
                "{k}: {:?}",
                pieces[k]
            );
            assert_eq!(pieces[k].end, pieces[(k + 1) % 4].start);
        }
    }
}
