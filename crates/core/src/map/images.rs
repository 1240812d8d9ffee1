//! Registration in the capture's own images: where did the rig stand, judged by how the 3D
//! segments of an earlier capture project onto the edges the new capture's cameras saw?
//!
//! Registration in 3D ([`super::register`]) pairs the new capture's 3D segments with the
//! map's. Those are few where it matters: a capture of a bare wall passes the accuracy gate
//! with 8–20 segments, and two captures 15–30° apart share four or five of them — too few to
//! tell a pose from one a stride over. The new capture's image segments are hundreds per
//! view, and an earlier capture's 3D segment need only have been *seen* by the new cameras,
//! not matched and gated in all three, to say where the rig stood: its projection must lie
//! on an image segment, to a few tenths of a pixel.
//!
//! [`refine_in_images`] starts from a pose (a 3D registration's, or the prior), projects each
//! reference segment into the three views, pairs it with the image segment of the same
//! orientation lying along it, and solves the pose by Gauss–Newton (Huber-weighted) on the
//! image segments' distances from the projected lines, each under the image line's noise
//! and the reference's own covariance projected into the image, with the prior as a
//! measurement; association and solution alternate as the gate narrows from a few pixels
//! to its χ². Where the refinements leave many projections in view unpaired, each start is
//! searched locally (a grid across the floor and in heading, as far as twice the prior's
//! spread, scored by one truncated cost over every visible projection) and the grid's
//! cheapest cells refined — its inner ±4 cm first, the rest only when that leaves the fit
//! unsettled and only cells cheaper than the best refined fit — so a start outside the
//! right basin, where a 3D registration of few segments may leave it
//! (one stride over along a repetitive wall), is not refined into the wrong one; the
//! refined pose of lowest cost wins. A start
//! that sees too few references for a fit is not refined at all. Last, the winner is refined
//! again from a step over by each period its paired references repeat at (a row of fins or
//! uprights, farther than the search reaches): a fit there clearly cheaper replaces it, one
//! about as cheap widens its covariance along the row.
//!
//! The fit's information is scaled by the residuals' spread about their model (the
//! a-posteriori variance factor, never below [`ImageParams::min_variance_factor`]): on the
//! shared rooms the residuals at the fitted pose are 0.02–0.07 px where the model says
//! 0.3–0.7 px — the reference's own error lies mostly along the rays of the capture that
//! measured it, which a camera a few centimetres from it barely sees across — and unscaled,
//! the edges claimed ten times the spread they had (docs/SESSIONS.md).

use nalgebra::{
    Isometry3, Matrix2x3, Matrix3, Matrix6, Point3, SMatrix, Vector2, Vector3, Vector6,
};

use super::poses::{difference, perturbed};
use super::register::{rival_weight, Measured, PosePrior, RIVAL_COST};
use crate::checkpoint::{never_stopped, Checkpoint, Stopped};
use crate::geometry::camera::Camera;
use crate::segment::{LineNoise, Segment2};

/// A capture's image evidence: its rig's cameras (rig frame) and each view's segments, in
/// the (distorted) pixels they were extracted in.
#[derive(Debug, Clone, Copy)]
pub struct Views<'a> {
    pub cameras: &'a [Camera; 3],
    pub segments: [&'a [Segment2]; 3],
    /// Line noise of a segment that carries none ([`LineNoise::for_list`]).
    pub list_noise_px: f64,
}

/// A capture's image evidence made ready for [`refine_in_images_until`]: each camera's
/// projection with its `K·R` factored once, and each view's segments undistorted and
/// indexed by where they run — when a refinement first needs them, once for all the
/// earlier captures an AddCapture refines against (most of which a panorama's capture does
/// not see at all).
pub struct IndexedViews<'a> {
    views: Views<'a>,
    offset_floor_px: f64,
    lenses: [Lens; 3],
    lines: std::cell::OnceCell<[ViewIndex; 3]>,
}

impl<'a> IndexedViews<'a> {
    /// `params` as the refinements will be given them (the image lines' offset floor).
    pub fn new(views: &Views<'a>, params: &ImageParams) -> IndexedViews<'a> {
        IndexedViews {
            views: *views,
            offset_floor_px: params.offset_floor_px,
            lenses: std::array::from_fn(|k| Lens::of(&views.cameras[k])),
            lines: std::cell::OnceCell::new(),
        }
    }

    fn lines(&self) -> &[ViewIndex; 3] {
        self.lines
            .get_or_init(|| image_lines(&self.views, self.offset_floor_px))
    }
}

/// A camera as the projections need it: the derivative's `K·R` computed once, not per point.
#[derive(Debug, Clone, Copy)]
struct Lens {
    rotation: Matrix3<f64>,
    translation: Vector3<f64>,
    intrinsics: Matrix3<f64>,
    intrinsics_rotation: Matrix3<f64>,
    width: f64,
    height: f64,
}

impl Lens {
    /// How far a rig-frame point's pixel moves along `normal` per metre it moves (the
    /// transposed derivative of [`project`] times `normal`), from its `pixel` and its
    /// homogeneous `h` as [`pixel_of`] gives them: the derivative's rows
    /// (K·R)ᵢ − pixelᵢ·(K·R)₂ over h.z, summed along the normal without forming them.
    fn across_gradient(
        &self,
        pixel: &Vector2<f64>,
        h: &Vector3<f64>,
        normal: &Vector2<f64>,
    ) -> Vector3<f64> {
        let kr = &self.intrinsics_rotation;
        (kr.row(0).transpose() * normal.x + kr.row(1).transpose() * normal.y
            - kr.row(2).transpose() * normal.dot(pixel))
            / h.z
    }

    fn of(camera: &Camera) -> Lens {
        Lens {
            rotation: *camera.rotation(),
            translation: *camera.translation(),
            intrinsics: *camera.intrinsics(),
            intrinsics_rotation: camera.intrinsics() * camera.rotation(),
            width: camera.width() as f64,
            height: camera.height() as f64,
        }
    }
}

/// What [`refine_in_images`] found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageFit {
    /// The capture's rig in the references' frame.
    pub pose: Isometry3<f64>,
    /// Its covariance, prior included, as [`PosePrior::covariance`].
    pub covariance: Matrix6<f64>,
    /// The information of the images alone (no prior).
    pub information: Matrix6<f64>,
    /// Projections (reference segment, view) paired with an image segment.
    pub inliers: u32,
    /// Reference segments paired in at least one view.
    pub references: u32,
    /// The truncated cost the starts were compared by.
    pub cost: f64,
}

/// Tunables of [`refine_in_images`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageParams {
    /// Fewest reference segments paired (in any view) for a fit.
    pub min_references: u32,
    /// Projections shorter than this take no part, pixels: their direction says little.
    pub min_projected_px: f64,
    /// Pixel gates of the association rounds, widest first; the last rounds gate by χ².
    pub pixel_gates: [f64; 3],
    /// Floor of an image line's offset noise, pixels (what the edge points do not show).
    pub offset_floor_px: f64,
    /// Isotropic noise added to each reference endpoint, metres.
    pub reference_floor_m: f64,
    /// The local search about each start: steps across the floor (metres) and in heading
    /// (radians), and how many steps either side ([`GRID_STEPS_XY`], [`GRID_STEPS_YAW`]).
    pub grid_step_m: f64,
    pub grid_step_rad: f64,
    /// Grid cells refined, cheapest first.
    pub refined_starts: usize,
    /// The local search runs only when the refinements from the starts pair fewer than this
    /// share of the projections in view: in the right basin nearly all of them pair (the
    /// driving loop's seed 4, capture 1: 93% at the true pose, 50% in the basin 34 mm off).
    /// At 0.8 or 0.9 one of the driving loop's seeds at 3° settled in a wrong basin (map
    /// 2.9% → 9.3% wrong); at 0.95 every figure is the search's everywhere, at a third of
    /// its cost.
    pub settled_fraction: f64,
    /// The search reaches past its inner ±4 cm, as far as the prior's spread, only when the
    /// inner search leaves fewer than this share of the projections in view paired: in the
    /// driving loop at 3° the two starts one stride over left 81%, the right basins the
    /// inner search left unsettled 66–95% (at 0.95 the outer search ran 55 times in eight
    /// sessions and changed nothing else; it doubles an AddCapture where it runs).
    pub wide_search_fraction: f64,
    /// The fit's information is the images' scaled by the residuals' spread about what
    /// their variances say (the a-posteriori variance factor), which may shrink them by at
    /// most this much: see [`refine_in_images`].
    pub min_variance_factor: f64,
}

/// Steps either side of a start in the local search: across the floor, at least ±2 × 2 cm,
/// and in heading, ±1 × 0.5°: the 3D registrations it starts from are off by up to 4 cm and
/// 0.5° where they fail (the driving loop, seed 4: 34 mm), and the right pose's basin is a
/// few pixels, about 2 cm and 0.5° at 3 m, wide.
pub const GRID_STEPS_XY: i32 = 2;
pub const GRID_STEPS_YAW: i32 = 1;
/// Across the floor the search reaches as far as the prior says the rig may be,
/// [`SEARCH_SIGMAS`] σ per axis, but at most this many steps either side (±10 cm). Where
/// a repetitive wall leaves a 3D registration one stride over, the start is as far off as
/// the odometry was: 9–12 cm in the driving loop at 3° / 5 cm, whose two seeds of eight
/// that failed wholesale at the fixed ±4 cm (capture 1 registered 95 and 102 mm off, the
/// right basin's cost 48 and 87 against 166 and 187) now place it within 4 mm.
pub const MAX_GRID_STEPS_XY: i32 = 5;
const SEARCH_SIGMAS: f64 = 2.0;

impl Default for ImageParams {
    fn default() -> Self {
        ImageParams {
            min_references: 8,
            min_projected_px: 15.0,
            pixel_gates: [6.0, 3.0, 1.5],
            offset_floor_px: 0.15,
            reference_floor_m: 0.002,
            grid_step_m: 0.02,
            grid_step_rad: 0.5f64.to_radians(),
            refined_starts: 3,
            settled_fraction: 0.95,
            wide_search_fraction: 0.9,
            min_variance_factor: 0.04,
        }
    }
}

/// χ² with 2 degrees of freedom (the image line's offset and angle) at 0.99: the gate of a
/// pairing in the last rounds and the truncation of the cost.
const PAIR_GATE: f64 = 9.21;
/// Huber's threshold on a pairing's normalised residual.
const HUBER: f64 = 2.0;
/// Gauss–Newton steps per round of association, and rounds after the pixel gates.
const STEPS: usize = 3;
const CHI2_ROUNDS: usize = 3;
/// Widest angle between a projection and its image segment, radians (beyond the noise).
const ANGLE_GATE_RAD: f64 = 0.06;

/// An image segment, undistorted, with what the fit needs of it.
#[derive(Debug, Clone, Copy)]
struct ImageLine {
    start: Vector2<f64>,
    end: Vector2<f64>,
    /// Unit direction start → end.
    direction: Vector2<f64>,
    length: f64,
    offset_var: f64,
    angle_var: f64,
}

/// A reference segment projected into one view.
#[derive(Debug, Clone, Copy)]
struct Projected {
    start: Vector2<f64>,
    end: Vector2<f64>,
    /// Unit normal (direction turned +90°) and offset: n·x + c = 0 on the line.
    normal: Vector2<f64>,
    offset: f64,
    length: f64,
    /// Variance across the line of each projected end from the reference's covariance.
    start_var: f64,
    end_var: f64,
}

/// One pairing: reference `reference` in view `view` lies along image segment `line`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Pairing {
    reference: usize,
    view: usize,
    line: usize,
}

/// One view's image segments and a grid of the cells each passes through, so that a
/// projection reads only the segments near it.
struct ViewIndex {
    lines: Vec<ImageLine>,
    cells: Vec<Vec<u32>>,
    /// Side of a cell, pixels.
    cell: f64,
    columns: usize,
    rows: usize,
}

/// Side of a [`ViewIndex`] cell, pixels: wider than the widest pixel gate …
const CELL_PX: f64 = 16.0;
/// … but cells per side at most this: a calibration may declare images of 65,536 pixels a
/// side, and a grid of 16-pixel cells over three of those would take gigabytes.
const MAX_CELLS_PER_SIDE: f64 = 256.0;

impl std::ops::Index<usize> for ViewIndex {
    type Output = ImageLine;
    fn index(&self, i: usize) -> &ImageLine {
        &self.lines[i]
    }
}

impl ViewIndex {
    fn new(lines: Vec<ImageLine>, width: u32, height: u32) -> ViewIndex {
        let cell = CELL_PX.max(width.max(height) as f64 / MAX_CELLS_PER_SIDE);
        let columns = (width as f64 / cell).ceil() as usize + 1;
        let rows = (height as f64 / cell).ceil() as usize + 1;
        let mut cells = vec![Vec::new(); columns * rows];
        for (i, line) in lines.iter().enumerate() {
            let mut last = usize::MAX;
            Self::walk(line.start, line.end, cell, columns, rows, |cell| {
                if cell != last {
                    cells[cell].push(i as u32);
                    last = cell;
                }
            });
        }
        for cell in &mut cells {
            cell.dedup();
        }
        ViewIndex {
            lines,
            cells,
            cell,
            columns,
            rows,
        }
    }

    /// The cells under points every cell's width from `a` to `b` (those inside the grid):
    /// with their neighbours, every cell within a cell of the segment.
    fn walk(
        a: Vector2<f64>,
        b: Vector2<f64>,
        cell: f64,
        columns: usize,
        rows: usize,
        mut visit: impl FnMut(usize),
    ) {
        Self::walk_points(a, b, cell, |c, r| {
            if c >= 0.0 && r >= 0.0 && (c as usize) < columns && (r as usize) < rows {
                visit(r as usize * columns + c as usize);
            }
        });
    }

    /// The cells (column, row, as floats, perhaps outside the grid) under points every
    /// cell's width from `a` to `b`.
    fn walk_points(a: Vector2<f64>, b: Vector2<f64>, cell: f64, mut visit: impl FnMut(f64, f64)) {
        let steps = ((b - a).norm() / cell).ceil().clamp(1.0, 4096.0) as usize;
        for k in 0..=steps {
            let p = a + (b - a) * (k as f64 / steps as f64);
            visit((p.x / cell).floor(), (p.y / cell).floor());
        }
    }

    /// Every segment passing through a cell under the projection or next to one, each once
    /// (`seen` holds, per segment and per cell, the stamp of the last query that read it).
    fn near(&self, p: &Projected, seen: &mut Seen, mut visit: impl FnMut(usize)) {
        let columns = self.columns;
        seen.stamp += 1;
        Self::walk(p.start, p.end, self.cell, columns, self.rows, |cell| {
            let (c, r) = ((cell % columns) as isize, (cell / columns) as isize);
            self.read_about(c, r, 1, seen, &mut visit);
        });
    }

    /// Every segment passing through a cell within `radius` cells of one under the
    /// projection, each once; a point of the projection outside the grid counts as the
    /// grid's cell nearest it (so that what lies within `radius` of the projection's points
    /// inside the grid is read wherever the projection runs).
    fn within(&self, p: &Projected, radius: isize, seen: &mut Seen, mut visit: impl FnMut(usize)) {
        let (last_column, last_row) = (self.columns as f64 - 1.0, self.rows as f64 - 1.0);
        seen.stamp += 1;
        Self::walk_points(p.start, p.end, self.cell, |c, r| {
            let (c, r) = (c.clamp(0.0, last_column), r.clamp(0.0, last_row));
            self.read_about(c as isize, r as isize, radius, seen, &mut visit);
        });
    }

    /// The segments of the cells within `radius` of cell (`c`, `r`) not read yet by this
    /// query (stamp `seen.stamp`).
    fn read_about(
        &self,
        c: isize,
        r: isize,
        radius: isize,
        seen: &mut Seen,
        visit: &mut impl FnMut(usize),
    ) {
        let (columns, rows) = (self.columns, self.rows);
        let stamp = seen.stamp;
        for dr in -radius..=radius {
            for dc in -radius..=radius {
                let (cc, rr) = (c + dc, r + dr);
                if cc < 0 || rr < 0 || cc as usize >= columns || rr as usize >= rows {
                    continue;
                }
                let at = rr as usize * columns + cc as usize;
                if seen.cells[at] == stamp {
                    continue;
                }
                seen.cells[at] = stamp;
                for &i in &self.cells[at] {
                    if seen.lines[i as usize] != stamp {
                        seen.lines[i as usize] = stamp;
                        visit(i as usize);
                    }
                }
            }
        }
    }
}

/// What a [`ViewIndex`] query has read already: the stamp of the last query per segment and
/// per cell.
struct Seen {
    lines: Vec<u32>,
    cells: Vec<u32>,
    stamp: u32,
}

impl Seen {
    fn of(index: &ViewIndex) -> Seen {
        Seen {
            lines: vec![0; index.lines.len()],
            cells: vec![0; index.cells.len()],
            stamp: 0,
        }
    }
}

/// Each view's segments as [`ImageLine`]s, indexed by where they run.
fn image_lines(views: &Views, offset_floor_px: f64) -> [ViewIndex; 3] {
    std::array::from_fn(|k| {
        let camera = &views.cameras[k];
        let lines: Vec<ImageLine> = views.segments[k]
            .iter()
            .filter_map(|s| {
                let a = camera.undistort(s.start).coords;
                let b = camera.undistort(s.end).coords;
                let length = (b - a).norm();
                if !length.is_finite() || length < 1.0 {
                    return None;
                }
                let noise = s
                    .noise
                    .unwrap_or_else(|| LineNoise::for_list(views.list_noise_px, length));
                Some(ImageLine {
                    start: a,
                    end: b,
                    direction: (b - a) / length,
                    length,
                    offset_var: noise.offset_px.powi(2) + offset_floor_px.powi(2),
                    angle_var: noise.angle_rad.powi(2),
                })
            })
            .collect();
        ViewIndex::new(lines, camera.width(), camera.height())
    })
}

/// A rig-frame point in a camera's undistorted pixels; `None` behind the camera.
fn pixel_of(lens: &Lens, x: &Vector3<f64>) -> Option<(Vector2<f64>, Vector3<f64>)> {
    let c = lens.rotation * x + lens.translation;
    if c.z <= 0.05 {
        return None;
    }
    let h = lens.intrinsics * c;
    Some((Vector2::new(h.x / h.z, h.y / h.z), h))
}

/// The unit normal (direction turned +90°) and offset of the line through `a` and `b`:
/// n·x + c = 0 on it.
fn line_through(a: &Vector2<f64>, b: &Vector2<f64>) -> (Vector2<f64>, f64) {
    let d = b - a;
    let normal = Vector2::new(-d.y, d.x) / d.norm();
    (normal, -normal.dot(a))
}

/// [`pixel_of`], with the derivative of the pixel by the point.
fn project(lens: &Lens, x: &Vector3<f64>) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
    let (pixel, h) = pixel_of(lens, x)?;
    // d(h.xy / h.z)/dc = (K_xy − pixel · K_z) / h.z, then dc/dx = R.
    let kr = &lens.intrinsics_rotation;
    let row = |i: usize| (kr.row(i) - kr.row(2) * pixel[i]) / h.z;
    let jacobian = Matrix2x3::from_rows(&[row(0), row(1)]);
    Some((pixel, jacobian))
}

/// Each reference projected into each view at `pose` (capture rig → references' frame);
/// `None` where it is behind a camera, outside the image or too short there.
fn project_all(
    references: &[Measured],
    lenses: &[Lens; 3],
    pose: &Isometry3<f64>,
    params: &ImageParams,
) -> Vec<[Option<Projected>; 3]> {
    project_turned(lenses, pose, &turned_references(references, pose), params)
}

/// A reference turned into the axes of a capture's rig: its ends (not yet shifted by the
/// capture's position) and their covariances.
struct Turned {
    start: Point3<f64>,
    end: Point3<f64>,
    covariances: [Matrix3<f64>; 2],
}

/// Each reference turned by the rotation of a capture at `pose`: what depends on that
/// rotation alone, so that a search's cells of one heading share it.
fn turned_references(references: &[Measured], pose: &Isometry3<f64>) -> Vec<Turned> {
    let rotation = pose.inverse().rotation;
    let to_rig = rotation.to_rotation_matrix().into_inner();
    references
        .iter()
        .map(|m| Turned {
            start: rotation.transform_point(&m.start),
            end: rotation.transform_point(&m.end),
            covariances: std::array::from_fn(|block| {
                let c = m.covariance.fixed_view::<3, 3>(3 * block, 3 * block);
                to_rig * c * to_rig.transpose()
            }),
        })
        .collect()
}

/// [`project_all`], given the references [`turned_references`] by `pose`'s rotation.
fn project_turned(
    lenses: &[Lens; 3],
    pose: &Isometry3<f64>,
    turned: &[Turned],
    params: &ImageParams,
) -> Vec<[Option<Projected>; 3]> {
    // The inverse pose's point transform is its rotation, then its translation.
    let shift = pose.inverse().translation;
    let floor = params.reference_floor_m.powi(2);
    turned
        .iter()
        .map(|t| {
            let a = (shift * t.start).coords;
            let b = (shift * t.end).coords;
            let [ca, cb] = &t.covariances;
            std::array::from_fn(|k| {
                let lens = &lenses[k];
                let (pa, ha) = pixel_of(lens, &a)?;
                let (pb, hb) = pixel_of(lens, &b)?;
                let d = pb - pa;
                let length = d.norm();
                if length < params.min_projected_px {
                    return None;
                }
                let (w, h) = (lens.width, lens.height);
                let inside = |p: &Vector2<f64>| p.x >= 0.0 && p.y >= 0.0 && p.x <= w && p.y <= h;
                if !inside(&pa) && !inside(&pb) && !inside(&((pa + pb) * 0.5)) {
                    return None;
                }
                let (normal, offset) = line_through(&pa, &pb);
                let across = |pixel: &Vector2<f64>, h: &Vector3<f64>, c: &Matrix3<f64>| {
                    let g = lens.across_gradient(pixel, h, &normal);
                    g.dot(&(c * g)) + floor * g.norm_squared()
                };
                let (start_var, end_var) = (across(&pa, &ha, ca), across(&pb, &hb, cb));
                Some(Projected {
                    start: pa,
                    end: pb,
                    normal,
                    offset,
                    length,
                    start_var,
                    end_var,
                })
            })
        })
        .collect()
}

/// The image segment's distances from the projected line: at its midpoint, and the turn
/// between them (radians), each with its variance; `None` when they do not overlap along
/// the line.
fn residuals(p: &Projected, line: &ImageLine) -> Option<(Vector2<f64>, Vector2<f64>)> {
    let ra = p.normal.dot(&line.start) + p.offset;
    let rb = p.normal.dot(&line.end) + p.offset;
    let along = (p.end - p.start) / p.length;
    let ta = along.dot(&(line.start - p.start));
    let tb = along.dot(&(line.end - p.start));
    let overlap = ta.max(tb).min(p.length) - ta.min(tb).max(0.0);
    if overlap < 0.5 * line.length.min(p.length) {
        return None;
    }
    let mid = 0.5 * (ra + rb);
    let turn = (rb - ra) / line.length;
    // The reference's across-line variance where the image segment's midpoint falls,
    // interpolated between the projected ends (their errors taken as independent).
    let t = (0.5 * (ta + tb) / p.length).clamp(-0.5, 1.5);
    let reference_mid = (1.0 - t).powi(2) * p.start_var + t.powi(2) * p.end_var;
    let reference_turn = (p.start_var + p.end_var) / p.length.powi(2);
    Some((
        Vector2::new(mid, turn),
        Vector2::new(
            line.offset_var + reference_mid,
            line.angle_var + reference_turn,
        ),
    ))
}

/// Where [`associate`] looks for a projection's image segment: the view's index about it,
/// or lists gathered beforehand per reference and view ([`gathered`], [`gathered_about`]) —
/// the index still, for a projection that has none, or that has moved or turned from the
/// one its list was gathered about by more than the list allows.
struct Candidates<'c> {
    seen: [Seen; 3],
    lists: Option<&'c [[Option<Vec<u32>>; 3]]>,
    anchored: Option<Anchors<'c>>,
}

/// The projections lists were gathered about, and how far a projection may lie from its
/// own and still read its list: moved by at most `moved_px` at either end, turned by at
/// most the angle whose cosine is `turned_cos`.
struct Anchors<'c> {
    projected: &'c [[Option<Projected>; 3]],
    moved_px: [f64; 3],
    turned_cos: f64,
}

impl<'c> Candidates<'c> {
    fn near(lines: &[ViewIndex; 3]) -> Self {
        Candidates {
            seen: std::array::from_fn(|k| Seen::of(&lines[k])),
            lists: None,
            anchored: None,
        }
    }

    fn listed(lines: &[ViewIndex; 3], lists: &'c [[Option<Vec<u32>>; 3]]) -> Self {
        Candidates {
            lists: Some(lists),
            ..Candidates::near(lines)
        }
    }

    /// Lists gathered about `anchors` by [`gathered_about`].
    fn anchored(
        lines: &[ViewIndex; 3],
        lists: &'c [[Option<Vec<u32>>; 3]],
        anchors: &'c [[Option<Projected>; 3]],
    ) -> Self {
        Candidates {
            anchored: Some(Anchors {
                projected: anchors,
                moved_px: std::array::from_fn(|k| REFINE_MOVED_CELLS as f64 * lines[k].cell),
                turned_cos: REFINE_TURNED_RAD.cos(),
            }),
            ..Candidates::listed(lines, lists)
        }
    }

    /// The list of (`reference`, `view`) where `p` may read it.
    fn list(&self, reference: usize, view: usize, p: &Projected) -> Option<&'c [u32]> {
        let listed = self.lists?[reference][view].as_deref()?;
        if let Some(anchors) = &self.anchored {
            let anchor = anchors.projected[reference][view].as_ref()?;
            let moved = (p.start - anchor.start)
                .norm()
                .max((p.end - anchor.end).norm());
            let turned =
                ((p.end - p.start) / p.length).dot(&((anchor.end - anchor.start) / anchor.length));
            // (A NaN fails both: the index then.)
            if !(moved <= anchors.moved_px[view] && turned >= anchors.turned_cos) {
                return None;
            }
        }
        Some(listed)
    }
}

/// The best image segment for each projection under `gate` (pixels, or χ² when `None`).
fn associate(
    projected: &[[Option<Projected>; 3]],
    lines: &[ViewIndex; 3],
    pixel_gate: Option<f64>,
    candidates: &mut Candidates,
) -> Vec<Pairing> {
    associate_below(projected, lines, pixel_gate, candidates, 0.0, f64::INFINITY).expect("no bound")
}

/// [`associate`], giving up (`None`) as soon as `spent` plus what the projections paired so
/// far cost — each its best χ², at most [`PAIR_GATE`], an unpaired one [`PAIR_GATE`] — exceeds
/// `limit`: a lower bound of [`cost`]'s total, every term of which is non-negative.
fn associate_below(
    projected: &[[Option<Projected>; 3]],
    lines: &[ViewIndex; 3],
    pixel_gate: Option<f64>,
    candidates: &mut Candidates,
    spent: f64,
    limit: f64,
) -> Option<Vec<Pairing>> {
    let mut pairings = Vec::new();
    let mut lower = spent;
    for (reference, views) in projected.iter().enumerate() {
        for (view, p) in views.iter().enumerate() {
            let Some(p) = p else { continue };
            let along = (p.end - p.start) / p.length;
            let mut best: Option<(f64, usize)> = None;
            let mut consider = |i: usize| {
                let line = &lines[view][i];
                // Same orientation (contrast), within the angle gate.
                let cos = along.dot(&line.direction);
                if cos < ANGLE_GATE_RAD.cos() {
                    return;
                }
                let Some((r, var)) = residuals(p, line) else {
                    return;
                };
                let chi2 = r.x * r.x / var.x + r.y * r.y / var.y;
                let within = match pixel_gate {
                    Some(g) => r.x.abs() + 0.5 * line.length * r.y.abs() <= g,
                    None => chi2 <= PAIR_GATE,
                };
                if within && best.is_none_or(|(b, _)| chi2 < b) {
                    best = Some((chi2, i));
                }
            };
            match candidates.list(reference, view, p) {
                Some(listed) => listed.iter().for_each(|&i| consider(i as usize)),
                None => lines[view].near(p, &mut candidates.seen[view], &mut consider),
            }
            lower += best.map_or(PAIR_GATE, |(chi2, _)| chi2.min(PAIR_GATE));
            if lower > limit {
                return None;
            }
            if let Some((_, line)) = best {
                pairings.push(Pairing {
                    reference,
                    view,
                    line,
                });
            }
        }
    }
    Some(pairings)
}

/// Farthest, in index cells, that [`gathered`] reads about a projection: a reference so
/// near the cameras that the search moves its projection further is left to the index walk
/// of each cell (reading about it would cost more than the walks it saves).
const GATHER_RADIUS_CELLS: isize = 6;

/// For a local search over `cells` (each the projections at one pose): per reference and
/// view, every image segment [`associate`] may pair it with at any of them — those about
/// its projection in the first cell that shows it, within as many more index cells as any
/// cell moves its ends, and turned from it by no more than the angle gate plus the most any
/// cell turns it; `None` where that is farther than [`GATHER_RADIUS_CELLS`]. Each cell then
/// reads a few segments, not the index: walking the index was nine tenths of scoring a cell.
fn gathered(
    cells: &[Vec<[Option<Projected>; 3]>],
    lines: &[ViewIndex; 3],
) -> Vec<[Option<Vec<u32>>; 3]> {
    let references = cells.first().map_or(0, Vec::len);
    let mut seen: [Seen; 3] = std::array::from_fn(|k| Seen::of(&lines[k]));
    let direction = |p: &Projected| (p.end - p.start) / p.length;
    (0..references)
        .map(|reference| {
            std::array::from_fn(|view| {
                let mut shown = cells.iter().filter_map(|c| c[reference][view].as_ref());
                let Some(anchor) = shown.next() else {
                    return Some(Vec::new());
                };
                let along = direction(anchor);
                // The largest turn is the arc cosine of the smallest cosine: one `acos`.
                let (mut moved, mut least_cos) = (0.0f64, 1.0f64);
                for p in shown {
                    moved = moved
                        .max((p.start - anchor.start).norm())
                        .max((p.end - anchor.end).norm());
                    least_cos = least_cos.min(direction(p).dot(&along).clamp(-1.0, 1.0));
                }
                let turned = least_cos.acos();
                let moved_cells = (moved / lines[view].cell).ceil();
                // (A NaN, from a degenerate projection, is as far.)
                if moved_cells.is_nan() || moved_cells > (GATHER_RADIUS_CELLS - 2) as f64 {
                    return None;
                }
                Some(candidates_about(
                    &lines[view],
                    anchor,
                    moved_cells as isize,
                    turned,
                    &mut seen[view],
                ))
            })
        })
        .collect()
}

/// Every image segment [`associate`] may pair a projection with once it has moved by at most
/// `moved_cells` index cells from `anchor` and turned by at most `turned` radians: those
/// about the anchor within two more cells (a point of the moved projection lies within
/// `moved_cells` of the anchor's point at the same place along it, which lies within half a
/// cell of a point the walk samples — or, off the grid, beyond the grid cell nearest it —
/// and the index walk reads the cells next to its own), turned from it by at most the angle
/// gate plus `turned`.
fn candidates_about(
    index: &ViewIndex,
    anchor: &Projected,
    moved_cells: isize,
    turned: f64,
    seen: &mut Seen,
) -> Vec<u32> {
    let along = (anchor.end - anchor.start) / anchor.length;
    let gate = (ANGLE_GATE_RAD + turned).min(std::f64::consts::PI).cos();
    let mut listed = Vec::new();
    index.within(anchor, 2 + moved_cells, seen, |i| {
        if along.dot(&index[i].direction) >= gate {
            listed.push(i as u32);
        }
    });
    listed
}

/// How far a refinement's later rounds may move a projection from where its first round
/// found it, in index cells, and turn it, in radians, and still read the image segments
/// gathered about it then ([`gathered_about`]); beyond, the index. A refinement from a start
/// in the right basin moves most projections by a few pixels: a cell's sixteen covers them.
const REFINE_MOVED_CELLS: isize = 1;
const REFINE_TURNED_RAD: f64 = 0.02;

/// For a refinement starting at `projected` (its first round's projections): per reference
/// and view, every image segment [`associate`] may pair it with in any later round that
/// leaves it within [`REFINE_MOVED_CELLS`] and [`REFINE_TURNED_RAD`] of where it is now
/// ([`Candidates::list`] checks that); `None` where it is not in view. Its rounds then read a
/// few segments each, not the index: walking the index was a quarter of an AddCapture of
/// segment lists.
fn gathered_about(
    projected: &[[Option<Projected>; 3]],
    lines: &[ViewIndex; 3],
) -> Vec<[Option<Vec<u32>>; 3]> {
    let mut seen: [Seen; 3] = std::array::from_fn(|k| Seen::of(&lines[k]));
    projected
        .iter()
        .map(|views| {
            std::array::from_fn(|view| {
                let anchor = views[view].as_ref()?;
                Some(candidates_about(
                    &lines[view],
                    anchor,
                    REFINE_MOVED_CELLS,
                    REFINE_TURNED_RAD,
                    &mut seen[view],
                ))
            })
        })
        .collect()
}

/// The residuals of `pairings` at `pose`, normalised, each with its derivative by the pose's
/// perturbation ([`perturbed`]); a pairing whose projection vanished gives zeros.
///
/// The derivative is analytic: an image point's distance from the line through the
/// projected ends `a`, `b` moves by −n·((1 − t)·da + t·db) when the ends move by `da`, `db`
/// (`t` the point's place along a → b, `n` the line's normal), and a reference point `X`
/// moves in the rig by Rᵀ[X − t]ₓ·ω − Rᵀ·δ.
fn linearised(
    references: &[Measured],
    lenses: &[Lens; 3],
    lines: &[ViewIndex; 3],
    pairings: &[Pairing],
    pose: &Isometry3<f64>,
    variances: &[Vector2<f64>],
) -> Vec<(Vector2<f64>, SMatrix<f64, 2, 6>)> {
    let inverse = pose.inverse();
    let to_rig = inverse.rotation.to_rotation_matrix().into_inner();
    // d(rig point)/dξ for a reference point.
    let moved_by = |world: &Point3<f64>| {
        let v = world.coords - pose.translation.vector;
        let mut d = SMatrix::<f64, 3, 6>::zeros();
        d.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(to_rig * v.cross_matrix()));
        d.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-to_rig));
        d
    };
    pairings
        .iter()
        .zip(variances)
        .map(|(pair, var)| {
            let m = &references[pair.reference];
            let lens = &lenses[pair.view];
            let a = (inverse * m.start).coords;
            let b = (inverse * m.end).coords;
            let line = &lines[pair.view][pair.line];
            let (Some((pa, ja)), Some((pb, jb))) = (project(lens, &a), project(lens, &b)) else {
                return (Vector2::zeros(), SMatrix::zeros());
            };
            let (normal, offset) = line_through(&pa, &pb);
            let (da, db) = (ja * moved_by(&m.start), jb * moved_by(&m.end));
            let d = pb - pa;
            let at = |x: &Vector2<f64>| {
                let t = d.dot(&(x - pa)) / d.norm_squared();
                let r = normal.dot(x) + offset;
                (r, -(normal.transpose() * ((1.0 - t) * da + t * db)))
            };
            let ((ra, ga), (rb, gb)) = (at(&line.start), at(&line.end));
            let (sx, sy) = (var.x.sqrt(), var.y.sqrt() * line.length);
            let mut jacobian = SMatrix::<f64, 2, 6>::zeros();
            jacobian.set_row(0, &((ga + gb) * (0.5 / sx)));
            jacobian.set_row(1, &((gb - ga) / sy));
            (Vector2::new(0.5 * (ra + rb) / sx, (rb - ra) / sy), jacobian)
        })
        .collect()
}

/// Gauss–Newton steps on `pairings` from `pose`, the prior as a measurement; returns the
/// pose and the images' information at it.
#[allow(clippy::too_many_arguments)]
fn solve(
    references: &[Measured],
    lenses: &[Lens; 3],
    lines: &[ViewIndex; 3],
    pairings: &[Pairing],
    variances: &[Vector2<f64>],
    prior: &PosePrior,
    prior_information: &Matrix6<f64>,
    mut pose: Isometry3<f64>,
    min_variance_factor: f64,
) -> (Isometry3<f64>, Matrix6<f64>) {
    let mut information = Matrix6::zeros();
    // How many views each reference is paired in: its own error is common to them, so its
    // pairings share one reference's worth of weight.
    let mut views_of = vec![0u32; references.len()];
    for p in pairings {
        views_of[p.reference] += 1;
    }
    for _ in 0..STEPS {
        let linear = linearised(references, lenses, lines, pairings, &pose, variances);
        let mut h = Matrix6::zeros();
        let mut g = Vector6::zeros();
        for ((r, jac), pair) in linear.iter().zip(pairings) {
            let share = 1.0 / views_of[pair.reference].max(1) as f64;
            let norm = r.norm();
            let huber = if norm <= HUBER { 1.0 } else { HUBER / norm };
            let w = share * huber;
            h += w * jac.transpose() * jac;
            g += w * jac.transpose() * r;
        }
        // The a-posteriori variance factor: how far the residuals are from what their
        // variances say, over the pairings' degrees of freedom less the pose's.
        let dof = (2 * linear.len()).saturating_sub(6).max(1) as f64;
        let spread: f64 = linear.iter().map(|(r, _)| r.norm_squared()).sum::<f64>() / dof;
        information = h / spread.max(min_variance_factor);
        let e = difference(&pose, &prior.rig_to_world);
        let lhs = h + prior_information;
        let rhs = -(g + prior_information * e);
        let Some(step) = lhs.cholesky().map(|c| c.solve(&rhs)) else {
            break;
        };
        pose = perturbed(&pose, &step);
        if step.norm() < 1e-9 {
            break;
        }
    }
    (pose, information)
}

/// How well a pose explains the images: its pairings, the projections in view, and the
/// truncated cost — every visible projection costs its best pairing's χ², at most
/// [`PAIR_GATE`], and the prior its χ².
struct Scored {
    total: f64,
    pairings: Vec<Pairing>,
    visible: usize,
}

/// [`Scored`] of `pose`, whose projections are `projected`.
fn cost(
    projected: &[[Option<Projected>; 3]],
    lines: &[ViewIndex; 3],
    candidates: &mut Candidates,
    pose: &Isometry3<f64>,
    prior: &PosePrior,
    prior_information: &Matrix6<f64>,
) -> Scored {
    cost_below(
        projected,
        lines,
        candidates,
        pose,
        prior,
        prior_information,
        f64::INFINITY,
    )
    .expect("no bound")
}

/// [`cost`], or `None` once it is sure to exceed `bound` (the total is then never
/// computed); the total, when given, is [`cost`]'s to the bit.
fn cost_below(
    projected: &[[Option<Projected>; 3]],
    lines: &[ViewIndex; 3],
    candidates: &mut Candidates,
    pose: &Isometry3<f64>,
    prior: &PosePrior,
    prior_information: &Matrix6<f64>,
    bound: f64,
) -> Option<Scored> {
    let e = difference(pose, &prior.rig_to_world);
    let prior_cost = e.dot(&(prior_information * e));
    // The bound is summed in another order than the total: a margin far above rounding, so
    // that no cell whose total is within the bound is given up.
    let limit = if bound.is_finite() {
        bound + 1e-9 * bound.abs().max(1.0)
    } else {
        bound
    };
    let pairings = associate_below(projected, lines, None, candidates, prior_cost, limit)?;
    let visible: usize = projected.iter().flatten().filter(|p| p.is_some()).count();
    let mut total = PAIR_GATE * (visible - pairings.len()) as f64;
    for p in &pairings {
        let proj = projected[p.reference][p.view].as_ref().expect("paired");
        let (r, var) = residuals(proj, &lines[p.view][p.line]).expect("paired");
        total += (r.x * r.x / var.x + r.y * r.y / var.y).min(PAIR_GATE);
    }
    total += prior_cost;
    Some(Scored {
        total,
        pairings,
        visible,
    })
}

/// Refines the capture's pose (its rig in the frame of `references`) from each of `starts`
/// so that the references project onto its image segments, searching about the starts when
/// that leaves many projections unpaired; the refined pose of lowest truncated cost wins.
/// `None` when fewer than [`ImageParams::min_references`] references are in view at every
/// start or paired at the end, or the prior has no inverse.
pub fn refine_in_images(
    references: &[Measured],
    views: &Views,
    starts: &[Isometry3<f64>],
    prior: &PosePrior,
    params: &ImageParams,
) -> Option<ImageFit> {
    never_stopped(refine_in_images_until(
        references,
        &IndexedViews::new(views, params),
        starts,
        prior,
        params,
        Checkpoint::NEVER,
    ))
}

/// [`refine_in_images`], asking `checkpoint` before each refinement and each cell of the
/// local search: a capture of many segments makes each a few milliseconds.
pub fn refine_in_images_until(
    references: &[Measured],
    views: &IndexedViews,
    starts: &[Isometry3<f64>],
    prior: &PosePrior,
    params: &ImageParams,
    checkpoint: Checkpoint,
) -> Result<Option<ImageFit>, Stopped> {
    // Every reference, uncertain ones too: what makes a segment uncertain is its direction's or
    // depth's spread, which its covariance carries into the image; a wrong correspondence
    // among them rarely projects onto an image segment in all its views. On the driving loop
    // (eight seeds, two noise draws) certain references alone gave 7.4% / 9.5% map error at
    // 1° and 15% completeness at 3°, all of them 7.6% / 5.6% and 22%.
    let Some(prior_information) = prior.covariance.try_inverse() else {
        return Ok(None);
    };
    let lenses = &views.lenses;
    // A capture that looked elsewhere: no start puts enough of the references in view for a
    // fit, and a search a few centimetres and half a degree about them would bring in a few
    // at the images' borders at most. (In a panorama, most of a capture's pair neighbours are
    // such: searching each cost three quarters of an AddCapture.)
    let at_starts: Vec<Vec<[Option<Projected>; 3]>> = starts
        .iter()
        .map(|start| project_all(references, lenses, start, params))
        .collect();
    let in_view = |projected: &[[Option<Projected>; 3]]| {
        projected
            .iter()
            .filter(|views| views.iter().any(Option::is_some))
            .count()
    };
    if at_starts
        .iter()
        .all(|projected| in_view(projected) < params.min_references as usize)
    {
        return Ok(None);
    }
    let lines = views.lines();
    // From `start`, whose projections are `anchors`.
    let refine = |start: &Isometry3<f64>,
                  anchors: Vec<[Option<Projected>; 3]>|
     -> Option<(ImageFit, f64, Vec<usize>)> {
        let mut pose = *start;
        let mut information = Matrix6::zeros();
        let rounds = params
            .pixel_gates
            .iter()
            .map(|&g| Some(g))
            .chain(std::iter::repeat_n(None, CHI2_ROUNDS));
        let lists = gathered_about(&anchors, lines);
        let mut candidates = Candidates::anchored(lines, &lists, &anchors);
        // The last round's gate and pairings: a χ² round that pairs as the one before it
        // solves the same problem from where that one converged, and so would every round
        // after it.
        let mut last: Option<(Option<f64>, Vec<Pairing>)> = None;
        for (round, gate) in rounds.enumerate() {
            // The first round is at the start, where the lists were gathered.
            let moved;
            let projected = if round == 0 {
                &anchors
            } else {
                moved = project_all(references, lenses, &pose, params);
                &moved
            };
            let pairings = associate(projected, lines, gate, &mut candidates);
            if pairings.len() < params.min_references as usize
                || last
                    .as_ref()
                    .is_some_and(|(g, p)| *g == gate && *p == pairings)
            {
                break;
            }
            let variances: Vec<Vector2<f64>> = pairings
                .iter()
                .map(|p| {
                    let proj = projected[p.reference][p.view].as_ref().expect("paired");
                    residuals(proj, &lines[p.view][p.line]).expect("paired").1
                })
                .collect();
            (pose, information) = solve(
                references,
                lenses,
                lines,
                &pairings,
                &variances,
                prior,
                &prior_information,
                pose,
                params.min_variance_factor,
            );
            last = Some((gate, pairings));
        }
        let scored = cost(
            &project_all(references, lenses, &pose, params),
            lines,
            &mut candidates,
            &pose,
            prior,
            &prior_information,
        );
        let mut paired: Vec<usize> = scored.pairings.iter().map(|p| p.reference).collect();
        paired.sort_unstable();
        paired.dedup();
        if paired.len() < params.min_references as usize {
            return None;
        }
        let covariance = (information + prior_information).try_inverse()?;
        let fit = ImageFit {
            pose,
            covariance,
            information,
            inliers: scored.pairings.len() as u32,
            references: paired.len() as u32,
            cost: scored.total,
        };
        Some((
            fit,
            scored.pairings.len() as f64 / scored.visible.max(1) as f64,
            paired,
        ))
    };
    type Refined = Option<(ImageFit, f64, Vec<usize>)>;
    let better = |a: Refined, b: Refined| match (a, b) {
        (Some(a), Some(b)) => Some(if b.0.cost < a.0.cost { b } else { a }),
        (a, b) => a.or(b),
    };
    // The best fit against the same fit a period over: along a row of like edges (a
    // radiator's fins, a bookcase's uprights) a start one step off settles one step off, as
    // sure of itself as in place, and a search about the starts reaches no farther than the
    // prior's spread. Each period the paired references repeat at is tried both ways from
    // the best fit and refined: a fit a period over that is clearly cheaper wins; one about
    // as cheap is a rival, which leaves the fit as uncertain along the row as the two are
    // apart ([`with_rivals`]).
    let finish = |best: Refined| -> Result<Option<ImageFit>, Stopped> {
        let Some((mut fit, _, paired)) = best else {
            return Ok(None);
        };
        let mut rivals: Vec<ImageFit> = Vec::new();
        for shift in period_shifts(references, &paired) {
            checkpoint.before("registration")?;
            let xi = Vector6::new(0.0, 0.0, 0.0, shift.x, shift.y, shift.z);
            let start = perturbed(&fit.pose, &xi);
            if let Some((other, _, _)) =
                refine(&start, project_all(references, lenses, &start, params))
            {
                rivals.push(other);
            }
        }
        let apart = |a: &ImageFit, b: &ImageFit| {
            (a.pose.translation.vector - b.pose.translation.vector).norm() > SAME_FIT_M
        };
        // A shift may settle back on the fit, and two on one rival: each counts once.
        let mut distinct: Vec<ImageFit> = Vec::new();
        for r in rivals {
            if apart(&r, &fit) && distinct.iter().all(|d| apart(d, &r)) {
                distinct.push(r);
            }
        }
        let mut rivals = distinct;
        if let Some(k) = (0..rivals.len())
            .filter(|&k| rivals[k].cost < fit.cost - CLEARLY_CHEAPER)
            .min_by(|&a, &b| rivals[a].cost.total_cmp(&rivals[b].cost))
        {
            fit = rivals.swap_remove(k);
            rivals.retain(|r| apart(r, &fit));
        }
        Ok(Some(with_rivals(fit, &rivals, &prior_information)))
    };
    let mut best = None;
    for (start, anchors) in starts.iter().zip(at_starts) {
        checkpoint.before("registration")?;
        best = better(best, refine(start, anchors));
    }
    if best
        .as_ref()
        .is_some_and(|(_, paired, _)| *paired >= params.settled_fraction)
    {
        return finish(best);
    }
    // Too few of the projections in view found their image segment: a local search about
    // each start, since the basin of the right pose is a few pixels wide and a 3D
    // registration or odometry may leave the rig a few centimetres outside it. (About the
    // best refined pose alone it cost one of the driving loop's seeds at 3°: 2.9% → 9.3%.)
    let kept = params.refined_starts;
    if kept == 0 {
        return finish(best);
    }
    let (step_m, step_rad) = (params.grid_step_m, params.grid_step_rad);
    let reach = |variance: f64| -> i32 {
        let steps = (SEARCH_SIGMAS * variance.max(0.0).sqrt() / step_m).ceil();
        if steps.is_finite() {
            (steps as i32).clamp(GRID_STEPS_XY, MAX_GRID_STEPS_XY)
        } else {
            GRID_STEPS_XY
        }
    };
    let (reach_x, reach_y) = (
        reach(prior.covariance[(3, 3)]),
        reach(prior.covariance[(4, 4)]),
    );
    let grid = |x: i32, y: i32, yaw: i32| -> Vec<(i32, i32, i32)> {
        (-x..=x)
            .flat_map(|i| (-y..=y).flat_map(move |j| (-yaw..=yaw).map(move |k| (i, j, k))))
            .collect()
    };
    let inner = grid(GRID_STEPS_XY, GRID_STEPS_XY, GRID_STEPS_YAW);
    // The cells of one heading share their rotation, so the references' turned ends and
    // covariances: once per start and heading, for both stages, rather than once per cell.
    let turned: Vec<Vec<Vec<Turned>>> = starts
        .iter()
        .map(|start| {
            (-GRID_STEPS_YAW..=GRID_STEPS_YAW)
                .map(|k| {
                    let xi = Vector6::new(0.0, 0.0, k as f64 * step_rad, 0.0, 0.0, 0.0);
                    turned_references(references, &perturbed(start, &xi))
                })
                .collect()
        })
        .collect();
    // Beyond it in heading too: at the start's heading alone, one of the driving loop's
    // seeds at 3° (7, third draw) stayed a stride over.
    let outer: Vec<_> = grid(reach_x, reach_y, GRID_STEPS_YAW)
        .into_iter()
        .filter(|&(i, j, _)| i.abs() > GRID_STEPS_XY || j.abs() > GRID_STEPS_XY)
        .collect();
    // The inner ±4 cm first; the rest of the prior's spread only when that leaves the fit as
    // unsettled as a start one stride over along a repetitive wall is (scoring a cell does
    // not refine it, and the wider grid's wrong cells that score well unrefined would
    // otherwise displace the inner grid's right one: the driving loop's seed 4 at 3°, second
    // draw, 1.8% → 51% wrong).
    for (stage, order) in [inner, outer].iter().enumerate() {
        let unsettled = best
            .as_ref()
            .is_none_or(|(_, paired, _)| *paired < params.wide_search_fraction);
        if order.is_empty() || (stage > 0 && !unsettled) {
            break;
        }
        // Each scored cell with its place in the grid's order (which breaks ties as it did
        // when every cell was scored), and the `kept` cheapest totals so far: a cell sure to
        // cost more than the last of those cannot be refined, and its scoring stops there.
        // The cells nearest each start are scored first, since the right basin is usually
        // there.
        let mut cells: Vec<(f64, usize, Isometry3<f64>)> = Vec::new();
        let mut cheapest: Vec<f64> = Vec::with_capacity(kept + 1);
        // Beyond the inner grid a cell is worth refining only if, unrefined, it already
        // costs less than the best refined fit: the right basin one stride over does (48
        // refined against 166 where the driving loop's seed 6 failed).
        let ceiling = if stage > 0 {
            best.as_ref().map_or(f64::INFINITY, |(fit, _, _)| fit.cost)
        } else {
            f64::INFINITY
        };
        let grid_cells = order.len();
        for (s, start) in starts.iter().enumerate() {
            let poses: Vec<Isometry3<f64>> = order
                .iter()
                .map(|&(i, j, k)| {
                    let xi = Vector6::new(
                        0.0,
                        0.0,
                        k as f64 * step_rad,
                        i as f64 * step_m,
                        j as f64 * step_m,
                        0.0,
                    );
                    perturbed(start, &xi)
                })
                .collect();
            checkpoint.before("registration")?;
            let projected: Vec<_> = poses
                .iter()
                .zip(order.iter())
                .map(|(pose, &(_, _, k))| {
                    let heading = (k + GRID_STEPS_YAW) as usize;
                    project_turned(lenses, pose, &turned[s][heading], params)
                })
                .collect();
            let lists = gathered(&projected, lines);
            let mut candidates = Candidates::listed(lines, &lists);
            let mut nearest_first: Vec<usize> = (0..grid_cells).collect();
            nearest_first.sort_by_key(|&c| {
                let (i, j, k) = order[c];
                (i * i + j * j, k * k, c)
            });
            for c in nearest_first {
                checkpoint.before("registration")?;
                let bound = if cheapest.len() == kept {
                    cheapest[kept - 1].min(ceiling)
                } else {
                    ceiling
                };
                let Some(scored) = cost_below(
                    &projected[c],
                    lines,
                    &mut candidates,
                    &poses[c],
                    prior,
                    &prior_information,
                    bound,
                ) else {
                    continue;
                };
                let at = cheapest.partition_point(|&t| t <= scored.total);
                cheapest.insert(at, scored.total);
                cheapest.truncate(kept);
                cells.push((scored.total, s * grid_cells + c, poses[c]));
            }
        }
        cells.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for (_, _, start) in cells.iter().take(kept) {
            checkpoint.before("registration")?;
            best = better(
                best,
                refine(start, project_all(references, lenses, start, params)),
            );
        }
    }
    finish(best)
}

/// A fit a period over that costs this much less than the best wins outright: four
/// projections more explained than the best explains. Less is what a row running out of
/// the reference's view gives the fit one step along it.
const CLEARLY_CHEAPER: f64 = 4.0 * PAIR_GATE;
/// Fits whose rigs stand within this of each other are one fit found twice.
const SAME_FIT_M: f64 = 0.01;

/// `fit` with the spread of its `rivals` added to its images' covariance: each weighs as its
/// likelihood against the fit's, e^(−Δcost/2), the prior included in the costs as the fits
/// were compared (and as [`super::register`] weighs its rivals), and the covariance of that
/// mixture about the fit is added, so that an edge along a repetitive row says how little
/// it knows along the row rather than vouching for one step. (Weighed by the images' costs
/// alone, without the prior's share, rivals count more, and the driving loops lost: the
/// circle's sixteen seeds at 1° / 2 cm 54.8% → 53.4% complete, at 3° / 5 cm 3.04% → 3.17%
/// wrong; docs/SESSIONS.md.)
fn with_rivals(
    mut fit: ImageFit,
    rivals: &[ImageFit],
    prior_information: &Matrix6<f64>,
) -> ImageFit {
    let weighed: Vec<(f64, Vector6<f64>)> = rivals
        .iter()
        .filter(|r| r.cost - fit.cost <= RIVAL_COST)
        .map(|r| {
            (
                rival_weight(r.cost - fit.cost),
                difference(&r.pose, &fit.pose),
            )
        })
        .collect();
    if weighed.is_empty() {
        return fit;
    }
    let total = 1.0 + weighed.iter().map(|(w, _)| w).sum::<f64>();
    // (I⁻¹ + Σ w u uᵀ)⁻¹ one rank at a time (Sherman–Morrison), which needs no inverse of
    // the images' information: it may be singular along what they do not see.
    let mut information = fit.information;
    for (w, d) in weighed {
        let u = d * (w / total).sqrt();
        let iu = information * u;
        information -= iu * iu.transpose() / (1.0 + u.dot(&iu));
    }
    let information = (information + information.transpose()) * 0.5;
    if let Some(covariance) = (information + prior_information).try_inverse() {
        fit.information = information;
        fit.covariance = (covariance + covariance.transpose()) * 0.5;
    }
    fit
}

/// Two references closer than this across are one edge's two faces, not a period.
const MIN_PERIOD_M: f64 = 0.03;
/// Farther apart than this, a row's next edge is rarely what a fit confuses its edge with.
const MAX_PERIOD_M: f64 = 0.5;
/// A period is a step that carries at least this many paired references onto another
/// reference, either way: two alike side by side, both paired, vote for each other, and a
/// fit that saw both may have taken one for the other. (Asking for a row of three lost
/// one of the circle's eight seeds at 3° / 5 cm of its second draw: 2.53% → 3.20% wrong.)
const MIN_PERIOD_VOTES: usize = 2;
/// Shifts within this of each other are one period.
const PERIOD_TOLERANCE_M: f64 = 0.02;
/// At most this many periods are tried (each both ways).
const MAX_PERIODS: usize = 2;
/// References whose directions differ by less than this are alike for a period.
const PERIOD_ANGLE_DEG: f64 = 5.0;
/// The periods are read from at most this many paired references, and at most this many
/// offsets between references are compared: a hostile session's thousands of references
/// make this a bounded pass, not a quadratic one.
const MAX_PERIOD_PAIRED: usize = 64;
const MAX_PERIOD_OFFSETS: usize = 1024;

/// The steps across the floor (the references' frame, z up) by which a row of like
/// references repeats: for each `paired` reference, the horizontal offset to each other
/// reference parallel to it, side by side with it along its line and at its height; the
/// offsets that at least [`MIN_PERIOD_VOTES`] paired references share (within
/// [`PERIOD_TOLERANCE_M`]), the most shared first, each both ways.
fn period_shifts(references: &[Measured], paired: &[usize]) -> Vec<Vector3<f64>> {
    let cos_max = PERIOD_ANGLE_DEG.to_radians().cos();
    // Each reference's midpoint, direction and length; `None` for a degenerate one.
    type Line = (Point3<f64>, Vector3<f64>, f64);
    let lines: Vec<Option<Line>> = references
        .iter()
        .map(|m| {
            let d = m.end - m.start;
            let length = d.norm();
            (length > 1e-6 && length.is_finite())
                .then(|| (nalgebra::center(&m.start, &m.end), d / length, length))
        })
        .collect();
    // (paired reference, its offset to a neighbour of the row)
    let mut offsets: Vec<(usize, Vector3<f64>)> = Vec::new();
    for &j in paired.iter().take(MAX_PERIOD_PAIRED) {
        let Some(&Some((mid, direction, length))) = lines.get(j) else {
            continue;
        };
        for (k, other) in lines.iter().enumerate() {
            let Some((other_mid, other_direction, other_length)) = *other else {
                continue;
            };
            if k == j || direction.dot(&other_direction).abs() < cos_max {
                continue;
            }
            let apart = other_mid - mid;
            let along = apart.dot(&direction);
            let across = apart - direction * along;
            let floor = Vector3::new(across.x, across.y, 0.0);
            let side_by_side = along.abs() < 0.5 * (length + other_length);
            if side_by_side
                && across.z.abs() < PERIOD_TOLERANCE_M
                && (MIN_PERIOD_M..=MAX_PERIOD_M).contains(&floor.norm())
            {
                offsets.push((j, floor));
            }
        }
        if offsets.len() >= MAX_PERIOD_OFFSETS {
            offsets.truncate(MAX_PERIOD_OFFSETS);
            break;
        }
    }
    // Each offset's votes: the paired references with an offset like it, either way.
    let mut periods: Vec<(usize, Vector3<f64>)> = offsets
        .iter()
        .map(|&(_, o)| {
            let mut voters: Vec<usize> = offsets
                .iter()
                .filter(|(_, p)| {
                    (p - o).norm() < PERIOD_TOLERANCE_M || (p + o).norm() < PERIOD_TOLERANCE_M
                })
                .map(|&(j, _)| j)
                .collect();
            voters.sort_unstable();
            voters.dedup();
            (voters.len(), o)
        })
        .filter(|&(votes, _)| votes >= MIN_PERIOD_VOTES)
        .collect();
    periods.sort_by(|a, b| {
        b.0.cmp(&a.0)
            .then(a.1.norm().total_cmp(&b.1.norm()))
            .then(a.1.x.total_cmp(&b.1.x))
            .then(a.1.y.total_cmp(&b.1.y))
    });
    let mut chosen: Vec<Vector3<f64>> = Vec::new();
    for (_, o) in periods {
        if chosen.len() == MAX_PERIODS {
            break;
        }
        let known = chosen
            .iter()
            .any(|p| (p - o).norm() < PERIOD_TOLERANCE_M || (p + o).norm() < PERIOD_TOLERANCE_M);
        if !known {
            chosen.push(o);
        }
    }
    chosen.into_iter().flat_map(|o| [o, -o]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::preset_rig;
    use nalgebra::{Point3, UnitQuaternion};

    /// Segments 2.5–4 m in front of the rig's first camera, upright and level, at several
    /// depths (so that moving along the view changes the picture), rig frame.
    fn scene(rig: &crate::geometry::Rig) -> Vec<Point3<f64>> {
        let camera = rig.camera(0);
        let axis = camera.axis().normalize();
        let side = axis.cross(&Vector3::z()).normalize();
        let up = side.cross(&axis).normalize();
        let mut ends = Vec::new();
        for i in 0..6 {
            for j in 0..4 {
                let depth = 2.5 + 0.3 * ((i + 2 * j) % 6) as f64;
                let centre = camera.centre()
                    + axis * depth
                    + side * (-0.9 + 0.36 * i as f64)
                    + up * (-0.5 + 0.33 * j as f64);
                let (a, b) = if (i + j) % 2 == 0 {
                    (centre - up * 0.12, centre + up * 0.12)
                } else {
                    (centre - side * 0.12, centre + side * 0.12)
                };
                ends.push(a);
                ends.push(b);
            }
        }
        ends
    }

    fn measured(ends: &[Point3<f64>], pose: &Isometry3<f64>) -> Vec<Measured> {
        ends.chunks(2)
            .map(|e| Measured {
                start: pose * e[0],
                end: pose * e[1],
                covariance: Matrix6::identity() * 1e-6,
                uncertain: false,
            })
            .collect()
    }

    /// Each view's image of the rig-frame segments, in the camera's (distorted) pixels.
    fn images(rig: &crate::geometry::Rig, ends: &[Point3<f64>]) -> [Vec<Segment2>; 3] {
        std::array::from_fn(|k| {
            let camera = rig.camera(k);
            ends.chunks(2)
                .filter_map(|e| {
                    let a = camera.project(&e[0])?;
                    let b = camera.project(&e[1])?;
                    let inside = |p: &nalgebra::Point2<f64>| {
                        p.x >= 0.0
                            && p.y >= 0.0
                            && p.x <= camera.width() as f64
                            && p.y <= camera.height() as f64
                    };
                    (inside(&a) && inside(&b)).then(|| Segment2 {
                        noise: Some(LineNoise {
                            offset_px: 0.05,
                            angle_rad: 0.002,
                            shift_px: 0.0,
                        }),
                        ..Segment2::new(a, b)
                    })
                })
                .collect()
        })
    }

    fn truth() -> Isometry3<f64> {
        Isometry3::from_parts(
            Vector3::new(0.4, -0.2, 0.0).into(),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.35),
        )
    }

    /// An odometry prior at `pose` (1°, 0.3° of tilt, 5 cm, 1 cm) and its information.
    fn odometry_at(pose: Isometry3<f64>) -> (PosePrior, Matrix6<f64>) {
        let prior = PosePrior::odometry(pose, 1.0, 0.3, 0.05, 0.01);
        let information = prior.covariance.try_inverse().expect("invertible");
        (prior, information)
    }

    fn off(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
        (
            (a.rotation * b.rotation.inverse()).angle().to_degrees(),
            (a.translation.vector - b.translation.vector).norm(),
        )
    }

    #[test]
    fn a_pose_centimetres_off_is_brought_onto_the_image_segments() {
        let rig = preset_rig();
        let ends = scene(&rig);
        let references = measured(&ends, &truth());
        let lists = images(&rig, &ends);
        assert!(lists.iter().all(|l| l.len() >= 16), "the scene is in view");
        let views = Views {
            cameras: rig.cameras(),
            segments: std::array::from_fn(|k| &lists[k][..]),
            list_noise_px: 0.3,
        };
        // Odometry 3 cm and 0.6° off, several pixels in the images.
        let xi = Vector6::new(0.0, 0.0, 0.6f64.to_radians(), 0.03, -0.025, 0.0);
        let start = perturbed(&truth(), &xi);
        let prior = PosePrior::odometry(start, 1.0, 0.3, 0.05, 0.01);
        let fit = refine_in_images(
            &references,
            &views,
            &[start],
            &prior,
            &ImageParams::default(),
        )
        .expect("registered");
        let (deg, m) = off(&fit.pose, &truth());
        assert!(deg < 0.02 && m < 0.001, "{deg}° {m} m off");
        assert!(fit.references >= 20, "{} references paired", fit.references);
        // Its covariance owns up to the error (exact data: the variance factor's floor).
        let e = difference(&fit.pose, &truth());
        let chi2 = e.dot(&(fit.covariance.try_inverse().expect("invertible") * e));
        assert!(chi2 < 22.5, "χ² {chi2}");
    }

    #[test]
    fn a_start_one_post_over_is_searched_as_far_as_its_prior_allows() {
        // Rows of like posts in front of the rig, 8 cm apart, along the world's x: moved one
        // post along them, the rig sees the same picture but for the rows' ends (5 of 6
        // posts paired, as the driving loop's wrong basins pair 81%), a basin no refinement
        // leaves and the ±4 cm of a tighter prior's search do not reach past.
        let pitch = 0.08;
        assert!(pitch > (GRID_STEPS_XY + 1) as f64 * ImageParams::default().grid_step_m);
        // Odometry of 5 cm per axis: the right post is 1.6σ from the prior.
        a_start_a_post_over_comes_back(pitch, 0.05);
    }

    /// Posts `pitch` apart along the world's x, `count` of them centred in front of the rig's
    /// first camera in each of two rows (2.5 m and 4 m away: one row at one depth would let
    /// a turn stand for a step along it); the rig's pose, which looks along the world's y,
    /// and the posts' ends in the rig's frame.
    fn rows_of_posts(
        rig: &crate::geometry::Rig,
        pitch: f64,
        count: usize,
    ) -> (Isometry3<f64>, Vec<Point3<f64>>) {
        let camera = rig.camera(0);
        let axis = camera.axis().normalize();
        let side = axis.cross(&Vector3::z()).normalize();
        let truth = Isometry3::from_parts(
            Vector3::new(0.4, -0.2, 0.0).into(),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -side.y.atan2(side.x)),
        );
        let middle = (count as f64 - 1.0) / 2.0;
        let ends = [(2.5, 0.0), (4.0, 0.35)]
            .into_iter()
            .flat_map(|(depth, height)| {
                (0..count).flat_map(move |k| {
                    let foot = camera.centre()
                        + axis * depth
                        + side * (pitch * (k as f64 - middle))
                        + Vector3::z() * height;
                    [foot - Vector3::z() * 0.15, foot + Vector3::z() * 0.15]
                })
            })
            .collect();
        (truth, ends)
    }

    /// [`rows_of_posts`] registered in the images from a start `offset_m` along the rows
    /// from the truth, under odometry of `sigma_m` per axis across the floor: the fit, the
    /// true pose and how many posts each view holds.
    fn fit_along_posts(
        pitch: f64,
        count: usize,
        offset_m: f64,
        sigma_m: f64,
    ) -> (ImageFit, Isometry3<f64>, [usize; 3]) {
        let rig = preset_rig();
        let (truth, row) = rows_of_posts(&rig, pitch, count);
        let references = measured(&row, &truth);
        let lists = images(&rig, &row);
        let views = Views {
            cameras: rig.cameras(),
            segments: std::array::from_fn(|k| &lists[k][..]),
            list_noise_px: 0.3,
        };
        let start = perturbed(&truth, &Vector6::new(0.0, 0.0, 0.0, offset_m, 0.0, 0.0));
        let prior = PosePrior::odometry(start, 1.0, 0.3, sigma_m, 0.01);
        let fit = refine_in_images(
            &references,
            &views,
            &[start],
            &prior,
            &ImageParams::default(),
        )
        .expect("registered");
        (fit, truth, std::array::from_fn(|k| lists[k].len()))
    }

    /// Six posts a row, a start one post over: the fit comes back onto the true pose with
    /// every post paired in every view.
    fn a_start_a_post_over_comes_back(pitch: f64, sigma_m: f64) {
        let (fit, truth, in_view) = fit_along_posts(pitch, 6, pitch, sigma_m);
        assert_eq!(in_view, [12; 3], "the rows are in view");
        let (deg, m) = off(&fit.pose, &truth);
        assert!(deg < 0.02 && m < 0.001, "{deg}° {m} m off");
        assert_eq!(fit.inliers, 36, "every post paired in every view");
    }

    fn upright(x: f64, y: f64) -> Measured {
        Measured {
            start: Point3::new(x, y, 0.5),
            end: Point3::new(x, y, 0.9),
            covariance: Matrix6::identity() * 1e-6,
            uncertain: false,
        }
    }

    #[test]
    fn a_row_repeats_at_its_pitch_and_a_pair_alongside_is_no_row() {
        // Five uprights 21 cm apart along a wall at y = 3, one lying beam, and two uprights
        // 1.5 cm apart (a board's two faces) elsewhere.
        let mut references: Vec<Measured> = (0..5).map(|k| upright(0.21 * k as f64, 3.0)).collect();
        references.push(Measured {
            start: Point3::new(0.0, 3.0, 1.2),
            end: Point3::new(1.0, 3.0, 1.2),
            ..upright(0.0, 0.0)
        });
        references.push(upright(-2.0, 1.0));
        references.push(upright(-2.0, 1.015));
        let row: Vec<usize> = (0..5).collect();
        let shifts = period_shifts(&references, &row);
        assert!(!shifts.is_empty(), "the row's pitch is found");
        assert!(
            (shifts[0].norm() - 0.21).abs() < 1e-9 && shifts[0].y.abs() < 1e-9,
            "one step along the row first: {:?}",
            shifts[0]
        );
        assert_eq!(shifts[1], -shifts[0], "both ways");
        assert!(shifts.len() <= 2 * MAX_PERIODS);
        // The two faces are too close to be a period, the beam has no like neighbour: paired
        // alone they give nothing to try.
        assert!(period_shifts(&references, &[5, 6, 7]).is_empty());
        // Two like uprights alongside, both paired, may be taken one for the other; with one
        // of them paired, the other is not known to be in view.
        let pair = [upright(0.0, 3.0), upright(0.3, 3.0)];
        assert_eq!(period_shifts(&pair, &[0, 1]).len(), 2);
        assert!(period_shifts(&pair, &[0]).is_empty());
        // An upright 30 cm behind another is a neighbour across the floor as well, one a
        // metre away is not, nor is one standing on another.
        let apart = [upright(0.0, 3.0), upright(0.0, 3.3), upright(0.0, 2.0)];
        let shifts = period_shifts(&apart, &[0, 1, 2]);
        assert_eq!(shifts.len(), 2);
        assert!((shifts[0].y.abs() - 0.3).abs() < 1e-9, "{:?}", shifts[0]);
        let stacked = [
            upright(0.0, 3.0),
            Measured {
                start: Point3::new(0.0, 3.0, 1.0),
                end: Point3::new(0.0, 3.0, 1.4),
                ..upright(0.0, 0.0)
            },
        ];
        assert!(
            period_shifts(&stacked, &[0, 1]).is_empty(),
            "one above the other"
        );
    }

    #[test]
    fn a_start_a_post_over_beyond_the_search_is_brought_back_by_the_rows_period() {
        // Posts 20 cm apart: from a start one post over, the wrong basin pairs five of six
        // posts per row, the local search reaches 10 cm at most, and only the row's period
        // finds the right fit, clearly cheaper.
        let pitch = 0.2;
        assert!(pitch > (MAX_GRID_STEPS_XY + 1) as f64 * ImageParams::default().grid_step_m);
        // Odometry of 10 cm per axis: the right post is 2σ from the prior.
        a_start_a_post_over_comes_back(pitch, 0.1);
    }

    #[test]
    fn a_row_longer_than_the_view_leaves_the_fit_uncertain_along_it() {
        // Thirty posts a row, running out of every view at both sides: a post over sees the
        // same picture, so the images cannot say which post is which, and the fit must not
        // claim to know its place along the row to millimetres.
        let pitch = 0.2;
        let (fit, truth, in_view) = fit_along_posts(pitch, 30, 0.0, 0.1);
        assert!(in_view.iter().all(|&n| n < 60), "the rows run out of view");
        let (deg, m) = off(&fit.pose, &truth);
        assert!(deg < 0.02 && m < 0.001, "{deg}° {m} m off: started there");
        let along = Vector6::new(0.0, 0.0, 0.0, 1.0, 0.0, 0.0);
        let across = Vector6::new(0.0, 0.0, 0.0, 0.0, 1.0, 0.0);
        let images_sigma = |v: &Vector6<f64>| {
            let covariance = fit.information.try_inverse().expect("the rows fix all six");
            v.dot(&(covariance * v)).sqrt()
        };
        // Rivals a pitch either way, as good in the images and each 2σ of the prior from it:
        // weighed e^-2 each, σ ≈ 0.46 pitch along the row (without them, 0.4 mm).
        assert!(
            images_sigma(&along) > 0.25 * pitch,
            "σ along the row {} m",
            images_sigma(&along)
        );
        assert!(
            images_sigma(&across) < 0.02,
            "σ across {} m",
            images_sigma(&across)
        );
    }

    /// The scene seen from the true pose: the rig's lenses, the references and each view's index.
    fn indexed_scene() -> ([Lens; 3], Vec<Measured>, [ViewIndex; 3]) {
        let rig = preset_rig();
        let ends = scene(&rig);
        let lists = images(&rig, &ends);
        let views = Views {
            cameras: rig.cameras(),
            segments: std::array::from_fn(|k| &lists[k][..]),
            list_noise_px: 0.3,
        };
        let lines = image_lines(&views, ImageParams::default().offset_floor_px);
        let lenses = std::array::from_fn(|k| Lens::of(rig.camera(k)));
        (lenses, measured(&ends, &truth()), lines)
    }

    #[test]
    fn the_analytic_derivative_is_the_numerical_one() {
        let (lenses, references, lines) = indexed_scene();
        let params = ImageParams::default();
        // Off the true pose, so that the residuals are not zero.
        let xi = Vector6::new(0.002, -0.001, 0.004, 0.01, -0.008, 0.005);
        let pose = perturbed(&truth(), &xi);
        let projected = project_all(&references, &lenses, &pose, &params);
        let pairings = associate(&projected, &lines, Some(6.0), &mut Candidates::near(&lines));
        assert!(pairings.len() >= 40, "{} pairings", pairings.len());
        let variances = vec![Vector2::new(0.09, 1e-5); pairings.len()];
        let at = |pose: &Isometry3<f64>| {
            linearised(&references, &lenses, &lines, &pairings, pose, &variances)
        };
        let here = at(&pose);
        let delta = 1e-6;
        for j in 0..6 {
            let mut step = Vector6::zeros();
            step[j] = delta;
            let (plus, minus) = (at(&perturbed(&pose, &step)), at(&perturbed(&pose, &-step)));
            for (i, (_, jacobian)) in here.iter().enumerate() {
                let numerical = (plus[i].0 - minus[i].0) / (2.0 * delta);
                let analytic = jacobian.column(j);
                let scale = numerical.norm().max(1.0);
                assert!(
                    (numerical - analytic).norm() < 1e-4 * scale,
                    "pairing {i}, ξ{j}: numerical {numerical:?}, analytic {analytic:?}"
                );
            }
        }
    }

    #[test]
    fn the_across_gradient_is_the_derivative_along_the_normal() {
        let rig = preset_rig();
        let normal = Vector2::new(0.6, -0.8);
        for camera in rig.cameras() {
            let lens = Lens::of(camera);
            let lens = &lens;
            let (axis, centre) = (camera.axis().normalize(), camera.centre());
            for (depth, side) in [(2.8, 0.4), (3.5, -0.2), (2.0, 0.7)] {
                let aside = axis.cross(&Vector3::z()).normalize();
                let x = (centre + axis * depth + aside * side + Vector3::z() * 0.3).coords;
                let (pixel, jacobian) = project(lens, &x).expect("in front");
                let (_, h) = pixel_of(lens, &x).expect("in front");
                let formed = jacobian.transpose() * normal;
                let summed = lens.across_gradient(&pixel, &h, &normal);
                assert!(
                    (formed - summed).norm() <= 1e-12 * formed.norm().max(1.0),
                    "{formed:?} against {summed:?}"
                );
            }
        }
    }

    #[test]
    fn the_search_scores_its_cells_from_gathered_candidates_as_from_the_index() {
        let (lenses, references, lines) = indexed_scene();
        let params = ImageParams::default();
        let start = perturbed(&truth(), &Vector6::new(0.0, 0.0, 0.004, 0.02, -0.03, 0.0));
        let (prior, information) = odometry_at(start);
        // Wider steps than the search's, so that projections move by many pixels and turn;
        // then so wide that some are left to the index walk.
        // (Far cells pair little: the comparison must still see pairings.)
        for (step_m, step_rad, walked_some, min_paired) in
            [(0.03, 0.01, false, 100), (0.4, 0.01, true, 40)]
        {
            let poses: Vec<Isometry3<f64>> = (-2..=2)
                .flat_map(|i| (-1..=1).map(move |k| (i as f64, k as f64)))
                .map(|(i, k)| {
                    perturbed(
                        &start,
                        &Vector6::new(0.0, 0.0, step_rad * k, step_m * i, 0.0, 0.0),
                    )
                })
                .collect();
            let projected: Vec<_> = poses
                .iter()
                .map(|pose| project_all(&references, &lenses, pose, &params))
                .collect();
            let gathered = gathered(&projected, &lines);
            let unlisted = gathered.iter().flatten().filter(|l| l.is_none()).count();
            assert_eq!(
                unlisted > 0,
                walked_some,
                "{unlisted} left to the walk at {step_m} m"
            );
            let mut paired = 0;
            for (pose, projected) in poses.iter().zip(&projected) {
                let score = |candidates: &mut Candidates| {
                    cost(projected, &lines, candidates, pose, &prior, &information)
                };
                let listed = score(&mut Candidates::listed(&lines, &gathered));
                let walked = score(&mut Candidates::near(&lines));
                assert_eq!(listed.total, walked.total);
                assert_eq!(listed.pairings.len(), walked.pairings.len());
                paired += walked.pairings.len();
            }
            assert!(
                paired >= min_paired,
                "{paired} pairings over the cells at {step_m} m"
            );
        }
    }

    #[test]
    fn a_bounded_cost_is_the_cost_or_sure_to_exceed_its_bound() {
        let (lenses, references, lines) = indexed_scene();
        let params = ImageParams::default();
        let (prior, information) = odometry_at(truth());
        let (mut given, mut given_up) = (0, 0);
        for (m, rad) in [(0.0, 0.0), (0.01, 0.002), (0.03, -0.004), (0.08, 0.01)] {
            let pose = perturbed(&truth(), &Vector6::new(0.0, 0.0, rad, m, -m, 0.0));
            let projected = project_all(&references, &lenses, &pose, &params);
            let whole = cost(
                &projected,
                &lines,
                &mut Candidates::near(&lines),
                &pose,
                &prior,
                &information,
            );
            for bound in [0.0, 0.5 * whole.total, whole.total, 2.0 * whole.total] {
                match cost_below(
                    &projected,
                    &lines,
                    &mut Candidates::near(&lines),
                    &pose,
                    &prior,
                    &information,
                    bound,
                ) {
                    Some(scored) => {
                        assert_eq!(scored.total.to_bits(), whole.total.to_bits());
                        assert_eq!(scored.pairings, whole.pairings);
                        given += 1;
                    }
                    None => {
                        assert!(whole.total > bound, "{} within {bound}", whole.total);
                        given_up += 1;
                    }
                }
            }
        }
        assert!(
            given >= 8 && given_up >= 4,
            "{given} given, {given_up} given up"
        );
    }

    #[test]
    fn a_refinement_pairs_from_its_gathered_candidates_as_from_the_index() {
        let (lenses, references, lines) = indexed_scene();
        let params = ImageParams::default();
        let start = perturbed(&truth(), &Vector6::new(0.0, 0.0, 0.004, 0.02, -0.03, 0.0));
        let anchors = project_all(&references, &lenses, &start, &params);
        let lists = gathered_about(&anchors, &lines);
        // Poses a refinement's rounds might reach (a few millimetres and tenths of a degree
        // away: every projection reads its list), then poses so far that some move more
        // than a cell from where the lists were gathered (those read the index).
        for (metres, radians, near) in [(0.002, 0.0005, true), (0.2, 0.1, false)] {
            for k in 0..6 {
                let mut xi = Vector6::zeros();
                xi[k] = if k < 3 { radians } else { metres };
                let pose = perturbed(&start, &xi);
                let projected = project_all(&references, &lenses, &pose, &params);
                let mut anchored = Candidates::anchored(&lines, &lists, &anchors);
                let (mut in_view, mut listed) = (0, 0);
                for (reference, views) in projected.iter().enumerate() {
                    for (view, p) in views.iter().enumerate() {
                        if let Some(p) = p {
                            in_view += 1;
                            listed += usize::from(anchored.list(reference, view, p).is_some());
                        }
                    }
                }
                assert!(in_view >= 20, "{in_view} projections in view, ξ {xi:?}");
                assert_eq!(
                    listed == in_view,
                    near,
                    "{listed} of {in_view} listed, ξ {xi:?}"
                );
                for gate in [Some(6.0), Some(2.0), None] {
                    let from_lists = associate(&projected, &lines, gate, &mut anchored);
                    let walked = associate(&projected, &lines, gate, &mut Candidates::near(&lines));
                    assert!(!near || !walked.is_empty(), "ξ {xi:?}, gate {gate:?}");
                    assert_eq!(
                        from_lists
                            .iter()
                            .map(|p| (p.reference, p.view, p.line))
                            .collect::<Vec<_>>(),
                        walked
                            .iter()
                            .map(|p| (p.reference, p.view, p.line))
                            .collect::<Vec<_>>(),
                        "ξ {xi:?}, gate {gate:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_caller_who_stopped_waiting_stops_the_fit() {
        let rig = preset_rig();
        let ends = scene(&rig);
        let references = measured(&ends, &truth());
        let lists = images(&rig, &ends);
        let views = Views {
            cameras: rig.cameras(),
            segments: std::array::from_fn(|k| &lists[k][..]),
            list_noise_px: 0.3,
        };
        let prior = PosePrior::odometry(truth(), 1.0, 0.3, 0.05, 0.01);
        let gone = || true;
        let got = refine_in_images_until(
            &references,
            &IndexedViews::new(&views, &ImageParams::default()),
            &[truth()],
            &prior,
            &ImageParams::default(),
            Checkpoint::new(&gone),
        );
        assert!(got.is_err(), "{got:?}");
    }

    #[test]
    fn a_huge_declared_image_gets_a_bounded_grid() {
        let line = ImageLine {
            start: Vector2::new(10.0, 10.0),
            end: Vector2::new(60_000.0, 50_000.0),
            direction: Vector2::new(1.0, 0.0),
            length: 1.0,
            offset_var: 0.01,
            angle_var: 0.0001,
        };
        let index = ViewIndex::new(vec![line], 65_536, 65_536);
        assert!(index.columns <= 258 && index.rows <= 258);
        assert!(index.cells.iter().filter(|c| !c.is_empty()).count() > 100);
        let small = ViewIndex::new(vec![line], 512, 512);
        assert_eq!((small.columns, small.cell), (33, CELL_PX));
    }

    #[test]
    fn too_few_references_in_view_give_no_fit() {
        let rig = preset_rig();
        let ends = scene(&rig);
        let few = &ends[..8];
        let references = measured(few, &truth());
        let lists = images(&rig, few);
        let views = Views {
            cameras: rig.cameras(),
            segments: std::array::from_fn(|k| &lists[k][..]),
            list_noise_px: 0.3,
        };
        let prior = PosePrior::odometry(truth(), 1.0, 0.3, 0.05, 0.01);
        let fit = refine_in_images(
            &references,
            &views,
            &[truth()],
            &prior,
            &ImageParams::default(),
        );
        assert_eq!(fit, None);
    }
}
