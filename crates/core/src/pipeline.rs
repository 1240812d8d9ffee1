//! The whole matching pipeline in one call: segment lists in, triplets and 3D segments out.
//!
//! ```text
//! segment lists ─▶ check + undistort ─▶ rectify ─▶ bucket ─▶ predict ─▶ validate ⇄ reconstruct ─▶ merge fragments (reconstruct)
//! ```
//!
//! One entry point, [`run`]: from images it runs [`crate::extract`] on the three first (in
//! parallel).
//!
//! Input problems are errors that name the list, the segment and the coordinate; zero-length
//! segments are dropped and counted; empty lists give an empty result.

use rayon::prelude::*;
use rustc_hash::{FxHashMap, FxHashSet};
use std::time::Instant;

use nalgebra::Point2;
use thiserror::Error;

use crate::extract::{self, Adjacent, Extraction, GreyImage};
use crate::geometry::{
    estimate_line_constrained, estimate_line_through, DirectionOfLine, KnownDirection,
    Line3Estimate, LineObservation, PointOnLine, Rectification, RectifyError, Rig, RigFrames,
};
use crate::matching::{self, Hypothesis, MatchParams, ParamErrors, RectSegment, Views};
use crate::reconstruct::{
    fragment_groups, reconstruct, reconstruct_fragments, reconstruct_pieces, END_SIGMA_PX,
};
use crate::segment::{root_sum_square, CrowdingModel, LineNoise, Segment3, SegmentList};

/// How far outside the image a segment endpoint may lie, in image sizes: farther is not a
/// detector's imprecision but a unit or index mix-up.
const OUT_OF_IMAGE_MARGIN: f64 = 1.0;
/// Validation rounds at most (each after reconstruction rejected some winners); one or two
/// suffice in practice.
const MAX_VALIDATION_ROUNDS: usize = 4;
/// Triplets reconstructed between two questions to the checkpoint.
const RECONSTRUCT_CHUNK: usize = 4096;

pub use crate::checkpoint::{Checkpoint, Stopped};

/// What Match works on: three images, whose segments are extracted here (in parallel, view
/// 1's segment graph feeding validation), or three segment lists, with view 1's graph when
/// the client knows it (`graph`: indices into `lists[0]`, as [`crate::extract`] finds them;
/// validation then counts support across those vertices as well as between segments whose
/// ends are within `neighbour_radius_px`).
#[derive(Clone, Copy)]
pub enum Input<'a> {
    Images([&'a GreyImage; 3]),
    Lists {
        lists: &'a [SegmentList; 3],
        graph: &'a [Adjacent],
    },
}

impl<'a> Input<'a> {
    /// Three segment lists, no graph.
    pub fn lists(lists: &'a [SegmentList; 3]) -> Input<'a> {
        Input::Lists { lists, graph: &[] }
    }
}

/// How to match: the matcher's parameters, the extractor's (for images), and when to stop
/// (`checkpoint`, asked between stages: a request's deadline).
#[derive(Clone)]
pub struct Options<'a> {
    pub params: MatchParams,
    pub extract: extract::Params,
    pub checkpoint: Checkpoint<'a>,
}

impl Default for Options<'_> {
    fn default() -> Self {
        Options {
            params: MatchParams::default(),
            extract: extract::Params::default(),
            checkpoint: Checkpoint::NEVER,
        }
    }
}

impl Options<'static> {
    /// The defaults with these matcher parameters.
    pub fn with(params: MatchParams) -> Options<'static> {
        Options {
            params,
            ..Options::default()
        }
    }
}

/// What Match found: triplets and 3D segments, and from images what was extracted from each.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Matched {
    pub output: MatchOutput,
    pub extracted: Option<[Extraction; 3]>,
}

/// Matches three views seen by `rig` and reconstructs the 3D segments: the one entry point
/// of the pipeline. From images, `stats.total_ms` of the output covers extraction too.
pub fn run(rig: &Rig, input: Input, options: &Options) -> Result<Matched, MatchError> {
    match input {
        Input::Images(images) => match_images(rig, images, options),
        Input::Lists { lists, graph } => Ok(Matched {
            output: match_lists(rig, lists, graph, &options.params, options.checkpoint)?,
            extracted: None,
        }),
    }
}

fn match_images(
    rig: &Rig,
    images: [&GreyImage; 3],
    options: &Options,
) -> Result<Matched, MatchError> {
    let Options {
        params,
        extract: extract_params,
        checkpoint,
    } = options;
    let checkpoint = *checkpoint;
    let start = Instant::now();
    params.check().map_err(MatchError::Params)?;
    extract_params.check().map_err(MatchError::Extract)?;
    for (view, image) in images.iter().enumerate() {
        let cam = rig.camera(view);
        if (image.width(), image.height()) != (cam.width(), cam.height()) {
            return Err(MatchError::ImageSize {
                view,
                width: image.width(),
                height: image.height(),
                expected_width: cam.width(),
                expected_height: cam.height(),
            });
        }
    }
    checkpoint.before("extract")?;
    let one = |v: usize| {
        extract::extract_until(images[v], Some(rig.camera(v)), extract_params, checkpoint)
    };
    let (first, (second, third)) = rayon::join(|| one(0), || rayon::join(|| one(1), || one(2)));
    let (first, second, third) = (first?, second?, third?);
    let lists = [
        first.segments.clone(),
        second.segments.clone(),
        third.segments.clone(),
    ];
    let mut output = match_lists(rig, &lists, &first.graph, params, checkpoint)?;
    output.stats.extract_ms = Some([
        first.stats.total_ms,
        second.stats.total_ms,
        third.stats.total_ms,
    ]);
    output.stats.smoothing_sigma_px = Some([
        first.stats.smoothing_sigma_px,
        second.stats.smoothing_sigma_px,
        third.stats.smoothing_sigma_px,
    ]);
    output.stats.total_ms = ms(start);
    Ok(Matched {
        output,
        extracted: Some([first, second, third]),
    })
}

/// A reconstructed 3D segment with how it measures up, or `None` when rejected.
type Fit = Option<(Line3Estimate, Quality)>;
/// Segments shorter than this are zero-length: dropped and counted.
const ZERO_LENGTH_PX: f64 = 1e-9;

/// One matched triplet: indices into the three input lists.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Triplet {
    pub segments: [u32; 3],
    /// Verification residual in the third view, pixels.
    pub residual_px: f64,
}

/// One 3D segment, rig frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Reconstructed {
    pub segment: Segment3,
    /// Index into [`MatchOutput::triplets`] of the (first) triplet it comes from.
    pub triplet: u32,
    /// Every triplet it comes from: several when collinear fragments were merged.
    pub triplets: Vec<u32>,
    /// RMS distance of the image lines from the reprojected 3D line, pixels.
    pub residual_px: f64,
    /// Covariance of the two endpoints `(start, end)` stacked, metres²: the estimate's own
    /// ([`Line3Estimate::covariance`]), each view's own shift
    /// ([`Line3Estimate::systematic_covariance`]) and the shift its three views share
    /// ([`shared_shift_covariance`] of `shift_sigma_m`).
    pub covariance: nalgebra::Matrix6<f64>,
    /// σ of the shift across the line that the three views share ([`SHARED_SHIFT_PX`]),
    /// metres, included in `covariance`: segments of one scene compared with one another
    /// (a session) take it out again, since they share most of it.
    pub shift_sigma_m: f64,
    /// 1σ uncertainty of the direction (largest across the line), degrees: `covariance`'s
    /// ([`Reconstructed::direction_covariance`]).
    pub direction_sigma_deg: f64,
    /// 1σ uncertainty of the midpoint's position across the line (largest), metres.
    pub position_sigma_m: f64,
    /// The segment does not meet the accuracy asked for (`MatchParams::gate_*`): reported
    /// only when `include_uncertain` is set.
    pub uncertain: bool,
    /// It was estimated along the scene's dominant direction it lies along, or in the plane
    /// square to one (`MatchParams::dominant_directions`), its views alone leaving its
    /// direction too loose for the gate: its direction and covariance hold the scene's
    /// well-measured lines as well as its own. Still `uncertain` when the uniqueness test
    /// then found a rival.
    pub aligned: bool,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct MatchStats {
    pub segments_in: [u32; 3],
    pub segments_used: [u32; 3],
    pub zero_length_dropped: [u32; 3],
    /// Segments dropped per list as near-copies of an earlier one ([`DUPLICATE_PX`]).
    pub duplicates_dropped: [u32; 3],
    /// Segments not used per list for being fainter than `MatchParams::min_gradient` or
    /// `min_gradient_to_background` times the list's background.
    pub low_contrast_dropped: [u32; 3],
    pub hypotheses: u32,
    pub triplets: u32,
    pub segments_3d: u32,
    /// 3D segments left out of the answer because they do not meet the accuracy asked for
    /// (counted whether or not `include_uncertain` brought them back).
    pub uncertain: u32,
    /// Hypotheses whose three image lines are not one 3D line within their noise (χ² test).
    pub inconsistent: u32,
    /// Winners that would have been certain but have a rival triplet, sharing one of their
    /// segments, that is one 3D line elsewhere within its noise: the images cannot tell the
    /// two apart, so they are uncertain (counted in `uncertain` too).
    pub ambiguous: u32,
    /// Of the winners the gate doubted: made certain by a vertex they share with a certain
    /// one (`MatchParams::vertex_reach_px`), before the uniqueness test (which may still find
    /// them `ambiguous`).
    pub joined_at_vertices: u32,
    /// Of the winners the gate doubted for their direction alone: made certain by the
    /// direction of the scene's well-measured lines they lie along, or by the plane square to
    /// one (`MatchParams::dominant_directions`), before the uniqueness test.
    pub along_dominant_directions: u32,
    /// How much larger than stated the image-line noise turned out to be in this capture (a
    /// factor on σ, at least 1; read off the first reconstructions: mostly the calibration's
    /// own error).
    pub noise_scale: f64,
    /// Each view's gradient gain relative to view 1, measured on every hypothesis whose three
    /// gradients are known (`matching::gain`; 1 where too few are): cameras with their own
    /// exposure. The gradient test of the depth-blind hypotheses divides it out.
    pub gradient_gains: [f64; 3],
    /// Hypotheses refused because the verifying view could not check their depth and their
    /// gradients, divided by the gains, disagree by more than
    /// `MatchParams::depth_blind_gradient_ratio_max`.
    pub depth_blind_refused: u32,
    pub rectify_ms: f64,
    pub predict_ms: f64,
    pub validate_ms: f64,
    pub reconstruct_ms: f64,
    pub total_ms: f64,
    pub collinear_rig: bool,
    /// The plane of the three centres does not face the scene: each searched pair had its own
    /// rectified frame, the third view reached through 3D points (`RigFrames`).
    pub per_pair_rectification: bool,
    /// Angle between the two searched pairs' epipolar lines at the centre of image 1, degrees
    /// ([`crate::geometry::rectify::epipolar_angle_deg`]); 0 when one pair alone is searched.
    pub epipolar_angle_deg: f64,
    /// Image input: extraction time of each image, milliseconds.
    pub extract_ms: Option<[f64; 3]>,
    /// Image input: the smoothing each image was extracted at, pixels (asked for or chosen).
    pub smoothing_sigma_px: Option<[f64; 3]>,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct MatchOutput {
    pub triplets: Vec<Triplet>,
    pub segments_3d: Vec<Reconstructed>,
    pub stats: MatchStats,
}

impl Reconstructed {
    /// `covariance` without the shift the three views share: what segments of one scene
    /// are compared by (a session's registration and fusion), since they share most of it.
    pub fn relative_covariance(&self) -> nalgebra::Matrix6<f64> {
        self.covariance
            - shared_shift_covariance(&self.segment.start, &self.segment.end, self.shift_sigma_m)
    }

    /// Covariance of the unit direction (rank 2, across the line), from `covariance`.
    pub fn direction_covariance(&self) -> nalgebra::Matrix3<f64> {
        crate::geometry::line::direction_covariance(
            &self.segment.start,
            &self.segment.end,
            &self.covariance,
        )
    }

    /// Covariance of the midpoint across the line (rank 2), from `covariance`: the shared
    /// shift included.
    pub fn midpoint_covariance(&self) -> nalgebra::Matrix3<f64> {
        crate::geometry::line::midpoint_covariance(
            &self.segment.start,
            &self.segment.end,
            &self.covariance,
        )
    }
}

impl MatchOutput {
    /// The 3D segments alone, in answer order (what a scorer or a picture takes).
    pub fn segments(&self) -> Vec<Segment3> {
        self.segments_3d.iter().map(|r| r.segment).collect()
    }
}

/// Which coordinate of a segment is at fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Coordinate {
    U1,
    V1,
    U2,
    V2,
    Gradient,
}

impl Coordinate {
    pub fn name(self) -> &'static str {
        match self {
            Coordinate::U1 => "u1",
            Coordinate::V1 => "v1",
            Coordinate::U2 => "u2",
            Coordinate::V2 => "v2",
            Coordinate::Gradient => "gradient",
        }
    }
}

#[derive(Debug, Clone, PartialEq, Error)]
pub enum MatchError {
    /// The matcher's parameters (`MatchOptions`), every problem.
    #[error(transparent)]
    Params(ParamErrors),
    #[error(transparent)]
    Rectify(#[from] RectifyError),
    #[error("list {list}, segment {index}: {} is not a finite number", coordinate.name())]
    NonFiniteCoordinate {
        list: usize,
        index: usize,
        coordinate: Coordinate,
    },
    #[error(
        "list {list}, segment {index}: {} = {value} is far outside the {width}x{height} image",
        coordinate.name()
    )]
    OutOfImage {
        list: usize,
        index: usize,
        coordinate: Coordinate,
        value: f64,
        width: u32,
        height: u32,
    },
    /// The extractor's parameters (`MatchOptions.extract`), every problem.
    #[error(transparent)]
    Extract(ParamErrors),
    #[error(
        "image {view}: {width}x{height} pixels, but its camera is {expected_width}x{expected_height}"
    )]
    ImageSize {
        view: usize,
        width: u32,
        height: u32,
        expected_width: u32,
        expected_height: u32,
    },
    #[error("list {list}, segment {index}: gradient = {value} must be at least 0")]
    NegativeGradient {
        list: usize,
        index: usize,
        value: f64,
    },
    #[error("list {list}, segment {index}: {field} must be a finite number greater than 0")]
    NonPositiveSigma {
        list: usize,
        index: usize,
        field: &'static str,
    },
    #[error(
        "list {list}, segment {index}: shift_sigma_px = {value} must be a finite number from 0 \
         to {max}",
        max = crate::matching::MAX_LIST_SHIFT_PX
    )]
    ShiftOutOfRange {
        list: usize,
        index: usize,
        value: f64,
    },
    /// The lists are so repetitive (many copies of one line, or one crowd of parallel lines)
    /// that matching them would make more hypotheses than a request may.
    #[error(
        "the segment lists make more than {limit} match hypotheses: lists this dense or this \
         repetitive (many near-copies of one line) cannot be matched unambiguously; send fewer \
         segments"
    )]
    TooManyHypotheses { limit: usize },
    /// The [`Checkpoint`] said the result was no longer wanted.
    #[error("stopped before {stage}: the result is no longer wanted")]
    Stopped { stage: &'static str },
}

impl From<Stopped> for MatchError {
    fn from(Stopped { stage }: Stopped) -> MatchError {
        MatchError::Stopped { stage }
    }
}

/// Segments of one view after checking, kept for matching.
struct Prepared {
    rect: Vec<RectSegment>,
    /// View 1 in the second pair frame, index for index with `rect` (per-pair frames only).
    rect_second: Vec<RectSegment>,
    zero_length: u32,
    /// Segments fainter than the floor of `MatchParams::min_gradient` and
    /// `min_gradient_to_background`.
    low_contrast: u32,
    duplicates: u32,
}

/// Two segments whose ends are both this close (start to start, end to end), pixels, are one:
/// the second is dropped. Far below any tolerance of matching, so nothing distinct is lost,
/// and enough to catch a detector's duplicates — which, left in, multiply the hypotheses
/// (n copies of a line in each view make n³ triplets).
pub const DUPLICATE_PX: f64 = 0.5;
/// Earlier segments compared per grid cell when looking for a copy: bounds the search when a
/// list piles distinct segments onto one place.
const DUPLICATE_SCAN: usize = 32;

/// Finds near-copies among the segments kept so far ([`DUPLICATE_PX`]), by their midpoints
/// on a grid of cells `2·DUPLICATE_PX` wide: a copy's midpoint is within `DUPLICATE_PX` of
/// the segment's, so it lies in one of the 2×2 cells nearest to it. Each cell holds a chain
/// through one flat list of the kept ends, so no cell allocates.
#[derive(Default)]
struct Copies {
    /// Per cell, the newest kept segment whose midpoint falls in it.
    heads: FxHashMap<(i64, i64), u32>,
    /// The ends of the segments kept, each with the previous one of its cell.
    kept: Vec<([Point2<f64>; 2], u32)>,
}

const NO_SEGMENT: u32 = u32::MAX;

impl Copies {
    /// True when `a`–`b` (or `b`–`a`, for an unoriented list) copies a segment seen before;
    /// otherwise remembers it.
    fn seen(&mut self, a: Point2<f64>, b: Point2<f64>, oriented: bool) -> bool {
        const CELL_PX: f64 = 2.0 * DUPLICATE_PX;
        let m = nalgebra::center(&a, &b) / CELL_PX;
        let (cx, cy) = (m.x.floor(), m.y.floor());
        // The neighbour cells on the side of the cell the midpoint is nearer to.
        let step = |f: f64| if f < 0.5 { -1 } else { 1 };
        let (sx, sy) = (step(m.x - cx), step(m.y - cy));
        let (cx, cy) = (cx as i64, cy as i64);
        let near = |p: Point2<f64>, q: Point2<f64>| (p - q).norm_squared() <= DUPLICATE_PX.powi(2);
        for cell in [(cx, cy), (cx + sx, cy), (cx, cy + sy), (cx + sx, cy + sy)] {
            let mut at = self.heads.get(&cell).copied().unwrap_or(NO_SEGMENT);
            for _ in 0..DUPLICATE_SCAN {
                if at == NO_SEGMENT {
                    break;
                }
                let ([p, q], previous) = self.kept[at as usize];
                if (near(a, p) && near(b, q)) || (!oriented && near(a, q) && near(b, p)) {
                    return true;
                }
                at = previous;
            }
        }
        let head = self.heads.entry((cx, cy)).or_insert(NO_SEGMENT);
        self.kept.push(([a, b], *head));
        *head = (self.kept.len() - 1) as u32;
        false
    }
}

fn check_list(rig: &Rig, list_index: usize, list: &SegmentList) -> Result<u32, MatchError> {
    let cam = rig.camera(list_index);
    let (w, h) = (cam.width() as f64, cam.height() as f64);
    let mut zero = 0;
    for (index, s) in list.segments.iter().enumerate() {
        let coords = [
            (Coordinate::U1, s.start.x, w),
            (Coordinate::V1, s.start.y, h),
            (Coordinate::U2, s.end.x, w),
            (Coordinate::V2, s.end.y, h),
        ];
        for (coordinate, value, size) in coords {
            if !value.is_finite() {
                return Err(MatchError::NonFiniteCoordinate {
                    list: list_index,
                    index,
                    coordinate,
                });
            }
            if value < -OUT_OF_IMAGE_MARGIN * size || value > (1.0 + OUT_OF_IMAGE_MARGIN) * size {
                return Err(MatchError::OutOfImage {
                    list: list_index,
                    index,
                    coordinate,
                    value,
                    width: cam.width(),
                    height: cam.height(),
                });
            }
        }
        if let Some(g) = s.gradient {
            if !g.is_finite() {
                return Err(MatchError::NonFiniteCoordinate {
                    list: list_index,
                    index,
                    coordinate: Coordinate::Gradient,
                });
            }
            if g < 0.0 {
                return Err(MatchError::NegativeGradient {
                    list: list_index,
                    index,
                    value: g,
                });
            }
        }
        if let Some(n) = s.noise {
            let valid = |x: f64| x.is_finite() && x > 0.0;
            for (field, value) in [
                ("offset_sigma_px", n.offset_px),
                ("angle_sigma_deg", n.angle_rad),
            ] {
                if !valid(value) {
                    return Err(MatchError::NonPositiveSigma {
                        list: list_index,
                        index,
                        field,
                    });
                }
            }
            if !(0.0..=crate::matching::MAX_LIST_SHIFT_PX).contains(&n.shift_px) {
                return Err(MatchError::ShiftOutOfRange {
                    list: list_index,
                    index,
                    value: n.shift_px,
                });
            }
        }
        if s.length() < ZERO_LENGTH_PX {
            zero += 1;
        }
    }
    Ok(zero)
}

/// The segments of `view` that matching uses, rectified in its frame of `frames` (view 1 of
/// per-pair frames: in both, and only those that map into both).
fn prepare(
    rig: &Rig,
    frames: &RigFrames,
    view: usize,
    list: &SegmentList,
    zero_length: u32,
    params: &MatchParams,
) -> (Prepared, Vec<LineObservation>) {
    let cam = rig.camera(view);
    let rect = frames.frame_of(view);
    let second = (view == 0 && !frames.shared).then(|| &frames.pair_frames[1]);
    let mut out = Prepared {
        rect: Vec::with_capacity(list.segments.len()),
        rect_second: Vec::new(),
        zero_length,
        low_contrast: 0,
        duplicates: 0,
    };
    let floor = params
        .min_gradient
        .max(params.min_gradient_to_background * list.background_gradient.unwrap_or(0.0));
    let mut copies = Copies::default();
    // Undistorted image segments with their noise, parallel to `out.rect`: kept apart, since
    // their noise gains its crowding after prediction while the views borrow `rect`.
    let mut observed = Vec::with_capacity(list.segments.len());
    for (index, s) in list.segments.iter().enumerate() {
        let len = s.length();
        if len < ZERO_LENGTH_PX || len < params.min_length_px {
            continue;
        }
        if copies.seen(s.start, s.end, list.oriented) {
            out.duplicates += 1;
            continue;
        }
        let (p, q) = (cam.undistort(s.start), cam.undistort(s.end));
        let (Some(a), Some(b)) = (rect.to_rect(view, p), rect.to_rect(view, q)) else {
            continue;
        };
        let gradient = s.gradient.unwrap_or(f64::NAN);
        // A list without gradients (NaN) is not filtered: nothing says its segments are faint.
        if gradient < floor {
            out.low_contrast += 1;
            continue;
        }
        if let Some(second) = second {
            let (Some(a2), Some(b2)) = (second.to_rect(view, p), second.to_rect(view, q)) else {
                continue;
            };
            out.rect_second
                .push(RectSegment::new(a2, b2, gradient, index as u32));
        }
        out.rect
            .push(RectSegment::new(a, b, gradient, index as u32));
        // Crowding is added later, only for the segments that reach reconstruction.
        let noise = s
            .noise
            .unwrap_or_else(|| LineNoise::for_list(params.line_noise_px, (q - p).norm()));
        // A list that states a segment's noise has said all it knows about it, its shift too.
        let systematic_px = s.noise.map_or(params.list_shift_px, |n| n.shift_px);
        observed.push(LineObservation {
            view,
            start: p,
            end: q,
            noise,
            systematic_px,
        });
    }
    (out, observed)
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

/// The three views' line observations, reconstructed from on demand. Before a segment is
/// first used, the model noise of a list segment that did not state its own gains the
/// disturbance of its parallel neighbours ([`crate::segment::Crowding`], each view's index
/// built once, when first asked); a list that states its noise is taken at its word. Only
/// what is reconstructed needs it, so it is computed for nothing else.
struct Observations<'a> {
    rect: [&'a [RectSegment]; 3],
    lines: &'a mut [Vec<LineObservation>],
    lists: &'a [SegmentList; 3],
    crowded: [Vec<bool>; 3],
    crowding: [Option<crate::segment::Crowding>; 3],
    /// Per view, each list segment's index among the rectified ones (built when first asked).
    rect_index: [Option<Vec<u32>>; 3],
    /// The lists' crowding model, with `MatchParams::list_push_px`.
    crowding_model: CrowdingModel,
}

impl<'a> Observations<'a> {
    fn new(
        rect: [&'a [RectSegment]; 3],
        lines: &'a mut [Vec<LineObservation>],
        lists: &'a [SegmentList; 3],
        list_push_px: f64,
    ) -> Self {
        let crowded = std::array::from_fn(|v| vec![false; lines[v].len()]);
        Observations {
            rect,
            lines,
            lists,
            crowded,
            crowding: [None, None, None],
            rect_index: [None, None, None],
            crowding_model: CrowdingModel::lists(list_push_px),
        }
    }

    /// The rectified index of view `v`'s list segment `j`, `None` for one not prepared
    /// (zero length).
    fn rect_of(&mut self, v: usize, j: u32) -> Option<u32> {
        let (rect, len) = (self.rect[v], self.lists[v].segments.len());
        let index = self.rect_index[v].get_or_insert_with(|| {
            let mut index = vec![NO_SEGMENT; len];
            for (r, s) in rect.iter().enumerate() {
                index[s.index as usize] = r as u32;
            }
            index
        });
        index.get(j as usize).copied().filter(|&r| r != NO_SEGMENT)
    }

    /// The maximum-likelihood 3D line of each triplet (indices into the rectified views).
    fn estimates(&mut self, rig: &Rig, triplets: &[[u32; 3]]) -> Vec<Option<Line3Estimate>> {
        self.add_crowding(triplets);
        reconstruct(
            rig,
            [&self.lines[0][..], &self.lines[1][..], &self.lines[2][..]],
            triplets,
        )
    }

    fn add_crowding(&mut self, triplets: &[[u32; 3]]) {
        let rect = self.rect;
        let model = self.crowding_model;
        for (v, (view, list)) in self.lines.iter_mut().zip(self.lists).enumerate() {
            let mut asked: Vec<usize> = Vec::new();
            for t in triplets {
                let i = t[v] as usize;
                if !self.crowded[v][i] {
                    self.crowded[v][i] = true;
                    if list.segments[rect[v][i].index as usize].noise.is_none() {
                        asked.push(i);
                    }
                }
            }
            if asked.is_empty() {
                continue;
            }
            let queries: Vec<usize> = asked.iter().map(|&i| rect[v][i].index as usize).collect();
            let index = self.crowding[v]
                .get_or_insert_with(|| crate::segment::Crowding::new(&list.segments));
            // Contrast is known only for an oriented list; without it no push is undone.
            let nearest = if list.oriented && model.repulsion.is_some() {
                index.distances_and_opposites(&list.segments, &queries, model)
            } else {
                let distances = index.distances(&list.segments, &queries, model);
                distances.into_iter().map(|d| (d, None)).collect()
            };
            for (&i, (distance, opposite)) in asked.iter().zip(nearest) {
                let o = &mut view[i];
                let (noise, correction) = o.noise.crowded_and_corrected(
                    distance,
                    opposite,
                    (o.end - o.start).norm(),
                    model,
                );
                o.noise = noise;
                // Measured in the list's pixels, applied to the undistorted line: a move of
                // tenths of a pixel, which the lens does not turn measurably. Matching went
                // on the lines as given, within tolerances of pixels.
                if let Some(correction) = correction {
                    o.start += correction.start;
                    o.end += correction.end;
                }
            }
        }
    }
}

/// Matches three segment lists ([`run`]'s `Input::Lists`).
fn match_lists(
    rig: &Rig,
    lists: &[SegmentList; 3],
    graph: &[Adjacent],
    params: &MatchParams,
    checkpoint: Checkpoint,
) -> Result<MatchOutput, MatchError> {
    let start = Instant::now();
    params.check().map_err(MatchError::Params)?;
    checkpoint.before("rectify")?;
    let mut zero = [0u32; 3];
    for (i, list) in lists.iter().enumerate() {
        zero[i] = check_list(rig, i, list)?;
    }
    let frames = RigFrames::new(rig)?;
    // Validation and the extraction graph work in the first frame, where views 1 and 2 are.
    let rect = &frames.pair_frames[0];
    // A checkpoint per view: a list of the most segments a request may send takes a good
    // part of a second to rectify and sort at this stage (tests/hostile, a crowd at its
    // deadline).
    let mut prepared: Vec<Prepared> = Vec::with_capacity(3);
    let mut observed: Vec<Vec<LineObservation>> = Vec::with_capacity(3);
    for v in 0..3 {
        checkpoint.before("rectify")?;
        let (view, observations) = prepare(rig, &frames, v, &lists[v], zero[v], params);
        prepared.push(view);
        observed.push(observations);
    }
    let mut stats = MatchStats {
        noise_scale: 1.0,
        gradient_gains: [1.0; 3],
        segments_in: std::array::from_fn(|v| lists[v].segments.len() as u32),
        segments_used: std::array::from_fn(|v| prepared[v].rect.len() as u32),
        zero_length_dropped: std::array::from_fn(|v| prepared[v].zero_length),
        duplicates_dropped: std::array::from_fn(|v| prepared[v].duplicates),
        low_contrast_dropped: std::array::from_fn(|v| prepared[v].low_contrast),
        collinear_rig: rect.collinear(),
        per_pair_rectification: !frames.shared,
        // One pair searched alone loses the directions along its epipolar lines.
        epipolar_angle_deg: if frames.searched == [true, true] {
            crate::geometry::rectify::epipolar_angle_deg(rig)
        } else {
            0.0
        },
        rectify_ms: ms(start),
        ..MatchStats::default()
    };
    let views = Views {
        segments: [&prepared[0].rect, &prepared[1].rect, &prepared[2].rect],
        oriented: lists.iter().all(|l| l.oriented),
    };

    checkpoint.before("predict")?;
    let t = Instant::now();
    let first: [&[RectSegment]; 2] = if frames.shared {
        [&prepared[0].rect, &prepared[0].rect]
    } else {
        [&prepared[0].rect, &prepared[0].rect_second]
    };
    let predicted = matching::predict_in_frames_until(&frames, &views, first, params, checkpoint)
        .map_err(|e| match e {
        matching::PredictError::Stopped(s) => MatchError::from(s),
        matching::PredictError::TooManyHypotheses { limit } => {
            MatchError::TooManyHypotheses { limit }
        }
    })?;
    stats.predict_ms = ms(t);
    let hypotheses = predicted.hypotheses;
    stats.hypotheses = hypotheses.len() as u32;
    stats.gradient_gains = predicted.gradient_gains;
    stats.depth_blind_refused = predicted.depth_blind_refused;

    let request = Matching {
        rig,
        rect,
        views: &views,
        lists,
        graph,
        hypotheses: &hypotheses,
        params,
        checkpoint,
    };
    let kept = validate_and_reconstruct(&request, &mut observed, &mut stats)?;

    checkpoint.before("assemble")?;
    let t = Instant::now();
    let output = assemble(&request, &observed, &kept, &mut stats);
    stats.reconstruct_ms += ms(t);
    stats.triplets = output.triplets.len() as u32;
    stats.segments_3d = output.segments_3d.len() as u32;
    stats.total_ms = ms(start);
    Ok(MatchOutput { stats, ..output })
}

/// One request as every stage after prediction reads it: the rig, the frame validation works
/// in (views 1 and 2), the prepared views, the lists as given, view 1's segment graph, the
/// hypotheses, the parameters and the deadline.
#[derive(Clone, Copy)]
struct Matching<'a> {
    rig: &'a Rig,
    rect: &'a Rectification,
    views: &'a Views<'a>,
    lists: &'a [SegmentList; 3],
    graph: &'a [Adjacent],
    hypotheses: &'a [Hypothesis],
    params: &'a MatchParams,
    checkpoint: Checkpoint<'a>,
}

/// How a reconstruction measures up, in the units its users think in.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Quality {
    /// Certain along the scene's dominant direction it lies along, or in its plane
    /// ([`align_with_dominant_directions`]), not by its views alone.
    aligned: bool,
    direction_sigma_deg: f64,
    /// Of the reported covariance: the shared shift included.
    position_sigma_m: f64,
    /// σ of the shift the three views share ([`shared_shift_sigma_m`]), which the estimate's
    /// own covariance leaves out and the reported one adds.
    shift_sigma_m: f64,
    certain: bool,
}

/// The part of a segment's position error its three views share, pixels: a shift of the
/// whole line across itself, the same in every view, which no averaging over the views
/// removes and no disagreement between them shows. The lines' own noise, independent from
/// view to view, accounts for the bulk of the 3D errors but not for their tail: measured on
/// the rendered rooms (images, `includeUncertain`, segments on their true edge), the
/// midpoint's squared normalised error fell within χ²'s 99% quantile for 95.3% (office) and
/// 95.6% (lab) without this term, 98.8% / 97.4% with 0.15 px, 99.3% / 98.2% with 0.3 px
/// (docs/ACCURACY.md, "The shift the views share"). An edge's neighbours and its profile,
/// which move its located line, look alike from three cameras a few decimetres apart: the
/// tail of one view's offset comes with the others'.
pub const SHARED_SHIFT_PX: f64 = 0.3;

/// σ of the shared shift at a segment, metres: [`SHARED_SHIFT_PX`] at its midpoint's range
/// from the rig's `centre`, over the cameras' mean focal length.
fn shared_shift_sigma_m(
    rig: &Rig,
    centre: &nalgebra::Point3<f64>,
    start: &nalgebra::Point3<f64>,
    end: &nalgebra::Point3<f64>,
) -> f64 {
    SHARED_SHIFT_PX * (nalgebra::center(start, end) - centre).norm() / mean_focal_px(rig)
}

/// σ of the shared shift per metre of range for `rig`: [`SHARED_SHIFT_PX`] over its
/// cameras' mean focal length.
pub fn shared_shift_per_metre(rig: &Rig) -> f64 {
    SHARED_SHIFT_PX / mean_focal_px(rig)
}

fn mean_focal_px(rig: &Rig) -> f64 {
    (0..3).map(|v| rig.camera(v).focal_px()).sum::<f64>() / 3.0
}

/// The covariance of the two endpoints `(start, end)` stacked that a shift of σ `sigma_m`
/// across the line, common to both ends, adds: σ²·P in every 3×3 block, P the projector
/// across the line. Both ends move together, so the direction's covariance does not change.
/// A reported covariance less this one is what two segments of the same scene, which share
/// most of the shift, compare by (a session's registration and fusion).
pub fn shared_shift_covariance(
    start: &nalgebra::Point3<f64>,
    end: &nalgebra::Point3<f64>,
    sigma_m: f64,
) -> nalgebra::Matrix6<f64> {
    let mut out = nalgebra::Matrix6::zeros();
    let d = end - start;
    let length = d.norm();
    if !(sigma_m > 0.0 && length > 0.0) {
        return out;
    }
    let u = d / length;
    let across = crate::geometry::line::across_projector(&u) * (sigma_m * sigma_m);
    for (r, c) in [(0, 0), (0, 3), (3, 0), (3, 3)] {
        out.fixed_view_mut::<3, 3>(r, c).copy_from(&across);
    }
    out
}

/// What a segment's answer reports, and the gate judges: the estimate's own covariance and
/// the shift of σ `shift_sigma_m` its three views share.
fn reported_covariance(est: &Line3Estimate, shift_sigma_m: f64) -> nalgebra::Matrix6<f64> {
    est.covariance_with_own_shifts() + shared_shift_covariance(&est.start, &est.end, shift_sigma_m)
}

/// The largest and smallest variance across the line of a 3x3 covariance whose part along
/// the line is not asked for: its eigenvalues in the plane `basis` spans (closed form, 2x2).
pub(crate) fn principal_variances(
    m: &nalgebra::Matrix3<f64>,
    basis: &nalgebra::Matrix3x2<f64>,
) -> (f64, f64) {
    eigenvalues_2x2(&(basis.transpose() * m * basis))
}

/// The two eigenvalues of a 2×2 covariance, largest first, floored at 0.
fn eigenvalues_2x2(c: &nalgebra::Matrix2<f64>) -> (f64, f64) {
    let (a, b, d) = (c[(0, 0)], 0.5 * (c[(0, 1)] + c[(1, 0)]), c[(1, 1)]);
    let (mean, spread) = (0.5 * (a + d), (0.25 * (a - d) * (a - d) + b * b).sqrt());
    ((mean + spread).max(0.0), (mean - spread).max(0.0))
}

/// The radius, in standard deviations, within which a round two-dimensional Gaussian error
/// lies with probability `confidence`: √(−2 ln(1 − c)), 2.45 at 0.95.
pub(crate) fn round_quantile(confidence: f64) -> f64 {
    (-2.0 * (1.0 - confidence).ln()).sqrt()
}

/// Whether an error across the line, Gaussian with principal variances `(major, minor)`, lies
/// within `radius` with probability at least `confidence` — the promise asked exactly. The
/// error is two-dimensional, and an elongated ellipse (a line's depth is known far worse than
/// its sideways position) holds more of its probability inside the disc than a round one of
/// the same major axis: the round bound refused half the segments it need not have.
pub(crate) fn within_radius(variances: (f64, f64), radius: f64, confidence: f64) -> bool {
    let (major, minor) = variances;
    let round_bound = round_quantile(confidence);
    if round_bound * major.sqrt() <= radius {
        return true; // inside even if the error were round
    }
    // Not even the major axis alone stays inside often enough.
    let major_sigma = major.sqrt();
    if major_sigma <= 0.0 || erf(radius / (major_sigma * std::f64::consts::SQRT_2)) < confidence {
        return false;
    }
    // Inside often enough even counting only a rectangle inscribed in the disc (half sides a
    // along the major axis, b along the minor, a² + b² = radius²): a bound from below, which
    // settles most cases without the integral. Tried at b = a few minor σ (best for an
    // elongated error) and with the sides in the ratio of the two σ (best for a round one).
    let minor_sigma = minor.max(0.0).sqrt();
    let inside = |a: f64, sigma: f64| {
        if sigma > 0.0 {
            erf(a / (sigma * std::f64::consts::SQRT_2))
        } else {
            1.0
        }
    };
    let in_rectangle = |b: f64| {
        let a = (radius * radius - b * b).max(0.0).sqrt();
        inside(a, major_sigma) * inside(b, minor_sigma)
    };
    let proportional = radius * minor_sigma / major_sigma.hypot(minor_sigma);
    let settled = [proportional, 2.5 * minor_sigma, 3.5 * minor_sigma]
        .into_iter()
        .filter(|&b| b < radius)
        .any(|b| in_rectangle(b) >= confidence);
    if settled {
        return true;
    }
    within_radius_probability(major, minor, radius) >= confidence
}

/// P(x² + y² ≤ r²) for independent x ~ N(0, major), y ~ N(0, minor): the integral over x of
/// its density times P(|y| ≤ √(r² − x²)), with x = r sin t (smooth in t), by Simpson's rule.
fn within_radius_probability(major: f64, minor: f64, radius: f64) -> f64 {
    const INTERVALS: usize = 48; // even; the integrand is smooth, 48 gives 1e-6
    let (sx, sy) = (major.sqrt(), minor.sqrt());
    let half_pi = std::f64::consts::FRAC_PI_2;
    let h = 2.0 * half_pi / INTERVALS as f64;
    let integrand = |t: f64| {
        let x = radius * t.sin();
        let across = (radius * radius - x * x).max(0.0).sqrt();
        let inside_y = if sy <= 1e-12 * radius {
            1.0
        } else {
            erf(across / (sy * std::f64::consts::SQRT_2))
        };
        let density = (-0.5 * (x / sx).powi(2)).exp() / (sx * (2.0 * std::f64::consts::PI).sqrt());
        density * inside_y * radius * t.cos()
    };
    let sum: f64 = (0..=INTERVALS)
        .map(|i| {
            let weight = if i == 0 || i == INTERVALS {
                1.0
            } else if i % 2 == 1 {
                4.0
            } else {
                2.0
            };
            weight * integrand(-half_pi + i as f64 * h)
        })
        .sum();
    (sum * h / 3.0).clamp(0.0, 1.0)
}

/// The error function (Abramowitz & Stegun 7.1.26, |error| < 1.5e-7).
fn erf(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let y = 1.0 - poly * (-x * x).exp();
    if x < 0.0 {
        -y
    } else {
        y
    }
}

/// Upper `z`-standard-deviation quantile of χ² with `dof` degrees of freedom
/// (Wilson–Hilferty; within 3% of the exact value from 1 degree of freedom up).
fn chi2_quantile(dof: usize, z: f64) -> f64 {
    let k = dof.max(1) as f64;
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + z * a.sqrt()).powi(3)
}

/// How far off its line of image lines a triplet may be before it is not one 3D line: the
/// χ² of its residuals beyond this many standard deviations of a normal (about 1 in 1,000
/// true triplets refused).
const CONSISTENCY_Z: f64 = 3.09;

/// Fewest first-round reconstructions from which the capture's noise scale is estimated.
const MIN_FOR_NOISE_SCALE: usize = 20;
/// The upper quartile of a standard normal. The noise scale is read at the upper quartile of
/// the winners' χ²: many true triplets test nothing (a line in an epipolar plane of one pair
/// is fitted exactly by the other two views, whatever the calibration), so the lower half
/// says little. Wrong first-round winners sit above it (8–23% of them on a capture of LSD's
/// lists of the rendered rooms, nearly all in the upper quarter), so it is read among the
/// winners the scale leaves consistent ([`variance_factor`]).
const QUARTILE_Z: f64 = 0.674;
/// Most rounds of [`variance_factor`]'s trimming; it settles in two or three.
const NOISE_SCALE_ROUNDS: usize = 4;

/// How much larger than stated this capture's image-line noise really is, as a variance
/// factor (at least 1): the upper quartile of the first winners' χ² over the quartile a χ²
/// of their degrees of freedom would have. An image line's own noise is measured, but the
/// calibration's error is not: a real rig's cameras disagree by a few tenths of a pixel, which
/// this reads off the data (the a-posteriori variance of unit weight, made robust). Made
/// robust twice: the quartile, and, from the second round on, only among the winners the
/// factor so far leaves consistent (what [`consistent`] will accept once they are scaled) —
/// a wrong winner's χ² says nothing of the lines' noise, and left in, the wrong winners of a
/// capture of LSD's lists set the quartile (1.09–1.56 on 8 of the rendered rooms' 24
/// captures, 1 on all but 2 without them: docs/ACCURACY.md, "A noise scale read among
/// consistent winners"). Lines truly noisier than stated stay in: their χ² grows with the
/// factor they set.
fn variance_factor(estimates: &[Option<Line3Estimate>]) -> f64 {
    // Per winner: χ² over its quartile, and over its consistency bound.
    let ratios: Vec<(f64, f64)> = estimates
        .iter()
        .flatten()
        .filter(|e| e.dof > 0)
        .map(|e| {
            (
                e.chi2 / chi2_quantile(e.dof, QUARTILE_Z),
                e.chi2 / chi2_quantile(e.dof, CONSISTENCY_Z),
            )
        })
        .collect();
    let mut factor = f64::INFINITY;
    for _ in 0..NOISE_SCALE_ROUNDS {
        let mut within: Vec<f64> = ratios
            .iter()
            .filter(|&&(_, to_bound)| to_bound <= factor)
            .map(|&(to_quartile, _)| to_quartile)
            .collect();
        if within.len() < MIN_FOR_NOISE_SCALE {
            break;
        }
        let k = within.len() * 3 / 4;
        let (_, quartile, _) = within.select_nth_unstable_by(k, f64::total_cmp);
        let next = quartile.max(1.0);
        if next == factor {
            break;
        }
        factor = next;
    }
    if factor.is_finite() {
        factor
    } else {
        1.0
    }
}

/// An estimate with its image-line noise scaled by `factor` (variance): χ² shrinks by it, and
/// the covariance grows by it where the estimate's own scatter had not already grown it more
/// (see `geometry::estimate_line`).
fn rescaled(mut est: Line3Estimate, factor: f64) -> Line3Estimate {
    if factor > 1.0 {
        let own = if est.dof > 0 {
            (est.chi2 / est.dof as f64).max(1.0)
        } else {
            1.0
        };
        est.covariance *= factor.max(own) / own;
        est.chi2 /= factor;
    }
    est
}

/// How far an end may slide along its line because the line itself is uncertain, metres
/// (1σ). An end is where a view's ray through its image end meets the 3D line; a line placed
/// δ off across itself, in the plane of that ray, meets the ray δ·cot θ further along (θ the
/// angle between ray and line), so the end of a receding line overshoots the edge's true end
/// by far more than the line misses the edge — the scorer's distance to the edge *segment*
/// sees it, the across-line tests do not. The middle of the three views' slides, as
/// `estimate_line` takes the middle view's end noise. `covariance` is of (start, end)
/// stacked, `which` 0 or 1.
fn end_slide_sigma_m(
    rig: &Rig,
    at: &nalgebra::Point3<f64>,
    direction: &nalgebra::Vector3<f64>,
    covariance: &nalgebra::Matrix6<f64>,
    which: usize,
) -> f64 {
    let block = covariance
        .fixed_view::<3, 3>(3 * which, 3 * which)
        .into_owned();
    let per_view: [f64; 3] =
        std::array::from_fn(|v| slide_variance(&(at - rig.camera(v).centre()), direction, &block));
    crate::geometry::line::middle_of(per_view[0], per_view[1], per_view[2]).sqrt()
}

/// The variance of an end's slide along the line of unit `direction` for one view, whose
/// `ray` runs from its centre to the end; `block` is the end's covariance.
fn slide_variance(
    ray: &nalgebra::Vector3<f64>,
    direction: &nalgebra::Vector3<f64>,
    block: &nalgebra::Matrix3<f64>,
) -> f64 {
    // In squares, without a root: with r the ray, c = r·u and w = r − c·u (across the line,
    // in the ray's plane, |w|² = |r|²·sin²θ), the variance is (wᵀ·B·w / |w|²)·cot²θ =
    // (wᵀ·B·w / |w|²)·c² / |w|², sin θ floored in the second |w|².
    let range2 = ray.norm_squared();
    if range2 <= 0.0 {
        return 0.0;
    }
    let along = ray.dot(direction);
    let across = ray - direction * along;
    let across2 = across.norm_squared();
    // A ray along the line itself has no plane with it: every direction across is in one,
    // and the variance across both of them bounds the one that counts.
    let variance = if across2 > 0.0 {
        across.dot(&(block * across)) / across2
    } else {
        block.trace() - direction.dot(&(block * direction))
    };
    let floored = across2.max(END_SLIDE_MIN_SIN * END_SLIDE_MIN_SIN * range2);
    variance.max(0.0) * along * along / floored
}

/// How far past the part all three views saw an end may move where two views carry it on
/// (`Line3Estimate::reach_m`), as a share of the gate's position tolerance there. Measured in
/// docs/ACCURACY.md ("Ends two views agree on"): half the tolerance adds 0.6–1.0 points of
/// completeness in both rooms from images and from LSD lists and no wrong segment; the whole
/// tolerance adds wrong ones past the edges' ends, the middle view's end with no bound more.
const REACH_SHARE_OF_TOLERANCE: f64 = 0.5;

/// Below this sine of the angle between a ray and its line, an end's slide is taken at this
/// angle (3°): the line is then nearly a ray itself, and its ends are as unknown as the
/// trim can make them.
const END_SLIDE_MIN_SIN: f64 = 0.05;

/// Moves the segment's ends along its line, each by a share of its length (`a` from the
/// start towards the end, `b` from the end towards the start; negative moves outwards). The
/// new ends are fixed blends of the old, so their covariance follows exactly.
fn blend_ends(est: &mut Line3Estimate, a: f64, b: f64) {
    // start' = (1 − a)·start + a·end, end' = b·start + (1 − b)·end: the covariance's 3x3
    // blocks combine as scalars (every fit that reaches past its overlap comes here, so the
    // 6x6 products are spelled out).
    let (start, end) = (est.start, est.end);
    est.start = start + (end - start) * a;
    est.end = end + (start - end) * b;
    let c = &est.covariance;
    let ss = c.fixed_view::<3, 3>(0, 0).into_owned();
    let se = c.fixed_view::<3, 3>(0, 3).into_owned();
    let ee = c.fixed_view::<3, 3>(3, 3).into_owned();
    let es = se.transpose();
    let (a1, b1) = (1.0 - a, 1.0 - b);
    let new_ss = ss * (a1 * a1) + (se + es) * (a1 * a) + ee * (a * a);
    let new_ee = ss * (b * b) + (se + es) * (b * b1) + ee * (b1 * b1);
    let new_se = ss * (a1 * b) + se * (a1 * b1) + es * (a * b) + ee * (a * b1);
    let mut covariance = nalgebra::Matrix6::<f64>::zeros();
    covariance.fixed_view_mut::<3, 3>(0, 0).copy_from(&new_ss);
    covariance.fixed_view_mut::<3, 3>(0, 3).copy_from(&new_se);
    covariance
        .fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&new_se.transpose());
    covariance.fixed_view_mut::<3, 3>(3, 3).copy_from(&new_ee);
    est.covariance = covariance;
    est.systematic_shifts = est.systematic_shifts.map(|u| {
        let (us, ue) = (u.fixed_rows::<3>(0), u.fixed_rows::<3>(3));
        let mut moved = nalgebra::Vector6::zeros();
        moved.fixed_rows_mut::<3>(0).copy_from(&(us * a1 + ue * a));
        moved.fixed_rows_mut::<3>(3).copy_from(&(us * b + ue * b1));
        moved
    });
}

/// True when the observations are images of one 3D line within their stated noise.
fn consistent(est: &Line3Estimate) -> bool {
    est.chi2 <= chi2_quantile(est.dof, CONSISTENCY_Z)
}

/// The gate's position tolerance at `p`: max(`gate_position_m`, `gate_position_rel` × its
/// distance from the rig's `centre`).
fn position_tolerance(
    params: &MatchParams,
    centre: &nalgebra::Point3<f64>,
    p: &nalgebra::Point3<f64>,
) -> f64 {
    params
        .gate_position_m
        .max(params.gate_position_rel * (p - centre).norm())
}

/// A reconstruction kept when it is one line within its noise (χ² test) and its residual
/// within bounds, with how it measures up.
fn accept(est: Option<Line3Estimate>, rig: &Rig, params: &MatchParams) -> Fit {
    let mut est = est.filter(|e| e.residual_px <= params.max_residual_px && consistent(e))?;
    let u = est.direction();
    // The promise: at the gate's confidence, the direction within its bound, and the midpoint
    // and both ends across the line within the position bound at their range.
    let k = round_quantile(params.gate_confidence);
    let centre = rig.centroid();
    let tolerance = |p: &nalgebra::Point3<f64>| position_tolerance(params, &centre, p);
    // Where two views of three carry an end on past the part all three saw, it moves out
    // towards where they put it, by at most a share of the tolerance there: the third view
    // stopped short (an extractor's end, a junction) more often than the two ran on past the
    // edge, and an end moved by less than the tolerance keeps the promise wherever the part
    // all three saw ended.
    let length = (est.end - est.start).norm();
    let reach = |i: usize, at: &nalgebra::Point3<f64>| {
        est.reach_m[i].min(REACH_SHARE_OF_TOLERANCE * tolerance(at))
    };
    let (reach_start, reach_end) = (reach(0, &est.start), reach(1, &est.end));
    if reach_start + reach_end > 0.0 && length > 0.0 {
        blend_ends(&mut est, -reach_start / length, -reach_end / length);
    }
    // An end that may lie past the true end by more than the tolerance (a receding line, whose
    // ends the images place poorly, and along which an end slides as far as the line is
    // uncertain across: `end_slide_sigma_m`) is pulled in to where it may not: the answer
    // reports the part of the line it is sure of. The new ends are fixed blends of the old,
    // so their covariance follows exactly.
    let length = (est.end - est.start).norm();
    let trim = |sigma: f64, at: &nalgebra::Point3<f64>| (k * sigma - tolerance(at)).max(0.0);
    let untrimmed_shift_sigma_m = shared_shift_sigma_m(rig, &centre, &est.start, &est.end);
    let untrimmed = reported_covariance(&est, untrimmed_shift_sigma_m);
    let (trim_start, trim_end) = (
        trim(
            root_sum_square(
                est.end_along_sigma_m[0],
                end_slide_sigma_m(rig, &est.start, &u, &untrimmed, 0),
            ),
            &est.start,
        ),
        trim(
            root_sum_square(
                est.end_along_sigma_m[1],
                end_slide_sigma_m(rig, &est.end, &u, &untrimmed, 1),
            ),
            &est.end,
        ),
    );
    let long_enough = trim_start + trim_end < length;
    let trimmed = trim_start + trim_end > 0.0 && long_enough;
    if trimmed {
        blend_ends(&mut est, trim_start / length, trim_end / length);
    }
    let (e1, e2) = crate::geometry::across_basis(&u);
    let basis = nalgebra::Matrix3x2::from_columns(&[e1, e2]);
    // What the answer reports, and the gate judges, adds the shift every view shares
    // ([`SHARED_SHIFT_PX`]): the direction is untouched by it, the position is not.
    let (shift_sigma_m, reported) = if trimmed {
        let shift_sigma_m = shared_shift_sigma_m(rig, &centre, &est.start, &est.end);
        (shift_sigma_m, reported_covariance(&est, shift_sigma_m))
    } else {
        (untrimmed_shift_sigma_m, untrimmed)
    };
    // The direction judged and reported is the reported covariance's: the views' own shifts
    // turn the line (the shift they share does not).
    let direction_var = principal_variances(
        &crate::geometry::line::direction_covariance(&est.start, &est.end, &reported),
        &basis,
    );
    let direction_sigma_deg = direction_var.0.sqrt().to_degrees();
    if direction_sigma_deg > params.max_direction_sigma_deg {
        return None;
    }
    let midpoint_var = principal_variances(
        &crate::geometry::line::midpoint_covariance(&est.start, &est.end, &reported),
        &basis,
    );
    let position_sigma_m = midpoint_var.0.sqrt();
    let mid = nalgebra::center(&est.start, &est.end);
    let start_var = principal_variances(&reported.fixed_view::<3, 3>(0, 0).into_owned(), &basis);
    let end_var = principal_variances(&reported.fixed_view::<3, 3>(3, 3).into_owned(), &basis);
    let confidence = params.gate_confidence;
    let certain = long_enough
        && within_radius(
            direction_var,
            params.gate_direction_deg.to_radians(),
            confidence,
        )
        && within_radius(midpoint_var, tolerance(&mid), confidence)
        && within_radius(start_var, tolerance(&est.start), confidence)
        && within_radius(end_var, tolerance(&est.end), confidence)
        && seen_long_enough(rig, &est);
    Some((
        est,
        Quality {
            aligned: false,
            direction_sigma_deg,
            position_sigma_m,
            shift_sigma_m,
            certain,
        },
    ))
}

/// Whether the segment is at least [`matching::predict::MIN_OVERLAP_PX`] long in the image of
/// one of the views, what the matcher asks of any part the views share. A trim of ends the
/// line cannot vouch for, or an overlap of short pieces, can leave a piece of line a pixel
/// long in every view: its direction is what its line's covariance says, but a 5-cm piece of
/// it is nothing the views measured as a segment, and a scorer counts every degree of it
/// (docs/ACCURACY.md, "A piece of line no view sees as a segment").
fn seen_long_enough(rig: &Rig, est: &Line3Estimate) -> bool {
    longest_image_px(rig, est) >= matching::predict::MIN_OVERLAP_PX
}

/// The segment's longest image among the views, pixels (pinhole projection; a view that has
/// an end behind it sees none of it).
fn longest_image_px(rig: &Rig, est: &Line3Estimate) -> f64 {
    rig.cameras()
        .iter()
        .filter_map(|c| Some((c.pinhole(&est.end)? - c.pinhole(&est.start)?).norm()))
        .fold(0.0, f64::max)
}

/// Validation ranks hypotheses and resolves rivalries; only its winners are reconstructed.
/// A winner that reconstruction rejects (no overlap, residual or direction uncertainty too
/// large) leaves the pool and validation runs again, so a rival it displaced gets its turn.
/// Returns the accepted hypotheses with their reconstructions.
fn validate_and_reconstruct(
    request: &Matching,
    observed: &mut [Vec<LineObservation>],
    stats: &mut MatchStats,
) -> Result<Vec<(usize, Line3Estimate, Quality)>, MatchError> {
    let Matching {
        rig,
        rect,
        views,
        lists,
        graph,
        hypotheses,
        params,
        checkpoint,
    } = *request;
    let mut fits: Vec<Option<Fit>> = vec![None; hypotheses.len()];
    let mut alive: Vec<bool> = vec![true; hypotheses.len()];
    let mut observations = Observations::new(views.segments, observed, lists, params.list_push_px);
    checkpoint.before("validate")?;
    let t = Instant::now();
    let ranking = if params.validate {
        let mut adjacency = matching::adjacency(views.segments[0], params.neighbour_radius_px);
        add_graph(&mut adjacency, graph, rig, rect, views.segments[0]);
        matching::rank_until(rect, views, &adjacency, hypotheses, params, checkpoint)?
    } else {
        Vec::new()
    };
    stats.validate_ms += ms(t);
    let mut kept: Vec<usize> = Vec::new();
    for round in 0..MAX_VALIDATION_ROUNDS {
        let t = Instant::now();
        kept = if params.validate {
            matching::select(views, hypotheses, &ranking, &alive, params)
        } else {
            (0..hypotheses.len()).filter(|&h| alive[h]).collect()
        };
        stats.validate_ms += ms(t);

        checkpoint.before("reconstruct")?;
        let t = Instant::now();
        let (todo, estimates) = estimate_unfitted(request, &mut observations, &kept, &fits)?;
        if round == 0 {
            stats.noise_scale = variance_factor(&estimates).sqrt();
        }
        let factor = stats.noise_scale.powi(2);
        for (&h, est) in todo.iter().zip(estimates) {
            let est = est.map(|e| rescaled(e, factor));
            if est.is_some_and(|e| !consistent(&e)) {
                stats.inconsistent += 1;
            }
            fits[h] = Some(accept(est, rig, params));
        }
        stats.reconstruct_ms += ms(t);
        let mut rejected = false;
        for &h in &kept {
            if matches!(fits[h], Some(None)) {
                alive[h] = false;
                rejected = true;
            }
        }
        if !rejected || !params.validate || round + 1 == MAX_VALIDATION_ROUNDS {
            break;
        }
    }
    if params.validate {
        let t = Instant::now();
        yield_to_certain_rivals(
            request,
            &mut observations,
            &ranking,
            &alive,
            &mut fits,
            &mut kept,
            stats,
        )?;
        stats.reconstruct_ms += ms(t);
    }
    if params.vertex_reach_px > 0.0 {
        checkpoint.before("reconstruct")?;
        let t = Instant::now();
        join_at_vertices(request, &observations, &kept, &mut fits, stats)?;
        stats.reconstruct_ms += ms(t);
    }
    if params.dominant_directions {
        checkpoint.before("reconstruct")?;
        let t = Instant::now();
        align_with_dominant_directions(request, &observations, &kept, &mut fits, stats)?;
        stats.reconstruct_ms += ms(t);
    }
    if params.validate {
        // The rivals' reconstructions are more work: a request past its deadline stops here.
        checkpoint.before("reconstruct")?;
        let t = Instant::now();
        flag_ambiguous(request, &mut observations, &kept, &alive, &mut fits, stats);
        stats.reconstruct_ms += ms(t);
    }
    Ok(kept
        .into_iter()
        .filter_map(|h| fits[h].flatten().map(|(est, quality)| (h, est, quality)))
        .collect())
}

/// The maximum-likelihood lines of those of `which` not fitted yet, in chunks between
/// questions to the checkpoint: their indices and estimates, in order.
fn estimate_unfitted(
    request: &Matching,
    observations: &mut Observations,
    which: &[usize],
    fits: &[Option<Fit>],
) -> Result<(Vec<usize>, Vec<Option<Line3Estimate>>), Stopped> {
    let todo: Vec<usize> = which
        .iter()
        .copied()
        .filter(|&h| fits[h].is_none())
        .collect();
    let triplets: Vec<[u32; 3]> = todo
        .iter()
        .map(|&h| request.hypotheses[h].segments)
        .collect();
    let mut estimates = Vec::with_capacity(triplets.len());
    for chunk in triplets.chunks(RECONSTRUCT_CHUNK) {
        request.checkpoint.before("reconstruct")?;
        estimates.extend(observations.estimates(request.rig, chunk));
    }
    Ok((todo, estimates))
}

/// A doubtful winner gives way to a certain rival that fits better by this much χ² (a
/// likelihood e^½ ≈ 1.6 times its own or more). 1, 2 and 4 measured (docs/ACCURACY.md).
const YIELD_CHI2_MARGIN: f64 = 1.0;
/// Most doubtful winners sharing one of a newcomer's segments for it to stand in for them.
const MAX_YIELD_RIVALS: usize = 16;
/// A winner whose views disagree on where both its ends lie by more than this many of their
/// σ (`Line3Estimate::ends_disagreement`) is three edges that happen to lie on one 3D line,
/// not one edge seen three times: the ghost of a repetitive structure — a radiator's fins,
/// matched one fin over in one view and one fin the other way in the other, which a third
/// camera half-way along the baseline checks no better than the first two (docs/ACCURACY.md,
/// "Ghosts whose ends disagree"). Occlusion moves one end in some views, not both; a real
/// edge's ends agree within a few σ ([`AMBIGUITY_ENDS_AGREE`]). 4, 5, 7 and 10 measured
/// alike on the rendered rooms; 20 and 40 let some ghosts stand.
const GHOST_ENDS_DISAGREE: f64 = 10.0;

/// Validation ranks by neighbour support, and a winner the accuracy gate then doubts still
/// holds its three segments against every rival — even one that would be certain. Here the
/// doubtful winners stand aside: the uniqueness pass runs again with the certain winners
/// first, then the other hypotheses in ranking order, then the doubtful winners, and a
/// newcomer it admits takes the place of the doubtful winners it conflicts with when it is
/// certain and, against each of them, either fits better by [`YIELD_CHI2_MARGIN`] or is one
/// edge where the winner is a ghost (below). Only a newcomer whose depth the verification
/// checked (not [`Hypothesis::depth_blind`]) may stand in, and by the better fit only one
/// whose three lines carry measured noise (the extractor's, not the list model's): a ghost
/// along a baseline, and a line whose certainty rests on a model of the noise, come out
/// certain too easily to replace a winner that had more support (docs/ACCURACY.md, "A
/// doubtful winner gives way").
///
/// A winner whose views' ends disagree by more than [`GHOST_ENDS_DISAGREE`] σ is doubtful
/// too, however certain its covariance: the ghost of a repetitive structure, whose lines fit
/// one 3D line as well as the true edge's do. It gives way to a newcomer whose ends agree
/// (within [`AMBIGUITY_ENDS_AGREE`]) and that fits as well (χ² within
/// [`AMBIGUITY_CHI2_MARGIN`]): evidence the list model's noise does not enter, so lists'
/// newcomers may take a ghost's place — only those sharing a segment with a ghost are tried,
/// which bounds the work. The doubtful winners that are not replaced stay, flagged as before
/// (a ghost, by [`flag_ambiguous`], when its rival is as likely).
fn yield_to_certain_rivals(
    request: &Matching,
    observations: &mut Observations,
    ranking: &[usize],
    alive: &[bool],
    fits: &mut [Option<Fit>],
    kept: &mut Vec<usize>,
    stats: &MatchStats,
) -> Result<(), MatchError> {
    let Matching {
        rig,
        views,
        lists,
        hypotheses,
        params,
        ..
    } = *request;
    let quality = |f: &Option<Fit>| match f {
        Some(Some((_, q))) => Some(q.certain),
        _ => None,
    };
    let ends_disagreement = |fits: &[Option<Fit>], h: usize| match &fits[h] {
        Some(Some((e, _))) => e.ends_disagreement,
        _ => 0.0,
    };
    let mut standing = vec![false; hypotheses.len()];
    let mut doubtful = vec![false; hypotheses.len()];
    let mut ghost = vec![false; hypotheses.len()];
    for &h in kept.iter() {
        standing[h] = true;
        ghost[h] = ends_disagreement(fits, h) > GHOST_ENDS_DISAGREE;
        doubtful[h] = ghost[h] || quality(&fits[h]) == Some(false);
    }
    if !doubtful.iter().any(|&d| d) {
        return Ok(());
    }
    // Per view, the segments the ghosts hold: a newcomer on one may stand in for a ghost.
    let mut ghosts_segments: [FxHashSet<u32>; 3] = Default::default();
    for &h in kept.iter().filter(|&&h| ghost[h]) {
        for (v, held) in ghosts_segments.iter_mut().enumerate() {
            held.insert(hypotheses[h].segments[v]);
        }
    }
    let meets_ghost =
        |h: usize| (0..3).any(|v| ghosts_segments[v].contains(&hypotheses[h].segments[v]));
    let measured = |h: usize| {
        (0..3).all(|v| {
            let s = &views.segments[v][hypotheses[h].segments[v] as usize];
            lists[v]
                .segments
                .get(s.index as usize)
                .is_some_and(|l| l.noise.is_some())
        })
    };
    let order: Vec<usize> = ranking
        .iter()
        .copied()
        .filter(|&h| standing[h] && !doubtful[h])
        .chain(ranking.iter().copied().filter(|&h| {
            !standing[h] && !hypotheses[h].depth_blind && (measured(h) || meets_ghost(h))
        }))
        .chain(ranking.iter().copied().filter(|&h| doubtful[h]))
        .collect();
    let newcomers: Vec<usize> = matching::select(views, hypotheses, &order, alive, params)
        .into_iter()
        .filter(|&h| !standing[h])
        .collect();
    if newcomers.is_empty() {
        return Ok(());
    }
    // The doubtful winners by segment, so a newcomer meets only those it may conflict with.
    let mut by_segment: FxHashMap<(usize, u32), Vec<usize>> = FxHashMap::default();
    for &h in kept.iter().filter(|&&h| doubtful[h]) {
        for v in 0..3 {
            by_segment
                .entry((v, hypotheses[h].segments[v]))
                .or_default()
                .push(h);
        }
    }
    // A segment that many doubtful winners share (fragments of one line, or a list built to
    // pile them up) is a crowd, not a rivalry: a newcomer meeting one does not stand in, and
    // the pairwise tests stay linear in the winners.
    let rivals_of = |h: usize| {
        let shared: Vec<&Vec<usize>> = (0..3)
            .filter_map(|v| by_segment.get(&(v, hypotheses[h].segments[v])))
            .collect();
        if shared.iter().any(|users| users.len() > MAX_YIELD_RIVALS) {
            return None;
        }
        let mut rivals: Vec<usize> = shared
            .into_iter()
            .flatten()
            .copied()
            .filter(|&d| matching::conflict(views, &hypotheses[h], &hypotheses[d], params))
            .collect();
        rivals.sort_unstable();
        rivals.dedup();
        Some(rivals)
    };
    // Only a newcomer that could stand in is reconstructed: one that meets doubtful winners,
    // and, without measured noise, only ghosts among them (the one test it may pass).
    let candidates: Vec<(usize, Vec<usize>)> = newcomers
        .into_iter()
        .filter_map(|h| {
            let rivals = rivals_of(h)?;
            (!rivals.is_empty() && (measured(h) || rivals.iter().all(|&d| ghost[d])))
                .then_some((h, rivals))
        })
        .collect();
    if candidates.is_empty() {
        return Ok(());
    }
    let standing_in: Vec<usize> = candidates.iter().map(|&(h, _)| h).collect();
    let (todo, estimates) = estimate_unfitted(request, observations, &standing_in, fits)?;
    let factor = stats.noise_scale.powi(2);
    for (&h, est) in todo.iter().zip(estimates) {
        fits[h] = Some(accept(est.map(|e| rescaled(e, factor)), rig, params));
    }
    let chi2 = |h: usize| match &fits[h] {
        Some(Some((e, _))) => e.chi2,
        _ => f64::INFINITY,
    };
    let mut replaced = FxHashSet::default();
    let mut winners = Vec::new();
    for (h, rivals) in candidates {
        if quality(&fits[h]) != Some(true) {
            continue;
        }
        let (measured_noise, one_edge) = (
            measured(h),
            ends_disagreement(fits, h) <= AMBIGUITY_ENDS_AGREE,
        );
        if rivals.iter().all(|&d| {
            (measured_noise && chi2(d) > chi2(h) + YIELD_CHI2_MARGIN)
                || (one_edge && ghost[d] && chi2(h) <= chi2(d) + AMBIGUITY_CHI2_MARGIN)
        }) {
            replaced.extend(rivals);
            winners.push(h);
        }
    }
    kept.retain(|h| !replaced.contains(h));
    kept.extend(winners);
    kept.sort_unstable();
    Ok(())
}

/// How much worse (in χ²) a rival's fit may be than the winner's and still be taken for as
/// likely: 4 is a likelihood ratio of e⁻² ≈ 0.14.
const AMBIGUITY_CHI2_MARGIN: f64 = 4.0;
/// Ends that agree within this many of their σ (largest less smallest of the three views)
/// are as good as ends can agree: a rival that does that is as likely as a winner that does
/// better.
const AMBIGUITY_ENDS_AGREE: f64 = 3.0;
/// A rival that does not meet the gate itself counts when its midpoint is this many σ (of
/// the two lines' joint position noise) off the winner's line: beyond the noise, a second
/// place the images fit as well. 2 and 3 measured alike except for one ghost in the office
/// (docs/ACCURACY.md, item 6).
const APART_SIGMAS: f64 = 2.0;
/// Most rivals reconstructed to test one winner's uniqueness.
const MAX_RIVALS: usize = 16;

/// Uniqueness in three views: a winner one of whose segments also forms, with other
/// segments, a triplet that is one 3D line within its noise somewhere else (beyond the gate's
/// position or direction tolerance) is ambiguous — the images cannot tell the two apart, as
/// with the fins of a radiator seen along the direction the third camera cannot check — and
/// it is flagged uncertain, whatever its covariance says. Validation chose by neighbour
/// support, which a repetitive structure gives every shifted copy of itself alike. The rival
/// must be a place of its own: one that meets the gate, or one whose midpoint is
/// [`APART_SIGMAS`] off the winner's line under both covariances (a short rival, too
/// imprecise for the gate, is still proof of a second fit when it lies well away — the lab's
/// radiator fins from LSD lists). An imprecise rival within its noise of the winner proves
/// nothing. Rivals are the hypotheses sharing a segment with the winner, and the triplets
/// that take one of its segments for one of opposite contrast ([`flipped_rivals`]), which
/// oriented matching never forms.
fn flag_ambiguous(
    request: &Matching,
    observations: &mut Observations,
    kept: &[usize],
    alive: &[bool],
    fits: &mut [Option<Fit>],
    stats: &mut MatchStats,
) {
    let Matching {
        rig,
        hypotheses,
        params,
        ..
    } = *request;
    let certain: Vec<usize> = kept
        .iter()
        .copied()
        .filter(|&h| matches!(&fits[h], Some(Some((_, q))) if q.certain))
        .collect();
    if certain.is_empty() {
        return;
    }
    // Which hypotheses use each segment, for the segments of the certain winners only.
    // Per view, each segment's slot in `users` (NO_SLOT: not a certain winner's).
    const NO_SLOT: u32 = u32::MAX;
    let mut slot: [Vec<u32>; 3] =
        std::array::from_fn(|v| vec![NO_SLOT; observations.rect[v].len()]);
    let mut users: Vec<Vec<u32>> = Vec::new();
    for &h in &certain {
        for (v, slots) in slot.iter_mut().enumerate() {
            let s = &mut slots[hypotheses[h].segments[v] as usize];
            if *s == NO_SLOT {
                *s = users.len() as u32;
                users.push(Vec::new());
            }
        }
    }
    for (r, hyp) in hypotheses.iter().enumerate() {
        if !alive[r] {
            continue;
        }
        for (v, slots) in slot.iter().enumerate() {
            let s = slots[hyp.segments[v] as usize];
            if s != NO_SLOT {
                users[s as usize].push(r as u32);
            }
        }
    }
    let mut rivals_of: Vec<(usize, Vec<usize>)> = Vec::with_capacity(certain.len());
    let mut todo: Vec<usize> = Vec::new();
    for &h in &certain {
        let mut rivals: Vec<usize> = Vec::new();
        for (v, slots) in slot.iter().enumerate() {
            for &r in &users[slots[hypotheses[h].segments[v] as usize] as usize] {
                let r = r as usize;
                if r != h && !rivals.contains(&r) && rivals.len() < MAX_RIVALS {
                    rivals.push(r);
                }
            }
        }
        todo.extend(rivals.iter().copied().filter(|&r| fits[r].is_none()));
        rivals_of.push((h, rivals));
    }
    todo.sort_unstable();
    todo.dedup();
    let triplets: Vec<[u32; 3]> = todo.iter().map(|&r| hypotheses[r].segments).collect();
    let factor = stats.noise_scale.powi(2);
    // Each rival's fit, accepted (and kept in `fits`) only when a winner asks: most rivals
    // fit far worse than every winner they rival, which their χ² alone says (`as_likely`),
    // and the acceptance, which changes neither χ² nor the ends' disagreement, would be
    // wasted on them.
    let unaccepted: Vec<Option<Line3Estimate>> = observations
        .estimates(rig, &triplets)
        .into_iter()
        .map(|est| est.map(|e| rescaled(e, factor)))
        .collect();
    let centre = rig.centroid();
    let counts = |winner: &Line3Estimate, fit: &Fit| {
        matches!(fit, Some((rival, q))
            if as_likely_elsewhere(winner, rival, &centre, params)
                && (q.certain || significantly_apart(winner, rival)))
    };
    let counts_unaccepted = |winner: &Line3Estimate, est: &Option<Line3Estimate>| {
        est.filter(|rival| as_likely(winner, rival))
            .is_some_and(|rival| counts(winner, &accept(Some(rival), rig, params)))
    };
    for (h, rivals) in rivals_of {
        let Some(Some((winner, _))) = fits[h] else {
            continue;
        };
        let mut ambiguous = false;
        for &r in &rivals {
            if fits[r].is_none() {
                let Some(rival) = todo.binary_search(&r).ok().and_then(|i| unaccepted[i]) else {
                    continue;
                };
                if !as_likely(&winner, &rival) {
                    continue;
                }
                fits[r] = Some(accept(Some(rival), rig, params));
            }
            if fits[r].as_ref().is_some_and(|fit| counts(&winner, fit)) {
                ambiguous = true;
                break;
            }
        }
        ambiguous = ambiguous
            || flipped_rivals(rig, observations, hypotheses[h].segments, stats.noise_scale)
                .iter()
                .any(|est| counts_unaccepted(&winner, est));
        if ambiguous {
            if let Some(Some((_, quality))) = &mut fits[h] {
                quality.certain = false;
                stats.ambiguous += 1;
            }
        }
    }
}

/// Shared vertices: an uncertain winner that ends, in all three views, where a certain winner
/// ends — a corner the two edges share — is estimated again through that vertex, whose 3D
/// place the certain segment measured (its end and that end's covariance, a point the line
/// passes through: [`crate::geometry::estimate_line_through`]). It takes the new fit when that
/// is still one line within its noise and now meets the gate. A short segment's direction is
/// what the gate refuses (docs/ACCURACY.md); a vertex fixed by a long segment fixes one of its
/// ends, two vertices the whole line.
///
/// The ends must meet within `MatchParams::vertex_reach_px` in every view, each view's image
/// of the certain end against the uncertain segment's observed ends: an occluded line that
/// stops at an occluding contour meets it at a different place in each view, and a T-junction
/// meets the other segment's middle, not its end. Only winners certain before this step lend
/// vertices, so the outcome does not depend on the order. Those made certain are then
/// checked for uniqueness like every certain winner ([`flag_ambiguous`]).
fn join_at_vertices(
    request: &Matching,
    observations: &Observations,
    kept: &[usize],
    fits: &mut [Option<Fit>],
    stats: &mut MatchStats,
) -> Result<(), Stopped> {
    let Matching {
        rig,
        hypotheses,
        params,
        checkpoint,
        ..
    } = *request;
    let reach = params.vertex_reach_px;
    let cameras = [rig.camera(0), rig.camera(1), rig.camera(2)];
    // The certain winners' ends: where each lies, how well, its image in each view
    // (undistorted, as the observations are) and its triplet.
    struct Vertex {
        known: PointOnLine,
        image: [Point2<f64>; 3],
        segments: [u32; 3],
    }
    let mut vertices: Vec<Vertex> = Vec::new();
    for &h in kept {
        let Some(Some((est, quality))) = &fits[h] else {
            continue;
        };
        if !quality.certain {
            continue;
        }
        for (point, block) in [(est.start, 0), (est.end, 3)] {
            let image = cameras.map(|c| c.pinhole(&point));
            let [Some(a), Some(b), Some(c)] = image else {
                continue;
            };
            vertices.push(Vertex {
                known: PointOnLine {
                    point,
                    covariance: est.covariance.fixed_view::<3, 3>(block, block).into_owned(),
                },
                image: [a, b, c],
                segments: hypotheses[h].segments,
            });
        }
    }
    if vertices.is_empty() {
        return Ok(());
    }
    // Indexed by their image in view 1, in cells as wide as the reach. A cell where more
    // ends pile up than edges meet at a corner is a crowd, not a vertex: it lends none (and a
    // request that piles its segments' ends on one pixel pays once for them, not once per
    // segment).
    // Cells no smaller than a hundredth of a pixel, and their neighbours found with
    // saturating steps: a reach of 1e-300 px put the ends in a cell at i64::MAX, whose
    // neighbour overflowed (found by `fuzz/match_whole`), and a certain end projected from
    // near a camera's plane lands there at any reach.
    let cell_px = reach.max(MIN_VERTEX_CELL_PX);
    let cell = |p: &Point2<f64>| {
        (
            (p.x / cell_px).floor() as i64,
            (p.y / cell_px).floor() as i64,
        )
    };
    let mut cells: FxHashMap<(i64, i64), Vec<u32>> = FxHashMap::default();
    for (i, v) in vertices.iter().enumerate() {
        cells.entry(cell(&v.image[0])).or_default().push(i as u32);
    }
    cells.retain(|_, ends| ends.len() <= MAX_ENDS_AT_A_VERTEX);
    let factor = stats.noise_scale.powi(2);
    let uncertain: Vec<usize> = kept
        .iter()
        .copied()
        .filter(|&h| matches!(&fits[h], Some(Some((_, q))) if !q.certain))
        .collect();
    for (done, h) in uncertain.into_iter().enumerate() {
        if done % RECONSTRUCT_CHUNK == 0 {
            checkpoint.before("reconstruct")?;
        }
        // A triplet whose depth rests on the searched view alone (its verifying view runs
        // along the line: docs/RIGS.md) has ends the views place along that line, and a
        // vertex that meets them there may lie anywhere along the rays: on the near-collinear
        // rig it pinned 13 lines of 16 rooms to another edge's end, each near no edge.
        if hypotheses[h].depth_blind {
            continue;
        }
        let segments = hypotheses[h].segments;
        let obs: [LineObservation; 3] =
            std::array::from_fn(|v| observations.lines[v][segments[v] as usize]);
        let meets = |vertex: &Vertex| {
            (0..3).all(|v| {
                let (o, q) = (&obs[v], vertex.image[v]);
                vertex.segments[v] != segments[v]
                    && ((o.start - q).norm() <= reach || (o.end - q).norm() <= reach)
            })
        };
        let mut through: Vec<PointOnLine> = Vec::new();
        for end in [obs[0].start, obs[0].end] {
            let (cx, cy) = cell(&end);
            let nearest = (cx.saturating_sub(1)..=cx.saturating_add(1))
                .flat_map(|x| (cy.saturating_sub(1)..=cy.saturating_add(1)).map(move |y| (x, y)))
                .filter_map(|key| cells.get(&key))
                .flatten()
                .map(|&i| &vertices[i as usize])
                .filter_map(|v| {
                    let apart = (v.image[0] - end).norm();
                    (apart <= reach && meets(v)).then_some((apart, v))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((_, v)) = nearest {
                if through.iter().all(|k| k.point != v.known.point) {
                    through.push(v.known);
                }
            }
        }
        if through.is_empty() {
            continue;
        }
        let est = estimate_line_through(&cameras, &obs, END_SIGMA_PX, &through)
            .map(|e| rescaled(e, factor));
        if let Some(fit) = accept(est, rig, params).filter(|(_, q)| q.certain) {
            fits[h] = Some(Some(fit));
            stats.joined_at_vertices += 1;
        }
    }
    Ok(())
}

/// Winners certain before this step whose direction σ is under this lend the scene its
/// dominant directions, degrees.
const MODE_MEMBER_SIGMA_DEG: f64 = 2.0;
/// A dominant direction needs this many such winners along it.
const MODE_MIN_MEMBERS: usize = 5;
/// At most this many dominant directions (a room has three; a fourth for a slanted roof).
const MAX_MODES: usize = 4;
/// The dominant directions are sought among at most this many of the best-measured lines
/// (every pair of them is compared, four times at most): a room's captures have a few
/// hundred certain segments; a request of 100,000 segments a list would otherwise cost 10¹⁰
/// comparisons.
const MAX_MODE_LINES: usize = 512;
/// A winner counts along a direction within max(this, 2.5σ) of it, degrees.
const MODE_REACH_DEG: f64 = 2.0;
/// Floor on a member's direction σ in its weight, degrees: no line measures the scene's
/// direction better than the calibration does.
const MODE_WEIGHT_FLOOR_DEG: f64 = 0.3;
/// Winners whose direction σ is under this say how many of the scene's lines lie along no
/// dominant direction, degrees.
const ALONG_NONE_SIGMA_DEG: f64 = 1.0;
/// The share along none is at least this, and is drawn toward 0.3 as if five more lines had
/// been seen: a few well-measured lines cannot prove a scene wholly built along its modes.
const ALONG_NONE_MIN: f64 = 0.05;
const ALONG_NONE_PRIOR: (f64, f64) = (0.3, 5.0);
/// A doubted winner takes a dominant direction when it lies along it with this posterior
/// probability (against lying along none of them). 0.8 and 0.99 take the same segments
/// within a few in a room; the posteriors come out near 0 or 1.
const ALONG_POSTERIOR: f64 = 0.95;
/// Nor a winner shorter than this in any view, pixels: a direction does not place a line,
/// and a short segment's place and correspondence are the least sure of all (with none, or
/// 12 px, a segment near no edge in the office; with 16 px, lines a neighbour pulled off
/// their edge in the synthetic room's realistic lists as they were drawn until 2026-12-07,
/// 3.1% wrong: docs/ACCURACY.md).
const ALONG_MIN_PX: f64 = 20.0;
/// Two dominant directions are square to each other when their cosine is under this
/// (88°): a line along one lies in the other's plane.
const SQUARE_COS: f64 = 0.035;

/// A well-measured line's weight in the scene's directions: its direction's information,
/// floored at [`MODE_WEIGHT_FLOOR_DEG`].
fn mode_weight(variance: f64) -> f64 {
    1.0 / (variance + MODE_WEIGHT_FLOOR_DEG.to_radians().powi(2))
}

/// The variance of an angle that lines share (a direction's, or a plane's tilt), from each
/// line's deviation from it and its own variance (radians, radians²): their weighted spread
/// beyond their own noise, plus the weighted mean's own.
fn shared_variance(deviations: impl Iterator<Item = (f64, f64)> + Clone) -> f64 {
    let total: f64 = deviations.clone().map(|(_, var)| mode_weight(var)).sum();
    let spread = deviations
        .map(|(angle, var)| mode_weight(var) * (angle * angle - var))
        .sum::<f64>()
        / total;
    spread.max(0.0) + 1.0 / total
}

/// One dominant direction of a scene: a unit vector (either sense), the variance of the
/// direction its lines share about it (radians², per axis across it), and how many lines
/// lie along it.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Mode {
    direction: nalgebra::Vector3<f64>,
    variance: f64,
    members: usize,
}

/// The scene's dominant directions, from well-measured lines (each its unit direction and
/// direction variance, radians²): greedily the direction most lines lie along, their
/// information-weighted mean, its variance the members' spread beyond their own noise plus
/// the mean's own; then the next among the lines left.
fn dominant_directions(lines: &[(nalgebra::Vector3<f64>, f64)]) -> Vec<Mode> {
    // The best measured first, and no more than MAX_MODE_LINES of them: every pair is
    // compared, and a request's lists may hold 100,000 segments each.
    let mut order: Vec<usize> = (0..lines.len()).collect();
    order.sort_by(|&a, &b| lines[a].1.total_cmp(&lines[b].1).then(a.cmp(&b)));
    order.truncate(MAX_MODE_LINES);
    let lines: Vec<(nalgebra::Vector3<f64>, f64)> = order.iter().map(|&i| lines[i]).collect();
    // Each line's reach, as the cosine its neighbours' directions must exceed (once per line,
    // not per pair).
    let reach: Vec<f64> = lines
        .iter()
        .map(|(_, var)| (2.5 * var.sqrt()).max(MODE_REACH_DEG.to_radians()).cos())
        .collect();
    let mut left: Vec<bool> = vec![true; lines.len()];
    let mut modes = Vec::new();
    while modes.len() < MAX_MODES {
        let along = |i: usize, j: usize| lines[i].0.dot(&lines[j].0).abs() > reach[j];
        let support: Vec<f64> = (0..lines.len())
            .map(|i| {
                if !left[i] {
                    return 0.0;
                }
                (0..lines.len())
                    .filter(|&j| left[j] && along(i, j))
                    .map(|j| mode_weight(lines[j].1))
                    .sum()
            })
            .collect();
        let Some(seed) = (0..lines.len())
            .filter(|&i| left[i])
            .max_by(|&a, &b| support[a].total_cmp(&support[b]).then(b.cmp(&a)))
        else {
            break;
        };
        let members: Vec<usize> = (0..lines.len())
            .filter(|&j| left[j] && along(seed, j))
            .collect();
        if members.len() < MODE_MIN_MEMBERS {
            break;
        }
        let sense = |j: usize| lines[j].0 * lines[j].0.dot(&lines[seed].0).signum();
        let Some(direction) = members
            .iter()
            .map(|&j| sense(j) * mode_weight(lines[j].1))
            .sum::<nalgebra::Vector3<f64>>()
            .try_normalize(1e-12)
        else {
            break;
        };
        let variance = shared_variance(
            members
                .iter()
                .map(|&j| (sense(j).dot(&direction).clamp(-1.0, 1.0).acos(), lines[j].1)),
        );
        modes.push(Mode {
            direction,
            variance,
            members: members.len(),
        });
        members.iter().for_each(|&j| left[j] = false);
    }
    modes
}

/// A doubted winner is estimated again with the scene's dominant direction it lies along,
/// when it lies along one — whether the gate doubts its direction or, with a direction that
/// passes, its position: a line along the 1–2 baseline or receding from the rig, whose ends
/// swing across it by its direction's σ times half its length (docs/ACCURACY.md, "A
/// direction for the lines doubted for their position"). Rooms are built along three
/// directions, and their long, well-measured lines tell the short ones theirs, which a short
/// segment's 20–40 px at a 0.3 m baseline cannot (docs/ACCURACY.md, "The scene's dominant
/// directions"). The directions come from this capture's certain winners
/// ([`dominant_directions`]); the share of its lines along none of them, from the best
/// measured. A winner takes a direction when the posterior that it lies along it, against
/// along none, reaches [`ALONG_POSTERIOR`]; failing that, a direction's plane when it lies
/// in it with that posterior (across the direction, or along another square to it: a room's
/// horizontal lines, its vertical known, however its furniture is turned — the planes'
/// shares and spreads from the best-measured lines across a direction and along none). Its
/// maximum-likelihood line is then found again from its three views with that direction
/// (two degrees of freedom) or that plane (one: the tilt out of it) as one more observation
/// ([`estimate_line_constrained`]), and the gate judges the result whole — a direction does
/// not place a line, so one whose position the views leave loose stays doubted. Not for a
/// winner shorter than [`ALONG_MIN_PX`] in a view; and those made certain are then checked
/// for uniqueness like every certain winner ([`flag_ambiguous`]): a wrong correspondence is
/// as vertical as a right one, and the first trial of such a prior (a study on the answers)
/// let in the lab's radiator fins, ambiguous winners whose direction was never in doubt.
/// Winners whose verification was blind to their depth are included: their gradients had to
/// agree closely to be hypotheses at all, and on a rig whose baselines run along the room's
/// directions (the L-shape) they are nearly every line (leaving them out cost both rooms a
/// point or two and the L-shape all of its gain: docs/ACCURACY.md).
fn align_with_dominant_directions(
    request: &Matching,
    observations: &Observations,
    kept: &[usize],
    fits: &mut [Option<Fit>],
    stats: &mut MatchStats,
) -> Result<(), Stopped> {
    let Matching {
        rig,
        views,
        hypotheses,
        params,
        checkpoint,
        ..
    } = *request;
    // A fit's direction, the basis across it, its direction covariance (the views' own
    // shifts in it, as reported) and that covariance in the basis.
    let direction_of = |est: &Line3Estimate| {
        let u = est.direction();
        let (e1, e2) = crate::geometry::across_basis(&u);
        let basis = nalgebra::Matrix3x2::from_columns(&[e1, e2]);
        let covariance = crate::geometry::line::direction_covariance(
            &est.start,
            &est.end,
            &est.covariance_with_own_shifts(),
        );
        let across = basis.transpose() * covariance * basis;
        (u, basis, covariance, across)
    };
    let certain: Vec<(nalgebra::Vector3<f64>, f64)> = kept
        .iter()
        .filter_map(|&h| match &fits[h] {
            Some(Some((est, q))) if q.certain => {
                let (u, _, _, across) = direction_of(est);
                Some((u, eigenvalues_2x2(&across).0))
            }
            _ => None,
        })
        .collect();
    let lending: Vec<(nalgebra::Vector3<f64>, f64)> = certain
        .iter()
        .copied()
        .filter(|(_, var)| var.sqrt() < MODE_MEMBER_SIGMA_DEG.to_radians())
        .collect();
    let modes = dominant_directions(&lending);
    if modes.is_empty() {
        return Ok(());
    }
    // What the best-measured lines do: lie along a mode; else lie across one, in the plane
    // normal to it (a room's horizontal lines, its vertical known, however its furniture
    // turns); else neither. Their shares, drawn toward ALONG_NONE_PRIOR, weigh the three
    // kinds of explanation of a doubted line.
    let best: Vec<&(nalgebra::Vector3<f64>, f64)> = certain
        .iter()
        .filter(|(_, var)| var.sqrt() < ALONG_NONE_SIGMA_DEG.to_radians())
        .collect();
    let tilt = |u: &nalgebra::Vector3<f64>, m: &Mode| u.dot(&m.direction).clamp(-1.0, 1.0).asin();
    let mut across_lines: Vec<Vec<(f64, f64)>> = vec![Vec::new(); modes.len()];
    let mut off_every_mode = 0usize;
    for (u, var) in &best {
        let along_one = modes.iter().any(|m| {
            let angle = u.dot(&m.direction).abs().clamp(0.0, 1.0).acos();
            angle * angle <= 9.0 * (var + m.variance)
        });
        if along_one {
            continue;
        }
        let tilts: Vec<f64> = modes.iter().map(|m| tilt(u, m)).collect();
        let plane = (0..modes.len())
            .filter(|&k| tilts[k].powi(2) <= 9.0 * (var + modes[k].variance))
            .min_by(|&a, &b| tilts[a].abs().total_cmp(&tilts[b].abs()));
        match plane {
            Some(k) => across_lines[k].push((tilts[k], *var)),
            None => off_every_mode += 1,
        }
    }
    let (prior_share, prior_count) = ALONG_NONE_PRIOR;
    let seen = best.len() as f64 + prior_count;
    let along_none =
        ((off_every_mode as f64 + prior_share * prior_count) / seen).max(ALONG_NONE_MIN);
    // Each mode's plane: its share, and the variance of a line's tilt out of it — the
    // lines' spread beyond their own noise, plus the normal's own.
    let planes: Vec<(f64, f64)> = modes
        .iter()
        .zip(&across_lines)
        .map(|(m, lines)| {
            if lines.is_empty() {
                return (0.0, 0.0);
            }
            (
                lines.len() as f64 / seen,
                shared_variance(lines.iter().copied()) + m.variance,
            )
        })
        .collect();
    let along_share = (1.0 - along_none - planes.iter().map(|p| p.0).sum::<f64>()).max(0.0);
    let members: usize = modes.iter().map(|m| m.members).sum();
    let mut candidates: Vec<(usize, KnownDirection)> = Vec::new();
    for &h in kept {
        let Some(Some((est, quality))) = &fits[h] else {
            continue;
        };
        if quality.certain {
            continue;
        }
        if (0..3).any(|v| views.segments[v][hypotheses[h].segments[v] as usize].len < ALONG_MIN_PX)
        {
            continue;
        }
        let (u, basis, direction_covariance, across) = direction_of(est);
        // Densities on the sphere of directions (per steradian) at this line's: each mode's
        // (a Gaussian across it, the line's variance and the mode's); each plane's (a
        // Gaussian in the tilt out of it, even along it: π radians of lines); a uniform
        // direction's (1 / 2π).
        let along: Vec<f64> = modes
            .iter()
            .map(|m| {
                let toward = m.direction * m.direction.dot(&u).signum();
                let z = basis.transpose() * (toward - u);
                let spread = across + nalgebra::Matrix2::identity() * m.variance;
                let density = spread.try_inverse().map_or(0.0, |inv| {
                    (-0.5 * (z.transpose() * inv * z)[(0, 0)]).exp()
                        / (2.0 * std::f64::consts::PI * spread.determinant().max(0.0).sqrt())
                });
                along_share * m.members as f64 / members as f64 * density
            })
            .collect();
        let in_plane: Vec<f64> = modes
            .iter()
            .zip(&planes)
            .map(|(m, &(share, variance))| {
                if share <= 0.0 {
                    return 0.0;
                }
                let t = tilt(&u, m);
                let var = (m.direction.transpose() * direction_covariance * m.direction)[(0, 0)]
                    + variance;
                share * (-0.5 * t * t / var).exp()
                    / ((2.0 * std::f64::consts::PI * var).sqrt() * std::f64::consts::PI)
            })
            .collect();
        let total: f64 = along.iter().sum::<f64>()
            + in_plane.iter().sum::<f64>()
            + along_none / (2.0 * std::f64::consts::PI);
        if !total.is_finite() || total <= 0.0 {
            continue;
        }
        let best_mode = (0..modes.len()).max_by(|&a, &b| along[a].total_cmp(&along[b]));
        if let Some(k) = best_mode.filter(|&k| along[k] / total >= ALONG_POSTERIOR) {
            candidates.push((
                h,
                KnownDirection::Along(DirectionOfLine {
                    direction: modes[k].direction,
                    variance: modes[k].variance,
                }),
            ));
            continue;
        }
        // Lying in a mode's plane: across it, or along another mode square to it.
        let plane_posterior: Vec<f64> = (0..modes.len())
            .map(|k| {
                let square: f64 = (0..modes.len())
                    .filter(|&j| modes[j].direction.dot(&modes[k].direction).abs() < SQUARE_COS)
                    .map(|j| along[j])
                    .sum();
                (in_plane[k] + square) / total
            })
            .collect();
        let best_plane = (0..modes.len())
            .filter(|&k| planes[k].0 > 0.0)
            .max_by(|&a, &b| plane_posterior[a].total_cmp(&plane_posterior[b]));
        if let Some(k) = best_plane.filter(|&k| plane_posterior[k] >= ALONG_POSTERIOR) {
            candidates.push((
                h,
                KnownDirection::Across(DirectionOfLine {
                    direction: modes[k].direction,
                    variance: planes[k].1,
                }),
            ));
        }
    }
    if candidates.is_empty() {
        return Ok(());
    }
    // Estimated again from the views with the mode's direction, or its plane, as one more
    // observation of the line (the stored fit is cut to what its ends vouch for under its
    // own direction): on the pool's threads, a chunk at a time (the fits are independent;
    // the results come in the candidates' order).
    let cameras = [rig.camera(0), rig.camera(1), rig.camera(2)];
    let factor = stats.noise_scale.powi(2);
    for chunk in candidates.chunks(RECONSTRUCT_CHUNK) {
        checkpoint.before("reconstruct")?;
        let refitted: Vec<Fit> = chunk
            .par_iter()
            .map(|(h, known)| {
                let segments = hypotheses[*h].segments;
                let obs: [LineObservation; 3] =
                    std::array::from_fn(|v| observations.lines[v][segments[v] as usize]);
                let est = estimate_line_constrained(&cameras, &obs, END_SIGMA_PX, &[], Some(known))
                    .map(|e| rescaled(e, factor));
                accept(est, rig, params).filter(|(_, q)| q.certain)
            })
            .collect();
        for ((h, _), fit) in chunk.iter().zip(refitted) {
            if let Some((est, quality)) = fit {
                fits[*h] = Some(Some((
                    est,
                    Quality {
                        aligned: true,
                        ..quality
                    },
                )));
                stats.along_dominant_directions += 1;
            }
        }
    }
    Ok(())
}

/// Most certain ends in one cell of [`join_at_vertices`]'s index (as wide as the reach, or
/// [`MIN_VERTEX_CELL_PX`]) for them to lend a vertex: a corner where a few edges meet.
const MAX_ENDS_AT_A_VERTEX: usize = 8;
/// Smallest cell of that index, pixels: any cell at least as wide as the reach finds the
/// same vertices (the 3 × 3 cells about an end hold every end within the reach of it).
const MIN_VERTEX_CELL_PX: f64 = 0.01;

/// How far across a segment an opposite-contrast segment may lie to be tried in its place,
/// pixels.
const FLIP_REACH_PX: f64 = 16.0;

/// The fits (rescaled by the noise scale, not yet accepted) of the triplets that take one of
/// `segments` (rectified indices) for a segment of opposite contrast alongside it, reversed.
/// Matching is oriented, so these are never hypotheses; but an edge whose contrast flips
/// between the views (a cabinet's front edge, seen against the wall from below and against its
/// own top from above) cannot form its true triplet, and where one view alone fixes the depth
/// the other two meet a neighbouring edge of that view in a ghost that fits as well as any
/// true line. The flipped triplet
/// is the ghost's rival — when its contrast's strength agrees with the other two views at
/// least as well as the winner's own segment does: the flipped sign is evidence for the
/// winner, and only the magnitude can weigh against it (the office's ghosts: 36 grey levels
/// per pixel in the third view against 21 in the others, the flipped edge 14). Without the
/// gradients the sign alone speaks, for the winner.
fn flipped_rivals(
    rig: &Rig,
    observations: &mut Observations,
    segments: [u32; 3],
    noise_scale: f64,
) -> Vec<Option<Line3Estimate>> {
    let gradient = |observations: &Observations, v: usize, r: u32| {
        Some(observations.rect[v][r as usize].gradient).filter(|g| *g > 0.0 && g.is_finite())
    };
    let mut triplets: Vec<(usize, u32)> = Vec::new();
    for (v, &i) in segments.iter().enumerate() {
        if !observations.lists[v].oriented {
            continue;
        }
        // How far the winner's contrast in view v is from the other two views' (log ratio).
        let others = [(v + 1) % 3, (v + 2) % 3].map(|w| gradient(observations, w, segments[w]));
        let (Some(mine), [Some(a), Some(b)]) = (gradient(observations, v, i), others) else {
            continue;
        };
        let reference = (a * b).sqrt();
        let mismatch = |g: f64| (g / reference).ln().abs();
        let list = &observations.lists[v].segments;
        let at = observations.rect[v][i as usize].index as usize;
        let index =
            observations.crowding[v].get_or_insert_with(|| crate::segment::Crowding::new(list));
        let d = list[at].end - list[at].start;
        let mut tried = 0;
        // Nearest first, and at most MAX_RIVALS per view: a list may crowd a segment with
        // reversed copies, and each one tried is a reconstruction.
        for (j, _) in index.alongside(list, at, FLIP_REACH_PX) {
            let other = &list[j as usize];
            if (other.end - other.start).dot(&d) >= 0.0 {
                continue;
            }
            if let Some(r) = observations.rect_of(v, j) {
                if gradient(observations, v, r).is_some_and(|g| mismatch(g) <= mismatch(mine)) {
                    triplets.push((v, r));
                    tried += 1;
                    if tried == MAX_RIVALS {
                        break;
                    }
                }
            }
        }
    }
    if triplets.is_empty() {
        return Vec::new();
    }
    let asked: Vec<[u32; 3]> = triplets
        .iter()
        .map(|&(v, r)| {
            let mut t = segments;
            t[v] = r;
            t
        })
        .collect();
    observations.add_crowding(&asked);
    let factor = noise_scale.powi(2);
    asked
        .iter()
        .zip(&triplets)
        .map(|(t, &(v, _))| {
            let mut obs: [LineObservation; 3] =
                std::array::from_fn(|w| observations.lines[w][t[w] as usize]);
            std::mem::swap(&mut obs[v].start, &mut obs[v].end);
            reconstruct_pieces(rig, &obs).map(|e| rescaled(e, factor))
        })
        .collect()
}

/// Whether `rival` explains its images about as well as `winner`: χ² at most
/// [`AMBIGUITY_CHI2_MARGIN`] worse, ends agreeing across the views within
/// [`AMBIGUITY_ENDS_AGREE`] σ or no worse than the winner's. Neither changes when a fit is
/// accepted (its ends moved), so it is asked of a rival before its acceptance.
fn as_likely(winner: &Line3Estimate, rival: &Line3Estimate) -> bool {
    rival.chi2 <= winner.chi2 + AMBIGUITY_CHI2_MARGIN
        && rival.ends_disagreement <= winner.ends_disagreement.max(AMBIGUITY_ENDS_AGREE)
}

/// Whether `rival` explains its images about as well as `winner` ([`as_likely`]) with a 3D
/// line somewhere else: its midpoint off the winner's line by more than the gate's position
/// tolerance, or its direction by more than the gate's direction tolerance.
fn as_likely_elsewhere(
    winner: &Line3Estimate,
    rival: &Line3Estimate,
    centre: &nalgebra::Point3<f64>,
    params: &MatchParams,
) -> bool {
    if !as_likely(winner, rival) {
        return false;
    }
    let u = winner.direction();
    let mid = nalgebra::center(&rival.start, &rival.end);
    let tolerance = position_tolerance(params, centre, &mid);
    let w = mid - winner.start;
    let across = (w - u * w.dot(&u)).norm();
    across > tolerance
        || rival.direction().dot(&u).abs() < params.gate_direction_deg.to_radians().cos()
}

/// Whether two 3D lines' midpoints are apart by more than [`APART_SIGMAS`] standard
/// deviations of their joint position noise, across `winner`'s line in the direction that
/// separates them: an uncertain rival somewhere else is then a different line, not the
/// winner's own seen less precisely.
fn significantly_apart(winner: &Line3Estimate, rival: &Line3Estimate) -> bool {
    // The midpoint's whole covariance, along its line too: a rival tilted from the winner
    // carries some of its ends' spread across the winner's line. (`midpoint_covariance`
    // keeps the across part only; with it, measured, more rivals count: office images
    // 1.01% / 62.7% -> 0.76% / 62.2%, lab 0.88% / 65.2% -> 0.66% / 65.0%.)
    let midpoint_covariance = |e: &Line3Estimate| {
        let c = &e.covariance;
        (c.fixed_view::<3, 3>(0, 0)
            + c.fixed_view::<3, 3>(0, 3)
            + c.fixed_view::<3, 3>(3, 0)
            + c.fixed_view::<3, 3>(3, 3))
            * 0.25
    };
    let u = winner.direction();
    let w =
        nalgebra::center(&rival.start, &rival.end) - nalgebra::center(&winner.start, &winner.end);
    let across = w - u * w.dot(&u);
    let Some(n) = across.try_normalize(0.0) else {
        return false;
    };
    let joint = midpoint_covariance(winner) + midpoint_covariance(rival);
    let variance = (n.transpose() * joint * n)[(0, 0)].max(0.0);
    across.norm() > APART_SIGMAS * variance.sqrt()
}

/// Adds the pairs of `graph` (indices into the caller's list of view 1) that `adjacency`
/// (indices into `segments`, the prepared view 1) lacks, their vertex rectified.
fn add_graph(
    adjacency: &mut Vec<(u32, u32, Point2<f64>)>,
    graph: &[Adjacent],
    rig: &Rig,
    rect: &Rectification,
    segments: &[RectSegment],
) {
    if graph.is_empty() {
        return;
    }
    let mut prepared_index: FxHashMap<u32, u32> = FxHashMap::default();
    for (i, s) in segments.iter().enumerate() {
        prepared_index.insert(s.index, i as u32);
    }
    let mut known: FxHashSet<(u32, u32)> = adjacency
        .iter()
        .map(|&(a, b, _)| (a.min(b), a.max(b)))
        .collect();
    for e in graph {
        let (Some(&a), Some(&b)) = (prepared_index.get(&e.a), prepared_index.get(&e.b)) else {
            continue;
        };
        let key = (a.min(b), a.max(b));
        if a == b || !known.insert(key) {
            continue;
        }
        if let Some(vertex) = rect.to_rect(0, rig.camera(0).undistort(e.vertex)) {
            adjacency.push((key.0, key.1, vertex));
        }
    }
}

/// The output: collinear fragments accepted together (they share a segment) make one 3D
/// segment, estimated from all their pieces — longer, so better determined, than each piece
/// alone; if that joint estimate is rejected, the best-determined piece stands for the
/// group. Segments that miss the accuracy asked for are left out (and counted) unless
/// `include_uncertain` asks for them, flagged.
fn assemble(
    request: &Matching,
    observed: &[Vec<LineObservation>],
    kept: &[(usize, Line3Estimate, Quality)],
    stats: &mut MatchStats,
) -> MatchOutput {
    let Matching {
        rig,
        views,
        hypotheses,
        params,
        ..
    } = *request;
    let indices: Vec<usize> = kept.iter().map(|k| k.0).collect();
    let triplets: Vec<[u32; 3]> = indices.iter().map(|&h| hypotheses[h].segments).collect();
    let views_observed: [&[LineObservation]; 3] = std::array::from_fn(|v| &observed[v][..]);
    let mut output = MatchOutput::default();
    for group in fragment_groups(&triplets) {
        let merged = (group.len() > 1).then(|| {
            let factor = stats.noise_scale.powi(2);
            let fragments = group.iter().map(|&k| triplets[k]);
            accept(
                reconstruct_fragments(rig, views_observed, fragments).map(|e| rescaled(e, factor)),
                rig,
                params,
            )
        });
        let best_piece = || {
            group
                .iter()
                .map(|&k| (kept[k].1, kept[k].2))
                .min_by(|a, b| a.1.direction_sigma_deg.total_cmp(&b.1.direction_sigma_deg))
        };
        let Some((est, quality)) = merged.flatten().or_else(best_piece) else {
            continue;
        };
        if !quality.certain {
            stats.uncertain += 1;
            if !params.include_uncertain {
                continue;
            }
        }
        let first_triplet = output.triplets.len() as u32;
        for &k in &group {
            let hyp = &hypotheses[indices[k]];
            output.triplets.push(Triplet {
                segments: std::array::from_fn(|v| {
                    views.segments[v][hyp.segments[v] as usize].index
                }),
                residual_px: hyp.residual_px,
            });
        }
        output.segments_3d.push(Reconstructed {
            segment: Segment3 {
                start: est.start,
                end: est.end,
            },
            triplet: first_triplet,
            triplets: (first_triplet..output.triplets.len() as u32).collect(),
            residual_px: est.residual_px,
            covariance: reported_covariance(&est, quality.shift_sigma_m),
            shift_sigma_m: quality.shift_sigma_m,
            direction_sigma_deg: quality.direction_sigma_deg,
            position_sigma_m: quality.position_sigma_m,
            uncertain: !quality.certain,
            aligned: quality.aligned,
        });
    }
    output
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::segment::Segment2;
    use crate::testing::preset_rig;

    /// A vertical line 2 m ahead of the rig, as a fit of `chi2` with ends agreeing to
    /// `ends` σ.
    fn line_at(x: f64, z: f64, chi2: f64, ends: f64) -> Line3Estimate {
        Line3Estimate {
            start: nalgebra::Point3::new(x, -0.2, z),
            end: nalgebra::Point3::new(x, 0.2, z),
            covariance: nalgebra::Matrix6::identity() * 1e-6,
            systematic_shifts: [nalgebra::Vector6::zeros(); 3],
            chi2,
            dof: 2,
            residual_px: 0.05,
            end_along_sigma_m: [0.003; 2],
            ends_disagreement: ends,
            reach_m: [0.0; 2],
        }
    }

    /// The χ² of `n` winners with 2 degrees of freedom and noise `scale` times what is stated:
    /// its quantiles, evenly spread (a χ² of 2 dof is exponential, mean 2).
    fn winners_of_scale(n: usize, scale: f64) -> Vec<Option<Line3Estimate>> {
        (0..n)
            .map(|i| {
                let p = (i as f64 + 0.5) / n as f64;
                Some(line_at(
                    0.0,
                    2.0,
                    -2.0 * (1.0 - p).ln() * scale * scale,
                    0.0,
                ))
            })
            .collect()
    }

    #[test]
    fn the_noise_scale_is_read_among_consistent_winners() {
        // Lines as noisy as stated: 1.
        let honest = winners_of_scale(200, 1.0);
        assert!((variance_factor(&honest) - 1.0).abs() < 0.05);
        // Twice as noisy: the scale sees it, the trimming keeps them all.
        let noisy = variance_factor(&winners_of_scale(200, 2.0));
        assert!((noisy - 4.0).abs() < 0.25, "{noisy}");
        // Lines as stated and a fifth as many wrong winners far off: the quartile alone
        // would be theirs (the 150th of 240, among the wrong ones' 40), the consistent ones
        // say 1.
        let mut contaminated = honest.clone();
        contaminated.extend((0..40).map(|i| Some(line_at(0.0, 2.0, 100.0 + i as f64, 0.0))));
        let mut ratios: Vec<f64> = contaminated
            .iter()
            .flatten()
            .map(|e| e.chi2 / chi2_quantile(e.dof, QUARTILE_Z))
            .collect();
        ratios.sort_by(f64::total_cmp);
        assert!(ratios[ratios.len() * 3 / 4] > 1.2, "the untrimmed quartile");
        let trimmed = variance_factor(&contaminated);
        assert!((trimmed - 1.0).abs() < 0.05, "{trimmed}");
    }

    /// A line receding from the rig, 2 to 3 m ahead, to the right and below, whose ends are
    /// known to `sigma_m` in every direction.
    fn receding_line(sigma_m: f64) -> Line3Estimate {
        Line3Estimate {
            start: nalgebra::Point3::new(0.5, 0.3, 2.0),
            end: nalgebra::Point3::new(0.5, 0.3, 3.0),
            covariance: nalgebra::Matrix6::identity() * (sigma_m * sigma_m),
            ..line_at(0.0, 2.0, 0.5, 1.0)
        }
    }

    #[test]
    fn an_end_slides_along_a_receding_line_by_what_the_line_misses_across() {
        let rig = preset_rig();
        let sigma = 0.01;
        let est = receding_line(sigma);
        let u = est.direction();
        let slide = |e: &Line3Estimate, at: &nalgebra::Point3<f64>, which| {
            end_slide_sigma_m(&rig, at, &e.direction(), &e.covariance, which)
        };
        // The rays meet the far end at about 11°: the end slides σ·cot θ, five times what the
        // line misses across. The middle view's: within the three views' cot θ.
        let cot = |v: usize| {
            let ray = (est.end - rig.camera(v).centre()).normalize();
            let cos = ray.dot(&u);
            cos / (1.0 - cos * cos).sqrt()
        };
        let (lo, hi) = (0..3)
            .map(cot)
            .fold((f64::INFINITY, 0.0_f64), |(lo, hi), c| {
                (lo.min(c), hi.max(c))
            });
        let far = slide(&est, &est.end, 1);
        assert!(lo > 4.0, "{lo}");
        assert!(
            far >= sigma * lo - 1e-12 && far <= sigma * hi + 1e-12,
            "{far} not within {lo}σ–{hi}σ"
        );
        // The near end, seen less obliquely, slides less.
        assert!(slide(&est, &est.start, 0) < far);
        // An uncertainty along the line alone moves no end along it.
        let mut covariance = nalgebra::Matrix6::zeros();
        covariance
            .fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&(u * u.transpose() * (sigma * sigma)));
        let e = Line3Estimate { covariance, ..est };
        assert!(
            slide(&e, &e.end, 1) < 1e-9 * sigma,
            "{}",
            slide(&e, &e.end, 1)
        );
        // A ray straight along the line: the end is as unknown along it as the floor of 3°
        // makes it (at least), not known exactly; and a ray square to it, no slide at all.
        let z = nalgebra::Vector3::z();
        let round = nalgebra::Matrix3::identity() * (sigma * sigma);
        let floor = sigma / END_SLIDE_MIN_SIN;
        let head_on = slide_variance(&(z * 2.0), &z, &round).sqrt();
        assert!(head_on >= 0.99 * floor, "{head_on} against {floor}");
        assert_eq!(slide_variance(&nalgebra::Vector3::x(), &z, &round), 0.0);
        assert_eq!(slide_variance(&nalgebra::Vector3::zeros(), &z, &round), 0.0);
        // A vertical line straight ahead, seen nearly square on: hardly any slide.
        let frontal = Line3Estimate {
            covariance: est.covariance,
            ..line_at(0.0, 2.0, 0.5, 1.0)
        };
        assert!(slide(&frontal, &frontal.end, 1) < 0.15 * sigma);
    }

    #[test]
    fn a_receding_line_placed_loosely_across_is_cut_to_what_its_ends_can_vouch_for() {
        // The image ends alone (3 mm along) would keep the whole metre; the line's own 1 cm
        // across, carried along by the grazing rays, pulls both ends in — the far one most —
        // and a line placed to 0.1 mm keeps its length.
        let rig = preset_rig();
        let params = MatchParams::default();
        let (est, _) = accept(Some(receding_line(0.01)), &rig, &params).expect("kept");
        let (precise, _) = accept(Some(receding_line(1e-4)), &rig, &params).expect("kept");
        let original = receding_line(0.0);
        assert_eq!(precise.start, original.start);
        assert_eq!(precise.end, original.end);
        let (cut_start, cut_end) = (
            (est.start - original.start).norm(),
            (original.end - est.end).norm(),
        );
        assert!(
            cut_end > 0.05 && cut_end > cut_start,
            "{cut_start} {cut_end}"
        );
        // Pulled in along the line, not off it.
        let u = original.direction();
        assert!(((est.end - original.start).cross(&u)).norm() < 1e-12);
    }

    #[test]
    fn a_piece_of_line_shorter_than_the_matchers_overlap_in_every_view_is_not_certain() {
        // A well-measured line 2 m in front of the first camera, across its axis, 40 cm
        // long; then the same line cut to its middle 2 mm as a trim cuts (the ends blended,
        // so its direction stays as well known): about half a pixel in every image of the
        // preset rig.
        let rig = preset_rig();
        let params = MatchParams::default();
        let camera = rig.camera(0);
        let centre = camera.centre() + camera.axis() * 2.0;
        let across = crate::geometry::across_basis(&camera.axis()).0;
        let long = Line3Estimate {
            start: centre - across * 0.2,
            end: centre + across * 0.2,
            ..line_at(0.0, 2.0, 0.5, 1.0)
        };
        let mut short = long;
        let cut = 0.5 * (1.0 - 0.002 / 0.4);
        blend_ends(&mut short, cut, cut);
        let (long_px, short_px) = (
            longest_image_px(&rig, &long),
            longest_image_px(&rig, &short),
        );
        assert!(long_px > 100.0 && short_px < 1.0, "{long_px} {short_px}");
        let (_, quality) = accept(Some(long), &rig, &params).expect("kept");
        assert!(quality.certain);
        let (_, quality) = accept(Some(short), &rig, &params).expect("kept, flagged");
        assert!(quality.direction_sigma_deg < 1.0, "{quality:?}");
        assert!(!quality.certain);
    }

    #[test]
    fn an_end_two_views_carry_on_moves_out_by_at_most_half_the_tolerance() {
        // A vertical line 2 m ahead, precise: the tolerance is 2 cm at both ends.
        let rig = preset_rig();
        let params = MatchParams::default();
        let line = |reach_m| Line3Estimate {
            reach_m,
            ..line_at(0.1, 2.0, 0.5, 1.0)
        };
        let original = line([0.0; 2]);
        let u = original.direction();
        let tolerance = position_tolerance(&params, &rig.centroid(), &original.end);
        assert!((tolerance - 0.02).abs() < 1e-3, "{tolerance}");
        // 5 mm past the start: all of it; 30 cm past the end: half the tolerance.
        let (est, quality) = accept(Some(line([0.005, 0.3])), &rig, &params).expect("kept");
        let moved_start = (original.start - est.start).dot(&u);
        let moved_end = (est.end - original.end).dot(&u);
        assert!((moved_start - 0.005).abs() < 1e-12, "{moved_start}");
        let half =
            REACH_SHARE_OF_TOLERANCE * position_tolerance(&params, &rig.centroid(), &est.end);
        assert!(
            (moved_end - half).abs() < 1e-4,
            "{moved_end} against {half}"
        );
        // Along the line, not off it; and the segment stays as certain as it was.
        assert!(((est.end - original.start).cross(&u)).norm() < 1e-12);
        let (_, unmoved) = accept(Some(original), &rig, &params).expect("kept");
        assert_eq!(quality.certain, unmoved.certain);
        // The moved ends' covariance follows the blend: carried on past the old ends, it
        // grows across the line.
        let across = |e: &Line3Estimate| e.covariance[(0, 0)] + e.covariance[(3, 3)];
        assert!(
            across(&est) >= across(&original),
            "{} {}",
            across(&est),
            across(&original)
        );
    }

    #[test]
    fn the_shared_shift_widens_the_position_and_leaves_the_direction() {
        let est = Line3Estimate {
            start: nalgebra::Point3::new(0.3, -0.2, 2.0),
            end: nalgebra::Point3::new(0.1, 0.5, 2.6),
            ..line_at(0.0, 2.0, 0.5, 1.0)
        };
        let sigma = 0.002;
        let shifted = Line3Estimate {
            covariance: est.covariance + shared_shift_covariance(&est.start, &est.end, sigma),
            ..est
        };
        let difference = shifted.direction_covariance() - est.direction_covariance();
        assert!(difference.abs().max() < 1e-18, "{difference}");
        // Across the line the midpoint gains σ² in every direction, along it nothing.
        let u = est.direction();
        let (e1, e2) = crate::geometry::across_basis(&u);
        let added = shifted.midpoint_covariance() - est.midpoint_covariance();
        for e in [e1, e2] {
            assert!((e.dot(&(added * e)) - sigma * sigma).abs() < 1e-15);
        }
        assert!((added * u).norm() < 1e-15);
        assert!(
            shared_shift_covariance(&est.start, &est.start, sigma)
                .abs()
                .max()
                == 0.0
        );
        assert!(
            shared_shift_covariance(&est.start, &est.end, 0.0)
                .abs()
                .max()
                == 0.0
        );
    }

    #[test]
    fn a_reported_segment_carries_the_shared_shift_and_a_session_can_take_it_out() {
        // Exact projections of a few lines 2–3.5 m ahead of the rig, every match: each
        // segment's reported covariance is its estimate's with the shift its range gives, and
        // what a session compares by is the estimate's alone.
        let rig = preset_rig();
        let out = lines_ahead_matched(&rig, None);
        assert!(out.segments_3d.len() >= 6, "{:?}", out.stats);
        let focal = (0..3).map(|v| rig.camera(v).focal_px()).sum::<f64>() / 3.0;
        assert!((shared_shift_per_metre(&rig) - SHARED_SHIFT_PX / focal).abs() < 1e-18);
        for r in &out.segments_3d {
            let mid = nalgebra::center(&r.segment.start, &r.segment.end);
            let expected = SHARED_SHIFT_PX * (mid - rig.centroid()).norm() / focal;
            assert!((r.shift_sigma_m - expected).abs() <= 1e-12 * expected);
            let relative = r.relative_covariance();
            let shift = shared_shift_covariance(&r.segment.start, &r.segment.end, r.shift_sigma_m);
            assert!((relative + shift - r.covariance).abs().max() <= 1e-15);
            // The reported position σ holds the shift: at least σ of the shift itself.
            assert!(r.position_sigma_m >= r.shift_sigma_m * (1.0 - 1e-9));
        }
    }

    /// Exact projections of eight lines 2–3.5 m ahead of `rig`, each segment stating `noise`
    /// (or none), matched with every segment in the answer.
    fn lines_ahead_matched(rig: &Rig, noise: Option<LineNoise>) -> MatchOutput {
        let ahead = rig.camera(0).axis();
        let (side, up) = crate::geometry::across_basis(&ahead);
        let lines: Vec<[nalgebra::Point3<f64>; 2]> = (0..8)
            .map(|i| {
                let depth = 2.0 + 0.2 * i as f64;
                let at = rig.centroid() + ahead * depth + side * (0.15 * i as f64 - 0.5);
                let along = if i % 2 == 0 { up } else { side + up * 0.3 };
                [at - along * 0.25, at + along * 0.25]
            })
            .collect();
        let list = |view: usize| SegmentList {
            segments: lines
                .iter()
                .map(|l| {
                    let cam = rig.camera(view);
                    Segment2 {
                        gradient: Some(20.0),
                        noise,
                        ..Segment2::new(cam.project(&l[0]).unwrap(), cam.project(&l[1]).unwrap())
                    }
                })
                .collect(),
            oriented: true,
            background_gradient: None,
        };
        let lists = [list(0), list(1), list(2)];
        let params = MatchParams {
            include_uncertain: true,
            ..MatchParams::default()
        };
        run(rig, Input::lists(&lists), &Options::with(params))
            .expect("lines match")
            .output
    }

    #[test]
    fn the_reported_direction_sigma_is_the_reported_covariances_each_views_shift_in_it() {
        // Lists that state no noise (the model's, with `list_shift_px`), and lists that state
        // it with and without a shift of their own: the direction σ each segment reports is
        // the one its reported covariance gives, and a shift of each view's line turns the
        // 3D line, so it widens that σ where the same lines state none (a little for these
        // lines, which every view sees broadside: a shift mostly moves them; much for a line
        // along a baseline, whose ends two different views place).
        let rig = preset_rig();
        let stated = |shift_px| LineNoise {
            offset_px: 0.05,
            angle_rad: 0.0005,
            shift_px,
        };
        let model = lines_ahead_matched(&rig, None);
        let (plain, shifted) = (
            lines_ahead_matched(&rig, Some(stated(0.0))),
            lines_ahead_matched(&rig, Some(stated(0.3))),
        );
        for out in [&model, &plain, &shifted] {
            assert!(out.segments_3d.len() >= 6, "{:?}", out.stats);
            for r in &out.segments_3d {
                let (major, _) = principal_variances(
                    &r.direction_covariance(),
                    &nalgebra::Matrix3x2::from_columns(&{
                        let u = (r.segment.end - r.segment.start).normalize();
                        let (e1, e2) = crate::geometry::across_basis(&u);
                        [e1, e2]
                    }),
                );
                let from_covariance = major.sqrt().to_degrees();
                assert!(
                    (r.direction_sigma_deg - from_covariance).abs() <= 1e-9 * from_covariance,
                    "{} against {from_covariance}",
                    r.direction_sigma_deg
                );
            }
        }
        assert_eq!(
            plain.triplets, shifted.triplets,
            "a shift is not matched by"
        );
        assert_eq!(plain.segments_3d.len(), shifted.segments_3d.len());
        for a in &plain.segments_3d {
            let b = shifted
                .segments_3d
                .iter()
                .find(|b| b.triplets == a.triplets)
                .expect("the same triplets make the same segments");
            assert!(
                b.direction_sigma_deg > a.direction_sigma_deg,
                "{} with the shift, {} without",
                b.direction_sigma_deg,
                a.direction_sigma_deg
            );
        }
    }

    #[test]
    fn a_rival_elsewhere_that_explains_the_images_as_well_makes_a_winner_ambiguous() {
        let params = MatchParams::default();
        let centre = nalgebra::Point3::origin();
        let ambiguous = |winner: &Line3Estimate, rival: Line3Estimate| {
            as_likely_elsewhere(winner, &rival, &centre, &params)
        };
        let winner = line_at(0.0, 2.0, 0.5, 1.0);
        // The next fin of a radiator at another depth, fitted as well: ambiguous.
        assert!(ambiguous(&winner, line_at(0.05, 2.7, 0.8, 1.5)));
        // The same line again (a fragment, a millimetre off): no rival.
        assert!(!ambiguous(&winner, line_at(0.001, 2.0, 0.5, 1.0)));
        // Elsewhere but a far worse fit, or ends that disagree where the winner's agree.
        assert!(!ambiguous(&winner, line_at(0.05, 2.7, 5.0, 1.0)));
        assert!(!ambiguous(&winner, line_at(0.05, 2.7, 0.8, 9.0)));
        // A winner whose own ends disagree (one hidden) has no edge there over the rival.
        let hidden = line_at(0.0, 2.0, 0.5, 8.0);
        assert!(ambiguous(&hidden, line_at(0.05, 2.7, 0.8, 7.0)));
    }

    #[test]
    fn an_imprecise_rival_counts_only_when_it_lies_beyond_the_noise() {
        let winner = line_at(0.0, 2.0, 0.5, 1.0);
        let imprecise = |x: f64, sigma_m: f64| Line3Estimate {
            covariance: nalgebra::Matrix6::identity() * sigma_m * sigma_m,
            ..line_at(x, 2.0, 0.5, 1.0)
        };
        // 5 cm off with σ 1 cm at each end (0.71 cm at the midpoint): a second place.
        assert!(significantly_apart(&winner, &imprecise(0.05, 0.01)));
        // The same 5 cm with σ 4 cm: the winner's own line, seen less precisely.
        assert!(!significantly_apart(&winner, &imprecise(0.05, 0.04)));
        // Along the winner's line is not apart, however precise.
        let along = Line3Estimate {
            start: nalgebra::Point3::new(0.0, 0.3, 2.0),
            end: nalgebra::Point3::new(0.0, 0.7, 2.0),
            ..line_at(0.0, 2.0, 0.5, 1.0)
        };
        assert!(!significantly_apart(&winner, &along));
    }

    #[test]
    fn a_ghost_is_ambiguous_when_the_true_edge_flips_contrast_in_the_view_that_fixes_depth() {
        let rig = preset_rig();
        let (c1, c2) = (rig.camera(0).centre(), rig.camera(1).centre());
        let along = (c2 - c1).normalize();
        // A 60 cm edge parallel to the baseline of cameras 1 and 2, and its ghost in the same
        // epipolar plane 25% farther from camera 1: the two look alike in views 1 and 2 and
        // only view 3 tells their depths apart.
        let near = nalgebra::Point3::new(-0.1, 2.0, -0.15);
        let edge = [near - along * 0.3, near + along * 0.3];
        let ghost = edge.map(|p| c1 + (p - c1) * 1.25);
        // Each segment as seen, with its contrast (grey levels per pixel).
        let seen = |view: usize, line: &[nalgebra::Point3<f64>; 2], reversed: bool, gradient| {
            let cam = rig.camera(view);
            let (a, b) = (
                cam.project(&line[0]).unwrap(),
                cam.project(&line[1]).unwrap(),
            );
            let (a, b) = if reversed { (b, a) } else { (a, b) };
            Segment2 {
                gradient: Some(gradient),
                ..Segment2::new(a, b)
            }
        };
        let list = |segments: Vec<Segment2>| SegmentList {
            segments,
            oriented: true,
            background_gradient: None,
        };
        let params = MatchParams {
            include_uncertain: true,
            ..MatchParams::default()
        };
        // Views 1 and 2 see the edge at 20 grey levels per pixel; the ghost's segment in view 3
        // is a stronger edge (30: within the depth-blind ratio, 1.6, of the other two).
        let run_with = |third: Vec<Segment2>| {
            let lists = [
                list(vec![seen(0, &edge, false, 20.0)]),
                list(vec![seen(1, &edge, false, 21.0)]),
                list(third),
            ];
            let options = Options::with(params.clone());
            run(&rig, Input::lists(&lists), &options).unwrap().output
        };
        let answer = |third: Vec<Segment2>| {
            let out = run_with(third);
            assert_eq!(out.segments_3d.len(), 1, "{:?}", out.stats);
            (out.segments_3d[0].uncertain, out.stats.ambiguous)
        };
        // A ghost whose view-3 edge is 1.8 times as strong as the others' is not a triplet at
        // all: view 2, along the line, cannot check its depth, so the gradients must agree.
        let out = run_with(vec![seen(2, &ghost, false, 36.0)]);
        assert!(out.segments_3d.is_empty(), "{:?}", out.stats);
        assert_eq!(out.stats.depth_blind_refused, 1);
        let ghost_in_three = seen(2, &ghost, false, 30.0);
        // View 3 sees only the ghost's line: nothing else fits, the answer vouches for it.
        assert_eq!(answer(vec![ghost_in_three]), (false, 0));
        // View 3 also sees the true edge, its contrast flipped (seen against another
        // background from above) and nearer the other views' in strength: oriented matching
        // cannot form that triplet, but it fits views 1 and 2 as well as the ghost does, so
        // the ghost is not vouched for.
        let flipped = |gradient| seen(2, &edge, true, gradient);
        assert_eq!(answer(vec![ghost_in_three, flipped(18.0)]), (true, 1));
        // A flipped edge whose strength agrees with views 1 and 2 worse than the winner's
        // does: both the sign and the strength speak for the winner.
        assert_eq!(answer(vec![ghost_in_three, flipped(70.0)]), (false, 0));
    }

    #[test]
    fn a_doubtful_winner_gives_way_to_a_certain_rival_that_fits_better() {
        let rig = preset_rig();
        // Views 2 and 3 see only the edge's lower half (the upper half hidden from them). Its
        // ghost is seen whole in views 2 and 3 — a line there that happens to fit — and so
        // covers more of view 1's segment, which validation ranks first.
        let (edge, ghost) = an_edge_and_its_ghost(&rig);
        let lower = [edge[0], nalgebra::center(&edge[0], &edge[1])];
        let seen = |view, line: &[nalgebra::Point3<f64>; 2], shift_px, sigma_px| {
            imaged(&rig, view, line, shift_px, sigma_px)
        };
        let list = oriented;
        // The ghost's lines are imprecise (0.35 px at each end), too imprecise for the gate,
        // and its third view is 0.8 px off the ghost's place: one 3D line within its noise,
        // but a worse fit than the edge's precise lines (0.05 px). Without the rule the ghost
        // keeps view 1's segment and the default answer is empty.
        let run_lists = |edge_sigma_px: Option<f64>, include_uncertain| {
            let lists = [
                list(vec![seen(0, &edge, 0.0, edge_sigma_px)]),
                list(vec![
                    seen(1, &lower, 0.0, edge_sigma_px),
                    seen(1, &ghost, 0.0, Some(0.35)),
                ]),
                list(vec![
                    seen(2, &lower, 0.0, edge_sigma_px),
                    seen(2, &ghost, 0.8, Some(0.35)),
                ]),
            ];
            matched(&rig, &lists, include_uncertain)
        };
        // The edge's triplet is the answer, certain: the ghost, uncertain, gave way.
        let out = run_lists(Some(0.05), false);
        assert_eq!(out.segments_3d.len(), 1, "{:?}", out.stats);
        let answer = &out.segments_3d[0];
        assert!(!answer.uncertain);
        assert_eq!(out.triplets[answer.triplet as usize].segments, [0, 0, 0]);
        let depth = |p: &nalgebra::Point3<f64>| p.y;
        assert!((depth(&answer.segment.start) - 2.0).abs() < 0.01);
        assert!((depth(&answer.segment.end) - 2.0).abs() < 0.01);
        // And the ghost is not answered beside it, even among the uncertain.
        let everything = run_lists(Some(0.05), true);
        assert_eq!(everything.segments_3d.len(), 1, "{:?}", everything.stats);
        // An edge whose certainty would rest on the list model's noise does not take the
        // ghost's place: the ghost stays, doubtful, and the default answer is empty.
        let modelled = run_lists(None, true);
        assert_eq!(modelled.segments_3d.len(), 1, "{:?}", modelled.stats);
        assert!(modelled.segments_3d[0].uncertain);
        assert!(run_lists(None, false).segments_3d.is_empty());
    }

    #[test]
    fn a_ghost_whose_ends_disagree_gives_way_to_the_edge_it_took_a_segment_from() {
        let rig = preset_rig();
        // Views 2 and 3 see only the edge's lower part (the rest hidden from them). A
        // repetitive structure's ghost: a line on view 1's rays that views 2 and 3 also hold —
        // but their segments are the images of two other pieces of that line, one 6 cm
        // higher, one 6 cm lower, as the fins of a radiator matched one fin over each way are.
        // The three lines fit that one 3D line exactly, and the ghost covers more of view 1's
        // segment, which validation ranks first; only the views' ends say it is three edges,
        // not one.
        let (edge, ghost) = an_edge_and_its_ghost(&rig);
        let lower = [edge[0], edge[0] + (edge[1] - edge[0]) * 0.6];
        let shifted = |dz: f64| ghost.map(|p| p + nalgebra::Vector3::new(0.0, 0.0, dz));
        let seen = |view, line: &[nalgebra::Point3<f64>; 2], sigma_px| {
            imaged(&rig, view, line, 0.0, sigma_px)
        };
        let list = oriented;
        let run_lists = |sigma_px: Option<f64>, include_uncertain| {
            let lists = [
                list(vec![seen(0, &edge, sigma_px)]),
                list(vec![
                    seen(1, &lower, sigma_px),
                    seen(1, &shifted(0.06), sigma_px),
                ]),
                list(vec![
                    seen(2, &lower, sigma_px),
                    seen(2, &shifted(-0.06), sigma_px),
                ]),
            ];
            matched(&rig, &lists, include_uncertain)
        };
        for sigma_px in [Some(0.05), None] {
            // Every match: the ghost was the winner, its views' ends tens of σ apart.
            let everything = run_lists(sigma_px, true);
            let ghost_fit = everything
                .segments_3d
                .iter()
                .find(|s| everything.triplets[s.triplet as usize].segments == [0, 1, 1]);
            assert!(ghost_fit.is_none(), "{sigma_px:?}: the ghost is answered");
            // The edge's triplet is the answer, certain, at the edge's depth.
            let out = run_lists(sigma_px, false);
            assert_eq!(out.segments_3d.len(), 1, "{sigma_px:?}: {:?}", out.stats);
            let answer = &out.segments_3d[0];
            assert!(!answer.uncertain);
            assert_eq!(out.triplets[answer.triplet as usize].segments, [0, 0, 0]);
            for end in [&answer.segment.start, &answer.segment.end] {
                assert!((end.y - 2.0).abs() < 0.01, "{sigma_px:?}: {end}");
            }
        }
    }

    #[test]
    fn a_short_segment_ending_at_a_certain_ones_end_is_placed_through_their_vertex() {
        let rig = preset_rig();
        // A post 2 m ahead, 60 cm tall, seen precisely (0.05 px at each end); from its top a
        // short rail runs off to the side and back, 14 cm, seen to 0.15 px: too short for its
        // direction to meet the gate alone.
        let top = nalgebra::Point3::new(0.05, 2.0, 0.15);
        let post = [nalgebra::Point3::new(0.05, 2.0, -0.45), top];
        let rail = [top, top + nalgebra::Vector3::new(0.1, 0.07, 0.06)];
        let seen = |view: usize, line: &[nalgebra::Point3<f64>; 2], sigma_px: Option<f64>| {
            let cam = rig.camera(view);
            let (a, b) = (
                cam.project(&line[0]).unwrap(),
                cam.project(&line[1]).unwrap(),
            );
            Segment2 {
                gradient: Some(20.0),
                noise: sigma_px.map(|s| LineNoise::from_endpoint_sigma(s, (b - a).norm())),
                ..Segment2::new(a, b)
            }
        };
        // `gap_px`: the rail's segment in view 3 starts this far along itself from the post's
        // top, as where an occluded line stops differs from view to view.
        let lists_with = |gap_px: f64| -> [SegmentList; 3] {
            std::array::from_fn(|v| {
                let mut rail = seen(v, &rail, Some(0.15));
                if v == 2 {
                    rail.start += (rail.end - rail.start).normalize() * gap_px;
                }
                SegmentList {
                    segments: vec![seen(v, &post, Some(0.05)), rail],
                    oriented: true,
                    background_gradient: None,
                }
            })
        };
        let lists = lists_with(0.0);
        let run_with = |vertex_reach_px| {
            let params = MatchParams {
                vertex_reach_px,
                include_uncertain: true,
                ..MatchParams::default()
            };
            run(&rig, Input::lists(&lists), &Options::with(params))
                .unwrap()
                .output
        };
        let rail_of = |out: &MatchOutput| {
            out.segments_3d
                .iter()
                .find(|s| out.triplets[s.triplet as usize].segments == [1, 1, 1])
                .cloned()
                .expect("the rail is matched")
        };
        let alone = run_with(0.0);
        assert_eq!(alone.stats.joined_at_vertices, 0);
        let before = rail_of(&alone);
        assert!(before.uncertain, "{before:?}");
        let joined = run_with(MatchParams::VERTEX_REACH_PX);
        assert_eq!(joined.stats.joined_at_vertices, 1, "{:?}", joined.stats);
        let after = rail_of(&joined);
        assert!(!after.uncertain, "{after:?}");
        assert!(after.direction_sigma_deg < 0.8 * before.direction_sigma_deg);
        // And it is where the rail is: its ends on the rail's line.
        let truth = (rail[1] - rail[0]).normalize();
        for p in [after.segment.start, after.segment.end] {
            let w = p - rail[0];
            assert!((w - truth * w.dot(&truth)).norm() < 0.005, "{p}");
        }
        // The post lent its vertex and stayed as it was.
        let post_of = |out: &MatchOutput| {
            out.segments_3d
                .iter()
                .find(|s| out.triplets[s.triplet as usize].segments == [0, 0, 0])
                .map(|s| (s.segment, s.uncertain))
        };
        assert_eq!(post_of(&joined), post_of(&alone));
        assert_eq!(post_of(&alone).map(|p| p.1), Some(false));
        // Ends that meet in two views but not the third are no vertex.
        let apart = lists_with(3.0);
        let params = MatchParams {
            include_uncertain: true,
            ..MatchParams::default()
        };
        let out = run(&rig, Input::lists(&apart), &Options::with(params))
            .unwrap()
            .output;
        assert_eq!(out.stats.joined_at_vertices, 0, "{:?}", out.stats);
        assert!(rail_of(&out).uncertain);
        // A reach far below a pixel is a valid option: it finds no vertex, and the index of
        // the ends stays within i64 (found by fuzzing: an overflow in the neighbouring cell).
        for tiny in [1e-300, f64::MIN_POSITIVE, 1e-17] {
            let out = run_with(tiny);
            assert_eq!(out.stats.joined_at_vertices, 0, "{tiny}");
            assert_eq!(rail_of(&out).uncertain, before.uncertain);
        }
    }

    #[test]
    fn dominant_directions_are_the_directions_most_lines_share() {
        // Forty lines near three axes (the second a tilted one), 0.5° apart at most, and
        // four lines along no axis.
        let axes = [
            nalgebra::Vector3::z(),
            nalgebra::Vector3::new(1.0, 0.2, 0.0).normalize(),
            nalgebra::Vector3::new(-0.2, 1.0, 0.0).normalize(),
        ];
        let mut lines = Vec::new();
        for (k, axis) in axes.iter().enumerate() {
            let (e1, e2) = crate::geometry::across_basis(axis);
            for i in 0..(20 - 5 * k) {
                let a = (i as f64 * 0.7).sin() * 0.5f64.to_radians();
                let b = (i as f64 * 1.3).cos() * 0.5f64.to_radians();
                let sense = if i % 2 == 0 { 1.0 } else { -1.0 };
                lines.push((
                    (axis + e1 * a + e2 * b).normalize() * sense,
                    0.3f64.to_radians().powi(2),
                ));
            }
        }
        for d in [
            [1.0, 1.0, 1.0],
            [1.0, -1.0, 0.5],
            [0.3, 1.0, -1.0],
            [-1.0, 0.4, 0.7],
        ] {
            lines.push((
                nalgebra::Vector3::from(d).normalize(),
                0.3f64.to_radians().powi(2),
            ));
        }
        let modes = dominant_directions(&lines);
        assert_eq!(modes.len(), 3, "{modes:?}");
        for (mode, (axis, members)) in modes.iter().zip(axes.iter().zip([20, 15, 10])) {
            assert_eq!(mode.members, members);
            assert!(
                mode.direction.dot(axis).abs().acos().to_degrees() < 0.2,
                "{mode:?}"
            );
            assert!(mode.variance.sqrt().to_degrees() < 0.5, "{mode:?}");
        }
        // Fewer than five lines along a direction make none.
        assert!(dominant_directions(&lines[..4]).is_empty());
        assert!(dominant_directions(&[]).is_empty());
        // A crowd of lines is searched among its best-measured MAX_MODE_LINES alone: 600
        // precise verticals and 5,000 looser horizontals give the vertical, from 512 lines.
        let crowd: Vec<(nalgebra::Vector3<f64>, f64)> = (0..600)
            .map(|_| (nalgebra::Vector3::z(), 0.2f64.to_radians().powi(2)))
            .chain((0..5000).map(|_| (nalgebra::Vector3::x(), 1.0f64.to_radians().powi(2))))
            .collect();
        let modes = dominant_directions(&crowd);
        assert_eq!(modes.len(), 1, "{modes:?}");
        assert_eq!(modes[0].members, MAX_MODE_LINES);
        assert!(modes[0].direction.z.abs() > 0.9999);
    }

    /// A vertical edge 2 m ahead of the preset rig, 40 cm tall, and its ghost: the same line
    /// on view 1's rays, 30% farther.
    fn an_edge_and_its_ghost(
        rig: &Rig,
    ) -> ([nalgebra::Point3<f64>; 2], [nalgebra::Point3<f64>; 2]) {
        let c1 = rig.camera(0).centre();
        let edge = [
            nalgebra::Point3::new(0.05, 2.0, -0.25),
            nalgebra::Point3::new(0.05, 2.0, 0.15),
        ];
        (edge, edge.map(|p| c1 + (p - c1) * 1.3))
    }

    /// `line` as view `view` of the preset rig sees it, moved `shift_px` along the image's x,
    /// with `sigma_px` of measured noise at each end, as the extractor gives it (`None`: a
    /// list's segment that says nothing of its noise).
    fn imaged(
        rig: &Rig,
        view: usize,
        line: &[nalgebra::Point3<f64>; 2],
        shift_px: f64,
        sigma_px: Option<f64>,
    ) -> Segment2 {
        let cam = rig.camera(view);
        let (a, b) = (
            cam.project(&line[0]).unwrap(),
            cam.project(&line[1]).unwrap(),
        );
        let shift = nalgebra::Vector2::new(shift_px, 0.0);
        Segment2 {
            gradient: Some(20.0),
            noise: sigma_px.map(|s| LineNoise::from_endpoint_sigma(s, (b - a).norm())),
            ..Segment2::new(a + shift, b + shift)
        }
    }

    /// The default answer to `lists`, or (`include_uncertain`) every match.
    fn matched(rig: &Rig, lists: &[SegmentList; 3], include_uncertain: bool) -> MatchOutput {
        let params = MatchParams {
            include_uncertain,
            ..MatchParams::default()
        };
        run(rig, Input::lists(lists), &Options::with(params))
            .unwrap()
            .output
    }

    fn oriented(segments: Vec<Segment2>) -> SegmentList {
        SegmentList {
            segments,
            oriented: true,
            background_gradient: None,
        }
    }

    /// Each 3D line imaged exactly by the preset rig as an oriented list segment, its ends
    /// good to the σ given with it (pixels): the same index in all three lists.
    fn lists_of_lines(rig: &Rig, lines: &[([nalgebra::Point3<f64>; 2], f64)]) -> [SegmentList; 3] {
        std::array::from_fn(|v| {
            oriented(
                lines
                    .iter()
                    .map(|(line, sigma_px)| imaged(rig, v, line, 0.0, Some(*sigma_px)))
                    .collect(),
            )
        })
    }

    /// Every match of `lists` (uncertain ones too), with or without the dominant directions.
    fn matched_with_directions(
        rig: &Rig,
        lists: &[SegmentList; 3],
        dominant_directions: bool,
    ) -> MatchOutput {
        let params = MatchParams {
            dominant_directions,
            include_uncertain: true,
            ..MatchParams::default()
        };
        run(rig, Input::lists(lists), &Options::with(params))
            .unwrap()
            .output
    }

    /// Every match of `lists` without the scene's dominant directions and with them, having
    /// checked what both tests of them hold: the first `certain` lines certain alone, line
    /// `doubted` uncertain alone, and with the directions certain and aligned, the only one.
    fn aligned_by_the_scene(
        rig: &Rig,
        lists: &[SegmentList; 3],
        certain: u32,
        doubted: u32,
    ) -> (MatchOutput, MatchOutput) {
        let of = reconstructed_from;
        let alone = matched_with_directions(rig, lists, false);
        for i in 0..certain {
            assert!(!of(&alone, i).uncertain, "line {i}: {:?}", of(&alone, i));
        }
        let before = of(&alone, doubted);
        assert!(before.uncertain, "{before:?}");
        let along = matched_with_directions(rig, lists, true);
        assert_eq!(
            along.stats.along_dominant_directions, 1,
            "{:?}",
            along.stats
        );
        let after = of(&along, doubted);
        assert!(!after.uncertain && after.aligned, "{after:?}");
        (alone, along)
    }

    /// Asserts that both ends of `segment` lie within 1 cm of `line`'s line; returns the
    /// segment's unit direction.
    fn ends_on_line(
        segment: &Reconstructed,
        line: &[nalgebra::Point3<f64>; 2],
    ) -> nalgebra::Vector3<f64> {
        let truth = (line[1] - line[0]).normalize();
        for p in [segment.segment.start, segment.segment.end] {
            let w = p - line[0];
            assert!((w - truth * w.dot(&truth)).norm() < 0.01, "{p}");
        }
        (segment.segment.end - segment.segment.start).normalize()
    }

    /// The 3D segment of the triplet that takes list segment `i` in every view.
    fn reconstructed_from(out: &MatchOutput, i: u32) -> Reconstructed {
        out.segments_3d
            .iter()
            .find(|s| out.triplets[s.triplet as usize].segments == [i, i, i])
            .cloned()
            .unwrap_or_else(|| panic!("segment {i} is matched: {:?}", out.stats))
    }

    #[test]
    fn a_short_upright_takes_the_direction_of_the_uprights_around_it() {
        let rig = preset_rig();
        let upright = |x: f64, y: f64, z0: f64, z1: f64| {
            [
                nalgebra::Point3::new(x, y, z0),
                nalgebra::Point3::new(x, y, z1),
            ]
        };
        // Five long posts, seen to 0.05 px at each end: certain, the scene's vertical.
        let posts = [
            upright(-0.62, 2.1, -0.5, 0.25),
            upright(-0.31, 2.6, -0.35, 0.3),
            upright(0.02, 2.3, -0.55, 0.05),
            upright(0.27, 2.9, -0.4, 0.35),
            upright(0.58, 2.2, -0.3, 0.2),
        ];
        // A short upright (12 cm, about 30 px) and a short slanted rail, seen to 0.15 px: too
        // short for their directions to meet the gate alone. And a shorter upright, 6 cm.
        let short = upright(-0.15, 2.35, -0.05, 0.07);
        let slanted = [
            nalgebra::Point3::new(0.4, 2.45, -0.2),
            nalgebra::Point3::new(0.47, 2.5, -0.11),
        ];
        let shorter = upright(0.13, 2.4, 0.2, 0.26);
        let mut lines: Vec<([nalgebra::Point3<f64>; 2], f64)> =
            posts.iter().map(|p| (*p, 0.05)).collect();
        lines.extend([(short, 0.15), (slanted, 0.15), (shorter, 0.15)]);
        let lists = lists_of_lines(&rig, &lines);
        let of = reconstructed_from;
        let (alone, along) = aligned_by_the_scene(&rig, &lists, 5, 5);
        assert_eq!(alone.stats.along_dominant_directions, 0);
        let (before, after) = (of(&alone, 5), of(&along, 5));
        assert!(!before.aligned);
        assert!(after.direction_sigma_deg < 0.5 * before.direction_sigma_deg);
        // Upright, and where the short upright is: its ends on its line.
        let u = ends_on_line(&after, &short);
        let truth = (short[1] - short[0]).normalize();
        assert!(u.dot(&truth).abs().acos().to_degrees() < 0.5, "{u}");
        // The slanted rail lies along no direction of the scene, and the 6-cm upright is too
        // short to be given one: both stay as they were.
        for i in [6, 7] {
            assert_eq!(of(&along, i), of(&alone, i), "segment {i}");
            assert!(of(&along, i).uncertain);
        }
        // The posts are untouched.
        for i in 0..5 {
            assert_eq!(of(&along, i), of(&alone, i));
        }
    }

    #[test]
    fn a_short_rail_turned_off_the_axes_takes_the_horizontal_of_the_uprights() {
        let rig = preset_rig();
        let line = |a: [f64; 3], b: [f64; 3]| {
            [
                nalgebra::Point3::new(a[0], a[1], a[2]),
                nalgebra::Point3::new(b[0], b[1], b[2]),
            ]
        };
        // A horizontal line of `length` at (x, y, z), turned by `azimuth` degrees from x.
        let rail = |x: f64, y: f64, z: f64, azimuth: f64, length: f64| {
            let (s, c) = azimuth.to_radians().sin_cos();
            let h = 0.5 * length;
            line([x - c * h, y - s * h, z], [x + c * h, y + s * h, z])
        };
        // Five long posts and three long rails, each turned its own way (no second
        // direction shared by five lines), seen to 0.05 px at each end: certain; the scene's
        // vertical, and its horizontal.
        let mut long = vec![
            line([-0.62, 2.1, -0.5], [-0.62, 2.1, 0.25]),
            line([-0.31, 2.6, -0.35], [-0.31, 2.6, 0.3]),
            line([0.02, 2.3, -0.55], [0.02, 2.3, 0.05]),
            line([0.27, 2.9, -0.4], [0.27, 2.9, 0.35]),
            line([0.58, 2.2, -0.3], [0.58, 2.2, 0.2]),
        ];
        long.push(rail(-0.2, 2.5, -0.45, 15.0, 0.6));
        long.push(rail(0.3, 2.6, 0.4, -25.0, 0.5));
        long.push(rail(0.0, 2.8, -0.3, 70.0, 0.35));
        // A short rail (14 cm, turned 35°) and a short slanted line, seen to 0.15 px: too
        // short for their directions to meet the gate alone.
        let short = rail(-0.3, 2.4, -0.25, 35.0, 0.14);
        let slanted = line([0.4, 2.45, -0.2], [0.47, 2.5, -0.11]);
        let mut lines: Vec<([nalgebra::Point3<f64>; 2], f64)> =
            long.iter().map(|l| (*l, 0.05)).collect();
        lines.extend([(short, 0.15), (slanted, 0.15)]);
        let lists = lists_of_lines(&rig, &lines);
        let of = reconstructed_from;
        let (n_long, short_index, slanted_index) = (long.len() as u32, 8, 9);
        let (alone, along) = aligned_by_the_scene(&rig, &lists, n_long, short_index);
        let (before, after) = (of(&alone, short_index), of(&along, short_index));
        // The plane fixes the tilt out of it; the turn within it, which the images measure,
        // is now the direction's largest uncertainty.
        assert!(after.direction_sigma_deg < before.direction_sigma_deg);
        // Horizontal, turned as the rail is, and where it is.
        let u = ends_on_line(&after, &short);
        let truth = (short[1] - short[0]).normalize();
        assert!(u.z.abs() < 0.5f64.to_radians().sin(), "{u}");
        assert!(u.dot(&truth).abs().acos().to_degrees() < 2.0, "{u}");
        // The slanted line lies in no plane of the scene's: it stays as it was, and so do
        // the long lines.
        assert_eq!(of(&along, slanted_index), of(&alone, slanted_index));
        assert!(of(&along, slanted_index).uncertain);
        for i in 0..n_long {
            assert_eq!(of(&along, i), of(&alone, i));
        }
    }

    #[test]
    fn the_extractors_graph_joins_validations_adjacency_in_prepared_indices() {
        let rig = preset_rig();
        let rect = Rectification::new(&rig).unwrap();
        let p = |u: f64, v: f64| rect.to_rect(0, Point2::new(u, v)).unwrap();
        // Prepared view 1: the caller's segments 0, 2 and 3 (1 was too short, say).
        let segments = [
            RectSegment::new(p(100.0, 100.0), p(100.0, 200.0), f64::NAN, 0),
            RectSegment::new(p(300.0, 100.0), p(300.0, 200.0), f64::NAN, 2),
            RectSegment::new(p(100.0, 200.0), p(200.0, 200.0), f64::NAN, 3),
        ];
        let mut adjacency = vec![(0, 2, p(100.0, 200.0))];
        let graph = [
            Adjacent {
                a: 0,
                b: 3,
                vertex: Point2::new(100.0, 200.0),
            }, // already known
            Adjacent {
                a: 0,
                b: 2,
                vertex: Point2::new(200.0, 150.0),
            }, // new: far ends meet
            Adjacent {
                a: 1,
                b: 2,
                vertex: Point2::new(300.0, 100.0),
            }, // 1 was dropped
        ];
        add_graph(&mut adjacency, &graph, &rig, &rect, &segments);
        assert_eq!(adjacency.len(), 2);
        let (a, b, vertex) = adjacency[1];
        assert_eq!((a, b), (0, 1));
        assert!((vertex - p(200.0, 150.0)).norm() < 1e-9);
    }

    #[test]
    fn the_gate_asks_the_disc_probability_exactly() {
        // A round error: P(r) = 1 − exp(−r²/2σ²), so the 95% radius is 2.448σ.
        for r in [0.5f64, 1.0, 2.0, 3.0] {
            let exact = 1.0 - (-0.5 * r * r).exp();
            assert!(
                (within_radius_probability(1.0, 1.0, r) - exact).abs() < 1e-5,
                "{r}"
            );
        }
        assert!(within_radius((1.0, 1.0), 2.45, 0.95));
        assert!(!within_radius((1.0, 1.0), 2.40, 0.95));
        // A line-like error: the minor axis adds almost nothing, so 1.96σ of the major axis
        // holds 95%, where the round bound would have asked for 2.448σ.
        let p = within_radius_probability(1.0, 1e-6, 1.96);
        assert!((p - 0.95).abs() < 1e-3, "{p}");
        assert!(within_radius((1.0, 1e-6), 2.0, 0.95));
        assert!(!within_radius((1.0, 1e-6), 1.9, 0.95));
        // In between, the probability lies between the two and falls as the minor axis grows.
        let probabilities: Vec<f64> = [0.01, 0.1, 0.5, 1.0]
            .iter()
            .map(|&minor| within_radius_probability(1.0, minor, 2.2))
            .collect();
        assert!(
            probabilities.windows(2).all(|w| w[1] < w[0]),
            "{probabilities:?}"
        );
    }

    #[test]
    fn the_gates_shortcuts_decide_as_the_integral_does() {
        // The round bound, the major axis alone and the inscribed rectangle settle most cases
        // before the integral: each must agree with it wherever it is not within its precision.
        let mut checked = 0;
        for major in [0.01f64, 0.3, 1.0, 4.0] {
            for ratio in [0.0, 1e-4, 0.01, 0.1, 0.3, 0.6, 1.0] {
                let minor = major * ratio;
                for step in 1..60 {
                    let radius = major.sqrt() * step as f64 * 0.06;
                    for confidence in [0.9, 0.95, 0.99] {
                        let p = within_radius_probability(major, minor, radius);
                        if (p - confidence).abs() < 1e-5 {
                            continue;
                        }
                        assert_eq!(
                            within_radius((major, minor), radius, confidence),
                            p >= confidence,
                            "major {major} minor {minor} radius {radius} p {p} confidence {confidence}"
                        );
                        checked += 1;
                    }
                }
            }
        }
        assert!(checked > 4000, "{checked}");
    }
}
