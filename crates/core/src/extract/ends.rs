//! Where a segment really ends.
//!
//! A chain stops short of the end of its edge: near a corner or a junction the smoothed
//! gradient bends towards the other edge and non-maximum suppression gives up a pixel or two
//! early. But along a straight step edge that stops, the Gaussian-smoothed gradient across it
//! falls to exactly half its plateau value at the end, whatever σ (half the kernel still sees
//! the edge). So each free end slides along the segment's line to where the gradient
//! component across the line crosses half of its median along the segment. Taking the
//! component across the line ignores the gradient of a perpendicular edge meeting there. Ends
//! only move outwards: where a chain stopped with the gradient already below half, the edge
//! goes on with a weaker contrast and the chain end is as good a guess as any.

use nalgebra::{Point2, Vector2};

use super::gradient::sobel;

/// How far an end may move, pixels: a chain can stop up to ~5 px short of a sharp corner whose
/// pixels the other side's chain took.
pub const MAX_SLIDE_PX: f64 = 6.0;
/// Sampling step along the line, pixels; the crossing is interpolated between samples.
const STEP_PX: f64 = 0.5;
/// Samples of the plateau, at most: a median of 8 is steady enough (recall unchanged from 16),
/// and long segments would otherwise cost a sample per pixel.
const PLATEAU_SAMPLES: usize = 8;
/// A free end this close to the image frame (along the segment) is moved onto it, pixels:
/// the gradient is zero on the one-pixel border, so chains stop 1.5 px short of the frame.
const FRAME_SNAP_PX: f64 = 2.5;
/// Samples closer than this to an end do not count towards the plateau, pixels.
const PLATEAU_MARGIN_PX: f64 = 3.0;

/// The smoothed image the gradient is computed from, on demand: a few hundred samples per
/// image do not justify keeping image-sized gradient arrays.
#[derive(Debug, Clone, Copy)]
pub struct Smoothed<'a> {
    pub pixels: &'a [f32],
    pub width: usize,
    pub height: usize,
}

/// Gradient at a sub-pixel position (bilinear), `None` outside the image's interior.
fn sample(g: &Smoothed, p: Point2<f64>) -> Option<Vector2<f64>> {
    let (x, y) = (p.x.floor(), p.y.floor());
    if !(x >= 1.0 && y >= 1.0 && x + 2.0 < g.width as f64 && y + 2.0 < g.height as f64) {
        return None;
    }
    let (fx, fy) = (p.x - x, p.y - y);
    let (x, y) = (x as usize, y as usize);
    // The four pixels' gradients from the four rows they share (all inside the frame, where
    // `gradient_at` would compute the same).
    let row = |k: usize| &g.pixels[(y + k - 1) * g.width..(y + k) * g.width];
    let rows = [row(0), row(1), row(2), row(3)];
    let at = |dx: usize, dy: usize| {
        let (u, v) = sobel(rows[dy], rows[dy + 1], rows[dy + 2], x + dx);
        Vector2::new(f64::from(u), f64::from(v))
    };
    let top = at(0, 0) * (1.0 - fx) + at(1, 0) * fx;
    let bottom = at(0, 1) * (1.0 - fx) + at(1, 1) * fx;
    Some(top * (1.0 - fy) + bottom * fy)
}

/// The gradient across the segment `start`→`end` at position `t` (pixels from `start`),
/// positive when it agrees with the segment's contrast orientation (DESIGN §1: gradient along
/// `(dv, −du)`). `to_image` maps the segment's (undistorted) frame to image pixels.
fn across(
    g: &Smoothed,
    to_image: &impl Fn(Point2<f64>) -> Point2<f64>,
    start: Point2<f64>,
    dir: Vector2<f64>,
    t: f64,
) -> Option<f64> {
    let normal = Vector2::new(dir.y, -dir.x);
    sample(g, to_image(start + dir * t)).map(|v| v.dot(&normal))
}

/// Moves the free ends of the oriented segment `start`→`end` (flags say which ends are free)
/// outwards to where the gradient across it falls to half its median; returns the new ends.
/// An end stays put when the gradient there is already below half, or does not fall to half
/// within [`MAX_SLIDE_PX`], or the walk leaves the image.
/// The segment lives in undistorted pixels; `to_image` maps them to the gradient's pixels
/// (identity without lens distortion), so the ends stay on the segment's line.
pub fn refine_ends(
    g: &Smoothed,
    to_image: impl Fn(Point2<f64>) -> Point2<f64>,
    start: Point2<f64>,
    end: Point2<f64>,
    free: (bool, bool),
) -> (Point2<f64>, Point2<f64>) {
    let len = (end - start).norm();
    if len < 1e-9 || !(free.0 || free.1) {
        return (start, end);
    }
    let dir = (end - start) / len;
    // Plateau: the median over the interior of the segment.
    let margin = PLATEAU_MARGIN_PX.min(len / 2.0);
    let samples = ((len - 2.0 * margin).floor() as usize + 1).min(PLATEAU_SAMPLES);
    let spacing = (len - 2.0 * margin) / (samples.max(2) - 1) as f64;
    let mut values: Vec<f64> = (0..samples)
        .filter_map(|k| across(g, &to_image, start, dir, margin + spacing * k as f64))
        .collect();
    if values.is_empty() {
        return (start, end);
    }
    values.sort_by(f64::total_cmp);
    let half = 0.5 * values[values.len() / 2];
    if half.is_nan() || half <= 0.0 {
        return (start, end);
    }
    // Position (from `start`, along `dir`) where the profile crosses `half` near `t0`, moving
    // outwards with `outward` = +1 (beyond the end) or −1 (beyond the start).
    let crossing = |t0: f64, outward: f64| -> Option<f64> {
        let value = |t: f64| across(g, &to_image, start, dir, t);
        let at = value(t0)?;
        // Ends only grow: a chain that stops where the gradient is already below half ended
        // at a change of contrast along a longer edge (a T-junction seen from the weaker
        // side), and walking back would cut the edge there.
        if at < half {
            return None;
        }
        let step = outward * STEP_PX;
        let (mut t_prev, mut v_prev) = (t0, at);
        let mut moved = 0.0;
        while moved < MAX_SLIDE_PX {
            let t_next = t_prev + step;
            let v_next = value(t_next)?;
            if (v_prev >= half) != (v_next >= half) {
                let f = (v_prev - half) / (v_prev - v_next);
                return Some(t_prev + (t_next - t_prev) * f);
            }
            (t_prev, v_prev) = (t_next, v_next);
            moved += STEP_PX;
        }
        None
    };
    let mut t_start = if free.0 { crossing(0.0, -1.0) } else { None }.unwrap_or(0.0);
    let mut t_end = if free.1 { crossing(len, 1.0) } else { None }.unwrap_or(len);
    // An edge that runs out of the image ends at the frame, not where the gradient (zero on
    // the one-pixel border) stops showing it.
    let frame = |t: f64, outward: f64| -> f64 {
        let p = to_image(start + dir * t);
        let d = to_image(start + dir * (t + outward)) - p;
        let (w, h) = (g.width as f64 - 0.5, g.height as f64 - 0.5);
        // The first border the line meets going outwards, if it is near.
        let mut nearest = f64::INFINITY;
        for (coord, delta, lo, hi) in [(p.x, d.x, -0.5, w), (p.y, d.y, -0.5, h)] {
            let to_border = if delta < -0.3 {
                (coord - lo) / -delta
            } else if delta > 0.3 {
                (hi - coord) / delta
            } else {
                continue;
            };
            nearest = nearest.min(to_border);
        }
        if (0.0..=FRAME_SNAP_PX).contains(&nearest) {
            t + outward * nearest
        } else {
            t
        }
    };
    if free.0 {
        t_start = frame(t_start, -1.0);
    }
    if free.1 {
        t_end = frame(t_end, 1.0);
    }
    if t_end - t_start < 1.0 {
        return (start, end);
    }
    (start + dir * t_start, start + dir * t_end)
}

#[cfg(test)]
mod tests {
    use super::super::gradient::smooth;
    use super::super::GreyImage;
    use super::*;

    #[test]
    fn a_sample_is_the_bilinear_mix_of_the_four_pixels_gradients_to_the_bit() {
        use super::super::gradient::gradient_at;
        let (w, h) = (23usize, 17usize);
        let mut rng = trinocular_synth::Rng::new(0x9e37_79b9_7f4a_7c15);
        let mut next = move || rng.next_u64();
        let pixels: Vec<f32> = (0..w * h).map(|_| (next() % 200) as f32 * 0.37).collect();
        let g = Smoothed {
            pixels: &pixels,
            width: w,
            height: h,
        };
        let mut inside = 0;
        for _ in 0..500 {
            let p = Point2::new(
                (next() % 10_000) as f64 / 10_000.0 * w as f64,
                (next() % 10_000) as f64 / 10_000.0 * h as f64,
            );
            let Some(got) = sample(&g, p) else {
                continue;
            };
            inside += 1;
            let (x, y) = (p.x.floor(), p.y.floor());
            let (fx, fy) = (p.x - x, p.y - y);
            let at = |dx: usize, dy: usize| {
                let (u, v) = gradient_at(&pixels, w, h, x as usize + dx, y as usize + dy);
                Vector2::new(f64::from(u), f64::from(v))
            };
            let top = at(0, 0) * (1.0 - fx) + at(1, 0) * fx;
            let bottom = at(0, 1) * (1.0 - fx) + at(1, 1) * fx;
            assert_eq!(got, top * (1.0 - fy) + bottom * fy, "at {p}");
        }
        assert!(inside > 300, "{inside} samples inside");
    }

    /// A bright rectangle [10.3, 30.6] x [8.5, 40.2] (area-sampled) on a dark background.
    fn rectangle() -> GreyImage {
        let (w, h) = (48usize, 52usize);
        let cover = |lo: f64, hi: f64, c: f64| ((c + 0.5).min(hi) - (c - 0.5).max(lo)).max(0.0);
        let px = (0..w * h)
            .map(|i| {
                let (u, v) = ((i % w) as f64, (i / w) as f64);
                (30.0 + 150.0 * cover(10.3, 30.6, u) * cover(8.5, 40.2, v)) as f32
            })
            .collect();
        GreyImage::new(w as u32, h as u32, px).unwrap()
    }

    #[test]
    fn ends_slide_to_the_corners() {
        let img = rectangle();
        let pixels = smooth(&img, 1.0);
        let g = Smoothed {
            pixels: &pixels,
            width: 48,
            height: 52,
        };
        // The left side: bright on the right of the image, so on the left of a walker going
        // down the screen.
        let id = |p: Point2<f64>| p;
        let (start, end) = (Point2::new(10.3, 11.0), Point2::new(10.3, 38.0));
        let (s, e) = refine_ends(&g, id, start, end, (true, true));
        assert!((s.y - 8.5).abs() < 0.25, "start {s:?}");
        assert!((e.y - 40.2).abs() < 0.25, "end {e:?}");
        // Ends already beyond the edge's end stay (ends only grow).
        let long = (Point2::new(10.3, 7.0), Point2::new(10.3, 42.0));
        assert_eq!(refine_ends(&g, id, long.0, long.1, (true, true)), long);
        // Ends that are not free stay, and a segment walked against its contrast has no
        // plateau to measure.
        assert_eq!(
            refine_ends(&g, id, start, end, (false, false)),
            (start, end)
        );
        assert_eq!(refine_ends(&g, id, end, start, (true, true)), (end, start));
    }
}
