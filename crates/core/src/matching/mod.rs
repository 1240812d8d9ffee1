//! Trinocular matching (DESIGN §2.3–2.5): buckets, hypothesis prediction and verification,
//! local-consistency validation.
//!
//! Input: the three views' segments already rectified ([`RectSegment`], see
//! [`crate::geometry::rectify`]). Output: triplets of indices into those views. Pure and
//! synchronous; prediction runs in parallel over the segments of view 1 on the current rayon
//! pool, and the output is the same whatever the number of threads.

pub mod bucket;
pub mod gain;
pub mod predict;
pub mod validate;

use nalgebra::{Point2, Vector2};

use crate::params::{check_all, Rule};

pub use predict::{
    predict, predict_in_frames_until, predict_until, Hypothesis, PredictError, Predicted,
};
pub use validate::{adjacency, conflict, rank, rank_until, select, validate};

/// Matching parameters. Units are in the names; `Default` gives the documented defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct MatchParams {
    /// Depth range searched, metres, along the rig's viewing direction.
    pub depth_min_m: f64,
    pub depth_max_m: f64,
    /// Distance allowed between a segment and its prediction in the verifying view, pixels.
    pub tolerance_px: f64,
    /// Orientation difference allowed between the two segments of the searched pair, degrees.
    pub angle_tolerance_deg: f64,
    /// Orientation difference allowed in the verifying view, degrees, on top of what
    /// `tolerance_px` allows over the predicted segment's length.
    pub verify_angle_tolerance_deg: f64,
    /// Shortest segment used, pixels.
    pub min_length_px: f64,
    /// Largest ratio of the gradient magnitudes of two matched segments (when both known).
    pub gradient_ratio_max: f64,
    /// The same, among the three segments of a triplet whose verification cannot check its
    /// depth: the segment of view 1 runs within 15° of the verifying view's epipolar lines,
    /// so that view confirms the line wherever along the rays it lies, and the depth rests on
    /// the searched view alone. Each gradient is first divided by its view's gain, measured
    /// on the request's hypotheses ([`gain`]). Correct triplets of the rendered rooms have a
    /// median ratio of 1.02 and 1.33–1.36 at the 95th percentile (docs/RIGS.md).
    pub depth_blind_gradient_ratio_max: f64,
    /// Segments whose mean gradient is known and below this are not matched, grey levels
    /// per pixel. On real photographs faint repetitive texture (mortar between bricks) is
    /// where false matches come from (docs/RIGS.md#real-photographs); 0 matches everything.
    pub min_gradient: f64,
    /// Segments whose mean gradient is below this multiple of their list's
    /// `background_gradient` (when both are known) are not matched: an edge must stand out
    /// from the noise and texture of its image. Clean images have a background well under one
    /// grey level per pixel, below any edge extraction keeps; a photograph of brick has two
    /// or more, and its mortar lines fall under the floor (docs/RIGS.md#real-photographs).
    pub min_gradient_to_background: f64,
    /// Run local-consistency validation.
    pub validate: bool,
    /// Endpoints closer than this share a vertex (neighbour support), pixels.
    pub neighbour_radius_px: f64,
    /// Largest RMS reprojection residual of a reconstructed 3D segment, pixels.
    pub max_residual_px: f64,
    /// Noise of a segment whose list does not say how precise it is: its line is taken for a
    /// fit to one independent point per 2 px, each off by this, pixels (`LineNoise::for_list`).
    /// Extracted segments carry their own, measured from their edge points.
    pub line_noise_px: f64,
    /// σ of a shift of such a list segment's line across itself, independent from view to
    /// view, that `line_noise_px`'s model leaves out, pixels: a detector's systematic error,
    /// which no number of points averages away (OpenCV LSD's lines are off by about 0.1 px at
    /// every length). The reported covariance and the gate count it; the χ² tests, which
    /// compare the views with one another, do not (`LineObservation::systematic_px`). 0 for
    /// exact lines.
    pub list_shift_px: f64,
    /// How hard a neighbour of opposite contrast pushes the lines of a list that does not
    /// state its noise, at full strength, pixels: the matcher moves them back
    /// (`segment::Repulsion`; the default is OpenCV LSD's, measured). 0 for lists whose
    /// detector does not push (exact synthetic lines, or one that models its neighbours).
    pub list_push_px: f64,
    /// 3D segments whose direction σ exceeds this are dropped, degrees.
    pub max_direction_sigma_deg: f64,
    /// An uncertain 3D segment that ends, within this many pixels in every view, where a
    /// certain one ends is estimated again through that shared vertex (`pipeline`,
    /// docs/ACCURACY.md "Shared vertices"); 0 turns it off. 2 gained completeness in both
    /// rendered rooms from images and LSD lists at no error; 3 placed a segment from LSD lists
    /// near no edge.
    pub vertex_reach_px: f64,
    /// A 3D segment the gate doubts for its direction alone takes the direction of the
    /// scene's well-measured lines it lies along (a room's three), when it does with 95%
    /// posterior probability, or else the plane square to one it lies in (a room's
    /// horizontal), and is judged again (`pipeline`, docs/ACCURACY.md "The scene's dominant
    /// directions"). False for a scene not built along a few directions.
    pub dominant_directions: bool,
    /// The accuracy a 3D segment must meet, at `gate_confidence`, to be in the answer by
    /// default: its direction within `gate_direction_deg`, and its midpoint and both ends
    /// across the line within max(`gate_position_m`, `gate_position_rel` × distance from the
    /// rig).
    pub gate_direction_deg: f64,
    pub gate_position_m: f64,
    pub gate_position_rel: f64,
    pub gate_confidence: f64,
    /// Also answer with the 3D segments that miss that accuracy, flagged `uncertain`.
    pub include_uncertain: bool,
}

impl Default for MatchParams {
    fn default() -> Self {
        MatchParams {
            depth_min_m: 0.3,
            depth_max_m: 15.0,
            tolerance_px: 2.0,
            angle_tolerance_deg: 30.0,
            verify_angle_tolerance_deg: 3.0,
            min_length_px: 8.0,
            gradient_ratio_max: 3.0,
            depth_blind_gradient_ratio_max: 1.6,
            min_gradient: 0.0,
            min_gradient_to_background: 2.5,
            validate: true,
            neighbour_radius_px: 8.0,
            max_residual_px: 1.5,
            line_noise_px: 0.3,
            list_push_px: crate::segment::CrowdingModel::LSD_PUSH_PX,
            list_shift_px: MatchParams::LIST_SHIFT_PX,
            max_direction_sigma_deg: 180.0,
            vertex_reach_px: MatchParams::VERTEX_REACH_PX,
            dominant_directions: true,
            gate_direction_deg: 5.0,
            gate_position_m: 0.02,
            gate_position_rel: 0.01,
            gate_confidence: 0.95,
            include_uncertain: false,
        }
    }
}

impl MatchParams {
    /// The default of [`MatchParams::vertex_reach_px`].
    pub const VERTEX_REACH_PX: f64 = 2.0;
    /// The default of [`MatchParams::list_shift_px`]: the least that brings the position of
    /// OpenCV LSD lists' 3D segments within χ²'s 99% quantile for 98% of them in both
    /// rendered rooms (docs/ACCURACY.md, "A list line's own shift"), and the floor our own
    /// extractor's noise has.
    pub const LIST_SHIFT_PX: f64 = 0.1;
}

/// Largest `list_shift_px`: a detector whose lines are systematically off by more than a
/// pixel should say so per segment (`offsetSigmaPx`).
pub const MAX_LIST_SHIFT_PX: f64 = 1.0;

/// Largest `vertex_reach_px`: ends farther apart than a segment's own minimum length are not
/// one vertex.
pub const MAX_VERTEX_REACH_PX: f64 = 8.0;

/// Largest `list_push_px`: a push is at most a quarter of the distance anyway, and five
/// times LSD's is no detector's.
pub const MAX_LIST_PUSH_PX: f64 = 5.0;

/// A parameter out of its domain; `field` is the schema's `MatchOptions` field name.
pub use crate::params::{ParamError, ParamErrors};

impl MatchParams {
    /// Checks every field; reports every problem. Every field must be finite as well as in
    /// its range.
    pub fn check(&self) -> Result<(), ParamErrors> {
        let rule = |field, value: f64, ok: bool, requirement| {
            Rule::new(field, value, value.is_finite() && ok, requirement)
        };
        check_all([
            rule(
                "depth_min_m",
                self.depth_min_m,
                self.depth_min_m > 0.0,
                "a finite number greater than 0",
            ),
            rule(
                "depth_max_m",
                self.depth_max_m,
                self.depth_max_m > self.depth_min_m,
                "a finite number greater than depth_min_m",
            ),
            rule(
                "tolerance_px",
                self.tolerance_px,
                self.tolerance_px > 0.0 && self.tolerance_px <= 50.0,
                "a finite number in (0, 50]",
            ),
            rule(
                "angle_tolerance_deg",
                self.angle_tolerance_deg,
                self.angle_tolerance_deg > 0.0 && self.angle_tolerance_deg <= 90.0,
                "a finite number in (0, 90]",
            ),
            rule(
                "verify_angle_tolerance_deg",
                self.verify_angle_tolerance_deg,
                self.verify_angle_tolerance_deg >= 0.0 && self.verify_angle_tolerance_deg <= 45.0,
                "a finite number in [0, 45]",
            ),
            rule(
                "min_length_px",
                self.min_length_px,
                self.min_length_px >= 0.0,
                "a finite number at least 0",
            ),
            rule(
                "gradient_ratio_max",
                self.gradient_ratio_max,
                self.gradient_ratio_max >= 1.0,
                "a finite number at least 1",
            ),
            rule(
                "depth_blind_gradient_ratio_max",
                self.depth_blind_gradient_ratio_max,
                self.depth_blind_gradient_ratio_max >= 1.0,
                "a finite number at least 1",
            ),
            rule(
                "min_gradient",
                self.min_gradient,
                self.min_gradient >= 0.0,
                "a finite number at least 0",
            ),
            rule(
                "min_gradient_to_background",
                self.min_gradient_to_background,
                self.min_gradient_to_background >= 0.0,
                "a finite number at least 0",
            ),
            rule(
                "neighbour_radius_px",
                self.neighbour_radius_px,
                self.neighbour_radius_px >= 0.0 && self.neighbour_radius_px <= 100.0,
                "a finite number in [0, 100]",
            ),
            rule(
                "max_residual_px",
                self.max_residual_px,
                self.max_residual_px > 0.0,
                "a finite number greater than 0",
            ),
            rule(
                "line_noise_px",
                self.line_noise_px,
                self.line_noise_px > 0.0,
                "a finite number greater than 0",
            ),
            rule(
                "list_push_px",
                self.list_push_px,
                (0.0..=MAX_LIST_PUSH_PX).contains(&self.list_push_px),
                "a finite number in [0, 5]",
            ),
            rule(
                "list_shift_px",
                self.list_shift_px,
                (0.0..=MAX_LIST_SHIFT_PX).contains(&self.list_shift_px),
                "a finite number in [0, 1]",
            ),
            rule(
                "max_direction_sigma_deg",
                self.max_direction_sigma_deg,
                self.max_direction_sigma_deg > 0.0,
                "a finite number greater than 0",
            ),
            rule(
                "vertex_reach_px",
                self.vertex_reach_px,
                (0.0..=MAX_VERTEX_REACH_PX).contains(&self.vertex_reach_px),
                "a finite number in [0, 8]",
            ),
            rule(
                "gate_direction_deg",
                self.gate_direction_deg,
                self.gate_direction_deg > 0.0 && self.gate_direction_deg <= 180.0,
                "a finite number in (0, 180]",
            ),
            rule(
                "gate_position_m",
                self.gate_position_m,
                self.gate_position_m > 0.0,
                "a finite number greater than 0",
            ),
            rule(
                "gate_position_rel",
                self.gate_position_rel,
                self.gate_position_rel >= 0.0,
                "a finite number at least 0",
            ),
            rule(
                "gate_confidence",
                self.gate_confidence,
                self.gate_confidence > 0.0 && self.gate_confidence < 1.0,
                "a finite number in (0, 1)",
            ),
        ])
    }
}

/// A segment in rectified pixels, with what the matcher asks of it precomputed.
#[derive(Debug, Clone, Copy)]
pub struct RectSegment {
    pub a: Point2<f64>,
    pub b: Point2<f64>,
    /// Unit direction a→b.
    pub dir: Vector2<f64>,
    pub len: f64,
    /// Mean gradient magnitude, NaN when unknown.
    pub gradient: f64,
    /// Index in the caller's list.
    pub index: u32,
}

impl RectSegment {
    pub fn new(a: Point2<f64>, b: Point2<f64>, gradient: f64, index: u32) -> RectSegment {
        let d = b - a;
        let len = d.norm();
        let dir = if len > 0.0 { d / len } else { Vector2::x() };
        RectSegment {
            a,
            b,
            dir,
            len,
            gradient,
            index,
        }
    }

    /// Signed distance of `p` from the segment's line (positive on the left of a→b in a
    /// y-down image, i.e. along (dir.y, −dir.x)).
    #[inline]
    pub fn line_distance(&self, p: Point2<f64>) -> f64 {
        let w = p - self.a;
        w.x * self.dir.y - w.y * self.dir.x
    }

    /// Position of `p`'s foot along the segment, pixels from `a`.
    #[inline]
    pub fn along(&self, p: Point2<f64>) -> f64 {
        (p - self.a).dot(&self.dir)
    }
}

/// True when the gradient magnitudes (if both known) are within `ratio_max` of each other.
#[inline]
pub fn gradients_compatible(g1: f64, g2: f64, ratio_max: f64) -> bool {
    if !(g1 > 0.0 && g2 > 0.0) {
        return true;
    }
    let r = if g1 > g2 { g1 / g2 } else { g2 / g1 };
    r <= ratio_max
}

/// The three rectified views as the matcher sees them.
#[derive(Debug, Clone)]
pub struct Views<'a> {
    pub segments: [&'a [RectSegment]; 3],
    /// True when all three lists are oriented by contrast.
    pub oriented: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_problem_of_the_parameters_is_reported_once_in_field_order() {
        let params = MatchParams {
            tolerance_px: f64::NAN,
            min_gradient: -1.0,
            gate_confidence: 1.0,
            ..MatchParams::default()
        };
        let e = params.check().unwrap_err();
        let fields: Vec<_> = e.problems().iter().map(|p| p.field).collect();
        assert_eq!(fields, ["tolerance_px", "min_gradient", "gate_confidence"]);
        assert_eq!(e.field(), "tolerance_px");
        assert!(MatchParams::default().check().is_ok());
    }

    /// The lists' push and shift: 0 (exact lines) and their largest are accepted, anything
    /// beyond either end or not finite names the option.
    #[test]
    fn a_list_push_and_shift_are_off_at_zero_and_bounded() {
        type Set = fn(&mut MatchParams, f64);
        let options: [(&str, f64, Set); 2] = [
            ("list_push_px", MAX_LIST_PUSH_PX, |p, v| p.list_push_px = v),
            ("list_shift_px", MAX_LIST_SHIFT_PX, |p, v| {
                p.list_shift_px = v
            }),
        ];
        for (field, max, set) in options {
            let with = |value: f64| {
                let mut params = MatchParams::default();
                set(&mut params, value);
                params.check()
            };
            for value in [0.0, max] {
                assert!(with(value).is_ok(), "{field} {value}");
            }
            for value in [-0.01, max + 0.01, f64::NAN, f64::INFINITY] {
                assert_eq!(with(value).unwrap_err().field(), field, "{value}");
            }
        }
        assert!(crate::segment::CrowdingModel::lists(0.0)
            .repulsion
            .is_none());
        assert_eq!(
            crate::segment::CrowdingModel::lists(MatchParams::default().list_push_px),
            crate::segment::CrowdingModel::LISTS
        );
    }
}
