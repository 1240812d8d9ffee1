//! The grey image every extraction stage reads: row-major `f32` grey levels on the 8-bit
//! scale (0–255), whatever the source depth, so that thresholds in grey levels mean the same
//! for 8- and 16-bit images. Pixel `(u, v)` is column `u`, row `v`, its centre at integer
//! coordinates (DESIGN §1).

/// A grey image. Invariant: `pixels.len() == width * height`.
#[derive(Debug, Clone, PartialEq)]
pub struct GreyImage {
    width: u32,
    height: u32,
    pixels: Vec<f32>,
}

impl GreyImage {
    /// `None` unless `pixels.len() == width * height`.
    pub fn new(width: u32, height: u32, pixels: Vec<f32>) -> Option<GreyImage> {
        (pixels.len() as u64 == u64::from(width) * u64::from(height)).then_some(GreyImage {
            width,
            height,
            pixels,
        })
    }

    /// From 8-bit grey levels; `None` unless `bytes.len() == width * height`.
    pub fn from_u8(width: u32, height: u32, bytes: &[u8]) -> Option<GreyImage> {
        GreyImage::new(width, height, bytes.iter().map(|&b| f32::from(b)).collect())
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// Row-major grey levels.
    pub fn pixels(&self) -> &[f32] {
        &self.pixels
    }

    /// Grey level at column `u`, row `v`; panics out of bounds (callers iterate inside).
    #[inline]
    pub fn at(&self, u: usize, v: usize) -> f32 {
        self.pixels[v * self.width as usize + u]
    }

    /// Rounded to 8 bits, for writing out.
    pub fn to_u8(&self) -> Vec<u8> {
        self.pixels
            .iter()
            .map(|&p| p.round().clamp(0.0, 255.0) as u8)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn size_must_match_the_pixels() {
        assert!(GreyImage::new(2, 3, vec![0.0; 6]).is_some());
        assert!(GreyImage::new(2, 3, vec![0.0; 5]).is_none());
        let img = GreyImage::from_u8(2, 1, &[10, 250]).unwrap();
        assert_eq!(img.at(1, 0), 250.0);
        assert_eq!(img.to_u8(), vec![10, 250]);
    }
}
