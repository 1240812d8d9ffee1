//! Reconstruction (DESIGN §2.6): each matched triplet becomes a 3D segment in the rig frame —
//! the maximum-likelihood line of its three image lines, weighted by their noise, with its
//! covariance, its χ² and the extent every view saw
//! ([`crate::geometry::estimate_line`]). Collinear fragments that validation accepted together
//! (triplets sharing a segment in some view) are grouped and estimated as one line from all
//! their pieces ([`fragment_groups`], [`reconstruct_fragments`]).

use rayon::prelude::*;
use rustc_hash::FxHashMap;

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

/// Groups triplets that share a segment in some view (validation accepts such triplets
/// together only as collinear fragments of one line). Groups hold positions in `triplets`,
/// come in order of their first member, members in input order.
pub fn fragment_groups(triplets: &[[u32; 3]]) -> Vec<Vec<usize>> {
    let mut parent: Vec<usize> = (0..triplets.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let mut owner: [FxHashMap<u32, usize>; 3] = Default::default();
    for (k, triplet) in triplets.iter().enumerate() {
        for (v, owner) in owner.iter_mut().enumerate() {
            let segment = triplet[v];
            if let Some(&other) = owner.get(&segment) {
                let (a, b) = (root(&mut parent, k), root(&mut parent, other));
                let (lo, hi) = (a.min(b), a.max(b));
                parent[hi] = lo;
            } else {
                owner.insert(segment, k);
            }
        }
    }
    // A root is its group's first member (unions keep the lower index as the root).
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let mut group_of_root: Vec<usize> = vec![usize::MAX; triplets.len()];
    for k in 0..triplets.len() {
        let r = root(&mut parent, k);
        if group_of_root[r] == usize::MAX {
            group_of_root[r] = groups.len();
            groups.push(Vec::new());
        }
        groups[group_of_root[r]].push(k);
    }
    groups
}

/// Estimates one 3D segment from a group of fragment triplets: each view's distinct segments
/// among them, in index order, are pieces of the same line — longer together, so better
/// determined, than any one triplet.
pub fn reconstruct_fragments(
    rig: &Rig,
    observations: [&[LineObservation]; 3],
    fragments: impl Iterator<Item = [u32; 3]> + Clone,
) -> Option<Line3Estimate> {
    let mut pieces: Vec<LineObservation> = Vec::new();
    for (v, view) in observations.iter().enumerate() {
        let mut ids: Vec<u32> = fragments.clone().map(|t| t[v]).collect();
        ids.sort_unstable();
        ids.dedup();
        pieces.extend(ids.iter().map(|&i| view[i as usize]));
    }
    reconstruct_pieces(rig, &pieces)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triplets_sharing_a_segment_in_any_view_are_one_group_in_input_order() {
        let triplets = [
            [0, 0, 0],
            [1, 1, 1],
            [2, 0, 2], // shares view 2's segment 0 with the first
            [3, 3, 3],
            [4, 4, 1], // shares view 3's segment 1 with the second
            [5, 5, 5],
        ];
        assert_eq!(
            fragment_groups(&triplets),
            vec![vec![0, 2], vec![1, 4], vec![3], vec![5]]
        );
        assert!(fragment_groups(&[]).is_empty());
    }

    #[test]
    fn a_chain_of_shared_segments_joins_groups_that_met_late() {
        // 0 and 1 share nothing; 2 shares with both, so all three are one group.
        let triplets = [[0, 0, 0], [1, 1, 1], [0, 1, 2]];
        assert_eq!(fragment_groups(&triplets), vec![vec![0, 1, 2]]);
    }
}
