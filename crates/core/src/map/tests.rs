//! Tests of [`fuse`] on small hand-made sessions: merging, separation, filtering, order
//! independence, chaining, and invariance under a rigid motion of the whole session.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;

use super::{fuse, Capture, FuseParams, MapSegment};
use crate::segment::Segment3;

/// A deterministic noise source (xorshift), uniform in [-1, 1].
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }

    fn vec(&mut self, scale: f64) -> Vector3<f64> {
        Vector3::new(self.next(), self.next(), self.next()) * scale
    }
}

fn pose(x: f64, y: f64, yaw_deg: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, 1.2),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians()),
    )
}

/// World segments `(a, b)` as seen from `pose`, each endpoint moved by up to `noise` metres.
fn seen(
    pose: &Isometry3<f64>,
    world: &[(Point3<f64>, Point3<f64>)],
    noise: &mut Noise,
    amount: f64,
) -> Vec<Segment3> {
    let inv = pose.inverse();
    world
        .iter()
        .map(|(a, b)| Segment3 {
            start: inv * a + noise.vec(amount),
            end: inv * b + noise.vec(amount),
        })
        .collect()
}

#[test]
fn default_params_pass_and_bad_ones_name_their_field() {
    FuseParams::default().check().unwrap();
    let bad = |f: fn(&mut FuseParams)| {
        let mut p = FuseParams::default();
        f(&mut p);
        p.check().unwrap_err().field()
    };
    assert_eq!(bad(|p| p.lateral_m = 0.0), "lateral_m");
    assert_eq!(bad(|p| p.lateral_rel = f64::NAN), "lateral_rel");
    assert_eq!(bad(|p| p.angle_deg = 90.0), "angle_deg");
    assert_eq!(bad(|p| p.max_gap_m = -1.0), "max_gap_m");
    assert_eq!(bad(|p| p.min_observations = 0), "min_observations");
}

fn p(x: f64, y: f64, z: f64) -> Point3<f64> {
    Point3::new(x, y, z)
}

/// A capture of `segments` at an exact pose, without covariances.
fn capture(id: u32, rig_to_world: Isometry3<f64>, segments: &[Segment3]) -> Capture<'_> {
    Capture {
        id,
        rig_to_world,
        segments,
        ..Default::default()
    }
}

#[test]
fn one_wall_edge_seen_twice_is_one_segment_with_two_observations() {
    let wall = [(p(0.0, 3.0, 0.8), p(2.0, 3.0, 0.8))];
    let (pa, pb) = (pose(1.0, 0.0, 0.0), pose(2.0, 0.5, 25.0));
    let mut n = Noise(7);
    let (sa, sb) = (
        seen(&pa, &wall, &mut n, 0.005),
        seen(&pb, &wall, &mut n, 0.005),
    );
    let captures = [capture(4, pa, &sa), capture(9, pb, &sb)];
    let map = fuse(&captures, &FuseParams::default());
    assert_eq!(map.len(), 1, "{map:?}");
    assert_eq!(map[0].observations, 2);
    assert_eq!(map[0].captures, vec![4, 9]);
    for q in [map[0].start, map[0].end] {
        assert!((q.y - 3.0).abs() < 0.01 && (q.z - 0.8).abs() < 0.01, "{q}");
    }
    assert!((map[0].length() - 2.0).abs() < 0.02);
}

#[test]
fn fragments_of_one_capture_count_once() {
    let pa = pose(0.0, 0.0, 0.0);
    let world = [
        (p(-1.0, 3.0, 1.0), p(0.2, 3.0, 1.0)),
        (p(0.205, 3.0, 1.0), p(1.0, 3.0, 1.0)),
    ];
    let s = seen(&pa, &world, &mut Noise(3), 0.0);
    let map = fuse(
        &[Capture {
            id: 1,
            rig_to_world: pa,
            segments: &s,
            ..Default::default()
        }],
        &FuseParams::default(),
    );
    assert_eq!(map.len(), 1);
    assert_eq!((map[0].observations, map[0].captures.clone()), (1, vec![1]));
    assert!((map[0].length() - 2.0).abs() < 1e-9);
}

/// Two shelf boards either side of a 3 cm divider are two edges on one line: seen by two
/// captures, each board is one map segment, and none runs across the divider (with the 5 cm
/// gap this fusion once allowed, one segment spanned both: the lab's wrong map segments).
#[test]
fn collinear_edges_either_side_of_a_divider_stay_two() {
    let world = [
        (p(-0.8, 3.0, 1.2), p(-0.015, 3.0, 1.2)),
        (p(0.015, 3.0, 1.2), p(0.8, 3.0, 1.2)),
    ];
    let (pa, pb) = (pose(0.0, 0.0, 0.0), pose(0.3, 0.1, 0.2));
    let (sa, sb) = (
        seen(&pa, &world, &mut Noise(5), 0.002),
        seen(&pb, &world, &mut Noise(6), 0.002),
    );
    let captures = [capture(1, pa, &sa), capture(2, pb, &sb)];
    let mut map = fuse(&captures, &FuseParams::default());
    map.sort_by(|a, b| a.start.x.min(a.end.x).total_cmp(&b.start.x.min(b.end.x)));
    assert_eq!(map.len(), 2, "{map:?}");
    for (m, (a, b)) in map.iter().zip(&world) {
        assert_eq!(m.captures, vec![1, 2]);
        let (lo, hi) = (m.start.x.min(m.end.x), m.start.x.max(m.end.x));
        assert!((lo - a.x).abs() < 0.01 && (hi - b.x).abs() < 0.01, "{m:?}");
    }
}

#[test]
fn parallel_edges_ten_centimetres_apart_stay_separate() {
    let world = [
        (p(0.0, 3.0, 1.0), p(2.0, 3.0, 1.0)),
        (p(0.0, 3.0, 1.1), p(2.0, 3.0, 1.1)),
        (p(0.0, 3.1, 0.5), p(2.0, 3.1, 0.5)),
        (p(0.0, 3.0, 0.5), p(2.0, 3.0, 0.5)),
    ];
    let poses = [pose(1.0, 0.0, 0.0), pose(1.5, 0.3, -20.0)];
    let mut n = Noise(11);
    let segs: Vec<_> = poses
        .iter()
        .map(|q| seen(q, &world, &mut n, 0.005))
        .collect();
    let captures: Vec<_> = (0..2)
        .map(|i| Capture {
            id: i as u32,
            rig_to_world: poses[i],
            segments: &segs[i],
            ..Default::default()
        })
        .collect();
    let map = fuse(&captures, &FuseParams::default());
    assert_eq!(map.len(), 4, "{map:?}");
    assert!(map.iter().all(|m| m.observations == 2));
}

#[test]
fn segments_seen_once_are_dropped_with_min_observations_two() {
    let common = [(p(0.0, 3.0, 1.0), p(2.0, 3.0, 1.0))];
    let poses = [pose(1.0, 0.0, 0.0), pose(1.2, 0.0, 15.0)];
    let mut n = Noise(5);
    let mut a = seen(&poses[0], &common, &mut n, 0.003);
    a.extend(seen(
        &poses[0],
        &[(p(0.0, 4.0, 0.0), p(0.0, 4.0, 2.0))],
        &mut n,
        0.0,
    ));
    let b = seen(&poses[1], &common, &mut n, 0.003);
    let captures = [
        Capture {
            id: 0,
            rig_to_world: poses[0],
            segments: &a,
            ..Default::default()
        },
        Capture {
            id: 1,
            rig_to_world: poses[1],
            segments: &b,
            ..Default::default()
        },
    ];
    assert_eq!(fuse(&captures, &FuseParams::default()).len(), 2);
    let two = FuseParams {
        min_observations: 2,
        ..FuseParams::default()
    };
    let map = fuse(&captures, &two);
    assert_eq!(map.len(), 1);
    assert_eq!(map[0].captures, vec![0, 1]);
}

/// A room of `edges` random edges, seen in fragments with noise from `poses` turning poses.
fn session(seed: u64, edges: usize, poses: usize) -> (Vec<Isometry3<f64>>, Vec<Vec<Segment3>>) {
    let mut n = Noise(seed);
    let world: Vec<_> = (0..edges)
        .map(|_| {
            let a = p(3.0 * n.next(), 3.0 * n.next(), 1.0 + n.next());
            (a, a + n.vec(1.0))
        })
        .collect();
    let poses: Vec<_> = (0..poses)
        .map(|k| {
            pose(
                0.1 * n.next(),
                0.1 * n.next(),
                360.0 * k as f64 / poses as f64,
            )
        })
        .collect();
    let segs = poses
        .iter()
        .map(|q| {
            let mut out = Vec::new();
            for (a, b) in &world {
                if n.next() < -0.3 {
                    continue; // not seen from here
                }
                // Sometimes in two fragments.
                let cut = 0.5 + 0.3 * n.next();
                let m = a + (b - a) * cut;
                if n.next() > 0.4 {
                    out.extend(seen(q, &[(*a, m), (m, *b)], &mut n, 0.004));
                } else {
                    out.extend(seen(q, &[(*a, *b)], &mut n, 0.004));
                }
            }
            out
        })
        .collect();
    (poses, segs)
}

fn captures_of<'a>(poses: &[Isometry3<f64>], segs: &'a [Vec<Segment3>]) -> Vec<Capture<'a>> {
    poses
        .iter()
        .zip(segs)
        .enumerate()
        .map(|(i, (q, s))| Capture {
            id: i as u32,
            rig_to_world: *q,
            segments: s,
            ..Default::default()
        })
        .collect()
}

#[test]
fn the_map_does_not_depend_on_capture_order() {
    let (poses, segs) = session(42, 120, 12);
    let captures = captures_of(&poses, &segs);
    let params = FuseParams::default();
    let map = fuse(&captures, &params);
    assert!(map.iter().any(|m| m.observations > 3), "fusion happened");
    let mut shuffled = captures.clone();
    let mut n = Noise(99);
    for i in (1..shuffled.len()).rev() {
        let j = ((n.next() + 1.0) * 0.5 * (i + 1) as f64) as usize;
        shuffled.swap(i, j.min(i));
    }
    assert_ne!(
        shuffled.iter().map(|c| c.id).collect::<Vec<_>>(),
        (0..12).collect::<Vec<_>>()
    );
    assert_eq!(fuse(&shuffled, &params), map, "bit for bit");
    shuffled.reverse();
    assert_eq!(fuse(&shuffled, &params), map);

    // In a session the ids are arrival indices: numbered by arrival, the geometry is the same
    // bit for bit, and each segment's captures are the same captures under their new numbers.
    let renumbered: Vec<Capture> = shuffled
        .iter()
        .enumerate()
        .map(|(i, c)| Capture {
            id: i as u32,
            rig_to_world: c.rig_to_world,
            segments: c.segments,
            ..Default::default()
        })
        .collect();
    let mut new_id = vec![0u32; shuffled.len()];
    for (i, c) in shuffled.iter().enumerate() {
        new_id[c.id as usize] = i as u32;
    }
    let again = fuse(&renumbered, &params);
    assert_eq!(again.len(), map.len());
    for (x, y) in again.iter().zip(&map) {
        assert_eq!(
            (x.start, x.end, x.observations),
            (y.start, y.end, y.observations)
        );
        let mut expected: Vec<u32> = y.captures.iter().map(|&c| new_id[c as usize]).collect();
        expected.sort_unstable();
        assert_eq!(x.captures, expected);
    }
}

#[test]
fn a_gently_bending_chain_is_split_into_straight_pieces() {
    // 24 chords of 0.3 m along an arc, each turning 1° from the last: neighbours link, but
    // the whole chain turns 23°, so one line cannot hold it.
    let (radius, step) = (0.15 / 0.5f64.to_radians().sin(), 1f64.to_radians());
    let centre = p(0.0, 3.0 + radius, 1.0);
    let at = |k: usize| {
        let t = -std::f64::consts::FRAC_PI_2 + step * k as f64;
        centre + Vector3::new(radius * t.cos(), radius * t.sin(), 0.0)
    };
    let world: Vec<_> = (0..24).map(|k| (at(k), at(k + 1))).collect();
    let q = pose(0.0, 0.0, 0.0);
    let s = seen(&q, &world, &mut Noise(1), 0.0);
    let params = FuseParams::default();
    let map = fuse(
        &[Capture {
            id: 0,
            rig_to_world: q,
            segments: &s,
            ..Default::default()
        }],
        &params,
    );
    assert!(map.len() >= 3, "{}", map.len());
    for m in &map {
        for t in [0.0, 0.5, 1.0] {
            let x = m.start + (m.end - m.start) * t;
            let off = ((x - centre).norm() - radius).abs();
            assert!(off < 0.05, "{off} m off the arc");
        }
    }
}

#[test]
fn empty_and_degenerate_input_give_an_empty_map() {
    let q = pose(0.0, 0.0, 0.0);
    let degenerate = [
        Segment3 {
            start: p(1.0, 1.0, 1.0),
            end: p(1.0, 1.0, 1.0),
        },
        Segment3 {
            start: p(f64::NAN, 1.0, 1.0),
            end: p(1.0, 2.0, 1.0),
        },
    ];
    let c = Capture {
        id: 0,
        rig_to_world: q,
        segments: &degenerate,
        ..Default::default()
    };
    assert!(fuse(&[], &FuseParams::default()).is_empty());
    assert!(fuse(&[c], &FuseParams::default()).is_empty());
}

fn close(a: &Point3<f64>, b: &Point3<f64>) -> bool {
    (a - b).norm() < 1e-7
}

fn same_up_to_orientation(m: &MapSegment, e: &MapSegment) -> bool {
    m.captures == e.captures
        && ((close(&m.start, &e.start) && close(&m.end, &e.end))
            || (close(&m.start, &e.end) && close(&m.end, &e.start)))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Moving every pose by one rigid motion moves the map by it (the tolerances depend on
    /// ranges only, and the canonical order on rig-frame coordinates).
    #[test]
    fn a_rigid_motion_of_the_session_moves_the_map(
        axis in (-1.0f64..1.0, -1.0f64..1.0, 0.2f64..1.0),
        angle in -3.1f64..3.1,
        shift in (-20.0f64..20.0, -20.0f64..20.0, -5.0f64..5.0),
        seed in 1u64..1000,
    ) {
        let (poses, segs) = session(seed, 40, 6);
        let params = FuseParams::default();
        let map = fuse(&captures_of(&poses, &segs), &params);
        let motion = Isometry3::from_parts(
            Translation3::new(shift.0, shift.1, shift.2),
            UnitQuaternion::from_axis_angle(
                &nalgebra::Unit::new_normalize(Vector3::new(axis.0, axis.1, axis.2)),
                angle,
            ),
        );
        let moved_poses: Vec<_> = poses.iter().map(|q| motion * q).collect();
        let moved = fuse(&captures_of(&moved_poses, &segs), &params);
        prop_assert_eq!(moved.len(), map.len());
        for e in &map {
            let expected = MapSegment {
                start: motion * e.start,
                end: motion * e.end,
                ..e.clone()
            };
            prop_assert!(
                moved.iter().any(|m| same_up_to_orientation(m, &expected)),
                "{:?} missing", expected
            );
        }
    }
}

/// `segments` with an isotropic covariance of `sigma` metres on every endpoint.
fn with_sigma(segments: &[Segment3], sigma: f64) -> Vec<nalgebra::Matrix6<f64>> {
    vec![nalgebra::Matrix6::identity() * sigma * sigma; segments.len()]
}

/// A capture's pose, segments and their covariances.
type Seen<'a> = (Isometry3<f64>, &'a [Segment3], &'a [nalgebra::Matrix6<f64>]);

/// Captures 0 and 1: the first posed exactly, the second known to `pose_covariance`.
fn two_captures<'a>(
    first: Seen<'a>,
    second: Seen<'a>,
    pose_covariance: nalgebra::Matrix6<f64>,
) -> [Capture<'a>; 2] {
    [
        Capture {
            id: 0,
            rig_to_world: first.0,
            segments: first.1,
            covariances: first.2,
            ..Default::default()
        },
        Capture {
            id: 1,
            rig_to_world: second.0,
            segments: second.1,
            covariances: second.2,
            pose_covariance,
        },
    ]
}

#[test]
fn a_segment_seen_again_is_known_better_and_its_covariance_says_so() {
    let wall = [(p(0.0, 3.0, 0.8), p(2.0, 3.0, 0.8))];
    let poses = [
        pose(1.0, 0.0, 0.0),
        pose(1.5, 0.3, 10.0),
        pose(0.5, 0.2, -10.0),
    ];
    let mut n = Noise(3);
    let segments: Vec<Vec<Segment3>> = poses
        .iter()
        .map(|q| seen(q, &wall, &mut n, 0.002))
        .collect();
    let covariances: Vec<_> = segments.iter().map(|s| with_sigma(s, 0.004)).collect();
    let fused = |k: usize| {
        let captures: Vec<Capture> = (0..k)
            .map(|i| Capture {
                id: i as u32,
                rig_to_world: poses[i],
                segments: &segments[i],
                covariances: &covariances[i],
                ..Default::default()
            })
            .collect();
        let map = fuse(&captures, &FuseParams::default());
        assert_eq!(map.len(), 1, "{map:?}");
        map[0].clone()
    };
    let (once, thrice) = (fused(1), fused(3));
    assert_eq!(thrice.observations, 3);
    // One observation: the covariance across the line is its own (4 mm on each end).
    assert!(
        (once.position_sigma_m - 0.004 / 2f64.sqrt()).abs() < 2e-4,
        "{once:?}"
    );
    // Three: information adds, σ shrinks by about √3.
    let ratio = once.position_sigma_m / thrice.position_sigma_m;
    assert!((ratio - 3f64.sqrt()).abs() < 0.1, "{ratio}");
    assert!(thrice.direction_sigma_deg < once.direction_sigma_deg);
    // The line itself is where the three agree, within their noise.
    for q in [thrice.start, thrice.end] {
        assert!(
            (q.y - 3.0).abs() < 0.004 && (q.z - 0.8).abs() < 0.004,
            "{q}"
        );
    }
}

/// One capture's sighting of an edge: its pose, its segments and their covariances.
type Sighting = (Isometry3<f64>, Vec<Segment3>, Vec<nalgebra::Matrix6<f64>>);

/// A wall edge seen by two captures at a slight angle, 1 mm of noise, each segment stated
/// at 3 mm across.
fn one_wall_edge_at_a_slight_angle() -> (Sighting, Sighting) {
    let wall = [(p(0.0, 3.0, 0.8), p(2.0, 3.0, 0.8))];
    let (pa, pb) = (pose(1.0, 0.0, 0.0), pose(1.2, 0.2, 2.0));
    let mut n = Noise(5);
    let (sa, sb) = (
        seen(&pa, &wall, &mut n, 0.001),
        seen(&pb, &wall, &mut n, 0.001),
    );
    let (ca, cb) = (with_sigma(&sa, 0.003), with_sigma(&sb, 0.003));
    ((pa, sa, ca), (pb, sb, cb))
}

#[test]
fn where_a_segment_ends_is_no_doubt_across_the_fused_line() {
    // Two sightings of one edge at a slight angle, one with 30 cm of spread along itself
    // (a receding line's ends): it must not make the fused line doubtful across it.
    let ((pa, sa, ca), (pb, sb, mut cb)) = one_wall_edge_at_a_slight_angle();
    let along = (sb[0].end - sb[0].start).normalize();
    for k in 0..2 {
        let mut block = cb[0].fixed_view_mut::<3, 3>(3 * k, 3 * k);
        block += along * along.transpose() * 0.3f64.powi(2);
    }
    let captures = two_captures((pa, &sa, &ca), (pb, &sb, &cb), nalgebra::Matrix6::zeros());
    let map = fuse(&captures, &FuseParams::default());
    assert_eq!(map.len(), 1);
    assert!(map[0].position_sigma_m < 0.003, "{:?}", map[0]);
}

#[test]
fn the_gate_leaves_out_what_a_capture_placed_by_its_odometry_alone_saw() {
    // Two captures see one wall edge each; the second's pose is known to 3 degrees only,
    // so at 3 m its edge may be 15 cm off: not a segment the map can vouch for.
    let (pa, pb) = (pose(1.0, 0.0, 0.0), pose(1.0, 0.0, 90.0));
    let mut n = Noise(9);
    let sa = seen(&pa, &[(p(0.0, 3.0, 0.8), p(2.0, 3.0, 0.8))], &mut n, 0.001);
    let sb = seen(
        &pb,
        &[(p(-2.0, -1.0, 0.8), p(-2.0, 1.0, 0.8))],
        &mut n,
        0.001,
    );
    let (ca, cb) = (with_sigma(&sa, 0.003), with_sigma(&sb, 0.003));
    let odometry = super::PosePrior::odometry(pb, 3.0, 0.3, 0.05, 0.01).covariance;
    let captures = two_captures((pa, &sa, &ca), (pb, &sb, &cb), odometry);
    let gate = super::MapGate::of(&crate::matching::MatchParams::default());
    let gated = FuseParams {
        gate: Some(gate),
        ..FuseParams::default()
    };
    let map = fuse(&captures, &gated);
    assert_eq!(map.len(), 1, "{map:?}");
    assert_eq!(map[0].captures, vec![0]);
    assert!(!map[0].uncertain);
    // Asked for, it is there, flagged; without a gate, there and not flagged.
    let everything = FuseParams {
        gate: Some(super::MapGate {
            include_uncertain: true,
            ..gate
        }),
        ..FuseParams::default()
    };
    let map = fuse(&captures, &everything);
    assert_eq!(map.len(), 2);
    let doubtful: Vec<_> = map.iter().filter(|m| m.uncertain).collect();
    assert_eq!(doubtful.len(), 1);
    assert_eq!(doubtful[0].captures, vec![1]);
    assert!(doubtful[0].position_sigma_m > 0.05, "{:?}", doubtful[0]);
    assert!(fuse(&captures, &FuseParams::default())
        .iter()
        .all(|m| !m.uncertain));
}

#[test]
fn a_capture_placed_loosely_along_a_line_does_not_carry_its_end_past_the_truth() {
    // A wall edge from x = 0 to 2 m. Capture 0, its pose exact, saw 0.2–1.5 m of it; capture
    // 1 saw 0.2–1.9 m, but its pose is known to 4 cm along x (across the edge to 2 mm): where
    // its ends lie along the edge is that uncertain, and 2.45σ of it exceeds the 3 cm
    // tolerance at that range by 6–7 cm.
    let (pa, pb) = (pose(1.0, 0.0, 0.0), pose(1.2, 0.2, 10.0));
    let mut n = Noise(11);
    let sa = seen(&pa, &[(p(0.2, 3.0, 0.8), p(1.5, 3.0, 0.8))], &mut n, 0.0);
    let sb = seen(&pb, &[(p(0.2, 3.0, 0.8), p(1.9, 3.0, 0.8))], &mut n, 0.0);
    let (ca, cb) = (with_sigma(&sa, 0.002), with_sigma(&sb, 0.002));
    let along_x = nalgebra::Matrix6::from_diagonal(&nalgebra::Vector6::new(
        1e-10,
        1e-10,
        1e-10,
        0.04 * 0.04,
        0.002 * 0.002,
        1e-6,
    ));
    let captures = two_captures((pa, &sa, &ca), (pb, &sb, &cb), along_x);
    let gated = FuseParams {
        gate: Some(super::MapGate::of(&crate::matching::MatchParams::default())),
        ..FuseParams::default()
    };
    let map = fuse(&captures, &gated);
    assert_eq!(map.len(), 1, "{map:?}");
    assert_eq!(map[0].captures, vec![0, 1]);
    assert!(!map[0].uncertain, "{:?}", map[0]);
    let (lo, hi) = {
        let (a, b) = (map[0].start.x, map[0].end.x);
        (a.min(b), a.max(b))
    };
    // The sure capture's start stands; capture 1's end is pulled in by the excess.
    assert!((lo - 0.2).abs() < 0.002, "start {lo}");
    assert!(hi > 1.8 && hi < 1.86, "end {hi}");
    // Without the gate's promise the map reports every observed end.
    let everything = fuse(&captures, &FuseParams::default());
    let hi = everything[0].start.x.max(everything[0].end.x);
    assert!((hi - 1.9).abs() < 0.002, "end {hi}");
}

#[test]
fn a_gate_out_of_range_is_named() {
    let mut params = FuseParams {
        gate: Some(super::MapGate::of(&crate::matching::MatchParams::default())),
        ..FuseParams::default()
    };
    params.check().unwrap();
    params.gate.as_mut().unwrap().confidence = 1.0;
    assert_eq!(params.check().unwrap_err().field(), "gate.confidence");
}

#[test]
fn a_map_segment_adds_once_the_shift_its_rigs_views_share() {
    // The same edge seen twice: fused without the shift, reported and gated with it added
    // once, at the segment's range from the nearest rig, across the line only.
    let ((pa, sa, ca), (pb, sb, cb)) = one_wall_edge_at_a_slight_angle();
    let captures = two_captures((pa, &sa, &ca), (pb, &sb, &cb), nalgebra::Matrix6::zeros());
    let gate = super::MapGate::of(&crate::matching::MatchParams::default());
    let fused = |gate: super::MapGate| {
        let map = fuse(
            &captures,
            &FuseParams {
                gate: Some(gate),
                ..FuseParams::default()
            },
        );
        assert_eq!(map.len(), 1, "{map:?}");
        map[0].clone()
    };
    let without = fused(gate);
    let per_metre = 0.002;
    let with = fused(super::MapGate {
        shift_per_metre: per_metre,
        ..gate
    });
    assert_eq!((with.start, with.end), (without.start, without.end));
    let mid = nalgebra::center(&with.start, &with.end);
    let range = [pa, pb]
        .iter()
        .map(|q| (mid - Point3::from(q.translation.vector)).norm())
        .fold(f64::INFINITY, f64::min);
    let sigma = per_metre * range;
    let u = (with.end - with.start).normalize();
    let across = nalgebra::Matrix3::identity() - u * u.transpose();
    let added = with.covariance - without.covariance;
    for (r, c) in [(0, 0), (0, 3), (3, 0), (3, 3)] {
        let block = added.fixed_view::<3, 3>(r, c).into_owned();
        assert!(
            (block - across * sigma * sigma).abs().max() < 1e-12,
            "{block}"
        );
    }
    assert!(with.position_sigma_m > without.position_sigma_m);
    assert_eq!(with.direction_sigma_deg, without.direction_sigma_deg);
}
