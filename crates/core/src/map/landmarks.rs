//! The room's long horizontal lines as landmarks of position: the compass's counterpart for
//! where a capture stands.
//!
//! Registration ties a capture to the map through the segments both saw; a capture that sees
//! another stretch of the same wall, or the far end of a desk the map saw the near end of,
//! shares no segment with the map and keeps its odometry's position. But a long horizontal
//! line is one line however little of it each capture saw: the floor's edge along a wall says
//! how far from that wall the rig stood, across the line, wherever along it the capture
//! looked. [`line_edges`] finds, for each long certain horizontal segment of a new capture,
//! the one line of an earlier capture it continues — parallel, at the same height, across the
//! line within the two poses' spread, and no rival line within it — and turns the lines found
//! against each earlier capture into one edge of the pose graph whose information lies across
//! those lines alone (and in the heading, through each line's lever arm from the rig).
//!
//! A line whose offset is known only far from where it was seen is known by as much less:
//! each offset is compared where the two segments' middles meet, and a segment extrapolated
//! there carries its direction's spread over the distance.

use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, RowVector6, SymmetricEigen, Vector3};

use super::poses::{perturbed, RelativePose};
use super::register::{block_diag, Measured, PosePrior};

/// Shortest segment used as a landmark, metres: a short segment's line is poorly placed
/// once extrapolated, and short horizontal edges are mostly furniture.
pub const MIN_LENGTH_M: f64 = 0.3;
/// A landmark's direction rises less than this (sine of the slope, about 3°).
const HORIZONTAL_SLOPE: f64 = 0.05;
/// Two lines are one only when their horizontal directions agree within this (sine, ~1.5°):
/// the compass has set the heading to a tenth of a degree.
const PARALLEL_SINE: f64 = 0.026;
/// A capture's landmarks are its longest this many: each is compared with every landmark of
/// up to nine earlier captures, and a client's capture may hold tens of thousands of
/// segments (a room's walls give a few dozen).
pub const MAX_LANDMARKS: usize = 128;
/// χ²₁ at 0.999: an offset is within the poses' spread, and two candidates are one line.
const GATE: f64 = 10.83;
/// What no segment's covariance says about a room's lines, metres (1σ across): walls bow and
/// floors are not flat, by a few millimetres over a room.
const BUILT_SIGMA_M: f64 = 0.01;

/// A landmark segment in the world: its ends, their covariance (world axes, the capture's
/// pose uncertainty not included), and the rig that saw it.
#[derive(Debug, Clone, Copy)]
struct Landmark {
    start: Point3<f64>,
    end: Point3<f64>,
    covariance: Matrix6<f64>,
    rig: Point3<f64>,
}

impl Landmark {
    /// The capture's long certain horizontal segments, placed by `pose`: the
    /// [`MAX_LANDMARKS`] longest, in their own order.
    fn all(segments: &[Measured], pose: &Isometry3<f64>) -> Vec<Landmark> {
        let rig = Point3::from(pose.translation.vector);
        let mut all: Vec<Landmark> = segments
            .iter()
            .filter(|m| !m.uncertain)
            .map(|m| m.transformed(pose))
            .filter(|m| {
                let d = m.end - m.start;
                let length = d.norm();
                length >= MIN_LENGTH_M
                    && d.z.abs() <= HORIZONTAL_SLOPE * length
                    && m.covariance.iter().all(|v| v.is_finite())
            })
            .map(|m| Landmark {
                start: m.start,
                end: m.end,
                covariance: m.covariance,
                rig,
            })
            .collect();
        if all.len() > MAX_LANDMARKS {
            let length = |l: &Landmark| (l.end - l.start).norm();
            let mut by_length: Vec<usize> = (0..all.len()).collect();
            by_length.sort_by(|&a, &b| length(&all[b]).total_cmp(&length(&all[a])).then(a.cmp(&b)));
            by_length.truncate(MAX_LANDMARKS);
            by_length.sort_unstable();
            all = by_length.into_iter().map(|k| all[k]).collect();
        }
        all
    }

    fn horizontal_direction(&self) -> Vector3<f64> {
        let d = self.end - self.start;
        Vector3::new(d.x, d.y, 0.0).normalize()
    }

    fn middle(&self) -> Point3<f64> {
        Point3::from((self.start.coords + self.end.coords) * 0.5)
    }

    /// The point of the line at `place`'s abscissa along `along` (a horizontal unit vector),
    /// and the variance of its component along `normal` from the ends' covariance.
    fn at(
        &self,
        place: &Point3<f64>,
        along: &Vector3<f64>,
        normal: &Vector3<f64>,
    ) -> (Point3<f64>, f64) {
        let d = self.end - self.start;
        let t = (place - self.start).dot(along) / d.dot(along);
        let point = self.start + d * t;
        let w = RowVector6::new(
            (1.0 - t) * normal.x,
            (1.0 - t) * normal.y,
            (1.0 - t) * normal.z,
            t * normal.x,
            t * normal.y,
            t * normal.z,
        );
        (point, (w * self.covariance * w.transpose())[(0, 0)])
    }
}

/// How a pose's perturbation (rotation vector about the rig's origin, world axes, then
/// translation) moves a point `lever` from the rig along `normal`.
fn jacobian(lever: &Vector3<f64>, normal: &Vector3<f64>) -> RowVector6<f64> {
    let r = lever.cross(normal);
    RowVector6::new(r.x, r.y, r.z, normal.x, normal.y, normal.z)
}

/// One landmark of the new capture found on an earlier capture's line.
#[derive(Debug, Clone, Copy)]
struct Found {
    /// The earlier capture.
    to: usize,
    /// How the new capture's pose moves the offset, and the offset (new minus earlier, m).
    jacobian: RowVector6<f64>,
    offset: f64,
    /// Of the two segments' lines alone, the room's straightness included.
    variance: f64,
    /// Of the earlier capture's segment alone: two candidates' offsets differ by their own
    /// lines' noise, the new capture's line being common to both.
    their_variance: f64,
    /// Of the earlier capture's pose, along the line's normal.
    to_variance: f64,
}

/// The edges the new capture `from` (its rig-frame `segments`, placed at `pose`) gets from
/// the long horizontal lines it continues in the captures `candidates` (each with its
/// segments and its pose in the session), one edge per earlier capture that gives any.
/// Captures in `tied` already have an edge from the new one (registration found segments in
/// common) and give none: the same lines would count twice.
pub fn line_edges(
    from: usize,
    segments: &[Measured],
    pose: &PosePrior,
    candidates: &[(usize, &[Measured], PosePrior)],
    tied: &[usize],
) -> Vec<RelativePose> {
    let own = Landmark::all(segments, &pose.rig_to_world);
    if own.is_empty() {
        return Vec::new();
    }
    let theirs: Vec<(usize, &PosePrior, Vec<Landmark>)> = candidates
        .iter()
        .filter(|(j, _, _)| *j != from && !tied.contains(j))
        .map(|(j, s, p)| (*j, p, Landmark::all(s, &p.rig_to_world)))
        .filter(|(_, _, l)| !l.is_empty())
        .collect();
    let mut found: Vec<Found> = Vec::new();
    for mine in &own {
        let along = mine.horizontal_direction();
        let mut matches: Vec<Found> = Vec::new();
        for (j, their_pose, lines) in &theirs {
            for line in lines {
                let theirs_along = line.horizontal_direction();
                if along.cross(&theirs_along).z.abs() > PARALLEL_SINE {
                    continue;
                }
                let normal = Vector3::new(-theirs_along.y, theirs_along.x, 0.0);
                let place = Point3::from((mine.middle().coords + line.middle().coords) * 0.5);
                let (p, vp) = mine.at(&place, &theirs_along, &normal);
                let (q, vq) = line.at(&place, &theirs_along, &normal);
                let (_, vpz) = mine.at(&place, &theirs_along, &Vector3::z());
                let (_, vqz) = line.at(&place, &theirs_along, &Vector3::z());
                let j_mine = jacobian(&(p - mine.rig), &normal);
                let j_theirs = jacobian(&(q - line.rig), &normal);
                let spread =
                    |j: &RowVector6<f64>, c: &Matrix6<f64>| (j * c * j.transpose())[(0, 0)];
                let variance = vp + vq + 2.0 * BUILT_SIGMA_M * BUILT_SIGMA_M;
                let to_variance = spread(&j_theirs, &their_pose.covariance);
                let offset = (p - q).dot(&normal);
                let within = offset * offset
                    <= GATE * (variance + to_variance + spread(&j_mine, &pose.covariance));
                let z_mine = jacobian(&(p - mine.rig), &Vector3::z());
                let z_theirs = jacobian(&(q - line.rig), &Vector3::z());
                let rise = p.z - q.z;
                let level = rise * rise
                    <= GATE
                        * (vpz
                            + vqz
                            + 2.0 * BUILT_SIGMA_M * BUILT_SIGMA_M
                            + spread(&z_mine, &pose.covariance)
                            + spread(&z_theirs, &their_pose.covariance));
                if within && level {
                    matches.push(Found {
                        to: *j,
                        jacobian: j_mine,
                        offset,
                        variance,
                        their_variance: vq,
                        to_variance,
                    });
                }
            }
        }
        // Two lines within the spread that are not one line (a board in front of the wall,
        // a desk's two edges): the capture could be on either, so on neither. Whether they
        // are one is the earlier captures' to say, not the room's straightness: a line that
        // bows is then taken for two, and gives no edge.
        let one_line = matches.iter().all(|a| {
            matches.iter().all(|b| {
                let d = a.offset - b.offset;
                d * d
                    <= GATE * (a.their_variance + b.their_variance + a.to_variance + b.to_variance)
            })
        });
        if !one_line {
            continue;
        }
        if let Some(best) = matches
            .into_iter()
            .min_by(|a, b| (a.variance + a.to_variance).total_cmp(&(b.variance + b.to_variance)))
        {
            found.push(best);
        }
    }
    let mut targets: Vec<usize> = found.iter().map(|f| f.to).collect();
    targets.sort_unstable();
    targets.dedup();
    targets
        .into_iter()
        .filter_map(|to| {
            let lines: Vec<&Found> = found.iter().filter(|f| f.to == to).collect();
            let at = candidates.iter().find(|(j, _, _)| *j == to)?.2;
            edge(from, to, pose, &at.rig_to_world, &lines)
        })
        .collect()
}

/// The edge the `lines` found against capture `to` (at `to_pose`) give the new capture at
/// `pose`: its pose shifted (translation only) to the least-squares fit of the offsets, the
/// information of the lines in `to`'s frame; `None` when the lines disagree among themselves.
fn edge(
    from: usize,
    to: usize,
    pose: &PosePrior,
    to_pose: &Isometry3<f64>,
    lines: &[&Found],
) -> Option<RelativePose> {
    let mut information = Matrix6::zeros();
    let mut gradient = Vector3::zeros();
    for f in lines {
        let j = f.jacobian;
        information += j.transpose() * j / f.variance;
        let normal = Vector3::new(j[3], j[4], j[5]);
        gradient += normal * (f.offset / f.variance);
    }
    // The shift of the translation alone that best cancels the offsets: a rotation could
    // cancel them too, through the lines' lever arms, but the heading is the compass's.
    let translation: Matrix3<f64> = information.fixed_view::<3, 3>(3, 3).into_owned();
    let eig = SymmetricEigen::new(translation);
    let largest = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
    if largest <= 0.0 || !largest.is_finite() {
        return None;
    }
    let mut shift = Vector3::zeros();
    for k in 0..3 {
        let value = eig.eigenvalues[k];
        if value > 1e-9 * largest {
            let v = eig.eigenvectors.column(k);
            shift -= v * (v.dot(&gradient) / value);
        }
    }
    let agree = lines.iter().all(|f| {
        let normal = Vector3::new(f.jacobian[3], f.jacobian[4], f.jacobian[5]);
        let residual = f.offset + normal.dot(&shift);
        residual * residual <= GATE * f.variance
    });
    if !agree {
        return None;
    }
    let shifted = perturbed(
        &pose.rig_to_world,
        &nalgebra::Vector6::new(0.0, 0.0, 0.0, shift.x, shift.y, shift.z),
    );
    // Into `to`'s frame: both the rotation vector and the translation turn with it.
    let turn = block_diag(
        &to_pose
            .rotation
            .to_rotation_matrix()
            .into_inner()
            .transpose(),
    );
    Some(RelativePose {
        from,
        to,
        pose: to_pose.inverse() * shifted,
        information: turn * information * turn.transpose(),
        inliers: lines.len() as u32,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector6};

    /// A segment between world points `a` and `b` as the rig at `pose` measures it, each end
    /// known to `sigma` metres in every direction.
    fn seen(pose: &Isometry3<f64>, a: [f64; 3], b: [f64; 3], sigma: f64) -> Measured {
        Measured {
            start: pose.inverse() * Point3::from(a),
            end: pose.inverse() * Point3::from(b),
            covariance: Matrix6::identity() * sigma * sigma,
            uncertain: false,
        }
    }

    fn rig(x: f64, y: f64, yaw_deg: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, y, 1.2),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians()),
        )
    }

    /// A robot's prior: `yaw_deg` and `xy_m` of spread (1σ), little tilt and height.
    fn prior(pose: Isometry3<f64>, yaw_deg: f64, xy_m: f64) -> PosePrior {
        let (tilt, yaw, z) = (0.3f64.to_radians(), yaw_deg.to_radians(), 0.01);
        PosePrior {
            rig_to_world: pose,
            covariance: Matrix6::from_diagonal(&Vector6::new(
                tilt * tilt,
                tilt * tilt,
                yaw * yaw,
                xy_m * xy_m,
                xy_m * xy_m,
                z * z,
            )),
        }
    }

    fn pinned(pose: Isometry3<f64>) -> PosePrior {
        PosePrior {
            rig_to_world: pose,
            covariance: Matrix6::identity() * 1e-12,
        }
    }

    /// The anchor sees the floor's edge along the wall y = 3 from x = 0 to 1.2; the new
    /// capture, 2 m along, sees the same edge from x = 2.4 to 3.6 and nothing the anchor saw.
    fn wall_seen_twice(new_truth: &Isometry3<f64>) -> (Vec<Measured>, Vec<Measured>) {
        let anchor = rig(0.5, 1.0, 0.0);
        let theirs = vec![seen(&anchor, [0.0, 3.0, 0.0], [1.2, 3.0, 0.0], 0.002)];
        let mine = vec![seen(new_truth, [2.4, 3.0, 0.0], [3.6, 3.0, 0.0], 0.002)];
        (theirs, mine)
    }

    #[test]
    fn a_capture_that_continues_a_wall_line_is_placed_across_it_and_not_along_it() {
        let truth = rig(3.0, 1.2, 0.0);
        let (theirs, mine) = wall_seen_twice(&truth);
        // The odometry puts the rig 4 cm off across the wall and 3 cm along it.
        let given = prior(rig(3.03, 1.24, 0.0), 0.1, 0.03);
        let anchor = pinned(rig(0.5, 1.0, 0.0));
        let edges = line_edges(1, &mine, &given, &[(0, &theirs, anchor)], &[]);
        assert_eq!(edges.len(), 1);
        let edge = edges[0];
        assert_eq!((edge.from, edge.to, edge.inliers), (1, 0, 1));
        // Nothing is known along the wall (x); across it (y), a few millimetres.
        let information = edge.information;
        assert!(information[(3, 3)].abs() < 1e-6 * information[(4, 4)]);
        assert!(information[(4, 4)] > 1.0 / (0.02 * 0.02));

        let solved = super::super::poses::optimise(&[anchor, given], &[edge]);
        let at = solved[1].rig_to_world.translation.vector;
        // Most of the way: the line's offset is known to 1.4 cm (the room's straightness, a
        // centimetre per sighting), the odometry's to 3 cm, so about a fifth of its 4 cm stays.
        assert!((at.y - 1.2).abs() < 0.01, "across the wall: {}", at.y);
        assert!(
            (at.x - 3.03).abs() < 0.005,
            "along it, the odometry's: {}",
            at.x
        );
        // And the graph says what it knows: across, millimetres; along, the odometry's 3 cm.
        let c = solved[1].covariance;
        assert!(c[(4, 4)].sqrt() < 0.015, "{}", c[(4, 4)].sqrt());
        assert!(
            (c[(3, 3)].sqrt() - 0.03).abs() < 0.002,
            "{}",
            c[(3, 3)].sqrt()
        );
    }

    #[test]
    fn two_lines_within_the_spread_are_no_landmark() {
        let truth = rig(3.0, 1.2, 0.0);
        let (mut theirs, mine) = wall_seen_twice(&truth);
        // A skirting board's top 6 cm in front of the floor's edge, at the same height as
        // far as a 5 cm prior can tell: the capture's line could be either.
        let anchor_pose = rig(0.5, 1.0, 0.0);
        theirs.push(seen(
            &anchor_pose,
            [0.0, 2.94, 0.01],
            [1.2, 2.94, 0.01],
            0.002,
        ));
        let given = prior(rig(3.03, 1.24, 0.0), 1.0, 0.05);
        let edges = line_edges(1, &mine, &given, &[(0, &theirs, pinned(anchor_pose))], &[]);
        assert!(edges.is_empty());
    }

    #[test]
    fn a_line_beyond_the_spread_or_at_another_height_is_no_landmark() {
        let truth = rig(3.0, 1.2, 0.0);
        let anchor_pose = rig(0.5, 1.0, 0.0);
        let (_, mine) = wall_seen_twice(&truth);
        let given = prior(rig(3.0, 1.2, 0.0), 0.1, 0.02);
        let far = vec![seen(&anchor_pose, [0.0, 3.3, 0.0], [1.2, 3.3, 0.0], 0.002)];
        let high = vec![seen(&anchor_pose, [0.0, 3.0, 0.4], [1.2, 3.0, 0.4], 0.002)];
        for theirs in [far, high] {
            let edges = line_edges(1, &mine, &given, &[(0, &theirs, pinned(anchor_pose))], &[]);
            assert!(edges.is_empty());
        }
    }

    #[test]
    fn a_capture_tied_by_segments_in_common_gives_no_line_edge() {
        let truth = rig(3.0, 1.2, 0.0);
        let (theirs, mine) = wall_seen_twice(&truth);
        let given = prior(rig(3.03, 1.24, 0.0), 0.1, 0.03);
        let anchor = pinned(rig(0.5, 1.0, 0.0));
        assert!(line_edges(1, &mine, &given, &[(0, &theirs, anchor)], &[0]).is_empty());
    }

    #[test]
    fn a_crowd_of_lines_is_read_from_its_longest() {
        let at = rig(0.0, 0.0, 0.0);
        // Ten thousand level segments 0.3–0.8 m long across the floor plan, and every
        // thousandth the longest of all.
        let crowd: Vec<Measured> = (0..10_000)
            .map(|k| {
                let length = if k % 1000 == 0 {
                    2.0
                } else {
                    0.3 + 0.5 * ((k * 7919) % 1000) as f64 / 1000.0
                };
                let y = 1.0 + k as f64 * 1e-3;
                seen(&at, [0.0, y, 0.0], [length, y, 0.0], 0.002)
            })
            .collect();
        let read = Landmark::all(&crowd, &at);
        assert_eq!(read.len(), MAX_LANDMARKS);
        let lengths: Vec<f64> = read.iter().map(|l| (l.end - l.start).norm()).collect();
        assert_eq!(lengths.iter().filter(|&&l| l > 1.0).count(), 10);
        // None left out is longer than the shortest kept: those longer are all among the
        // kept, one fewer than their number at most.
        let shortest_kept = lengths.iter().cloned().fold(f64::INFINITY, f64::min);
        let longer = crowd
            .iter()
            .filter(|m| (m.end - m.start).norm() > shortest_kept + 1e-12)
            .count();
        assert!(longer < MAX_LANDMARKS, "{longer}");
    }

    #[test]
    fn short_sloping_or_uncertain_segments_are_no_landmarks() {
        let truth = rig(3.0, 1.2, 0.0);
        let anchor_pose = rig(0.5, 1.0, 0.0);
        let (theirs, _) = wall_seen_twice(&truth);
        let given = prior(rig(3.03, 1.24, 0.0), 0.1, 0.03);
        let short = seen(&truth, [2.4, 3.0, 0.0], [2.6, 3.0, 0.0], 0.002);
        let sloping = seen(&truth, [2.4, 3.0, 0.0], [3.6, 3.0, 0.2], 0.002);
        let uncertain = Measured {
            uncertain: true,
            ..seen(&truth, [2.4, 3.0, 0.0], [3.6, 3.0, 0.0], 0.002)
        };
        for mine in [short, sloping, uncertain] {
            let edges = line_edges(
                1,
                &[mine],
                &given,
                &[(0, &theirs, pinned(anchor_pose))],
                &[],
            );
            assert!(edges.is_empty());
        }
    }
}
