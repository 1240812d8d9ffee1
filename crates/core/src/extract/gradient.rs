//! Smoothing and gradient: a separable Gaussian, then the Sobel operator scaled to grey levels
//! per pixel.
//!
//! The Gaussian sets the scale at which edges are seen (and how much sensor noise survives);
//! Sobel adds a little smoothing across the derivative. Borders replicate the edge pixels, and
//! the one-pixel frame of the gradient is zero: nothing there has both neighbours the
//! non-maximum suppression needs.

use super::GreyImage;

/// Kernel half-width in standard deviations: beyond 3σ the weights are below 1.1%.
const KERNEL_SIGMAS: f64 = 3.0;

/// The image gradient, row-major like the image.
#[derive(Debug, Clone, PartialEq)]
pub struct Gradient {
    pub width: usize,
    pub height: usize,
    /// ∂I/∂u and ∂I/∂v, grey levels per pixel.
    pub gu: Vec<f32>,
    pub gv: Vec<f32>,
    /// |∇I|, grey levels per pixel.
    pub magnitude: Vec<f32>,
}

/// Normalised Gaussian weights for `sigma_px`, of odd length; `[1.0]` when `sigma_px` ≤ 0.
pub fn gaussian_kernel(sigma_px: f64) -> Vec<f32> {
    if sigma_px.is_nan() || sigma_px <= 0.0 {
        return vec![1.0];
    }
    let radius = (KERNEL_SIGMAS * sigma_px).ceil() as i64;
    let weights: Vec<f64> = (-radius..=radius)
        .map(|i| (-((i * i) as f64) / (2.0 * sigma_px * sigma_px)).exp())
        .collect();
    let sum: f64 = weights.iter().sum();
    weights.iter().map(|w| (w / sum) as f32).collect()
}

/// [`smooth`], borrowing the image itself where the kernel is a single tap (no smoothing, as
/// the rooms' renders choose): the same pixels without a copy of the whole image.
pub fn smoothed(image: &GreyImage, sigma_px: f64) -> std::borrow::Cow<'_, [f32]> {
    if gaussian_kernel(sigma_px).len() == 1 {
        std::borrow::Cow::Borrowed(image.pixels())
    } else {
        std::borrow::Cow::Owned(smooth(image, sigma_px))
    }
}

/// Separable Gaussian blur with replicated borders.
pub fn smooth(image: &GreyImage, sigma_px: f64) -> Vec<f32> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 was just detected on the running CPU.
        return unsafe { smooth_avx2(image, sigma_px) };
    }
    smooth_body(image, sigma_px)
}

/// [`smooth_body`] compiled for AVX2: the same operations in the same order (no fused
/// multiply-add), so the same bits, eight lanes at a time instead of four.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn smooth_avx2(image: &GreyImage, sigma_px: f64) -> Vec<f32> {
    smooth_body(image, sigma_px)
}

#[inline(always)]
fn smooth_body(image: &GreyImage, sigma_px: f64) -> Vec<f32> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let kernel = gaussian_kernel(sigma_px);
    if kernel.len() == 1 || w == 0 || h == 0 {
        return image.pixels().to_vec();
    }
    let r = kernel.len() / 2;
    // Rows: padded copy of each row so the inner loop has no bounds logic and vectorises.
    let mut horizontal = vec![0.0f32; w * h];
    let mut padded = vec![0.0f32; w + 2 * r];
    for (src, dst) in image
        .pixels()
        .chunks_exact(w)
        .zip(horizontal.chunks_exact_mut(w))
    {
        padded[..r].fill(src[0]);
        padded[r..r + w].copy_from_slice(src);
        padded[r + w..].fill(src[w - 1]);
        for (k, &weight) in kernel.iter().enumerate() {
            for (d, &s) in dst.iter_mut().zip(&padded[k..k + w]) {
                *d += weight * s;
            }
        }
    }
    // Columns: each output row is a weighted sum of whole input rows.
    let mut out = vec![0.0f32; w * h];
    for (y, dst) in out.chunks_exact_mut(w).enumerate() {
        for (k, &weight) in kernel.iter().enumerate() {
            let sy = (y + k).saturating_sub(r).min(h - 1);
            let src = &horizontal[sy * w..(sy + 1) * w];
            for (d, &s) in dst.iter_mut().zip(src) {
                *d += weight * s;
            }
        }
    }
    out
}

/// The Sobel gradient of row `y` (1 ≤ y < height − 1) of a `width`-wide image into `gu`, `gv`,
/// `magnitude` (each `width` long; the first and last entries are zero).
#[inline]
pub fn gradient_row(
    smoothed: &[f32],
    width: usize,
    y: usize,
    gu: &mut [f32],
    gv: &mut [f32],
    magnitude: &mut [f32],
) {
    let above = &smoothed[(y - 1) * width..y * width];
    let row = &smoothed[y * width..(y + 1) * width];
    let below = &smoothed[(y + 1) * width..(y + 2) * width];
    for x in 1..width - 1 {
        let (u, v) = sobel(above, row, below, x);
        gu[x] = u;
        gv[x] = v;
        magnitude[x] = (u * u + v * v).sqrt();
    }
    for out in [gu, gv, magnitude] {
        out[0] = 0.0;
        out[width - 1] = 0.0;
    }
}

/// The Sobel gradient at column `x` (1 ≤ x < width − 1) of the row `row` between `above` and
/// `below`, divided by 8. Every gradient of the extraction is this arithmetic in this order,
/// so a magnitude computed twice is the same to the bit.
#[inline(always)]
pub(crate) fn sobel(above: &[f32], row: &[f32], below: &[f32], x: usize) -> (f32, f32) {
    let u = (above[x + 1] - above[x - 1])
        + 2.0 * (row[x + 1] - row[x - 1])
        + (below[x + 1] - below[x - 1]);
    let v =
        (below[x - 1] - above[x - 1]) + 2.0 * (below[x] - above[x]) + (below[x + 1] - above[x + 1]);
    (u * 0.125, v * 0.125)
}

/// Sobel gradient of a `width` x `height` image, divided by 8 so a ramp of slope 1 grey level
/// per pixel gives magnitude 1.
pub fn gradient(smoothed: &[f32], width: usize, height: usize) -> Gradient {
    let n = width * height;
    let mut g = Gradient {
        width,
        height,
        gu: vec![0.0; n],
        gv: vec![0.0; n],
        magnitude: vec![0.0; n],
    };
    if width < 3 || height < 3 || smoothed.len() != n {
        return g;
    }
    for y in 1..height - 1 {
        let r = y * width..(y + 1) * width;
        gradient_row(
            smoothed,
            width,
            y,
            &mut g.gu[r.clone()],
            &mut g.gv[r.clone()],
            &mut g.magnitude[r],
        );
    }
    g
}

/// The gradient at pixel `(x, y)` alone (zero on the one-pixel frame and outside): the
/// reference the tests hold the row-wise and sampled gradients to.
#[cfg(test)]
pub fn gradient_at(
    smoothed: &[f32],
    width: usize,
    height: usize,
    x: usize,
    y: usize,
) -> (f32, f32) {
    if x == 0 || y == 0 || x + 1 >= width || y + 1 >= height {
        return (0.0, 0.0);
    }
    let rows = |k: usize| &smoothed[(y + k - 1) * width..(y + k) * width];
    sobel(rows(0), rows(1), rows(2), x)
}

/// Grid step of [`background_magnitude`]'s sample, pixels: one pixel in sixteen is plenty
/// for a median and costs a few percent of the gradient pass.
const BACKGROUND_STEP: usize = 4;
/// Its histogram: bins of 1/16 grey level per pixel up to 64, the rest in the last bin (a
/// median that high means an image that is all edges).
const BACKGROUND_BINS_PER_LEVEL: f32 = 16.0;
const BACKGROUND_BINS: usize = 64 * 16;
/// The width of one bin of [`background_magnitude`], grey levels per pixel: a median within it
/// is no gradient at all (a flat image reports the first bin's centre).
pub const BACKGROUND_RESOLUTION: f64 = 1.0 / BACKGROUND_BINS_PER_LEVEL as f64;

/// The median gradient magnitude over the image, sampled on a grid, grey levels per pixel:
/// what a typical pixel looks like. On a clean image of surfaces that is the smoothed sensor
/// noise (well under one grey level per pixel); on a photograph of brick, foliage or gravel it
/// is the texture's own contrast. An edge only a few times above it cannot be told from the
/// texture around it, and there the false matches come from (docs/RIGS.md). 0 for an image
/// too small to have an interior.
pub fn background_magnitude(smoothed: &[f32], width: usize, height: usize) -> f32 {
    if width < 3 || height < 3 || smoothed.len() != width * height {
        return 0.0;
    }
    let mut histogram = BackgroundHistogram::new();
    for y in sampled(height) {
        let above = &smoothed[(y - 1) * width..y * width];
        let row = &smoothed[y * width..(y + 1) * width];
        let below = &smoothed[(y + 1) * width..(y + 2) * width];
        for x in sampled(width) {
            let (u, v) = sobel(above, row, below, x);
            histogram.add((u * u + v * v).sqrt());
        }
    }
    histogram.median()
}

/// The rows (or columns) of an image `len` pixels high (or wide) that the background samples:
/// every [`BACKGROUND_STEP`]th from the first inside the frame.
fn sampled(len: usize) -> std::iter::StepBy<std::ops::Range<usize>> {
    (1..len.saturating_sub(1)).step_by(BACKGROUND_STEP)
}

/// The sample of [`background_magnitude`] as a histogram, so that a pass that computes the
/// gradient anyway (`edges::edge_points`) can fill it from the magnitudes it already has, at
/// the same pixels ([`BackgroundHistogram::samples_row`], [`BackgroundHistogram::add_row`]),
/// to the same median.
pub struct BackgroundHistogram {
    bins: Vec<u32>,
    count: u32,
}

impl BackgroundHistogram {
    pub fn new() -> BackgroundHistogram {
        BackgroundHistogram {
            bins: vec![0; BACKGROUND_BINS],
            count: 0,
        }
    }

    #[inline]
    pub fn add(&mut self, magnitude: f32) {
        let bin = (magnitude * BACKGROUND_BINS_PER_LEVEL) as usize;
        self.bins[bin.min(BACKGROUND_BINS - 1)] += 1;
        self.count += 1;
    }

    /// Whether row `y` (1 ≤ y < height − 1) is one [`background_magnitude`] samples.
    #[inline]
    pub fn samples_row(y: usize) -> bool {
        (y - 1).is_multiple_of(BACKGROUND_STEP)
    }

    /// Adds the sampled pixels of one row's gradient magnitudes (`width` long, as
    /// [`gradient_row`] writes them).
    pub fn add_row(&mut self, magnitude: &[f32]) {
        for x in sampled(magnitude.len()) {
            self.add(magnitude[x]);
        }
    }

    /// Adds another sample's counts (a histogram is the same whatever order its pixels came
    /// in, so bands of an image sampled apart and merged give the whole image's).
    pub fn merge(&mut self, other: &BackgroundHistogram) {
        for (mine, theirs) in self.bins.iter_mut().zip(&other.bins) {
            *mine += theirs;
        }
        self.count += other.count;
    }

    /// The median, to within one bin (its centre); 0 when nothing was added.
    pub fn median(&self) -> f32 {
        if self.count == 0 {
            return 0.0;
        }
        let half = self.count.div_ceil(2);
        let mut seen = 0u32;
        for (bin, &n) in self.bins.iter().enumerate() {
            seen += n;
            if seen >= half {
                // The bin's centre: the median to within 1/32 grey level per pixel.
                return (bin as f32 + 0.5) / BACKGROUND_BINS_PER_LEVEL;
            }
        }
        0.0
    }
}

impl Default for BackgroundHistogram {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_smoothing_borrows_the_image_and_any_other_is_the_blur() {
        let img = GreyImage::new(5, 4, (0..20).map(|i| (i * 7 % 11) as f32).collect()).unwrap();
        for sigma in [0.0, -1.0, f64::NAN] {
            let view = smoothed(&img, sigma);
            assert!(matches!(view, std::borrow::Cow::Borrowed(_)), "σ {sigma}");
            assert_eq!(&*view, &smooth(&img, sigma)[..]);
        }
        let blurred = smoothed(&img, 0.8);
        assert!(matches!(blurred, std::borrow::Cow::Owned(_)));
        assert_eq!(&*blurred, &smooth(&img, 0.8)[..]);
        assert_ne!(&*blurred, img.pixels());
    }

    #[test]
    fn kernel_is_normalised_and_symmetric() {
        let k = gaussian_kernel(1.2);
        assert_eq!(k.len(), 2 * 4 + 1);
        assert!((k.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        assert!((0..k.len()).all(|i| k[i] == k[k.len() - 1 - i]));
        assert_eq!(gaussian_kernel(0.0), vec![1.0]);
    }

    #[test]
    fn smoothing_keeps_flat_images_flat_and_spreads_a_spike() {
        let flat = GreyImage::new(9, 7, vec![42.0; 63]).unwrap();
        assert!(smooth(&flat, 1.0).iter().all(|&p| (p - 42.0).abs() < 1e-4));
        let mut spike = vec![0.0; 81];
        spike[40] = 81.0;
        let s = smooth(&GreyImage::new(9, 9, spike).unwrap(), 1.0);
        assert!((s.iter().sum::<f32>() - 81.0).abs() < 1e-3, "mass kept");
        assert!(s[40] < 81.0 && s[39] > 0.0 && s[31] > 0.0 && (s[39] - s[41]).abs() < 1e-5);
    }

    #[test]
    fn a_ramp_has_unit_gradient_along_it() {
        let (w, h) = (8, 6);
        let ramp: Vec<f32> = (0..w * h).map(|i| (i % w) as f32 * 3.0).collect();
        let g = gradient(&ramp, w, h);
        let i = 3 * w + 4;
        assert!((g.gu[i] - 3.0).abs() < 1e-6 && g.gv[i].abs() < 1e-6);
        assert!((g.magnitude[i] - 3.0).abs() < 1e-6);
        assert_eq!(g.magnitude[0], 0.0, "frame stays zero");
        assert_eq!(gradient_at(&ramp, w, h, 4, 3), (g.gu[i], g.gv[i]));
        assert_eq!(gradient_at(&ramp, w, h, 0, 3), (0.0, 0.0));
    }

    #[test]
    fn background_is_the_noise_on_a_flat_image_and_the_texture_on_a_textured_one() {
        let (w, h) = (64, 48);
        let mut rng = trinocular_synth::Rng::new(7);
        // Flat grey with σ = 2 sensor noise, smoothed like extraction does.
        let flat: Vec<f32> = (0..w * h)
            .map(|_| (128.0 + 2.0 * rng.normal() as f32).round())
            .collect();
        let flat = smooth(&GreyImage::new(w as u32, h as u32, flat).unwrap(), 1.0);
        let noise = background_magnitude(&flat, w, h);
        assert!(noise > 0.1 && noise < 1.0, "{noise}");
        // Stripes of 30 grey levels, a period of 5 pixels: most pixels sit on a steep ramp.
        let stripes: Vec<f32> = (0..w * h)
            .map(|i| if (i % w) % 5 < 2 { 100.0 } else { 130.0 })
            .collect();
        let stripes = smooth(&GreyImage::new(w as u32, h as u32, stripes).unwrap(), 1.0);
        let texture = background_magnitude(&stripes, w, h);
        assert!(texture > 4.0, "{texture}");
        assert_eq!(background_magnitude(&[0.0; 4], 2, 2), 0.0);
    }
}
