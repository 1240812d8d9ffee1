//! Edge points: non-maximum suppression with sub-pixel localisation, then hysteresis.
//!
//! 1. **Non-maximum suppression** (Devernay 1995): a pixel is an edge point when its gradient
//!    magnitude is a maximum along the axis (u or v) closest to the gradient direction, and at
//!    least `low_gradient`. Comparing along an axis rather than along the quantised diagonal
//!    keeps the chain one pixel thin and makes the sub-pixel step below unbiased.
//! 2. **Sub-pixel localisation**: a parabola through the three magnitudes along that axis puts
//!    the point at the parabola's peak (within half a pixel of the pixel centre). A pixel
//!    whose neighbour along that axis is in the gradient's zero frame gives no point.
//! 3. **Hysteresis**: points at least `high_gradient` are edges, and so are points connected to
//!    them through 8-connected edge points; isolated weak responses (noise) go.

use super::gradient::{self, Gradient};

/// Marks "no edge point here" in [`EdgeMap::index`].
pub const NO_POINT: u32 = u32::MAX;

/// One edge point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgePoint {
    /// The pixel it was found in.
    pub x: u32,
    pub y: u32,
    /// Sub-pixel position, pixels (DESIGN §1: pixel centres at integers).
    pub u: f32,
    pub v: f32,
    /// Gradient there, grey levels per pixel.
    pub gu: f32,
    pub gv: f32,
    pub magnitude: f32,
}

/// Edge points and, per pixel, the index of the point found there.
#[derive(Debug, Clone, PartialEq)]
pub struct EdgeMap {
    pub width: usize,
    pub height: usize,
    /// In row-major order of their pixels.
    pub points: Vec<EdgePoint>,
    /// Per pixel (row-major): index into `points`, or [`NO_POINT`].
    pub index: Vec<u32>,
}

impl EdgeMap {
    /// Calls `visit` with the index entry (a point, or [`NO_POINT`]) of each of the eight
    /// pixels about `(x, y)` that lie in the image, in row-major order.
    #[inline(always)]
    pub fn for_each_neighbour(&self, x: usize, y: usize, mut visit: impl FnMut(u32)) {
        let (w, h) = (self.width, self.height);
        // Suppression leaves the border without points, so a point has its eight neighbours
        // in the image: read at fixed offsets, without clamping.
        let off_border = x >= 1 && y >= 1 && x + 1 < w && y + 1 < h;
        for_each_neighbour_pixel(y * w + x, (w, h), off_border, |k| visit(self.index[k]));
    }

    /// The point at pixel `(x, y)`, if any.
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> Option<u32> {
        let i = self.index[y * self.width + x];
        (i != NO_POINT).then_some(i)
    }
}

/// Offset of the peak of the parabola through `(−1, before)`, `(0, centre)`, `(1, after)`,
/// clamped to ±0.5; 0 when the three do not bend down.
#[inline]
pub fn subpixel_offset(before: f32, centre: f32, after: f32) -> f32 {
    let curvature = before - 2.0 * centre + after;
    if curvature < 0.0 {
        (0.5 * (before - after) / curvature).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

/// Where suppression writes the points of a band of rows: the points in row-major order,
/// and the band's rows of the image's index, numbered from the band's first point (made the
/// image's numbers when the bands are put together, [`join_bands`]).
struct Band<'a> {
    width: usize,
    height: usize,
    first_row: usize,
    points: Vec<EdgePoint>,
    index: &'a mut [u32],
}

/// Step 1 and 2 for row `y`: appends its edge points to `band`, given the gradient magnitude
/// of rows `y − 1`, `y`, `y + 1` and the gradient of row `y`.
#[allow(clippy::too_many_arguments)]
fn suppress_row(
    band: &mut Band,
    y: usize,
    above: &[f32],
    row: &[f32],
    below: &[f32],
    gu: &[f32],
    gv: &[f32],
    low: f32,
) {
    let w = band.width;
    // The test of every pixel is branch-free arithmetic over a block (`maxima`, which the
    // compiler vectorises); only the few pixels it marks are visited one by one. A test with
    // an early return per pixel mispredicted on the tens of thousands of noise pixels over
    // the low threshold of an unsmoothed image.
    let mut start = 1;
    while start < w - 1 {
        let end = (start + MASK_BLOCK).min(w - 1);
        let mut marked = if end - start == MASK_BLOCK {
            fn block(v: &[f32], from: usize) -> &[f32; MASK_BLOCK] {
                v[from..from + MASK_BLOCK]
                    .try_into()
                    .expect("a whole block")
            }
            maxima(
                block(above, start),
                block(row, start - 1),
                block(row, start),
                block(row, start + 1),
                block(below, start),
                block(gu, start),
                block(gv, start),
                low,
            )
        } else {
            (start..end).fold(0u32, |mask, x| {
                let max = is_maximum(
                    (above[x], row[x - 1], row[x], row[x + 1], below[x]),
                    (gu[x], gv[x]),
                    low,
                );
                mask | (u32::from(max) << (x - start))
            })
        };
        while marked != 0 {
            let x = start + marked.trailing_zeros() as usize;
            marked &= marked - 1;
            push_point(band, (x, y), above, row, below, gu, gv);
        }
        start = end;
    }
}

/// Pixels tested at once by [`suppress_row`]: one bit each of a `u32`.
const MASK_BLOCK: usize = 16;

/// [`is_maximum`] for the [`MASK_BLOCK`] pixels of a block: bit `i` set when pixel `i` is
/// one. `left` and `right` are the row shifted by one pixel either way.
#[allow(clippy::too_many_arguments)]
#[inline]
fn maxima(
    above: &[f32; MASK_BLOCK],
    left: &[f32; MASK_BLOCK],
    centre: &[f32; MASK_BLOCK],
    right: &[f32; MASK_BLOCK],
    below: &[f32; MASK_BLOCK],
    gu: &[f32; MASK_BLOCK],
    gv: &[f32; MASK_BLOCK],
    low: f32,
) -> u32 {
    let mut is_max = [false; MASK_BLOCK];
    for i in 0..MASK_BLOCK {
        is_max[i] = is_maximum(
            (above[i], left[i], centre[i], right[i], below[i]),
            (gu[i], gv[i]),
            low,
        );
    }
    is_max
        .iter()
        .enumerate()
        .fold(0u32, |mask, (i, &m)| mask | (u32::from(m) << i))
}

/// Whether a pixel of magnitude `centre` is a candidate edge point: at least `low` and a
/// maximum along the axis closest to its gradient `(gu, gv)`, against its neighbours
/// `above`, `left`, `right`, `below`. Written without branches, so that it vectorises.
#[inline(always)]
fn is_maximum(
    (above, left, centre, right, below): (f32, f32, f32, f32, f32),
    (gu, gv): (f32, f32),
    low: f32,
) -> bool {
    let along_u = gu.abs() >= gv.abs();
    let before = if along_u { left } else { above };
    let after = if along_u { right } else { below };
    // Strict on one side so a plateau of two equal pixels gives one point, not none.
    (centre >= low)
        & ((centre > before) & (centre >= after) | (centre >= before) & (centre > after))
}

/// Appends the edge point of pixel `(x, y)`, which [`is_maximum`] marked, located to sub-pixel
/// precision along its axis; none next to the gradient's frame.
#[allow(clippy::too_many_arguments)]
#[inline]
fn push_point(
    band: &mut Band,
    (x, y): (usize, usize),
    above: &[f32],
    row: &[f32],
    below: &[f32],
    gu: &[f32],
    gv: &[f32],
) {
    let along_u = gu[x].abs() >= gv[x].abs();
    // The gradient's one-pixel frame is zero, not measured: a point next to it along the
    // suppression axis would be a maximum against a made-up neighbour, and its sub-pixel
    // step pulled off the edge (a line running along the border came out 0.3–0.5 px off, and
    // its 3D segment up to 60σ away).
    let beside_frame = if along_u {
        x == 1 || x + 2 == band.width
    } else {
        y == 1 || y + 2 == band.height
    };
    if beside_frame {
        return;
    }
    let (before, after) = if along_u {
        (row[x - 1], row[x + 1])
    } else {
        (above[x], below[x])
    };
    let centre = row[x];
    let s = subpixel_offset(before, centre, after);
    let (u, v) = if along_u {
        (x as f32 + s, y as f32)
    } else {
        (x as f32, y as f32 + s)
    };
    band.index[(y - band.first_row) * band.width + x] = band.points.len() as u32;
    band.points.push(EdgePoint {
        x: x as u32,
        y: y as u32,
        u,
        v,
        gu: gu[x],
        gv: gv[x],
        magnitude: centre,
    });
}

fn empty_map(w: usize, h: usize) -> EdgeMap {
    EdgeMap {
        width: w,
        height: h,
        points: Vec::new(),
        index: vec![NO_POINT; w * h],
    }
}

/// Bands of the suppression per thread of the compute pool: bands are searched on the pool's
/// threads at once, each computing its own gradient rows (two more than it suppresses), and
/// put together in row order, so the points, their order and the index are those of a single
/// pass to the bit. A few per thread let a thread that frees up take a share of what is left;
/// on a pool of one thread the image is one band, the single pass itself.
const BANDS_PER_THREAD: usize = 4;
/// The fewest rows a band is given: below it the two extra gradient rows cost more than a
/// second thread gains.
const MIN_BAND_ROWS: usize = 32;

/// Rows per band of an image `height` rows high on the current pool.
fn band_rows(height: usize) -> usize {
    let threads = rayon::current_num_threads();
    if threads <= 1 {
        return height;
    }
    height
        .div_ceil(threads * BANDS_PER_THREAD)
        .max(MIN_BAND_ROWS)
}

/// The image's map from its bands' points (in row order) and the index their bands filled
/// with band-local numbers: each band's numbers are moved on by the points before it.
fn join_bands(w: usize, h: usize, mut index: Vec<u32>, bands: Vec<Vec<EdgePoint>>) -> EdgeMap {
    let total: usize = bands.iter().map(Vec::len).sum();
    let mut bands = bands.into_iter();
    // The first band's points are the start of the image's, where they lie: a single band,
    // one thread's pass, is not copied at all.
    let mut points = bands.next().unwrap_or_default();
    points.reserve_exact(total - points.len());
    for band in bands {
        let offset = points.len() as u32;
        for p in &band {
            index[pixel_of(p, w)] += offset;
        }
        points.extend(band);
    }
    EdgeMap {
        width: w,
        height: h,
        points,
        index,
    }
}

/// Step 1 and 2: the local maxima of the gradient magnitude of at least `low_gradient`.
pub fn non_maximum_suppression(gradient: &Gradient, low_gradient: f32) -> EdgeMap {
    let (w, h) = (gradient.width, gradient.height);
    if w < 3 || h < 3 {
        return empty_map(w, h);
    }
    let m = &gradient.magnitude;
    // A noiseless flat image has magnitude 0 everywhere: never an edge, whatever the threshold.
    let low = low_gradient.max(f32::MIN_POSITIVE);
    let mut index = vec![NO_POINT; w * h];
    let mut band = Band {
        width: w,
        height: h,
        first_row: 0,
        points: Vec::new(),
        index: &mut index,
    };
    for y in 1..h - 1 {
        let r = |k: usize| &m[k * w..(k + 1) * w];
        let g = y * w..(y + 1) * w;
        suppress_row(
            &mut band,
            y,
            r(y - 1),
            r(y),
            r(y + 1),
            &gradient.gu[g.clone()],
            &gradient.gv[g],
            low,
        );
    }
    let points = band.points;
    join_bands(w, h, index, vec![points])
}

/// [`gradient::gradient`] and [`non_maximum_suppression`] in one pass over the smoothed image,
/// keeping three rows of gradient instead of three image-sized arrays: the same points, with
/// far less memory traffic.
pub fn edge_points(smoothed: &[f32], width: usize, height: usize, low_gradient: f32) -> EdgeMap {
    edge_points_and_background(smoothed, width, height, low_gradient).0
}

/// [`edge_points`], and [`gradient::background_magnitude`] of the same image from the
/// magnitudes the pass computes anyway (the same sample, so the same value to the bit),
/// instead of a second pass of its own over the image. Bands of rows run on the compute
/// pool at once ([`band_rows`]).
pub fn edge_points_and_background(
    smoothed: &[f32],
    width: usize,
    height: usize,
    low_gradient: f32,
) -> (EdgeMap, f32) {
    use rayon::prelude::*;
    let (w, h) = (width, height);
    if w < 3 || h < 3 || smoothed.len() != w * h {
        return (empty_map(w, h), 0.0);
    }
    let low = low_gradient.max(f32::MIN_POSITIVE);
    let mut index = vec![NO_POINT; w * h];
    let rows_per_band = band_rows(h);
    let bands: Vec<(Vec<EdgePoint>, gradient::BackgroundHistogram)> = index
        .par_chunks_mut(rows_per_band * w)
        .enumerate()
        .map(|(b, rows)| {
            let first_row = b * rows_per_band;
            let rows_here = rows.len() / w;
            let mut band = Band {
                width: w,
                height: h,
                first_row,
                points: Vec::new(),
                index: rows,
            };
            let background =
                suppress_band(smoothed, &mut band, first_row..first_row + rows_here, low);
            (band.points, background)
        })
        .collect();
    let mut background = gradient::BackgroundHistogram::new();
    let mut points = Vec::with_capacity(bands.len());
    for (band_points, band_background) in bands {
        background.merge(&band_background);
        points.push(band_points);
    }
    (join_bands(w, h, index, points), background.median())
}

/// The fused gradient and suppression of the rows `rows` of the image (those inside its
/// one-pixel frame), into `band`; the background's sample of those rows.
fn suppress_band(
    smoothed: &[f32],
    band: &mut Band,
    rows: std::ops::Range<usize>,
    low: f32,
) -> gradient::BackgroundHistogram {
    let (w, h) = (band.width, band.height);
    let mut background = gradient::BackgroundHistogram::new();
    let (first, last) = (rows.start.max(1), rows.end.min(h - 1));
    if first >= last {
        return background;
    }
    // Ring of three rows: gradient row y lives in slot y % 3; row 0 and h-1 stay zero.
    let mut gu = vec![0.0f32; 3 * w];
    let mut gv = vec![0.0f32; 3 * w];
    let mut mag = vec![0.0f32; 3 * w];
    let fill = |y: usize, gu: &mut [f32], gv: &mut [f32], mag: &mut [f32]| {
        let s = (y % 3) * w..(y % 3 + 1) * w;
        if y == 0 || y == h - 1 {
            gu[s.clone()].fill(0.0);
            gv[s.clone()].fill(0.0);
            mag[s].fill(0.0);
        } else {
            gradient::gradient_row(
                smoothed,
                w,
                y,
                &mut gu[s.clone()],
                &mut gv[s.clone()],
                &mut mag[s],
            );
        }
    };
    fill(first - 1, &mut gu, &mut gv, &mut mag);
    fill(first, &mut gu, &mut gv, &mut mag);
    for y in first..last {
        fill(y + 1, &mut gu, &mut gv, &mut mag);
        let slot = |k: usize| (k % 3) * w..(k % 3 + 1) * w;
        if gradient::BackgroundHistogram::samples_row(y) {
            background.add_row(&mag[slot(y)]);
        }
        suppress_row(
            band,
            y,
            &mag[slot(y - 1)],
            &mag[slot(y)],
            &mag[slot(y + 1)],
            &gu[slot(y)],
            &gv[slot(y)],
            low,
        );
    }
    background
}

/// Step 3: keeps the points connected (8-connectivity) to a point of at least `high_gradient`.
/// Consumes the map: the kept points are compacted in place and its index updated, so no
/// second image-sized buffer is needed.
///
/// The flood marks a kept point in its own index entry (the top bit) and walks pixels, not
/// points: a neighbour's pixel is known from the offset it was found at, so the flood reads
/// only the index (three rows of it about the current pixel, in cache) and never the 28-byte
/// points, and needs no array of flags beside it. A pixel's eight neighbours are read at fixed
/// offsets when every point lies off the image's border, as suppression leaves them; a map
/// built otherwise is flooded through the clamped neighbourhood.
pub fn hysteresis(mut map: EdgeMap, high_gradient: f32) -> EdgeMap {
    const KEPT: u32 = 1 << 31;
    let (w, h) = (map.width, map.height);
    // Point numbers must leave the top bit free (an index of 2³¹ points is 8 GiB of them).
    assert!(map.points.len() < KEPT as usize, "too many edge points");
    let interior = map.points.iter().all(|p| {
        let (x, y) = (p.x as usize, p.y as usize);
        x >= 1 && y >= 1 && x + 1 < w && y + 1 < h
    });
    let mut stack: Vec<usize> = Vec::new();
    for i in 0..map.points.len() {
        let p = &map.points[i];
        let seed = pixel_of(p, w);
        if p.magnitude < high_gradient || map.index[seed] & KEPT != 0 {
            continue;
        }
        map.index[seed] |= KEPT;
        stack.push(seed);
        while let Some(at) = stack.pop() {
            let visit = |k: usize| {
                let entry = map.index[k];
                if entry != NO_POINT && entry & KEPT == 0 {
                    map.index[k] = entry | KEPT;
                    stack.push(k);
                }
            };
            for_each_neighbour_pixel(at, (w, h), interior, visit);
        }
    }
    let mut kept = 0usize;
    for i in 0..map.points.len() {
        let p = map.points[i];
        let pixel = pixel_of(&p, w);
        // Written whether kept or not (a dropped point is overwritten by the next kept one):
        // no branch on a flag that is set for four points in ten, in no pattern.
        let keep_it = map.index[pixel] & KEPT != 0;
        map.points[kept] = p;
        map.index[pixel] = if keep_it { kept as u32 } else { NO_POINT };
        kept += usize::from(keep_it);
    }
    map.points.truncate(kept);
    // The points grew by doubling: up to half their capacity is slack, which on a noisy
    // image is the largest buffer of the whole extraction.
    map.points.shrink_to_fit();
    map
}

/// Calls `visit` with each of the eight pixels about pixel `at` of a `w` × `h` image that lie
/// in the image, in row-major order: at fixed offsets when the caller knows `at` is
/// `off_border` (no clamping, no division), else through the clamped neighbourhood.
#[inline(always)]
fn for_each_neighbour_pixel(
    at: usize,
    (w, h): (usize, usize),
    off_border: bool,
    mut visit: impl FnMut(usize),
) {
    if off_border {
        for k in [
            at - w - 1,
            at - w,
            at - w + 1,
            at - 1,
            at + 1,
            at + w - 1,
            at + w,
            at + w + 1,
        ] {
            visit(k);
        }
    } else {
        let (x, y) = (at % w, at / w);
        for ny in y.saturating_sub(1)..=(y + 1).min(h - 1) {
            for nx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
                if (nx, ny) != (x, y) {
                    visit(ny * w + nx);
                }
            }
        }
    }
}

/// Row-major index of a point's pixel.
#[inline]
pub fn pixel_of(p: &EdgePoint, width: usize) -> usize {
    p.y as usize * width + p.x as usize
}

#[cfg(test)]
mod tests {
    use super::super::gradient::{background_magnitude, gradient, smooth, BackgroundHistogram};
    use super::super::GreyImage;
    use super::*;

    #[test]
    fn parabola_peak() {
        assert_eq!(subpixel_offset(1.0, 2.0, 1.0), 0.0);
        assert!((subpixel_offset(1.0, 2.0, 1.5) - (0.5 * -0.5 / -1.5)).abs() < 1e-6);
        assert_eq!(subpixel_offset(1.0, 1.0, 1.0), 0.0);
        assert_eq!(
            subpixel_offset(0.0, 1.0, 1.0),
            0.5,
            "a plateau peaks half-way"
        );
        assert_eq!(subpixel_offset(0.0, 1.0, 5.0), 0.0, "not a peak");
    }

    /// A vertical step edge at u = `edge` (sub-pixel), area-sampled, dark left, bright right.
    fn step(width: usize, height: usize, edge: f32) -> GreyImage {
        let px = (0..width * height)
            .map(|i| {
                let u = (i % width) as f32;
                let covered = (u + 0.5 - edge).clamp(0.0, 1.0);
                20.0 + 100.0 * covered
            })
            .collect();
        GreyImage::new(width as u32, height as u32, px).unwrap()
    }

    #[test]
    fn a_step_gives_one_thin_line_of_points_at_the_edge() {
        for edge in [10.0f32, 10.25, 10.5, 10.8] {
            let img = step(24, 12, edge);
            let g = gradient(&smooth(&img, 1.0), 24, 12);
            let map = non_maximum_suppression(&g, 2.0);
            let fused = edge_points(&smooth(&img, 1.0), 24, 12, 2.0);
            assert_eq!(fused, map, "one pass gives the same points");
            // Rows 1..=10 each hold exactly one point, within 0.1 px of the edge.
            assert_eq!(map.points.len(), 10, "edge at {edge}");
            for p in &map.points {
                assert!((p.u - edge).abs() < 0.1, "edge {edge}: point at {}", p.u);
                assert!(p.gu > 0.0 && p.gv.abs() < 1e-3);
            }
        }
    }

    #[test]
    fn no_point_is_located_against_the_zero_frame() {
        // An edge 0.2 px past the first gradient column: its magnitude peaks at x = 1,
        // whose left neighbour is the frame's made-up zero.
        let img = step(24, 12, 1.2);
        let g = gradient(&smooth(&img, 0.0), 24, 12);
        assert!(g.magnitude[5 * 24 + 1] > g.magnitude[5 * 24 + 2]);
        let map = non_maximum_suppression(&g, 2.0);
        assert!(map.points.iter().all(|p| p.x != 1), "{:?}", map.points);
        assert_eq!(map, edge_points(&smooth(&img, 0.0), 24, 12, 2.0));
        // The same edge a pixel further in is found, in every row but the frame's.
        let img = step(24, 12, 2.2);
        let map = non_maximum_suppression(&gradient(&smooth(&img, 0.0), 24, 12), 2.0);
        assert_eq!(map.points.len(), 10);
        assert!(map.points.iter().all(|p| (p.u - 2.2).abs() < 0.1));
    }

    /// The suppression as first written, pixel by pixel with an early return per test: the
    /// reference the block-wise mask of [`suppress_row`] must equal point for point.
    fn reference_suppression(g: &Gradient, low: f32) -> EdgeMap {
        let (w, h) = (g.width, g.height);
        let mut map = empty_map(w, h);
        let low = low.max(f32::MIN_POSITIVE);
        for y in 1..h.saturating_sub(1) {
            for x in 1..w.saturating_sub(1) {
                let m = |x: usize, y: usize| g.magnitude[y * w + x];
                let centre = m(x, y);
                if centre < low {
                    continue;
                }
                let along_u = g.gu[y * w + x].abs() >= g.gv[y * w + x].abs();
                let beside_frame = if along_u {
                    x == 1 || x + 2 == w
                } else {
                    y == 1 || y + 2 == h
                };
                if beside_frame {
                    continue;
                }
                let (before, after) = if along_u {
                    (m(x - 1, y), m(x + 1, y))
                } else {
                    (m(x, y - 1), m(x, y + 1))
                };
                let is_max =
                    (centre > before && centre >= after) || (centre >= before && centre > after);
                if !is_max {
                    continue;
                }
                let s = subpixel_offset(before, centre, after);
                let (u, v) = if along_u {
                    (x as f32 + s, y as f32)
                } else {
                    (x as f32, y as f32 + s)
                };
                map.index[y * w + x] = map.points.len() as u32;
                map.points.push(EdgePoint {
                    x: x as u32,
                    y: y as u32,
                    u,
                    v,
                    gu: g.gu[y * w + x],
                    gv: g.gv[y * w + x],
                    magnitude: centre,
                });
            }
        }
        map
    }

    /// Hysteresis as first written, every neighbour read through the clamped ranges: the
    /// reference for the fixed offsets of [`hysteresis`].
    fn reference_hysteresis(mut map: EdgeMap, high: f32) -> EdgeMap {
        let (w, h) = (map.width, map.height);
        let mut keep = vec![false; map.points.len()];
        let mut stack = Vec::new();
        for i in 0..map.points.len() {
            if map.points[i].magnitude < high || keep[i] {
                continue;
            }
            keep[i] = true;
            stack.push(i);
            while let Some(j) = stack.pop() {
                let (x, y) = (map.points[j].x as usize, map.points[j].y as usize);
                for ny in y.saturating_sub(1)..=(y + 1).min(h - 1) {
                    for nx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
                        if let Some(k) = map.at(nx, ny) {
                            if !keep[k as usize] {
                                keep[k as usize] = true;
                                stack.push(k as usize);
                            }
                        }
                    }
                }
            }
        }
        let kept: Vec<EdgePoint> = map
            .points
            .iter()
            .zip(&keep)
            .filter(|(_, &k)| k)
            .map(|(p, _)| *p)
            .collect();
        map.index.fill(NO_POINT);
        for (i, p) in kept.iter().enumerate() {
            map.index[pixel_of(p, w)] = i as u32;
        }
        map.points = kept;
        map
    }

    #[test]
    fn the_block_wise_suppression_and_hysteresis_find_the_reference_points_exactly() {
        // Noise quantised to whole grey levels (so that neighbours tie and plateaus occur),
        // widths on and off the block size, heights on and off the bands' (the fused pass's
        // bands put together: a last band of one row, of two, several bands), thresholds from
        // everything to almost nothing.
        let mut rng = trinocular_synth::Rng::new(0x2545_f491_4f6c_dd1d);
        let mut next = move || rng.next_u64();
        let mut selective = false;
        let mut several_bands = false;
        // The fused pass is one band on a pool of one thread, and bands put together on more.
        let pools: Vec<rayon::ThreadPool> = [1, 2, 3]
            .into_iter()
            .map(|threads| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("pool")
            })
            .collect();
        for (w, h) in [
            (3, 3),
            (5, 4),
            (17, 9),
            (18, 18),
            (33, 20),
            (64, 31),
            (101, 47),
            (40, 65),
            (29, 66),
            (23, 130),
            (37, 200),
        ] {
            for smoothing in [0.0, 0.7] {
                let px = (0..w * h).map(|_| (next() % 24) as f32).collect();
                let img = GreyImage::new(w as u32, h as u32, px).unwrap();
                let smoothed = smooth(&img, smoothing);
                let g = gradient(&smoothed, w, h);
                for low in [0.0, 2.0, 6.0, 40.0] {
                    let reference = reference_suppression(&g, low);
                    assert_eq!(
                        non_maximum_suppression(&g, low),
                        reference,
                        "{w}x{h} low {low}"
                    );
                    let (fused, background) = edge_points_and_background(&smoothed, w, h, low);
                    assert_eq!(fused, reference, "fused, {w}x{h}");
                    for (threads, pool) in (1..).zip(&pools) {
                        let bands = pool.install(|| h.div_ceil(band_rows(h)));
                        let (banded, banded_background) =
                            pool.install(|| edge_points_and_background(&smoothed, w, h, low));
                        let at = format!("{w}x{h}, {threads} threads, {bands} bands");
                        assert_eq!(banded, reference, "{at}");
                        assert_eq!(banded_background.to_bits(), background.to_bits(), "{at}");
                        several_bands |= bands > 2;
                    }
                    // The background's median of the full gradient's magnitudes, every
                    // fourth pixel of every fourth row from (1, 1).
                    let mut sample = BackgroundHistogram::new();
                    for y in (1..h - 1).step_by(4) {
                        for x in (1..w - 1).step_by(4) {
                            sample.add(g.magnitude[y * w + x]);
                        }
                    }
                    let expected = sample.median().to_bits();
                    assert_eq!(background.to_bits(), expected, "in the pass, {w}x{h}");
                    assert_eq!(
                        background_magnitude(&smoothed, w, h).to_bits(),
                        expected,
                        "on its own, {w}x{h}"
                    );
                    if w > 20 && low == 2.0 {
                        assert!(reference.points.len() > w, "the noise gives points");
                    }
                    // Seeds from none to all: above every point, the points' 90th percentile,
                    // `low`.
                    let mut magnitudes: Vec<f32> =
                        reference.points.iter().map(|p| p.magnitude).collect();
                    magnitudes.sort_by(f32::total_cmp);
                    let p90 = magnitudes.get(magnitudes.len() * 9 / 10).copied();
                    for high in [Some(f32::MAX), p90, Some(low)].into_iter().flatten() {
                        let kept = reference_hysteresis(reference.clone(), high);
                        assert_eq!(hysteresis(reference.clone(), high), kept, "{w}x{h} {high}");
                        selective |=
                            !kept.points.is_empty() && kept.points.len() < reference.points.len();
                    }
                }
            }
        }
        assert!(selective, "some case keeps some points and drops others");
        assert!(
            several_bands,
            "some image is searched in three bands or more"
        );
    }

    /// A map with points on the image's border (no suppression makes one, a caller could):
    /// flooded through the clamped neighbourhood, it keeps what the reference keeps.
    #[test]
    fn hysteresis_of_points_on_the_border_is_the_references() {
        let mut rng = trinocular_synth::Rng::new(0x2545_f491_4f6c_dd1d);
        let mut on_border = 0;
        for (w, h) in [(1, 1), (1, 7), (7, 1), (2, 2), (5, 4), (16, 9)] {
            for _ in 0..40 {
                let mut map = EdgeMap {
                    width: w,
                    height: h,
                    points: Vec::new(),
                    index: vec![NO_POINT; w * h],
                };
                for y in 0..h {
                    for x in 0..w {
                        if rng.below(3) != 0 {
                            map.index[y * w + x] = map.points.len() as u32;
                            on_border += usize::from(x == 0 || y == 0 || x + 1 == w || y + 1 == h);
                            map.points.push(EdgePoint {
                                x: x as u32,
                                y: y as u32,
                                u: x as f32,
                                v: y as f32,
                                gu: 1.0,
                                gv: 0.0,
                                magnitude: rng.below(10) as f32,
                            });
                        }
                    }
                }
                for high in [0.0, 8.0, 9.0, 10.0] {
                    assert_eq!(
                        hysteresis(map.clone(), high),
                        reference_hysteresis(map.clone(), high),
                        "{w}x{h} {high}"
                    );
                }
            }
        }
        assert!(on_border > 100);
    }

    #[test]
    fn hysteresis_keeps_weak_points_connected_to_strong_ones_only() {
        // Row 2: a strong point at x=2 with weak neighbours continuing to x=5; row 6: weak only.
        let (w, h) = (10, 9);
        let mut m = vec![0.0f32; w * h];
        for (x, val) in [(2, 10.0), (3, 3.0), (4, 3.0), (5, 3.0)] {
            m[2 * w + x] = val;
        }
        for x in 2..6 {
            m[6 * w + x] = 3.0;
        }
        let g = Gradient {
            width: w,
            height: h,
            gu: vec![0.0; w * h],
            gv: m.clone(),
            magnitude: m,
        };
        let all = non_maximum_suppression(&g, 2.0);
        assert_eq!(all.points.len(), 8);
        let kept = hysteresis(all.clone(), 8.0);
        assert_eq!(kept.points.len(), 4);
        assert!(kept.points.iter().all(|p| p.v == 2.0));
        assert_eq!(kept.at(3, 2), Some(1));
        assert_eq!(kept.at(3, 6), None);
    }
}
