//! Chains of connected edge points, and the junctions where chains meet.
//!
//! Each point is linked to at most one successor and one predecessor among its 8 neighbours
//! (after Devernay 1995): the successor lies ahead along the edge direction, the predecessor
//! behind it, both with a gradient pointing the same way (within 90°), and the nearest such
//! point wins. A link is made only when it is mutual — `q` is `p`'s best successor *and* `p`
//! is `q`'s best predecessor — so chains never branch. Walking a chain, the edge direction is
//! the gradient turned by −90° on screen: the brighter side is on the walker's left, which
//! is DESIGN §1's segment orientation, so chains come out oriented by contrast, and a chain
//! ends where the contrast flips.
//!
//! Where a chain's end wanted to link to a point already taken by another chain, the two meet
//! at a **junction**; it is recorded, as the graph the matcher's validation uses.

use super::edges::EdgeMap;

const NONE: u32 = u32::MAX;
/// From this many points up, each point's best neighbours are looked up on the pool's
/// threads, in tasks of [`POINTS_PER_TASK`]; below it the lookups cost less than collecting
/// them in order from several tasks (docs/PERFORMANCE.md).
const PARALLEL_POINTS: usize = 1 << 16;
const POINTS_PER_TASK: usize = 1 << 14;

/// A chain: indices into [`EdgeMap::points`], in walking order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Chain {
    pub points: Vec<u32>,
    /// True when the last point links back to the first.
    pub closed: bool,
}

/// The end of chain `chain` (its first point when `at_start`, else its last) meets chain
/// `other` at its point `other_position` (index into `other`'s points).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Junction {
    pub chain: u32,
    pub at_start: bool,
    pub other: u32,
    pub other_position: u32,
}

/// The chains of an edge map and their junctions.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Chains {
    pub chains: Vec<Chain>,
    pub junctions: Vec<Junction>,
}

/// Best neighbours of point `p` ahead of it and behind it along its edge direction.
#[inline]
fn best_neighbours(map: &EdgeMap, p: usize) -> (u32, u32) {
    let a = &map.points[p];
    // Edge direction: the gradient turned so that the bright side is on the left (v down).
    let (tu, tv) = (-a.gv, a.gu);
    let (x, y) = (a.x as usize, a.y as usize);
    let (mut ahead, mut behind) = ((NONE, f32::INFINITY), (NONE, f32::INFINITY));
    let consider = |q: u32| {
        if q == NONE {
            return;
        }
        let b = &map.points[q as usize];
        if a.gu * b.gu + a.gv * b.gv <= 0.0 {
            return;
        }
        let (du, dv) = (b.u - a.u, b.v - a.v);
        let along = du * tu + dv * tv;
        let d2 = du * du + dv * dv;
        if along > 0.0 && d2 < ahead.1 {
            ahead = (q, d2);
        } else if along < 0.0 && d2 < behind.1 {
            behind = (q, d2);
        }
    };
    // In row-major order, which breaks ties between equally near neighbours.
    map.for_each_neighbour(x, y, consider);
    (ahead.0, behind.0)
}

/// Links the points of `map` into chains (see the module doc). Chains come in the order of
/// their first point's pixel (row-major), so the result is deterministic.
pub fn link(map: &EdgeMap) -> Chains {
    let n = map.points.len();
    let (forward, backward): (Vec<u32>, Vec<u32>) =
        if n >= PARALLEL_POINTS && rayon::current_num_threads() > 1 {
            use rayon::prelude::*;
            (0..n)
                .into_par_iter()
                .with_min_len(POINTS_PER_TASK)
                .map(|p| best_neighbours(map, p))
                .unzip()
        } else {
            (0..n).map(|p| best_neighbours(map, p)).unzip()
        };
    let mut next = vec![NONE; n];
    let mut previous = vec![NONE; n];
    for p in 0..n {
        let q = forward[p];
        if q != NONE && backward[q as usize] == p as u32 {
            next[p] = q;
            previous[q as usize] = p as u32;
        }
    }
    // Freed before the chains are built (together with the chains they were the peak of a
    // noisy image); the junctions ask again at the chains' ends.
    drop((forward, backward));

    let mut chain_of = vec![NONE; n];
    let mut position = vec![0u32; n];
    let mut chains = Vec::new();
    let mut walk = |start: usize, chains: &mut Vec<Chain>, chain_of: &mut Vec<u32>| {
        let id = chains.len() as u32;
        let mut points = Vec::new();
        let mut p = start as u32;
        let mut closed = false;
        loop {
            chain_of[p as usize] = id;
            position[p as usize] = points.len() as u32;
            points.push(p);
            let q = next[p as usize];
            if q == NONE {
                break;
            }
            if chain_of[q as usize] != NONE {
                closed = q as usize == start;
                break;
            }
            p = q;
        }
        chains.push(Chain { points, closed });
    };
    // Open chains start at points without a predecessor; what is left are loops.
    for (p, &before) in previous.iter().enumerate() {
        if before == NONE {
            walk(p, &mut chains, &mut chain_of);
        }
    }
    for p in 0..n {
        if chain_of[p] == NONE {
            walk(p, &mut chains, &mut chain_of);
        }
    }
    debug_assert!(chains.iter().all(|c| !c.points.is_empty()));

    // Junctions: an open end whose wanted link went to another chain.
    let mut junctions = Vec::new();
    for (id, chain) in chains.iter().enumerate() {
        if chain.closed {
            continue;
        }
        let (first, last) = (chain.points[0], chain.points[chain.points.len() - 1]);
        let ends = [
            (true, best_neighbours(map, first as usize).1),
            (false, best_neighbours(map, last as usize).0),
        ];
        for (at_start, wanted) in ends {
            if wanted == NONE || chain_of[wanted as usize] == id as u32 {
                continue;
            }
            junctions.push(Junction {
                chain: id as u32,
                at_start,
                other: chain_of[wanted as usize],
                other_position: position[wanted as usize],
            });
        }
    }
    Chains { chains, junctions }
}

#[cfg(test)]
mod tests {
    use super::super::edges::{pixel_of, EdgePoint, NO_POINT};
    use super::*;

    fn map_of(width: usize, height: usize, points: &[(f32, f32, f32, f32)]) -> EdgeMap {
        let mut map = EdgeMap {
            width,
            height,
            points: Vec::new(),
            index: vec![NO_POINT; width * height],
        };
        for &(u, v, gu, gv) in points {
            let p = EdgePoint {
                x: u.round() as u32,
                y: v.round() as u32,
                u,
                v,
                gu,
                gv,
                magnitude: (gu * gu + gv * gv).sqrt(),
            };
            map.index[pixel_of(&p, width)] = map.points.len() as u32;
            map.points.push(p);
        }
        map
    }

    /// A map large enough to look its neighbours up on several threads links the same
    /// chains and junctions as on one.
    #[test]
    fn a_large_map_links_the_same_on_any_pool() {
        let (w, h) = (400usize, 300usize);
        let mut rng = trinocular_synth::Rng::new(0x9e37_79b9_7f4a_7c15);
        let mut points = Vec::new();
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                if rng.below(4) != 0 {
                    let angle = rng.range(0.0, std::f64::consts::TAU) as f32;
                    points.push((
                        x as f32 + rng.symmetric(0.2) as f32,
                        y as f32 + rng.symmetric(0.2) as f32,
                        5.0 * angle.cos(),
                        5.0 * angle.sin(),
                    ));
                }
            }
        }
        let map = map_of(w, h, &points);
        assert!(map.points.len() >= PARALLEL_POINTS);
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| link(&map))
        };
        let one = on(1);
        assert!(one.chains.len() > 1000 && !one.junctions.is_empty());
        assert_eq!(on(2), one);
        assert_eq!(on(3), one);
    }

    #[test]
    fn a_horizontal_edge_bright_above_chains_left_to_right() {
        // Gradient pointing up (−v): bright above, so the walker goes towards +u.
        let pts: Vec<_> = (1..8).rev().map(|x| (x as f32, 3.0, 0.0, -5.0)).collect();
        let chains = link(&map_of(10, 6, &pts));
        assert_eq!(chains.chains.len(), 1);
        let c = &chains.chains[0];
        assert!(!c.closed);
        let map = map_of(10, 6, &pts);
        let us: Vec<f32> = c.points.iter().map(|&i| map.points[i as usize].u).collect();
        assert_eq!(us, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]);
    }

    #[test]
    fn contrast_flip_breaks_the_chain() {
        let pts: Vec<_> = (1..9)
            .map(|x| (x as f32, 3.0, 0.0, if x < 5 { -5.0 } else { 5.0 }))
            .collect();
        let chains = link(&map_of(10, 6, &pts));
        assert_eq!(chains.chains.len(), 2);
    }

    #[test]
    fn a_square_outline_is_one_closed_chain() {
        // Dark square [3, 7]² on a bright background: gradients point outwards.
        let mut pts = Vec::new();
        for i in 3..=7 {
            let f = i as f32;
            pts.push((f, 3.0, 0.0, -5.0));
            pts.push((f, 7.0, 0.0, 5.0));
            if i > 3 && i < 7 {
                pts.push((3.0, f, -5.0, 0.0));
                pts.push((7.0, f, 5.0, 0.0));
            }
        }
        // Corners: diagonal gradients.
        for (u, v, gu, gv) in &mut pts {
            if (*u == 3.0 || *u == 7.0) && (*v == 3.0 || *v == 7.0) {
                *gu = if *u == 3.0 { -3.5 } else { 3.5 };
                *gv = if *v == 3.0 { -3.5 } else { 3.5 };
            }
        }
        let chains = link(&map_of(11, 11, &pts));
        assert_eq!(chains.chains.len(), 1, "{chains:?}");
        assert!(chains.chains[0].closed);
        assert_eq!(chains.chains[0].points.len(), 16);
    }

    #[test]
    fn a_t_junction_is_recorded() {
        // A horizontal edge along v = 5 (bright above), and a vertical one along u = 5 from
        // v = 1 down to v = 4, ending at the horizontal edge, bright on its right.
        let mut pts: Vec<_> = (1..10).map(|x| (x as f32, 5.0, 0.0, -5.0)).collect();
        pts.extend((1..5).map(|y| (5.0, y as f32, 3.0, -1.0)));
        let chains = link(&map_of(11, 8, &pts));
        assert_eq!(chains.chains.len(), 2, "{chains:?}");
        assert_eq!(chains.junctions.len(), 1, "{chains:?}");
        let j = chains.junctions[0];
        assert!(!j.at_start);
        assert_eq!(chains.chains[j.other as usize].points.len(), 9);
    }
}
