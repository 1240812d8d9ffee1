//! A map in files people and tools open: ASCII PLY and OBJ (vertices joined by edges, for
//! MeshLab, CloudCompare, Blender), and the paper's figure 7 — the map seen from above as a
//! floor plan (x right, y up), segments darker and thicker the more captures saw them, each
//! rig pose as a marker with its viewing direction (and, in orange, where the robot said it
//! was), and a scale bar — as SVG or PNG.

use std::fmt::Write;

use nalgebra::{Isometry3, Point2, Vector3};

use super::MapSegment;
use crate::overlay::Picture;

/// ASCII PLY: two vertices per segment, one edge per segment with its observations.
pub fn to_ply(map: &[MapSegment]) -> String {
    let mut out = String::new();
    let _ = write!(
        out,
        "ply\nformat ascii 1.0\ncomment trinocular session map, world frame, metres, z up\n\
         element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
         element edge {}\nproperty int vertex1\nproperty int vertex2\n\
         property int observations\nend_header\n",
        2 * map.len(),
        map.len()
    );
    for m in map {
        for p in [m.start, m.end] {
            let _ = writeln!(out, "{} {} {}", p.x, p.y, p.z);
        }
    }
    for (i, m) in map.iter().enumerate() {
        let _ = writeln!(out, "{} {} {}", 2 * i, 2 * i + 1, m.observations);
    }
    out
}

/// Wavefront OBJ: `v` lines, then one `l` line per segment (1-based indices).
pub fn to_obj(map: &[MapSegment]) -> String {
    let mut out = String::from("# trinocular session map, world frame, metres, z up\n");
    for m in map {
        for p in [m.start, m.end] {
            let _ = writeln!(out, "v {} {} {}", p.x, p.y, p.z);
        }
    }
    for i in 0..map.len() {
        let _ = writeln!(out, "l {} {}", 2 * i + 1, 2 * i + 2);
    }
    out
}

/// Largest side of a top view, pixels.
const MAX_SIDE_PX: f64 = 1200.0;
const MARGIN_PX: f64 = 40.0;
/// Length of a pose's viewing-direction tick, pixels.
const POSE_TICK_PX: f64 = 16.0;
const POSE_COLOUR: [u8; 3] = [31, 95, 208];
/// The poses as the robot gave them, where they differ from the ones the map uses.
const PRIOR_COLOUR: [u8; 3] = [230, 120, 20];

/// Where world (x, y) goes on a top view.
struct Layout {
    xmin: f64,
    ymin: f64,
    px_per_m: f64,
    width: u32,
    height: u32,
    /// Scale bar length, metres (a round number).
    bar_m: f64,
}

impl Layout {
    fn new(map: &[MapSegment], poses: &[Isometry3<f64>], priors: &[Isometry3<f64>]) -> Layout {
        let points = map
            .iter()
            .flat_map(|m| [m.start.coords, m.end.coords])
            .chain(poses.iter().chain(priors).map(|p| p.translation.vector))
            .filter(|p| p.x.is_finite() && p.y.is_finite());
        let (mut xmin, mut xmax, mut ymin, mut ymax) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for p in points {
            (xmin, xmax) = (xmin.min(p.x), xmax.max(p.x));
            (ymin, ymax) = (ymin.min(p.y), ymax.max(p.y));
        }
        if xmin > xmax {
            (xmin, xmax, ymin, ymax) = (0.0, 1.0, 0.0, 1.0);
        }
        let span = (xmax - xmin).max(ymax - ymin).max(0.5);
        let px_per_m = ((MAX_SIDE_PX - 2.0 * MARGIN_PX) / span).min(400.0);
        let width = ((xmax - xmin) * px_per_m + 2.0 * MARGIN_PX).ceil() as u32;
        let height = ((ymax - ymin) * px_per_m + 2.0 * MARGIN_PX).ceil() as u32;
        // The largest 1-2-5 length that fits in a quarter of the picture's width.
        let room = 0.25 * f64::from(width.max(200)) / px_per_m;
        let bar_m = [0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0]
            .into_iter()
            .rev()
            .find(|&l| l <= room)
            .unwrap_or(0.1);
        Layout {
            xmin,
            ymin,
            px_per_m,
            width,
            height,
            bar_m,
        }
    }

    /// Pixel of world (x, y): x right, y up.
    fn px(&self, x: f64, y: f64) -> Point2<f64> {
        Point2::new(
            MARGIN_PX + (x - self.xmin) * self.px_per_m,
            f64::from(self.height) - MARGIN_PX - (y - self.ymin) * self.px_per_m,
        )
    }

    /// A pose's centre and the end of its viewing-direction tick (the rig looks along its
    /// +y axis), or no tick when it looks straight up or down.
    fn pose(&self, pose: &Isometry3<f64>) -> (Point2<f64>, Option<Point2<f64>>) {
        let t = pose.translation.vector;
        let c = self.px(t.x, t.y);
        let look = pose.rotation * Vector3::y();
        let flat = nalgebra::Vector2::new(look.x, -look.y);
        let tick = (flat.norm() > 1e-6).then(|| c + flat.normalize() * POSE_TICK_PX);
        (c, tick)
    }

    /// Scale bar: left and right ends, bottom left.
    fn bar(&self) -> (Point2<f64>, Point2<f64>) {
        let y = f64::from(self.height) - 0.4 * MARGIN_PX;
        let x0 = 0.5 * MARGIN_PX;
        (
            Point2::new(x0, y),
            Point2::new(x0 + self.bar_m * self.px_per_m, y),
        )
    }
}

/// Grey level and stroke width of a segment seen `observations` times, out of `most`.
fn style(observations: u32, most: u32) -> (u8, f64) {
    let f = if most > 1 {
        f64::from(observations.saturating_sub(1)) / f64::from(most - 1)
    } else {
        1.0
    };
    ((170.0 * (1.0 - f)).round() as u8, 1.0 + 2.0 * f)
}

/// Figure 7 as SVG: one `<line>` per map segment (and no other `<line>`), poses as circles
/// with a viewing-direction tick, a scale bar labelled in metres. `priors` (empty, or one
/// per pose) are the poses as given: each is drawn in orange, joined to the pose the map
/// uses, so what registration moved shows.
pub fn top_view_svg(
    map: &[MapSegment],
    poses: &[Isometry3<f64>],
    priors: &[Isometry3<f64>],
) -> String {
    let l = Layout::new(map, poses, priors);
    let most = map.iter().map(|m| m.observations).max().unwrap_or(1);
    let mut out = String::new();
    let _ = writeln!(
        out,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\">",
        w = l.width,
        h = l.height
    );
    let _ = writeln!(out, "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>");
    let _ = writeln!(out, "<g stroke-linecap=\"round\">");
    for m in map {
        let (a, b) = (l.px(m.start.x, m.start.y), l.px(m.end.x, m.end.y));
        let (g, w) = style(m.observations, most);
        let _ = writeln!(
            out,
            "<line x1=\"{:.1}\" y1=\"{:.1}\" x2=\"{:.1}\" y2=\"{:.1}\" stroke=\"rgb({g},{g},{g})\" \
             stroke-width=\"{w:.1}\" data-observations=\"{}\"/>",
            a.x, a.y, b.x, b.y, m.observations
        );
    }
    let _ = writeln!(out, "</g>");
    let rgb = |c: [u8; 3]| format!("rgb({},{},{})", c[0], c[1], c[2]);
    let prior_colour = rgb(PRIOR_COLOUR);
    for (prior, pose) in priors.iter().zip(poses) {
        let (c, tick) = l.pose(prior);
        let to = l.pose(pose).0;
        let _ = writeln!(
            out,
            "<g class=\"prior\" stroke=\"{prior_colour}\" fill=\"none\"><circle cx=\"{:.1}\" \
             cy=\"{:.1}\" r=\"4\" stroke-width=\"1.5\"/><path d=\"M{:.1} {:.1} L{:.1} {:.1}\" \
             stroke-dasharray=\"2 2\"/>{}</g>",
            c.x,
            c.y,
            c.x,
            c.y,
            to.x,
            to.y,
            tick.map(|t| format!(
                "<path d=\"M{:.1} {:.1} L{:.1} {:.1}\" stroke-width=\"1.5\"/>",
                c.x, c.y, t.x, t.y
            ))
            .unwrap_or_default()
        );
    }
    let colour = rgb(POSE_COLOUR);
    for p in poses {
        let (c, tick) = l.pose(p);
        let _ = writeln!(
            out,
            "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"4\" fill=\"{colour}\"/>",
            c.x, c.y
        );
        if let Some(t) = tick {
            let _ = writeln!(
                out,
                "<path d=\"M{:.1} {:.1} L{:.1} {:.1}\" stroke=\"{colour}\" stroke-width=\"2\"/>",
                c.x, c.y, t.x, t.y
            );
        }
    }
    let (a, b) = l.bar();
    let _ = writeln!(
        out,
        "<path d=\"M{:.1} {:.1} V{:.1} H{:.1} V{:.1}\" fill=\"none\" stroke=\"black\" stroke-width=\"2\"/>",
        a.x,
        a.y - 5.0,
        a.y,
        b.x,
        b.y - 5.0
    );
    let _ = writeln!(
        out,
        "<text x=\"{:.1}\" y=\"{:.1}\" font-family=\"sans-serif\" font-size=\"12\">{} m</text>",
        b.x + 6.0,
        b.y + 4.0,
        l.bar_m
    );
    out.push_str("</svg>\n");
    out
}

/// Figure 7 as PNG bytes, the same drawing as [`top_view_svg`]; the scale bar, with a tick
/// at each end, has no label: it is the largest of 0.1, 0.2, 0.5, 1, 2, 5… m that fits in a
/// quarter of the picture's width (the SVG says which).
pub fn top_view_png(
    map: &[MapSegment],
    poses: &[Isometry3<f64>],
    priors: &[Isometry3<f64>],
) -> Result<Vec<u8>, image::ImageError> {
    let l = Layout::new(map, poses, priors);
    let most = map.iter().map(|m| m.observations).max().unwrap_or(1);
    let mut pic = Picture::new(l.width, l.height, [255, 255, 255]);
    // Faint first, so well-observed segments are drawn on top.
    let mut order: Vec<&MapSegment> = map.iter().collect();
    order.sort_by_key(|m| m.observations);
    for m in order {
        let (g, w) = style(m.observations, most);
        pic.line(
            l.px(m.start.x, m.start.y),
            l.px(m.end.x, m.end.y),
            [g, g, g],
            w.round() as i64,
        );
    }
    for (prior, pose) in priors.iter().zip(poses) {
        let (c, tick) = l.pose(prior);
        pic.line(c, l.pose(pose).0, PRIOR_COLOUR, 1);
        pic.line(c, c, PRIOR_COLOUR, 5);
        if let Some(t) = tick {
            pic.line(c, t, PRIOR_COLOUR, 1);
        }
    }
    for p in poses {
        let (c, tick) = l.pose(p);
        pic.line(c, c, POSE_COLOUR, 7);
        if let Some(t) = tick {
            pic.line(c, t, POSE_COLOUR, 2);
        }
    }
    let (a, b) = l.bar();
    pic.line(a, b, [0, 0, 0], 2);
    for end in [a, b] {
        pic.line(end, end - nalgebra::Vector2::new(0.0, 6.0), [0, 0, 0], 2);
    }
    pic.to_png()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Translation3, UnitQuaternion};

    fn map() -> Vec<MapSegment> {
        let seg = |a: [f64; 3], b: [f64; 3], obs: u32| MapSegment {
            start: Point3::from(a),
            end: Point3::from(b),
            observations: obs,
            captures: (0..obs).collect(),
            covariance: nalgebra::Matrix6::zeros(),
            direction_sigma_deg: 0.0,
            position_sigma_m: 0.0,
            uncertain: false,
        };
        vec![
            seg([0.0, 3.0, 1.0], [2.0, 3.0, 1.0], 1),
            seg([2.0, 3.0, 0.0], [2.0, 3.0, 2.0], 3),
            seg([-1.0, 0.0, 0.0], [-1.0, 2.5, 0.0], 5),
        ]
    }

    fn poses() -> Vec<Isometry3<f64>> {
        (0..4)
            .map(|k| {
                Isometry3::from_parts(
                    Translation3::new(0.5, 1.0, 1.2),
                    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), f64::from(k) * 1.5),
                )
            })
            .collect()
    }

    #[test]
    fn ply_header_counts_match_its_body() {
        let ply = to_ply(&map());
        let (header, body) = ply.split_once("end_header\n").unwrap();
        assert!(header.starts_with("ply\nformat ascii 1.0\n"));
        assert!(header.contains("element vertex 6\n") && header.contains("element edge 3\n"));
        let rows: Vec<Vec<f64>> = body
            .lines()
            .map(|l| l.split(' ').map(|v| v.parse().unwrap()).collect())
            .collect();
        assert_eq!(rows.len(), 9);
        assert!(rows[..6].iter().all(|r| r.len() == 3));
        assert_eq!(rows[7], vec![2.0, 3.0, 3.0], "second edge, 3 observations");
    }

    #[test]
    fn obj_has_vertices_and_lines() {
        let obj = to_obj(&map());
        assert_eq!(obj.lines().filter(|l| l.starts_with("v ")).count(), 6);
        let lines: Vec<_> = obj.lines().filter(|l| l.starts_with("l ")).collect();
        assert_eq!(lines, ["l 1 2", "l 3 4", "l 5 6"]);
    }

    #[test]
    fn svg_draws_one_line_per_segment_and_every_pose() {
        let svg = top_view_svg(&map(), &poses(), &[]);
        assert!(svg.starts_with("<svg ") && svg.trim_end().ends_with("</svg>"));
        assert_eq!(svg.matches("<line ").count(), 3);
        assert_eq!(svg.matches("<circle ").count(), 4);
        assert!(!svg.contains("class=\"prior\""));
        assert!(svg.contains(" m</text>"), "scale bar label");
        assert_eq!(svg.matches('<').count(), svg.matches('>').count());
    }

    #[test]
    fn png_decodes_with_north_up_and_darker_lines_for_more_observations() {
        let png = top_view_png(&map(), &poses(), &[]).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        let l = Layout::new(&map(), &poses(), &[]);
        assert_eq!((img.width(), img.height()), (l.width, l.height));
        let grey_at = |x: f64, y: f64| {
            let q = l.px(x, y);
            img.get_pixel(q.x.round() as u32, q.y.round() as u32).0
        };
        assert_eq!(grey_at(1.0, 3.0), [170, 170, 170], "seen once: light");
        assert_eq!(grey_at(-1.0, 1.5), [0, 0, 0], "seen most: black");
        assert!(l.px(0.0, 3.0).y < l.px(0.0, 0.0).y, "y up");
    }

    #[test]
    fn the_poses_as_given_are_drawn_joined_to_the_ones_the_map_uses() {
        let refined = poses();
        let given: Vec<Isometry3<f64>> = refined
            .iter()
            .map(|p| Translation3::new(0.3, -0.2, 0.0) * p)
            .collect();
        let svg = top_view_svg(&map(), &refined, &given);
        assert_eq!(svg.matches("class=\"prior\"").count(), refined.len());
        assert_eq!(svg.matches("<circle ").count(), 2 * refined.len());
        let png = top_view_png(&map(), &refined, &given).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        let l = Layout::new(&map(), &refined, &given);
        let t = given[0].translation.vector;
        let q = l.px(t.x, t.y);
        assert_eq!(
            img.get_pixel(q.x.round() as u32, q.y.round() as u32).0,
            PRIOR_COLOUR
        );
    }

    #[test]
    fn an_empty_map_still_draws() {
        assert!(top_view_svg(&[], &[], &[]).contains("</svg>"));
        image::load_from_memory(&top_view_png(&[], &[], &[]).unwrap()).unwrap();
        assert!(to_ply(&[]).contains("element vertex 0\n"));
    }
}
