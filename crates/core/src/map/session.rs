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

use nalgebra::{Matrix6, Point3};

use super::compass::{self, Reading};
use super::images::{refine_in_images_until, ImageParams, IndexedViews, Views};
use super::landmarks;
use super::poses::{register_pair, relative_covariance, RelativePose};
use super::register::{register_seen, Measured, PosePrior, RegisterParams, Registration, Sector};
use crate::checkpoint::{never_stopped, Checkpoint, Stopped};

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
    /// to its pose (in position, and in heading at a metre a radian), no farther than
    /// `reach_m` (a robot's local map; the whole session is the map's). On the shared rooms
    /// and the synthetic driving loop, 8 and 4 find every pose as 64 and 12 did, at a third
    /// of the cost; 3 pairs did too.
    pub map_captures: usize,
    pub pair_captures: usize,
    pub reach_m: f64,
    /// How a pair is refined in the new capture's images, when they are given.
    pub images: ImageParams,
    /// Whether the room's directions turn a capture's heading ([`super::compass`]): the
    /// registration's prior, and an edge of the heading alone to the anchor. Off, a session
    /// is placed by its segments in common and its odometry only.
    pub compass: bool,
    /// Whether long horizontal lines a capture continues in earlier captures it shares no
    /// segment with tie its position across them ([`super::landmarks`]).
    pub landmarks: bool,
}

impl Default for SessionParams {
    fn default() -> Self {
        SessionParams {
            register: RegisterParams::default(),
            map_captures: 8,
            pair_captures: 4,
            reach_m: 10.0,
            images: ImageParams::default(),
            compass: true,
            landmarks: true,
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
    never_stopped(add_capture_until(
        placed,
        edges,
        prior,
        segments,
        params,
        Checkpoint::NEVER,
    ))
}

/// [`add_capture`], asking `checkpoint` while the session's poses are solved and between
/// the registrations: [`neighbours_until`], then [`place_until`].
pub fn add_capture_until(
    placed: &[Placed],
    edges: &[RelativePose],
    prior: &PosePrior,
    segments: &[Measured],
    params: &SessionParams,
    checkpoint: Checkpoint,
) -> Result<Added, Stopped> {
    let neighbours = neighbours_until(placed, edges, prior, params, checkpoint)?;
    place_until(
        placed,
        &neighbours,
        prior,
        segments,
        None,
        params,
        checkpoint,
    )
}

/// [`add_capture`] with the capture's image evidence: each registration refined in its
/// images ([`refine_in_images`]).
pub fn add_capture_with_views(
    placed: &[Placed],
    edges: &[RelativePose],
    prior: &PosePrior,
    segments: &[Measured],
    views: &Views,
    params: &SessionParams,
) -> Added {
    never_stopped(
        neighbours_until(placed, edges, prior, params, Checkpoint::NEVER).and_then(|n| {
            place_until(
                placed,
                &n,
                prior,
                segments,
                Some(views),
                params,
                Checkpoint::NEVER,
            )
        }),
    )
}

/// The earlier captures a new one is registered to, chosen from the poses alone — so that a
/// caller holding a long session's captures encoded reads the segments of these few only.
#[derive(Debug, Clone, PartialEq)]
pub struct Neighbours {
    /// Every earlier capture's pose as the session's graph solves it now.
    pub poses: Vec<PosePrior>,
    /// The captures whose segments make the map the new capture is registered to: the
    /// nearest that the graph places well, nearest first, at most `map_captures`.
    pub map: Vec<usize>,
    /// The captures it is registered to pair by pair: the nearest `pair_captures`.
    pub pairs: Vec<usize>,
}

impl Neighbours {
    /// Every capture whose segments [`place_until`] reads, ascending, each once: the map's,
    /// the pairs' and the anchor's (the first capture), whose reading of the room's
    /// directions every later capture's heading is tied to ([`super::compass`]).
    pub fn needed(&self) -> Vec<usize> {
        let anchor = (!self.poses.is_empty()).then_some(0);
        let mut all: Vec<usize> = self
            .map
            .iter()
            .chain(&self.pairs)
            .chain(&anchor)
            .copied()
            .collect();
        all.sort_unstable();
        all.dedup();
        all
    }
}

/// Solves the session's poses and chooses the captures a capture at `prior` is registered
/// to (see [`Neighbours`]). Reads the captures' priors only, never their segments.
pub fn neighbours_until(
    placed: &[Placed],
    edges: &[RelativePose],
    prior: &PosePrior,
    params: &SessionParams,
    checkpoint: Checkpoint,
) -> Result<Neighbours, Stopped> {
    let poses = solve_poses_until(placed, edges, checkpoint)?;
    let here = prior.rig_to_world;
    // Nearest in position and in heading: a capture shares what it sees with those that
    // stood close and looked the same way, not with one that stood there facing away.
    let mut near: Vec<(f64, usize)> = poses
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let apart = (p.rig_to_world.translation.vector - here.translation.vector).norm();
            let turned = (p.rig_to_world.rotation * here.rotation.inverse()).angle();
            (apart <= params.reach_m).then_some((apart + TURN_AS_DISTANCE_M * turned, i))
        })
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    // The map: the captures the graph places well. A capture known only by its odometry is
    // left out: its pose error is shared by all its segments, and many segments each given
    // that error's spread as if independent would let wrong pairs in by the dozen.
    let map = near
        .iter()
        .map(|&(_, i)| i)
        .filter(|&i| well_placed(&poses[i]))
        .take(params.map_captures)
        .collect();
    let pairs = near
        .iter()
        .map(|&(_, i)| i)
        .take(params.pair_captures)
        .collect();
    Ok(Neighbours { poses, map, pairs })
}

/// Registers a new capture (`segments`, rig frame; `prior`) to its `neighbours`' segments in
/// `placed` as a map, then to each of its pair neighbours as an edge of the pose graph.
/// Reads the segments of [`Neighbours::needed`] only.
pub fn place_until(
    placed: &[Placed],
    neighbours: &Neighbours,
    prior: &PosePrior,
    segments: &[Measured],
    views: Option<&Views>,
    params: &SessionParams,
    checkpoint: Checkpoint,
) -> Result<Added, Stopped> {
    let current = &neighbours.poses;
    // The map's segments, each as uncertain as its capture's pose.
    let mut references: Vec<Measured> = Vec::new();
    // Where the map's captures looked; one that saw all round sees everything.
    let mut seen_from: Option<Vec<Sector>> = Some(Vec::new());
    for &i in &neighbours.map {
        let pose = &current[i];
        let moved: Vec<Measured> = placed[i]
            .segments
            .iter()
            .map(|m| m.transformed_with(&pose.rig_to_world, &pose.covariance))
            .collect();
        if moved.is_empty() {
            continue;
        }
        let sector = Sector::of(Point3::from(pose.rig_to_world.translation.vector), &moved);
        seen_from = seen_from.zip(sector).map(|(mut all, s)| {
            all.push(s);
            all
        });
        references.extend(moved);
    }
    let seen_from = seen_from.unwrap_or_default();
    // The heading the room's directions give the capture against the map's captures: the
    // registration then starts from it and holds it as firmly as the two readings allow.
    let mut readings: Vec<Option<Reading>> = vec![None; placed.len()];
    if params.compass {
        for i in neighbours
            .needed()
            .into_iter()
            .filter(|&i| i < placed.len())
        {
            readings[i] = compass::reading(placed[i].segments, &current[i].rig_to_world.rotation);
        }
    }
    // The map's reading: the anchor's and the map's captures', those that agree.
    let candidates: Vec<usize> = std::iter::once(0)
        .chain(neighbours.map.iter().copied().filter(|&i| i != 0))
        .filter(|&i| i < placed.len() && readings[i].is_some())
        .collect();
    let with_heading_variance = |i: usize| readings[i].map(|r| (r, current[i].covariance[(2, 2)]));
    let consensus = compass::consensus(
        &candidates
            .iter()
            .filter_map(|&i| with_heading_variance(i))
            .collect::<Vec<_>>(),
    );
    let map_reading = consensus.as_ref().map(|(r, _)| *r);
    // A capture's reading may stand for the map's when it agrees with the consensus.
    let trusted = |i: usize| -> Option<(Reading, PosePrior)> {
        let (map, _) = consensus.as_ref()?;
        let own = with_heading_variance(i)?;
        let d = compass::quarter_wrap(own.0.angle - map.angle);
        let spread = own.0.sigma * own.0.sigma + own.1 + map.sigma * map.sigma;
        (d * d <= compass::READING_GATE * spread).then_some((own.0, current[i]))
    };
    let own = params
        .compass
        .then(|| compass::reading(segments, &prior.rig_to_world.rotation))
        .flatten();
    let guided = match (own, map_reading) {
        (Some(own), Some(map)) => {
            let (turn, variance) = compass::relative_heading(&own, &map);
            compass::with_heading(prior, turn, variance)
        }
        _ => *prior,
    };
    checkpoint.before("registration")?;
    let mut registration =
        register_seen(&references, &seen_from, segments, &guided, &params.register);
    // How far it moved is told from the robot's pose, not from the compass's turn of it.
    registration.rotation_change_deg = (registration.rig_to_world.rotation
        * prior.rig_to_world.rotation.inverse())
    .angle()
    .to_degrees();
    registration.translation_change_m = (registration.rig_to_world.translation.vector
        - prior.rig_to_world.translation.vector)
        .norm();

    // The pairs start from where registration put the new capture, with the spread its
    // odometry gives it, against each earlier capture where the graph puts it, with the
    // spread of that capture's own odometry.
    let from = PosePrior {
        rig_to_world: registration.rig_to_world,
        covariance: prior.covariance,
    };
    let index = placed.len();
    let mut edges = Vec::new();
    let views = views.map(|views| IndexedViews::new(views, &params.images));
    for &to in &neighbours.pairs {
        checkpoint.before("registration")?;
        let at = PosePrior {
            rig_to_world: current[to].rig_to_world,
            covariance: placed[to].prior.covariance,
        };
        let mut found = register_pair(segments, placed[to].segments, &from, &at, &params.register);
        if let Some(views) = &views {
            let predicted = at.rig_to_world.inverse() * from.rig_to_world;
            let relative = PosePrior {
                rig_to_world: predicted,
                covariance: relative_covariance(&from, &at),
            };
            let mut starts: Vec<_> = found.iter().map(|f| f.0).collect();
            starts.push(predicted);
            if let Some(fit) = refine_in_images_until(
                placed[to].segments,
                views,
                &starts,
                &relative,
                &params.images,
                checkpoint,
            )? {
                found = Some((fit.pose, fit.information, fit.references));
            }
        }
        if let Some((pose, information, inliers)) = found {
            edges.push(RelativePose {
                from: index,
                to,
                pose,
                information,
                inliers,
            });
        }
    }
    // The long lines it continues in captures it shares no segment with: its position across
    // them ([`super::landmarks`]), against the anchor's and the map's captures.
    if params.landmarks {
        checkpoint.before("registration")?;
        let tied: Vec<usize> = edges.iter().map(|e| e.to).collect();
        let mut near: Vec<usize> = std::iter::once(0)
            .chain(neighbours.map.iter().copied())
            .filter(|&j| j < placed.len())
            .collect();
        near.sort_unstable();
        near.dedup();
        let candidates: Vec<(usize, &[Measured], PosePrior)> = near
            .into_iter()
            .map(|j| (j, placed[j].segments, current[j]))
            .collect();
        let placed_here = PosePrior {
            rig_to_world: registration.rig_to_world,
            covariance: registration.covariance,
        };
        edges.extend(landmarks::line_edges(
            index,
            segments,
            &placed_here,
            &candidates,
            &tied,
        ));
    }
    // One edge of the heading alone, to the anchor when it reads the room's directions (else
    // to the nearest capture that does, one the graph places well first): it ties a capture
    // that shares no segment with its neighbours to the session all the same, and, tied to
    // the anchor rather than along a chain of neighbours, its error does not add up along the
    // robot's path. An edge to the anchor costs the pose graph nothing: the anchor does not
    // move ([`super::poses::optimise`]).
    let target = [0]
        .iter()
        .chain(&neighbours.map)
        .chain(&neighbours.pairs)
        .filter(|&&j| j < placed.len())
        .find_map(|&j| trusted(j).map(|t| (j, t)));
    if let Some((to, other)) = target {
        edges.extend(heading_edge(index, segments, &registration, to, &other));
    }
    Ok(Added {
        registration,
        edges,
    })
}

/// The edge of the heading alone from capture `from` (its `segments`, placed by
/// `registration`) to capture `to` (its reading and its pose in the session), or `None` when
/// `from` reads no direction or one its pose cannot have: a reading taken from a desk set
/// askew that fills the view would be dropped by the graph, but only after it had pulled.
fn heading_edge(
    from: usize,
    segments: &[Measured],
    registration: &Registration,
    to: usize,
    (other, at): &(Reading, PosePrior),
) -> Option<RelativePose> {
    let own = compass::reading(segments, &registration.rig_to_world.rotation)?;
    let (turn, variance) = compass::relative_heading(&own, other);
    let spread = variance + registration.covariance[(2, 2)] + at.covariance[(2, 2)];
    if turn * turn > compass::READING_GATE * spread {
        return None;
    }
    let (pose, information) =
        compass::heading_edge(&registration.rig_to_world, &at.rig_to_world, turn, variance);
    Some(RelativePose {
        from,
        to,
        pose,
        information,
        inliers: own.segments as u32,
    })
}

/// How far a turn of one radian takes two captures' views apart, for choosing the nearest
/// (metres): about the depth of a room's walls.
const TURN_AS_DISTANCE_M: f64 = 1.0;

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

/// The most work a session's pose graph may take to solve ([`graph_work`]): 2²³ (8.4 million)
/// products of 6×6 blocks a factorisation, about 2 s of a whole solve on one core. A robot
/// mowing a hall in rows of 40 captures, each row tied to the one before, is 4.0 million at
/// 2,000 captures and solves in 0.83 s (`cargo bench --bench map -- pose_graph`); a square
/// hall mown in 100 rows of 100 is 77 million, and wider graphs take minutes and gigabytes.
pub const MAX_GRAPH_WORK: u64 = 1 << 23;

/// The work of solving the pose graph of `captures` tied by `edges`, in products of 6×6
/// blocks a step, from the edges alone (see [`MAX_GRAPH_WORK`]).
pub fn graph_work(captures: usize, edges: &[RelativePose]) -> u64 {
    // Edges to the anchor do not widen the band: it does not move.
    let links: Vec<(usize, usize)> = edges
        .iter()
        .filter(|e| e.from != 0 && e.to != 0)
        .map(|e| (e.from, e.to))
        .collect();
    super::envelope::ordered_work(captures, &links)
}

/// The session's poses: every capture's odometry prior and every edge, solved together.
///
/// An edge can be wrong with confidence — two captures of a repetitive scene registered one
/// step apart, the segments agreeing with each other on a shift of 20 cm — and one such
/// edge pulls a whole stretch of the session off. So the solution is checked against every
/// edge: while the worst disagrees beyond [`EDGE_GATE`] it is dropped and the poses solved
/// again (the other edges and the priors outvote it; an edge alone with its captures'
/// priors is outvoted by them).
pub fn solve_poses(placed: &[Placed], edges: &[RelativePose]) -> Vec<PosePrior> {
    never_stopped(solve_poses_until(placed, edges, Checkpoint::NEVER))
}

/// [`solve_poses`], asking `checkpoint` within each solve.
pub fn solve_poses_until(
    placed: &[Placed],
    edges: &[RelativePose],
    checkpoint: Checkpoint,
) -> Result<Vec<PosePrior>, Stopped> {
    let priors = graph_priors(placed);
    let mut edges: Vec<RelativePose> = edges
        .iter()
        .filter(|e| e.from < placed.len() && e.to < placed.len() && e.from != e.to)
        .copied()
        .collect();
    let mut start: Option<Vec<nalgebra::Isometry3<f64>>> = None;
    loop {
        let mut solved =
            super::poses::optimise_until(&priors, &edges, start.as_deref(), checkpoint)?;
        // The anchor does not move; its tiny variance only keeps the system invertible.
        if let (Some(first), Some(anchor)) = (solved.first_mut(), priors.first()) {
            first.rig_to_world = anchor.rig_to_world;
        }
        let worst = edges
            .iter()
            .map(|e| super::poses::edge_chi2(&solved, e))
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            Some((k, chi2)) if chi2 > EDGE_GATE => {
                edges.remove(k);
                start = Some(solved.iter().map(|p| p.rig_to_world).collect());
            }
            _ => return Ok(solved),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::RegistrationStatus;
    use nalgebra::{Isometry3, Vector3};

    /// A box room about the origin, 5 x 6 x 2.4 m, with shelves on three walls: every edge
    /// with 3 mm of isotropic noise (covariance only; the edges are exact).
    fn room() -> Vec<Measured> {
        crate::map::test_room::box_room(0.003, true)
    }

    fn pose(x: f64, y: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::new(Vector3::new(x, y, 1.2), Vector3::z() * yaw)
    }

    fn errors(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
        (
            (a.rotation * b.rotation.inverse()).angle().to_degrees(),
            (a.translation.vector - b.translation.vector).norm(),
        )
    }

    /// Eight captures on a ring of 0.3 m, each turned to face outwards, and the room as each
    /// sees it in its rig frame.
    fn ring() -> (Vec<Isometry3<f64>>, Vec<Vec<Measured>>) {
        let world = room();
        let truths: Vec<Isometry3<f64>> = (0..8)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 8.0;
                pose(0.3 * a.cos(), 0.3 * a.sin(), a)
            })
            .collect();
        let seen = truths
            .iter()
            .map(|t| world.iter().map(|m| m.transformed(&t.inverse())).collect())
            .collect();
        (truths, seen)
    }

    #[test]
    fn a_loop_of_noisy_odometry_is_registered_tied_by_edges_and_closed() {
        let (truths, seen) = ring();
        let offsets = [
            (0.0, 0.0, 0.0),
            (2.0, 0.04, -0.03),
            (-1.5, -0.03, 0.02),
            (2.5, 0.02, 0.05),
            (-2.0, 0.05, -0.04),
            (1.0, -0.04, -0.03),
            (-2.5, 0.01, 0.04),
            (1.5, -0.05, 0.02),
        ];
        let priors: Vec<PosePrior> = truths
            .iter()
            .zip(offsets)
            .map(|(t, (yaw, dx, dy))| {
                let off = Isometry3::new(
                    Vector3::new(dx, dy, 0.0),
                    Vector3::z() * f64::to_radians(yaw),
                );
                let moved = Isometry3::from_parts(
                    (t.translation.vector + off.translation.vector).into(),
                    off.rotation * t.rotation,
                );
                PosePrior::with_default_covariance(moved)
            })
            .collect();
        let params = SessionParams::default();
        let mut placed: Vec<Placed> = Vec::new();
        let mut edges = Vec::new();
        for (k, (prior, segments)) in priors.iter().zip(&seen).enumerate() {
            let added = add_capture(&placed, &edges, prior, segments, &params);
            let expected = if k == 0 {
                RegistrationStatus::EmptyMap
            } else {
                RegistrationStatus::Registered
            };
            assert_eq!(added.registration.status, expected, "capture {k}");
            assert!(added.edges.iter().all(|e| e.from == k && e.to < k));
            // It overlaps every earlier one, and pairs with the nearest few; from the second
            // capture on, one edge ties its heading to the anchor's by the room's directions;
            // any other edge is of the room's long lines, to a capture it does not pair with.
            let (heading, others): (Vec<&RelativePose>, Vec<&RelativePose>) =
                added.edges.iter().partition(|e| heading_only(e));
            let (segment, lines): (Vec<&RelativePose>, Vec<&RelativePose>) =
                others.into_iter().partition(|e| of_segments(e));
            assert_eq!(segment.len(), k.min(params.pair_captures), "capture {k}");
            assert!(lines.iter().all(|l| segment.iter().all(|s| s.to != l.to)));
            assert_eq!(heading.len(), usize::from(k > 0), "capture {k}");
            assert!(heading.iter().all(|e| e.to == 0));
            placed.push(Placed {
                prior: *prior,
                segments,
            });
            edges.extend(added.edges);
        }
        // The last capture ties back to the first by their segments: the loop closes.
        assert!(edges
            .iter()
            .any(|e| e.from == 7 && e.to == 0 && !heading_only(e)));
        let solved = solve_poses(&placed, &edges);
        for (k, (s, t)) in solved.iter().zip(&truths).enumerate() {
            let (deg, m) = errors(&s.rig_to_world, t);
            assert!(deg < 0.05 && m < 0.005, "capture {k}: {deg} deg {m} m");
            let given = errors(&priors[k].rig_to_world, t);
            assert!(k == 0 || (deg < given.0 && m < given.1));
        }
        // The anchor is the first capture's pose as given.
        assert_eq!(solved[0].rig_to_world, priors[0].rig_to_world);
    }

    /// Placing reads the segments of the neighbours it chose and of no other capture: a
    /// caller that decodes only those gets the very answer of one that decoded them all.
    #[test]
    fn placing_reads_only_the_neighbours_it_chose() {
        let (truths, seen) = ring();
        let priors: Vec<PosePrior> = truths
            .iter()
            .map(|t| PosePrior::with_default_covariance(*t))
            .collect();
        let params = SessionParams {
            map_captures: 3,
            pair_captures: 2,
            ..SessionParams::default()
        };
        let mut placed: Vec<Placed> = Vec::new();
        let mut edges = Vec::new();
        for (prior, segments) in priors.iter().zip(&seen).take(7) {
            edges.extend(add_capture(&placed, &edges, prior, segments, &params).edges);
            placed.push(Placed {
                prior: *prior,
                segments,
            });
        }
        let (prior, segments) = (&priors[7], &seen[7]);
        let neighbours =
            neighbours_until(&placed, &edges, prior, &params, Checkpoint::NEVER).unwrap();
        let needed = neighbours.needed();
        assert!(
            !needed.is_empty() && needed.len() <= 6 && needed.len() < placed.len(),
            "{needed:?}"
        );
        let lazy: Vec<Placed> = placed
            .iter()
            .enumerate()
            .map(|(i, p)| Placed {
                prior: p.prior,
                segments: if needed.contains(&i) { p.segments } else { &[] },
            })
            .collect();
        let full = add_capture(&placed, &edges, prior, segments, &params);
        let read_few = place_until(
            &lazy,
            &neighbours,
            prior,
            segments,
            None,
            &params,
            Checkpoint::NEVER,
        )
        .unwrap();
        assert_eq!(read_few, full);
        assert_eq!(full.registration.status, RegistrationStatus::Registered);
        assert_eq!(full.edges.iter().filter(|e| of_segments(e)).count(), 2);
    }

    /// An edge of segments in common: information in every direction of the relative pose,
    /// where one of the room's long lines ([`landmarks`]) has none along itself or in height.
    fn of_segments(e: &RelativePose) -> bool {
        let values = nalgebra::SymmetricEigen::new(e.information).eigenvalues;
        let largest = values.iter().cloned().fold(0.0, f64::max);
        values.iter().all(|&v| v > 1e-9 * largest)
    }

    /// An edge of the heading alone ([`compass`]): no information in translation.
    fn heading_only(e: &RelativePose) -> bool {
        e.information
            .fixed_view::<3, 3>(3, 3)
            .iter()
            .all(|&v| v == 0.0)
    }

    /// A capture that shares no segment with the map — it faces another wall — is turned by
    /// the room's directions: the heading its odometry got 2° wrong comes back to within a
    /// twentieth of a degree, in the pose AddCapture answers and in the session's solution;
    /// its position, which the directions cannot say, stays the odometry's.
    #[test]
    fn a_capture_facing_another_wall_takes_its_heading_from_the_rooms_directions() {
        let world = room();
        // The level edges whose ends both lie on one wall (`across` of the wall's plane).
        let on_wall = |across: fn(&Point3<f64>) -> f64, at: f64| -> Vec<Measured> {
            world
                .iter()
                .filter(|m| (m.start.z - m.end.z).abs() < 1e-9)
                .filter(|m| across(&m.start) == at && across(&m.end) == at)
                .copied()
                .collect()
        };
        let north = on_wall(|p| p.y, 3.0);
        let east = on_wall(|p| p.x, 2.5);
        assert!(north.len() >= 4 && east.len() >= 4);
        let truths = [pose(0.0, 0.0, 0.0), pose(0.5, 0.2, 0.3)];
        let seen = |segments: &[Measured], truth: &Isometry3<f64>| -> Vec<Measured> {
            segments
                .iter()
                .map(|m| m.transformed(&truth.inverse()))
                .collect()
        };
        let (first, second) = (seen(&north, &truths[0]), seen(&east, &truths[1]));
        let off = Isometry3::new(
            Vector3::new(0.03, -0.02, 0.0),
            Vector3::z() * 2f64.to_radians(),
        );
        let given = Isometry3::from_parts(
            (truths[1].translation.vector + off.translation.vector).into(),
            off.rotation * truths[1].rotation,
        );
        let priors = [
            PosePrior::with_default_covariance(truths[0]),
            PosePrior::with_default_covariance(given),
        ];
        let params = SessionParams::default();
        let mut placed = vec![Placed {
            prior: priors[0],
            segments: &first,
        }];
        let added = add_capture(&placed, &[], &priors[1], &second, &params);
        assert_eq!(
            added.registration.status,
            RegistrationStatus::TooFewInCommon
        );
        let (deg, m) = errors(&added.registration.rig_to_world, &truths[1]);
        assert!(deg < 0.05, "answered {deg}° off");
        assert!((m - 0.036).abs() < 0.002, "answered {m} m off");
        assert_eq!(added.edges.len(), 1);
        assert!(heading_only(&added.edges[0]) && added.edges[0].to == 0);
        placed.push(Placed {
            prior: priors[1],
            segments: &second,
        });
        let solved = solve_poses(&placed, &added.edges);
        let (deg, m) = errors(&solved[1].rig_to_world, &truths[1]);
        assert!(deg < 0.05, "solved {deg}° off");
        assert!((m - 0.036).abs() < 0.002, "solved {m} m off");
        // Known to what two readings of five segments each allow (each segment within
        // 0.25° of the room's directions), not to the odometry's 3°.
        let sigma = solved[1].covariance[(2, 2)].sqrt().to_degrees();
        assert!(sigma < 0.25, "{sigma}°");
    }

    #[test]
    fn the_graph_work_grows_with_the_band_not_the_session() {
        let edge = |from: usize, to: usize| RelativePose {
            from,
            to,
            pose: Isometry3::identity(),
            information: Matrix6::identity(),
            inliers: 10,
        };
        // A drive of 10,000 captures, each tied to the four before it: a band of five.
        let drive: Vec<RelativePose> = (1..10_000)
            .flat_map(|k| {
                (1..=4)
                    .filter(move |b| *b <= k)
                    .map(move |b| edge(k, k - b))
            })
            .collect();
        assert!(graph_work(10_000, &drive) <= 10_000 * 25);
        // A square hall mown in 100 rows of 100, each capture tied to the one before and to
        // its neighbour in the row before: no order narrows that band below a row, and it
        // is past what a request may take. Ten rows of 1,000 are not: ordered across the
        // rows, their band is a few captures wide.
        let mown = |row: usize| -> Vec<RelativePose> {
            (1..10_000)
                .flat_map(|k| {
                    let mut e = vec![edge(k, k - 1)];
                    if k >= row {
                        e.push(edge(k, k - row));
                    }
                    e
                })
                .collect()
        };
        assert!(graph_work(10_000, &mown(100)) > MAX_GRAPH_WORK);
        assert!(graph_work(10_000, &mown(1000)) < MAX_GRAPH_WORK);
        // Every capture of the drive tied to the anchor as well (the room's directions)
        // costs nothing more: the anchor does not move.
        let mut compassed = drive.clone();
        compassed.extend((1..10_000).map(|k| edge(k, 0)));
        assert_eq!(graph_work(10_000, &compassed), graph_work(10_000, &drive));
    }

    /// Captures with no segments at `poses`, each prior with the default covariance.
    fn placed_at(poses: &[Isometry3<f64>]) -> Vec<Placed<'static>> {
        poses
            .iter()
            .map(|t| Placed {
                prior: PosePrior::with_default_covariance(*t),
                segments: &[],
            })
            .collect()
    }

    #[test]
    fn an_edge_the_others_contradict_is_dropped() {
        let truths: Vec<Isometry3<f64>> = (0..6)
            .map(|k| pose(0.5 * k as f64, 0.0, 0.1 * k as f64))
            .collect();
        let placed = placed_at(&truths);
        let exact = |from: usize, to: usize| RelativePose {
            from,
            to,
            pose: truths[to].inverse() * truths[from],
            information: Matrix6::identity() * 1e6,
            inliers: 20,
        };
        let mut edges: Vec<RelativePose> = (1..6).map(|k| exact(k, k - 1)).collect();
        edges.push(exact(5, 0));
        // One edge as sure of itself as the others, and 20 cm wrong.
        let mut wrong = exact(3, 1);
        wrong.pose = Isometry3::translation(0.2, 0.0, 0.0) * wrong.pose;
        edges.push(wrong);
        let believed = super::super::poses::optimise(&graph_priors(&placed), &edges);
        let spoilt = (0..6)
            .map(|k| errors(&believed[k].rig_to_world, &truths[k]).1)
            .fold(0.0, f64::max);
        assert!(
            spoilt > 0.02,
            "the wrong edge alone pulls poses {spoilt} m off"
        );
        let solved = solve_poses(&placed, &edges);
        for (k, (s, t)) in solved.iter().zip(&truths).enumerate() {
            let (deg, m) = errors(&s.rig_to_world, t);
            assert!(deg < 1e-3 && m < 1e-3, "capture {k}: {deg} deg {m} m");
        }
    }

    /// A request past its deadline stops solving its session's graph at the next block row,
    /// not at the end of a solve that may take seconds; a checkpoint that never stops gives
    /// the poses `solve_poses` gives.
    #[test]
    fn a_solve_stops_promptly_once_its_result_is_not_wanted() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        let n = 2_000;
        let truths: Vec<Isometry3<f64>> = (0..n).map(|k| pose(0.3 * k as f64, 0.0, 0.0)).collect();
        let placed = placed_at(&truths);
        let edges: Vec<RelativePose> = (1..n)
            .map(|k| RelativePose {
                from: k,
                to: k - 1,
                pose: truths[k - 1].inverse() * truths[k],
                information: Matrix6::identity() * 1e4,
                inliers: 20,
            })
            .collect();
        let asked = AtomicUsize::new(0);
        const ANSWERED_BEFORE_STOP: usize = 100;
        let stop = || asked.fetch_add(1, Ordering::Relaxed) >= ANSWERED_BEFORE_STOP;
        let stopped = solve_poses_until(&placed, &edges, Checkpoint::new(&stop));
        assert_eq!(
            stopped.err(),
            Some(Stopped {
                stage: "pose graph"
            })
        );
        // One factorisation asks once per block row: it stopped within the first of its
        // 2,000 rows that asked after the stop, not after the solve.
        assert_eq!(asked.load(Ordering::Relaxed), ANSWERED_BEFORE_STOP + 1);
        let whole = solve_poses_until(&placed, &edges, Checkpoint::NEVER).expect("never stops");
        assert_eq!(whole, solve_poses(&placed, &edges));
    }
}
