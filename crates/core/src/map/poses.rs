//! The poses of a whole session at once: a small pose graph.
//!
//! Registering each capture to the map as it arrives chains its errors: a capture that finds
//! little in common with the map keeps its odometry, and the captures after it are registered
//! to it, error and all. And independent references from one capture share that capture's
//! pose error, so counting them as independent would make a doubtful capture outvote a sure
//! one. The graph keeps the two apart: each pair of captures that see the same edges gives one
//! constraint on their *relative* pose (registration of one to the other, with only the
//! information the segments bring), each capture's odometry gives its prior, and all poses
//! are solved together by Gauss–Newton — so where a panoramic session comes back to its start,
//! the loop closes and the correction spreads along it.
//!
//! The normal equations are banded, not dense ([`super::envelope`]): a session of thousands of
//! captures solves in what its band costs.
//!
//! Poses are perturbed as in [`super::register`]: a rotation vector about the rig's origin
//! (world axes), then a translation.

use nalgebra::{Isometry3, Matrix6, Point3, UnitQuaternion, Vector6};

use super::envelope::{narrow_positions, Envelope};
use crate::checkpoint::{never_stopped, Checkpoint, Stopped};

use super::register::{
    register_seen, Measured, PosePrior, RegisterParams, RegistrationStatus, Sector,
};

/// What two captures' segments say about where one rig was in the other's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelativePose {
    /// The capture whose rig is placed…
    pub from: usize,
    /// …in this capture's rig frame.
    pub to: usize,
    /// `from`'s rig-to-`to`'s-rig transform.
    pub pose: Isometry3<f64>,
    /// The information (inverse covariance) of that pose from the segments alone, in the
    /// perturbation of [`PosePrior::covariance`] taken in `to`'s frame.
    pub information: Matrix6<f64>,
    pub inliers: u32,
}

/// The relative pose of captures `from` and `to` (rig-frame segments, world priors), or `None`
/// when registration finds too little in common.
pub fn relative_pose(
    from: usize,
    to: usize,
    segments: &[Vec<Measured>],
    priors: &[PosePrior],
    params: &RegisterParams,
) -> Option<RelativePose> {
    let (pose, information, inliers) = register_pair(
        &segments[from],
        &segments[to],
        &priors[from],
        &priors[to],
        params,
    )?;
    Some(RelativePose {
        from,
        to,
        pose,
        information,
        inliers,
    })
}

/// Registers one capture's segments (`from_segments`, rig frame) to another's, from where
/// each rig is believed to be: the returned `from`-rig-to-`to`-rig transform, the information
/// of the segments alone in it (as [`RelativePose::information`]) and the inliers; `None` when
/// registration finds too little in common or contradicts the poses.
///
/// The poses' covariances should be their odometry's, not the tighter ones of an earlier
/// registration: centred on a pose that registration got slightly wrong, a tight prior holds
/// the pair there, and the segments' information then vouches for the error (measured: a
/// loop closure 1.3–1.5° off with χ² in the thousands; from the odometry's spread the same
/// pair closes within 0.1°).
pub fn register_pair(
    from_segments: &[Measured],
    to_segments: &[Measured],
    from: &PosePrior,
    to: &PosePrior,
    params: &RegisterParams,
) -> Option<(Isometry3<f64>, Matrix6<f64>, u32)> {
    let predicted = to.rig_to_world.inverse() * from.rig_to_world;
    let prior = PosePrior {
        rig_to_world: predicted,
        covariance: relative_covariance(from, to),
    };
    // `to`'s segments are in its rig frame: it looked from the origin.
    let seen_from: Vec<Sector> = Sector::of(Point3::origin(), to_segments)
        .into_iter()
        .collect();
    let got = register_seen(to_segments, &seen_from, from_segments, &prior, params);
    if got.status != RegistrationStatus::Registered {
        return None;
    }
    // The registration's information is the prior's plus the segments'; the graph adds the
    // priors itself, so only the segments' is kept.
    let posterior = got.covariance.try_inverse()?;
    let prior_information = prior.covariance.try_inverse()?;
    let information = positive_part(&(posterior - prior_information));
    Some((got.rig_to_world, information, got.inliers))
}

/// The covariance of `i`'s pose in `j`'s frame when both world poses carry their priors'
/// independent errors (first order; rotation–translation cross terms left out).
pub(crate) fn relative_covariance(i: &PosePrior, j: &PosePrior) -> Matrix6<f64> {
    let rj = j.rig_to_world.rotation.to_rotation_matrix().into_inner();
    let lever = i.rig_to_world.translation.vector - j.rig_to_world.translation.vector;
    let cross = lever.cross_matrix();
    let rotation = i.covariance.fixed_view::<3, 3>(0, 0) + j.covariance.fixed_view::<3, 3>(0, 0);
    let translation = i.covariance.fixed_view::<3, 3>(3, 3)
        + j.covariance.fixed_view::<3, 3>(3, 3)
        + cross * j.covariance.fixed_view::<3, 3>(0, 0) * cross.transpose();
    let mut c = Matrix6::zeros();
    c.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(rj.transpose() * rotation * rj));
    c.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&(rj.transpose() * translation * rj));
    c
}

/// A symmetric matrix with its negative eigenvalues (round-off of a difference) set to 0.
fn positive_part(m: &Matrix6<f64>) -> Matrix6<f64> {
    let eig = nalgebra::SymmetricEigen::new((m + m.transpose()) * 0.5);
    let values = eig.eigenvalues.map(|v| v.max(0.0));
    eig.eigenvectors * Matrix6::from_diagonal(&values) * eig.eigenvectors.transpose()
}

/// The difference `a ⊖ b` in the perturbation's terms: the rotation vector taking `b`'s
/// rotation to `a`'s, then the translation from `b`'s origin to `a`'s.
pub(crate) fn difference(a: &Isometry3<f64>, b: &Isometry3<f64>) -> Vector6<f64> {
    let rotation = (a.rotation * b.rotation.inverse()).scaled_axis();
    let translation = a.translation.vector - b.translation.vector;
    Vector6::new(
        rotation.x,
        rotation.y,
        rotation.z,
        translation.x,
        translation.y,
        translation.z,
    )
}

/// `pose` moved by the perturbation `xi` (rotation vector about the rig's origin, world
/// axes, then translation), as [`PosePrior::covariance`] describes it.
pub(crate) fn perturbed(pose: &Isometry3<f64>, xi: &Vector6<f64>) -> Isometry3<f64> {
    let rotation = UnitQuaternion::from_scaled_axis(xi.fixed_rows::<3>(0).into_owned());
    Isometry3::from_parts(
        (pose.translation.vector + xi.fixed_rows::<3>(3)).into(),
        rotation * pose.rotation,
    )
}

/// Largest variance (radians², metres²) of a prior that pins its capture in place.
const PINNED_VARIANCE: f64 = 1e-10;

/// True when `prior` pins its capture: known so well (a session's anchor) that no edge
/// moves it.
pub(crate) fn pins(prior: &PosePrior) -> bool {
    (0..6).all(|k| prior.covariance[(k, k)] <= PINNED_VARIANCE)
}

/// How far (χ² under its information) the solved poses may be from what an edge says.
pub fn edge_chi2(poses: &[PosePrior], edge: &RelativePose) -> f64 {
    let predicted = poses[edge.to].rig_to_world.inverse() * poses[edge.from].rig_to_world;
    let e = difference(&edge.pose, &predicted);
    e.dot(&(edge.information * e))
}

/// Gauss–Newton steps of [`optimise`], at most; it stops sooner when a step moves no pose by
/// more than [`SETTLED`] (radians, metres): far below any pose's precision.
const STEPS: usize = 10;
const SETTLED: f64 = 1e-8;
/// Step of the numerical derivatives: radians and metres.
const DELTA: f64 = 1e-7;

/// The poses that best agree with the priors and the relative poses, each with its marginal
/// covariance. A capture with a (nearly) exact prior anchors the others.
pub fn optimise(priors: &[PosePrior], relative: &[RelativePose]) -> Vec<PosePrior> {
    optimise_from(priors, relative, None)
}

/// [`optimise`], starting from `start` (one pose per prior) rather than the priors' poses:
/// a solution already close, as when an edge has just been dropped, converges in a step.
pub fn optimise_from(
    priors: &[PosePrior],
    relative: &[RelativePose],
    start: Option<&[Isometry3<f64>]>,
) -> Vec<PosePrior> {
    never_stopped(optimise_until(priors, relative, start, Checkpoint::NEVER))
}

/// [`optimise_from`], asking `checkpoint` at each step and within each factorisation.
pub fn optimise_until(
    priors: &[PosePrior],
    relative: &[RelativePose],
    start: Option<&[Isometry3<f64>]>,
    checkpoint: Checkpoint,
) -> Result<Vec<PosePrior>, Stopped> {
    let n = priors.len();
    let informations: Vec<Option<Matrix6<f64>>> =
        priors.iter().map(|p| p.covariance.try_inverse()).collect();
    let mut poses: Vec<Isometry3<f64>> = match start {
        Some(s) if s.len() == n => s.to_vec(),
        _ => priors.iter().map(|p| p.rig_to_world).collect(),
    };
    // An edge from a capture to itself, or to one that is not there, says nothing.
    let relative: Vec<&RelativePose> = relative
        .iter()
        .filter(|r| r.from < n && r.to < n && r.from != r.to)
        .collect();
    // A capture its prior pins (a session's anchor) does not move: an edge to it is a factor
    // on its other end alone, and does not widen the envelope — every capture may be tied to
    // the anchor and the band stays as narrow as the session's other edges make it.
    let pinned: Vec<bool> = priors.iter().map(pins).collect();
    // The captures in an order that keeps each near those it is tied to: the information
    // matrix is then a narrow envelope of blocks (`super::envelope`).
    let links: Vec<(usize, usize)> = relative
        .iter()
        .filter(|r| !pinned[r.from] && !pinned[r.to])
        .map(|r| (r.from, r.to))
        .collect();
    let position = narrow_positions(n, &links);
    let zero = Envelope::new(n, links.iter().map(|&(a, b)| (position[a], position[b])));
    // What the edge says against what the poses of its two ends say.
    let residual = |from: &Isometry3<f64>, to: &Isometry3<f64>, r: &RelativePose| {
        difference(&r.pose, &(to.inverse() * from))
    };
    let mut factor = None;
    for _ in 0..STEPS {
        let mut hessian = zero.clone();
        let mut gradient = vec![Vector6::<f64>::zeros(); n];
        for (i, (p, info)) in priors.iter().zip(&informations).enumerate() {
            let Some(info) = info else { continue };
            let e = difference(&poses[i], &p.rig_to_world);
            // d e / d ξᵢ is the identity to first order.
            hessian.add(position[i], position[i], info);
            gradient[position[i]] -= info * e;
        }
        for r in &relative {
            if pinned[r.from] && pinned[r.to] {
                continue;
            }
            let (from, to) = (poses[r.from], poses[r.to]);
            let e0 = residual(&from, &to, r);
            let mut jacobian = nalgebra::SMatrix::<f64, 6, 12>::zeros();
            for k in 0..6 {
                let mut xi = Vector6::zeros();
                xi[k] = DELTA;
                let moved_from = residual(&perturbed(&from, &xi), &to, r);
                let moved_to = residual(&from, &perturbed(&to, &xi), r);
                jacobian.set_column(k, &((moved_from - e0) / DELTA));
                jacobian.set_column(6 + k, &((moved_to - e0) / DELTA));
            }
            let jt_i = jacobian.transpose() * r.information;
            let h = jt_i * jacobian;
            let g = jt_i * e0;
            let ends = [position[r.from], position[r.to]];
            let moves = [!pinned[r.from], !pinned[r.to]];
            // The lower triangle only: the envelope is symmetric.
            let block = |a: usize, b: usize| -> Matrix6<f64> {
                h.fixed_view::<6, 6>(6 * a, 6 * b).into_owned()
            };
            for a in 0..2 {
                if moves[a] {
                    gradient[ends[a]] -= g.fixed_rows::<6>(6 * a);
                    hessian.add(ends[a], ends[a], &block(a, a));
                }
            }
            if moves[0] && moves[1] {
                hessian.add(ends[1], ends[0], &block(1, 0));
            }
        }
        factor = hessian.cholesky_until(checkpoint)?;
        let Some(step) = factor.as_ref().and_then(|f| f.solve(&gradient)) else {
            break;
        };
        for (i, pose) in poses.iter_mut().enumerate() {
            *pose = perturbed(pose, &step[position[i]]);
        }
        if step.iter().map(|v| v.amax()).fold(0.0, f64::max) < SETTLED {
            break;
        }
    }
    // The marginal covariances: the inverse of the information at the solution (the last
    // step is too small to change it), its diagonal blocks only.
    let covariance = match factor {
        Some(f) => f.inverse_diagonal_until(checkpoint)?,
        None => None,
    };
    Ok(poses
        .into_iter()
        .enumerate()
        .map(|(i, rig_to_world)| PosePrior {
            rig_to_world,
            covariance: covariance
                .as_ref()
                .map(|c| c[position[i]])
                .unwrap_or(priors[i].covariance),
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn pose(x: f64, y: f64, angle: f64) -> Isometry3<f64> {
        Isometry3::new(Vector3::new(x, y, 1.0), Vector3::z() * angle)
    }

    /// A prior that pins its capture at `t`, as a session's anchor.
    fn pinned(t: &Isometry3<f64>) -> PosePrior {
        PosePrior {
            rig_to_world: *t,
            covariance: Matrix6::identity() * 1e-12,
        }
    }

    #[test]
    fn a_loop_of_exact_relative_poses_corrects_noisy_priors() {
        let truth: Vec<Isometry3<f64>> = (0..8)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 8.0;
                pose(a.cos(), a.sin(), a)
            })
            .collect();
        let noise = [0.0, 0.03, -0.02, 0.04, -0.05, 0.02, 0.01, -0.03];
        let priors: Vec<PosePrior> = truth
            .iter()
            .zip(noise)
            .enumerate()
            .map(|(k, (t, e))| {
                let off = Isometry3::rotation(Vector3::z() * e) * *t;
                let prior = PosePrior::odometry(off, 3.0, 0.3, 0.05, 0.01);
                if k == 0 {
                    pinned(t)
                } else {
                    prior
                }
            })
            .collect();
        let strong = Matrix6::identity() * 1e8;
        let relative: Vec<RelativePose> = (0..8)
            .map(|k| {
                let (from, to) = ((k + 1) % 8, k);
                RelativePose {
                    from,
                    to,
                    pose: truth[to].inverse() * truth[from],
                    information: strong,
                    inliers: 10,
                }
            })
            .collect();
        let got = optimise(&priors, &relative);
        assert_eq!(got[0].rig_to_world, priors[0].rig_to_world);
        for (g, t) in got.iter().zip(&truth) {
            let angle = (g.rig_to_world.rotation * t.rotation.inverse()).angle();
            let shift = (g.rig_to_world.translation.vector - t.translation.vector).norm();
            assert!(angle < 1e-4 && shift < 1e-4, "{angle} {shift}");
        }
    }

    /// Edges to a pinned capture place the others as an edge between two free captures
    /// would, each on its own: a star of exact edges to the anchor puts every capture where
    /// the edges say, and the anchor stays exactly where its prior has it.
    #[test]
    fn edges_to_a_pinned_capture_place_the_others() {
        let truth: Vec<Isometry3<f64>> = (0..5)
            .map(|k| pose(0.4 * k as f64, -0.1 * k as f64, 0.3 * k as f64))
            .collect();
        let priors: Vec<PosePrior> = truth
            .iter()
            .enumerate()
            .map(|(k, t)| {
                if k == 0 {
                    pinned(t)
                } else {
                    let off = Isometry3::new(
                        Vector3::new(0.03, -0.02, 0.0),
                        Vector3::z() * 0.02 * k as f64,
                    );
                    PosePrior::odometry(off * *t, 3.0, 0.3, 0.05, 0.01)
                }
            })
            .collect();
        assert!(pins(&priors[0]) && !pins(&priors[1]));
        let star: Vec<RelativePose> = (1..5)
            .map(|k| RelativePose {
                from: k,
                to: 0,
                pose: truth[0].inverse() * truth[k],
                information: Matrix6::identity() * 1e10,
                inliers: 10,
            })
            .collect();
        let got = optimise(&priors, &star);
        assert_eq!(got[0].rig_to_world, priors[0].rig_to_world);
        for (g, t) in got.iter().zip(&truth) {
            let angle = (g.rig_to_world.rotation * t.rotation.inverse()).angle();
            let shift = (g.rig_to_world.translation.vector - t.translation.vector).norm();
            assert!(angle < 1e-6 && shift < 1e-6, "{angle} {shift}");
        }
    }
}
