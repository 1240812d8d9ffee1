//! Plain segment data shared by every stage: 2D segments in pixels as they come in, and the
//! lists that carry them.

use nalgebra::{Point2, Point3};

/// √(a² + b²), two independent σ combined, or a vector's length, for the magnitudes a match
/// meets (pixels, metres, radians): `f64::hypot` guards against an overflow and underflow
/// these never reach at several times the cost, and the fits and the gate take it thousands
/// of times per match.
#[inline]
pub fn root_sum_square(a: f64, b: f64) -> f64 {
    (a * a + b * b).sqrt()
}

/// A 2D segment in (distorted, as observed) image pixels, from `start` to `end`.
///
/// When its list is oriented, walking from `start` to `end` the brighter side is on the
/// walker's left as seen on screen (v down): the gradient points along
/// `(end.y − start.y, −(end.x − start.x))`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment2 {
    pub start: Point2<f64>,
    pub end: Point2<f64>,
    /// Mean gradient magnitude along the segment, grey levels per pixel, when known.
    pub gradient: Option<f64>,
    /// How precisely the segment's line is known, when its source says (the extractor
    /// measures it from the edge points; a client may give it). `None`: the matcher's
    /// documented model for lists applies ([`LineNoise::for_list`]).
    pub noise: Option<LineNoise>,
}

/// The 1σ uncertainty of a 2D segment's line, in (undistorted) pixels: of its perpendicular
/// position at the segment's midpoint, and of its direction. The two are independent for a
/// least-squares line through points spread evenly along the segment, which is what both
/// sources below describe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineNoise {
    pub offset_px: f64,
    pub angle_rad: f64,
    /// σ of a shift of the whole line across itself that `offset_px` leaves out, pixels: the
    /// source's systematic error, which no number of points along the line averages away and
    /// which the views do not share. It widens what the 3D segment reports, not the fit or
    /// the tests between the views ([`crate::geometry::line::LineObservation::systematic_px`]).
    pub shift_px: f64,
}

impl LineNoise {
    /// Pixels of segment per independent edge point, for lists that do not say how precise
    /// their segments are: detectors fit a line to the edge pixels along the segment, whose
    /// errors are correlated over about this span.
    pub const LIST_POINT_SPACING_PX: f64 = 2.0;

    /// The line through two endpoints each off by an independent `sigma_px` across it, on a
    /// segment `length_px` long: for a source that knows only "endpoints good to σ".
    pub fn from_endpoint_sigma(sigma_px: f64, length_px: f64) -> LineNoise {
        LineNoise {
            offset_px: sigma_px / std::f64::consts::SQRT_2,
            angle_rad: std::f64::consts::SQRT_2 * sigma_px / length_px.max(1e-9),
            shift_px: 0.0,
        }
    }

    /// The line fitted by least squares to `points` edge points spread evenly over
    /// `length_px`, each off the line by independent noise `sigma_px`.
    pub fn from_point_fit(sigma_px: f64, points: f64, length_px: f64) -> LineNoise {
        let n = points.max(2.0);
        LineNoise {
            offset_px: sigma_px / n.sqrt(),
            angle_rad: sigma_px * (12.0 / n).sqrt() / length_px.max(1e-9),
            shift_px: 0.0,
        }
    }

    /// The model for a segment of a list that gives no noise of its own: a line fitted to
    /// one independent point every [`LineNoise::LIST_POINT_SPACING_PX`], each off by
    /// `point_sigma_px` (`MatchOptions.line_noise_px`).
    pub fn for_list(point_sigma_px: f64, length_px: f64) -> LineNoise {
        LineNoise::from_point_fit(
            point_sigma_px,
            length_px / Self::LIST_POINT_SPACING_PX,
            length_px,
        )
    }
}

impl Segment2 {
    pub fn new(start: Point2<f64>, end: Point2<f64>) -> Segment2 {
        Segment2 {
            start,
            end,
            gradient: None,
            noise: None,
        }
    }

    pub fn length(&self) -> f64 {
        (self.end - self.start).norm()
    }
}

/// The segments of one image.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SegmentList {
    pub segments: Vec<Segment2>,
    /// True when every segment is oriented by contrast.
    pub oriented: bool,
    /// The median gradient magnitude of the image the segments come from, grey levels per
    /// pixel (`extract::gradient::background_magnitude`): the contrast of its noise and
    /// texture. `None` when unknown (a list from elsewhere that does not say).
    pub background_gradient: Option<f64>,
}

/// A 3D segment in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment3 {
    pub start: Point3<f64>,
    pub end: Point3<f64>,
}

impl Segment3 {
    pub fn length(&self) -> f64 {
        (self.end - self.start).norm()
    }
}

/// Farthest a parallel neighbour may be to disturb a segment's line, pixels.
pub const CROWDING_RADIUS_PX: f64 = 8.0;
/// How much a parallel neighbour `d` px away disturbs a segment's line: an extra offset σ of
/// `peak_px · exp(−d² / 2·spread_px²)`, at most d/2 (two edges closer than that are seen as
/// one, between them). Two edges closer than a few pixels blur into each other before they
/// are located, and each pulls the other's line off; how far depends on how much the image
/// was blurred before the edges were located.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CrowdingModel {
    pub peak_px: f64,
    pub spread_px: f64,
    /// The systematic part of a neighbour of opposite contrast's disturbance, where it is
    /// corrected (a list's line detector); `None`: all of it is noise (our extractor).
    pub repulsion: Option<Repulsion>,
}

/// Two edges of opposite contrast a few pixels apart — the two sides of a stripe, a gap
/// between books — push each other's located line apart, by an amount the distance between
/// them decides: 91–99% of OpenCV LSD's lines beside such a neighbour 2–4 px away are off
/// away from it, by a median that falls with the distance like a Gaussian
/// (`tools/line_noise_study.py`, its table by the neighbour's contrast). That part is a
/// bias, not noise: the line is moved back toward the neighbour by
/// `peak_px · pull · exp(−d² / 2·spread_px²)` (at most d/4), `pull` the neighbour's
/// gradient over the segment's (at most 3; 1 when either is unknown), and what stays
/// uncertain is `residual_share` of that push, as an endpoint noise in place of the
/// crowding noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Repulsion {
    pub peak_px: f64,
    pub spread_px: f64,
    pub residual_share: f64,
}

/// How LSD's push falls with the distance, pixels (a Gaussian's σ), and the share of it that
/// stays as noise once the line is moved back ([`CrowdingModel::LISTS`]).
const LSD_PUSH_SPREAD_PX: f64 = 1.61;
const LSD_PUSH_RESIDUAL_SHARE: f64 = 0.45;

/// Largest gradient ratio a neighbour's push scales by: a far stronger neighbour's tail
/// swamps the segment's own peak, and a push proportional to it no longer holds.
const MAX_REPULSION_PULL: f64 = 3.0;

impl Repulsion {
    /// How far a line is pushed away from a neighbour of opposite contrast `distance_px`
    /// away whose gradient is `pull` times its own, pixels.
    pub fn push_px(&self, distance_px: f64, pull: f64) -> f64 {
        if !(distance_px > 0.0 && distance_px < CROWDING_RADIUS_PX) || pull.is_nan() {
            return 0.0;
        }
        let gaussian =
            (-(distance_px * distance_px) / (2.0 * self.spread_px * self.spread_px)).exp();
        (self.peak_px * pull.clamp(0.0, MAX_REPULSION_PULL) * gaussian).min(0.25 * distance_px)
    }
}

/// The blur of an edge in the rendered rooms before any smoothing, as a Gaussian σ, pixels
/// squared: fitted so that the crowding measured after smoothing by 1 px and by 0.5 px
/// (`tools/line_noise_study.py`) scales with the total blur √(σ² + this).
const EDGE_BLUR2_PX2: f64 = 0.27;

impl CrowdingModel {
    /// Measured on the rendered rooms after smoothing by 1 px: segments longer than 40 px
    /// with a parallel neighbour within 3 px are off their true line by a median 0.58 px,
    /// within 3–5 px 0.15 px, beyond 5 px 0.01 px.
    const AT_UNIT_SMOOTHING: CrowdingModel = CrowdingModel {
        peak_px: 1.35,
        spread_px: 2.2,
        repulsion: None,
    };

    /// Segments from a list a client sent: its extractor's blur is unknown, so it is taken
    /// for ours at 1 px of smoothing, about the scale line detectors smooth at — except a
    /// neighbour of opposite contrast, whose push is corrected as measured on OpenCV's LSD
    /// (default parameters; the shared rooms' lists, 1,600 lines on a true edge with such a
    /// neighbour): a median push of 0.61 px at 2–2.5 px, 0.42 px at 2.5–3, 0.21 px at 3–3.5,
    /// 0.13 px at 3.5–4, 0.05 px at 4–4.5, none beyond. LSD locates a line as the centroid of
    /// its support region, and a neighbour's region cuts its own short on that side. Moved
    /// back, such a line is off by a robust σ of 0.26, 0.20, 0.08, 0.06 px in those bins,
    /// about 0.45 of the push over the 0.04–0.06 px of a line alone. (Our own extractor's
    /// lines are pushed too, a third as far at no smoothing; corrected the same way it gave
    /// the lab a far segment more: docs/ACCURACY.md.)
    ///
    /// `push_px` scales that push (`MatchOptions.list_push_px`, default [`Self::LSD_PUSH_PX`]);
    /// 0 corrects nothing, and the crowding noise is the extractor's at 1 px.
    pub const fn lists(push_px: f64) -> CrowdingModel {
        CrowdingModel {
            repulsion: if push_px > 0.0 {
                Some(Repulsion {
                    peak_px: push_px,
                    spread_px: LSD_PUSH_SPREAD_PX,
                    residual_share: LSD_PUSH_RESIDUAL_SHARE,
                })
            } else {
                None
            },
            ..Self::AT_UNIT_SMOOTHING
        }
    }

    /// The push of an opposite-contrast neighbour at full strength on OpenCV LSD's lines.
    pub const LSD_PUSH_PX: f64 = 1.63;
    /// The lists' model as it is by default.
    pub const LISTS: CrowdingModel = Self::lists(Self::LSD_PUSH_PX);

    /// For edges located after Gaussian smoothing by `smoothing_sigma_px`: the spread scales
    /// with the total blur, the peak stays (a neighbour close enough still pulls as hard). After 0.5 px of smoothing, neighbours within 2–3 px shift
    /// a line by a median 0.11 px and within 3–4 px by 0.025 px.
    pub fn for_smoothing(smoothing_sigma_px: f64) -> CrowdingModel {
        let sigma2 = if smoothing_sigma_px.is_finite() {
            smoothing_sigma_px.max(0.0).powi(2)
        } else {
            1.0
        };
        let scale = ((sigma2 + EDGE_BLUR2_PX2) / (1.0 + EDGE_BLUR2_PX2)).sqrt();
        CrowdingModel {
            peak_px: Self::AT_UNIT_SMOOTHING.peak_px,
            spread_px: Self::AT_UNIT_SMOOTHING.spread_px * scale,
            repulsion: None,
        }
    }

    /// The distance at which a full-strength neighbour pulls as much as one at `distance_px`
    /// whose gradient is `pull` times this segment's (the pull is proportional to it).
    fn equivalent_distance(&self, distance_px: f64, pull: f64) -> f64 {
        let spread2 = 2.0 * self.spread_px * self.spread_px;
        (distance_px * distance_px - spread2 * pull.ln()).sqrt()
    }
}

/// Segments closer to each other than this across are pieces of one line, not neighbours.
const COLLINEAR_PX: f64 = 0.3;
/// Largest angle between two segments that count as parallel neighbours.
const PARALLEL_COS: f64 = 0.985; // 10°

impl LineNoise {
    /// This noise with the disturbance of a parallel neighbour `distance_px` away added
    /// (nothing beyond [`CROWDING_RADIUS_PX`]). The neighbour shifts the line by a varying
    /// amount where it runs alongside, so the direction suffers as if both ends moved.
    pub fn crowded(self, distance_px: f64, length_px: f64, model: CrowdingModel) -> LineNoise {
        if distance_px.is_nan() || distance_px >= CROWDING_RADIUS_PX {
            return self;
        }
        // No edge is pulled past the middle between the two: closer than that they are one.
        let extra = (model.peak_px
            * (-(distance_px * distance_px) / (2.0 * model.spread_px * model.spread_px)).exp())
        .min(0.5 * distance_px);
        let other = LineNoise::from_endpoint_sigma(extra, length_px);
        LineNoise {
            offset_px: root_sum_square(self.offset_px, other.offset_px),
            angle_rad: root_sum_square(self.angle_rad, other.angle_rad),
            ..self
        }
    }
}

impl LineNoise {
    /// This noise crowded by its neighbours, and the correction of its line for the push of
    /// its nearest neighbour of opposite contrast where the model corrects it
    /// ([`Repulsion`]). A line whose nearest neighbour (`distance_px`, as
    /// [`Crowding::distances`] measures it) is that one keeps the residual of the push as
    /// its crowding noise; any other, [`LineNoise::crowded`].
    pub fn crowded_and_corrected(
        self,
        distance_px: f64,
        opposite: Option<Opposite>,
        length_px: f64,
        model: CrowdingModel,
    ) -> (LineNoise, Option<Correction>) {
        let (Some(opposite), Some(repulsion)) = (opposite, model.repulsion) else {
            return (self.crowded(distance_px, length_px, model), None);
        };
        let correction = opposite.correction(&repulsion);
        // A weaker neighbour's distance is lengthened, never shortened: when the opposite
        // one is the nearest, the distance is at least its own.
        let noise = if distance_px >= opposite.distance_px {
            let residual = LineNoise::from_endpoint_sigma(
                std::f64::consts::SQRT_2 * repulsion.residual_share * correction.push_px,
                length_px,
            );
            LineNoise {
                offset_px: root_sum_square(self.offset_px, residual.offset_px),
                angle_rad: root_sum_square(self.angle_rad, residual.angle_rad),
                ..self
            }
        } else {
            self.crowded(distance_px, length_px, model)
        };
        (noise, Some(correction))
    }
}

/// Most candidates a crowding query looks at.
const MAX_CROWDING_CANDIDATES: usize = 1536;
/// Side of the windows of [`Crowding`]'s grid over the segments' midpoints, pixels (about
/// twice [`CROWDING_RADIUS_PX`]: a query's rectangle, 16 px across, spans two or three).
const CROWDING_CELL_PX: f64 = 16.0;

/// For each segment, the distance to its nearest parallel neighbour that runs alongside it
/// (the neighbour's midpoint projects onto the segment), pixels across — lengthened for a
/// neighbour of weaker gradient, which pulls less (both gradients known); `f64::INFINITY` when
/// none is within [`CROWDING_RADIUS_PX`]. Segments on one line (closer than a third of a
/// pixel) are pieces, not neighbours.
///
/// The segments' midpoints are put in a grid of square windows; a segment looks only in the
/// windows that the rectangle a neighbour's midpoint can lie in (alongside it, within the
/// radius across) touches. The grid covers the midpoints' bounding box with at most a few
/// windows per segment, so it never grows with the image.
pub fn crowding(segments: &[Segment2], model: CrowdingModel) -> Vec<f64> {
    let all: Vec<usize> = (0..segments.len()).collect();
    Crowding::new(segments).distances(segments, &all, model)
}

/// A segment's nearest neighbour of opposite contrast ([`Crowding::distances_and_opposites`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Opposite {
    /// How far across, pixels.
    pub distance_px: f64,
    /// Unit normal of the segment toward the neighbour.
    pub toward: nalgebra::Vector2<f64>,
    /// The neighbour's gradient over the segment's (1 when either is unknown).
    pub pull: f64,
    /// Where along the segment the neighbour runs beside it, as fractions of its length
    /// from its start.
    pub alongside: (f64, f64),
}

/// How a line is corrected for a neighbour's push ([`Opposite::correction`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correction {
    /// Moves of the segment's two ends, pixels.
    pub start: nalgebra::Vector2<f64>,
    pub end: nalgebra::Vector2<f64>,
    /// The push at the segment's middle, pixels.
    pub push_px: f64,
}

impl Opposite {
    /// The correction of the segment's line under `model`. The push acts only where the
    /// neighbour runs beside it, so the line fitted to the segment's points moved there is
    /// shifted by the share alongside and turned by their lever arm (least squares over
    /// evenly spread points): its ends are moved back by that line's value at each end.
    pub fn correction(&self, model: &Repulsion) -> Correction {
        let push = model.push_px(self.distance_px, self.pull);
        let (a, b) = (self.alongside.0 - 0.5, self.alongside.1 - 0.5);
        // Points at t ∈ [−½, ½] displaced by `push` over [a, b]: offset push·(b − a), slope
        // push·((b² − a²)/2) / (1/12).
        let offset = push * (b - a);
        let slope = push * 6.0 * (b * b - a * a);
        Correction {
            start: self.toward * (offset - 0.5 * slope),
            end: self.toward * (offset + 0.5 * slope),
            push_px: offset,
        }
    }
}

/// What a crowding query asks of a segment, computed once.
struct Shape {
    start: Point2<f64>,
    dir: nalgebra::Vector2<f64>,
    mid: Point2<f64>,
    len: f64,
}

/// One segment in its window of the grid: what a query reads, laid out in a row.
#[derive(Clone, Copy)]
struct Entry {
    dir: nalgebra::Vector2<f64>,
    mid: Point2<f64>,
    index: u32,
}

/// The index behind [`crowding`]: built once per list, asked as often as needed.
pub struct Crowding {
    shapes: Vec<Option<Shape>>,
    /// The grid: window (cx, cy) holds `entries[starts[cy·nx + cx]..starts[cy·nx + cx + 1]]`.
    origin: Point2<f64>,
    cell: f64,
    nx: usize,
    ny: usize,
    starts: Vec<u32>,
    entries: Vec<Entry>,
    /// The longest segment's length, pixels: how far a midpoint can be from the segments it
    /// overlaps.
    longest: f64,
}

impl Crowding {
    pub fn new(segments: &[Segment2]) -> Crowding {
        let shapes: Vec<Option<Shape>> = segments
            .iter()
            .map(|s| {
                let len = s.length();
                if !(len > 0.0 && len.is_finite()) {
                    return None;
                }
                Some(Shape {
                    start: s.start,
                    dir: (s.end - s.start) / len,
                    mid: nalgebra::center(&s.start, &s.end),
                    len,
                })
            })
            .collect();
        let (mut lo, mut hi) = (
            Point2::new(f64::INFINITY, f64::INFINITY),
            Point2::new(f64::NEG_INFINITY, f64::NEG_INFINITY),
        );
        for sh in shapes.iter().flatten() {
            lo = lo.inf(&sh.mid);
            hi = hi.sup(&sh.mid);
        }
        if !(lo.x <= hi.x && lo.y <= hi.y) {
            (lo, hi) = (Point2::origin(), Point2::origin());
        }
        // Far-flung midpoints (a client's list may hold any coordinates) widen the windows
        // rather than multiply them: at most about four per segment.
        let count = shapes.iter().flatten().count();
        let max_cells = (4 * count).max(64) as f64;
        let (w, h) = (hi.x - lo.x, hi.y - lo.y);
        let mut cell = CROWDING_CELL_PX;
        while (w / cell + 1.0) * (h / cell + 1.0) > max_cells {
            cell *= 2.0;
        }
        let nx = (w / cell) as usize + 1;
        let ny = (h / cell) as usize + 1;
        let cell_of = |p: &Point2<f64>| {
            let cx = (((p.x - lo.x) / cell) as usize).min(nx - 1);
            let cy = (((p.y - lo.y) / cell) as usize).min(ny - 1);
            cy * nx + cx
        };
        let mut starts = vec![0u32; nx * ny + 1];
        for sh in shapes.iter().flatten() {
            starts[cell_of(&sh.mid) + 1] += 1;
        }
        for c in 0..nx * ny {
            starts[c + 1] += starts[c];
        }
        let mut cursor = starts.clone();
        let mut entries = vec![
            Entry {
                dir: nalgebra::Vector2::zeros(),
                mid: Point2::origin(),
                index: 0,
            };
            count
        ];
        for (i, shape) in shapes.iter().enumerate() {
            if let Some(sh) = shape {
                let c = cell_of(&sh.mid);
                entries[cursor[c] as usize] = Entry {
                    dir: sh.dir,
                    mid: sh.mid,
                    index: i as u32,
                };
                cursor[c] += 1;
            }
        }
        let longest = shapes.iter().flatten().map(|sh| sh.len).fold(0.0, f64::max);
        Crowding {
            shapes,
            origin: lo,
            cell,
            nx,
            ny,
            starts,
            entries,
            longest,
        }
    }

    /// The crowding distance of each segment at `queries` (indices into the `segments` the
    /// index was built from).
    /// `model` says how a weaker neighbour's pull compares with a stronger one's.
    pub fn distances(
        &self,
        segments: &[Segment2],
        queries: &[usize],
        model: CrowdingModel,
    ) -> Vec<f64> {
        queries
            .iter()
            .map(|&i| self.nearest(segments, i, model, false).0)
            .collect()
    }

    /// For each segment at `queries`, [`Crowding::distances`]'s distance and, found in the
    /// same walk of the grid, its nearest neighbour of opposite contrast alongside (within
    /// [`CROWDING_RADIUS_PX`] across, its midpoint projecting onto the segment): the one whose
    /// push ([`Repulsion`]) it feels. Meaningful for oriented segments only.
    pub fn distances_and_opposites(
        &self,
        segments: &[Segment2],
        queries: &[usize],
        model: CrowdingModel,
    ) -> Vec<(f64, Option<Opposite>)> {
        queries
            .iter()
            .map(|&i| self.nearest(segments, i, model, true))
            .collect()
    }

    /// Segment `i`'s crowding distance under `model` and (if `opposite`) its nearest
    /// neighbour of opposite contrast.
    fn nearest(
        &self,
        segments: &[Segment2],
        i: usize,
        model: CrowdingModel,
        opposite: bool,
    ) -> (f64, Option<Opposite>) {
        let Some(sh) = &self.shapes[i] else {
            return (f64::INFINITY, None);
        };
        let s = &segments[i];
        let normal = nalgebra::Vector2::new(-sh.dir.y, sh.dir.x);
        let mut best = f64::INFINITY;
        let mut best_opposite: Option<Opposite> = None;
        self.for_each_near(i, CROWDING_RADIUS_PX, 0.0, |j, along, across| {
            if !(along > 0.0 && along < sh.len && across > COLLINEAR_PX) {
                return;
            }
            // The neighbour's gradient over the segment's, where both are known.
            let ratio = match (s.gradient, segments[j].gradient) {
                (Some(mine), Some(theirs)) if mine > 0.0 => Some(theirs / mine),
                _ => None,
            };
            // A weaker neighbour pulls less: as if it were farther.
            let pull = ratio.map_or(1.0, |r| r.clamp(1e-3, 1.0));
            best = best.min(model.equivalent_distance(across, pull));
            let Some(other) = self.shapes[j].as_ref().filter(|_| opposite) else {
                return;
            };
            if other.dir.dot(&sh.dir) >= 0.0
                || best_opposite.is_some_and(|b| b.distance_px <= across)
            {
                return;
            }
            let side = (other.mid - sh.start).dot(&normal).signum();
            let (a, b) = (
                (segments[j].start - sh.start).dot(&sh.dir),
                (segments[j].end - sh.start).dot(&sh.dir),
            );
            let (from, to) = (a.min(b).clamp(0.0, sh.len), a.max(b).clamp(0.0, sh.len));
            best_opposite = Some(Opposite {
                distance_px: across,
                toward: normal * side,
                pull: ratio.filter(|r| *r >= 0.0).unwrap_or(1.0),
                alongside: (from / sh.len, to / sh.len),
            });
        });
        let distance = if best <= CROWDING_RADIUS_PX {
            best
        } else {
            f64::INFINITY
        };
        (distance, best_opposite)
    }

    /// The segments within 10° of segment `i`'s line, either way round, that lie alongside
    /// it: their midpoint within `reach_px` across it, and the two overlapping along it; each
    /// with that distance across, nearest first.
    pub fn alongside(&self, segments: &[Segment2], i: usize, reach_px: f64) -> Vec<(u32, f64)> {
        let len = self.shapes[i].as_ref().map_or(0.0, |sh| sh.len);
        let mut found = Vec::new();
        self.for_each_near(i, reach_px, 0.5 * self.longest, |j, along, across| {
            let half = 0.5 * segments[j].length();
            if along > -half && along < len + half {
                found.push((j as u32, across));
            }
        });
        found.sort_unstable_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        found
    }

    /// Calls `visit(j, along, across)` for each segment j ≠ i within 10° of segment i's line
    /// (either way round) whose midpoint lies at most `reach_px` across it and from
    /// `beyond_px` before its start to `beyond_px` past its end along it (`along` from its
    /// start).
    fn for_each_near(
        &self,
        i: usize,
        reach_px: f64,
        beyond_px: f64,
        mut visit: impl FnMut(usize, f64, f64),
    ) {
        let Some(sh) = &self.shapes[i] else {
            return;
        };
        // A neighbour's midpoint lies in the rectangle from `beyond_px` before the start to
        // `beyond_px` past the end along the segment, `reach_px` either side across it: the
        // windows its bounding box touches (widened by a rounding margin) hold every such
        // midpoint; each is then tested exactly.
        const ROUNDING_PX: f64 = 1e-6;
        let n = nalgebra::Vector2::new(-sh.dir.y, sh.dir.x);
        let half_extent = (0.5 * sh.len + beyond_px) * sh.dir.abs() + reach_px * n.abs();
        let centre = sh.mid;
        let (lo, hi) = (
            centre - half_extent.add_scalar(ROUNDING_PX),
            centre + half_extent.add_scalar(ROUNDING_PX),
        );
        let index = |v: f64, origin: f64, n: usize| -> Option<usize> {
            let k = ((v - origin) / self.cell).floor();
            (k.is_finite()).then(|| k.clamp(0.0, (n - 1) as f64) as usize)
        };
        if hi.x < self.origin.x
            || hi.y < self.origin.y
            || lo.x > self.origin.x + self.nx as f64 * self.cell
            || lo.y > self.origin.y + self.ny as f64 * self.cell
        {
            return;
        }
        let (Some(x0), Some(x1), Some(y0), Some(y1)) = (
            index(lo.x, self.origin.x, self.nx),
            index(hi.x, self.origin.x, self.nx),
            index(lo.y, self.origin.y, self.ny),
            index(hi.y, self.origin.y, self.ny),
        ) else {
            return;
        };
        // A client's list may pile thousands of copies onto one place: the scan is bounded,
        // and a segment with that many candidates is crowded anyway.
        let mut budget = MAX_CROWDING_CANDIDATES;
        for cy in y0..=y1 {
            let row = cy * self.nx;
            let cells =
                &self.entries[self.starts[row + x0] as usize..self.starts[row + x1 + 1] as usize];
            for other in cells {
                if budget == 0 {
                    return;
                }
                budget -= 1;
                let j = other.index as usize;
                if j == i || other.dir.dot(&sh.dir).abs() < PARALLEL_COS {
                    continue;
                }
                let along = (other.mid - sh.start).dot(&sh.dir);
                let across = (other.mid - sh.start).dot(&n).abs();
                if along > -beyond_px && along < sh.len + beyond_px && across <= reach_px {
                    visit(j, along, across);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_finds_exactly_the_neighbours_every_pair_would() {
        // Random segments, many near-parallel (a room's), some far away: each query's visits
        // are those of the definition applied to every other segment.
        let mut rng = trinocular_synth::Rng::new(11);
        let mut uniform = |lo: f64, hi: f64| rng.range(lo, hi);
        let mut segments: Vec<Segment2> = (0..400)
            .map(|k| {
                let (x, y) = (uniform(0.0, 300.0), uniform(0.0, 300.0));
                let angle = if k % 3 == 0 {
                    uniform(0.0, std::f64::consts::TAU)
                } else {
                    (k % 2) as f64 * std::f64::consts::FRAC_PI_2 + uniform(-0.2, 0.2)
                };
                let len = uniform(2.0, 80.0);
                seg((x, y), (x + len * angle.cos(), y + len * angle.sin()))
            })
            .collect();
        segments.push(seg((5000.0, -3000.0), (5040.0, -3000.0)));
        let index = Crowding::new(&segments);
        for (reach, beyond) in [(CROWDING_RADIUS_PX, 0.0), (16.0, 0.5 * index.longest)] {
            for i in 0..segments.len() {
                let mut got = Vec::new();
                index.for_each_near(i, reach, beyond, |j, along, across| {
                    got.push((j, along.to_bits(), across.to_bits()))
                });
                got.sort_unstable();
                let sh = index.shapes[i].as_ref().unwrap();
                let n = nalgebra::Vector2::new(-sh.dir.y, sh.dir.x);
                let expected: Vec<(usize, u64, u64)> = index
                    .shapes
                    .iter()
                    .enumerate()
                    .filter_map(|(j, other)| {
                        let other = other.as_ref()?;
                        let along = (other.mid - sh.start).dot(&sh.dir);
                        let across = (other.mid - sh.start).dot(&n).abs();
                        (j != i
                            && other.dir.dot(&sh.dir).abs() >= PARALLEL_COS
                            && along > -beyond
                            && along < sh.len + beyond
                            && across <= reach)
                            .then_some((j, along.to_bits(), across.to_bits()))
                    })
                    .collect();
                assert_eq!(got, expected, "segment {i}");
            }
        }
    }

    fn seg(a: (f64, f64), b: (f64, f64)) -> Segment2 {
        Segment2::new(Point2::new(a.0, a.1), Point2::new(b.0, b.1))
    }

    #[test]
    fn crowding_finds_parallel_neighbours_alongside_and_nothing_else() {
        let segments = [
            seg((0.0, 0.0), (100.0, 0.0)),
            seg((10.0, 3.0), (60.0, 3.5)), // parallel, alongside, 3 px away
            seg((0.0, 40.0), (100.0, 40.0)), // parallel but far
            seg((50.0, 5.0), (50.0, 30.0)), // close but perpendicular
            seg((120.0, 0.0), (160.0, 0.0)), // collinear piece
        ];
        let d = crowding(&segments, CrowdingModel::LISTS);
        assert!((d[0] - 3.25).abs() < 0.1, "{d:?}");
        assert!((d[1] - 3.4).abs() < 0.01, "{d:?}");
        assert!(
            d[2].is_infinite() && d[3].is_infinite() && d[4].is_infinite(),
            "{d:?}"
        );
        // A weaker neighbour counts as farther away.
        let mut weak = segments;
        weak[0].gradient = Some(40.0);
        weak[1].gradient = Some(4.0);
        let d = crowding(&weak, CrowdingModel::LISTS);
        assert!(d[0] > 5.0 && (d[1] - 3.4).abs() < 0.01, "{d:?}");
    }

    #[test]
    fn segments_alongside_overlap_either_way_round_within_reach() {
        let segments = [
            seg((0.0, 0.0), (100.0, 0.0)),
            seg((90.0, 6.0), (-30.0, 6.0)), // reversed, longer, midpoint before 0's middle
            seg((150.0, 5.0), (120.0, 5.0)), // in reach across but past the end
            seg((180.0, 10.0), (60.0, 10.5)), // midpoint past 0's end, still overlapping
            seg((20.0, 40.0), (80.0, 40.0)), // beyond reach
            seg((50.0, -10.0), (50.0, 10.0)), // across
        ];
        let index = Crowding::new(&segments);
        let found: Vec<u32> = index
            .alongside(&segments, 0, 16.0)
            .iter()
            .map(|&(j, _)| j)
            .collect();
        assert_eq!(found, vec![1, 3], "nearest first");
    }

    #[test]
    fn only_a_neighbour_of_opposite_contrast_alongside_pushes() {
        // Segments are oriented by contrast: a neighbour running the other way has the
        // opposite contrast.
        let segments = [
            seg((0.0, 0.0), (100.0, 0.0)),
            seg((80.0, 3.0), (20.0, 3.0)), // opposite, 3 px on the left (+y), x 20–80
            seg((0.0, -2.0), (100.0, -2.0)), // same contrast, nearer: crowds, does not push
            seg((100.0, 20.0), (0.0, 20.0)), // opposite but beyond reach
        ];
        let index = Crowding::new(&segments);
        let found: Vec<Option<Opposite>> = index
            .distances_and_opposites(&segments, &[0, 1, 2, 3], CrowdingModel::LISTS)
            .into_iter()
            .map(|(_, o)| o)
            .collect();
        let o = found[0].expect("segment 0 has an opposite neighbour");
        assert!((o.distance_px - 3.0).abs() < 1e-12, "{o:?}");
        assert!(
            (o.toward - nalgebra::Vector2::new(0.0, 1.0)).norm() < 1e-12,
            "{o:?}"
        );
        assert!((o.alongside.0 - 0.2).abs() < 1e-12 && (o.alongside.1 - 0.8).abs() < 1e-12);
        assert_eq!(o.pull, 1.0);
        // Segment 1 sees 0 (its midpoint alongside) below it, toward −y.
        let back = found[1].expect("segment 1 has an opposite neighbour");
        assert!((back.toward - nalgebra::Vector2::new(0.0, -1.0)).norm() < 1e-12);
        // Segment 2's only neighbour within reach (segment 0) has the same contrast; the one
        // of opposite contrast alongside, segment 1, is 5 px away.
        assert!((found[2].unwrap().distance_px - 5.0).abs() < 1e-12);
        assert!(found[3].is_none());
    }

    #[test]
    fn the_walk_for_opposites_finds_the_crowding_distance_too() {
        let mut rng = trinocular_synth::Rng::new(5);
        let segments: Vec<Segment2> = (0..300)
            .map(|_| {
                let (x, y) = (rng.range(0.0, 200.0), rng.range(0.0, 200.0));
                let angle = if rng.range(0.0, 1.0) < 0.5 {
                    0.0
                } else {
                    std::f64::consts::PI
                };
                let angle = angle + rng.range(-0.1, 0.1);
                let len = rng.range(5.0, 60.0);
                let mut s = seg((x, y), (x + len * angle.cos(), y + len * angle.sin()));
                s.gradient = Some(rng.range(5.0, 40.0));
                s
            })
            .collect();
        let index = Crowding::new(&segments);
        let all: Vec<usize> = (0..segments.len()).collect();
        let model = CrowdingModel::LISTS;
        let together = index.distances_and_opposites(&segments, &all, model);
        let distances: Vec<f64> = together.iter().map(|(d, _)| *d).collect();
        assert_eq!(distances, index.distances(&segments, &all, model));
        assert!(together.iter().filter(|(_, o)| o.is_some()).count() > 30);
    }

    #[test]
    fn a_push_falls_with_distance_and_never_exceeds_a_quarter_of_it() {
        let model = CrowdingModel::LISTS.repulsion.unwrap();
        let pushes: Vec<f64> = [1.0, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0]
            .iter()
            .map(|&d| model.push_px(d, 1.0))
            .collect();
        for (d, p) in [1.0, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0].iter().zip(&pushes) {
            assert!(*p >= 0.0 && *p <= 0.25 * d + 1e-12, "{d}: {p}");
        }
        assert!(pushes[2..].windows(2).all(|w| w[0] > w[1]), "{pushes:?}");
        // What the model was fitted to (LSD's median push by distance; within the spread).
        for (d, median) in [(2.75, 0.42), (3.25, 0.21), (3.75, 0.13), (4.25, 0.05)] {
            assert!((model.push_px(d, 1.0) - median).abs() < 0.06, "{d}");
        }
        assert_eq!(model.push_px(CROWDING_RADIUS_PX, 1.0), 0.0);
        assert_eq!(model.push_px(3.0, f64::NAN), 0.0);
        // A weaker neighbour pushes less, a far stronger one no more than thrice as hard.
        assert!(model.push_px(3.5, 0.5) < model.push_px(3.5, 1.0));
        assert_eq!(
            model.push_px(3.5, 10.0),
            model.push_px(3.5, MAX_REPULSION_PULL)
        );
    }

    #[test]
    fn a_correction_is_the_least_squares_line_of_the_points_pushed_alongside() {
        let model = CrowdingModel::LISTS.repulsion.unwrap();
        let toward = nalgebra::Vector2::new(0.0, 1.0);
        let opposite = |alongside| Opposite {
            distance_px: 3.0,
            toward,
            pull: 1.0,
            alongside,
        };
        let push = model.push_px(3.0, 1.0);
        // Alongside the whole segment: the line moves back by the whole push.
        let whole = opposite((0.0, 1.0)).correction(&model);
        assert!((whole.start - toward * push).norm() < 1e-12);
        assert!((whole.end - toward * push).norm() < 1e-12);
        // Alongside its second half: the least-squares line through evenly spread points, those
        // of the second half moved by the push, is what the ends follow.
        let half = opposite((0.5, 1.0)).correction(&model);
        let n = 2001;
        let (mut st, mut sy, mut stt, mut sty) = (0.0, 0.0, 0.0, 0.0);
        for k in 0..n {
            let t = k as f64 / (n - 1) as f64;
            let y = if t >= 0.5 { push } else { 0.0 };
            st += t;
            sy += y;
            stt += t * t;
            sty += t * y;
        }
        let nf = n as f64;
        let slope = (nf * sty - st * sy) / (nf * stt - st * st);
        let at_start = (sy - slope * st) / nf;
        assert!(
            (half.start.y - at_start).abs() < 2e-3,
            "{half:?} {at_start}"
        );
        assert!((half.end.y - (at_start + slope)).abs() < 2e-3, "{half:?}");
        assert!((half.push_px - 0.5 * push).abs() < 1e-12);
    }

    #[test]
    fn a_corrected_line_keeps_only_the_residual_of_the_push_as_noise() {
        let base = LineNoise::for_list(0.3, 60.0);
        let opposite = Opposite {
            distance_px: 3.0,
            toward: nalgebra::Vector2::new(0.0, 1.0),
            pull: 1.0,
            alongside: (0.0, 1.0),
        };
        let lists = CrowdingModel::LISTS;
        let (noise, correction) = base.crowded_and_corrected(3.0, Some(opposite), 60.0, lists);
        let crowded = base.crowded(3.0, 60.0, lists);
        let push = correction.expect("the list model corrects").push_px;
        assert!(push > 0.1 && noise.offset_px > base.offset_px, "{noise:?}");
        assert!(noise.offset_px < crowded.offset_px && noise.angle_rad < crowded.angle_rad);
        // A nearer neighbour of the same contrast crowds it as before; the push is still
        // undone.
        let (nearer, correction) = base.crowded_and_corrected(2.0, Some(opposite), 60.0, lists);
        assert_eq!(nearer, base.crowded(2.0, 60.0, lists));
        assert!(correction.is_some());
        // Our extractor's model corrects nothing.
        let ours = CrowdingModel::for_smoothing(0.0);
        let (noise, correction) = base.crowded_and_corrected(3.0, Some(opposite), 60.0, ours);
        assert_eq!((noise, correction), (base.crowded(3.0, 60.0, ours), None));
    }

    #[test]
    fn crowded_noise_grows_near_a_neighbour_and_not_far_away() {
        let base = LineNoise::for_list(0.3, 50.0);
        let model = CrowdingModel::LISTS;
        assert_eq!(base.crowded(f64::INFINITY, 50.0, model), base);
        assert_eq!(base.crowded(CROWDING_RADIUS_PX + 1.0, 50.0, model), base);
        let near = base.crowded(2.0, 50.0, model);
        let farther = base.crowded(5.0, 50.0, model);
        assert!(near.offset_px > farther.offset_px && farther.offset_px > base.offset_px);
        assert!(
            near.offset_px > 0.5,
            "a neighbour 2 px away moves a line by most of a pixel"
        );
    }

    #[test]
    fn crowding_reaches_less_far_after_less_smoothing() {
        let unit = CrowdingModel::for_smoothing(1.0);
        // A list is crowded as our extractor's lines at 1 px (and corrected as LSD's).
        assert_eq!(
            unit,
            CrowdingModel {
                repulsion: None,
                ..CrowdingModel::LISTS
            }
        );
        let light = CrowdingModel::for_smoothing(0.5);
        let base = LineNoise::for_list(0.05, 80.0);
        for d in [2.0, 3.0, 4.0] {
            assert!(base.crowded(d, 80.0, light).offset_px < base.crowded(d, 80.0, unit).offset_px);
        }
        // Nonsense smoothing falls back to the unit model rather than to no crowding at all.
        assert_eq!(CrowdingModel::for_smoothing(f64::NAN), unit);
    }
}
