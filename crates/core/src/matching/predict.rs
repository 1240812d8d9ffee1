//! Hypothesis prediction and verification (DESIGN §2.4, the paper's "prediction").
//!
//! For each segment S1 of view 1:
//! 1. choose the pair (1, j), j ∈ {2, 3}, whose epipolar direction makes the largest angle
//!    with S1 — a segment nearly parallel to the 1-2 epipolar lines is searched in view 3 and
//!    verified in view 2 (the trinocular advantage);
//! 2. candidates Sj share epipolar lines with S1 (their extents across the epipolar direction
//!    overlap — a generalisation of "cross the epipolar line through S1's midpoint" that also
//!    finds fragments) within the disparity interval of the depth range, with compatible
//!    orientation, contrast sign and gradient magnitude;
//! 3. the disparities at the two ends of the common part give, by transfer, the predicted
//!    segment in the third view k — its position, orientation and extent;
//! 4. a segment Sk of compatible orientation must lie within `tolerance_px` of that prediction
//!    over their common part. Every surviving (S1, S2, S3) is a hypothesis, with the largest
//!    of those two distances as its residual;
//! 5. where the prediction in the verifying view runs along its own disparity direction (S1
//!    along that pair's baseline), the verification cannot check the depth: such a hypothesis
//!    is kept only if its three gradients, divided by their views' gains, agree closely
//!    ([`super::gain`]), since a ghost has nothing else against it.
//!
//! Every count is bounded, so that no list — however repetitive: a thousand copies of one
//! line give a thousand cubed triplets — makes the work or the memory grow past a fixed
//! multiple of its length: at most [`MAX_CANDIDATES_PER_SEGMENT`] pairs per S1, at most
//! [`MAX_VERIFIED_PER_PAIR`] verified triplets per pair, the best
//! [`MAX_HYPOTHESES_PER_SEGMENT`] hypotheses per S1, and [`MAX_HYPOTHESES`] in all (past it,
//! an error). Real scenes stay far below each (the rendered rooms: at most 18 hypotheses for
//! one S1). The checkpoint is asked before each S1.

use nalgebra::{Point2, Vector2};
use rayon::prelude::*;

use super::bucket::{
    angle_key, approx_angle_key, approx_atan, period, Buckets, APPROX_ANGLE_KEY_ERROR,
};
use super::{gradients_compatible, MatchParams, RectSegment, Views};
use crate::checkpoint::{Checkpoint, Stopped};
use crate::geometry::{Rectification, RigFrames};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Instant;

/// A prediction in the verifying view that runs within this angle of the direction it moves
/// in as the disparity changes checks the line, not its depth (`verification_blind_to_depth`):
/// sin 15°. The angles in a room are either near 0 (lines along a baseline) or well away, so
/// 10° and 20° select the same triplets on the rendered rooms and rigs (docs/RIGS.md).
const DEPTH_BLIND_SIN: f64 = 0.258_819_045_102_520_76;
/// Shortest common part of two segments along the epipolar lines, and of a predicted segment
/// with the verifying one, pixels: below it the overlap is an accident of noise.
pub const MIN_OVERLAP_PX: f64 = 3.0;
/// S1 per rayon task: enough to amortise the scratch buffers.
const SEGMENTS_PER_TASK: usize = 32;
/// Work per round of the search ([`predict_in_frames_until`]): what another request may
/// wait for a thread while this one searches.
const ROUND_TIME: std::time::Duration = std::time::Duration::from_millis(2);
/// Most S1 per round, however fast they go.
const MAX_ROUND: usize = 1 << 14;
/// Most segments of the searched view paired with one S1 (the first, in index order).
pub const MAX_CANDIDATES_PER_SEGMENT: usize = 256;
/// Most hypotheses verified for one pair (the first, in index order).
pub const MAX_VERIFIED_PER_PAIR: usize = 32;
/// Up to this many candidates in the verifying view, all are tested and the verified sorted;
/// beyond, they are sorted first and tested up to [`MAX_VERIFIED_PER_PAIR`] verified.
const SORT_AFTER_AT_MOST: usize = 2 * MAX_VERIFIED_PER_PAIR;
/// Most hypotheses kept for one S1: those of smallest residual among the first
/// [`MAX_VERIFIED_PER_SEGMENT`] verified.
pub const MAX_HYPOTHESES_PER_SEGMENT: usize = 64;
/// Most triplets verified for one S1; its search stops there.
pub const MAX_VERIFIED_PER_SEGMENT: usize = 4 * MAX_HYPOTHESES_PER_SEGMENT;
/// Most hypotheses of one match: each costs validation and reconstruction state, so this
/// bounds a request's memory (about 400 bytes each at most).
pub const MAX_HYPOTHESES: usize = 200_000;

/// Why prediction produced no hypotheses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PredictError {
    #[error(transparent)]
    Stopped(#[from] Stopped),
    #[error("more than {limit} hypotheses")]
    TooManyHypotheses { limit: usize },
}

/// One predicted and verified triplet.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hypothesis {
    /// Indices into the three rectified views.
    pub segments: [u32; 3],
    /// Largest distance between prediction and verifying segment over their common part, px.
    pub residual_px: f64,
    /// The part of S1 the triplet covers, as positions along S1 (pixels from its start).
    pub s1_span: (f64, f64),
    /// Disparity at those two positions (δ is affine along an image line).
    pub disparity: (f64, f64),
    /// The pair frame the span and disparities are in (`RigFrames::pair_frames`): 0 once
    /// prediction returns.
    pub frame: u8,
    /// The verifying view could not check the depth (its prediction runs within 15° of the
    /// direction it moves in with the disparity), which the searched view alone then fixes:
    /// such a triplet's gradients must agree closely where they are known ([`super::gain`]),
    /// and it never takes a doubtful winner's place (`pipeline`, `yield_to_certain_rivals`).
    pub depth_blind: bool,
}

impl Hypothesis {
    /// Disparity at position `t` along S1 (pixels from its start), extrapolated linearly.
    pub fn disparity_at(&self, t: f64) -> f64 {
        let (t0, t1) = self.s1_span;
        let (d0, d1) = self.disparity;
        if (t1 - t0).abs() < 1e-9 {
            0.5 * (d0 + d1)
        } else {
            d0 + (d1 - d0) * (t - t0) / (t1 - t0)
        }
    }
}

/// The fixed geometry of one search: pair (1, j), verified in k.
struct Pair<'a> {
    j: usize,
    k: usize,
    /// The frame the pair is searched in (`RigFrames::pair_frames`), and view 1 rectified there.
    frame: usize,
    first: &'a [RectSegment],
    /// Epipolar vector c1 − cj (metres) and its unit direction.
    e_j: Vector2<f64>,
    e_j_len: f64,
    inv_e_j_len: f64,
    /// c1 − ck.
    e_k: Vector2<f64>,
    grid_j: &'a Buckets,
    grid_k: &'a Buckets,
}

/// Per-task scratch: "already seen" stamps per view, so a segment registered in several
/// windows is examined once per query.
struct Scratch {
    stamp: [Vec<u32>; 3],
    generation: u32,
    candidates: Vec<u32>,
    found: Vec<u32>,
    /// One segment's hypotheses while they are searched and thinned.
    hypotheses: Vec<Hypothesis>,
}

impl Scratch {
    fn new(views: &Views) -> Scratch {
        Scratch {
            stamp: std::array::from_fn(|v| vec![0; views.segments[v].len()]),
            generation: 0,
            candidates: Vec::new(),
            found: Vec::new(),
            hypotheses: Vec::new(),
        }
    }
    fn next(&mut self) -> u32 {
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.stamp.iter_mut().for_each(|s| s.fill(0));
            self.generation = 1;
        }
        self.generation
    }
}

#[inline]
fn first_visit(stamp: &mut [u32], segment: u32, generation: u32) -> bool {
    let s = &mut stamp[segment as usize];
    if *s == generation {
        false
    } else {
        *s = generation;
        true
    }
}

/// Predicts and verifies the hypotheses of every S1, in S1 order (deterministic).
pub fn predict(rect: &Rectification, views: &Views, params: &MatchParams) -> Vec<Hypothesis> {
    // Without a checkpoint only the total can fail; the bounds of the module doc still hold.
    predict_until(rect, views, params, Checkpoint::NEVER).unwrap_or_default()
}

/// What prediction found: the hypotheses, and what the gradient test of the depth-blind ones
/// measured and refused ([`super::gain`]).
#[derive(Debug, Clone)]
pub struct Predicted {
    pub hypotheses: Vec<Hypothesis>,
    /// Each view's gradient gain relative to view 1.
    pub gradient_gains: [f64; 3],
    /// Depth-blind hypotheses refused for gradients that disagree.
    pub depth_blind_refused: u32,
}

/// [`predict`], asking `checkpoint` before each S1, and failing past [`MAX_HYPOTHESES`].
pub fn predict_until(
    rect: &Rectification,
    views: &Views,
    params: &MatchParams,
    checkpoint: Checkpoint,
) -> Result<Vec<Hypothesis>, PredictError> {
    let frames = RigFrames {
        pair_frames: [rect.clone(), rect.clone()],
        shared: true,
        searched: [true, true],
    };
    let first = views.segments[0];
    predict_in_frames_until(&frames, views, [first, first], params, checkpoint)
        .map(|p| p.hypotheses)
}

/// [`predict_until`] in a rig's [`RigFrames`]: `views` holds view 1 and 2 rectified in the
/// first pair frame and view 3 in the second, `first` view 1 in each (the same segments,
/// index for index). The hypotheses' spans and disparities are in the first frame.
pub fn predict_in_frames_until(
    frames: &RigFrames,
    views: &Views,
    first: [&[RectSegment]; 2],
    params: &MatchParams,
    checkpoint: Checkpoint,
) -> Result<Predicted, PredictError> {
    let period = period(views.oriented);
    let tol = params.tolerance_px;
    let [frame_a, frame_b] = &frames.pair_frames;
    // View j's buckets along its epipolar lines with view 1 in `frame`.
    let buckets = |j: usize, frame: &Rectification| {
        Buckets::build_until(
            views.segments[j],
            frame.epipolar(0, j),
            tol,
            period,
            checkpoint,
        )
    };
    let grid2 = buckets(1, frame_a)?;
    let grid3 = buckets(2, frame_b)?;
    let pair = |j: usize| {
        let (k, frame, grid_j, grid_k) = if j == 1 {
            (2, 0, &grid2, &grid3)
        } else {
            (1, 1, &grid3, &grid2)
        };
        let rect = &frames.pair_frames[frame];
        let e_j = rect.epipolar(0, j);
        Pair {
            j,
            k,
            frame,
            first: first[frame],
            e_j,
            e_j_len: e_j.norm(),
            inv_e_j_len: 1.0 / e_j.norm(),
            e_k: rect.epipolar(0, k),
            grid_j,
            grid_k,
        }
    };
    let pairs = [pair(1), pair(2)];
    // The two frames share their focal length (the cameras' mean) and view 1's centre: the
    // disparity range is the same in both.
    let (d_min, d_max) = frame_a.disparity_range(params.depth_min_m, params.depth_max_m);
    let search = Search {
        views,
        frames,
        params,
        period,
        d_min,
        d_max,
        pairs: &pairs,
        verify_angle: params.verify_angle_tolerance_deg.to_radians().sin_cos(),
    };
    let s1 = views.segments[0];
    let total = AtomicUsize::new(0);
    let given_up = AtomicBool::new(false);
    let search_one = |scratch: &mut Scratch, i: usize| {
        if given_up.load(Ordering::Relaxed) || checkpoint.stopped() {
            given_up.store(true, Ordering::Relaxed);
            return Vec::new();
        }
        // Searched in the task's buffer and copied out at its final size: one
        // allocation per segment that has hypotheses, none for one that has none.
        let mut found = std::mem::take(&mut scratch.hypotheses);
        found.clear();
        search.one(i as u32, scratch, &mut found);
        keep_best(&mut found, MAX_HYPOTHESES_PER_SEGMENT);
        let out = found.to_vec();
        scratch.hypotheses = found;
        if total.fetch_add(out.len(), Ordering::Relaxed) + out.len() > MAX_HYPOTHESES {
            given_up.store(true, Ordering::Relaxed);
        }
        out
    };
    // In rounds: within one, the pool's threads work on this request alone (rayon's threads
    // take their own pending work first); between two, a thread that runs out of it takes
    // another request's job. Each round is sized from the last to take about ROUND_TIME, so a
    // request whose segments are slow to search (a crowd of them) holds the pool for that
    // long at a time, not for its whole search, and a quick one runs in one or two rounds.
    // The rounds only partition the S1 indices: the hypotheses are the same however they fall.
    let mut per_s1: Vec<Vec<Hypothesis>> = Vec::with_capacity(s1.len());
    let mut round_size = SEGMENTS_PER_TASK;
    let mut next = 0;
    while next < s1.len() && !given_up.load(Ordering::Relaxed) {
        let round = next..(next + round_size).min(s1.len());
        let count = round.len();
        let started = Instant::now();
        let found: Vec<Vec<Hypothesis>> = round
            .into_par_iter()
            .with_min_len(SEGMENTS_PER_TASK)
            .map_init(|| Scratch::new(views), &search_one)
            .collect();
        per_s1.extend(found);
        next += count;
        let per_segment = started.elapsed().as_secs_f64() / count as f64;
        round_size = (ROUND_TIME.as_secs_f64() / per_segment.max(1e-9)).clamp(1.0, MAX_ROUND as f64)
            as usize;
    }

    checkpoint.before("predict")?;
    if total.into_inner() > MAX_HYPOTHESES {
        return Err(PredictError::TooManyHypotheses {
            limit: MAX_HYPOTHESES,
        });
    }
    let mut hypotheses: Vec<Hypothesis> = per_s1.into_iter().flatten().collect();
    if !frames.shared {
        // Hypotheses found in the second frame, in the first's terms (validation compares
        // disparities along S1), through the 3D points at the ends of their span; dropped
        // where those do not map into the first frame.
        hypotheses.retain_mut(|h| {
            if h.frame == 0 {
                return true;
            }
            match in_first_frame(frames, first, h) {
                Some(moved) => {
                    *h = moved;
                    true
                }
                None => false,
            }
        });
    }
    let (gradient_gains, depth_blind_refused) = super::gain::refuse_depth_blind(
        views,
        &mut hypotheses,
        params.depth_blind_gradient_ratio_max,
    );
    Ok(Predicted {
        hypotheses,
        gradient_gains,
        depth_blind_refused,
    })
}

/// `h`, found in the second pair frame, with its span and disparities in the first.
fn in_first_frame(
    frames: &RigFrames,
    first: [&[RectSegment]; 2],
    h: &Hypothesis,
) -> Option<Hypothesis> {
    let i1 = h.segments[0] as usize;
    let (s_from, s_to) = (&first[1][i1], &first[0][i1]);
    let [to, from] = [&frames.pair_frames[0], &frames.pair_frames[1]];
    let moved = |t: f64, d: f64| -> Option<(f64, f64)> {
        let point = from.point(0, s_from.a + s_from.dir * t, d);
        let (a, delta) = to.project(0, &point)?;
        Some((s_to.along(a), delta))
    };
    let (t0, d0) = moved(h.s1_span.0, h.disparity.0)?;
    let (t1, d1) = moved(h.s1_span.1, h.disparity.1)?;
    let (s1_span, disparity) = if t0 <= t1 {
        ((t0, t1), (d0, d1))
    } else {
        ((t1, t0), (d1, d0))
    };
    (s1_span.0.is_finite() && s1_span.1.is_finite() && d0.is_finite() && d1.is_finite()).then_some(
        Hypothesis {
            s1_span,
            disparity,
            frame: 0,
            ..*h
        },
    )
}

/// Keeps the `max` hypotheses of smallest residual (ties: the earlier), in their order.
fn keep_best(out: &mut Vec<Hypothesis>, max: usize) {
    if out.len() <= max {
        return;
    }
    let mut order: Vec<usize> = (0..out.len()).collect();
    order.sort_by(|&a, &b| out[a].residual_px.total_cmp(&out[b].residual_px));
    let mut keep = vec![false; out.len()];
    order[..max].iter().for_each(|&i| keep[i] = true);
    let mut i = 0;
    out.retain(|_| {
        i += 1;
        keep[i - 1]
    });
}

struct Search<'a> {
    views: &'a Views<'a>,
    frames: &'a RigFrames,
    params: &'a MatchParams,
    period: f64,
    d_min: f64,
    d_max: f64,
    pairs: &'a [Pair<'a>; 2],
    /// Sine and cosine of `params.verify_angle_tolerance_deg`.
    verify_angle: (f64, f64),
}

impl Search<'_> {
    fn one(&self, i1: u32, scratch: &mut Scratch, out: &mut Vec<Hypothesis>) {
        // 1. The pair whose epipolar direction is farthest from S1's (in the pair's frame).
        let sin_to = |p: &Pair| {
            let s1 = &p.first[i1 as usize];
            (s1.dir.perp(&p.e_j) / p.e_j_len).abs()
        };
        let pair = match self.frames.searched {
            [true, false] => &self.pairs[0],
            [false, true] => &self.pairs[1],
            _ if sin_to(&self.pairs[0]) >= sin_to(&self.pairs[1]) => &self.pairs[0],
            _ => &self.pairs[1],
        };
        let s1 = &pair.first[i1 as usize];
        let tol = self.params.tolerance_px;
        let grid = pair.grid_j;
        let (ax, ay) = grid.frame(s1.a);
        let (bx, by) = grid.frame(s1.b);
        if (by - ay).abs() < MIN_OVERLAP_PX {
            return; // parallel to both epipolar directions: only a collinear rig gets here
        }
        let inv_dy1 = 1.0 / (by - ay);
        let key1 = angle_key(s1.dir, self.period);
        let angle_tol = self.params.angle_tolerance_deg.to_radians();
        let (shift_min, shift_max) = (
            self.d_min * pair.e_j_len - tol,
            self.d_max * pair.e_j_len + tol,
        );
        let generation = scratch.next();
        let (ylo, yhi) = (ay.min(by), ay.max(by));
        let Some((r0, r1)) = grid.rows(ylo, yhi) else {
            return;
        };
        // 2. Candidates in the band of rows S1 spans, shifted along the epipolar direction by
        //    the disparity interval.
        let mut candidates = std::mem::take(&mut scratch.candidates);
        candidates.clear();
        let stamp = &mut scratch.stamp[pair.j];
        for cy in r0..=r1 {
            let (band_lo, band_hi) = grid.row_span(cy);
            let (lo, hi) = (band_lo.max(ylo), band_hi.min(yhi));
            let x_at = |y: f64| ax + (bx - ax) * ((y - ay) / (by - ay));
            let (xa, xb) = (x_at(lo), x_at(hi));
            let Some((c0, c1)) = grid.columns(xa.min(xb) + shift_min, xa.max(xb) + shift_max)
            else {
                continue;
            };
            for cx in c0..=c1 {
                grid.for_each_in_cell(cx, cy, key1, angle_tol, |s| {
                    if first_visit(stamp, s, generation) {
                        candidates.push(s);
                    }
                });
            }
        }
        candidates.sort_unstable();
        candidates.truncate(MAX_CANDIDATES_PER_SEGMENT);
        for &ij in &candidates {
            if out.len() >= MAX_VERIFIED_PER_SEGMENT {
                break;
            }
            self.verify_pair(i1, s1, (ax, ay, bx, by), inv_dy1, pair, ij, scratch, out);
        }
        scratch.candidates = candidates;
    }

    /// True when the prediction in the verifying view runs within 15° ([`DEPTH_BLIND_SIN`]) of
    /// the direction it moves in as the disparity changes: the verification then confirms
    /// the line but hardly its depth, which rests on the searched view alone (a line along
    /// the baseline of view 1 and the verifying view).
    fn verification_blind_to_depth(
        &self,
        pair: &Pair,
        p0: Point2<f64>,
        d0: f64,
        q0: Point2<f64>,
        q_dir: Vector2<f64>,
    ) -> bool {
        let moved = if self.frames.shared {
            pair.e_k
        } else {
            let step = 0.01 * (self.d_max - self.d_min).max(1e-9);
            match self.frames.transfer(pair.frame, p0, d0 + step, pair.k) {
                Some(q) => q - q0,
                None => return false,
            }
        };
        let n = moved.norm();
        n > 0.0 && (moved.x * q_dir.y - moved.y * q_dir.x).abs() < DEPTH_BLIND_SIN * n
    }

    #[allow(clippy::too_many_arguments)]
    fn verify_pair(
        &self,
        i1: u32,
        s1: &RectSegment,
        (ax, ay, bx, by): (f64, f64, f64, f64),
        inv_dy1: f64,
        pair: &Pair,
        ij: u32,
        scratch: &mut Scratch,
        out: &mut Vec<Hypothesis>,
    ) {
        let params = self.params;
        let tol = params.tolerance_px;
        let sj = &self.views.segments[pair.j][ij as usize];
        if !gradients_compatible(s1.gradient, sj.gradient, params.gradient_ratio_max) {
            return;
        }
        let grid = pair.grid_j;
        let (cx_, cy_) = grid.frame(sj.a);
        let (dx_, dy_) = grid.frame(sj.b);
        if (dy_ - cy_).abs() < 1e-9 {
            return;
        }
        // Common part along the epipolar lines (turned-frame y).
        let lo = ay.min(by).max(cy_.min(dy_));
        let hi = ay.max(by).min(cy_.max(dy_));
        if hi - lo < MIN_OVERLAP_PX {
            return;
        }
        // In products by reciprocals (1/Δy of S1 is its caller's, once per S1): a division
        // costs several products, and every candidate took nine of them.
        let inv_dyj = 1.0 / (dy_ - cy_);
        let x1 = |y: f64| ax + (bx - ax) * ((y - ay) * inv_dy1);
        let xj = |y: f64| cx_ + (dx_ - cx_) * ((y - cy_) * inv_dyj);
        let slack = tol * pair.inv_e_j_len;
        let (d_lo, d_hi) = (
            (xj(lo) - x1(lo)) * pair.inv_e_j_len,
            (xj(hi) - x1(hi)) * pair.inv_e_j_len,
        );
        let in_range = |d: f64| d >= self.d_min - slack && d <= self.d_max + slack;
        if !in_range(d_lo) || !in_range(d_hi) {
            return;
        }
        // Positions along S1 of the common part's ends, in S1's own order.
        let t_at = |y: f64| s1.len * ((y - ay) * inv_dy1);
        let (mut t0, mut t1, mut d0, mut d1) = (t_at(lo), t_at(hi), d_lo, d_hi);
        if t0 > t1 {
            (t0, t1, d0, d1) = (t1, t0, d1, d0);
        }
        // 3. Transfer into the verifying view.
        let p0 = s1.a + s1.dir * t0;
        let p1 = s1.a + s1.dir * t1;
        let (q0, q1): (Point2<f64>, Point2<f64>) = if self.frames.shared {
            (p0 + pair.e_k * d0, p1 + pair.e_k * d1)
        } else {
            let transfer = |p, d| self.frames.transfer(pair.frame, p, d, pair.k);
            let (Some(q0), Some(q1)) = (transfer(p0, d0), transfer(p1, d1)) else {
                return;
            };
            (q0, q1)
        };
        let q = q1 - q0;
        let q_len = q.norm();
        if q_len < MIN_OVERLAP_PX {
            return;
        }
        let q_dir = q / q_len;
        // The angle tolerance a widens by the angle `tol` subtends at either end of the
        // prediction, atan x. The exact test is on its cosine, cos(a + atan x) =
        // (cos a − x·sin a) / √(1 + x²); the windows are only a prefilter, searched around an
        // approximate key with an approximate atan, widened by both their error bounds, so no
        // library trigonometry is called per prediction and nothing the exact test accepts
        // is missed.
        let key_q = approx_angle_key(q_dir, self.period);
        let widen = 2.0 * tol / q_len;
        let a = params.verify_angle_tolerance_deg.to_radians();
        let window_tol = a + approx_atan(widen) + 2.0 * APPROX_ANGLE_KEY_ERROR;
        let (sin_a, cos_a) = self.verify_angle;
        // a + atan x ≥ π: every direction passes.
        let opens_fully =
            a > std::f64::consts::FRAC_PI_2 && widen >= (std::f64::consts::PI - a).tan();
        let cos_tol = if opens_fully {
            -1.0
        } else {
            (cos_a - widen * sin_a) / (1.0 + widen * widen).sqrt()
        };
        // 4. Verify along the predicted segment.
        let generation = scratch.next();
        let grid_k = pair.grid_k;
        let k = pair.k;
        let Scratch { stamp, found, .. } = scratch;
        found.clear();
        let stamp = &mut stamp[k];
        // Only segments whose line comes within `tol` of the prediction somewhere can verify
        // it (the residual is the distance at two points between q0 and q1): the windows
        // skip the others from their own copy of the lines, without reading the segments.
        grid_k.for_each_cell_on_path(q0, q1, tol, |cx, cy| {
            grid_k.for_each_in_cell_near(cx, cy, key_q, window_tol, (q0, q1), tol, |ik| {
                if first_visit(stamp, ik, generation) {
                    found.push(ik);
                }
            });
        });
        // Candidates come out in window order; the output must not depend on the grid, and
        // the cap keeps the lowest indices. Usually the few that pass are sorted after the
        // tests (sorting every candidate first was 7% of a match); in a crowd, where the cap
        // binds, the candidates are sorted first and the tests stop at the cap, so a request
        // that piles segments up pays for the cap's worth, not for all it piled. Both give
        // the same hypotheses.
        let verified_before = out.len();
        let sort_first = found.len() > SORT_AFTER_AT_MOST;
        if sort_first {
            found.sort_unstable();
        }
        for &ik in found.iter() {
            if sort_first && out.len() - verified_before == MAX_VERIFIED_PER_PAIR {
                break;
            }
            let sk = &self.views.segments[k][ik as usize];
            let cos = sk.dir.dot(&q_dir);
            let aligned = if self.views.oriented { cos } else { cos.abs() };
            if aligned < cos_tol
                || !gradients_compatible(s1.gradient, sk.gradient, params.gradient_ratio_max)
                || !gradients_compatible(sj.gradient, sk.gradient, params.gradient_ratio_max)
            {
                continue;
            }
            let (ta, tb) = (sk.along(q0), sk.along(q1));
            if (tb - ta).abs() < 1e-9 {
                continue;
            }
            let (lo_t, hi_t) = (ta.min(tb).max(0.0), ta.max(tb).min(sk.len));
            if hi_t - lo_t < MIN_OVERLAP_PX {
                continue;
            }
            // Distance from Sk's line along the prediction, linear between q0 and q1.
            let (da, db) = (sk.line_distance(q0), sk.line_distance(q1));
            let at = |t: f64| da + (db - da) * (t - ta) / (tb - ta);
            let residual = at(lo_t).abs().max(at(hi_t).abs());
            if residual > tol {
                continue;
            }
            let segments = if pair.j == 1 {
                [i1, ij, ik]
            } else {
                [i1, ik, ij]
            };
            // Where the verification cannot check the depth, the three views' gradients must
            // agree more closely (once the views' gains are known: `gain`; an unknown
            // gradient agrees with any).
            let depth_blind = self.verification_blind_to_depth(pair, p0, d0, q0, q_dir);
            out.push(Hypothesis {
                segments,
                residual_px: residual,
                s1_span: (t0, t1),
                disparity: (d0, d1),
                frame: pair.frame as u8,
                depth_blind,
            });
        }
        let verified = &mut out[verified_before..];
        if verified.len() > 1 {
            let slot = if pair.j == 1 { 2 } else { 1 };
            verified.sort_unstable_by_key(|h| h.segments[slot]);
        }
        out.truncate(verified_before + MAX_VERIFIED_PER_PAIR);
    }
}
