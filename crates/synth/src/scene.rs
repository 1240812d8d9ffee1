//! Box worlds: axis-aligned boxes lit by one point light, with exact ray casting.
//!
//! A [`Scene`] is the ground truth of the synthetic data: every 3D edge is an edge of a box,
//! and every image intensity is the shading of the nearest box face along the pixel's ray.
//! Frames follow DESIGN §1: right-handed, metres, z up.
//!
//! Shading is deliberately simple and shadow-free (ambient + Lambert with 1/d² falloff): a
//! shadow boundary would be an image edge with no ground-truth 3D edge behind it, which would
//! make the error rate of a perfect matcher non-zero.
//!
//! [`Scene::room`] builds the standard test room: a 6 × 5 × 2.7 m office with furniture, a
//! door, a window, posters and a calibration board, dense enough that a rig at the room
//! centre sees a few hundred segments per image, horizontal and vertical.

use nalgebra::{Point3, Vector3};

use super::rng::Rng;
use trinocular_core::segment::Segment3;

/// Rays hit nothing closer than this along their direction (in units of the direction's
/// length), so a ray leaving a surface does not hit that surface again.
pub const HIT_EPS: f64 = 1e-9;
/// Ambient term of the shading, as a fraction of full brightness.
pub const AMBIENT: f64 = 0.25;
/// Power of the point light: the Lambert term is `LIGHT_POWER · cos θ / d²` (d in metres).
pub const LIGHT_POWER: f64 = 3.5;
/// Grey level of a ray that leaves the scene (a closed room never produces one).
pub const BACKGROUND: f64 = 0.0;

/// A face of an axis-aligned box, by the direction of its outward normal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Face {
    NegX = 0,
    PosX = 1,
    NegY = 2,
    PosY = 3,
    NegZ = 4,
    PosZ = 5,
}

impl Face {
    pub const ALL: [Face; 6] = [
        Face::NegX,
        Face::PosX,
        Face::NegY,
        Face::PosY,
        Face::NegZ,
        Face::PosZ,
    ];

    /// Index into [`Box3::albedo`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// The face on side `positive` of axis `axis` (0 = x, 1 = y, 2 = z).
    fn of_axis(axis: usize, positive: bool) -> Face {
        Face::ALL[2 * axis.min(2) + usize::from(positive)]
    }

    pub fn normal(self) -> Vector3<f64> {
        match self {
            Face::NegX => -Vector3::x(),
            Face::PosX => Vector3::x(),
            Face::NegY => -Vector3::y(),
            Face::PosY => Vector3::y(),
            Face::NegZ => -Vector3::z(),
            Face::PosZ => Vector3::z(),
        }
    }
}

/// An axis-aligned box. Invariant: `min <= max` componentwise (use [`Box3::new`] when the
/// corners may come in any order).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Box3 {
    pub min: Point3<f64>,
    pub max: Point3<f64>,
    /// Albedo in `0..=1` per face, indexed by [`Face::index`]: −x, +x, −y, +y, −z, +z.
    pub albedo: [f64; 6],
}

impl Box3 {
    /// The box spanned by two opposite corners, in any order.
    pub fn new(a: Point3<f64>, b: Point3<f64>, albedo: [f64; 6]) -> Box3 {
        Box3 {
            min: a.inf(&b),
            max: a.sup(&b),
            albedo,
        }
    }

    /// The 12 edges: 4 along x, then 4 along y, then 4 along z, each running from the low to
    /// the high coordinate.
    pub fn edges(&self) -> [Segment3; 12] {
        let (lo, hi) = (self.min, self.max);
        let corner = |x: bool, y: bool, z: bool| {
            Point3::new(
                if x { hi.x } else { lo.x },
                if y { hi.y } else { lo.y },
                if z { hi.z } else { lo.z },
            )
        };
        let mut out = [Segment3 { start: lo, end: lo }; 12];
        let mut k = 0;
        for axis in 0..3 {
            for (a, b) in [(false, false), (true, false), (false, true), (true, true)] {
                let (start, end) = match axis {
                    0 => (corner(false, a, b), corner(true, a, b)),
                    1 => (corner(a, false, b), corner(a, true, b)),
                    _ => (corner(a, b, false), corner(a, b, true)),
                };
                out[k] = Segment3 { start, end };
                k += 1;
            }
        }
        out
    }

    /// Whether `p` lies strictly inside the box shrunk by `shrink` on every side.
    pub fn contains_strictly(&self, p: &Point3<f64>, shrink: f64) -> bool {
        (0..3).all(|k| p[k] > self.min[k] + shrink && p[k] < self.max[k] - shrink)
    }
}

/// Parametric interval `(t_near, t_far, near_axis, far_axis)` of the line `origin + t·dir`
/// inside the box `[lo, hi]` (slab method), or `None` when the line misses it. The axes tell
/// which slab bounds the interval, to name the face that is hit.
pub(crate) fn slab(
    origin: &[f64; 3],
    dir: &[f64; 3],
    lo: &[f64; 3],
    hi: &[f64; 3],
) -> Option<(f64, f64, usize, usize)> {
    let (mut t_near, mut t_far) = (f64::NEG_INFINITY, f64::INFINITY);
    let (mut near_axis, mut far_axis) = (0, 0);
    for k in 0..3 {
        if dir[k] == 0.0 {
            // Parallel to this slab: inside it for all t, or never.
            if origin[k] < lo[k] || origin[k] > hi[k] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / dir[k];
        let (mut t0, mut t1) = ((lo[k] - origin[k]) * inv, (hi[k] - origin[k]) * inv);
        if t0 > t1 {
            std::mem::swap(&mut t0, &mut t1);
        }
        if t0 > t_near {
            t_near = t0;
            near_axis = k;
        }
        if t1 < t_far {
            t_far = t1;
            far_axis = k;
        }
        if t_near > t_far {
            return None;
        }
    }
    Some((t_near, t_far, near_axis, far_axis))
}

/// A ray as plain arrays, with the per-box hit test shared by [`Scene::cast`] and the
/// bounding-volume hierarchy, so both find bit-identical hits.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Ray {
    pub(crate) origin: [f64; 3],
    pub(crate) dir: [f64; 3],
}

impl Ray {
    pub(crate) fn new(origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Ray> {
        let origin = [origin.x, origin.y, origin.z];
        let dir = [dir.x, dir.y, dir.z];
        let finite = origin.iter().chain(&dir).all(|v| v.is_finite());
        (finite && dir != [0.0; 3]).then_some(Ray { origin, dir })
    }

    /// Ray parameter and face where the ray meets the box `[lo, hi]`, if beyond `HIT_EPS`.
    pub(crate) fn hit_box(&self, lo: &[f64; 3], hi: &[f64; 3]) -> Option<(f64, Face)> {
        let d = &self.dir;
        let (t_near, t_far, near_axis, far_axis) = slab(&self.origin, d, lo, hi)?;
        // Entering through the near face, or (from inside) leaving through the far one;
        // the face is on the side of the slab the ray meets it from.
        if t_near > HIT_EPS {
            Some((t_near, Face::of_axis(near_axis, d[near_axis] < 0.0)))
        } else if t_far > HIT_EPS {
            Some((t_far, Face::of_axis(far_axis, d[far_axis] > 0.0)))
        } else {
            None
        }
    }

    /// Keeps the nearer of `best` and the hit on box `index` (bounds `[lo, hi]`); ties go to
    /// the lower index so the result does not depend on the order boxes are visited in.
    pub(crate) fn offer(
        &self,
        lo: &[f64; 3],
        hi: &[f64; 3],
        index: usize,
        best: &mut Option<(f64, usize, Face)>,
    ) {
        if let Some((t, face)) = self.hit_box(lo, hi) {
            if best.is_none_or(|(bt, bi, _)| t < bt || (t == bt && index < bi)) {
                *best = Some((t, index, face));
            }
        }
    }

    pub(crate) fn hit(&self, t: f64, box_index: usize, face: Face) -> Hit {
        let p = |k: usize| self.origin[k] + self.dir[k] * t;
        Hit {
            t,
            box_index,
            face,
            point: Point3::new(p(0), p(1), p(2)),
        }
    }
}

/// The nearest surface along a ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter: `point = origin + t·dir`.
    pub t: f64,
    pub box_index: usize,
    pub face: Face,
    pub point: Point3<f64>,
}

/// A set of boxes and a point light.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    pub boxes: Vec<Box3>,
    pub light: Point3<f64>,
}

impl Scene {
    /// The 12 edges of every box, box by box: edge `12·i + k` is edge `k` of box `i` (see
    /// [`Box3::edges`]). Edges buried in other boxes are kept; visibility removes them.
    pub fn ground_truth_edges(&self) -> Vec<Segment3> {
        self.boxes.iter().flat_map(|b| b.edges()).collect()
    }

    /// Nearest hit along `origin + t·dir` with `t > HIT_EPS` (a ray starting inside a box
    /// hits that box's exit face). Ties go to the lowest box index. `None` for a zero or
    /// non-finite direction.
    pub fn cast(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        let ray = Ray::new(origin, dir)?;
        let mut best: Option<(f64, usize, Face)> = None;
        for (i, b) in self.boxes.iter().enumerate() {
            ray.offer(&b.min.coords.into(), &b.max.coords.into(), i, &mut best);
        }
        best.map(|(t, box_index, face)| ray.hit(t, box_index, face))
    }

    /// Grey level in `0..=255` of a hit: face albedo × (ambient + Lambert term of the point
    /// light with 1/d² falloff). No shadows (see the module doc).
    pub fn shade(&self, hit: &Hit) -> f64 {
        let albedo = self
            .boxes
            .get(hit.box_index)
            .map_or(0.0, |b| b.albedo[hit.face.index()]);
        let to_light = self.light - hit.point;
        let d2 = to_light.norm_squared().max(1e-6);
        let cos = (hit.face.normal().dot(&to_light) / d2.sqrt()).max(0.0);
        (255.0 * albedo * (AMBIENT + LIGHT_POWER * cos / d2)).clamp(0.0, 255.0)
    }

    /// The standard test room (see the module doc); `seed` varies sizes, positions, book
    /// layouts and albedos, never the room shell or the broad layout.
    ///
    /// Room interior: x ∈ [0, 6], y ∈ [0, 5], z ∈ [0, 2.7]. The north wall (y = 5) carries a
    /// bookshelf, a desk with a monitor and a calibration board above it, with a chair in
    /// front; the east wall a door and a cabinet; the south wall a window over a radiator; the
    /// west wall a whiteboard and a low shelf. The light hangs below the ceiling centre.
    pub fn room(seed: u64) -> Scene {
        let mut b = RoomBuilder {
            boxes: Vec::new(),
            rng: Rng::new(seed).fork(0x5CE7E),
        };
        b.shell();
        b.bookshelf();
        b.desk_and_board();
        b.east_wall();
        b.south_wall();
        b.west_wall();
        b.ceiling_fixture();
        Scene {
            boxes: b.boxes,
            light: Point3::new(3.0, 2.5, 2.5),
        }
    }
}

/// Anything that finds the nearest hit along a ray in a scene: the scene itself (brute
/// force) or its [`SceneIndex`](super::bvh::SceneIndex) (same hits, faster).
pub trait Tracer {
    fn scene(&self) -> &Scene;

    fn cast(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Hit>;

    /// Grey level seen along a ray (what a noise-free pinhole pixel records).
    fn radiance(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> f64 {
        self.cast(origin, dir)
            .map_or(BACKGROUND, |hit| self.scene().shade(&hit))
    }
}

impl Tracer for Scene {
    fn scene(&self) -> &Scene {
        self
    }

    fn cast(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        Scene::cast(self, origin, dir)
    }
}

const ROOM_X: f64 = 6.0;
const ROOM_Y: f64 = 5.0;
const ROOM_Z: f64 = 2.7;
const WALL: f64 = 0.1;

struct RoomBuilder {
    boxes: Vec<Box3>,
    rng: Rng,
}

impl RoomBuilder {
    /// Per-face albedo around `base`: faces of one object differ a little, as painted and
    /// worn surfaces do, so that edges between faces of one box keep some contrast.
    fn albedo(&mut self, base: f64) -> [f64; 6] {
        let mut a = [0.0; 6];
        for v in &mut a {
            *v = (base * (1.0 + self.rng.symmetric(0.12))).clamp(0.02, 0.98);
        }
        a
    }

    fn add(&mut self, min: [f64; 3], max: [f64; 3], base_albedo: f64) {
        let albedo = self.albedo(base_albedo);
        self.boxes
            .push(Box3::new(Point3::from(min), Point3::from(max), albedo));
    }

    fn jitter(&mut self, half_width: f64) -> f64 {
        self.rng.symmetric(half_width)
    }

    /// Floor, ceiling and walls as thin boxes around the interior. The north and south walls
    /// span the full width and the east and west walls fit between them, so no two shell
    /// boxes share an edge (which would give duplicate ground-truth edges).
    fn shell(&mut self) {
        let (x, y, z, w) = (ROOM_X, ROOM_Y, ROOM_Z, WALL);
        let floor = self.rng.range(0.25, 0.4);
        self.add([-w, -w, -w], [x + w, y + w, 0.0], floor);
        self.add([-w, -w, z], [x + w, y + w, z + w], 0.9);
        let walls = [
            ([-w, y, 0.0], [x + w, y + w, z]),
            ([-w, -w, 0.0], [x + w, 0.0, z]),
            ([-w, 0.0, 0.0], [0.0, y, z]),
            ([x, 0.0, 0.0], [x + w, y, z]),
        ];
        for (min, max) in walls {
            let base = self.rng.range(0.6, 0.8);
            self.add(min, max, base);
        }
    }

    /// A bookshelf against the north wall, with groups of books on every level: many short
    /// vertical edges, horizontal shelf edges, and occlusions between books.
    fn bookshelf(&mut self) {
        let x0 = 1.75 + self.jitter(0.05);
        let width = 1.0 + self.jitter(0.08);
        let depth = 0.32 + self.jitter(0.03);
        let height = 1.9 + self.jitter(0.08);
        let (y0, y1) = (ROOM_Y - depth, ROOM_Y);
        let board = 0.022;
        let wood = self.rng.range(0.3, 0.55);
        self.add([x0, y0, 0.0], [x0 + board, y1, height], wood);
        self.add(
            [x0 + width - board, y0, 0.0],
            [x0 + width, y1, height],
            wood,
        );
        self.add(
            [x0 - 0.01, y0 - 0.01, height],
            [x0 + width + 0.01, y1, height + board],
            wood,
        );
        // Plinth set back from the front, as real shelves have.
        self.add(
            [x0 + board, y0 + 0.03, 0.0],
            [x0 + width - board, y1, 0.08],
            wood * 0.6,
        );
        let levels = 5;
        let spacing = (height - 0.08) / levels as f64;
        for level in 0..levels {
            let z_floor = 0.08 + level as f64 * spacing;
            if level > 0 {
                let shade = wood * (1.0 + self.jitter(0.1));
                self.add(
                    [x0 + board, y0, z_floor - board],
                    [x0 + width - board, y1, z_floor],
                    shade,
                );
            }
            self.books(
                x0 + board,
                x0 + width - board,
                y0,
                z_floor,
                spacing - board - 0.03,
            );
        }
    }

    /// A group of 4–7 books standing on a shelf between `x_lo` and `x_hi`, spines facing −y.
    fn books(&mut self, x_lo: f64, x_hi: f64, shelf_front: f64, z: f64, max_height: f64) {
        let count = 4 + self.rng.index(4);
        let mut x = x_lo + self.rng.range(0.0, 0.35) * (x_hi - x_lo);
        for _ in 0..count {
            let w = self.rng.range(0.025, 0.07);
            if x + w > x_hi - 0.005 {
                break;
            }
            let h = self.rng.range(0.16, 0.3).min(max_height);
            let d = self.rng.range(0.15, 0.24);
            let front = shelf_front + self.rng.range(0.015, 0.06);
            let albedo = self.rng.range(0.08, 0.9);
            self.add([x, front, z], [x + w, front + d, z + h], albedo);
            x += w + if self.rng.chance(0.3) {
                self.rng.range(0.01, 0.06)
            } else {
                0.002
            };
        }
    }

    /// Desk against the north wall, a monitor on it, a calibration board (a light board with a
    /// grid of thin dark squares) on the wall above, a chair in front and a skirting board.
    fn desk_and_board(&mut self) {
        let x0 = 3.05 + self.jitter(0.04);
        let x1 = 4.45 + self.jitter(0.04);
        let y0 = 4.3 + self.jitter(0.03);
        let top = 0.74 + self.jitter(0.02);
        let desk = self.rng.range(0.45, 0.7);
        self.add([x0, y0, top - 0.03], [x1, ROOM_Y, top], desk);
        let leg = 0.045;
        for (lx, ly) in [(x0 + 0.03, y0 + 0.03), (x1 - 0.03 - leg, y0 + 0.03)] {
            self.add([lx, ly, 0.0], [lx + leg, ly + leg, top - 0.03], desk * 0.5);
        }
        for lx in [x0 + 0.03, x1 - 0.03 - leg] {
            self.add(
                [lx, ROOM_Y - 0.03 - leg, 0.0],
                [lx + leg, ROOM_Y - 0.03, top - 0.03],
                desk * 0.5,
            );
        }
        // Monitor: stand and screen, at the right end of the desk.
        let mx = x1 - 0.6 + self.jitter(0.03);
        let my = ROOM_Y - 0.25;
        self.add(
            [mx + 0.21, my, top],
            [mx + 0.29, my + 0.08, top + 0.12],
            0.15,
        );
        self.add([mx, my - 0.03, top + 0.12], [mx + 0.5, my, top + 0.44], 0.1);
        // Calibration board: 6 x 4 squares of 9 cm, 4 cm apart, 2 mm proud of the board.
        let bx = x0 + 0.08 + self.jitter(0.02);
        let bz = 1.0 + self.jitter(0.03);
        let (cols, rows, sq, gap) = (6usize, 4usize, 0.09, 0.04);
        let bw = cols as f64 * sq + (cols + 1) as f64 * gap;
        let bh = rows as f64 * sq + (rows + 1) as f64 * gap;
        let by = ROOM_Y - 0.015;
        self.add([bx, by, bz], [bx + bw, ROOM_Y, bz + bh], 0.92);
        for r in 0..rows {
            for c in 0..cols {
                let sx = bx + gap + c as f64 * (sq + gap);
                let sz = bz + gap + r as f64 * (sq + gap);
                self.add([sx, by - 0.002, sz], [sx + sq, by, sz + sq], 0.07);
            }
        }
        // Chair facing the desk, backrest towards the room centre.
        let cx = (x0 + x1) / 2.0 - 0.25 + self.jitter(0.1);
        let cy = y0 - 0.5 + self.jitter(0.05);
        let chair = self.rng.range(0.1, 0.5);
        let seat = 0.45 + self.jitter(0.02);
        self.add([cx, cy, seat - 0.05], [cx + 0.45, cy + 0.45, seat], chair);
        for (lx, ly) in [(0.0, 0.0), (0.41, 0.0), (0.0, 0.41), (0.41, 0.41)] {
            self.add(
                [cx + lx, cy + ly, 0.0],
                [cx + lx + 0.04, cy + ly + 0.04, seat - 0.05],
                chair * 0.6,
            );
        }
        self.add([cx, cy - 0.04, seat], [cx + 0.45, cy, seat + 0.42], chair);
        // Skirting board along the north wall (horizontal lines at floor level).
        self.add([0.0, ROOM_Y - 0.015, 0.0], [ROOM_X, ROOM_Y, 0.08], 0.85);
    }

    /// Door with frame and handle, a cabinet with two doors, and two posters.
    fn east_wall(&mut self) {
        let x = ROOM_X;
        let y0 = 1.0 + self.jitter(0.05);
        let y1 = y0 + 0.9;
        let top = 2.05;
        let frame = self.rng.range(0.75, 0.95);
        let door = self.rng.range(0.3, 0.6);
        self.add([x - 0.03, y0, 0.0], [x, y1, top], door);
        self.add([x - 0.05, y0 - 0.07, 0.0], [x, y0, top + 0.07], frame);
        self.add([x - 0.05, y1, 0.0], [x, y1 + 0.07, top + 0.07], frame);
        self.add([x - 0.05, y0, top], [x, y1, top + 0.07], frame);
        self.add(
            [x - 0.09, y0 + 0.72, 1.0],
            [x - 0.03, y0 + 0.82, 1.03],
            0.15,
        );
        // Cabinet.
        let c0 = 2.6 + self.jitter(0.05);
        let c1 = c0 + 1.2;
        let ch = 0.9 + self.jitter(0.05);
        let body = self.rng.range(0.5, 0.8);
        self.add([x - 0.45, c0, 0.0], [x, c1, ch], body);
        let mid = (c0 + c1) / 2.0;
        for (d0, d1) in [(c0 + 0.02, mid - 0.005), (mid + 0.005, c1 - 0.02)] {
            self.add([x - 0.47, d0, 0.1], [x - 0.45, d1, ch - 0.03], body * 0.85);
        }
        for hy in [mid - 0.06, mid + 0.04] {
            self.add(
                [x - 0.5, hy, ch - 0.3],
                [x - 0.47, hy + 0.02, ch - 0.12],
                0.1,
            );
        }
        for (p0, p1, z0, z1) in [(3.9, 4.6, 1.2, 2.0), (2.8, 3.5, 1.3, 1.8)] {
            let albedo = self.rng.range(0.1, 0.9);
            let j = self.jitter(0.05);
            self.add([x - 0.003, p0 + j, z0 + j], [x, p1 + j, z1 + j], albedo);
        }
        self.add([x - 0.015, 0.0, 0.0], [x, ROOM_Y, 0.08], 0.85);
    }

    /// Window (frame, pane, mullion, transom, sill) over a radiator with vertical fins.
    fn south_wall(&mut self) {
        let (x0, x1, z0, z1) = (2.0 + self.jitter(0.05), 4.0 + self.jitter(0.05), 0.9, 2.2);
        let frame = self.rng.range(0.8, 0.95);
        let f = 0.06;
        self.add([x0, 0.005, z0 + f], [x1, 0.01, z1 - f], 0.97);
        self.add([x0 - f, 0.0, z0], [x0, 0.06, z1], frame);
        self.add([x1, 0.0, z0], [x1 + f, 0.06, z1], frame);
        self.add([x0 - f, 0.0, z1 - f], [x1 + f, 0.06, z1], frame);
        self.add([x0 - f, 0.0, z0], [x1 + f, 0.06, z0 + f], frame);
        let xm = (x0 + x1) / 2.0;
        self.add(
            [xm - 0.025, 0.01, z0 + f],
            [xm + 0.025, 0.05, z1 - f],
            frame,
        );
        let zt = z0 + 0.7 * (z1 - z0);
        self.add(
            [x0, 0.01, zt - 0.025],
            [xm - 0.025, 0.05, zt + 0.025],
            frame,
        );
        self.add(
            [x0 - 0.1, 0.0, z0 - 0.04],
            [x1 + 0.1, 0.18, z0],
            frame * 0.9,
        );
        // Radiator body and fins.
        let (r0, r1) = (x0 + 0.2, x1 - 0.2);
        let rad = self.rng.range(0.7, 0.9);
        self.add([r0, 0.05, 0.15], [r1, 0.12, 0.7], rad);
        let fins = 8;
        for k in 0..fins {
            let fx = r0 + 0.05 + k as f64 * (r1 - r0 - 0.12) / (fins - 1) as f64;
            self.add([fx, 0.12, 0.17], [fx + 0.02, 0.135, 0.68], rad * 0.8);
        }
        self.add([0.0, 0.0, 0.0], [ROOM_X, 0.015, 0.08], 0.85);
    }

    /// Whiteboard with a pen tray, a low shelf with a few boxes on it, and a poster.
    fn west_wall(&mut self) {
        let y0 = 1.5 + self.jitter(0.1);
        self.add([0.0, y0, 0.9], [0.02, y0 + 1.8, 2.0], 0.95);
        self.add([0.02, y0 + 0.1, 0.9], [0.08, y0 + 1.7, 0.93], 0.4);
        let (s0, s1) = (3.6 + self.jitter(0.05), 4.8);
        let shelf = self.rng.range(0.3, 0.6);
        self.add([0.0, s0, 0.0], [0.4, s1, 0.75], shelf);
        let mut y = s0 + 0.05;
        for _ in 0..4 {
            let w = self.rng.range(0.12, 0.25);
            let h = self.rng.range(0.08, 0.3);
            let albedo = self.rng.range(0.1, 0.9);
            self.add([0.05, y, 0.75], [0.35, y + w, 0.75 + h], albedo);
            y += w + self.rng.range(0.02, 0.08);
            if y > s1 - 0.1 {
                break;
            }
        }
        let albedo = self.rng.range(0.1, 0.9);
        self.add([0.0, 0.4, 1.1], [0.003, 1.1, 1.9], albedo);
        self.add([0.0, 0.0, 0.0], [0.015, ROOM_Y, 0.08], 0.85);
    }

    fn ceiling_fixture(&mut self) {
        self.add([2.6, 2.3, ROOM_Z - 0.08], [3.4, 2.7, ROOM_Z], 0.95);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box(albedo: f64) -> Box3 {
        Box3::new(
            Point3::new(-0.5, 2.0, -0.5),
            Point3::new(0.5, 3.0, 0.5),
            [albedo; 6],
        )
    }

    #[test]
    fn ray_hits_box_at_the_right_distance_and_face() {
        let scene = Scene {
            boxes: vec![unit_box(0.5)],
            light: Point3::new(0.0, 0.0, 0.0),
        };
        let hit = scene
            .cast(&Point3::origin(), &Vector3::new(0.0, 2.0, 0.0))
            .unwrap();
        assert!((hit.t - 1.0).abs() < 1e-12, "t = {}", hit.t);
        assert_eq!(hit.face, Face::NegY);
        assert!((hit.point - Point3::new(0.0, 2.0, 0.0)).norm() < 1e-12);
        // An oblique ray enters through the −y face too, at (0.2, 2, 0).
        let hit = scene
            .cast(&Point3::origin(), &Vector3::new(0.1, 1.0, 0.0))
            .unwrap();
        assert_eq!(hit.face, Face::NegY);
        assert!((hit.t - 2.0).abs() < 1e-12);
        // From inside, the exit face.
        let hit = scene
            .cast(&Point3::new(0.0, 2.5, 0.0), &Vector3::new(0.0, 0.0, 1.0))
            .unwrap();
        assert_eq!(hit.face, Face::PosZ);
        assert!((hit.t - 0.5).abs() < 1e-12);
        assert!(scene
            .cast(&Point3::origin(), &Vector3::new(0.0, -1.0, 0.0))
            .is_none());
        assert!(scene
            .cast(&Point3::origin(), &Vector3::new(1.0, 0.0, 0.0))
            .is_none());
    }

    #[test]
    fn nearest_of_two_boxes_wins() {
        let near = unit_box(0.2);
        let mut far = unit_box(0.8);
        far.min.y += 3.0;
        far.max.y += 3.0;
        let scene = Scene {
            boxes: vec![far, near],
            light: Point3::origin(),
        };
        let hit = scene
            .cast(&Point3::origin(), &Vector3::new(0.0, 1.0, 0.0))
            .unwrap();
        assert_eq!(hit.box_index, 1);
    }

    #[test]
    fn shading_follows_lambert_and_distance() {
        let scene = Scene {
            boxes: vec![unit_box(0.5)],
            light: Point3::new(0.0, 1.0, 0.0),
        };
        let hit = scene
            .cast(&Point3::origin(), &Vector3::new(0.0, 1.0, 0.0))
            .unwrap();
        let expected = 255.0 * 0.5 * (AMBIENT + LIGHT_POWER / 1.0);
        assert!((scene.shade(&hit) - expected.min(255.0)).abs() < 1e-9);
        // A face turned away from the light gets the ambient term only.
        let side = scene
            .cast(&Point3::new(2.0, 2.5, 0.0), &Vector3::new(-1.0, 0.0, 0.0))
            .unwrap();
        assert_eq!(side.face, Face::PosX);
        assert!((scene.shade(&side) - 255.0 * 0.5 * AMBIENT).abs() < 1e-9);
    }

    #[test]
    fn box_edges_are_the_twelve_edges() {
        let b = unit_box(0.5);
        let edges = b.edges();
        let mut lengths: Vec<f64> = edges.iter().map(|e| e.length()).collect();
        lengths.sort_by(f64::total_cmp);
        assert!(lengths.iter().all(|&l| (l - 1.0).abs() < 1e-12));
        for e in &edges {
            let d = e.end - e.start;
            assert_eq!(d.iter().filter(|v| v.abs() > 0.0).count(), 1);
            assert!(d.iter().all(|&v| v >= 0.0));
        }
    }

    #[test]
    fn room_is_closed_and_reproducible() {
        let a = Scene::room(5);
        assert_eq!(a, Scene::room(5));
        assert_ne!(a, Scene::room(6));
        assert!(
            (40..=150).contains(&a.boxes.len()),
            "{} boxes",
            a.boxes.len()
        );
        assert!(a.boxes.iter().all(|b| (0..3).all(|k| b.min[k] < b.max[k])));
        assert!(a
            .boxes
            .iter()
            .all(|b| b.albedo.iter().all(|v| (0.0..=1.0).contains(v))));
        assert!(a.boxes.iter().all(|b| !b.contains_strictly(&a.light, 0.0)));
        // Every ray from the room centre hits something: the room is closed.
        let centre = Point3::new(3.0, 2.5, 1.2);
        let mut rng = Rng::new(1);
        for _ in 0..200 {
            let d = Vector3::new(rng.normal(), rng.normal(), rng.normal());
            assert!(a.cast(&centre, &d).is_some());
        }
    }
}
