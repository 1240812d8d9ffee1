//! Session maps: the 3D segments of many captures, each taken from its own pose, fused into
//! one panoramic map of a room in the world frame (the paper's figure 7).
//!
//! A robot turns in a room and sends one capture per pose. [`fuse`] moves every capture's
//! rig-frame segments to the world frame by the capture's pose, links pairs that are
//! collinear and overlapping (or nearly touching) within tolerance — candidates come from an
//! R-tree (`rstar`) of bounding boxes inflated by the tolerance — and merges each connected
//! group into one segment by a weighted total-least-squares line fit. The map is a pure
//! function of the *set* of captures, not of the order they arrived in, so a service can
//! recompute it from stored captures whenever it is asked. [`export`] writes PLY, OBJ and
//! top views.

pub mod compass;
mod envelope;
pub mod export;
mod fuse;
pub mod images;
pub mod landmarks;
pub mod poses;
pub mod register;
pub mod session;
#[cfg(test)]
mod test_room;
#[cfg(test)]
mod tests;

use nalgebra::{Isometry3, Matrix6, Point3};

use crate::params::{check_all, Rule};
use crate::segment::Segment3;

pub use fuse::fuse;
pub use register::{
    register, Measured, PosePrior, RegisterParams, Registration, RegistrationStatus,
};

/// One capture of a session: its 3D segments in the rig frame and the pose of the rig.
#[derive(Debug, Clone, Copy)]
pub struct Capture<'a> {
    /// Identifies the capture in [`MapSegment::captures`]; unique within a session.
    pub id: u32,
    /// Takes rig-frame points to the world frame (right-handed, metres, z up).
    pub rig_to_world: Isometry3<f64>,
    /// Rig-frame segments, e.g. a [`crate::pipeline::MatchOutput`]'s.
    pub segments: &'a [Segment3],
    /// Each segment's covariance (x1 y1 z1 x2 y2 z2, rig frame, metres²), as the match gives
    /// it; empty when unknown — each endpoint is then taken to be known to its lateral
    /// tolerance at 95%.
    pub covariances: &'a [Matrix6<f64>],
    /// How well the pose is known: the covariance of a small rotation vector about the rig's
    /// origin (world axes, radians) then of the translation (metres), as
    /// [`PosePrior::covariance`]; zero for a pose known exactly. Every segment of the capture
    /// shares it.
    pub pose_covariance: Matrix6<f64>,
}

impl Default for Capture<'_> {
    fn default() -> Self {
        Capture {
            id: 0,
            rig_to_world: Isometry3::identity(),
            segments: &[],
            covariances: &[],
            pose_covariance: Matrix6::zeros(),
        }
    }
}

/// Tolerances of [`fuse`].
///
/// Two segments are one line when the shorter's endpoints lie within the lateral tolerance of
/// the longer's line, their directions agree within `angle_deg`, and they overlap or leave a
/// gap of at most `max_gap_m` along the line. The lateral tolerance of a point is
/// `max(lateral_m, lateral_rel · range)`, `range` being its distance from the rig that saw it
/// (stereo errors grow with range); for a pair, the two segments' tolerances add in
/// quadrature.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FuseParams {
    /// Floor of the lateral tolerance, metres.
    pub lateral_m: f64,
    /// Lateral tolerance per metre of range from the capturing rig (0.01 = 1 cm at 1 m).
    pub lateral_rel: f64,
    /// Largest angle between two segments of one line, degrees.
    pub angle_deg: f64,
    /// Largest gap along the line between two segments that are merged, metres.
    pub max_gap_m: f64,
    /// Map segments supported by fewer distinct captures are dropped (1 keeps all).
    pub min_observations: u32,
    /// The accuracy a map segment must meet, by its fused covariance, to be in the map; none:
    /// every segment is.
    pub gate: Option<MapGate>,
}

/// The promise of a gated map, as a Match answer's (the session's match options give it):
/// at `confidence`, each map segment's direction within `direction_deg` of the truth and its
/// midpoint and both ends within max(`position_m`, `position_rel` × the distance to the
/// nearest rig that saw it) across the line — the pose's uncertainty included, so a capture
/// that registration could not place does not put its segments where they may not be.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapGate {
    pub direction_deg: f64,
    pub position_m: f64,
    pub position_rel: f64,
    pub confidence: f64,
    /// Keep the segments that miss it too, flagged [`MapSegment::uncertain`].
    pub include_uncertain: bool,
    /// σ of the shift across the line that a rig's three views share, per metre of range
    /// ([`crate::pipeline::SHARED_SHIFT_PX`] over the cameras' mean focal length; 0: none).
    /// The captures' own covariances are fused without it, since captures of one scene share
    /// it; a map segment's gate and reported covariance add it once.
    pub shift_per_metre: f64,
}

impl MapGate {
    /// The gate of a match's answer (`params`), for the map of the session it belongs to.
    pub fn of(params: &crate::matching::MatchParams) -> MapGate {
        MapGate {
            direction_deg: params.gate_direction_deg,
            position_m: params.gate_position_m,
            position_rel: params.gate_position_rel,
            confidence: params.gate_confidence,
            include_uncertain: params.include_uncertain,
            shift_per_metre: 0.0,
        }
    }

    /// The gate with the shift `rig`'s three views share ([`MapGate::shift_per_metre`]).
    pub fn sharing_shift(self, rig: &crate::geometry::Rig) -> MapGate {
        MapGate {
            shift_per_metre: crate::pipeline::shared_shift_per_metre(rig),
            ..self
        }
    }
}

impl Default for FuseParams {
    /// Measured on the shared rooms (`tools/eval_map.py`, docs/SESSIONS.md). The gap is 1 cm,
    /// not more: collinear edges a few centimetres apart are two edges (two shelf boards
    /// either side of a 3 cm divider), and a 5 cm gap joined them into one map segment that
    /// overran both — most of the lab's wrong map segments. The lateral tolerance is 1 cm or
    /// 0.25% of the range: with 0.5%, edges 1–1.5 cm apart at 3 m (a board's two faces) were
    /// fused into one line between them, which covers one of the two at best (office and
    /// lab, every noise level: error and completeness both better at 0.25%).
    fn default() -> Self {
        FuseParams {
            lateral_m: 0.01,
            lateral_rel: 0.0025,
            angle_deg: 3.0,
            max_gap_m: 0.01,
            min_observations: 1,
            gate: None,
        }
    }
}

/// A [`FuseParams`] field out of range.
pub use crate::params::{ParamError, ParamErrors};

impl FuseParams {
    /// Checks every field; reports every problem. (`contains` and comparisons are false for
    /// NaN, so non-finite values fail too.)
    pub fn check(&self) -> Result<(), ParamErrors> {
        check_all([
            Rule::new(
                "lateral_m",
                self.lateral_m,
                self.lateral_m > 0.0 && self.lateral_m <= 10.0,
                "in (0, 10]",
            ),
            Rule::new(
                "lateral_rel",
                self.lateral_rel,
                (0.0..=1.0).contains(&self.lateral_rel),
                "in [0, 1]",
            ),
            Rule::new(
                "angle_deg",
                self.angle_deg,
                self.angle_deg > 0.0 && self.angle_deg <= 45.0,
                "in (0, 45]",
            ),
            Rule::new(
                "max_gap_m",
                self.max_gap_m,
                (0.0..=100.0).contains(&self.max_gap_m),
                "in [0, 100]",
            ),
            Rule::new(
                "min_observations",
                f64::from(self.min_observations),
                self.min_observations >= 1,
                "at least 1",
            ),
        ])?;
        let Some(g) = self.gate else {
            return Ok(());
        };
        check_all([
            Rule::new(
                "gate.direction_deg",
                g.direction_deg,
                g.direction_deg > 0.0 && g.direction_deg <= 90.0,
                "in (0, 90]",
            ),
            Rule::new(
                "gate.position_m",
                g.position_m,
                g.position_m > 0.0 && g.position_m <= 100.0,
                "in (0, 100]",
            ),
            Rule::new(
                "gate.position_rel",
                g.position_rel,
                (0.0..=1.0).contains(&g.position_rel),
                "in [0, 1]",
            ),
            Rule::new(
                "gate.confidence",
                g.confidence,
                g.confidence > 0.0 && g.confidence < 1.0,
                "in (0, 1)",
            ),
        ])
    }
}

/// One segment of the map, world frame.
#[derive(Debug, Clone, PartialEq)]
pub struct MapSegment {
    pub start: Point3<f64>,
    pub end: Point3<f64>,
    /// Number of distinct captures supporting it (fragments of one capture count once).
    pub observations: u32,
    /// Their ids, sorted, unique.
    pub captures: Vec<u32>,
    /// Covariance of (start, end), metres², world frame: across the line, the fused line's
    /// (its observations' information added up, poses' uncertainty included); along it, where
    /// the observations' ends lie.
    pub covariance: Matrix6<f64>,
    /// 1σ of the direction (degrees) and of the midpoint across the line (metres): the
    /// largest of each, as a 3D segment of a Match reports them.
    pub direction_sigma_deg: f64,
    pub position_sigma_m: f64,
    /// It misses the map's gate ([`FuseParams::gate`]) and is there only because the gate
    /// asked to include uncertain segments.
    pub uncertain: bool,
}

impl MapSegment {
    /// The segment alone.
    pub fn segment(&self) -> Segment3 {
        Segment3 {
            start: self.start,
            end: self.end,
        }
    }

    pub fn length(&self) -> f64 {
        (self.end - self.start).norm()
    }
}
