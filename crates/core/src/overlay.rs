//! Pictures of a result, for people: the three images side by side with their segments
//! (matched ones coloured by triplet, the others grey — the paper's figures 5 and 6), and a
//! top view of 3D segments (the paper's figure 7). Plain RGB buffers; `write_png` encodes.

use nalgebra::Point2;

use crate::extract::GreyImage;
use crate::pipeline::MatchOutput;
use crate::segment::{Segment3, SegmentList};

/// An 8-bit RGB picture, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Picture {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

impl Picture {
    pub fn new(width: u32, height: u32, background: [u8; 3]) -> Picture {
        Picture {
            width,
            height,
            rgb: background.repeat(width as usize * height as usize),
        }
    }

    fn put(&mut self, x: i64, y: i64, colour: [u8; 3]) {
        if x >= 0 && y >= 0 && x < i64::from(self.width) && y < i64::from(self.height) {
            let i = 3 * (y as usize * self.width as usize + x as usize);
            self.rgb[i..i + 3].copy_from_slice(&colour);
        }
    }

    /// A line `thickness` pixels wide (DDA over the longer axis).
    pub fn line(&mut self, a: Point2<f64>, b: Point2<f64>, colour: [u8; 3], thickness: i64) {
        if !(a.x.is_finite() && a.y.is_finite() && b.x.is_finite() && b.y.is_finite()) {
            return;
        }
        let steps = (b - a).abs().max().ceil().clamp(1.0, 1e5) as i64;
        let half = thickness / 2;
        for s in 0..=steps {
            let p = a + (b - a) * (s as f64 / steps as f64);
            let (x, y) = (p.x.round() as i64, p.y.round() as i64);
            for dy in -half..=(thickness - 1 - half) {
                for dx in -half..=(thickness - 1 - half) {
                    self.put(x + dx, y + dy, colour);
                }
            }
        }
    }

    /// A small filled square marking the start of an oriented segment.
    pub fn dot(&mut self, p: Point2<f64>, colour: [u8; 3]) {
        if p.x.is_finite() && p.y.is_finite() {
            let (x, y) = (p.x.round() as i64, p.y.round() as i64);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    self.put(x + dx, y + dy, colour);
                }
            }
        }
    }

    /// PNG bytes.
    pub fn to_png(&self) -> Result<Vec<u8>, image::ImageError> {
        let mut out = std::io::Cursor::new(Vec::new());
        image::write_buffer_with_format(
            &mut out,
            &self.rgb,
            self.width,
            self.height,
            image::ExtendedColorType::Rgb8,
            image::ImageFormat::Png,
        )?;
        Ok(out.into_inner())
    }
}

/// PNG bytes of a grey image, rounded to 8 bits.
pub fn grey_png(image: &GreyImage) -> Result<Vec<u8>, image::ImageError> {
    let mut out = std::io::Cursor::new(Vec::new());
    image::write_buffer_with_format(
        &mut out,
        &image.to_u8(),
        image.width(),
        image.height(),
        image::ExtendedColorType::L8,
        image::ImageFormat::Png,
    )?;
    Ok(out.into_inner())
}

/// A well-spread colour for index `i` (golden-angle hue steps), bright enough on grey.
pub fn colour(i: usize) -> [u8; 3] {
    let hue = (i as f64 * 137.507_764) % 360.0;
    let (s, v) = (0.9, 1.0);
    let c = v * s;
    let x = c * (1.0 - ((hue / 60.0) % 2.0 - 1.0).abs());
    let (r, g, b) = match (hue / 60.0) as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    let to8 = |f: f64| ((f + m) * 255.0).round() as u8;
    [to8(r), to8(g), to8(b)]
}

const UNMATCHED: [u8; 3] = [150, 150, 150];
const GAP_PX: u32 = 8;

/// The three images side by side (dimmed so colours show), each list's segments drawn on
/// its image: segment `i` of image `v` in the colour of `triplet_of[v][i]` if matched, grey
/// otherwise; a dot marks each segment's start.
pub fn triplet_overlay(
    images: [&GreyImage; 3],
    lists: [&SegmentList; 3],
    triplet_of: [&[Option<usize>]; 3],
) -> Picture {
    let width = images.iter().map(|i| i.width()).sum::<u32>() + 2 * GAP_PX;
    let height = images.iter().map(|i| i.height()).max().unwrap_or(1);
    let mut pic = Picture::new(width, height, [0, 0, 0]);
    let mut x0 = 0u32;
    for v in 0..3 {
        let img = images[v];
        for y in 0..img.height() {
            for x in 0..img.width() {
                let g = (img.at(x as usize, y as usize).clamp(0.0, 255.0) * 0.6) as u8;
                pic.put(i64::from(x0 + x), i64::from(y), [g, g, g]);
            }
        }
        let shift = nalgebra::Vector2::new(f64::from(x0), 0.0);
        for (i, s) in lists[v].segments.iter().enumerate() {
            let c = triplet_of[v]
                .get(i)
                .copied()
                .flatten()
                .map_or(UNMATCHED, colour);
            pic.line(s.start + shift, s.end + shift, c, 1);
            pic.dot(s.start + shift, c);
        }
        x0 += img.width() + GAP_PX;
    }
    pic
}

/// Per list, per segment: the index of the 3D segment it went into, if any — the colours
/// of [`triplet_overlay`].
pub fn segment3_labels(output: &MatchOutput, sizes: [usize; 3]) -> [Vec<Option<usize>>; 3] {
    let mut out: [Vec<Option<usize>>; 3] = std::array::from_fn(|v| vec![None; sizes[v]]);
    for (k, r) in output.segments_3d.iter().enumerate() {
        for &t in &r.triplets {
            if let Some(t) = output.triplets.get(t as usize) {
                for (v, labels) in out.iter_mut().enumerate() {
                    if let Some(slot) = labels.get_mut(t.segments[v] as usize) {
                        *slot = Some(k);
                    }
                }
            }
        }
    }
    out
}

const BACKGROUND: [u8; 3] = [24, 24, 28];
const REFERENCE: [u8; 3] = [90, 90, 90];

/// Seen from above (x right, y up on the picture), `pixels_per_m` scale: `segments` in
/// colour over `reference` segments in grey (e.g. ground truth), camera centres as white dots.
pub fn top_view(
    segments: &[Segment3],
    reference: &[Segment3],
    cameras: &[nalgebra::Point3<f64>],
    pixels_per_m: f64,
) -> Picture {
    let points = segments
        .iter()
        .chain(reference)
        .flat_map(|s| [s.start, s.end])
        .chain(cameras.iter().copied())
        .filter(|p| p.x.is_finite() && p.y.is_finite());
    let (mut xmin, mut xmax, mut ymin, mut ymax) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in points {
        (xmin, xmax, ymin, ymax) = (xmin.min(p.x), xmax.max(p.x), ymin.min(p.y), ymax.max(p.y));
    }
    if xmin > xmax {
        (xmin, xmax, ymin, ymax) = (0.0, 1.0, 0.0, 1.0);
    }
    let margin = 20.0;
    let width = ((xmax - xmin) * pixels_per_m + 2.0 * margin).clamp(64.0, 4096.0) as u32;
    let height = ((ymax - ymin) * pixels_per_m + 2.0 * margin).clamp(64.0, 4096.0) as u32;
    let mut pic = Picture::new(width, height, BACKGROUND);
    let to_px = |x: f64, y: f64| {
        Point2::new(
            margin + (x - xmin) * pixels_per_m,
            f64::from(height) - margin - (y - ymin) * pixels_per_m,
        )
    };
    for s in reference {
        pic.line(
            to_px(s.start.x, s.start.y),
            to_px(s.end.x, s.end.y),
            REFERENCE,
            1,
        );
    }
    for (i, s) in segments.iter().enumerate() {
        pic.line(
            to_px(s.start.x, s.start.y),
            to_px(s.end.x, s.end.y),
            colour(i),
            2,
        );
    }
    for c in cameras {
        pic.dot(to_px(c.x, c.y), [255, 255, 255]);
    }
    pic
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::segment::Segment2;

    #[test]
    fn draws_matched_segments_in_colour_and_others_grey() {
        let img = GreyImage::new(20, 10, vec![100.0; 200]).unwrap();
        let seg = |u1, v1, u2, v2| Segment2::new(Point2::new(u1, v1), Point2::new(u2, v2));
        let list = SegmentList {
            segments: vec![seg(2.0, 5.0, 17.0, 5.0), seg(10.0, 1.0, 10.0, 3.0)],
            oriented: true,
            background_gradient: None,
        };
        let labels = [Some(0), None];
        let pic = triplet_overlay([&img; 3], [&list; 3], [&labels[..]; 3]);
        assert_eq!((pic.width, pic.height), (3 * 20 + 2 * GAP_PX, 10));
        let px = |x: u32, y: u32| {
            let i = 3 * (y * pic.width + x) as usize;
            [pic.rgb[i], pic.rgb[i + 1], pic.rgb[i + 2]]
        };
        assert_eq!(px(8, 5), colour(0));
        assert_eq!(px(20 + GAP_PX + 8, 5), colour(0), "second image shifted");
        assert_eq!(px(10, 2), UNMATCHED);
        assert_eq!(px(5, 8), [60, 60, 60], "dimmed image");
        let png = pic.to_png().unwrap();
        assert_eq!(&png[1..4], b"PNG");
    }

    #[test]
    fn top_view_puts_north_up() {
        let s = Segment3 {
            start: nalgebra::Point3::new(0.0, 0.0, 1.0),
            end: nalgebra::Point3::new(0.0, 2.0, 1.0),
        };
        let pic = top_view(&[s], &[], &[nalgebra::Point3::new(1.0, 0.0, 1.0)], 50.0);
        assert_eq!((pic.width, pic.height), (90, 140));
        let red_at = |x: u32, y: u32| pic.rgb[3 * (y * pic.width + x) as usize] > 100;
        assert!(
            red_at(20, 30) && red_at(20, 110),
            "segment along the left edge"
        );
        assert!(red_at(70, 120), "camera dot bottom right");
    }
}
