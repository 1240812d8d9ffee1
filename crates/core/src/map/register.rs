//! Registration of a capture to the map: where was the rig, given where the robot thinks it
//! was and the 3D segments already seen?
//!
//! A robot's pose is a prior, not a fact: wheel odometry drifts by a degree or more per turn
//! and centimetres per metre. [`register`] finds the rigid pose that best explains the
//! capture's 3D segments as segments already in the map, weighted by both sides'
//! covariances, and pulled towards the prior by the prior's own covariance — a maximum a
//! posteriori estimate.
//!
//! The steps:
//! 1. **Candidates.** Each capture segment is paired with the reference segments it may be
//!    under the prior: the χ² of its endpoints' distances to the reference's line, under the
//!    measurement noise *and* the spread the prior's uncertainty gives them there, within a
//!    wide gate; the segments must also overlap along the line.
//! 2. **Hypotheses.** Two candidate pairs of non-parallel segments fix all six degrees of
//!    freedom, and two parallel ones well apart fix the heading and the floor position,
//!    the prior holding the rest; each such pair of pairs, among the longest segments, is
//!    solved with the prior and scored by a truncated χ² over every capture segment (MSAC);
//!    a segment the pose places where none of the map's captures looked ([`Sector`]) costs
//!    what an inlier would, not the truncation, since the map could not have had it. A
//!    scene of many parallel edges, where the nearest reference is often the wrong one, is
//!    why association is not simply nearest-neighbour from the prior.
//! 3. **Refinement.** From the best hypothesis: associate each segment with its best
//!    reference within the measurement gate, solve by Gauss–Newton, re-associate, until the
//!    inliers no longer change. The covariance is the inverse of the information of the
//!    inliers and the prior.
//! 4. **Rivals.** The hypotheses well apart from the refined pose are re-solved, and the
//!    spread of those that explain the capture nearly as well is added to the covariance,
//!    each weighed by its likelihood against the refined pose's: a row of fins matched in
//!    place or one fin over is not a pose known to a millimetre. A rival the refined pose
//!    does not outweigh a hundredfold is not ruled out: along the directions to such rivals
//!    the prior, not the segments, places the capture.
//!
//! The pose is perturbed about the rig's origin, not the world's: a yaw error then moves no
//! point of the rig, as odometry's does, and the prior's rotation and translation are
//! independent.

use nalgebra::{
    Isometry3, Matrix2, Matrix2x3, Matrix3, Matrix4, Matrix6, Point3, SMatrix, Translation3,
    UnitQuaternion, Vector2, Vector3, Vector4, Vector6,
};

use crate::geometry::across_basis;

/// A 3D segment with the covariance of its endpoints stacked (x1 y1 z1 x2 y2 z2), metres².
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measured {
    pub start: Point3<f64>,
    pub end: Point3<f64>,
    pub covariance: Matrix6<f64>,
    /// The match flagged it uncertain (it missed the accuracy gate). Such segments help
    /// refine a pose but do not choose it: among them are the wrong correspondences, whose
    /// covariance does not describe their error, and a repetitive scene's wrong ones agree
    /// with one another.
    pub uncertain: bool,
}

impl Measured {
    /// The segment moved by `pose`, its covariance rotated with it.
    pub fn transformed(&self, pose: &Isometry3<f64>) -> Measured {
        let r = pose.rotation.to_rotation_matrix().into_inner();
        // Block by block (R C_ij Rᵀ): the endpoints rotate alike.
        let c = &self.covariance;
        let rotated = |i: usize, j: usize| r * c.fixed_view::<3, 3>(3 * i, 3 * j) * r.transpose();
        Measured {
            start: pose * self.start,
            end: pose * self.end,
            covariance: from_blocks(&rotated(0, 0), &rotated(1, 1), &rotated(0, 1)),
            uncertain: self.uncertain,
        }
    }

    /// The segment moved by `pose`, whose own uncertainty (`pose_covariance`, as
    /// [`PosePrior::covariance`]) is added to the endpoints': a reference from a capture
    /// whose pose is doubtful is doubtful by as much.
    pub fn transformed_with(
        &self,
        pose: &Isometry3<f64>,
        pose_covariance: &Matrix6<f64>,
    ) -> Measured {
        let mut moved = self.transformed(pose);
        moved.covariance += moved.pose_spread(pose, pose_covariance);
        moved
    }

    /// The covariance of this segment's endpoints (already in the world frame) that an
    /// uncertainty `pose_covariance` of `pose`, which placed it, gives them (first order).
    pub(crate) fn pose_spread(
        &self,
        pose: &Isometry3<f64>,
        pose_covariance: &Matrix6<f64>,
    ) -> Matrix6<f64> {
        // An endpoint p moves by −[p − o]ₓ δθ + δt: J_i = [−L_i  I], and block (i, j) of
        // J U Jᵀ is (J_i U) J_jᵀ.
        let origin = pose.translation.vector;
        let levers = [self.start, self.end].map(|p| (p.coords - origin).cross_matrix());
        let u = pose_covariance;
        let (u_rr, u_rt) = (u.fixed_view::<3, 3>(0, 0), u.fixed_view::<3, 3>(0, 3));
        let (u_tr, u_tt) = (u.fixed_view::<3, 3>(3, 0), u.fixed_view::<3, 3>(3, 3));
        let ju = levers.map(|l| (u_tr - l * u_rr, u_tt - l * u_rt));
        let block = |i: usize, j: usize| {
            let (rotation, translation) = &ju[i];
            translation - rotation * levers[j].transpose()
        };
        from_blocks(&block(0, 0), &block(1, 1), &block(0, 1))
    }

    fn length(&self) -> f64 {
        (self.end - self.start).norm()
    }

    /// The covariance across the line only, with `floor` metres of isotropic noise across it.
    /// Registration measures how far endpoints are from lines, wherever along them they fall:
    /// where a segment ends is no measurement of the pose, and its along-line spread, seen
    /// from a line at an angle, would excuse any distance.
    pub(crate) fn across_only(&self, floor: f64) -> Measured {
        let d = (self.end - self.start) / self.length();
        let across = Matrix3::identity() - d * d.transpose();
        let project = block_diag(&across);
        let mut covariance = project * self.covariance * project.transpose();
        covariance += project * (floor * floor);
        Measured {
            covariance,
            ..*self
        }
    }
}

/// Where the robot believes the rig was, and how sure it is: the covariance of a small
/// rotation vector about the rig's origin (world axes, radians) then of the translation
/// (world axes, metres), 6x6.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PosePrior {
    pub rig_to_world: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}

/// The prior's standard deviations when a client gives none: a wheeled robot's odometry on
/// a flat floor — 3° of heading and 5 cm across the floor, but its tilt (0.3°) and height
/// (1 cm) barely change, as the floor holds them.
pub const DEFAULT_YAW_SIGMA_DEG: f64 = 3.0;
pub const DEFAULT_TILT_SIGMA_DEG: f64 = 0.3;
pub const DEFAULT_XY_SIGMA_M: f64 = 0.05;
pub const DEFAULT_Z_SIGMA_M: f64 = 0.01;

impl PosePrior {
    /// A prior of independent errors: heading (about world z), tilt (about world x and y),
    /// across the floor (x, y) and height (z), as standard deviations.
    pub fn odometry(
        rig_to_world: Isometry3<f64>,
        yaw_sigma_deg: f64,
        tilt_sigma_deg: f64,
        xy_sigma_m: f64,
        z_sigma_m: f64,
    ) -> PosePrior {
        let (tilt, yaw) = (tilt_sigma_deg.to_radians(), yaw_sigma_deg.to_radians());
        let diagonal = Vector6::new(
            tilt * tilt,
            tilt * tilt,
            yaw * yaw,
            xy_sigma_m * xy_sigma_m,
            xy_sigma_m * xy_sigma_m,
            z_sigma_m * z_sigma_m,
        );
        PosePrior {
            rig_to_world,
            covariance: Matrix6::from_diagonal(&diagonal),
        }
    }

    /// [`PosePrior::odometry`] with the documented defaults.
    pub fn with_default_covariance(rig_to_world: Isometry3<f64>) -> PosePrior {
        PosePrior::odometry(
            rig_to_world,
            DEFAULT_YAW_SIGMA_DEG,
            DEFAULT_TILT_SIGMA_DEG,
            DEFAULT_XY_SIGMA_M,
            DEFAULT_Z_SIGMA_M,
        )
    }

    /// True when the pose is finite and the covariance symmetric positive definite.
    pub fn is_valid(&self) -> bool {
        let finite = self
            .rig_to_world
            .translation
            .vector
            .iter()
            .all(|v| v.is_finite())
            && self
                .rig_to_world
                .rotation
                .coords
                .iter()
                .all(|v| v.is_finite());
        let symmetric = (self.covariance - self.covariance.transpose()).abs().max()
            <= 1e-12 * self.covariance.abs().max().max(1e-300);
        finite && symmetric && self.covariance.cholesky().is_some()
    }
}

/// How registration went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RegistrationStatus {
    /// The pose was refined against the map.
    Registered,
    /// The map was empty (the session's first capture): the prior is kept.
    EmptyMap,
    /// Too few of the capture's segments were found in the map: the prior is kept (in a
    /// session, its heading turned to agree with the room's directions where the capture and
    /// the map both read them: [`super::compass`]).
    TooFewInCommon,
    /// The segments found in common place the rig where its prior says it cannot have been
    /// (beyond [`PRIOR_GATE`]): a repetitive scene matched one shift over, say. The prior
    /// is kept (in a session, turned as for `TooFewInCommon`).
    DisagreesWithPrior,
}

/// The outcome of [`register`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Registration {
    /// The refined pose, or the prior's when not [`RegistrationStatus::Registered`].
    pub rig_to_world: Isometry3<f64>,
    /// Its covariance, as [`PosePrior::covariance`].
    pub covariance: Matrix6<f64>,
    pub status: RegistrationStatus,
    /// Capture segments matched to a map segment.
    pub inliers: u32,
    /// How far the refined pose is from the prior: the angle of the rotation between them,
    /// degrees, and the distance between the rig origins, metres.
    pub rotation_change_deg: f64,
    pub translation_change_m: f64,
}

/// Tunables of [`register`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegisterParams {
    /// Fewest inliers for a registration; with fewer the prior is kept. Four: captures of
    /// bare walls share four or five segments with the map, and the prior holds what so few
    /// leave open (`Problem::settled_by_prior` along an ambiguous row; at six, the driving
    /// loop's bare-wall captures hung on their odometry alone).
    pub min_inliers: u32,
    /// Isotropic noise added to every endpoint's covariance, metres: what the segments'
    /// covariances do not model (a map built from slightly misplaced captures, ends of lines
    /// cut differently in each view).
    pub noise_floor_m: f64,
    /// Capture segments shorter than this take no part, metres.
    pub min_length_m: f64,
}

impl Default for RegisterParams {
    fn default() -> Self {
        RegisterParams {
            min_inliers: 4,
            noise_floor_m: 0.002,
            min_length_m: 0.05,
        }
    }
}

/// χ² with 4 degrees of freedom (two endpoints, two directions across the line each) at
/// 0.999: the gate of a candidate under the prior.
const CANDIDATE_GATE: f64 = 18.467;
/// … at 0.99: the gate of an inlier under a hypothesis, and the truncation of its cost.
const INLIER_GATE: f64 = 13.277;
/// χ² with 6 degrees of freedom at 0.999: how far, under the prior's covariance, a refined
/// pose may lie from the prior. Beyond it the segments agree with one another about a pose
/// the prior rules out — in a bookcase or a radiator, every shelf or fin one step over
/// explains the capture about as well — and the prior, not the segments, is believed.
pub const PRIOR_GATE: f64 = 22.458;
/// Candidates kept per capture segment, best first.
const MAX_CANDIDATES: usize = 6;
/// Capture segments (longest first) whose candidates seed hypotheses.
const SEED_SEGMENTS: usize = 10;
/// Seeds beyond those: the longest segments of a direction (within [`MIN_SEED_ANGLE_DEG`])
/// that fewer than `SEEDS_PER_DIRECTION` seeds have, at most `EXTRA_SEEDS` of them.
const EXTRA_SEEDS: usize = 3;
const SEEDS_PER_DIRECTION: usize = 4;
/// Two seeds must differ in direction by this much to fix the rotation, degrees …
const MIN_SEED_ANGLE_DEG: f64 = 20.0;
/// … or, parallel, lie this far apart across their direction, metres: two vertical edges a
/// stride apart fix the heading and the position across the floor, which is what odometry
/// gets wrong, while the prior holds the tilt and the height. A robot facing a bare wall may
/// see nothing else with certainty: on the synthetic driving loop, with only non-parallel
/// seeds, a capture whose long certain segments were all vertical was tried from its prior
/// alone and slid to a wrong minimum (map error at 1°/2 cm: 15.2% → 7.8% with these seeds).
const MIN_SEED_SEPARATION_M: f64 = 0.3;
/// A hypothesis from two pairs is itself uncertain: this much rotation (radians) and
/// translation (metres), as standard deviations, widen the gate while scoring it.
const HYPOTHESIS_SLACK_RAD: f64 = 0.003;
const HYPOTHESIS_SLACK_M: f64 = 0.005;
/// The best hypothesis: its perturbation of the prior, and how well it is known.
struct Hypotheses {
    xi: Vector6<f64>,
    information: Matrix6<f64>,
    /// Every hypothesis tried: its cost and perturbation.
    tried: Vec<(f64, Vector6<f64>)>,
}

/// Farthest a capture segment may reach past a reference's end along the line, metres.
const MAX_GAP_M: f64 = 0.2;
/// Gauss–Newton steps per solve, and rounds of re-association.
const SOLVE_STEPS: usize = 5;
const REFINE_ROUNDS: usize = 8;

/// Where a capture's segments were seen from: the rig's origin and the span of directions
/// about the vertical (world z) its segments cover. A map segment can only have been seen
/// within such a span; a capture segment that a pose places outside every span of the map
/// is one the map could not have, and leaving it unexplained is no evidence against that
/// pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sector {
    origin: Point3<f64>,
    /// The span's bounding directions across the floor, unit vectors, counter-clockwise
    /// from `from` to `to` (less than a half-turn apart).
    from: [f64; 2],
    to: [f64; 2],
}

impl Sector {
    /// The span of `segments` (world frame) seen from `origin`; `None` without segments or
    /// when they surround it (more than a half-turn: then everything counts as seen).
    pub fn of(origin: Point3<f64>, segments: &[Measured]) -> Option<Sector> {
        let azimuths: Vec<f64> = segments
            .iter()
            .flat_map(|s| [s.start, s.end])
            .map(|p| (p.y - origin.y).atan2(p.x - origin.x))
            .filter(|a| a.is_finite())
            .collect();
        let (sin, cos) = azimuths
            .iter()
            .fold((0.0, 0.0), |(s, c), a| (s + a.sin(), c + a.cos()));
        if azimuths.is_empty() || (sin == 0.0 && cos == 0.0) {
            return None;
        }
        // Offsets from the mean direction: the span runs from the least to the greatest.
        let mean = f64::atan2(sin, cos);
        let (lo, hi) = azimuths
            .iter()
            .map(|a| wrapped(a - mean))
            .fold((0.0f64, 0.0f64), |(lo, hi), d| (lo.min(d), hi.max(d)));
        let unit = |a: f64| [a.cos(), a.sin()];
        (hi - lo < std::f64::consts::PI).then_some(Sector {
            origin,
            from: unit(mean + lo),
            to: unit(mean + hi),
        })
    }

    /// Whether `p` lies within the span (at any height or range). Two cross products, not
    /// an arc tangent: registration asks it of every unexplained segment of every hypothesis.
    fn covers(&self, p: &Point3<f64>) -> bool {
        let v = [p.x - self.origin.x, p.y - self.origin.y];
        let cross = |a: [f64; 2], b: [f64; 2]| a[0] * b[1] - a[1] * b[0];
        cross(self.from, v) >= 0.0 && cross(v, self.to) >= 0.0
    }
}

/// An angle in (−π, π].
fn wrapped(a: f64) -> f64 {
    let turn = std::f64::consts::TAU;
    a - turn * ((a + std::f64::consts::PI) / turn).floor()
}

/// What an unexplained capture segment costs where the map could not have seen it: what an
/// inlier is expected to cost (χ²'s mean for its 4 degrees of freedom), so that a pose gains
/// nothing by placing segments out of sight rather than on their partners.
const UNSEEN_COST: f64 = 4.0;

/// Registers `capture` (rig frame) to `map` (world frame) from `prior`: see the module
/// documentation. Deterministic: the same inputs give the same pose.
pub fn register(
    map: &[Measured],
    capture: &[Measured],
    prior: &PosePrior,
    params: &RegisterParams,
) -> Registration {
    register_seen(map, &[], capture, prior, params)
}

/// [`register`] told where the map's segments were seen from (`seen_from`; empty: from
/// everywhere, as [`register`]).
pub fn register_seen(
    map: &[Measured],
    seen_from: &[Sector],
    capture: &[Measured],
    prior: &PosePrior,
    params: &RegisterParams,
) -> Registration {
    let kept = Registration {
        rig_to_world: prior.rig_to_world,
        covariance: prior.covariance,
        status: RegistrationStatus::EmptyMap,
        inliers: 0,
        rotation_change_deg: 0.0,
        translation_change_m: 0.0,
    };
    let references: Vec<Reference> = map
        .iter()
        .filter_map(|m| Reference::new(&m.across_only(params.noise_floor_m)))
        .collect();
    if references.is_empty() {
        return kept;
    }
    let too_few = Registration {
        status: RegistrationStatus::TooFewInCommon,
        ..kept
    };
    let Some(prior_information) = prior.covariance.try_inverse() else {
        return too_few;
    };
    let segments: Vec<Measured> = capture
        .iter()
        .filter(|s| s.length() >= params.min_length_m && s.length().is_finite())
        .map(|s| s.across_only(params.noise_floor_m))
        .collect();
    let problem = Problem {
        prior,
        prior_information,
        references: &references,
        segments: &segments,
        seen_from,
    };
    let candidates = problem.candidates();
    let best = problem.best_hypothesis(&candidates);
    let (xi, inliers, information) = problem.refine(best.xi, best.information, &candidates);
    // The segments' information, scaled down by how much more their residuals scatter than
    // their covariances say (the a-posteriori variance of unit weight, never scaled up): a
    // systematic error the segments share — two edges merged into one, ends cut differently
    // — otherwise makes a hundred inliers vouch for a pose a few millimetres off.
    let factor = problem.scatter(&xi, &inliers).max(1.0);
    let information =
        problem.prior_information + (information - problem.prior_information) / factor;
    if (inliers.len() as u32) < params.min_inliers {
        return Registration {
            inliers: inliers.len() as u32,
            ..too_few
        };
    }
    let finite = xi.iter().chain(information.iter()).all(|v| v.is_finite());
    if !finite {
        // A prior or covariances beyond floating point: nothing learnt, the prior kept.
        return Registration {
            inliers: inliers.len() as u32,
            ..too_few
        };
    }
    if xi.dot(&(prior_information * xi)) > PRIOR_GATE {
        return Registration {
            status: RegistrationStatus::DisagreesWithPrior,
            inliers: inliers.len() as u32,
            ..too_few
        };
    }
    let covariance = information
        .try_inverse()
        .map(|c| (c + c.transpose()) * 0.5)
        .unwrap_or(prior.covariance);
    let rivals = problem.rivals(&xi, &covariance, &best.tried, &candidates);
    let (xi, covariance) = match problem.settled_by_prior(&xi, &rivals.ambiguous) {
        Some((settled, along)) => (settled, covariance + along + rivals.spread),
        None => (xi, covariance + rivals.spread),
    };
    let pose = problem.pose(&xi);
    let change = pose * prior.rig_to_world.inverse();
    Registration {
        rig_to_world: pose,
        covariance,
        status: RegistrationStatus::Registered,
        inliers: inliers.len() as u32,
        rotation_change_deg: change.rotation.angle().to_degrees(),
        translation_change_m: (pose.translation.vector - prior.rig_to_world.translation.vector)
            .norm(),
    }
}

/// A map segment as a line to measure against.
struct Reference {
    a: Point3<f64>,
    direction: Vector3<f64>,
    length: f64,
    /// Across the line: two unit vectors, as rows.
    across: Matrix2x3<f64>,
    covariance: Matrix6<f64>,
    uncertain: bool,
}

impl Reference {
    fn new(m: &Measured) -> Option<Reference> {
        let length = m.length();
        let finite = m.start.iter().chain(m.end.iter()).all(|v| v.is_finite())
            && m.covariance.iter().all(|v| v.is_finite());
        if !finite || length < 1e-6 {
            return None;
        }
        let direction = (m.end - m.start) / length;
        let (e1, e2) = across_basis(&direction);
        Some(Reference {
            a: m.start,
            direction,
            length,
            across: Matrix2x3::from_rows(&[e1.transpose(), e2.transpose()]),
            covariance: m.covariance,
            uncertain: m.uncertain,
        })
    }

    /// Where `p` falls along the line, as a fraction of the segment (0 at `a`, 1 at the end).
    fn fraction(&self, p: &Point3<f64>) -> f64 {
        (p - self.a).dot(&self.direction) / self.length
    }
}

/// One pairing of a capture segment with a reference.
#[derive(Debug, Clone, Copy)]
struct Pair {
    segment: usize,
    reference: usize,
}

struct Problem<'a> {
    prior: &'a PosePrior,
    prior_information: Matrix6<f64>,
    references: &'a [Reference],
    segments: &'a [Measured],
    seen_from: &'a [Sector],
}

/// The residual of a pairing (both endpoints, across the reference's line), its Jacobian in
/// the pose perturbation, and the covariance of the residual from both sides' noise.
struct Linearised {
    residual: Vector4<f64>,
    jacobian: SMatrix<f64, 4, 6>,
    covariance: Matrix4<f64>,
}

/// A capture segment's two ends against a reference's line: where each falls along it
/// (a fraction of the reference, clamped to it) and its two residuals across it.
struct Ends {
    fractions: [f64; 2],
    residuals: [Vector2<f64>; 2],
}

impl Ends {
    /// `None` when the segment does not overlap the reference along the line, up to a gap.
    fn of(r: &Reference, world: &Measured) -> Option<Ends> {
        let (f0, f1) = (r.fraction(&world.start), r.fraction(&world.end));
        let gap = MAX_GAP_M / r.length;
        if f0.max(f1) < -gap || f0.min(f1) > 1.0 + gap {
            return None;
        }
        let fractions = [f0.clamp(0.0, 1.0), f1.clamp(0.0, 1.0)];
        let across =
            |q: &Point3<f64>, f: f64| r.across * (q - (r.a + r.direction * (f * r.length)));
        Some(Ends {
            fractions,
            residuals: [
                across(&world.start, fractions[0]),
                across(&world.end, fractions[1]),
            ],
        })
    }

    fn residual(&self) -> Vector4<f64> {
        let [e0, e1] = self.residuals;
        Vector4::new(e0[0], e0[1], e1[0], e1[1])
    }

    /// Block (i, j) of the residuals' covariance: the capture's endpoints' (i, j) block,
    /// plus the reference's endpoints' weighed by where each end's foot falls on it, seen
    /// across the line.
    fn block(&self, r: &Reference, world: &Measured, i: usize, j: usize) -> Matrix2<f64> {
        let (fi, fj) = (self.fractions[i], self.fractions[j]);
        let mut m = world
            .covariance
            .fixed_view::<3, 3>(3 * i, 3 * j)
            .into_owned();
        for (k, wk) in [1.0 - fi, fi].into_iter().enumerate() {
            for (l, wl) in [1.0 - fj, fj].into_iter().enumerate() {
                m += r.covariance.fixed_view::<3, 3>(3 * k, 3 * l) * (wk * wl);
            }
        }
        r.across * m * r.across.transpose()
    }
}

/// The symmetric matrix (M = 2N) of the diagonal blocks (0, 0), (1, 1) and the block (0, 1)
/// of two ends: their endpoints' 3×3 (M = 6) or their residuals' 2×2 (M = 4).
fn from_blocks<const N: usize, const M: usize>(
    b00: &SMatrix<f64, N, N>,
    b11: &SMatrix<f64, N, N>,
    b01: &SMatrix<f64, N, N>,
) -> SMatrix<f64, M, M> {
    debug_assert_eq!(M, 2 * N);
    let mut m = SMatrix::<f64, M, M>::zeros();
    m.fixed_view_mut::<N, N>(0, 0).copy_from(b00);
    m.fixed_view_mut::<N, N>(N, N).copy_from(b11);
    m.fixed_view_mut::<N, N>(0, N).copy_from(b01);
    m.fixed_view_mut::<N, N>(N, 0).copy_from(&b01.transpose());
    m
}

/// The inverse of a symmetric 2×2 matrix, `None` unless it is positive definite.
fn inverse_2x2(s: &Matrix2<f64>) -> Option<Matrix2<f64>> {
    let det = s.m11 * s.m22 - s.m12 * s.m21;
    (s.m11 > 0.0 && det > 0.0 && det.is_finite())
        .then(|| Matrix2::new(s.m22, -s.m12, -s.m21, s.m11) / det)
}

impl Problem<'_> {
    /// The pose at perturbation `xi` (rotation vector about the rig's origin, translation)
    /// of the prior.
    fn pose(&self, xi: &Vector6<f64>) -> Isometry3<f64> {
        let rotation = UnitQuaternion::from_scaled_axis(xi.fixed_rows::<3>(0).into_owned());
        let translation = self.prior.rig_to_world.translation.vector + xi.fixed_rows::<3>(3);
        Isometry3::from_parts(
            Translation3::from(translation),
            rotation * self.prior.rig_to_world.rotation,
        )
    }

    fn linearise(&self, pair: Pair, pose: &Isometry3<f64>) -> Option<Linearised> {
        let world = self.segments[pair.segment].transformed(pose);
        let r = &self.references[pair.reference];
        let ends = Ends::of(r, &world)?;
        let origin = pose.translation.vector;
        let mut jacobian = SMatrix::<f64, 4, 6>::zeros();
        for (i, q) in [world.start, world.end].into_iter().enumerate() {
            let lever = q.coords - origin;
            let d_rotation = -(r.across * lever.cross_matrix());
            jacobian
                .fixed_view_mut::<2, 3>(2 * i, 0)
                .copy_from(&d_rotation);
            jacobian
                .fixed_view_mut::<2, 3>(2 * i, 3)
                .copy_from(&r.across);
        }
        let [s00, s11, s01] = [(0, 0), (1, 1), (0, 1)].map(|(i, j)| ends.block(r, &world, i, j));
        Some(Linearised {
            residual: ends.residual(),
            jacobian,
            covariance: from_blocks(&s00, &s11, &s01),
        })
    }

    /// χ² of a pairing at `pose`, from the segments' noise alone.
    fn chi2(&self, pair: Pair, pose: &Isometry3<f64>) -> Option<f64> {
        let world = self.segments[pair.segment].transformed(pose);
        self.chi2_within(pair.reference, &world, f64::INFINITY)
    }

    /// χ² of a capture segment already moved by a pose and widened by its uncertainty
    /// ([`Measured::transformed_with`]) against reference `reference`, when it is within
    /// `gate`; `None` beyond the gate, off the reference's ends or degenerate.
    ///
    /// The pose's uncertainty moves the residual as it moves the segment's endpoints, so its
    /// share of the residual's covariance is the endpoints' spread seen across the line —
    /// computed once per segment and pose, not per pairing. The χ² of one end's two residuals
    /// under their own 2×2 block is a lower bound of the whole (a marginal's), so a pairing
    /// beyond the gate is mostly refused from one 2×2 block; the whole is the first end's
    /// plus the second's given the first.
    fn chi2_within(&self, reference: usize, world: &Measured, gate: f64) -> Option<f64> {
        let r = &self.references[reference];
        let ends = Ends::of(r, world)?;
        let [e0, e1] = ends.residuals;
        let s00 = ends.block(r, world, 0, 0);
        let s00_inv = inverse_2x2(&s00)?;
        let first = e0.dot(&(s00_inv * e0));
        if first > gate {
            return None;
        }
        let s11 = ends.block(r, world, 1, 1);
        if e1.dot(&(inverse_2x2(&s11)? * e1)) > gate {
            return None;
        }
        // The second end given the first (Schur complement): the whole χ² from 2×2 blocks.
        let s01 = ends.block(r, world, 0, 1);
        let gain = s01.transpose() * s00_inv;
        let rest = e1 - gain * e0;
        let rest_inv = inverse_2x2(&(s11 - gain * s01))?;
        let chi2 = first + rest.dot(&(rest_inv * rest));
        (chi2 <= gate).then_some(chi2)
    }

    /// Per capture segment, the references it may be under the prior, best first.
    fn candidates(&self) -> Vec<Vec<(usize, f64)>> {
        let pose = self.prior.rig_to_world;
        let origin = Point3::from(pose.translation.vector);
        // How far the prior's uncertainty may move a point at range ρ: 3σ of translation
        // plus 3σ of rotation times ρ; a cheap distance test before any χ².
        let sigma_t = self
            .prior
            .covariance
            .fixed_view::<3, 3>(3, 3)
            .trace()
            .sqrt();
        let sigma_r = self
            .prior
            .covariance
            .fixed_view::<3, 3>(0, 0)
            .trace()
            .sqrt();
        self.segments
            .iter()
            .map(|s| {
                let world = s.transformed_with(&pose, &self.prior.covariance);
                let mid = nalgebra::center(&world.start, &world.end);
                let reach =
                    3.0 * (sigma_t + sigma_r * (mid - origin).norm()) + 0.5 * s.length() + 0.1;
                let mut found: Vec<(usize, f64)> = self
                    .references
                    .iter()
                    .enumerate()
                    .filter(|(_, r)| {
                        let rmid = r.a + r.direction * (0.5 * r.length);
                        (rmid - mid).norm() <= reach + 0.5 * r.length
                    })
                    .filter_map(|(j, _)| {
                        self.chi2_within(j, &world, CANDIDATE_GATE).map(|c| (j, c))
                    })
                    .collect();
                found.sort_by(|x, y| x.1.total_cmp(&y.1).then(x.0.cmp(&y.0)));
                found.truncate(MAX_CANDIDATES);
                found
            })
            .collect()
    }

    /// Gauss–Newton from `xi` on `pairs` with the prior; returns the perturbation and the
    /// information matrix at it.
    fn solve(&self, mut xi: Vector6<f64>, pairs: &[Pair]) -> (Vector6<f64>, Matrix6<f64>) {
        let mut information = self.prior_information;
        for _ in 0..SOLVE_STEPS {
            let pose = self.pose(&xi);
            let mut h = self.prior_information;
            let mut g = -(self.prior_information * xi);
            for &pair in pairs {
                let Some(l) = self.linearise(pair, &pose) else {
                    continue;
                };
                let Some(w) = l.covariance.try_inverse() else {
                    continue;
                };
                let jt_w = l.jacobian.transpose() * w;
                h += jt_w * l.jacobian;
                g -= jt_w * l.residual;
            }
            information = h;
            let Some(step) = h.cholesky().map(|c| c.solve(&g)) else {
                break;
            };
            xi += step;
            if step.norm() < 1e-9 {
                break;
            }
        }
        (xi, information)
    }

    /// MSAC cost of a pose: every certain capture segment's best χ² among its certain
    /// candidates, truncated at the inlier gate.
    fn cost(&self, pose: &Isometry3<f64>, candidates: &[Vec<(usize, f64)>]) -> f64 {
        let slack = slack();
        candidates
            .iter()
            .enumerate()
            .filter(|(k, list)| !self.segments[*k].uncertain && !list.is_empty())
            .map(|(k, list)| {
                let world = self.segments[k].transformed_with(pose, &slack);
                let best = list
                    .iter()
                    .filter(|&&(j, _)| !self.references[j].uncertain)
                    .filter_map(|&(j, _)| self.chi2_within(j, &world, INLIER_GATE))
                    .fold(INLIER_GATE, f64::min);
                if best < INLIER_GATE {
                    best
                } else {
                    self.unexplained(&world)
                }
            })
            .sum::<f64>()
            // Segments without candidates cost the full truncation, as before.
            + INLIER_GATE
                * candidates
                    .iter()
                    .enumerate()
                    .filter(|(k, list)| !self.segments[*k].uncertain && list.is_empty())
                    .count() as f64
    }

    /// What a capture segment at `world` costs when nothing in the map explains it: the
    /// inlier gate, or [`UNSEEN_COST`] where no capture of the map looked.
    fn unexplained(&self, world: &Measured) -> f64 {
        let seen = self.seen_from.is_empty()
            || self
                .seen_from
                .iter()
                .any(|s| s.covers(&world.start) || s.covers(&world.end));
        if seen {
            INLIER_GATE
        } else {
            UNSEEN_COST
        }
    }

    /// A hypothesis from a start (a perturbation of the prior): what it associates as
    /// tightly as hypotheses are scored, solved with the prior; `None` beyond the prior gate.
    fn hypothesis_from(
        &self,
        start: &Vector6<f64>,
        candidates: &[Vec<(usize, f64)>],
    ) -> Option<(f64, Vector6<f64>, Matrix6<f64>)> {
        let pairs = self.associate(&self.pose(start), &slack(), candidates);
        let (xi, information) = self.solve(*start, &pairs);
        let distance = xi.dot(&(self.prior_information * xi));
        (distance <= PRIOR_GATE).then(|| {
            (
                self.cost(&self.pose(&xi), candidates) + distance,
                xi,
                information,
            )
        })
    }

    /// The best pose of two non-parallel pairings among the longest segments, or of the
    /// prior.
    fn best_hypothesis(&self, candidates: &[Vec<(usize, f64)>]) -> Hypotheses {
        let mut seeds: Vec<usize> = (0..self.segments.len())
            .filter(|&k| !self.segments[k].uncertain && !candidates[k].is_empty())
            .collect();
        seeds.sort_by(|&a, &b| {
            self.segments[b]
                .length()
                .total_cmp(&self.segments[a].length())
                .then(a.cmp(&b))
        });
        let direction = |k: usize| {
            let s = &self.segments[k];
            (s.end - s.start).normalize()
        };
        let cos_min = MIN_SEED_ANGLE_DEG.to_radians().cos();
        // The longest segments, and then the longest of each direction fewer than
        // [`SEEDS_PER_DIRECTION`] of them share: a capture facing a wall may have its longest
        // all along the wall, which fix nothing along it, while a row of short uprights does
        // — if the uprights that seed hypotheses include one the map saw.
        let longest = seeds.len().min(SEED_SEGMENTS);
        let mut extra: Vec<usize> = Vec::new();
        for &k in &seeds[longest..] {
            if extra.len() == EXTRA_SEEDS {
                break;
            }
            let alike = seeds[..longest]
                .iter()
                .chain(&extra)
                .filter(|&&j| direction(j).dot(&direction(k)).abs() > cos_min)
                .count();
            if alike < SEEDS_PER_DIRECTION {
                extra.push(k);
            }
        }
        seeds.truncate(longest);
        seeds.extend(extra);
        let separation = |k1: usize, k2: usize| {
            let (a, b) = (&self.segments[k1], &self.segments[k2]);
            let d = direction(k1);
            let apart = nalgebra::center(&b.start, &b.end) - nalgebra::center(&a.start, &a.end);
            (apart - d * apart.dot(&d)).norm()
        };
        // The prior itself is a hypothesis: with exact odometry it should win. It is solved on
        // what it associates as tightly as the two-pair hypotheses are scored, so that it
        // goes on to refinement as sure of itself as they do: refined from the prior's own
        // spread, a repetitive scene's pairs one step over would be associated too and pull
        // it there.
        let first = self
            .hypothesis_from(&Vector6::zeros(), candidates)
            .unwrap_or((
                self.cost(&self.prior.rig_to_world, candidates),
                Vector6::zeros(),
                self.prior_information,
            ));
        let mut tried = vec![first];
        for (n, &k1) in seeds.iter().enumerate() {
            for &k2 in &seeds[n + 1..] {
                if direction(k1).dot(&direction(k2)).abs() > cos_min
                    && separation(k1, k2) < MIN_SEED_SEPARATION_M
                {
                    continue;
                }
                for &(j1, _) in &candidates[k1] {
                    for &(j2, _) in &candidates[k2] {
                        if j1 == j2
                            || self.references[j1].uncertain
                            || self.references[j2].uncertain
                        {
                            continue;
                        }
                        let pairs = [
                            Pair {
                                segment: k1,
                                reference: j1,
                            },
                            Pair {
                                segment: k2,
                                reference: j2,
                            },
                        ];
                        let (xi, information) = self.solve(Vector6::zeros(), &pairs);
                        // A posteriori: a pose far from the prior pays for the distance, and
                        // one the prior rules out is no hypothesis at all (however many
                        // segments of a repetitive scene agree with it).
                        let distance = xi.dot(&(self.prior_information * xi));
                        if distance > PRIOR_GATE {
                            continue;
                        }
                        let cost = self.cost(&self.pose(&xi), candidates) + distance;
                        tried.push((cost, xi, information));
                    }
                }
            }
        }
        let all = tried.iter().map(|t| (t.0, t.1)).collect();
        let (_, xi, information) = tried
            .into_iter()
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .expect("the prior's own hypothesis is always there");
        Hypotheses {
            xi,
            information,
            tried: all,
        }
    }

    /// Associates and solves from `xi`, whose `information` says how well it is known, until
    /// the inliers settle: the perturbation, the inliers and the information at the end.
    /// Association is gated under the estimate's own uncertainty as well as the segments':
    /// a hypothesis from two pairs may be a little off, and the pairs that would correct it
    /// must not be refused for it.
    fn refine(
        &self,
        mut xi: Vector6<f64>,
        mut information: Matrix6<f64>,
        candidates: &[Vec<(usize, f64)>],
    ) -> (Vector6<f64>, Vec<Pair>, Matrix6<f64>) {
        let mut inliers: Vec<Pair> = Vec::new();
        for _ in 0..REFINE_ROUNDS {
            let pose = self.pose(&xi);
            let slack = information.try_inverse().unwrap_or(self.prior.covariance) + slack();
            let associated = self.associate(&pose, &slack, candidates);
            let settled = associated.len() == inliers.len()
                && associated
                    .iter()
                    .zip(&inliers)
                    .all(|(a, b)| a.segment == b.segment && a.reference == b.reference);
            inliers = associated;
            let (next, info) = self.solve(xi, &inliers);
            xi = next;
            information = info;
            if settled {
                break;
            }
        }
        (xi, inliers, information)
    }
}

impl Problem<'_> {
    /// χ² of the `inliers` at `xi` over their degrees of freedom (4 residuals each, less the
    /// pose's 6); 1 when there are too few to say.
    fn scatter(&self, xi: &Vector6<f64>, inliers: &[Pair]) -> f64 {
        let dof = (4 * inliers.len()).saturating_sub(6);
        if dof == 0 {
            return 1.0;
        }
        let pose = self.pose(xi);
        let chi2: f64 = inliers
            .iter()
            .filter_map(|&pair| self.chi2(pair, &pose))
            .sum();
        chi2 / dof as f64
    }

    /// Each capture segment's best candidate within the inlier gate at `pose`, known to
    /// within `uncertainty`.
    fn associate(
        &self,
        pose: &Isometry3<f64>,
        uncertainty: &Matrix6<f64>,
        candidates: &[Vec<(usize, f64)>],
    ) -> Vec<Pair> {
        candidates
            .iter()
            .enumerate()
            .filter(|(_, list)| !list.is_empty())
            .filter_map(|(k, list)| {
                let world = self.segments[k].transformed_with(pose, uncertainty);
                list.iter()
                    .filter_map(|&(j, _)| self.chi2_within(j, &world, INLIER_GATE).map(|c| (j, c)))
                    .min_by(|x, y| x.1.total_cmp(&y.1))
                    .map(|(j, _)| Pair {
                        segment: k,
                        reference: j,
                    })
            })
            .collect()
    }
}

impl Problem<'_> {
    /// The spread the hypotheses that explain the capture nearly as well as `xi` give it:
    /// each rival well apart from `xi` (beyond [`RIVAL_APART`] under `covariance` and the
    /// hypotheses' slack) weighs as its likelihood against the refined pose's, e^(−Δcost/2),
    /// and the covariance of that mixture about `xi` is added. A row of fins or shelves that
    /// the capture's few segments across one direction match one step over or in place
    /// alike then leaves that direction as uncertain as the alternatives are apart.
    fn rivals(
        &self,
        xi: &Vector6<f64>,
        covariance: &Matrix6<f64>,
        tried: &[(f64, Vector6<f64>)],
        candidates: &[Vec<(usize, f64)>],
    ) -> Rivals {
        let mut rivals = Rivals {
            spread: Matrix6::zeros(),
            ambiguous: Vec::new(),
        };
        let Some(apart) = (covariance + slack()).try_inverse() else {
            return rivals;
        };
        let own = self.cost(&self.pose(xi), candidates) + xi.dot(&(self.prior_information * xi));
        let mut total = 1.0;
        let mut counted: Vec<Vector6<f64>> = Vec::new();
        let mut near: Vec<&(f64, Vector6<f64>)> = tried
            .iter()
            .filter(|(cost, other)| {
                let d = other - xi;
                cost - own <= RIVAL_COST && d.dot(&(apart * d)) > RIVAL_APART
            })
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        for (_, start) in near.into_iter().take(MAX_RIVALS) {
            // Scored as it stands after its own association and solve, as the refined pose
            // is: a hypothesis from two pairs is a little off and costs more than it would.
            let Some((cost, other, _)) = self.hypothesis_from(start, candidates) else {
                continue;
            };
            let d = other - xi;
            let same = |x: &Vector6<f64>| (other - x).dot(&(apart * (other - x))) <= RIVAL_APART;
            // Hypotheses from different pairs often settle on one rival: it counts once.
            if same(xi) || counted.iter().any(same) {
                continue;
            }
            counted.push(other);
            if cost - own <= AMBIGUOUS_COST {
                rivals.ambiguous.push(other);
                continue;
            }
            let weight = rival_weight(cost - own);
            rivals.spread += d * d.transpose() * weight;
            total += weight;
        }
        rivals.spread /= total;
        rivals
    }

    /// Where the refined pose `xi` lies closest to the prior when moved along the directions
    /// towards its `ambiguous` rivals, and the prior's covariance within those directions;
    /// `None` without ambiguous rivals.
    fn settled_by_prior(
        &self,
        xi: &Vector6<f64>,
        ambiguous: &[Vector6<f64>],
    ) -> Option<(Vector6<f64>, Matrix6<f64>)> {
        // An orthonormal basis (in the prior's metric) of the directions to the rivals.
        let metric = &self.prior_information;
        let mut basis: Vec<Vector6<f64>> = Vec::new();
        for rival in ambiguous {
            let mut v = rival - xi;
            for b in &basis {
                v -= b * b.dot(&(metric * v));
            }
            let norm = v.dot(&(metric * v)).sqrt();
            if norm > 1e-6 {
                basis.push(v / norm);
            }
        }
        if basis.is_empty() {
            return None;
        }
        let mut settled = *xi;
        let mut along = Matrix6::zeros();
        for b in &basis {
            settled -= b * b.dot(&(metric * settled));
            along += b * b.transpose();
        }
        Some((settled, along))
    }
}

/// The rivals of a refined pose: the spread of those it outweighs, and those it does not
/// clearly outweigh.
struct Rivals {
    spread: Matrix6<f64>,
    ambiguous: Vec<Vector6<f64>>,
}

/// A rival within this much cost of the refined pose is not ruled out: 2 ln 100, a
/// likelihood under 100 times the rival's. Where the capture sees a row of like edges
/// running into ground the map has not seen yet, the pose one edge over explains one more
/// segment than the right one, a cost of up to [`INLIER_GATE`]; a rival left ambiguous is
/// settled by the prior instead (`Problem::settled_by_prior`). On the sparse panorama of
/// the service's tests the right pose costs 5.7 and 6.8 more than the one 19 cm off; on the
/// office with 3°/5 cm odometry a loop closure's refined pose, right, has a rival 12.5
/// worse, which the prior would have settled 4 cm off.
const AMBIGUOUS_COST: f64 = 9.21;

/// χ² with 6 degrees of freedom at 0.99: a hypothesis farther than this from the refined pose
/// is a rival, not the same solution found again.
const RIVAL_APART: f64 = 16.812;
/// Rivals costing more than this over the refined pose are not re-solved (their weight would
/// be under e^-7), and at most this many are.
pub(crate) const RIVAL_COST: f64 = 14.0;
const MAX_RIVALS: usize = 8;

/// A rival's weight in the mixture of a fit and its rivals: its likelihood against the fit's,
/// e^(−Δcost/2), one for a rival no worse than the fit.
pub(crate) fn rival_weight(more_cost: f64) -> f64 {
    (-more_cost.max(0.0) / 2.0).exp()
}

/// The uncertainty a hypothesis is scored with.
fn slack() -> Matrix6<f64> {
    let (r, t) = (
        HYPOTHESIS_SLACK_RAD * HYPOTHESIS_SLACK_RAD,
        HYPOTHESIS_SLACK_M * HYPOTHESIS_SLACK_M,
    );
    Matrix6::from_diagonal(&Vector6::new(r, r, r, t, t, t))
}

/// `r` on both 3x3 diagonal blocks of a 6x6.
pub(crate) fn block_diag(r: &Matrix3<f64>) -> Matrix6<f64> {
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(r);
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::test_room::edge;

    /// A box room's edges around the origin: floor and ceiling rectangles and the four
    /// vertical corners, plus a few shelves, each with an isotropic 5 mm covariance.
    fn room() -> Vec<Measured> {
        crate::map::test_room::box_room(0.005, false)
    }

    fn rotation_error_deg(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
        (a.rotation * b.rotation.inverse()).angle().to_degrees()
    }

    #[test]
    fn recovers_a_pose_several_degrees_and_centimetres_off() {
        let map = room();
        let truth = Isometry3::new(Vector3::new(0.3, -0.2, 1.2), Vector3::z() * 0.4);
        let capture: Vec<Measured> = map
            .iter()
            .map(|m| m.transformed(&truth.inverse()))
            .collect();
        let off = Isometry3::new(Vector3::new(0.04, -0.05, 0.01), Vector3::z() * 0.05);
        let prior = PosePrior::with_default_covariance(off * truth);
        let got = register(&map, &capture, &prior, &RegisterParams::default());
        assert_eq!(got.status, RegistrationStatus::Registered);
        assert!(got.inliers as usize >= map.len() - 2, "{}", got.inliers);
        assert!(rotation_error_deg(&got.rig_to_world, &truth) < 0.05);
        let dt = (got.rig_to_world.translation.vector - truth.translation.vector).norm();
        assert!(dt < 0.005, "{dt}");
        assert!(got.rotation_change_deg > 2.0);
        // The refined pose is far surer than the prior.
        assert!(got.covariance[(2, 2)] < 0.1 * prior.covariance[(2, 2)]);
    }

    #[test]
    fn keeps_the_prior_without_a_map_or_anything_in_common() {
        let map = room();
        let prior = PosePrior::with_default_covariance(Isometry3::identity());
        let empty = register(&[], &map, &prior, &RegisterParams::default());
        assert_eq!(empty.status, RegistrationStatus::EmptyMap);
        assert_eq!(empty.rig_to_world, prior.rig_to_world);
        // The capture's segments are 50 m away from everything in the map.
        let far = Isometry3::translation(50.0, 0.0, 0.0);
        let capture: Vec<Measured> = map.iter().map(|m| m.transformed(&far)).collect();
        let none = register(&map, &capture, &prior, &RegisterParams::default());
        assert_eq!(none.status, RegistrationStatus::TooFewInCommon);
        assert_eq!(none.rig_to_world, prior.rig_to_world);
        assert_eq!(none.covariance, prior.covariance);
    }

    /// A wall with only vertical edges in view: a radiator's fins 8 cm apart and a few door
    /// and cupboard edges, no certain segment in any other direction.
    fn vertical_edges() -> Vec<Measured> {
        let vertical = |x: f64, y: f64, z0: f64, z1: f64| {
            edge(Point3::new(x, y, z0), Point3::new(x, y, z1), 0.003)
        };
        let mut edges: Vec<Measured> = (0..10)
            .map(|k| vertical(-0.4 + 0.08 * k as f64, 3.0, 0.2, 0.8))
            .collect();
        for (x, y) in [
            (-1.6, 3.0),
            (-0.9, 3.0),
            (1.1, 3.0),
            (1.9, 2.2),
            (-2.2, 2.4),
        ] {
            edges.push(vertical(x, y, 0.0, 2.0));
        }
        edges
    }

    #[test]
    fn parallel_edges_apart_fix_the_heading_and_the_floor_position() {
        let map = vertical_edges();
        let truth = Isometry3::new(Vector3::new(0.2, -0.1, 1.2), Vector3::z() * 0.3);
        let capture: Vec<Measured> = map
            .iter()
            .map(|m| m.transformed(&truth.inverse()))
            .collect();
        // Odometry 2.5° and 5 cm off: from the prior alone the fins associate one over.
        let off = Isometry3::new(Vector3::new(-0.04, 0.03, 0.0), Vector3::z() * 0.044);
        let prior = PosePrior::with_default_covariance(Isometry3::from_parts(
            (truth.translation.vector + off.translation.vector).into(),
            off.rotation * truth.rotation,
        ));
        let got = register(&map, &capture, &prior, &RegisterParams::default());
        assert_eq!(got.status, RegistrationStatus::Registered);
        assert!(got.inliers as usize >= map.len() - 2, "{}", got.inliers);
        let (deg, m) = (
            rotation_error_deg(&got.rig_to_world, &truth),
            (got.rig_to_world.translation.vector - truth.translation.vector).norm(),
        );
        assert!(deg < 0.1 && m < 0.005, "{deg} deg, {m} m");
    }

    /// A wall at y = 3 with lines along x (x from -2 or -1.5 to `ends`): with [`post`], the
    /// rows the tests below register against.
    fn lines_along_x(ends: [f64; 4]) -> Vec<Measured> {
        let line = |a: [f64; 3], b: [f64; 3]| edge(Point3::from(a), Point3::from(b), 0.003);
        vec![
            line([-2.0, 3.0, 0.0], [ends[0], 3.0, 0.0]),
            line([-2.0, 3.0, 2.4], [ends[1], 3.0, 2.4]),
            line([-1.5, 2.5, 1.0], [ends[2], 2.5, 1.0]),
            line([-1.5, 2.8, 1.6], [ends[3], 2.8, 1.6]),
        ]
    }

    /// The `k`th vertical post of a row `pitch` apart from `first_x`, on that wall.
    fn post(first_x: f64, pitch: f64, k: usize) -> Measured {
        let x = first_x + pitch * k as f64;
        edge(Point3::new(x, 3.0, 0.2), Point3::new(x, 3.0, 0.8), 0.003)
    }

    /// The rig pose the row tests capture from.
    fn row_truth() -> Isometry3<f64> {
        Isometry3::new(Vector3::new(0.1, 0.2, 1.2), Vector3::z() * 0.1)
    }

    /// `world` as a rig at `rig_to_world` saw it.
    fn seen_from_rig(world: &[Measured], rig_to_world: &Isometry3<f64>) -> Vec<Measured> {
        world
            .iter()
            .map(|m| m.transformed(&rig_to_world.inverse()))
            .collect()
    }

    #[test]
    fn a_repetitive_row_leaves_its_direction_as_uncertain_as_the_alternatives() {
        // Lines along x fix everything but the position along x; only a radiator's fins fix
        // that, and the capture sees eight of the map's twelve: matched in place or one fin
        // over, it is explained exactly as well.
        let along_x = lines_along_x([2.0, 2.0, 1.5, 1.5]);
        let fin = |k| post(-0.44, 0.08, k);
        let map: Vec<Measured> = along_x.iter().copied().chain((0..12).map(fin)).collect();
        let seen: Vec<Measured> = along_x.iter().copied().chain((2..10).map(fin)).collect();
        let truth = row_truth();
        let capture = seen_from_rig(&seen, &truth);
        // The odometry is 6 cm off along x: nearer the fit one fin over than the true one.
        let prior =
            PosePrior::with_default_covariance(Isometry3::translation(0.06, 0.0, 0.0) * truth);
        let got = register(&map, &capture, &prior, &RegisterParams::default());
        assert_eq!(got.status, RegistrationStatus::Registered);
        let off = got.rig_to_world.translation.vector.x - truth.translation.vector.x;
        let sigma_x = got.covariance[(3, 3)].sqrt();
        // Wherever it lands, its covariance must own up to the other fit.
        assert!(sigma_x >= 0.02, "σx {sigma_x} m (off by {off} m)");
        assert!(off.abs() <= 3.0 * sigma_x, "off by {off} m, σx {sigma_x} m");
        // The other directions stay as sure as the lines make them.
        assert!(got.covariance[(4, 4)].sqrt() < 0.005);
    }

    #[test]
    fn a_row_running_into_unmapped_ground_is_placed_by_the_prior_along_it() {
        // The map has seen ten posts of a railing; the capture sees nine, the last of them
        // past the map's end. One post over, every post it sees has a partner in the map, so
        // that fit explains one segment more than the true one: what places the capture
        // along the row is only the odometry, and registration must not trade it for the fit.
        // (With the default prior's 5 cm, posts 15 cm apart leave the true fit 7 worse
        // than the one post over, within `AMBIGUOUS_COST`; under about 10 cm apart the
        // difference exceeds it, and the rivals' spread is what owns up to the row, as in
        // `a_repetitive_row_leaves_its_direction_as_uncertain_as_the_alternatives`.)
        let along_x = lines_along_x([2.0, 2.0, 1.5, 1.5]);
        let fin = |k| post(-0.75, 0.15, k);
        let map: Vec<Measured> = along_x.iter().copied().chain((0..10).map(fin)).collect();
        let seen: Vec<Measured> = along_x.iter().copied().chain((2..11).map(fin)).collect();
        let truth = row_truth();
        let capture = seen_from_rig(&seen, &truth);
        // The odometry is 2 cm off along the row, towards the fit one fin over, 3 cm off
        // across it and a degree off in heading.
        let odometry = Isometry3::new(Vector3::new(-0.02, 0.03, 0.0), Vector3::z() * 0.0175);
        let prior = PosePrior::with_default_covariance(odometry * truth);
        let got = register(&map, &capture, &prior, &RegisterParams::default());
        assert_eq!(got.status, RegistrationStatus::Registered);
        let off = got.rig_to_world.translation.vector - truth.translation.vector;
        let given = prior.rig_to_world.translation.vector - truth.translation.vector;
        // Along the row no farther from the truth than the odometry (the fit one post over is
        // 15 cm off), and the covariance says the row did not place it.
        assert!(
            off.x.abs() <= given.x.abs() + 1e-3,
            "{off:?}, given {given:?}"
        );
        assert!(
            got.covariance[(3, 3)].sqrt() >= 0.02,
            "{:?}",
            got.covariance
        );
        // What the lines fix is corrected: across the row and the heading.
        assert!(off.y.abs() < 0.005, "{off:?}");
        assert!(rotation_error_deg(&got.rig_to_world, &truth) < 0.1);
    }

    #[test]
    fn uprights_shorter_than_every_line_along_a_wall_still_place_the_capture_along_it() {
        // Ten long lines along x fix everything but the position along x, and they are the
        // capture's ten longest segments; five uprights, unevenly spaced so that only one fit
        // explains them, are what fixes x. The odometry is 15 cm off along x: hypotheses
        // seeded from the long lines alone stay where the prior puts them, and from there
        // the uprights are too far off to be associated.
        let mut world: Vec<Measured> = (0..10)
            .map(|k| {
                let z = 0.1 + 0.22 * k as f64;
                let y = 3.0 - 0.05 * (k % 3) as f64;
                edge(Point3::new(-2.0, y, z), Point3::new(1.5, y, z), 0.003)
            })
            .collect();
        world.extend(
            [-0.9, -0.55, 0.05, 0.3, 0.85]
                .map(|x| edge(Point3::new(x, 3.0, 0.2), Point3::new(x, 3.0, 0.8), 0.003)),
        );
        let truth = row_truth();
        let capture = seen_from_rig(&world, &truth);
        let prior =
            PosePrior::with_default_covariance(Isometry3::translation(0.15, 0.0, 0.0) * truth);
        let got = register(&world, &capture, &prior, &RegisterParams::default());
        assert_eq!(got.status, RegistrationStatus::Registered);
        let off = got.rig_to_world.translation.vector - truth.translation.vector;
        assert!(off.norm() < 0.01, "{off:?}");
        assert!(rotation_error_deg(&got.rig_to_world, &truth) < 0.1);
    }

    #[test]
    fn a_row_running_past_where_the_map_looked_is_not_moved_one_post_over() {
        // As above, posts 12 cm apart: one post over is then so much nearer the odometry that
        // the true fit costs 9.8 more, past `AMBIGUOUS_COST`. What tells them apart is where
        // the map's capture looked: its lines and posts end where its view did, and the post
        // the capture sees past them is one the map could not have had.
        let posts = |k| post(-0.6, 0.12, k);
        // The map's capture stood at (-0.5, 0.5) and its view ended at an azimuth of 67.5°,
        // between post 9 (68.6°) and post 10 (66.3°).
        let edge_of_view = |y: f64| -0.5 + (y - 0.5) / 67.5f64.to_radians().tan();
        let (wall, lower, upper) = (edge_of_view(3.0), edge_of_view(2.5), edge_of_view(2.8));
        let map: Vec<Measured> = lines_along_x([wall, wall, lower, upper])
            .into_iter()
            .chain((0..10).map(posts))
            .collect();
        let looked = Sector::of(Point3::new(-0.5, 0.5, 1.2), &map).expect("a span");
        let seen: Vec<Measured> = lines_along_x([1.5; 4])
            .into_iter()
            .chain((2..11).map(posts))
            .collect();
        let truth = row_truth();
        let capture = seen_from_rig(&seen, &truth);
        let odometry = Isometry3::new(Vector3::new(-0.02, 0.03, 0.0), Vector3::z() * 0.0175);
        let prior = PosePrior::with_default_covariance(odometry * truth);
        let params = RegisterParams::default();
        let off = |r: &Registration| r.rig_to_world.translation.vector - truth.translation.vector;
        let given = prior.rig_to_world.translation.vector - truth.translation.vector;
        // Not told where the map looked, registration takes the fit one post over.
        let blind = register(&map, &capture, &prior, &params);
        assert!(off(&blind).x < -0.1, "{:?}", off(&blind));
        // Told, the post past the view costs what an inlier would, the two fits are as good
        // as each other, and the odometry places the capture along the row.
        let got = register_seen(&map, &[looked], &capture, &prior, &params);
        assert_eq!(got.status, RegistrationStatus::Registered);
        assert!(
            off(&got).x.abs() <= given.x.abs() + 1e-3,
            "{:?}, given {given:?}",
            off(&got)
        );
        assert!(
            got.covariance[(3, 3)].sqrt() >= 0.02,
            "{:?}",
            got.covariance
        );
        assert!(off(&got).y.abs() < 0.005, "{:?}", off(&got));
        assert!(rotation_error_deg(&got.rig_to_world, &truth) < 0.1);
    }

    #[test]
    fn a_sector_spans_what_its_segments_cover_across_the_half_turn() {
        // Segments either side of the -x axis, where the azimuth wraps from π to -π.
        let line = |a: [f64; 3], b: [f64; 3]| edge(Point3::from(a), Point3::from(b), 0.003);
        let segments = [
            line([-3.0, 0.5, 0.0], [-3.0, 1.0, 0.0]),
            line([-3.0, -0.5, 0.0], [-3.0, -1.0, 0.0]),
        ];
        let sector = Sector::of(Point3::origin(), &segments).expect("a span");
        assert!(sector.covers(&Point3::new(-3.0, 0.0, 1.0)));
        assert!(sector.covers(&Point3::new(-3.0, 0.9, 0.0)));
        assert!(!sector.covers(&Point3::new(-3.0, 1.2, 0.0)));
        assert!(!sector.covers(&Point3::new(3.0, 0.0, 0.0)));
        // All round: no span.
        let around = [
            line([3.0, 0.0, 0.0], [3.0, 1.0, 0.0]),
            line([-3.0, 0.0, 0.0], [-3.0, 1.0, 0.0]),
            line([0.0, -3.0, 0.0], [1.0, -3.0, 0.0]),
        ];
        assert!(Sector::of(Point3::origin(), &around).is_none());
        assert!(Sector::of(Point3::origin(), &[]).is_none());
    }

    #[test]
    fn an_exact_prior_stays_put() {
        let map = room();
        let truth = Isometry3::new(Vector3::new(-0.4, 0.5, 1.0), Vector3::z() * -1.1);
        let capture: Vec<Measured> = map
            .iter()
            .map(|m| m.transformed(&truth.inverse()))
            .collect();
        let prior = PosePrior::with_default_covariance(truth);
        let got = register(&map, &capture, &prior, &RegisterParams::default());
        assert_eq!(got.status, RegistrationStatus::Registered);
        assert!(got.rotation_change_deg < 1e-6);
        assert!(got.translation_change_m < 1e-6);
    }
}
