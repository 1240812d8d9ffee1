//! Grey images of a scene, exact or as a camera would record them.
//!
//! The segment extractor is tested and benchmarked on these images, and every edge in them
//! has known 3D ground truth. An exact render (one ray through each pixel centre) is a pure
//! function of scene and camera, but no camera produces it: its edges are one-pixel
//! staircases, perfectly sharp and noise-free, so an extractor tuned on it would be tuned to
//! the wrong thing. [`render_image`] therefore models, in the order light meets them:
//!
//! ```text
//! rays ─▶ box filter over the pixel (anti-aliasing) ─▶ Gaussian blur (optics) ─▶ + noise ─▶ clamp ─▶ round
//!         RenderParams::supersample                    blur_sigma_px             noise_sigma          quantise
//! ```
//!
//! Pixel `(u, v)` is column `u`, row `v`, centred at integer coordinates, `(0, 0)` the centre
//! of the top-left pixel. Pixel coordinates are *distorted* image points: the ray of a point
//! of a camera with lens distortion is that of its undistorted point, so edges land where
//! [`Camera::project`] puts them (DESIGN §1).
//!
//! Supersampling multiplies the rays, so casting is organised for speed: the image is cut
//! into 16 × 16 pixel tiles, the boxes that the rays of a tile can meet are
//! found once per tile (a conservative frustum test), and each ray tests only those, in
//! scene order, with the per-box test of [`Scene::cast`], so hits are exactly those of
//! `Scene::cast`. Bands of tile rows are rendered in parallel (rayon); the noise of each row
//! comes from its own stream forked from `(seed, row)`, so an image is the same whatever the
//! number of threads.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::rng::Rng;
use super::scene::{Ray, Scene, BACKGROUND};
use trinocular_core::extract::GreyImage;
use trinocular_core::geometry::{Camera, Distortion, Rig};

/// Grey level a sensor saturates at (and the top of the [`GreyImage`] scale).
const WHITE: f64 = 255.0;
/// Side of the square pixel tiles whose rays share one list of candidate boxes. Smaller
/// tiles cull more boxes per ray but cull more often; at 16 px a tile of the standard room
/// keeps 2 to 3 of its 123 boxes on average (8 at most), and culling costs a few percent of
/// the casting.
const TILE: usize = 16;
/// Largest mismatch, in normalised image units, between an image point and the distortion
/// of its undistorted point for the point to count as imaging a ray: a thousandth of a pixel
/// at f = 1000 px, far above what a converged inversion leaves and far below the mismatch
/// of a point outside the lens model's range.
const UNDISTORT_TOLERANCE: f64 = 1e-6;
/// Slack of the frustum culling, metres: a box is dropped only if it lies this far outside
/// a bounding plane of the tile's rays, so rounding can never drop a box a ray meets.
const CULL_MARGIN_M: f64 = 1e-9;

/// How [`render_image`] turns a scene into a camera-like image. Each stage can be switched
/// off on its own; [`RenderParams::exact`] switches off all of them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderParams {
    /// Rays per pixel side: the pixel's square `[u−½, u+½] × [v−½, v+½]` is cut into
    /// `supersample × supersample` equal cells and one ray goes through each cell's centre.
    /// Their mean is the box-filtered (area-averaged) light a photosite integrates, so a
    /// pixel straddling an edge gets a grey between the two sides in proportion to the area
    /// each covers, which is what sub-pixel edge localisation relies on. Cell centres rather
    /// than jittered points keep the anti-aliased image a pure function of scene and camera
    /// (all randomness is sensor noise); the price is that an axis-aligned edge moves the
    /// grey in steps of `1/supersample` of a pixel. `1` is one ray through the pixel centre;
    /// `0` is taken as `1`.
    pub supersample: u32,
    /// Standard deviation, in pixels, of the Gaussian point-spread function applied to the
    /// anti-aliased image (separable; the image border is extended by repeating its edge
    /// pixels). Lens blur, diffraction and demosaicing spread a real edge over two or three
    /// pixels; gradient operators are designed for that. `0` (or anything not finite and
    /// positive) is no blur.
    pub blur_sigma_px: f64,
    /// Standard deviation, in grey levels of the 0–255 scale, of the zero-mean Gaussian
    /// noise added to every pixel independently (read and shot noise of the sensor, taken as
    /// signal-independent). `0` (or anything not finite and positive) is no noise.
    pub noise_sigma: f64,
    /// Round grey levels to integers, as an 8-bit analogue-to-digital converter does, so the
    /// extractor sees what it would read from an 8-bit file. The grey levels are clamped to
    /// `[0, 255]` whether or not they are rounded.
    pub quantise: bool,
}

impl Default for RenderParams {
    /// A sharp, well-exposed 8-bit camera: 3 × 3 rays per pixel (edge grey levels within a
    /// sixth of a pixel of the true area), a 0.7 px blur (an edge rises over about two
    /// pixels), noise of 2 grey levels (a decent sensor in office light), rounded to 8 bits.
    fn default() -> RenderParams {
        RenderParams {
            supersample: 3,
            blur_sigma_px: 0.7,
            noise_sigma: 2.0,
            quantise: true,
        }
    }
}

impl RenderParams {
    /// One ray through each pixel centre, no blur, no noise, no rounding: the exact radiance
    /// of the scene along each pixel-centre ray, clamped to `[0, 255]`.
    pub fn exact() -> RenderParams {
        RenderParams {
            supersample: 1,
            blur_sigma_px: 0.0,
            noise_sigma: 0.0,
            quantise: false,
        }
    }
}

/// The image `camera` records of `scene` (see [`RenderParams`] for the stages). Grey levels
/// are in `[0, 255]`, integers when `params.quantise`. `seed` draws the noise only: with
/// `noise_sigma = 0` the image does not depend on it.
///
/// Image points that the lens model maps to no ray (beyond the largest radius a strong
/// barrel distortion reaches, or on the branch beyond the radius where the distortion stops
/// being monotonic, which visibility also excludes) are [`BACKGROUND`], like the dark
/// border outside a real lens's image circle. Without distortion every point has its ray.
pub fn render_image(scene: &Scene, camera: &Camera, params: &RenderParams, seed: u64) -> GreyImage {
    let (width, height) = (camera.width() as usize, camera.height() as usize);
    let mut image = anti_aliased(scene, camera, params.supersample.max(1));
    let kernel = gaussian_kernel(params.blur_sigma_px, width.max(height));
    if let Some(kernel) = &kernel {
        blur_rows(&mut image, width, kernel);
    }
    let noise_sigma = if params.noise_sigma.is_finite() && params.noise_sigma > 0.0 {
        params.noise_sigma
    } else {
        0.0
    };
    let root = Rng::new(seed);
    let mut pixels = vec![0.0f32; width * height];
    pixels
        .par_chunks_mut(width)
        .enumerate()
        .for_each(|(row, out)| {
            match &kernel {
                Some(kernel) => blur_column_into(&image, width, height, row, kernel, out),
                None => {
                    for (o, &x) in out.iter_mut().zip(&image[row * width..(row + 1) * width]) {
                        *o = x as f32;
                    }
                }
            }
            let mut rng = root.fork(row as u64);
            for o in out.iter_mut() {
                let mut grey = f64::from(*o);
                if noise_sigma > 0.0 {
                    grey += noise_sigma * rng.normal();
                }
                grey = grey.clamp(0.0, WHITE);
                if params.quantise {
                    grey = grey.round();
                }
                *o = grey as f32;
            }
        });
    GreyImage::new(camera.width(), camera.height(), pixels)
        .expect("the pixel buffer holds width × height grey levels by construction")
}

/// The images of the three cameras of `rig`, with noise seeds derived from `seed` and the
/// camera index so the three noise fields are independent.
pub fn render_triplet(
    scene: &Scene,
    rig: &Rig,
    params: &RenderParams,
    seed: u64,
) -> [GreyImage; 3] {
    let root = Rng::new(seed);
    std::array::from_fn(|i| render_image(scene, rig.camera(i), params, camera_seed(&root, i)))
}

/// `image` as a camera with `gain` times the exposure would see it: every grey level, signal
/// and noise alike, scaled (cameras of one rig with exposures of their own).
pub fn with_exposure(image: &GreyImage, gain: f32) -> GreyImage {
    let scaled = image.pixels().iter().map(|p| p * gain).collect();
    GreyImage::new(image.width(), image.height(), scaled)
        .expect("the same number of pixels as the image's own")
}

/// The noise seed of camera `i` in [`render_triplet`].
fn camera_seed(root: &Rng, i: usize) -> u64 {
    root.fork(i as u64).next_u64()
}

/// The exact image `camera` sees, row-major (`v` rows of `u` columns), grey levels 0–255,
/// pixel `(u, v)` sampled along the ray through its centre (DESIGN §1): [`render_image`] with
/// [`RenderParams::exact`], rounded to 8 bits.
pub fn render(scene: &Scene, camera: &Camera) -> Vec<u8> {
    let params = RenderParams {
        quantise: true,
        ..RenderParams::exact()
    };
    render_image(scene, camera, &params, 0).to_u8()
}

/// A camera's numbers as plain arrays, mapping image points to rays. Unlike
/// [`Camera::undistort`] and [`Camera::ray`] it exposes the normalised coordinates, which
/// bound a tile's rays, and it reports the points the lens model images no ray through.
#[derive(Debug, Clone)]
struct PixelRays {
    fx: f64,
    fy: f64,
    skew: f64,
    cx: f64,
    cy: f64,
    distortion: Option<Distortion>,
    /// rig_to_cam rotation `R`, by rows.
    rotation: [[f64; 3]; 3],
    centre: Point3<f64>,
}

impl PixelRays {
    fn new(camera: &Camera) -> PixelRays {
        let (k, r) = (camera.intrinsics(), camera.rotation());
        PixelRays {
            fx: k[(0, 0)],
            fy: k[(1, 1)],
            skew: k[(0, 1)],
            cx: k[(0, 2)],
            cy: k[(1, 2)],
            distortion: camera.distortion().copied(),
            rotation: std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)])),
            centre: camera.centre(),
        }
    }

    /// Undistorted normalised coordinates `(x/z, y/z)` of the ray through image point
    /// `(u, v)`, or `None` where the lens model images no ray: where [`Distortion::remove`]
    /// finds no point that distorts back to the image point (beyond the largest radius a
    /// barrel distortion reaches), or finds one beyond the radius where the radial
    /// distortion stops being monotonic (as `FlatCamera::in_image` in visibility).
    fn normalised(&self, u: f64, v: f64) -> Option<[f64; 2]> {
        let yd = (v - self.cy) / self.fy;
        let xd = (u - self.cx - self.skew * yd) / self.fx;
        let Some(d) = &self.distortion else {
            return Some([xd, yd]);
        };
        let (x, y) = d.remove(xd, yd);
        let r2 = x * x + y * y;
        let monotonic = 1.0 + r2 * (3.0 * d.k1 + r2 * (5.0 * d.k2 + r2 * 7.0 * d.k3)) > 0.0;
        let (xr, yr) = d.apply(x, y);
        let round_trips =
            (xr - xd).abs() <= UNDISTORT_TOLERANCE && (yr - yd).abs() <= UNDISTORT_TOLERANCE;
        (monotonic && round_trips && x.is_finite() && y.is_finite()).then_some([x, y])
    }

    /// Rig-frame direction `Rᵀ·(x, y, 1)` of normalised coordinates.
    fn direction(&self, n: [f64; 2]) -> Vector3<f64> {
        self.to_rig([n[0], n[1], 1.0])
    }

    /// A camera-frame vector in the rig frame (`Rᵀ·c`).
    fn to_rig(&self, c: [f64; 3]) -> Vector3<f64> {
        let r = &self.rotation;
        Vector3::from_fn(|j, _| r[0][j] * c[0] + r[1][j] * c[1] + r[2][j] * c[2])
    }
}

/// The boxes of a scene as plain arrays, `(lo, hi)` by box index.
type BoxBounds = Vec<([f64; 3], [f64; 3])>;

/// Indices, in increasing order, of the boxes that may meet a ray from the optical centre
/// whose normalised coordinates lie in `[x_min, x_max] × [y_min, y_max]`: every box except
/// those wholly outside one of the five planes bounding that pyramid (its four sides and the
/// camera plane; a hit is always in front of the camera). Conservative: a kept box may be
/// missed by every ray, a dropped box is missed by all of them.
fn candidates(
    boxes: &BoxBounds,
    rays: &PixelRays,
    [x_min, x_max, y_min, y_max]: [f64; 4],
    out: &mut Vec<usize>,
) {
    // Inward normals, camera frame: x ≥ x_min·z, x ≤ x_max·z, likewise y, and z ≥ 0.
    let planes = [
        [1.0, 0.0, -x_min],
        [-1.0, 0.0, x_max],
        [0.0, 1.0, -y_min],
        [0.0, -1.0, y_max],
        [0.0, 0.0, 1.0],
    ]
    .map(|n| rays.to_rig(n));
    let c = rays.centre.coords;
    out.clear();
    out.extend((0..boxes.len()).filter(|&i| {
        let (lo, hi) = &boxes[i];
        let mid = Vector3::from_fn(|k, _| 0.5 * (lo[k] + hi[k]));
        let half = Vector3::from_fn(|k, _| 0.5 * (hi[k] - lo[k]));
        planes.iter().all(|n| {
            let reach = n.dot(&(mid - c)) + n.abs().dot(&half);
            reach >= -CULL_MARGIN_M * n.norm()
        })
    }));
}

/// Grey level along `origin + t·dir`: the nearest hit among the `candidates` boxes, found
/// with the per-box test and tie rule of [`Scene::cast`] in the same (index) order, shaded.
fn radiance_among(
    scene: &Scene,
    boxes: &BoxBounds,
    candidates: &[usize],
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
) -> f64 {
    let Some(ray) = Ray::new(origin, dir) else {
        return BACKGROUND;
    };
    let mut best = None;
    for &i in candidates {
        let (lo, hi) = &boxes[i];
        ray.offer(lo, hi, i, &mut best);
    }
    best.map_or(BACKGROUND, |(t, box_index, face)| {
        scene.shade(&ray.hit(t, box_index, face))
    })
}

/// Mean radiance over `n × n` cell-centre rays in each pixel, row-major, unclamped.
fn anti_aliased(scene: &Scene, camera: &Camera, n: u32) -> Vec<f64> {
    let (width, height) = (camera.width() as usize, camera.height() as usize);
    let rays = PixelRays::new(camera);
    let boxes: BoxBounds = scene
        .boxes
        .iter()
        .map(|b| (b.min.coords.into(), b.max.coords.into()))
        .collect();
    let n = n as usize;
    let offsets: Vec<f64> = (0..n).map(|k| (k as f64 + 0.5) / n as f64 - 0.5).collect();
    let rays_per_pixel = (n * n) as f64;
    let mut image = vec![0.0f64; width * height];
    image
        .par_chunks_mut(width * TILE)
        .enumerate()
        .for_each(|(band, out)| {
            let rows = out.len() / width;
            // Normalised coordinates of a tile's rays, sub-row by sub-row, reused.
            let mut points: Vec<Option<[f64; 2]>> = Vec::with_capacity(TILE * TILE * n * n);
            let mut kept = Vec::with_capacity(boxes.len());
            for first_column in (0..width).step_by(TILE) {
                let columns = TILE.min(width - first_column);
                let stride = columns * n;
                points.clear();
                let mut bounds = [
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                ];
                for r in 0..rows {
                    let v = (band * TILE + r) as f64;
                    for dv in &offsets {
                        for c in 0..columns {
                            let u = (first_column + c) as f64;
                            for du in &offsets {
                                let point = rays.normalised(u + du, v + dv);
                                if let Some([x, y]) = point {
                                    bounds = [
                                        bounds[0].min(x),
                                        bounds[1].max(x),
                                        bounds[2].min(y),
                                        bounds[3].max(y),
                                    ];
                                }
                                points.push(point);
                            }
                        }
                    }
                }
                if bounds[0] <= bounds[1] {
                    candidates(&boxes, &rays, bounds, &mut kept);
                } else {
                    kept.clear();
                }
                for r in 0..rows {
                    for c in 0..columns {
                        let mut sum = 0.0;
                        for sub_row in 0..n {
                            let start = (r * n + sub_row) * stride + c * n;
                            for point in &points[start..start + n] {
                                sum += point.map_or(BACKGROUND, |p| {
                                    let dir = rays.direction(p);
                                    radiance_among(scene, &boxes, &kept, &rays.centre, &dir)
                                });
                            }
                        }
                        out[r * width + first_column + c] = sum / rays_per_pixel;
                    }
                }
            }
        });
    image
}

/// Normalised Gaussian weights `w[0..=2r]` for offsets `−r..=r`, `r = ⌈3σ⌉` (the tails
/// beyond hold 0.3% of the weight) but at most `max_radius`; `None` when `sigma` is not
/// finite and positive. Normalising keeps the mean grey level of flat regions.
fn gaussian_kernel(sigma: f64, max_radius: usize) -> Option<Vec<f64>> {
    if !(sigma.is_finite() && sigma > 0.0) {
        return None;
    }
    // `as usize` saturates, and `max_radius` bounds the work for absurd sigmas.
    let radius = ((3.0 * sigma).ceil() as usize).clamp(1, max_radius.max(1));
    let weights: Vec<f64> = (0..=2 * radius)
        .map(|k| {
            let x = k as f64 - radius as f64;
            (-0.5 * (x / sigma).powi(2)).exp()
        })
        .collect();
    let total: f64 = weights.iter().sum();
    Some(weights.into_iter().map(|w| w / total).collect())
}

/// Convolves every row with `kernel` in place, repeating the edge pixels beyond the border.
fn blur_rows(image: &mut [f64], width: usize, kernel: &[f64]) {
    let radius = kernel.len() / 2;
    image.par_chunks_mut(width).for_each(|row| {
        let source = row.to_vec();
        for (u, out) in row.iter_mut().enumerate() {
            *out = kernel
                .iter()
                .enumerate()
                .map(|(k, w)| w * source[(u + k).saturating_sub(radius).min(width - 1)])
                .sum();
        }
    });
}

/// Row `row` of `image` convolved down its columns with `kernel`, repeating the edge rows
/// beyond the border.
fn blur_column_into(
    image: &[f64],
    width: usize,
    height: usize,
    row: usize,
    kernel: &[f64],
    out: &mut [f32],
) {
    let radius = kernel.len() / 2;
    let mut sums = vec![0.0f64; width];
    for (k, w) in kernel.iter().enumerate() {
        let source_row = (row + k).saturating_sub(radius).min(height - 1);
        let source = &image[source_row * width..(source_row + 1) * width];
        for (s, &x) in sums.iter_mut().zip(source) {
            *s += w * x;
        }
    }
    for (o, s) in out.iter_mut().zip(sums) {
        *o = s as f32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::{Pose, RigSpec};
    use crate::scene::{Box3, Tracer, AMBIENT};
    use crate::STANDARD_RIG_POSITION;
    use nalgebra::{Matrix3, Point2, Point3, Vector3};
    use trinocular_core::geometry::Distortion;

    /// Depth of the wall in [`two_tone_wall`], metres.
    const WALL_Y: f64 = 4.0;
    const LEFT_ALBEDO: f64 = 0.9;
    const RIGHT_ALBEDO: f64 = 0.3;

    /// A wall facing the camera at `y = 4 m`, of albedo 0.9 for `x < split_x` and 0.3 beyond,
    /// lit by a light so far away that only the ambient term counts: two flat regions.
    fn two_tone_wall(split_x: f64) -> Scene {
        let (lo, hi) = (-50.0, 50.0);
        Scene {
            boxes: vec![
                Box3::new(
                    Point3::new(lo, WALL_Y, lo),
                    Point3::new(split_x, WALL_Y + 0.1, hi),
                    [LEFT_ALBEDO; 6],
                ),
                Box3::new(
                    Point3::new(split_x, WALL_Y, lo),
                    Point3::new(hi, WALL_Y + 0.1, hi),
                    [RIGHT_ALBEDO; 6],
                ),
            ],
            light: Point3::new(0.0, -1e5, 0.0),
        }
    }

    fn flat_grey(albedo: f64) -> f64 {
        255.0 * albedo * AMBIENT
    }

    /// A camera at the origin looking along +y with z up (camera x = world x, so columns grow
    /// with x), principal point at the image centre.
    fn wall_camera(width: u32, height: u32, f: f64, distortion: Option<Distortion>) -> Camera {
        let k = Matrix3::new(
            f,
            0.0,
            (f64::from(width) - 1.0) / 2.0,
            0.0,
            f,
            (f64::from(height) - 1.0) / 2.0,
            0.0,
            0.0,
            1.0,
        );
        let r = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0);
        Camera::from_krt("wall", width, height, k, r, Vector3::zeros(), distortion)
            .expect("a valid test camera")
    }

    /// World x of the wall point imaged at column `u` by an undistorted [`wall_camera`].
    fn wall_x_at_column(camera: &Camera, u: f64) -> f64 {
        let ray = camera.ray(Point2::new(u, 0.0));
        ray.x / ray.y * WALL_Y
    }

    fn params(supersample: u32, blur_sigma_px: f64, noise_sigma: f64) -> RenderParams {
        RenderParams {
            supersample,
            blur_sigma_px,
            noise_sigma,
            quantise: false,
        }
    }

    /// Mean and standard deviation.
    fn moments(values: impl Iterator<Item = f64>) -> (f64, f64) {
        let v: Vec<f64> = values.collect();
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
        (mean, var.sqrt())
    }

    #[test]
    fn renders_a_box_where_it_projects() {
        let scene = Scene {
            boxes: vec![
                Box3::new(
                    Point3::new(-5.0, 4.0, -5.0),
                    Point3::new(5.0, 4.1, 5.0),
                    [0.9; 6],
                ),
                Box3::new(
                    Point3::new(-0.2, 2.0, -0.2),
                    Point3::new(0.2, 2.2, 0.2),
                    [0.1; 6],
                ),
            ],
            light: Point3::new(0.0, 0.0, 1.0),
        };
        // A small, wide-angle image: f = 60 px, principal point at the centre.
        let mut spec = RigSpec {
            width: 64,
            height: 48,
            ..RigSpec::collinear(0)
        };
        for c in &mut spec.cameras {
            (c.fx, c.fy, c.cx, c.cy) = (60.0, 60.0, 31.5, 23.5);
        }
        let rig = spec.build(&Pose::identity()).unwrap();
        let cam = &rig.cameras()[0];
        let img = render(&scene, cam);
        assert_eq!(img.len(), 64 * 48);
        let at = |p: Point3<f64>| {
            let q = cam.project(&p).unwrap();
            img[q.y.round() as usize * 64 + q.x.round() as usize]
        };
        // The dark box's front face, darker than the bright wall around it.
        let front = at(Point3::new(0.0, 2.0, 0.0));
        let wall = at(Point3::new(0.6, 4.0, 0.0));
        assert!(front + 50 < wall, "front {front}, wall {wall}");
        let expected = scene.radiance(&cam.centre(), &(Point3::new(0.6, 4.0, 0.0) - cam.centre()));
        assert!((f64::from(wall) - expected).abs() <= 1.0);
    }

    #[test]
    fn anti_aliasing_greys_an_edge_pixel_by_covered_area() {
        let camera = wall_camera(32, 4, 20.0, None);
        let (left, right) = (flat_grey(LEFT_ALBEDO), flat_grey(RIGHT_ALBEDO));
        // Column 16 covers [15.5, 16.5]; the edge leaves `covered` of it to the left region.
        let check = |covered: f64, supersample: u32, tolerance: f64| {
            let scene = two_tone_wall(wall_x_at_column(&camera, 15.5 + covered));
            let img = render_image(&scene, &camera, &params(supersample, 0.0, 0.0), 0);
            let expected = covered * left + (1.0 - covered) * right;
            let got = f64::from(img.at(16, 2));
            assert!(
                (got - expected).abs() <= tolerance * (left - right) + 1e-4,
                "covered {covered}, n = {supersample}: {got} vs {expected}"
            );
            assert!((f64::from(img.at(15, 2)) - left).abs() < 1e-4);
            assert!((f64::from(img.at(17, 2)) - right).abs() < 1e-4);
        };
        // Edges on the boundaries of the 3 × 3 cells are exact.
        check(1.0 / 3.0, 3, 0.0);
        check(2.0 / 3.0, 3, 0.0);
        // Anywhere else, within half a cell.
        for covered in [0.1, 0.37, 0.5, 0.81] {
            check(covered, 3, 1.0 / 6.0);
            check(covered, 16, 1.0 / 32.0);
        }
        // One ray per pixel is the staircase anti-aliasing removes.
        let scene = two_tone_wall(wall_x_at_column(&camera, 15.5 + 0.37));
        let exact = render_image(&scene, &camera, &RenderParams::exact(), 0);
        assert!((f64::from(exact.at(16, 2)) - right).abs() < 1e-4);
    }

    #[test]
    fn noise_has_the_requested_deviation_and_no_bias() {
        let camera = wall_camera(128, 128, 100.0, None);
        let scene = two_tone_wall(100.0);
        let clean = flat_grey(LEFT_ALBEDO);
        for quantise in [false, true] {
            let p = RenderParams {
                quantise,
                ..params(1, 0.0, 2.0)
            };
            let img = render_image(&scene, &camera, &p, 7);
            let (mean, sd) = moments(img.pixels().iter().map(|&g| f64::from(g) - clean));
            // 3σ of the mean of 16384 samples is 0.047.
            assert!(mean.abs() < 0.05, "quantise {quantise}: mean {mean}");
            assert!((sd - 2.0).abs() < 0.2, "quantise {quantise}: sd {sd}");
            if quantise {
                assert!(img.pixels().iter().all(|g| g.fract() == 0.0));
            }
        }
    }

    #[test]
    fn blur_keeps_flat_regions_and_spreads_a_step() {
        let camera = wall_camera(32, 16, 20.0, None);
        let (left, right) = (flat_grey(LEFT_ALBEDO), flat_grey(RIGHT_ALBEDO));
        // Flat: unchanged everywhere, borders included.
        let flat = render_image(&two_tone_wall(100.0), &camera, &params(1, 0.7, 0.0), 0);
        assert!(flat
            .pixels()
            .iter()
            .all(|&g| (f64::from(g) - left).abs() < 1e-4));
        // A step between columns 15 and 16.
        let scene = two_tone_wall(wall_x_at_column(&camera, 15.5));
        let sharp = render_image(&scene, &camera, &params(1, 0.0, 0.0), 0);
        let blurred = render_image(&scene, &camera, &params(1, 0.7, 0.0), 0);
        let row = |img: &GreyImage| (0..32).map(|u| f64::from(img.at(u, 8))).collect::<Vec<_>>();
        let (sharp, blurred) = (row(&sharp), row(&blurred));
        assert!((sharp[15] - left).abs() < 1e-4 && (sharp[16] - right).abs() < 1e-4);
        let step = left - right;
        assert!(blurred[14] < left - 0.005 * step && blurred[17] > right + 0.005 * step);
        assert!(blurred[15] < left - 0.1 * step && blurred[16] > right + 0.1 * step);
        assert!(blurred.windows(2).all(|w| w[1] <= w[0] + 1e-4));
        assert!(((blurred[15] + blurred[16]) / 2.0 - (left + right) / 2.0).abs() < 1e-3);
        let (sum_sharp, sum_blurred): (f64, f64) = (sharp.iter().sum(), blurred.iter().sum());
        assert!((sum_sharp - sum_blurred).abs() < 1e-3);
    }

    #[test]
    fn the_seed_draws_the_noise() {
        let camera = wall_camera(64, 48, 40.0, None);
        let scene = two_tone_wall(0.3);
        let p = RenderParams::default();
        let a = render_image(&scene, &camera, &p, 1);
        assert_eq!(a, render_image(&scene, &camera, &p, 1));
        assert_ne!(a, render_image(&scene, &camera, &p, 2));
        let clean = params(3, 0.7, 0.0);
        assert_eq!(
            render_image(&scene, &camera, &clean, 1),
            render_image(&scene, &camera, &clean, 2)
        );
    }

    #[test]
    fn triplets_have_independent_noise() {
        let mut spec = RigSpec {
            width: 48,
            height: 32,
            ..RigSpec::collinear(0)
        };
        for c in &mut spec.cameras {
            (c.fx, c.fy, c.cx, c.cy) = (40.0, 40.0, 23.5, 15.5);
            c.yaw_rad = 0.0;
            c.pitch_rad = 0.0;
            c.roll_rad = 0.0;
        }
        let rig = spec.build(&Pose::identity()).unwrap();
        // Far enough that the 0.24 m baseline moves nothing by a pixel: the three clean
        // images are alike and the differences are noise.
        let scene = two_tone_wall(1e3);
        let images = render_triplet(&scene, &rig, &RenderParams::default(), 5);
        for (i, img) in images.iter().enumerate() {
            let seed = camera_seed(&Rng::new(5), i);
            let alone = render_image(&scene, rig.camera(i), &RenderParams::default(), seed);
            assert_eq!(*img, alone);
        }
        assert_ne!(images[0], images[1]);
        assert_ne!(images[1], images[2]);
    }

    #[test]
    fn output_does_not_depend_on_the_thread_count() {
        let camera = wall_camera(96, 64, 50.0, None);
        let scene = two_tone_wall(0.2);
        let in_pool = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a thread pool")
                .install(|| render_image(&scene, &camera, &RenderParams::default(), 11))
        };
        assert_eq!(in_pool(1), in_pool(2));
    }

    #[test]
    fn distorted_cameras_put_edges_where_project_says() {
        let distortion = Distortion {
            k1: -0.25,
            k2: 0.05,
            p1: 0.002,
            p2: -0.001,
            k3: 0.0,
        };
        let camera = wall_camera(160, 120, 200.0, Some(distortion));
        let pinhole = wall_camera(160, 120, 200.0, None);
        // A vertical edge at x = 1.2 m on the wall 4 m away: normalised x = 0.3, where the
        // distortion moves it by more than a pixel.
        let split_x = 1.2;
        let scene = two_tone_wall(split_x);
        let edge_point = |z: f64| Point3::new(split_x, WALL_Y, z);
        // The point of the edge imaged on row 30 (above the centre: v falls as z rises).
        let row = 30usize;
        let (mut lo, mut hi) = (0.0, 4.0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            let v = camera.project(&edge_point(mid)).expect("in front").y;
            if v > row as f64 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let on_row = edge_point(0.5 * (lo + hi));
        let expected = camera.project(&on_row).expect("in front");
        assert!((expected.y - row as f64).abs() < 1e-6);
        let undistorted = pinhole.project(&on_row).expect("in front");
        assert!(
            (expected.x - undistorted.x).abs() > 1.0,
            "{expected} {undistorted}"
        );

        let img = render_image(&scene, &camera, &params(8, 0.0, 0.0), 0);
        // Area left of the edge along the row: each pixel contributes its covered fraction.
        let (left, right) = (flat_grey(LEFT_ALBEDO), flat_grey(RIGHT_ALBEDO));
        let first = expected.x.round() as usize - 6;
        let covered: f64 = (first..first + 13)
            .map(|u| (f64::from(img.at(u, row)) - right) / (left - right))
            .sum();
        let measured = first as f64 - 0.5 + covered;
        assert!(
            (measured - expected.x).abs() < 0.08,
            "edge at {measured}, projected at {}",
            expected.x
        );
    }

    #[test]
    fn tile_culling_finds_the_hits_of_a_full_scan() {
        // The standard room, as seen by a plain and by a distorted camera: every pixel of
        // the exact render is the radiance `Scene::cast` (all boxes) finds along its ray.
        let scene = Scene::room(3);
        let pose = Pose::from_position_yaw(Point3::from(STANDARD_RIG_POSITION), 0.0);
        let distortion = Distortion {
            k1: -0.2,
            k2: 0.04,
            p1: 0.001,
            p2: 0.0005,
            k3: 0.0,
        };
        for spec in [
            RigSpec::non_collinear(3),
            RigSpec::non_collinear(3).with_distortion(distortion),
        ] {
            let rig = spec.build(&pose).expect("a preset rig");
            let camera = rig.camera(1);
            let rays = PixelRays::new(camera);
            let img = render_image(&scene, camera, &RenderParams::exact(), 0);
            for v in 0..camera.height() as usize {
                for u in 0..camera.width() as usize {
                    let expected = rays.normalised(u as f64, v as f64).map_or(BACKGROUND, |p| {
                        scene.radiance(&camera.centre(), &rays.direction(p))
                    });
                    assert_eq!(
                        img.at(u, v),
                        expected.clamp(0.0, WHITE) as f32,
                        "({u}, {v})"
                    );
                }
            }
        }
    }

    #[test]
    fn pixels_beyond_the_lens_model_are_background() {
        // Barrel distortion this strong maps no ray beyond a distorted radius of 0.54; the
        // image corners are at 1.1.
        let distortion = Distortion {
            k1: -0.5,
            ..Distortion::default()
        };
        let camera = wall_camera(64, 64, 40.0, Some(distortion));
        let img = render_image(&two_tone_wall(100.0), &camera, &RenderParams::exact(), 0);
        assert_eq!(f64::from(img.at(0, 0)), BACKGROUND);
        assert_eq!(f64::from(img.at(63, 63)), BACKGROUND);
        assert!((f64::from(img.at(32, 32)) - flat_grey(LEFT_ALBEDO)).abs() < 1e-4);
    }
}
