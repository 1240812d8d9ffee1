//! Segments from images (DESIGN §2.1, the paper's preprocessing): edge points, chains of
//! connected edge points, and their polygonal approximation into line segments oriented by
//! contrast, with the graph of segments that share a chain vertex or a junction.
//!
//! ```text
//! GreyImage ─▶ smooth ─▶ gradient ─▶ non-maximum suppression (sub-pixel) ─▶ hysteresis
//!           ─▶ link into chains (+ junctions) ─▶ undistort points ─▶ split-and-merge ─▶ ends
//!           ─▶ segments + graph
//! ```
//!
//! Each stage is a plain function over plain data ([`gradient`], [`edges`], [`chain`],
//! [`polygon`]) and can be tested alone; [`extract`] runs them all. Pure and synchronous, one
//! image per call: the pipeline runs the three images of a triplet in parallel.
//!
//! Output segments are in the image's own (distorted) pixels, like any segment list a client
//! sends, but their lines were fitted to undistorted edge points: undistorting the two ends
//! (as the matcher does) gives back exactly the fitted line.

pub mod chain;
pub mod decode;
pub mod edges;
pub mod ends;
pub mod gradient;
pub mod image;
pub mod join;
pub mod polygon;
pub mod scale;

use std::time::Instant;

use nalgebra::Point2;

use crate::checkpoint::{never_stopped, Checkpoint, Stopped};
use crate::geometry::Camera;
use crate::params::{check_all, Rule};
use crate::segment::{CrowdingModel, LineNoise, Segment2, SegmentList};

pub use self::image::GreyImage;
pub use decode::{check_size, decode, decode_sized, from_raw, DecodeError, DecodeLimits};

/// Extraction parameters. Units are in the names; `Default` gives the documented defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct Params {
    /// Standard deviation of the Gaussian smoothing, pixels; `None` chooses it for each
    /// image from its own noise and texture ([`scale::choose`]).
    pub smoothing_sigma_px: Option<f64>,
    /// Hysteresis thresholds on the gradient magnitude, grey levels (0–255 scale) per pixel:
    /// edges start at `gradient_high` and continue down to `gradient_low`.
    pub gradient_low: f64,
    pub gradient_high: f64,
    /// Largest distance of an edge point from its segment's line, pixels.
    pub max_deviation_px: f64,
    /// Shorter segments are not reported, pixels.
    pub min_segment_px: f64,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            smoothing_sigma_px: None,
            gradient_low: 2.0,
            gradient_high: 5.0,
            max_deviation_px: 0.8,
            min_segment_px: 6.0,
        }
    }
}

/// A parameter out of its domain; `field` is the schema's `ExtractOptions` field name.
pub use crate::params::{ParamError, ParamErrors};

/// Largest smoothing accepted, pixels: beyond it edges of a room-scale image melt together,
/// and the kernel cost grows with σ.
pub const MAX_SMOOTHING_SIGMA_PX: f64 = 10.0;

impl Params {
    /// Checks every field; reports every problem.
    pub fn check(&self) -> Result<(), ParamErrors> {
        let sigma = self.smoothing_sigma_px.unwrap_or(0.0);
        check_all([
            Rule::new(
                "smoothing_sigma_px",
                sigma,
                (0.0..=MAX_SMOOTHING_SIGMA_PX).contains(&sigma),
                "between 0 and 10",
            ),
            Rule::new(
                "gradient_low",
                self.gradient_low,
                self.gradient_low >= 0.0 && self.gradient_low.is_finite(),
                "a finite number at least 0",
            ),
            Rule::new(
                "gradient_high",
                self.gradient_high,
                self.gradient_high >= self.gradient_low && self.gradient_high.is_finite(),
                "a finite number at least gradient_low",
            ),
            Rule::new(
                "max_deviation_px",
                self.max_deviation_px,
                self.max_deviation_px > 0.0 && self.max_deviation_px.is_finite(),
                "a finite number greater than 0",
            ),
            Rule::new(
                "min_segment_px",
                self.min_segment_px,
                self.min_segment_px >= 0.0 && self.min_segment_px.is_finite(),
                "a finite number at least 0",
            ),
        ])
    }
}

/// Two segments that meet: at a vertex of one chain's polygon, or where one chain ends on
/// another (a junction). `vertex` is where, in image pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Adjacent {
    pub a: u32,
    pub b: u32,
    pub vertex: Point2<f64>,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct ExtractStats {
    /// The smoothing used: the one asked for, or the one chosen for this image.
    pub smoothing_sigma_px: f64,
    pub edge_points: u32,
    pub chains: u32,
    pub junctions: u32,
    /// Gaussian smoothing.
    pub smooth_ms: f64,
    /// Gradient, non-maximum suppression, hysteresis.
    pub edges_ms: f64,
    pub chain_ms: f64,
    pub polygon_ms: f64,
    pub total_ms: f64,
}

/// The segments of one image and how they connect.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Extraction {
    /// Oriented by contrast (DESIGN §1), with their mean gradient magnitude.
    pub segments: SegmentList,
    /// Each pair once, `a < b`, sorted.
    pub graph: Vec<Adjacent>,
    pub stats: ExtractStats,
}

/// The part of segment `a`–`b` inside the image frame `[-0.5, size - 0.5]²` (Liang–Barsky);
/// `None` when nothing of it is inside.
fn clip_to_frame(
    a: Point2<f64>,
    b: Point2<f64>,
    width: u32,
    height: u32,
) -> Option<(Point2<f64>, Point2<f64>)> {
    let d = b - a;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    let bounds = [
        (-d.x, a.x + 0.5),
        (d.x, f64::from(width) - 0.5 - a.x),
        (-d.y, a.y + 0.5),
        (d.y, f64::from(height) - 0.5 - a.y),
    ];
    for (p, q) in bounds {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    (t0 < t1).then(|| (a + d * t0, a + d * t1))
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

/// Points left out of a piece's line fit at each break: the smoothed corner is rounded over
/// about σ. (Measured on the rendered office: 1 point at σ = 1 gives 21.4% strict errors, 0
/// points 28.8%, 2 points 23.0%, 3 points 26.0%: short segments need every point they have.)
fn corner_trim(smoothing_sigma_px: f64) -> usize {
    smoothing_sigma_px.round() as usize
}

/// Where to start a closed chain: the point farthest from its centroid, a corner of any
/// convex outline. Returns its position in `chain`.
fn loop_corner(chain: &[u32], map: &edges::EdgeMap) -> usize {
    let n = chain.len() as f32;
    let (cu, cv) = chain.iter().fold((0.0, 0.0), |(su, sv), &i| {
        let p = &map.points[i as usize];
        (su + p.u / n, sv + p.v / n)
    });
    let distance = |i: usize| {
        let p = &map.points[chain[i] as usize];
        (p.u - cu).powi(2) + (p.v - cv).powi(2)
    };
    (0..chain.len())
        .max_by(|&a, &b| distance(a).total_cmp(&distance(b)))
        .unwrap_or(0)
}

/// How far apart two pieces of one edge may lie to be joined into one segment
/// ([`join`]): the gap a junction leaves, and the offset of any piece's end from the joined
/// line. Measured on the rendered office and lab (docs/ACCURACY.md): gaps of 1, 2, 3, 4 and 8
/// px gave completeness +0.2/+1.3, +0.6/+1.4, −0.6/+0.8, −0.6/+1.6 and −2.4/0.0 points;
/// wider gaps join pieces of different edges that one view happens to line up.
const JOIN_LIMITS: join::Limits = join::Limits {
    max_gap_px: 2.0,
    max_offset_px: 0.5,
};

/// A piece kept from a chain, in undistorted pixels, before pieces of one line are joined.
struct Pending {
    part: join::Part,
    fit: polygon::FitSpread,
    /// How far the piece's midpoint lies from its fitted points' centroid, along it.
    centre_offset: f64,
    /// Gradient magnitude summed over the piece's chain points, and how many they are.
    magnitude_sum: f64,
    points: usize,
}

/// What a segment's noise is measured from ([`measure_noise`]): the spread of the points its
/// line was fitted to, and how far its midpoint lies from their centroid, along it.
#[derive(Debug, Clone, Copy)]
struct LineFit {
    spread: polygon::FitSpread,
    centre_offset: f64,
}

/// The segments of an image after joining, with per segment its line fit, and per pending
/// piece the segment it became (`None`: clipped away).
struct Placed {
    segments: Vec<Segment2>,
    fits: Vec<LineFit>,
    renumber: Vec<Option<u32>>,
}

/// A piece's place in its chain: its first and last points' positions in the chain's own
/// order, and the pending piece it became.
#[derive(Debug, Clone, Copy)]
struct ChainPiece {
    first: usize,
    last: usize,
    id: u32,
}

/// Every chain cut into straight pieces: the pieces kept (long enough), the vertices where
/// consecutive pieces of a chain meet (as [`Adjacent`] over pending pieces), and per chain
/// where its pieces lie in it (for the junctions).
struct ChainPieces {
    pending: Vec<Pending>,
    meetings: Vec<Adjacent>,
    per_chain: Vec<Vec<ChainPiece>>,
}

/// The polygonal approximation of each chain (in undistorted pixels), each piece's free ends
/// refined on the smoothed image, oriented by its mean gradient (bright side on the left)
/// and summarised for joining and for its noise. On a pool of more than one thread, blocks
/// of [`CHAINS_PER_CHECK`] chains are fitted at once, each asking `checkpoint` first, and put
/// together in chain order with their pieces renumbered: the same pieces, in the same order,
/// as the one pass over the chains a single thread (or an image of more chains than
/// [`PIXELS_PER_PARALLEL_CHAIN`] allows) makes.
fn fit_pieces(
    chains: &chain::Chains,
    on: &FitOn,
    checkpoint: Checkpoint,
) -> Result<ChainPieces, Stopped> {
    use rayon::prelude::*;
    let pixels = on.map.width * on.map.height;
    if rayon::current_num_threads() <= 1 || chains.chains.len() > pixels / PIXELS_PER_PARALLEL_CHAIN
    {
        return fit_block(&chains.chains, on, checkpoint);
    }
    let blocks: Vec<ChainPieces> = chains
        .chains
        .par_chunks(CHAINS_PER_CHECK)
        .map(|block| fit_block(block, on, checkpoint))
        .collect::<Result<_, Stopped>>()?;
    let mut all = ChainPieces {
        pending: Vec::with_capacity(blocks.iter().map(|b| b.pending.len()).sum()),
        meetings: Vec::new(),
        per_chain: Vec::with_capacity(chains.chains.len()),
    };
    for block in blocks {
        let offset = all.pending.len() as u32;
        all.pending.extend(block.pending);
        all.meetings
            .extend(block.meetings.into_iter().map(|m| Adjacent {
                a: m.a + offset,
                b: m.b + offset,
                ..m
            }));
        all.per_chain
            .extend(block.per_chain.into_iter().map(|pieces| {
                pieces
                    .into_iter()
                    .map(|p| ChainPiece {
                        id: p.id + offset,
                        ..p
                    })
                    .collect()
            }));
    }
    Ok(all)
}

/// What the chains are fitted on: the edge points they index, the smoothed image their ends
/// are refined on, the lens undone, the points trimmed at a corner, the parameters.
struct FitOn<'a> {
    map: &'a edges::EdgeMap,
    smoothed: ends::Smoothed<'a>,
    camera: Option<&'a Camera>,
    trim: usize,
    params: &'a Params,
}

/// [`fit_pieces`] of one block of chains, its pieces numbered from 0; asks `checkpoint`
/// every [`CHAINS_PER_CHECK`] chains.
fn fit_block(
    block: &[chain::Chain],
    on: &FitOn,
    checkpoint: Checkpoint,
) -> Result<ChainPieces, Stopped> {
    let FitOn {
        map,
        ref smoothed,
        camera,
        trim,
        params,
    } = *on;
    let undistort = |u: f32, v: f32| {
        let p = Point2::new(f64::from(u), f64::from(v));
        camera.map_or(p, |c| c.undistort(p))
    };
    let distort = |p: Point2<f64>| camera.map_or(p, |c| c.distort(p));
    let mut pending: Vec<Pending> = Vec::new();
    let mut meetings = Vec::new();
    let mut per_chain: Vec<Vec<ChainPiece>> = Vec::with_capacity(block.len());
    // A chain's point numbers and positions, in buffers the block's chains share.
    let (mut ids, mut points): (Vec<u32>, Vec<Point2<f64>>) = (Vec::new(), Vec::new());
    for (n, c) in block.iter().enumerate() {
        if n % CHAINS_PER_CHECK == 0 {
            checkpoint.before("extract")?;
        }
        // Start a loop at a corner, so no side is cut in two at an arbitrary start.
        let rotation = if c.closed {
            loop_corner(&c.points, map)
        } else {
            0
        };
        ids.clear();
        ids.extend_from_slice(&c.points);
        ids.rotate_left(rotation);
        points.clear();
        points.extend(ids.iter().map(|&i| {
            let p = &map.points[i as usize];
            undistort(p.u, p.v)
        }));
        let mut mine = Vec::new();
        let pieces = polygon::approximate(&points, c.closed, params.max_deviation_px, trim);
        // An end is free unless it is a vertex shared with a neighbouring piece kept.
        let long =
            |k: usize| (pieces[k].end - pieces[k].start).norm() >= params.min_segment_px.max(1e-9);
        let count = pieces.len();
        for (k, piece) in pieces.iter().enumerate() {
            if !long(k) {
                continue;
            }
            // A corner shared with a kept neighbour stays; any other end is free to slide.
            let shares_start = piece.joined.0
                && if c.closed {
                    long((k + count - 1) % count)
                } else {
                    k > 0 && long(k - 1)
                };
            let shares_end = piece.joined.1
                && if c.closed {
                    long((k + 1) % count)
                } else {
                    k + 1 < count && long(k + 1)
                };
            let (start, end) = ends::refine_ends(
                smoothed,
                distort,
                piece.start,
                piece.end,
                (!shares_start, !shares_end),
            );
            let piece = polygon::Piece {
                start,
                end,
                ..*piece
            };
            let last = if piece.last < piece.first {
                ids.len() - 1
            } else {
                piece.last
            };
            let (mut gu, mut gv, mut magnitude) = (0.0f64, 0.0f64, 0.0f64);
            for &i in &ids[piece.first..=last] {
                let p = &map.points[i as usize];
                gu += f64::from(p.gu);
                gv += f64::from(p.gv);
                magnitude += f64::from(p.magnitude);
            }
            let (mut a, mut b) = (piece.start, piece.end);
            // Chains walk with the bright side on the left; check against the mean gradient
            // in case a piece straddles a weak flip.
            let d = b - a;
            if gu * d.y - gv * d.x < 0.0 {
                std::mem::swap(&mut a, &mut b);
            }
            let id = pending.len() as u32;
            let mid = nalgebra::center(&piece.start, &piece.end);
            pending.push(Pending {
                part: join::Part {
                    start: a,
                    end: b,
                    moments: piece.moments,
                },
                fit: piece.fit,
                centre_offset: (mid - piece.line.centroid).dot(&piece.line.direction),
                magnitude_sum: magnitude,
                points: last - piece.first + 1,
            });
            // Positions in the chain's own order (undo the loop's rotation).
            let to_chain = |k: usize| (k + rotation) % ids.len();
            mine.push(ChainPiece {
                first: to_chain(piece.first),
                last: to_chain(last),
                id,
            });
            if let Some(previous) = mine.iter().rev().nth(1) {
                meetings.push(Adjacent {
                    a: previous.id,
                    b: id,
                    vertex: distort(piece.start),
                });
            }
        }
        if c.closed && mine.len() > 2 {
            let (first, last) = (mine[0].id, mine[mine.len() - 1].id);
            meetings.push(Adjacent {
                a: first,
                b: last,
                vertex: distort(pending[first as usize].part.start),
            });
        }
        per_chain.push(mine);
    }
    Ok(ChainPieces {
        pending,
        meetings,
        per_chain,
    })
}

/// Where a chain ends on another chain (a T-junction), the piece at that end meets the
/// other chain's piece that holds the junction point.
fn junction_meetings(
    chains: &chain::Chains,
    map: &edges::EdgeMap,
    per_chain: &[Vec<ChainPiece>],
) -> Vec<Adjacent> {
    let mut meetings = Vec::new();
    for j in &chains.junctions {
        let pieces = &per_chain[j.chain as usize];
        let end_piece = if j.at_start {
            pieces.first()
        } else {
            pieces.last()
        };
        let Some(&ChainPiece { id: a, .. }) = end_piece else {
            continue;
        };
        let at = j.other_position as usize;
        let Some(&ChainPiece { id: b, .. }) = per_chain[j.other as usize].iter().find(|piece| {
            let (first, last) = (piece.first, piece.last);
            if first <= last {
                (first..=last).contains(&at)
            } else {
                at >= first || at <= last // a loop's piece across its start
            }
        }) else {
            continue;
        };
        let other = &chains.chains[j.other as usize];
        let p = &map.points[other.points[at] as usize];
        meetings.push(Adjacent {
            a,
            b,
            vertex: Point2::new(f64::from(p.u), f64::from(p.v)),
        });
    }
    meetings
}

/// The adjacency of the final segments: each meeting of two pending pieces carried to the
/// segments they became (dropped where one was clipped away or both joined into one),
/// ordered and without repeats.
fn renumbered(meetings: Vec<Adjacent>, renumber: &[Option<u32>]) -> Vec<Adjacent> {
    let mut graph: Vec<Adjacent> = meetings
        .into_iter()
        .filter_map(|m| Some((renumber[m.a as usize]?, renumber[m.b as usize]?, m.vertex)))
        .filter(|(a, b, _)| a != b)
        .map(|(a, b, vertex)| Adjacent {
            a: a.min(b),
            b: a.max(b),
            vertex,
        })
        .collect();
    graph.sort_by_key(|e| (e.a, e.b));
    graph.dedup_by_key(|e| (e.a, e.b));
    graph
}

/// Joins the pieces of one line ([`join`]), then places each segment in the image: its ends
/// distorted back and clipped to the frame, too short ones dropped.
fn join_and_place(
    pending: &[Pending],
    params: &Params,
    distort: impl Fn(Point2<f64>) -> Point2<f64>,
    width: u32,
    height: u32,
) -> Placed {
    let parts: Vec<join::Part> = pending.iter().map(|p| p.part).collect();
    let mut renumber = vec![None; pending.len()];
    let mut segments = Vec::with_capacity(pending.len());
    let mut fits = Vec::with_capacity(pending.len());
    for group in join::join(&parts, JOIN_LIMITS) {
        let members = &group.members;
        let (start, end) = group.ends(&parts);
        let fit = match &group.fit {
            Some(joined) => {
                let spread = polygon::FitSpread {
                    points: members
                        .iter()
                        .map(|&k| pending[k as usize].fit.points)
                        .sum(),
                    rms_px: joined.across_px2.sqrt(),
                    // The length of evenly spread points with the same second moment: what
                    // sets the direction's precision.
                    span_px: (12.0 * joined.along_px2).sqrt(),
                };
                let mid = nalgebra::center(&start, &end);
                LineFit {
                    spread,
                    centre_offset: (mid - joined.line.centroid).dot(&joined.line.direction),
                }
            }
            None => {
                let p = &pending[members[0] as usize];
                LineFit {
                    spread: p.fit,
                    centre_offset: p.centre_offset,
                }
            }
        };
        let Some((a, b)) = clip_to_frame(distort(start), distort(end), width, height) else {
            continue;
        };
        if (b - a).norm() < params.min_segment_px {
            continue;
        }
        let (magnitude, count) = members.iter().fold((0.0, 0usize), |(m, c), &k| {
            let p = &pending[k as usize];
            (m + p.magnitude_sum, c + p.points)
        });
        let id = segments.len() as u32;
        for &k in members {
            renumber[k as usize] = Some(id);
        }
        segments.push(Segment2 {
            start: a,
            end: b,
            gradient: Some(magnitude / count.max(1) as f64),
            noise: None,
        });
        fits.push(fit);
    }
    Placed {
        segments,
        fits,
        renumber,
    }
}

/// Edge points closer than this along a chain share their noise (the smoothing and the
/// gradient stencil span a few pixels at σ = 1): the fit has one independent point per this
/// many pixels of chain. With the two constants below, measured on the rendered office and
/// lab against the projected ground truth (`tools/line_noise_study.py`; docs/ACCURACY.md).
const EDGE_POINT_CORRELATION: f64 = 3.0;
/// The spread of the fitted points about their line understates the line's true error by
/// this factor (the points were smoothed together before they were located).
const SPREAD_SCALE: f64 = 1.3;
/// Weight, in fitted points, of the image's typical edge-point spread when a segment's own
/// spread is measured on few points.
const PRIOR_POINTS: f64 = 8.0;
/// Systematic error of an extracted line that no number of points averages away (aliasing,
/// blur shared with a nearby edge, the rounding of corners): added to the offset, pixels, and
/// to the direction, as pixels over the length. The offset's floor is the smallest that makes
/// the 3D position's covariance hold 95% of the true errors within its 95% quantile in both
/// rendered rooms (0.08 px: 91.9% / 92.6%; 0.10: 95.1% / 93.4%; 0.12: 95.4% / 94.5%; long
/// segments, whose σ is mostly this floor, were the ones outside; docs/ACCURACY.md).
const SYSTEMATIC_OFFSET_PX: f64 = 0.10;
const SYSTEMATIC_ANGLE_PX: f64 = 0.1;
/// σ of a shift of an extracted line, independent from view to view, that its measured
/// noise leaves out ([`LineNoise::shift_px`]), pixels. Where one view alone fixes a line's
/// depth (a line along a baseline), that view's systematic error is the 3D position's: the
/// least of those measured that brings the lab's 3D positions within χ²'s 99% quantile for
/// 98% of them (0: 97.7%; 0.03: 98.1%; 0.05: 98.4%; 0.1: 98.9% — the office's 99.3–99.9%
/// throughout), at 0.8 point of the lab's completeness and none of the office's
/// (docs/ACCURACY.md, "Each extracted line's own shift").
pub const EXTRACTED_SHIFT_PX: f64 = 0.05;

/// Sets each segment's [`LineNoise`] from its own edge points: their spread about the line,
/// pooled with the image's typical spread at that contrast when they are few (the spread of
/// an edge point is inversely proportional to the gradient across it).
fn measure_noise(segments: &mut [Segment2], fits: &[LineFit]) {
    // The image's edge-point spread times gradient, over the segments with enough points.
    let mut scaled: Vec<f64> = segments
        .iter()
        .zip(fits)
        .filter(|(_, fit)| fit.spread.points >= 20)
        .filter_map(|(s, fit)| Some(fit.spread.rms_px * s.gradient?))
        .collect();
    scaled.sort_by(f64::total_cmp);
    let typical = scaled.get(scaled.len() / 2).copied();
    for (
        segment,
        &LineFit {
            spread: fit,
            centre_offset,
        },
    ) in segments.iter_mut().zip(fits)
    {
        let dof = fit.points.saturating_sub(2) as f64;
        let own = if dof > 0.0 {
            fit.rms_px.powi(2) * fit.points as f64 / dof
        } else {
            0.0
        };
        let prior = match (typical, segment.gradient) {
            (Some(t), Some(g)) if g > 0.0 => (t / g).powi(2),
            _ => own,
        };
        let variance =
            (dof * own + PRIOR_POINTS * prior) / (dof + PRIOR_POINTS) * SPREAD_SCALE * SPREAD_SCALE;
        let independent = (fit.span_px.max(1.0) / EDGE_POINT_CORRELATION)
            .min(fit.points as f64)
            .max(2.0);
        let fitted = LineNoise::from_point_fit(variance.sqrt(), independent, fit.span_px.max(1.0));
        let length = segment.length().max(1.0);
        let offset = fitted.offset_px.hypot(centre_offset * fitted.angle_rad);
        segment.noise = Some(LineNoise {
            offset_px: offset.hypot(SYSTEMATIC_OFFSET_PX),
            angle_rad: fitted.angle_rad.hypot(SYSTEMATIC_ANGLE_PX / length),
            shift_px: EXTRACTED_SHIFT_PX,
        });
    }
}

/// Widens each segment's noise by the pull of its nearest parallel neighbour
/// ([`LineNoise::crowded`]).
fn add_crowding(segments: &mut [Segment2], model: CrowdingModel) {
    let distances = crate::segment::crowding(segments, model);
    for (segment, distance) in segments.iter_mut().zip(distances) {
        let length = segment.length();
        segment.noise = segment.noise.map(|n| n.crowded(distance, length, model));
    }
}

/// Extracts the oriented segments of `image` and their graph. `camera` (if given) supplies
/// the lens distortion removed from edge points before the polygon fit. Parameters must
/// have passed [`Params::check`].
pub fn extract(image: &GreyImage, camera: Option<&Camera>, params: &Params) -> Extraction {
    never_stopped(extract_until(image, camera, params, Checkpoint::NEVER))
}

/// Chains fitted between two questions to the checkpoint, and by one task of the pool.
const CHAINS_PER_CHECK: usize = 256;
/// The blocks' pieces are copied once when they are put together: an image with more than
/// one chain per this many pixels is fitted in one pass, so that the copy stays near a byte a
/// pixel and the service's reservation per pixel (`service::memory`) holds. (Measured: 2000²
/// pixels of noise extracted unsmoothed peaked at 178 MB fitted in blocks, 163 MB in one pass
/// or with this bound; a photograph has a chain per 150 pixels, `herzjesu_p25`.)
const PIXELS_PER_PARALLEL_CHAIN: usize = 64;

/// [`extract`], asking `checkpoint` between its stages and as it fits the chains.
pub fn extract_until(
    image: &GreyImage,
    camera: Option<&Camera>,
    params: &Params,
    checkpoint: Checkpoint,
) -> Result<Extraction, Stopped> {
    let start = Instant::now();
    let mut stats = ExtractStats::default();
    let (w, h) = (image.width() as usize, image.height() as usize);

    let t = Instant::now();
    let smoothing = params
        .smoothing_sigma_px
        .unwrap_or_else(|| scale::choose(image, params.gradient_high).smoothing_sigma_px);
    stats.smoothing_sigma_px = smoothing;
    let smoothed = gradient::smoothed(image, smoothing);
    stats.smooth_ms = ms(t);

    checkpoint.before("extract")?;
    let t = Instant::now();
    let (candidates, background) =
        edges::edge_points_and_background(&smoothed, w, h, params.gradient_low as f32);
    checkpoint.before("extract")?;
    let map = edges::hysteresis(candidates, params.gradient_high as f32);
    stats.edges_ms = ms(t);
    stats.edge_points = map.points.len() as u32;

    checkpoint.before("extract")?;
    let t = Instant::now();
    let chains = chain::link(&map);
    stats.chain_ms = ms(t);
    stats.chains = chains.chains.len() as u32;
    stats.junctions = chains.junctions.len() as u32;

    let t = Instant::now();
    let distort = |p: Point2<f64>| camera.map_or(p, |c| c.distort(p));
    let ChainPieces {
        pending,
        mut meetings,
        per_chain,
    } = fit_pieces(
        &chains,
        &FitOn {
            map: &map,
            smoothed: ends::Smoothed {
                pixels: &smoothed,
                width: w,
                height: h,
            },
            camera,
            trim: corner_trim(smoothing),
            params,
        },
        checkpoint,
    )?;
    meetings.extend(junction_meetings(&chains, &map, &per_chain));
    checkpoint.before("extract")?;
    let Placed {
        mut segments,
        fits,
        renumber,
    } = join_and_place(&pending, params, distort, image.width(), image.height());
    let graph = renumbered(meetings, &renumber);
    measure_noise(&mut segments, &fits);
    add_crowding(&mut segments, CrowdingModel::for_smoothing(smoothing));
    stats.polygon_ms = ms(t);
    stats.total_ms = ms(start);
    Ok(Extraction {
        segments: SegmentList {
            segments,
            oriented: true,
            background_gradient: Some(f64::from(background)),
        },
        graph,
        stats,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]

        /// Any image, however small, flat, noisy or extreme, gives segments, never a panic; and
        /// every segment is finite, inside the image's frame and at least the minimum length.
        #[test]
        fn any_image_gives_sane_segments(
            width in 1u32..40,
            height in 1u32..40,
            seed in any::<u64>(),
            style in 0u8..4,
            sigma in proptest::option::of(0.0f64..3.0),
        ) {
            let mut state = seed | 1;
            let mut next = || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                state
            };
            let n = (width * height) as usize;
            let pixels: Vec<f32> = (0..n)
                .map(|i| match style {
                    0 => (next() % 256) as f32,                                  // noise
                    1 => if (i % width as usize) < width as usize / 2 { 0.0 } else { 255.0 }, // a step
                    2 => 77.0,                                                   // flat
                    _ => if next() % 7 == 0 { 255.0 } else { 0.0 },              // speckle
                })
                .collect();
            let image = GreyImage::new(width, height, pixels).unwrap();
            let params = Params { smoothing_sigma_px: sigma, ..Params::default() };
            let out = extract(&image, None, &params);
            for s in &out.segments.segments {
                for p in [s.start, s.end] {
                    prop_assert!(p.x.is_finite() && p.y.is_finite());
                    prop_assert!(p.x >= -0.5 - 1e-9 && p.x <= f64::from(width) - 0.5 + 1e-9, "{p:?}");
                    prop_assert!(p.y >= -0.5 - 1e-9 && p.y <= f64::from(height) - 0.5 + 1e-9, "{p:?}");
                }
                prop_assert!(s.length() >= params.min_segment_px - 1e-9);
                prop_assert!(s.gradient.is_some_and(|g| g.is_finite() && g >= 0.0));
            }
            for e in &out.graph {
                prop_assert!(e.a < e.b && (e.b as usize) < out.segments.segments.len());
            }
        }
    }

    #[test]
    fn params_are_checked_field_by_field() {
        assert!(Params::default().check().is_ok());
        let bad = [
            (
                Params {
                    smoothing_sigma_px: Some(-1.0),
                    ..Params::default()
                },
                "smoothing_sigma_px",
            ),
            (
                Params {
                    smoothing_sigma_px: Some(f64::NAN),
                    ..Params::default()
                },
                "smoothing_sigma_px",
            ),
            (
                Params {
                    gradient_low: -0.5,
                    ..Params::default()
                },
                "gradient_low",
            ),
            (
                Params {
                    gradient_high: 1.0,
                    ..Params::default()
                },
                "gradient_high",
            ),
            (
                Params {
                    max_deviation_px: 0.0,
                    ..Params::default()
                },
                "max_deviation_px",
            ),
            (
                Params {
                    min_segment_px: f64::INFINITY,
                    ..Params::default()
                },
                "min_segment_px",
            ),
        ];
        for (params, field) in bad {
            assert_eq!(params.check().unwrap_err().field(), field);
        }
    }
}
