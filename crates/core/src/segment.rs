//! Plain segment data shared by every stage: 2D segments in pixels as they come in, and the
//! lists that carry them.

use nalgebra::{Point2, Point3};

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
        }
    }

    /// The line fitted by least squares to `points` edge points spread evenly over
    /// `length_px`, each off the line by independent noise `sigma_px`.
    pub fn from_point_fit(sigma_px: f64, points: f64, length_px: f64) -> LineNoise {
        let n = points.max(2.0);
        LineNoise {
            offset_px: sigma_px / n.sqrt(),
            angle_rad: sigma_px * (12.0 / n).sqrt() / length_px.max(1e-9),
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
    };

    /// Segments from a list a client sent: its extractor's blur is unknown, so it is taken
    /// for ours at 1 px of smoothing, about the scale line detectors smooth at.
    pub const LISTS: CrowdingModel = Self::AT_UNIT_SMOOTHING;

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
            offset_px: self.offset_px.hypot(other.offset_px),
            angle_rad: self.angle_rad.hypot(other.angle_rad),
        }
    }
}

/// Most candidates a crowding query looks at per orientation bin.
const MAX_CROWDING_CANDIDATES: usize = 512;
/// Orientation bins of [`crowding`]: parallel neighbours (within 10°) share a bin or sit in
/// the next one.
const CROWDING_BINS: usize = 18;

/// For each segment, the distance to its nearest parallel neighbour that runs alongside it
/// (the neighbour's midpoint projects onto the segment), pixels across — lengthened for a
/// neighbour of weaker gradient, which pulls less (both gradients known); `f64::INFINITY` when
/// none is within [`CROWDING_RADIUS_PX`]. Segments on one line (closer than a third of a
/// pixel) are pieces, not neighbours.
///
/// Segments are sorted into 10° orientation bins, each by its position across the bin's
/// direction; a segment looks in its bin and the two next to it, in the window of positions
/// a neighbour alongside can have (O(n log n), no image-sized structure).
pub fn crowding(segments: &[Segment2], model: CrowdingModel) -> Vec<f64> {
    let all: Vec<usize> = (0..segments.len()).collect();
    Crowding::new(segments).distances(segments, &all, model)
}

/// What a crowding query asks of a segment, computed once.
struct Shape {
    start: Point2<f64>,
    dir: nalgebra::Vector2<f64>,
    mid: Point2<f64>,
    len: f64,
    bin: usize,
}

/// One segment in its orientation bin, sorted by position across the bin: what a query
/// reads, laid out in a row.
#[derive(Clone, Copy)]
struct Entry {
    rho: f64,
    dir: nalgebra::Vector2<f64>,
    mid: Point2<f64>,
    index: u32,
}

/// The orientation bin of a unit direction: by the fast approximate angle, and by the exact
/// one only where the two could disagree (within the approximation's error of a border).
fn orientation_bin(dir: nalgebra::Vector2<f64>, bin_width: f64) -> usize {
    use crate::angle::{angle_key, approx_angle_key, APPROX_ANGLE_KEY_ERROR};
    let bin_of = |theta: f64| ((theta / bin_width) as usize).min(CROWDING_BINS - 1);
    let approx = approx_angle_key(dir, std::f64::consts::PI);
    let lo = bin_of((approx - APPROX_ANGLE_KEY_ERROR).max(0.0));
    let hi = bin_of(approx + APPROX_ANGLE_KEY_ERROR);
    if lo == hi
        && approx > APPROX_ANGLE_KEY_ERROR
        && approx < std::f64::consts::PI - APPROX_ANGLE_KEY_ERROR
    {
        lo
    } else {
        bin_of(angle_key(dir, std::f64::consts::PI))
    }
}

/// The index behind [`crowding`]: built once per list, asked as often as needed.
pub struct Crowding {
    normals: [nalgebra::Vector2<f64>; CROWDING_BINS],
    shapes: Vec<Option<Shape>>,
    bins: Vec<Vec<Entry>>,
    /// The longest segment's length, pixels: how far a midpoint can be from the segments it
    /// overlaps.
    longest: f64,
}

impl Crowding {
    pub fn new(segments: &[Segment2]) -> Crowding {
        let bin_width = std::f64::consts::PI / CROWDING_BINS as f64;
        let normals: [nalgebra::Vector2<f64>; CROWDING_BINS] = std::array::from_fn(|b| {
            let theta = (b as f64 + 0.5) * bin_width;
            nalgebra::Vector2::new(-theta.sin(), theta.cos())
        });
        let normal_of_bin = |b: usize| normals[b];
        let shapes: Vec<Option<Shape>> = segments
            .iter()
            .map(|s| {
                let len = s.length();
                if !(len > 0.0 && len.is_finite()) {
                    return None;
                }
                let dir = (s.end - s.start) / len;
                let bin = orientation_bin(dir, bin_width);
                Some(Shape {
                    start: s.start,
                    dir,
                    mid: nalgebra::center(&s.start, &s.end),
                    len,
                    bin,
                })
            })
            .collect();
        let mut bins: Vec<Vec<Entry>> = vec![Vec::new(); CROWDING_BINS];
        for (i, shape) in shapes.iter().enumerate() {
            if let Some(sh) = shape {
                bins[sh.bin].push(Entry {
                    rho: sh.mid.coords.dot(&normal_of_bin(sh.bin)),
                    dir: sh.dir,
                    mid: sh.mid,
                    index: i as u32,
                });
            }
        }
        for b in &mut bins {
            b.sort_unstable_by(|x, y| x.rho.total_cmp(&y.rho));
        }
        let longest = shapes.iter().flatten().map(|sh| sh.len).fold(0.0, f64::max);
        Crowding {
            normals,
            shapes,
            bins,
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
        let radius = CROWDING_RADIUS_PX;
        queries
            .iter()
            .map(|&i| {
                let s = &segments[i];
                let mut best = f64::INFINITY;
                let len = self.shapes[i].as_ref().map_or(0.0, |sh| sh.len);
                self.for_each_near(i, radius, 0.0, |j, along, across| {
                    if along > 0.0 && along < len && across > COLLINEAR_PX {
                        // A weaker neighbour pulls less: as if it were farther.
                        let pull = match (s.gradient, segments[j].gradient) {
                            (Some(mine), Some(theirs)) if mine > 0.0 => {
                                (theirs / mine).clamp(1e-3, 1.0)
                            }
                            _ => 1.0,
                        };
                        best = best.min(model.equivalent_distance(across, pull));
                    }
                });
                if best <= radius {
                    best
                } else {
                    f64::INFINITY
                }
            })
            .collect()
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
        // A neighbour's midpoint is within `reach_px` across this segment and its half length
        // (plus `beyond_px`) along it from its midpoint; measured across bin b's direction,
        // which is off the segment's by an angle θ, that is within
        // reach·|cos θ| + (½·length + beyond)·|sin θ| — and
        // |sin θ| is the segment's direction dotted with the bin's normal. A bin nearly
        // parallel to the segment is searched in a narrow window, the next ones wider.
        const ROUNDING_PX: f64 = 1e-6;
        let n = nalgebra::Vector2::new(-sh.dir.y, sh.dir.x);
        for db in [CROWDING_BINS - 1, 0, 1] {
            let b = (sh.bin + db) % CROWDING_BINS;
            let normal = self.normals[b];
            let window =
                reach_px + (0.5 * sh.len + beyond_px) * sh.dir.dot(&normal).abs() + ROUNDING_PX;
            let rho = sh.mid.coords.dot(&normal);
            let list = &self.bins[b];
            let from = list.partition_point(|e| e.rho < rho - window);
            // A client's list may pile thousands of copies onto one line: the scan is
            // bounded, and a segment with that many candidates is crowded anyway.
            for other in list[from..].iter().take(MAX_CROWDING_CANDIDATES) {
                if other.rho > rho + window {
                    break;
                }
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
        assert_eq!(unit, CrowdingModel::LISTS);
        let light = CrowdingModel::for_smoothing(0.5);
        let base = LineNoise::for_list(0.05, 80.0);
        for d in [2.0, 3.0, 4.0] {
            assert!(base.crowded(d, 80.0, light).offset_px < base.crowded(d, 80.0, unit).offset_px);
        }
        // Nonsense smoothing falls back to the unit model rather than to no crowding at all.
        assert_eq!(CrowdingModel::for_smoothing(f64::NAN), unit);
    }
}
