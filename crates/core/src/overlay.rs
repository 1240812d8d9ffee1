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

    pub(crate) fn put(&mut self, x: i64, y: i64, colour: [u8; 3]) {
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
/// Under the images: a caption per camera and the legend.
const CAPTION_PX: u32 = 44;

/// The three images side by side (dimmed so colours show), each list's segments drawn on
/// its image: segment `i` of image `v` in the colour of `triplet_of[v][i]` if matched, grey
/// otherwise; a dot marks each segment's start. Under each image its camera's name and
/// counts; under all, the legend.
pub fn triplet_overlay(
    images: [&GreyImage; 3],
    lists: [&SegmentList; 3],
    triplet_of: [&[Option<usize>]; 3],
    names: [&str; 3],
) -> Picture {
    use crate::plot::{Anchor, Canvas};
    let width = images.iter().map(|i| i.width()).sum::<u32>() + 2 * GAP_PX;
    let images_height = images.iter().map(|i| i.height()).max().unwrap_or(1);
    let mut pic = Picture::new(width, images_height + CAPTION_PX, [255, 255, 255]);
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
        let mut matched = 0;
        for (i, s) in lists[v].segments.iter().enumerate() {
            let label = triplet_of[v].get(i).copied().flatten();
            matched += usize::from(label.is_some());
            let c = label.map_or(UNMATCHED, colour);
            pic.line(s.start + shift, s.end + shift, c, 1);
            pic.dot(s.start + shift, c);
        }
        let name = if names[v].is_empty() {
            format!("camera {}", v + 1)
        } else {
            format!("camera {} ({})", v + 1, names[v])
        };
        pic.text(
            Point2::new(f64::from(x0) + 4.0, f64::from(images_height) + 14.0),
            &format!(
                "{name}: {} segments, {matched} matched",
                lists[v].segments.len()
            ),
            [30, 30, 34],
            Anchor::Start,
        );
        x0 += img.width() + GAP_PX;
    }
    // The legend.
    let y = f64::from(images_height) + 34.0;
    let mut x = 4.0;
    for (swatch, label) in [
        (colour(0), "matched: a colour per 3D segment"),
        (UNMATCHED, "extracted, not matched"),
    ] {
        Canvas::line(
            &mut pic,
            Point2::new(x, y - 4.0),
            Point2::new(x + 18.0, y - 4.0),
            swatch,
            3.0,
            false,
        );
        pic.text(Point2::new(x + 24.0, y), label, [30, 30, 34], Anchor::Start);
        x += 24.0 + 8.0 * label.len() as f64 + 16.0;
    }
    pic.dot(Point2::new(x + 4.0, y - 4.0), [30, 30, 34]);
    pic.text(
        Point2::new(x + 12.0, y),
        "dot: a segment's start (brighter side on its left)",
        [30, 30, 34],
        Anchor::Start,
    );
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

const REFERENCE: [u8; 3] = [185, 185, 192];
const CAMERA: [u8; 3] = [31, 95, 208];

/// A colour of [`colour`] darkened to read on white.
fn on_white(i: usize) -> [u8; 3] {
    colour(i).map(|c| (f64::from(c) * 0.72).round() as u8)
}

/// Seen from above (x right, y up on the picture), `pixels_per_m` scale (less if the picture
/// would be larger than 1100 pixels): `segments` a colour each over `reference` segments in
/// grey (the ground truth), the cameras as blue dots, on a labelled metre grid with a scale
/// bar and a legend (`plot::FloorPlan`).
pub fn top_view(
    segments: &[Segment3],
    reference: &[Segment3],
    cameras: &[nalgebra::Point3<f64>],
    pixels_per_m: f64,
) -> Picture {
    use crate::plot::{Canvas, FloorPlan, LegendEntry, Swatch};
    let points = segments
        .iter()
        .chain(reference)
        .flat_map(|s| [(s.start.x, s.start.y), (s.end.x, s.end.y)])
        .chain(cameras.iter().map(|c| (c.x, c.y)));
    let legend = vec![
        LegendEntry::new(
            Swatch::Line {
                colour: on_white(0),
                width: 2.0,
            },
            "3D segment (a colour each)",
        ),
        LegendEntry::new(
            Swatch::Line {
                colour: REFERENCE,
                width: 1.0,
            },
            "ground truth seen by the three cameras",
        ),
        LegendEntry::new(
            Swatch::Disc {
                colour: CAMERA,
                filled: true,
            },
            "camera",
        ),
    ];
    let plan = FloorPlan::fit(points, pixels_per_m, 1100.0, legend);
    let mut pic = Picture::new(plan.width, plan.height, [255, 255, 255]);
    plan.draw_grid(&mut pic);
    for s in reference {
        let (a, b) = (plan.px(s.start.x, s.start.y), plan.px(s.end.x, s.end.y));
        pic.line(a, b, REFERENCE, 1);
    }
    for (i, s) in segments.iter().enumerate() {
        let (a, b) = (plan.px(s.start.x, s.start.y), plan.px(s.end.x, s.end.y));
        pic.line(a, b, on_white(i), 2);
    }
    for c in cameras {
        pic.disc(plan.px(c.x, c.y), 4.0, CAMERA, true);
    }
    plan.draw_frame(
        &mut pic,
        &format!("{} 3D segments from above (rig frame)", segments.len()),
    );
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
        let pic = triplet_overlay([&img; 3], [&list; 3], [&labels[..]; 3], ["a", "b", "c"]);
        assert_eq!(
            (pic.width, pic.height),
            (3 * 20 + 2 * GAP_PX, 10 + CAPTION_PX)
        );
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
    fn top_view_puts_north_up_with_its_scale_and_legend() {
        let s = Segment3 {
            start: nalgebra::Point3::new(0.0, 0.0, 1.0),
            end: nalgebra::Point3::new(0.0, 2.0, 1.0),
        };
        let pic = top_view(&[s], &[], &[nalgebra::Point3::new(1.0, 0.0, 1.0)], 50.0);
        let where_is = |c: [u8; 3]| -> Vec<(u32, u32)> {
            (0..pic.height)
                .flat_map(|y| (0..pic.width).map(move |x| (x, y)))
                .filter(|&(x, y)| {
                    let i = 3 * (y * pic.width + x) as usize;
                    pic.rgb[i..i + 3] == c
                })
                .collect()
        };
        // The legend's swatch has the segment's colour too: keep to the plot's pixels, above
        // the legend rows.
        let segment: Vec<_> = where_is(on_white(0))
            .into_iter()
            .filter(|&(_, y)| y + 60 < pic.height)
            .collect();
        let (xs, ys): (Vec<u32>, Vec<u32>) = segment.iter().copied().unzip();
        let span = |v: &[u32]| v.iter().max().unwrap() - v.iter().min().unwrap();
        assert!(span(&xs) <= 2, "a vertical line");
        assert!(
            (98..=102).contains(&span(&ys)),
            "2 m at 50 px/m: {}",
            span(&ys)
        );
        let camera: Vec<_> = where_is(CAMERA)
            .into_iter()
            .filter(|&(_, y)| y + 60 < pic.height)
            .collect();
        let cx = camera.iter().map(|p| f64::from(p.0)).sum::<f64>() / camera.len() as f64;
        let cy = camera.iter().map(|p| f64::from(p.1)).sum::<f64>() / camera.len() as f64;
        assert!(
            (cx - f64::from(xs[0]) - 50.0).abs() < 2.0,
            "1 m right of the segment"
        );
        assert!(
            (cy - f64::from(*ys.iter().max().unwrap())).abs() < 3.0,
            "level with its start, at the bottom: y up"
        );
        assert_eq!(pic.rgb[..3], [255, 255, 255], "light background");
    }
}
