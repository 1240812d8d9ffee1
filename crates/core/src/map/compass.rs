//! The room as a compass: most of a building's horizontal edges run along two perpendicular
//! directions, so the directions of a capture's horizontal 3D segments fix its heading up to
//! a quarter turn — even against a capture it shares no segment with.
//!
//! A robot's odometry loses its heading by a degree or more per turn, and segment
//! registration can only win it back where the map and the capture see the same edges: a
//! capture facing a bare wall, or the far side of a loop, keeps the odometry's error and
//! hands it on to every capture registered after it. A heading error is the costliest error
//! a map has (1° is 5 cm at 3 m, over the map's tolerance), and the compass fixes it from
//! any horizontal edges at all. [`reading`] finds the dominant horizontal direction of a
//! capture's certain segments, modulo 90°, with its precision; the difference of two
//! captures' readings, taken within a quarter turn of what their poses say, is their
//! relative heading ([`relative_heading`]).
//!
//! Where a room is not built so — no dominant direction, or two rival ones (a wing turned
//! by 30°, a desk turned by 4° filling the view) — a capture gives no reading and nothing
//! changes. A reading that disagrees with the poses by more than their spread is not used.

use nalgebra::{Isometry3, Matrix3, Matrix6, UnitQuaternion, Vector3};

use super::register::{Measured, PosePrior};

/// A capture's dominant horizontal direction in the world frame, modulo a quarter turn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// Radians, in (−π/4, π/4]: the angle from world x of the edges along one of the room's
    /// two directions (those along the other are at this angle + π/2).
    pub angle: f64,
    /// Standard deviation of `angle`, radians.
    pub sigma: f64,
    /// The segments that agree on it.
    pub segments: usize,
}

/// A segment counts as horizontal when its direction rises less than this (sine of the
/// slope, about 6°): the rig's tilt is known to a few tenths of a degree and a certain
/// segment's direction to a few degrees, so a horizontal edge passes and a vertical or a
/// sloping one does not.
const HORIZONTAL_SLOPE: f64 = 0.1;
/// Segments whose direction about the vertical is known worse than this (1σ, radians: 2°)
/// say little about a quarter of a degree, and are left out.
const MAX_SEGMENT_SIGMA: f64 = 0.035;
/// How far a room's edges stray from its two directions, added to each segment's own
/// direction noise (radians: 0.25°): walls and furniture are square to a fraction of a
/// degree, not exactly — and no single segment, however long, speaks for the whole room.
const BUILT_SIGMA: f64 = 0.0044;
/// Segments within this of the dominant direction agree with it (radians: 1°).
const AGREE: f64 = 0.0175;
/// A direction more than `2 · AGREE` from the dominant one, with at least this share of its
/// weight, makes the reading ambiguous.
const RIVAL_SHARE: f64 = 0.5;
/// Fewest segments a reading needs.
const MIN_SEGMENTS: usize = 3;
/// Most segments a reading compares (pairwise): the most precise are kept. A room's capture
/// has tens of horizontal certain segments, a large real photograph's a few hundred.
const MAX_READ: usize = 512;
/// The reading's precision is never taken to be better than this (radians: 0.05°).
const MIN_SIGMA: f64 = 0.00087;

/// `a` taken into (−π/4, π/4] modulo a quarter turn.
pub fn quarter_wrap(a: f64) -> f64 {
    let q = std::f64::consts::FRAC_PI_2;
    let r = a - q * (a / q).round();
    if r <= -q / 2.0 {
        r + q
    } else {
        r
    }
}

/// The dominant horizontal direction of `segments` (rig frame) once turned by `rotation`
/// (rig to world), or `None` when too few certain horizontal segments agree, or two
/// directions rival each other.
pub fn reading(segments: &[Measured], rotation: &UnitQuaternion<f64>) -> Option<Reading> {
    let r = rotation.to_rotation_matrix().into_inner();
    // (angle, weight) of each certain horizontal segment, in the world.
    let mut directions: Vec<(f64, f64)> = segments
        .iter()
        .filter(|m| !m.uncertain)
        .filter_map(|m| direction_about_vertical(m, &r))
        .collect();
    // The mode search compares every pair: a capture of a client's making with tens of
    // thousands of segments is read from its most precise few hundred, in their own order.
    if directions.len() > MAX_READ {
        let mut by_weight: Vec<usize> = (0..directions.len()).collect();
        by_weight.sort_by(|&a, &b| directions[b].1.total_cmp(&directions[a].1).then(a.cmp(&b)));
        by_weight.truncate(MAX_READ);
        by_weight.sort_unstable();
        directions = by_weight.into_iter().map(|k| directions[k]).collect();
    }
    if directions.len() < MIN_SEGMENTS {
        return None;
    }
    let support = |centre: f64| -> f64 {
        directions
            .iter()
            .map(|&(a, w)| {
                let d = quarter_wrap(a - centre) / AGREE;
                w * (1.0 - d * d).max(0.0)
            })
            .sum()
    };
    let supports: Vec<f64> = directions.iter().map(|&(a, _)| support(a)).collect();
    let best = (0..directions.len()).max_by(|&a, &b| supports[a].total_cmp(&supports[b]))?;
    let mode = directions[best].0;
    let rival = directions
        .iter()
        .zip(&supports)
        .filter(|((a, _), _)| quarter_wrap(a - mode).abs() > 2.0 * AGREE)
        .map(|(_, &s)| s)
        .fold(0.0, f64::max);
    if rival > RIVAL_SHARE * supports[best] {
        return None;
    }
    // The weighted mean of the agreeing segments, measured from the mode (no wrap inside).
    let agreeing: Vec<(f64, f64)> = directions
        .iter()
        .map(|&(a, w)| (quarter_wrap(a - mode), w))
        .filter(|(d, _)| d.abs() <= AGREE)
        .collect();
    if agreeing.len() < MIN_SEGMENTS {
        return None;
    }
    let total: f64 = agreeing.iter().map(|(_, w)| w).sum();
    let offset = agreeing.iter().map(|(d, w)| d * w).sum::<f64>() / total;
    // Segments that scatter more than their noise says widen the reading by as much.
    let chi2: f64 = agreeing
        .iter()
        .map(|(d, w)| w * (d - offset) * (d - offset))
        .sum();
    let scatter = (chi2 / (agreeing.len() - 1) as f64).max(1.0);
    Some(Reading {
        angle: quarter_wrap(mode + offset),
        sigma: (scatter / total).sqrt().max(MIN_SIGMA),
        segments: agreeing.len(),
    })
}

/// A segment's direction about the vertical (world, radians) and its weight (the inverse
/// variance of that angle, the room's own squareness included), when it is certain enough
/// and horizontal.
fn direction_about_vertical(m: &Measured, rig_to_world: &Matrix3<f64>) -> Option<(f64, f64)> {
    let d = rig_to_world * (m.end - m.start);
    let length = d.norm();
    let level = d.x.hypot(d.y);
    if length == 0.0 || d.z.abs() > HORIZONTAL_SLOPE * length {
        return None;
    }
    // The ends' difference across the line, in the horizontal plane.
    let across = rig_to_world.transpose() * Vector3::new(-d.y, d.x, 0.0) / level;
    let c = &m.covariance;
    let difference = c.fixed_view::<3, 3>(0, 0) + c.fixed_view::<3, 3>(3, 3)
        - c.fixed_view::<3, 3>(0, 3)
        - c.fixed_view::<3, 3>(3, 0);
    let variance = across.dot(&(difference * across)) / (level * level);
    if !variance.is_finite() || variance > MAX_SEGMENT_SIGMA * MAX_SEGMENT_SIGMA {
        return None;
    }
    Some((d.y.atan2(d.x), 1.0 / (variance + BUILT_SIGMA * BUILT_SIGMA)))
}

/// The readings of several captures as one, each given with the variance of its capture's
/// heading (its reading is in the world only as well as its pose is): the
/// information-weighted mean of those that agree with the reading most of the others agree
/// with (within [`READING_GATE`] of their joint spread; by count of captures, then weight),
/// and which agreed. A capture whose
/// view a desk set askew fills reads that desk, and one such reading in a plain mean would
/// turn every capture that trusts it.
pub fn consensus(readings: &[(Reading, f64)]) -> Option<(Reading, Vec<bool>)> {
    let variance = |(r, heading): &(Reading, f64)| r.sigma * r.sigma + heading;
    let agree = |a: &(Reading, f64), b: &(Reading, f64)| {
        let d = quarter_wrap(a.0.angle - b.0.angle);
        d * d <= READING_GATE * (variance(a) + variance(b))
    };
    // The reading the most captures agree with — each capture one vote, however precise it
    // claims to be: a desk read sharply is still one desk — then the most weight (ties: the
    // first, the anchor's).
    let support = |c: &(Reading, f64)| -> (usize, f64) {
        readings
            .iter()
            .filter(|r| agree(c, r))
            .fold((0, 0.0), |(n, w), r| (n + 1, w + 1.0 / variance(r)))
    };
    let mut best: Option<(usize, (usize, f64))> = None;
    for (k, c) in readings.iter().enumerate() {
        let s = support(c);
        if best.is_none_or(|(_, b)| s.0 > b.0 || (s.0 == b.0 && s.1 > b.1)) {
            best = Some((k, s));
        }
    }
    let centre = &readings[best?.0];
    let agreeing: Vec<bool> = readings.iter().map(|r| agree(centre, r)).collect();
    let (mut weights, mut sum, mut segments) = (0.0, 0.0, 0);
    for (r, _) in readings.iter().zip(&agreeing).filter(|(_, &a)| a) {
        let w = 1.0 / variance(r);
        weights += w;
        sum += w * quarter_wrap(r.0.angle - centre.0.angle);
        segments += r.0.segments;
    }
    Some((
        Reading {
            angle: quarter_wrap(centre.0.angle + sum / weights),
            sigma: weights.recip().sqrt(),
            segments,
        },
        agreeing,
    ))
}

/// The heading (about world z, radians) that would turn a capture read as `own` so that it
/// agrees with `other`, the nearest of the quarter turns, and the variance of that turn.
pub fn relative_heading(own: &Reading, other: &Reading) -> (f64, f64) {
    (
        quarter_wrap(other.angle - own.angle),
        own.sigma * own.sigma + other.sigma * other.sigma,
    )
}

/// χ² with one degree of freedom at 0.999: a reading further than this from what the poses
/// say (under both spreads) is not believed.
pub const READING_GATE: f64 = 10.83;

/// `prior` with a heading measurement fused in: the measurement says the pose should turn by
/// `turn` about world z, with variance `variance`. A measurement the prior cannot reconcile
/// (beyond [`READING_GATE`]) leaves it as it is.
pub fn with_heading(prior: &PosePrior, turn: f64, variance: f64) -> PosePrior {
    // The heading is the perturbation's third component (rotation about world z).
    const Z: usize = 2;
    let p = &prior.covariance;
    let innovation_variance = p[(Z, Z)] + variance;
    // Not positive (or NaN): nothing to weigh the turn by.
    let weighable = innovation_variance > 0.0;
    if !weighable || turn * turn > READING_GATE * innovation_variance {
        return *prior;
    }
    let gain = p.column(Z) / innovation_variance;
    let step = gain * turn;
    let covariance: Matrix6<f64> = p - gain * p.row(Z);
    PosePrior {
        rig_to_world: super::poses::perturbed(&prior.rig_to_world, &step),
        covariance: (covariance + covariance.transpose()) * 0.5,
    }
}

/// The relative pose `from`-rig-to-`to`-rig that turns `from` by `turn` about world z from
/// where `from_pose` has it, and the information of that relative pose in its heading alone
/// (in `to`'s frame, as [`super::poses::RelativePose::information`]).
pub fn heading_edge(
    from_pose: &Isometry3<f64>,
    to_pose: &Isometry3<f64>,
    turn: f64,
    variance: f64,
) -> (Isometry3<f64>, Matrix6<f64>) {
    let turned = super::poses::perturbed(
        from_pose,
        &nalgebra::Vector6::new(0.0, 0.0, turn, 0.0, 0.0, 0.0),
    );
    let vertical = to_pose.rotation.inverse() * Vector3::z();
    let mut information = Matrix6::zeros();
    information
        .fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(vertical * vertical.transpose() / variance));
    (to_pose.inverse() * turned, information)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Vector6};

    /// A segment from `a` to `b` (rig frame) with `sigma` metres of isotropic noise per end.
    fn segment(a: [f64; 3], b: [f64; 3], sigma: f64) -> Measured {
        Measured {
            start: Point3::from(a),
            end: Point3::from(b),
            covariance: Matrix6::identity() * sigma * sigma,
            uncertain: false,
        }
    }

    /// Horizontal edges of a square room turned by `angle` about the vertical: along both
    /// of its directions, at several heights, and a few verticals that say nothing.
    fn square_room(angle: f64) -> Vec<Measured> {
        let turn = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), angle);
        let mut all = Vec::new();
        for (k, height) in [0.1, 0.8, 1.5, 2.3].iter().enumerate() {
            let along = 1.0 + 0.3 * k as f64;
            let x = turn * Point3::new(3.0, -along / 2.0, *height);
            let y = turn * Point3::new(3.0, along / 2.0, *height);
            all.push(segment(x.coords.into(), y.coords.into(), 0.003));
            let u = turn * Point3::new(-along / 2.0, 2.0, *height);
            let v = turn * Point3::new(along / 2.0, 2.0, *height);
            all.push(segment(u.coords.into(), v.coords.into(), 0.003));
            let p = turn * Point3::new(2.0 + 0.2 * k as f64, 1.0, 0.0);
            all.push(segment(
                p.coords.into(),
                (p.coords + Vector3::z()).into(),
                0.003,
            ));
        }
        all
    }

    #[test]
    fn a_quarter_wrap_keeps_angles_within_an_eighth_of_a_turn() {
        for a in [-7.0, -1.0, -0.78, 0.0, 0.3, 0.785, 1.2, 5.0] {
            let w = quarter_wrap(a);
            let q = std::f64::consts::FRAC_PI_2;
            assert!(w > -q / 2.0 && w <= q / 2.0, "{a} -> {w}");
            let turns = (a - w) / q;
            assert!((turns - turns.round()).abs() < 1e-12, "{a} -> {w}");
        }
    }

    #[test]
    fn a_square_room_reads_its_turn_whatever_the_rig_heading() {
        let room_turn = 0.2;
        for heading in [0.0, 0.4, -1.3, 2.9] {
            let rig = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), heading);
            // The room as the rig sees it: turned back by the rig's heading.
            let seen: Vec<Measured> = square_room(room_turn)
                .iter()
                .map(|m| m.transformed(&Isometry3::from_parts(Default::default(), rig.inverse())))
                .collect();
            let got = reading(&seen, &rig).expect("a square room reads");
            assert!(
                quarter_wrap(got.angle - room_turn).abs() < 1e-9,
                "{heading}: {got:?}"
            );
            assert_eq!(got.segments, 8);
            assert!(got.sigma > 0.0 && got.sigma < BUILT_SIGMA, "{got:?}");
        }
    }

    /// A capture with far more segments than a room shows is read from its most precise
    /// ones, in bounded work, and still reads its room.
    #[test]
    fn a_crowd_of_segments_is_read_from_its_most_precise() {
        let room = square_room(0.1);
        let mut crowd: Vec<Measured> = (0..70).flat_map(|_| room.iter().copied()).collect();
        // Imprecise segments askew, three times as many: left out for the precise ones.
        for k in 0..3 * crowd.len() {
            let a = 0.5 + 0.001 * (k % 7) as f64;
            crowd.push(segment([0.0, 0.0, 1.0], [a.cos(), a.sin(), 1.0], 0.004));
        }
        assert!(crowd.len() > 4 * MAX_READ);
        let got = reading(&crowd, &UnitQuaternion::identity()).expect("the room reads");
        assert!(quarter_wrap(got.angle - 0.1).abs() < 1e-9, "{got:?}");
        assert_eq!(got.segments, MAX_READ);
    }

    #[test]
    fn two_rival_directions_give_no_reading() {
        let mut room = square_room(0.0);
        room.extend(square_room(0.5));
        assert_eq!(reading(&room, &UnitQuaternion::identity()), None);
        // One of them clearly stronger reads, rivals a fifth as strong aside.
        let mut room = square_room(0.0);
        room.extend(square_room(0.0));
        room.extend(square_room(0.5).into_iter().take(3));
        let got = reading(&room, &UnitQuaternion::identity()).expect("one direction dominates");
        assert!(got.angle.abs() < 1e-9, "{got:?}");
    }

    #[test]
    fn uncertain_vertical_and_imprecise_segments_give_no_reading() {
        let uncertain: Vec<Measured> = square_room(0.0)
            .into_iter()
            .map(|m| Measured {
                uncertain: true,
                ..m
            })
            .collect();
        assert_eq!(reading(&uncertain, &UnitQuaternion::identity()), None);
        let imprecise: Vec<Measured> = square_room(0.0)
            .into_iter()
            .map(|m| Measured {
                covariance: Matrix6::identity() * 0.1,
                ..m
            })
            .collect();
        assert_eq!(reading(&imprecise, &UnitQuaternion::identity()), None);
    }

    #[test]
    fn the_consensus_of_readings_leaves_out_the_one_that_read_a_desk_askew() {
        let at = |degrees: f64, sigma_deg: f64| Reading {
            angle: degrees.to_radians(),
            sigma: sigma_deg.to_radians(),
            segments: 10,
        };
        let heading = 0.05f64.to_radians().powi(2);
        let readings = [
            (at(0.1, 0.2), heading),
            (at(36.3, 0.1), heading),
            (at(-0.1, 0.2), heading),
            (at(89.9, 0.2), heading),
        ];
        let (got, agreeing) = consensus(&readings).expect("readings agree");
        assert_eq!(agreeing, [true, false, true, true]);
        // 89.9° is −0.1° a quarter turn on: the three agree about 0°.
        assert!(got.angle.to_degrees().abs() < 0.05, "{got:?}");
        assert_eq!(got.segments, 30);
        assert!(got.sigma < readings[0].0.sigma);
        assert_eq!(consensus(&[]), None);
    }

    #[test]
    fn a_heading_measurement_moves_the_prior_by_its_share_and_narrows_it() {
        let prior = PosePrior::odometry(Isometry3::identity(), 1.0, 0.3, 0.02, 0.01);
        let yaw_variance = 1f64.to_radians().powi(2);
        // A measurement as precise as the prior: half way, half the variance.
        let turn = 0.5f64.to_radians();
        let got = with_heading(&prior, turn, yaw_variance);
        let moved = got.rig_to_world.rotation.scaled_axis();
        assert!((moved.z - turn / 2.0).abs() < 1e-12, "{moved}");
        assert!((got.covariance[(2, 2)] - yaw_variance / 2.0).abs() < 1e-15);
        assert_eq!(got.rig_to_world.translation, prior.rig_to_world.translation);
        assert_eq!(got.covariance[(3, 3)], prior.covariance[(3, 3)]);
        // One the prior rules out (10° against 1° and 1°) changes nothing.
        assert_eq!(
            with_heading(&prior, 10f64.to_radians(), yaw_variance),
            prior
        );
    }

    #[test]
    fn a_heading_edge_says_the_turn_in_the_frame_of_its_target() {
        let from = Isometry3::new(Vector3::new(1.0, 2.0, 1.2), Vector3::new(0.01, -0.02, 0.7));
        let to = Isometry3::new(Vector3::new(-1.0, 0.5, 1.1), Vector3::new(0.02, 0.01, -0.4));
        let turn = 0.01;
        let (pose, information) = heading_edge(&from, &to, turn, 1e-6);
        // The relative pose the edge states, against the one the poses give: a turn about
        // world z, seen in `to`'s frame.
        let difference = super::super::poses::difference(&pose, &(to.inverse() * from));
        let vertical = to.rotation.inverse() * Vector3::z();
        let expected = Vector6::new(
            vertical.x * turn,
            vertical.y * turn,
            vertical.z * turn,
            0.0,
            0.0,
            0.0,
        );
        assert!((difference - expected).amax() < 1e-9, "{difference}");
        // Its χ² is the turn's, in units of its variance: 100.
        let chi2 = difference.dot(&(information * difference));
        assert!((chi2 - 100.0).abs() < 1e-6, "{chi2}");
    }
}
