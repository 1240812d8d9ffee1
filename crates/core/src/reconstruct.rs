//! Reconstruction (DESIGN §2.6): each matched triplet becomes a 3D segment in the rig frame —
//! the maximum-likelihood line of its three image lines, weighted by their noise, with its
//! covariance, its χ² and the extent every view saw
//! ([`crate::geometry::estimate_line`]).

use rayon::prelude::*;

use crate::geometry::{estimate_line, Line3Estimate, LineObservation, Rig};

/// Triplets per rayon task.
const TRIPLETS_PER_TASK: usize = 64;
/// How precisely an image segment's end is known along it, pixels: the floor of the 3D
/// endpoints' spread along the line (where a segment stops depends on contrast and occlusion
/// more than on noise, so this is a floor, not a model).
pub const END_SIGMA_PX: f64 = 1.0;

/// Estimates the 3D segment of each triplet of observations (`observations[v]`: view v's
/// segments, undistorted, with their noise); `None` where the line is undetermined or the
/// views share no part of it.
pub fn reconstruct(
    rig: &Rig,
    observations: [&[LineObservation]; 3],
    triplets: &[[u32; 3]],
) -> Vec<Option<Line3Estimate>> {
    let cameras = [rig.camera(0), rig.camera(1), rig.camera(2)];
    triplets
        .par_iter()
        .with_min_len(TRIPLETS_PER_TASK)
        .map(|t| {
            let obs = [
                observations[0][t[0] as usize],
                observations[1][t[1] as usize],
                observations[2][t[2] as usize],
            ];
            estimate_line(&cameras, &obs, END_SIGMA_PX)
        })
        .collect()
}

/// Estimates one 3D segment from a line seen in collinear pieces in each view (fragments
/// matched to one another): every piece is an observation of the same line.
pub fn reconstruct_pieces(rig: &Rig, pieces: &[LineObservation]) -> Option<Line3Estimate> {
    let cameras = [rig.camera(0), rig.camera(1), rig.camera(2)];
    estimate_line(&cameras, pieces, END_SIGMA_PX)
}
