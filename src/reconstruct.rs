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

/// One image line seen as several collinear pieces: the total-least-squares line through
/// their endpoints (each weighted by its piece's length), cut to the pieces' hull, directed
/// like the first piece.
pub fn merge_pieces(pieces: &[(Point2<f64>, Point2<f64>)]) -> Option<(Point2<f64>, Point2<f64>)> {
    let (&(first_a, first_b), _) = pieces.split_first()?;
    if pieces.len() == 1 {
        return Some((first_a, first_b));
    }
    let mut weight = 0.0;
    let mut centroid = nalgebra::Vector2::zeros();
    for &(a, b) in pieces {
        let w = (b - a).norm();
        weight += 2.0 * w;
        centroid += (a.coords + b.coords) * w;
    }
    if weight <= 0.0 {
        return None;
    }
    centroid /= weight;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for &(a, b) in pieces {
        let w = (b - a).norm();
        for p in [a, b] {
            let d = p.coords - centroid;
            sxx += w * d.x * d.x;
            sxy += w * d.x * d.y;
            syy += w * d.y * d.y;
        }
    }
    // Principal axis of the 2x2 scatter.
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let mut dir = nalgebra::Vector2::new(angle.cos(), angle.sin());
    if dir.dot(&(first_b - first_a)) < 0.0 {
        dir = -dir;
    }
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for &(a, b) in pieces {
        for p in [a, b] {
            let t = (p.coords - centroid).dot(&dir);
            lo = lo.min(t);
            hi = hi.max(t);
        }
    }
    Some((
        Point2::from(centroid + dir * lo),
        Point2::from(centroid + dir * hi),
    ))
}

/// Triangulates a line seen in pieces in each view (fragments matched to one another).
pub fn reconstruct_pieces(
    rig: &Rig,
    pieces: [&[(Point2<f64>, Point2<f64>)]; 3],
) -> Option<Line3Fit> {
    let cameras = [rig.camera(0), rig.camera(1), rig.camera(2)];
    let merged = [
        merge_pieces(pieces[0])?,
        merge_pieces(pieces[1])?,
        merge_pieces(pieces[2])?,
    ];
    triangulate_line(&cameras, &merged)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn merged_pieces_span_the_hull_on_the_common_line() {
        let p = |x: f64, y: f64| Point2::new(x, y);
        let pieces = [(p(0.0, 1.0), p(10.0, 1.0)), (p(20.0, 1.0), p(40.0, 1.0))];
        let (a, b) = merge_pieces(&pieces).unwrap();
        assert!((a - p(0.0, 1.0)).norm() < 1e-9 && (b - p(40.0, 1.0)).norm() < 1e-9);
        let reversed = [(p(10.0, 5.0), p(0.0, 5.0)), (p(40.0, 5.0), p(20.0, 5.0))];
        let (a, b) = merge_pieces(&reversed).unwrap();
        assert!(a.x > b.x, "keeps the first piece's direction");
    }
}
