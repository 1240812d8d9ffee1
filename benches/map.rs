//! Session map benchmarks (criterion, release):
//! - `fuse/12` and `fuse/50` fuse that many synthetic captures of one room, ~300 noisy,
//!   partly fragmented segments each (3,600 and 15,000 segments), on the default rayon pool
//!   — what a GetMap recomputes from stored captures;
//! - `pose_graph/{50,500,2000}`: the session's pose graph (`map::poses::optimise`) of a robot
//!   mowing a hall in rows 40 captures long, each capture tied to the two before it in its
//!   row and the two nearest in the row before — every row a loop closure — its odometry
//!   1° and 2 cm off: what every AddCapture and a refined GetMap solve.
//!
//!     cargo bench --bench map

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use trinocular::map::poses::{optimise, RelativePose};
use trinocular::map::{fuse, Capture, FuseParams, PosePrior};
use trinocular::segment::Segment3;

/// Uniform in [-1, 1], deterministic (xorshift).
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// A 6 x 5 x 2.5 m room with 1,200 axis-aligned edges on its walls, on a
/// 10 cm grid of lines; `n` poses turning in its
/// middle, each seeing the ~230 edges in its 76° field of view (nine in ten of them; three in
/// ten split in two, so ~280 segments), endpoints with 5 mm noise.
fn session(n: usize) -> (Vec<Isometry3<f64>>, Vec<Vec<Segment3>>) {
    let mut r = Noise(0x5eed);
    let mut edges = Vec::new();
    for _ in 0..1200 {
        let wall = ((r.next() + 1.0) * 2.0) as usize % 4;
        // Edges lie on a 10 cm grid of lines (shelves, frames, panels), so distinct lines are
        // at least 10 cm apart and edges on one line sometimes touch or overlap.
        let grid = |v: f64| (v * 10.0).round() / 10.0;
        let (u, z) = (r.next(), 1.25 + 1.2 * r.next());
        let dir_along = r.next() > 0.0;
        let (u, z) = if dir_along {
            (u, grid(z))
        } else {
            (grid(3.0 * u) / 3.0, z)
        };
        let base = match wall {
            0 => Point3::new(3.0 * u, 2.5, z),
            1 => Point3::new(3.0 * u, -2.5, z),
            2 => Point3::new(3.0, 2.5 * u, z),
            _ => Point3::new(-3.0, 2.5 * u, z),
        };
        let along = if wall < 2 { Vector3::x() } else { Vector3::y() };
        let dir = if dir_along { along } else { Vector3::z() };
        edges.push((base, base + dir * (0.2 + 0.6 * (r.next() + 1.0))));
    }
    let poses: Vec<_> = (0..n)
        .map(|k| {
            Isometry3::from_parts(
                Translation3::new(0.1 * r.next(), 0.1 * r.next(), 1.2),
                UnitQuaternion::from_axis_angle(
                    &Vector3::z_axis(),
                    std::f64::consts::TAU * k as f64 / n as f64,
                ),
            )
        })
        .collect();
    let jitter = |r: &mut Noise| Vector3::new(r.next(), r.next(), r.next()) * 0.005;
    let segments = poses
        .iter()
        .map(|pose| {
            let inv = pose.inverse();
            let mut out = Vec::new();
            let look = pose.rotation * Vector3::y();
            for &(a, b) in &edges {
                let to = nalgebra::center(&a, &b) - Point3::from(pose.translation.vector);
                let cos = (look.x * to.x + look.y * to.y) / look.xy().norm() / to.xy().norm();
                if cos < 38f64.to_radians().cos() || r.next() < -0.8 {
                    continue; // outside the field of view, or missed
                }
                let mut push = |p: Point3<f64>, q: Point3<f64>, r: &mut Noise| {
                    out.push(Segment3 {
                        start: inv * p + jitter(r),
                        end: inv * q + jitter(r),
                    })
                };
                if r.next() > 0.4 {
                    let m = a + (b - a) * 0.5;
                    push(a, m, &mut r);
                    push(m, b, &mut r);
                } else {
                    push(a, b, &mut r);
                }
            }
            out
        })
        .collect();
    (poses, segments)
}

fn bench_fuse(c: &mut Criterion) {
    let mut group = c.benchmark_group("fuse");
    for n in [12usize, 50] {
        let (poses, segments) = session(n);
        let captures: Vec<Capture> = poses
            .iter()
            .zip(&segments)
            .enumerate()
            .map(|(i, (p, s))| Capture {
                id: i as u32,
                rig_to_world: *p,
                segments: s,
                ..Capture::default()
            })
            .collect();
        let total: usize = segments.iter().map(Vec::len).sum();
        group.throughput(Throughput::Elements(total as u64));
        let params = FuseParams::default();
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| fuse(&captures, &params))
        });
    }
    group.finish();
}

/// The mowing session of `pose_graph/n`: priors and edges.
fn mowing(n: usize) -> (Vec<PosePrior>, Vec<RelativePose>) {
    const ROW: usize = 40;
    let mut r = Noise(0x9a7);
    let truth = |k: usize| {
        let (row, at) = (k / ROW, k % ROW);
        let x = if row % 2 == 0 { at } else { ROW - 1 - at } as f64 * 0.4;
        Isometry3::new(
            Vector3::new(x, row as f64 * 0.5, 1.2),
            Vector3::z() * (0.3 * (k as f64 * 0.7).sin()),
        )
    };
    let priors = (0..n)
        .map(|k| {
            let off = Isometry3::new(
                Vector3::new(0.02 * r.next(), 0.02 * r.next(), 0.0),
                Vector3::z() * 1f64.to_radians() * r.next(),
            );
            PosePrior::odometry(off * truth(k), 3.0, 0.3, 0.05, 0.01)
        })
        .collect();
    let mut edges = Vec::new();
    let mut tie = |from: usize, to: usize| {
        edges.push(RelativePose {
            from,
            to,
            pose: truth(to).inverse() * truth(from),
            information: nalgebra::Matrix6::identity() * 1e5,
            inliers: 20,
        })
    };
    for k in 1..n {
        let (row, at) = (k / ROW, k % ROW);
        for back in 1..=2 {
            if at >= back {
                tie(k, k - back);
            }
        }
        if row > 0 {
            // The same place in the row before, which ran the other way.
            let below = row * ROW - 1 - at;
            tie(k, below);
            if at + 1 < ROW {
                tie(k, below - 1);
            }
        }
    }
    (priors, edges)
}

fn bench_pose_graph(c: &mut Criterion) {
    let mut group = c.benchmark_group("pose_graph");
    group.sample_size(10);
    for n in [50usize, 500, 2000] {
        let (priors, edges) = mowing(n);
        group.throughput(Throughput::Elements(n as u64));
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| optimise(&priors, &edges))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_fuse, bench_pose_graph);
criterion_main!(benches);
