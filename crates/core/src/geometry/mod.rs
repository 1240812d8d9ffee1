//! Geometry of the rig: cameras, rectification, transfer between views, 3D lines.
//!
//! Frames, stated once:
//! - **rig**: right-handed, metres, z up; the frame the calibration's `P` map from.
//! - **image**: pixels, `u` right, `v` down, pixel centres at integer coordinates.
//! - **rect**: the rectified frame of [`rectify`]: z is the normal of the plane of the three
//!   optical centres (pointing at the scene), x runs along C1→C2. Rectified *pixels* are
//!   `f*·(x/z, y/z)` with one shared focal length `f*` and principal point 0.

pub mod camera;
pub mod line;
pub mod rectify;

pub use camera::{Camera, CameraError, Distortion, Rig, RigError};
pub use line::{
    across_basis, estimate_line, estimate_line_constrained, estimate_line_through, DirectionOfLine,
    KnownDirection, Line3Estimate, LineObservation, PointOnLine,
};
pub use rectify::{Rectification, RectifyError, RigFrames};

#[cfg(test)]
mod proptests;
