//! A map in files people and tools open: ASCII PLY (vertices coloured by how many captures
//! saw their segment, joined by edges) and OBJ (`l` elements, which MeshLab, CloudCompare and
//! Blender load as lines), and the paper's figure 7 — the map seen from above as a floor
//! plan (x right, y up): segments darker and thicker the more captures saw them, each rig
//! drawn where its cameras were with the direction they looked (and, in orange, where the
//! robot said it was), on a labelled metre grid with a scale bar, the axes, +y and a legend
//! (`plot::FloorPlan`) — as SVG or PNG, one drawing for both.

use std::fmt::Write;

use nalgebra::{Isometry3, Point2, Point3, Vector3};

use super::MapSegment;
use crate::geometry::Rig;
use crate::overlay::Picture;
use crate::plot::{Canvas, FloorPlan, LegendEntry, Svg, Swatch};

/// Colour of a segment seen `observations` times out of `most` in the PLY: from light blue
/// (once) to dark red (the most), so a viewer shows what the map is sure of.
fn ply_colour(observations: u32, most: u32) -> [u8; 3] {
    let f = if most > 1 {
        f64::from(observations.saturating_sub(1)) / f64::from(most - 1)
    } else {
        1.0
    };
    let mix = |a: f64, b: f64| (a + (b - a) * f).round() as u8;
    [mix(120.0, 180.0), mix(170.0, 20.0), mix(230.0, 30.0)]
}

/// ASCII PLY: two vertices per segment, coloured by its observations (`red green blue`), one
/// edge per segment with its observations.
pub fn to_ply(map: &[MapSegment]) -> String {
    let most = map.iter().map(|m| m.observations).max().unwrap_or(1);
    let mut out = String::new();
    let _ = write!(
        out,
        "ply\nformat ascii 1.0\ncomment trinocular session map, world frame, metres, z up; \
         colour: observations, light blue (once) to dark red (most, {most})\n\
         element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         element edge {}\nproperty int vertex1\nproperty int vertex2\n\
         property int observations\nend_header\n",
        2 * map.len(),
        map.len()
    );
    for m in map {
        let [r, g, b] = ply_colour(m.observations, most);
        for p in [m.start, m.end] {
            let _ = writeln!(out, "{} {} {} {r} {g} {b}", p.x, p.y, p.z);
        }
    }
    for (i, m) in map.iter().enumerate() {
        let _ = writeln!(out, "{} {} {}", 2 * i, 2 * i + 1, m.observations);
    }
    out
}

/// A single Match's 3D segments (rig frame) as ASCII PLY: two vertices per segment, each
/// segment in its colour of the overlay pictures (`overlay::colour`), one edge per segment.
pub fn segments_to_ply(segments: &[crate::segment::Segment3]) -> String {
    let mut out = String::new();
    let _ = write!(
        out,
        "ply\nformat ascii 1.0\ncomment trinocular 3D segments, rig frame, metres, z up; \
         colour: the segment's in the overlay\n\
         element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         element edge {}\nproperty int vertex1\nproperty int vertex2\nend_header\n",
        2 * segments.len(),
        segments.len()
    );
    for (i, s) in segments.iter().enumerate() {
        let [r, g, b] = crate::overlay::colour(i);
        for p in [s.start, s.end] {
            let _ = writeln!(out, "{} {} {} {r} {g} {b}", p.x, p.y, p.z);
        }
    }
    for i in 0..segments.len() {
        let _ = writeln!(out, "{} {}", 2 * i, 2 * i + 1);
    }
    out
}

/// Wavefront OBJ: `v` lines, then one `l` line per segment (1-based indices), in one object.
pub fn to_obj(map: &[MapSegment]) -> String {
    let mut out = String::from("# trinocular session map, world frame, metres, z up\no map\n");
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

/// Where a rig's cameras are and where they look, in the rig frame: what a top view draws
/// at each pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigMarker {
    pub centre: Point3<f64>,
    /// Unit, or zero when unknown.
    pub looking: Vector3<f64>,
}

impl RigMarker {
    /// The centroid of the rig's optical centres, looking along its cameras' mean axis.
    pub fn of(rig: &Rig) -> RigMarker {
        let axes: Vector3<f64> = rig.cameras().iter().map(|c| c.axis()).sum();
        RigMarker {
            centre: rig.centroid(),
            looking: axes.try_normalize(1e-9).unwrap_or_else(Vector3::zeros),
        }
    }

    /// For a rig not known: its frame's origin, looking along its +y axis.
    pub fn origin() -> RigMarker {
        RigMarker {
            centre: Point3::origin(),
            looking: Vector3::y(),
        }
    }
}

/// Largest side of a top view's plot, pixels, and its largest scale.
const MAX_SIDE_PX: f64 = 1100.0;
const MAX_PX_PER_M: f64 = 400.0;
/// Length of a pose's viewing-direction tick, pixels.
const POSE_TICK_PX: f64 = 16.0;
const POSE_COLOUR: [u8; 3] = [31, 95, 208];
/// The poses as the robot gave them, where they differ from the ones the map uses.
const PRIOR_COLOUR: [u8; 3] = [230, 120, 20];

/// Grey level and stroke width of a segment seen `observations` times, out of `most`.
fn style(observations: u32, most: u32) -> (u8, f64) {
    let f = if most > 1 {
        f64::from(observations.saturating_sub(1)) / f64::from(most - 1)
    } else {
        1.0
    };
    ((170.0 * (1.0 - f)).round() as u8, 1.0 + 2.0 * f)
}

/// A pose on the plan: where its cameras are, and the end of its viewing-direction tick (none
/// when it looks straight up or down).
fn marker(
    plan: &FloorPlan,
    pose: &Isometry3<f64>,
    rig: &RigMarker,
) -> (Point2<f64>, Option<Point2<f64>>) {
    let at = pose * rig.centre;
    let c = plan.px(at.x, at.y);
    let look = pose.rotation * rig.looking;
    let flat = nalgebra::Vector2::new(look.x, -look.y);
    let tick = (flat.norm() > 1e-6).then(|| c + flat.normalize() * POSE_TICK_PX);
    (c, tick)
}

/// The plan of a map: all of it, every pose and prior, with its legend.
fn plan_of(
    map: &[MapSegment],
    poses: &[Isometry3<f64>],
    priors: &[Isometry3<f64>],
    rig: &RigMarker,
) -> FloorPlan {
    let most = map.iter().map(|m| m.observations).max().unwrap_or(1);
    let points = map
        .iter()
        .flat_map(|m| [(m.start.x, m.start.y), (m.end.x, m.end.y)])
        .chain(poses.iter().chain(priors).map(|p| {
            let c = p * rig.centre;
            (c.x, c.y)
        }));
    let mut legend = vec![LegendEntry::new(
        Swatch::Disc {
            colour: POSE_COLOUR,
            filled: true,
        },
        "rig (map's pose)",
    )];
    if !priors.is_empty() {
        legend.push(LegendEntry::new(
            Swatch::Disc {
                colour: PRIOR_COLOUR,
                filled: false,
            },
            "pose as given",
        ));
    }
    let (g, w) = style(1, most.max(2));
    legend.push(LegendEntry::new(
        Swatch::Line {
            colour: [g, g, g],
            width: w,
        },
        "seen once",
    ));
    if most > 1 {
        let (g, w) = style(most, most);
        legend.push(LegendEntry::new(
            Swatch::Line {
                colour: [g, g, g],
                width: w,
            },
            format!("seen {most} times"),
        ));
    }
    FloorPlan::fit(points, MAX_PX_PER_M, MAX_SIDE_PX, legend)
}

/// Figure 7 on `canvas`; `segment` draws each map segment (the SVG marks its lines).
fn draw_top_view<C: Canvas>(
    canvas: &mut C,
    plan: &FloorPlan,
    map: &[MapSegment],
    poses: &[Isometry3<f64>],
    priors: &[Isometry3<f64>],
    rig: &RigMarker,
    segment: impl Fn(&mut C, &MapSegment, Point2<f64>, Point2<f64>, [u8; 3], f64),
) {
    let most = map.iter().map(|m| m.observations).max().unwrap_or(1);
    plan.draw_grid(canvas);
    // Faint first, so well-observed segments are drawn on top.
    let mut order: Vec<&MapSegment> = map.iter().collect();
    order.sort_by_key(|m| m.observations);
    for m in order {
        let (g, w) = style(m.observations, most);
        let (a, b) = (plan.px(m.start.x, m.start.y), plan.px(m.end.x, m.end.y));
        segment(canvas, m, a, b, [g, g, g], w);
    }
    for (prior, pose) in priors.iter().zip(poses) {
        canvas.begin_group("prior");
        let (c, tick) = marker(plan, prior, rig);
        canvas.line(c, marker(plan, pose, rig).0, PRIOR_COLOUR, 1.0, true);
        canvas.disc(c, 4.0, PRIOR_COLOUR, false);
        if let Some(t) = tick {
            canvas.line(c, t, PRIOR_COLOUR, 1.5, false);
        }
        canvas.end_group();
    }
    for p in poses {
        canvas.begin_group("pose");
        let (c, tick) = marker(plan, p, rig);
        canvas.disc(c, 4.0, POSE_COLOUR, true);
        if let Some(t) = tick {
            canvas.line(c, t, POSE_COLOUR, 2.0, false);
        }
        canvas.end_group();
    }
    plan.draw_frame(
        canvas,
        &format!(
            "map from above: {} segments, {} captures",
            map.len(),
            poses.len()
        ),
    );
}

/// Figure 7 as SVG: one `<line>` per map segment (and no other `<line>`: the grid and marks
/// are paths), each rig pose a filled circle with a viewing-direction tick, the grid, scale
/// bar, +y arrow and legend labelled. `priors` (empty, or one per pose) are the poses as
/// given: each is drawn in orange (class `prior`), joined to the pose the map uses, so what
/// registration moved shows. `rig`: where the cameras are in the rig frame.
pub fn top_view_svg(
    map: &[MapSegment],
    poses: &[Isometry3<f64>],
    priors: &[Isometry3<f64>],
    rig: &RigMarker,
) -> String {
    let plan = plan_of(map, poses, priors, rig);
    let mut svg = Svg::new(plan.width, plan.height, [255, 255, 255]);
    draw_top_view(
        &mut svg,
        &plan,
        map,
        poses,
        priors,
        rig,
        |svg, m, a, b, c, w| {
            svg.raw(&format!(
            "<line x1=\"{:.1}\" y1=\"{:.1}\" x2=\"{:.1}\" y2=\"{:.1}\" stroke=\"rgb({},{},{})\" \
             stroke-width=\"{w:.1}\" stroke-linecap=\"round\" data-observations=\"{}\"/>",
            a.x, a.y, b.x, b.y, c[0], c[1], c[2], m.observations
        ));
        },
    );
    svg.finish()
}

/// Figure 7 as PNG bytes, the same drawing as [`top_view_svg`].
pub fn top_view_png(
    map: &[MapSegment],
    poses: &[Isometry3<f64>],
    priors: &[Isometry3<f64>],
    rig: &RigMarker,
) -> Result<Vec<u8>, image::ImageError> {
    let plan = plan_of(map, poses, priors, rig);
    let mut pic = Picture::new(plan.width, plan.height, [255, 255, 255]);
    draw_top_view(
        &mut pic,
        &plan,
        map,
        poses,
        priors,
        rig,
        |pic, _, a, b, c, w| {
            Canvas::line(pic, a, b, c, w, false);
        },
    );
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
    fn ply_header_counts_match_its_body_and_colours_follow_observations() {
        let ply = to_ply(&map());
        let (header, body) = ply.split_once("end_header\n").unwrap();
        assert!(header.starts_with("ply\nformat ascii 1.0\n"));
        assert!(header.contains("element vertex 6\n") && header.contains("element edge 3\n"));
        assert!(header.contains("property uchar red\n"));
        let rows: Vec<Vec<f64>> = body
            .lines()
            .map(|l| l.split(' ').map(|v| v.parse().unwrap()).collect())
            .collect();
        assert_eq!(rows.len(), 9);
        assert!(rows[..6].iter().all(|r| r.len() == 6));
        assert_eq!(rows[7], vec![2.0, 3.0, 3.0], "second edge, 3 observations");
        let colour = |r: &[f64]| [r[3], r[4], r[5]];
        assert_eq!(
            colour(&rows[0]),
            [120.0, 170.0, 230.0],
            "seen once: light blue"
        );
        assert_eq!(colour(&rows[4]), [180.0, 20.0, 30.0], "seen most: dark red");
        assert_eq!(colour(&rows[0]), colour(&rows[1]), "both ends alike");
    }

    #[test]
    fn a_match_exports_as_ply_in_its_overlay_colours() {
        let segments: Vec<crate::segment::Segment3> = map()
            .iter()
            .map(|m| crate::segment::Segment3 {
                start: m.start,
                end: m.end,
            })
            .collect();
        let ply = segments_to_ply(&segments);
        let (header, body) = ply.split_once("end_header\n").unwrap();
        assert!(header.contains("element vertex 6\n") && header.contains("element edge 3\n"));
        let rows: Vec<&str> = body.lines().collect();
        assert_eq!(rows.len(), 9);
        let [r, g, b] = crate::overlay::colour(2);
        assert!(rows[4].ends_with(&format!(" {r} {g} {b}")), "{}", rows[4]);
        assert_eq!(rows[8], "4 5");
    }

    #[test]
    fn obj_has_vertices_and_lines() {
        let obj = to_obj(&map());
        assert_eq!(obj.lines().filter(|l| l.starts_with("v ")).count(), 6);
        let lines: Vec<_> = obj.lines().filter(|l| l.starts_with("l ")).collect();
        assert_eq!(lines, ["l 1 2", "l 3 4", "l 5 6"]);
    }

    #[test]
    fn svg_draws_one_line_per_segment_every_pose_and_its_frame() {
        let rig = RigMarker::origin();
        let svg = top_view_svg(&map(), &poses(), &[], &rig);
        assert!(svg.starts_with("<svg ") && svg.trim_end().ends_with("</svg>"));
        assert_eq!(svg.matches("<line ").count(), 3);
        assert_eq!(svg.matches("class=\"pose\"").count(), 4);
        assert!(!svg.contains("class=\"prior\""));
        for label in [
            " m</text>",
            "x (m)",
            "y (m)",
            "+y",
            "seen once",
            "seen 5 times",
            "rig",
        ] {
            assert!(svg.contains(label), "{label}");
        }
        assert_eq!(svg.matches('<').count(), svg.matches('>').count());
    }

    #[test]
    fn png_decodes_with_north_up_and_darker_lines_for_more_observations() {
        let rig = RigMarker::origin();
        let png = top_view_png(&map(), &poses(), &[], &rig).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        let l = plan_of(&map(), &poses(), &[], &rig);
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
    fn the_rig_is_drawn_where_its_cameras_are() {
        // Cameras 2 m along the rig's x from its origin: the marker follows them.
        let rig = RigMarker {
            centre: Point3::new(2.0, 0.0, 0.0),
            looking: Vector3::y(),
        };
        let pose = [Isometry3::translation(0.5, 1.0, 1.2)];
        let png = top_view_png(&map(), &pose, &[], &rig).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        let l = plan_of(&map(), &pose, &[], &rig);
        let q = l.px(2.5, 1.0);
        assert_eq!(
            img.get_pixel(q.x.round() as u32, q.y.round() as u32).0,
            POSE_COLOUR
        );
    }

    #[test]
    fn the_poses_as_given_are_drawn_joined_to_the_ones_the_map_uses() {
        let rig = RigMarker::origin();
        let refined = poses();
        let given: Vec<Isometry3<f64>> = refined
            .iter()
            .map(|p| Translation3::new(0.3, -0.2, 0.0) * p)
            .collect();
        let svg = top_view_svg(&map(), &refined, &given, &rig);
        assert_eq!(svg.matches("class=\"prior\"").count(), refined.len());
        assert!(svg.contains("pose as given"));
        let png = top_view_png(&map(), &refined, &given, &rig).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        let l = plan_of(&map(), &refined, &given, &rig);
        let t = given[0].translation.vector;
        let q = l.px(t.x, t.y);
        assert_eq!(
            img.get_pixel(q.x.round() as u32, q.y.round() as u32).0,
            PRIOR_COLOUR
        );
    }

    #[test]
    fn an_empty_map_still_draws() {
        let rig = RigMarker::origin();
        assert!(top_view_svg(&[], &[], &[], &rig).contains("</svg>"));
        image::load_from_memory(&top_view_png(&[], &[], &[], &rig).unwrap()).unwrap();
        assert!(to_ply(&[]).contains("element vertex 0\n"));
    }
}
