//! A session as a robot builds it, one capture at a time: where the new capture goes, and
//! what it says about the captures before it.
//!
//! [`add_capture`] does two things with a new capture's 3D segments:
//! 1. **Registers it to the map** ([`register`]): the captures the graph of the session so
//!    far places well (the first, which anchors the map, and those tied to it by edges, each
//!    as uncertain as its pose), nearest first. That is the pose AddCapture answers, and the
//!    centre the pairs below start from.
//! 2. **Registers it to each earlier capture it overlaps** ([`register_pair`]), from the two
//!    placed poses but with their *odometry's* spread: each pair that registers is one edge
//!    of the session's pose graph, a relative pose with the information of the two captures'
//!    segments alone.
//!
//! The map's poses are then the graph's solution ([`super::poses::optimise`]): every
//! capture's odometry prior and every stored edge, solved together, so where the session
//! comes round to its start the loop closes — with no registration redone when the map is
//! asked for. The edges are found as the captures arrive, so the map is a function of the
//! stored captures and their edges (replicas reading one store agree); the same captures
//! sent in another order may find slightly different edges.

use nalgebra::Matrix6;

use super::poses::{register_pair, RelativePose};
use super::register::{register, Measured, PosePrior, RegisterParams, Registration};

/// A capture already in the session.
#[derive(Debug, Clone, Copy)]
pub struct Placed<'a> {
    /// Where the robot said the rig was, with its odometry's covariance.
    pub prior: PosePrior,
    /// Its 3D segments, rig frame, each with its covariance.
    pub segments: &'a [Measured],
}

/// What [`add_capture`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct Added {
    /// The capture registered to the map.
    pub registration: Registration,
    /// Its edges to earlier captures: `from` is the new capture's index (the number of
    /// captures placed before it), `to` an earlier one's.
    pub edges: Vec<RelativePose>,
}

/// Tunables of [`add_capture`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SessionParams {
    pub register: RegisterParams,
    /// Earlier captures a new one is registered to, as a map and pair by pair: the nearest
    /// to its pose, no farther than `reach_m` (a robot's local map; the whole session is the
    /// map's).
    pub map_captures: usize,
    pub pair_captures: usize,
    pub reach_m: f64,
}

impl Default for SessionParams {
    fn default() -> Self {
        SessionParams {
            register: RegisterParams::default(),
            map_captures: 64,
            pair_captures: 12,
            reach_m: 10.0,
        }
    }
}

/// Places a new capture (`segments`, rig frame; `prior`, the robot's pose and its
/// covariance) in a session whose earlier captures are `placed`, in capture order, with the
/// pose-graph `edges` they found: see the module documentation.
///
/// The earlier captures stand where the graph puts them now ([`solve_poses`]), not where
/// registration left each when it arrived: a capture that found nothing in common when it
/// came may since have been tied to its neighbours, and it then takes part in the map.
pub fn add_capture(
    placed: &[Placed],
    edges: &[RelativePose],
    prior: &PosePrior,
    segments: &[Measured],
    params: &SessionParams,
) -> Added {
    let current = solve_poses(placed, edges);
    let here = prior.rig_to_world.translation.vector;
    let mut near: Vec<(f64, usize)> = current
        .iter()
        .enumerate()
        .map(|(i, p)| ((p.rig_to_world.translation.vector - here).norm(), i))
        .filter(|(d, _)| *d <= params.reach_m)
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));

    // The map: the captures the graph places well, each segment as uncertain as its
    // capture's pose. A capture known only by its odometry is left out: its pose error is
    // shared by all its segments, and many segments each given that error's spread as if
    // independent would let wrong pairs in by the dozen.
    let references: Vec<Measured> = near
        .iter()
        .map(|&(_, i)| (i, &current[i]))
        .filter(|(_, pose)| well_placed(pose))
        .take(params.map_captures)
        .flat_map(|(i, pose)| {
            placed[i]
                .segments
                .iter()
                .map(move |m| m.transformed_with(&pose.rig_to_world, &pose.covariance))
        })
        .collect();
    let registration = register(&references, segments, prior, &params.register);

    // The pairs start from where registration put the new capture, with the spread its
    // odometry gives it, against each earlier capture where the graph puts it, with the
    // spread of that capture's own odometry.
    let from = PosePrior {
        rig_to_world: registration.rig_to_world,
        covariance: prior.covariance,
    };
    let index = placed.len();
    let edges = near
        .iter()
        .take(params.pair_captures)
        .filter_map(|&(_, to)| {
            let at = PosePrior {
                rig_to_world: current[to].rig_to_world,
                covariance: placed[to].prior.covariance,
            };
            let (pose, information, inliers) =
                register_pair(segments, placed[to].segments, &from, &at, &params.register)?;
            Some(RelativePose {
                from: index,
                to,
                pose,
                information,
                inliers,
            })
        })
        .collect();
    Added {
        registration,
        edges,
    }
}

/// Largest spread of a capture's pose for its segments to be part of the map a new capture
/// is registered to: 0.5° of rotation and 3 cm of translation (1σ, the largest axis). Beyond
/// it the capture is known by little more than its odometry.
const WELL_PLACED_RAD: f64 = 0.0087;
const WELL_PLACED_M: f64 = 0.03;

fn well_placed(pose: &PosePrior) -> bool {
    let c = &pose.covariance;
    let largest = |k: usize| (k..k + 3).map(|i| c[(i, i)]).fold(0.0, f64::max).sqrt();
    largest(0) <= WELL_PLACED_RAD && largest(3) <= WELL_PLACED_M
}

/// The priors the pose graph starts from: each capture's odometry, but the first capture's
/// pose exact — it anchors the map, as a robot's start anchors its odometry.
pub fn graph_priors(placed: &[Placed]) -> Vec<PosePrior> {
    placed
        .iter()
        .enumerate()
        .map(|(i, p)| {
            if i == 0 {
                PosePrior {
                    rig_to_world: p.prior.rig_to_world,
                    covariance: Matrix6::identity() * ANCHOR_VARIANCE,
                }
            } else {
                p.prior
            }
        })
        .collect()
}

/// The anchor's variance in the graph (radians², metres²): exact for every purpose, yet
/// invertible.
const ANCHOR_VARIANCE: f64 = 1e-12;

/// χ² with 6 degrees of freedom at 0.999: an edge the solved poses disagree with by more than
/// this is not believed.
const EDGE_GATE: f64 = 22.458;

/// The session's poses: every capture's odometry prior and every edge, solved together.
///
/// An edge can be wrong with confidence — two captures of a repetitive scene registered one
/// step apart, the segments agreeing with each other on a shift of 20 cm — and one such
/// edge pulls a whole stretch of the session off. So the solution is checked against every
/// edge: while the worst disagrees beyond [`EDGE_GATE`] it is dropped and the poses solved
/// again (the other edges and the priors outvote it; an edge alone with its captures'
/// priors is outvoted by them).
pub fn solve_poses(placed: &[Placed], edges: &[RelativePose]) -> Vec<PosePrior> {
    let priors = graph_priors(placed);
    let mut edges: Vec<RelativePose> = edges
        .iter()
        .filter(|e| e.from < placed.len() && e.to < placed.len() && e.from != e.to)
        .copied()
        .collect();
    loop {
        let solved = super::poses::optimise(&priors, &edges);
        let worst = edges
            .iter()
            .map(|e| super::poses::edge_chi2(&solved, e))
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            Some((k, chi2)) if chi2 > EDGE_GATE => {
                edges.remove(k);
            }
            _ => return solved,
        }
    }
}
