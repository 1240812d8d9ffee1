//! Floor plans people can read: a top view (world x right, y up) with a metre grid whose
//! ticks are labelled, the axes named, a labelled scale bar, an arrow to +y ("north") and a
//! legend — drawn once through [`Canvas`] and rendered either as a raster ([`Picture`], labels
//! in an 8x8 bitmap font) or as SVG ([`Svg`]), so the PNG and the SVG of a map cannot differ.
//! Used by the session map's top views (`map::export`) and the demo's (`overlay::top_view`).

use std::fmt::Write;

use nalgebra::{Point2, Vector2};

use crate::overlay::Picture;

pub type Rgb = [u8; 3];

/// Where a text sits relative to its anchor point (on its baseline).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Anchor {
    Start,
    Middle,
    End,
}

/// What a picture is drawn with. Coordinates in pixels, y down.
pub trait Canvas {
    fn line(&mut self, a: Point2<f64>, b: Point2<f64>, colour: Rgb, width: f64, dashed: bool);
    fn disc(&mut self, centre: Point2<f64>, radius: f64, colour: Rgb, filled: bool);
    /// `text` with its baseline at `at.y`, placed by `anchor` along x.
    fn text(&mut self, at: Point2<f64>, text: &str, colour: Rgb, anchor: Anchor);
    /// What follows, to [`Canvas::end_group`], is one thing of kind `class` (an SVG group a
    /// reader can select; nothing on a raster).
    fn begin_group(&mut self, _class: &str) {}
    fn end_group(&mut self) {}
}

/// Width of one character of a label, pixels (the bitmap font's; the SVG's monospace font at
/// [`FONT_PX`] is narrower, so layouts made for the raster fit both).
pub const CHAR_PX: f64 = 8.0;
/// Height of a label, pixels.
pub const FONT_PX: f64 = 11.0;

fn text_width(text: &str) -> f64 {
    CHAR_PX * text.chars().count() as f64
}

fn anchored_x(at: f64, text: &str, anchor: Anchor) -> f64 {
    match anchor {
        Anchor::Start => at,
        Anchor::Middle => at - 0.5 * text_width(text),
        Anchor::End => at - text_width(text),
    }
}

impl Canvas for Picture {
    fn line(&mut self, a: Point2<f64>, b: Point2<f64>, colour: Rgb, width: f64, dashed: bool) {
        let thickness = width.round().max(1.0) as i64;
        if !dashed {
            Picture::line(self, a, b, colour, thickness);
            return;
        }
        let length = (b - a).norm();
        let dash = 3.0;
        let mut s = 0.0;
        while s < length {
            let e = (s + dash).min(length);
            Picture::line(
                self,
                a + (b - a) * (s / length),
                a + (b - a) * (e / length),
                colour,
                thickness,
            );
            s += 2.0 * dash;
        }
    }

    fn disc(&mut self, centre: Point2<f64>, radius: f64, colour: Rgb, filled: bool) {
        if !(centre.x.is_finite() && centre.y.is_finite()) {
            return;
        }
        let r = radius.max(0.5);
        let reach = r.ceil() as i64 + 1;
        let (cx, cy) = (centre.x.round() as i64, centre.y.round() as i64);
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                let d = ((dx * dx + dy * dy) as f64).sqrt();
                if d <= r && (filled || d >= r - 1.5) {
                    self.put(cx + dx, cy + dy, colour);
                }
            }
        }
    }

    fn text(&mut self, at: Point2<f64>, text: &str, colour: Rgb, anchor: Anchor) {
        let x0 = anchored_x(at.x, text, anchor).round() as i64;
        // The glyphs' baseline is their seventh row.
        let top = at.y.round() as i64 - 7;
        for (k, c) in text.chars().enumerate() {
            let glyph = font8x8::legacy::BASIC_LEGACY
                .get(c as usize)
                .copied()
                .unwrap_or(font8x8::legacy::BASIC_LEGACY[usize::from(b'?')]);
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..8 {
                    if bits & (1 << col) != 0 {
                        self.put(x0 + 8 * k as i64 + col, top + row as i64, colour);
                    }
                }
            }
        }
    }
}

/// An SVG document being drawn.
pub struct Svg {
    body: String,
    width: u32,
    height: u32,
}

fn css(c: Rgb) -> String {
    format!("rgb({},{},{})", c[0], c[1], c[2])
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

impl Svg {
    pub fn new(width: u32, height: u32, background: Rgb) -> Svg {
        let mut svg = Svg {
            body: String::new(),
            width,
            height,
        };
        let _ = writeln!(
            svg.body,
            "<rect width=\"100%\" height=\"100%\" fill=\"{}\"/>",
            css(background)
        );
        svg
    }

    /// Raw SVG added as it is (elements a caller wants to mark with its own attributes).
    pub fn raw(&mut self, element: &str) {
        self.body.push_str(element);
        self.body.push('\n');
    }

    pub fn finish(self) -> String {
        format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" \
             viewBox=\"0 0 {w} {h}\" font-family=\"monospace\" font-size=\"{FONT_PX}\">\n{}</svg>\n",
            self.body,
            w = self.width,
            h = self.height
        )
    }
}

impl Canvas for Svg {
    fn begin_group(&mut self, class: &str) {
        let _ = writeln!(self.body, "<g class=\"{}\">", escape(class));
    }

    fn end_group(&mut self) {
        self.body.push_str("</g>\n");
    }

    fn line(&mut self, a: Point2<f64>, b: Point2<f64>, colour: Rgb, width: f64, dashed: bool) {
        let _ = writeln!(
            self.body,
            "<path d=\"M{:.1} {:.1} L{:.1} {:.1}\" stroke=\"{}\" stroke-width=\"{width:.1}\" \
             stroke-linecap=\"round\"{}/>",
            a.x,
            a.y,
            b.x,
            b.y,
            css(colour),
            if dashed {
                " stroke-dasharray=\"3 3\""
            } else {
                ""
            }
        );
    }

    fn disc(&mut self, centre: Point2<f64>, radius: f64, colour: Rgb, filled: bool) {
        let paint = if filled {
            format!("fill=\"{}\"", css(colour))
        } else {
            format!(
                "fill=\"none\" stroke=\"{}\" stroke-width=\"1.5\"",
                css(colour)
            )
        };
        let _ = writeln!(
            self.body,
            "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"{radius:.1}\" {paint}/>",
            centre.x, centre.y
        );
    }

    fn text(&mut self, at: Point2<f64>, text: &str, colour: Rgb, anchor: Anchor) {
        let anchor = match anchor {
            Anchor::Start => "start",
            Anchor::Middle => "middle",
            Anchor::End => "end",
        };
        let _ = writeln!(
            self.body,
            "<text x=\"{:.1}\" y=\"{:.1}\" fill=\"{}\" text-anchor=\"{anchor}\">{}</text>",
            at.x,
            at.y,
            css(colour),
            escape(text)
        );
    }
}

/// How a legend entry is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Swatch {
    Line { colour: Rgb, width: f64 },
    Disc { colour: Rgb, filled: bool },
}

#[derive(Debug, Clone, PartialEq)]
pub struct LegendEntry {
    pub swatch: Swatch,
    pub label: String,
}

impl LegendEntry {
    pub fn new(swatch: Swatch, label: impl Into<String>) -> LegendEntry {
        LegendEntry {
            swatch,
            label: label.into(),
        }
    }

    fn width(&self) -> f64 {
        SWATCH_PX + 6.0 + text_width(&self.label) + LEGEND_GAP_PX
    }
}

const SWATCH_PX: f64 = 18.0;
const LEGEND_GAP_PX: f64 = 16.0;
const ROW_PX: f64 = 18.0;
const LEFT_PX: f64 = 56.0;
const RIGHT_PX: f64 = 24.0;
const TOP_PX: f64 = 40.0;
/// Below the plot: the x tick labels and the axis name.
const UNDER_PLOT_PX: f64 = 34.0;
/// Narrowest picture: room for the legend.
const MIN_WIDTH_PX: f64 = 480.0;

/// Where world (x, y) falls on a floor plan, and its frame: grid, axes, scale, legend.
#[derive(Debug, Clone, PartialEq)]
pub struct FloorPlan {
    pub width: u32,
    pub height: u32,
    pub px_per_m: f64,
    /// World (x, y) at the plot's left bottom corner, metres.
    origin: Vector2<f64>,
    /// The plot's box on the picture: left, top, right, bottom.
    plot: [f64; 4],
    legend: Vec<LegendEntry>,
    /// The legend's rows: entries per row.
    rows: Vec<std::ops::Range<usize>>,
}

impl FloorPlan {
    /// The plan of everything in `points` (world x, y; non-finite ones, and those beyond
    /// [`MAX_PLAN_COORD_M`], left out), cropped to them with a margin, `px_per_m` (or less, so
    /// that the plot's larger side is at most `max_side_px`), with `legend` under it.
    pub fn fit(
        points: impl IntoIterator<Item = (f64, f64)>,
        px_per_m: f64,
        max_side_px: f64,
        legend: Vec<LegendEntry>,
    ) -> FloorPlan {
        let (mut xmin, mut xmax, mut ymin, mut ymax) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        let placeable = |v: f64| v.abs() <= MAX_PLAN_COORD_M;
        for (x, y) in points {
            if placeable(x) && placeable(y) {
                (xmin, xmax) = (xmin.min(x), xmax.max(x));
                (ymin, ymax) = (ymin.min(y), ymax.max(y));
            }
        }
        if xmin > xmax {
            (xmin, xmax, ymin, ymax) = (0.0, 1.0, 0.0, 1.0);
        }
        // A little room round the content, so nothing sits on the frame.
        let pad = 0.04 * (xmax - xmin).max(ymax - ymin).max(0.5);
        let (xmin, xmax, ymin, ymax) = (xmin - pad, xmax + pad, ymin - pad, ymax + pad);
        let span = (xmax - xmin).max(ymax - ymin);
        // No floor on the scale: the picture's size and its grid's lines stay bounded however
        // far apart the points are (a floor of 1e-3 px/m once drew a session whose poses a
        // client put 1e189 m apart as a plot of 1e186 pixels, its grid never finished).
        let px_per_m = px_per_m.min(max_side_px / span);
        let plot_w = (xmax - xmin) * px_per_m;
        let plot_h = (ymax - ymin) * px_per_m;
        let width = (plot_w + LEFT_PX + RIGHT_PX).max(MIN_WIDTH_PX);
        // The plot centred across the width the legend may have widened.
        let left = LEFT_PX + 0.5 * (width - plot_w - LEFT_PX - RIGHT_PX);
        // Legend rows, filled left to right after the scale bar's room.
        let usable = width - 2.0 * 8.0;
        let mut rows = Vec::new();
        let (mut start, mut used) = (0, SCALE_ROOM_PX);
        for (i, e) in legend.iter().enumerate() {
            // A full row moves on; the first row holds the scale bar, so may hold no entry.
            if used + e.width() > usable && used > 0.0 {
                rows.push(start..i);
                (start, used) = (i, 0.0);
            }
            used += e.width();
        }
        rows.push(start..legend.len());
        let height = TOP_PX + plot_h + UNDER_PLOT_PX + ROW_PX * rows.len() as f64 + 10.0;
        FloorPlan {
            width: width.ceil() as u32,
            height: height.ceil() as u32,
            px_per_m,
            origin: Vector2::new(xmin, ymin),
            plot: [left, TOP_PX, left + plot_w, TOP_PX + plot_h],
            legend,
            rows,
        }
    }

    /// The pixel of world (x, y).
    pub fn px(&self, x: f64, y: f64) -> Point2<f64> {
        Point2::new(
            self.plot[0] + (x - self.origin.x) * self.px_per_m,
            self.plot[3] - (y - self.origin.y) * self.px_per_m,
        )
    }

    /// Grid spacing, metres: the smallest 1-2-5 step at least 48 pixels apart.
    pub fn grid_step_m(&self) -> f64 {
        nice_steps()
            .find(|&s| s * self.px_per_m >= 48.0)
            .unwrap_or(1000.0)
    }

    /// Scale bar length, metres: the largest 1-2-5 length within 120 pixels.
    pub fn scale_bar_m(&self) -> f64 {
        nice_steps()
            .take_while(|&s| s * self.px_per_m <= 120.0)
            .last()
            .unwrap_or(0.01)
    }

    /// The grid, under everything: lines every [`Self::grid_step_m`], labelled in metres along
    /// the bottom and left, the axes named.
    pub fn draw_grid(&self, canvas: &mut impl Canvas) {
        const GRID: Rgb = [228, 228, 232];
        const ZERO: Rgb = [180, 180, 188];
        const LABEL: Rgb = [90, 90, 96];
        let [left, top, right, bottom] = self.plot;
        let step = self.grid_step_m();
        let world = |p: Point2<f64>| {
            Vector2::new(
                self.origin.x + (p.x - left) / self.px_per_m,
                self.origin.y + (bottom - p.y) / self.px_per_m,
            )
        };
        let (lo, hi) = (
            world(Point2::new(left, bottom)),
            world(Point2::new(right, top)),
        );
        let label = |v: f64| {
            let v = if v.abs() < 1e-9 { 0.0 } else { v };
            let digits = if step >= 1.0 { 0 } else { 1 };
            format!("{v:.digits$}")
        };
        let mut k = (lo.x / step).ceil() as i64;
        while (k as f64) * step <= hi.x + 1e-9 {
            let x = k as f64 * step;
            let u = self.px(x, 0.0).x;
            let colour = if k == 0 { ZERO } else { GRID };
            canvas.line(
                Point2::new(u, top),
                Point2::new(u, bottom),
                colour,
                1.0,
                false,
            );
            canvas.line(
                Point2::new(u, bottom),
                Point2::new(u, bottom + 4.0),
                LABEL,
                1.0,
                false,
            );
            canvas.text(
                Point2::new(u, bottom + 15.0),
                &label(x),
                LABEL,
                Anchor::Middle,
            );
            k += 1;
        }
        let mut k = (lo.y / step).ceil() as i64;
        while (k as f64) * step <= hi.y + 1e-9 {
            let y = k as f64 * step;
            let v = self.px(0.0, y).y;
            let colour = if k == 0 { ZERO } else { GRID };
            canvas.line(
                Point2::new(left, v),
                Point2::new(right, v),
                colour,
                1.0,
                false,
            );
            canvas.line(
                Point2::new(left - 4.0, v),
                Point2::new(left, v),
                LABEL,
                1.0,
                false,
            );
            canvas.text(
                Point2::new(left - 6.0, v + 4.0),
                &label(y),
                LABEL,
                Anchor::End,
            );
            k += 1;
        }
        canvas.text(
            Point2::new(right, bottom + 29.0),
            "x (m)",
            LABEL,
            Anchor::End,
        );
        canvas.text(
            Point2::new(left - 6.0, top - 8.0),
            "y (m)",
            LABEL,
            Anchor::End,
        );
    }

    /// Over everything: the title, the arrow to +y, the labelled scale bar and the legend.
    pub fn draw_frame(&self, canvas: &mut impl Canvas, title: &str) {
        const INK: Rgb = [30, 30, 34];
        let [_, top, right, bottom] = self.plot;
        canvas.text(Point2::new(8.0, 16.0), title, INK, Anchor::Start);
        // North: +y of the world, in the top margin at the right, clear of the content.
        let n = Point2::new(right - 4.0, top - 30.0);
        canvas.line(n + Vector2::new(0.0, 24.0), n, INK, 2.0, false);
        canvas.line(n, n + Vector2::new(-5.0, 8.0), INK, 2.0, false);
        canvas.line(n, n + Vector2::new(5.0, 8.0), INK, 2.0, false);
        canvas.text(n + Vector2::new(-9.0, 16.0), "+y", INK, Anchor::End);
        // Scale bar, first in the legend's first row.
        let y = bottom + UNDER_PLOT_PX + 0.5 * ROW_PX + 4.0;
        let bar = self.scale_bar_m();
        let (a, b) = (
            Point2::new(8.0, y),
            Point2::new(8.0 + bar * self.px_per_m, y),
        );
        canvas.line(a, b, INK, 2.0, false);
        for end in [a, b] {
            canvas.line(end, end - Vector2::new(0.0, 6.0), INK, 2.0, false);
        }
        canvas.text(
            b + Vector2::new(6.0, 4.0),
            &format!("{} m", trim(bar)),
            INK,
            Anchor::Start,
        );
        for (r, row) in self.rows.iter().enumerate() {
            let y = y + ROW_PX * r as f64;
            let mut x = if r == 0 { SCALE_ROOM_PX } else { 8.0 };
            for e in &self.legend[row.clone()] {
                let mid = Point2::new(x + 0.5 * SWATCH_PX, y);
                match e.swatch {
                    Swatch::Line { colour, width } => canvas.line(
                        Point2::new(x, y),
                        Point2::new(x + SWATCH_PX, y),
                        colour,
                        width,
                        false,
                    ),
                    Swatch::Disc { colour, filled } => canvas.disc(mid, 4.0, colour, filled),
                }
                canvas.text(
                    Point2::new(x + SWATCH_PX + 6.0, y + 4.0),
                    &e.label,
                    INK,
                    Anchor::Start,
                );
                x += e.width();
            }
        }
    }
}

/// Room the scale bar and its label take at the start of the legend's first row.
const SCALE_ROOM_PX: f64 = 8.0 + 120.0 + 6.0 + 7.0 * CHAR_PX;

/// 1-2-5 lengths from 1 cm to 5·10¹³ m: at the smallest scale a plan can have (its largest
/// side over twice [`MAX_PLAN_COORD_M`]) a grid step of at least 48 pixels is among them.
fn nice_steps() -> impl Iterator<Item = f64> {
    (-2..14).flat_map(|e| [1.0, 2.0, 5.0].map(|m| m * 10f64.powi(e)))
}

/// Points farther than this from the origin (metres) are left out of a plan's extent, as
/// non-finite ones are: the extent, its span and the scale then stay finite and positive.
const MAX_PLAN_COORD_M: f64 = 1e12;

fn trim(v: f64) -> String {
    let s = format!("{v:.2}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan() -> FloorPlan {
        FloorPlan::fit(
            [(0.0, 0.0), (4.0, 3.0)],
            100.0,
            1000.0,
            vec![
                LegendEntry::new(
                    Swatch::Line {
                        colour: [0, 0, 0],
                        width: 2.0,
                    },
                    "a segment",
                ),
                LegendEntry::new(
                    Swatch::Disc {
                        colour: [0, 0, 255],
                        filled: true,
                    },
                    "a pose",
                ),
            ],
        )
    }

    #[test]
    fn world_maps_into_the_plot_with_y_up() {
        let p = plan();
        let (a, b) = (p.px(0.0, 0.0), p.px(4.0, 3.0));
        assert!(b.x > a.x && b.y < a.y, "x right, y up: {a} {b}");
        assert!((b.x - a.x - 400.0).abs() < 1e-9, "100 px per metre");
        for q in [a, b] {
            assert!(q.x > 0.0 && q.x < f64::from(p.width));
            assert!(q.y > 0.0 && q.y < f64::from(p.height));
        }
    }

    #[test]
    fn steps_are_round_and_readable() {
        let p = plan();
        assert_eq!(p.grid_step_m(), 0.5);
        assert_eq!(p.scale_bar_m(), 1.0);
        assert_eq!(trim(0.5), "0.5");
        assert_eq!(trim(2.0), "2");
    }

    #[test]
    fn svg_and_picture_draw_the_same_labels() {
        let p = plan();
        let mut svg = Svg::new(p.width, p.height, [255, 255, 255]);
        p.draw_grid(&mut svg);
        p.draw_frame(&mut svg, "title");
        let svg = svg.finish();
        for label in [
            "x (m)",
            "y (m)",
            "1 m",
            "a segment",
            "a pose",
            "+y",
            "title",
            ">2.0<",
        ] {
            assert!(svg.contains(label), "{label} missing from the SVG");
        }
        let mut picture = Picture::new(p.width, p.height, [255, 255, 255]);
        p.draw_grid(&mut picture);
        p.draw_frame(&mut picture, "title");
        let inked = picture.rgb.chunks(3).filter(|c| c[0] < 128).count();
        assert!(
            inked > 500,
            "the labels and bar are drawn: {inked} dark pixels"
        );
    }

    /// Points any distance apart make a picture of the bounded size, with a grid of a few
    /// lines: the size and the grid's count are what a client's poses control.
    #[test]
    fn points_far_apart_make_a_bounded_plan_with_a_few_grid_lines() {
        for far in [2e7, 1e11, 1e12, 1e189, f64::MAX] {
            let p = FloorPlan::fit(
                [(0.0, 0.0), (1.0, 1.0), (0.0, -far), (far, 0.0)],
                400.0,
                1100.0,
                Vec::new(),
            );
            assert!(
                p.width <= 1400 && p.height <= 1400,
                "{far}: {} x {}",
                p.width,
                p.height
            );
            assert!(p.px_per_m > 0.0 && p.px_per_m.is_finite(), "{far}");
            let mut svg = Svg::new(p.width, p.height, [255, 255, 255]);
            p.draw_grid(&mut svg);
            p.draw_frame(&mut svg, "title");
            let lines = svg.finish().matches("<path").count();
            assert!(lines < 120, "{far}: {lines} lines");
        }
    }

    #[test]
    fn text_is_drawn_from_the_bitmap_font() {
        let mut picture = Picture::new(40, 12, [255, 255, 255]);
        Canvas::text(
            &mut picture,
            Point2::new(0.0, 9.0),
            "1",
            [0, 0, 0],
            Anchor::Start,
        );
        let dark: Vec<(usize, usize)> = (0..12)
            .flat_map(|y| (0..40).map(move |x| (x, y)))
            .filter(|&(x, y)| picture.rgb[3 * (y * 40 + x)] == 0)
            .collect();
        assert!(!dark.is_empty());
        assert!(dark.iter().all(|&(x, y)| x < 8 && (2..10).contains(&y)));
    }
}
