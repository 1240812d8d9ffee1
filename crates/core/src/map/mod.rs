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

pub mod export;
mod fuse;
pub mod poses;
pub mod register;
#[cfg(test)]
mod tests;

use nalgebra::{Isometry3, Point3};

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
}

impl Default for FuseParams {
    /// Tuned on the shared `office` session (`tools/eval_map.py`): 1 cm + 0.5% of range
    /// beat 2 cm + 1% on both error rate and completeness, LSD and image input alike.
    fn default() -> Self {
        FuseParams {
            lateral_m: 0.01,
            lateral_rel: 0.005,
            angle_deg: 3.0,
            max_gap_m: 0.05,
            min_observations: 1,
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
