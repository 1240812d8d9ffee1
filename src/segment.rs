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
}

impl Segment2 {
    pub fn new(start: Point2<f64>, end: Point2<f64>) -> Segment2 {
        Segment2 {
            start,
            end,
            gradient: None,
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
