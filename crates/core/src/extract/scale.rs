//! How much to smooth an image before its edges are located, chosen from the image itself.
//!
//! Smoothing trades two errors. It keeps sensor noise and fine texture from starting edges,
//! but it blurs neighbouring edges into each other, and a line located on a blurred pair is
//! pulled toward its neighbour (`segment::crowding`) or lost in it. Measured
//! (docs/ACCURACY.md, "Smoothing chosen from the image"): on the rendered rooms — flat
//! surfaces, sensor noise of 2 grey levels — no smoothing instead of 1 px raises completeness
//! by 11–20 points and lowers the error in both rooms; on real photographs of a brick facade
//! it turns brick texture into segments (80% confirmed by a fourth photo → 57%); on synthetic
//! rooms with sensor noise of 5 or 8 grey levels it loses 6–12 points of completeness.
//!
//! So the default is the lightest smoothing that keeps both apart from the edges:
//! - *noise*: the sensor noise's gradient after smoothing (Immerkær's estimate of the noise,
//!   carried through the actual smoothing and Sobel kernels) stays [`NOISE_MARGIN`] times under
//!   the hysteresis's high threshold, so noise alone seldom starts an edge;
//! - *texture*: where the image's typical gradient is several times what its noise alone
//!   would give, the surfaces are textured, and texture is smoothed at 1 px.
//!
//! A client that sets `smoothing_sigma_px` gets exactly that instead.

use super::gradient::{background_magnitude, gaussian_kernel, BACKGROUND_RESOLUTION};
use super::GreyImage;

/// How many times the noise gradient's σ (per Sobel component) stays under `gradient_high`.
/// At 5 the rendered rooms' noise (2.05 grey levels, 0.89 after Sobel) needs no smoothing.
pub const NOISE_MARGIN: f64 = 5.0;
/// The typical gradient over the one noise alone gives, below which the image counts as
/// flat surfaces and above which ([`TEXTURED_RATIO`]) as textured; in between the smoothing
/// for texture rises linearly. Measured: 1.05–1.10 on the rendered images of the shared
/// rooms, 1.24 on the library's own renders, 8.1–8.5 on the `herzjesu_p25` photographs.
pub const FLAT_RATIO: f64 = 1.5;
pub const TEXTURED_RATIO: f64 = 3.0;
/// Smoothing for textured images, pixels: the scale line detectors smooth at, and ours before
/// the smoothing was chosen per image.
pub const TEXTURE_SMOOTHING_PX: f64 = 1.0;
/// The smoothings tried for the noise, from none up, pixels.
const STEP_PX: f64 = 0.1;
const MAX_NOISE_SMOOTHING_PX: f64 = 3.0;

/// What an image says about its own noise and texture, and the smoothing chosen from them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageScale {
    /// Sensor noise σ, grey levels (Immerkær's estimate).
    pub noise: f64,
    /// The image's median gradient magnitude (`gradient::background_magnitude` of the raw
    /// image) over the one its noise alone would give.
    pub texture_ratio: f64,
    /// The smoothing chosen, pixels.
    pub smoothing_sigma_px: f64,
}

/// Measures `image` and chooses its smoothing for hysteresis at `gradient_high`.
pub fn choose(image: &GreyImage, gradient_high: f64) -> ImageScale {
    let noise = noise_sigma(image);
    let (w, h) = (image.width() as usize, image.height() as usize);
    let median_gradient = f64::from(background_magnitude(image.pixels(), w, h));
    // Sobel of white noise (as `gradient` scales it): each component has σ = noise ·
    // noise_gain(0), the magnitude is Rayleigh with median σ·√(2 ln 2).
    let noise_median = noise * noise_gain(0.0) * (2.0 * std::f64::consts::LN_2).sqrt();
    let texture_ratio = if noise_median > 1e-6 {
        median_gradient / noise_median
    } else if median_gradient > BACKGROUND_RESOLUTION {
        f64::INFINITY // texture without noise
    } else {
        1.0 // flat: the median is the first bin's centre
    };
    let texture = TEXTURE_SMOOTHING_PX
        * ((texture_ratio - FLAT_RATIO) / (TEXTURED_RATIO - FLAT_RATIO)).clamp(0.0, 1.0);
    let limit = gradient_high / NOISE_MARGIN;
    let steps = (MAX_NOISE_SMOOTHING_PX / STEP_PX).round() as usize;
    let for_noise = (0..=steps)
        .map(|k| k as f64 * STEP_PX)
        .find(|&sigma| noise * noise_gain(sigma) <= limit)
        .unwrap_or(MAX_NOISE_SMOOTHING_PX);
    ImageScale {
        noise,
        texture_ratio,
        smoothing_sigma_px: for_noise.max(texture),
    }
}

/// σ of one Sobel gradient component (grey levels per pixel, as `gradient` scales it) of unit
/// white noise after Gaussian smoothing by `sigma_px`: the root sum of squares of the combined
/// separable kernels.
pub fn noise_gain(sigma_px: f64) -> f64 {
    let g: Vec<f64> = gaussian_kernel(sigma_px)
        .into_iter()
        .map(f64::from)
        .collect();
    let along = convolve(&g, &[0.25, 0.5, 0.25]);
    let across = convolve(&g, &[-0.5, 0.0, 0.5]);
    let energy = |k: &[f64]| k.iter().map(|w| w * w).sum::<f64>();
    (energy(&along) * energy(&across)).sqrt()
}

fn convolve(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    out
}

/// Pixels looked at for the noise, in evenly spaced whole rows: enough to know it to about 1%,
/// and a small part of the extraction's cost (every pixel of a 512 × 512 image took 2.5 ms,
/// more than the extraction itself).
const SAMPLE_PIXELS: usize = 16_384;

/// Immerkær's noise estimate: the mean absolute response to the difference of two Laplacians,
/// which cancels smooth intensity, over the interior rows sampled.
fn noise_sigma(image: &GreyImage) -> f64 {
    let (w, h) = (image.width() as usize, image.height() as usize);
    if w < 3 || h < 3 {
        return 0.0;
    }
    let p = image.pixels();
    let interior = h - 2;
    let rows = (SAMPLE_PIXELS / (w - 2)).clamp(1, interior);
    let stride = interior.div_ceil(rows).max(1);
    let (mut sum, mut count) = (0.0f64, 0usize);
    for v in (1..h - 1).step_by(stride) {
        let (up, row, down) = (
            &p[(v - 1) * w..v * w],
            &p[v * w..(v + 1) * w],
            &p[(v + 1) * w..],
        );
        let row_sum: f32 = (1..w - 1)
            .map(|u| {
                ((up[u - 1] + up[u + 1] + down[u - 1] + down[u + 1])
                    - 2.0 * (up[u] + down[u] + row[u - 1] + row[u + 1])
                    + 4.0 * row[u])
                    .abs()
            })
            .sum();
        sum += f64::from(row_sum);
        count += w - 2;
    }
    (std::f64::consts::FRAC_PI_2).sqrt() / 6.0 * sum / count as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic normal sequence (Box–Muller on a 64-bit LCG): no dependency for a test.
    fn noise_image(width: u32, height: u32, sigma: f64, seed: u64) -> GreyImage {
        let mut state = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
        let mut uniform = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let pixels = (0..width * height)
            .map(|_| {
                let (a, b) = (uniform(), uniform());
                let z = (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos();
                (128.0 + sigma * z) as f32
            })
            .collect();
        GreyImage::new(width, height, pixels).expect("sized")
    }

    #[test]
    fn the_noise_of_a_flat_noisy_image_is_measured_and_it_counts_as_flat() {
        for sigma in [1.0, 2.0, 5.0] {
            let scale = choose(&noise_image(256, 256, sigma, 7), 5.0);
            assert!(
                (scale.noise - sigma).abs() < 0.05 * sigma,
                "noise {sigma}: measured {}",
                scale.noise
            );
            assert!(
                (scale.texture_ratio - 1.0).abs() < 0.1,
                "noise alone: ratio {}",
                scale.texture_ratio
            );
        }
    }

    #[test]
    fn noisier_images_are_smoothed_more_and_the_noise_gradient_stays_under_the_margin() {
        let light = choose(&noise_image(256, 256, 1.0, 1), 5.0).smoothing_sigma_px;
        let medium = choose(&noise_image(256, 256, 4.0, 2), 5.0).smoothing_sigma_px;
        let heavy = choose(&noise_image(256, 256, 8.0, 3), 5.0).smoothing_sigma_px;
        assert_eq!(light, 0.0, "one grey level of noise needs no smoothing");
        assert!(light < medium && medium < heavy, "{light} {medium} {heavy}");
        for (noise, sigma) in [(4.0, medium), (8.0, heavy)] {
            assert!(noise * noise_gain(sigma) <= 5.0 / NOISE_MARGIN + 1e-9);
            assert!(noise * noise_gain(sigma - STEP_PX) > 5.0 / NOISE_MARGIN);
        }
    }

    #[test]
    fn the_noise_gain_matches_sobel_without_smoothing_and_falls_with_it() {
        // Sobel/8 on unit noise: √(6/16 · 2/4) per component.
        assert!((noise_gain(0.0) - (0.375f64 * 0.5).sqrt()).abs() < 1e-12);
        let gains: Vec<f64> = [0.5, 1.0, 2.0].iter().map(|&s| noise_gain(s)).collect();
        assert!(gains.windows(2).all(|p| p[1] < p[0]), "{gains:?}");
    }

    #[test]
    fn texture_is_smoothed_at_one_pixel_whatever_its_noise() {
        // Stripes of random brightness every 3 px, barely noisy: the typical gradient is
        // texture, not noise.
        let (w, h) = (240u32, 240u32);
        let noisy = noise_image(w, h, 0.6, 9);
        let pixels = noisy
            .pixels()
            .iter()
            .enumerate()
            .map(|(i, &p)| {
                let (u, v) = (i as u32 % w, i as u32 / w);
                let cell = (u / 3).wrapping_mul(2654435761) ^ (v / 3).wrapping_mul(40503);
                p + (cell % 17) as f32
            })
            .collect();
        let textured = GreyImage::new(w, h, pixels).expect("sized");
        let scale = choose(&textured, 5.0);
        assert!(scale.texture_ratio > TEXTURED_RATIO, "{scale:?}");
        assert_eq!(scale.smoothing_sigma_px, TEXTURE_SMOOTHING_PX);
    }

    #[test]
    fn tiny_and_flat_images_choose_without_dividing_by_zero() {
        let flat = GreyImage::new(16, 16, vec![100.0; 256]).expect("sized");
        let scale = choose(&flat, 5.0);
        assert_eq!(scale.smoothing_sigma_px, 0.0);
        assert!(scale.texture_ratio.is_finite());
        let tiny = GreyImage::new(2, 2, vec![0.0, 255.0, 255.0, 0.0]).expect("sized");
        assert!(choose(&tiny, 5.0).smoothing_sigma_px.is_finite());
    }
}
