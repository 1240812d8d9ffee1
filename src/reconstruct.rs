//! Reconstruction (DESIGN §2.6): each matched triplet becomes a 3D segment in the rig frame,
//! the least-squares intersection of the three back-projection planes, cut to the part all
//! three image segments cover, with its reprojection residual.

use nalgebra::Point2;
use rayon::prelude::*;

use crate::geometry::{triangulate_line, Line3Fit, Rig};

/// Triplets per rayon task.
const TRIPLETS_PER_TASK: usize = 64;

/// Triangulates each triplet of (undistorted, image-pixel) segments; `None` where the line is
/// undetermined or the three segments do not overlap along it.
pub fn reconstruct(
    rig: &Rig,
    segments: [&[(Point2<f64>, Point2<f64>)]; 3],
    triplets: &[[u32; 3]],
) -> Vec<Option<Line3Fit>> {
    let cameras = [rig.camera(0), rig.camera(1), rig.camera(2)];
    triplets
        .par_iter()
        .with_min_len(TRIPLETS_PER_TASK)
        .map(|t| {
            let views = [
                segments[0][t[0] as usize],
                segments[1][t[1] as usize],
                segments[2][t[2] as usize],
            ];
            triangulate_line(&cameras, &views)
        })
        .collect()
}
