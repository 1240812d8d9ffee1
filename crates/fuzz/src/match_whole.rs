//! The whole match of segment input: a structured generator builds a valid-ish rig from a few
//! numbers and three segment lists (3D segments projected into the views with noise, strays,
//! duplicates and near-duplicates, now and then one raw number), then the request is converted and matched as the service
//! does (`api::match_request`, `RunMatch::run_until`), and the answer is checked for
//! consistency. At most `MAX_SEGMENTS` segments per list keep one execution short.

use arbitrary::{Arbitrary, Unstructured};
use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use trinocular::api::{self, pb, RunError, RunMatch};
use trinocular::geometry::{Camera, Distortion};
use trinocular::pipeline::Checkpoint;

const MAX_SEGMENTS: usize = 300;

/// What the input bytes are read as: the fixed part, then operations until the bytes run out.
#[derive(Arbitrary, Debug)]
struct Head {
    rig: RigSeed,
    /// The calibration as K, R, t (else as projection matrices).
    krt: bool,
    oriented: [bool; 3],
    options: Option<Options>,
    /// At most one number of one segment set to anything (NaN, infinities, outside the image,
    /// negative sigmas...), for the input checks.
    raw: Option<Raw>,
}

#[derive(Arbitrary, Debug)]
struct Raw {
    view: u8,
    index: u16,
    /// u1, v1, u2, v2, gradient, offset sigma, angle sigma, shift sigma for 0 to 7; none for
    /// the rest
    /// (most inputs: a random number would make nearly every request fail its checks).
    field: u8,
    value: f64,
}

#[derive(Debug)]
pub struct Input {
    head: Head,
    ops: Vec<Op>,
}

/// Most operations read from one input.
const MAX_OPS: usize = 3 * MAX_SEGMENTS;

impl<'a> Arbitrary<'a> for Input {
    fn arbitrary(u: &mut Unstructured<'a>) -> arbitrary::Result<Input> {
        let head = Head::arbitrary(u)?;
        let ops = crate::ops_until_exhausted(u, MAX_OPS)?;
        Ok(Input { head, ops })
    }
}

#[derive(Arbitrary, Debug)]
pub(crate) struct RigSeed {
    /// Image size: 16 + 4 n pixels.
    size: [u8; 2],
    /// Focal length, relative to the image side: 0.3 to 1.3.
    focal: u8,
    /// Distance between cameras 1 and 2, centimetres (+1).
    baseline: u8,
    /// Camera 3's offset from the middle of that baseline, centimetres: (0, 0, 0) makes the
    /// rig collinear, and equal centres make it invalid.
    offset: [i8; 3],
    /// Each camera's yaw, pitch and roll, 0.05 degree steps (±6.4°).
    tilt: [[i8; 3]; 3],
    /// Principal point offset, 1/1280 of the image side steps (±10%).
    principal: [i8; 2],
    /// Radial distortion k1, thousandths.
    distortion: Option<i8>,
}

#[derive(Debug)]
enum Op {
    /// A 3D segment in front of the rig, projected into the views with pixel noise (1/64 px
    /// steps) on its image ends; hidden from the views whose bit in `hidden` is set when its
    /// top bits are 0 (one time in eight).
    Line {
        a: [i8; 3],
        b: [i8; 3],
        noise: [[i8; 4]; 3],
        hidden: u8,
        extra: Extra,
    },
    /// A segment in one view only, anywhere in the image (1/65535 of a side steps).
    Stray {
        view: u8,
        ends: [u16; 4],
        extra: Extra,
    },
    /// A copy of a segment already in a list: as it is, reversed, or moved by 1/256 px steps.
    Copy {
        view: u8,
        index: u16,
        reversed: bool,
        jitter: Option<[i8; 4]>,
    },
}

impl<'a> Arbitrary<'a> for Op {
    fn arbitrary(u: &mut Unstructured<'a>) -> arbitrary::Result<Op> {
        // Mostly lines seen in the three views, which matching turns into triplets.
        Ok(match u8::arbitrary(u)? {
            0..=179 => Op::Line {
                a: u.arbitrary()?,
                b: u.arbitrary()?,
                noise: u.arbitrary()?,
                hidden: u.arbitrary()?,
                extra: u.arbitrary()?,
            },
            180..=229 => Op::Stray {
                view: u.arbitrary()?,
                ends: u.arbitrary()?,
                extra: u.arbitrary()?,
            },
            _ => Op::Copy {
                view: u.arbitrary()?,
                index: u.arbitrary()?,
                reversed: u.arbitrary()?,
                jitter: u.arbitrary()?,
            },
        })
    }
}

#[derive(Arbitrary, Debug, Clone, Copy)]
pub(crate) struct Extra {
    gradient: Option<u8>,
    /// Offset (1/64 px) and angle (1/32 degree) sigmas.
    noise: Option<(u8, u8)>,
}

#[derive(Arbitrary, Debug)]
pub(crate) struct Options {
    /// Each of the nineteen numeric options, from 0 to 4 times its default (steps of 1/64).
    scaled: [Option<u8>; 19],
    /// One option set to any number (index modulo 19).
    raw: Option<(u8, f64)>,
    validate: Option<bool>,
    include_uncertain: Option<bool>,
    dominant_directions: Option<bool>,
}

/// The numeric options, as (default, setter): the order of `Options::scaled`.
type Setter = fn(&mut pb::MatchOptions, f64);
const NUMERIC: [(f64, Setter); 19] = [
    (0.3, |o, v| o.depth_min_m = Some(v)),
    (15.0, |o, v| o.depth_max_m = Some(v)),
    (2.0, |o, v| o.tolerance_px = Some(v)),
    (30.0, |o, v| o.angle_tolerance_deg = Some(v)),
    (3.0, |o, v| o.verify_angle_tolerance_deg = Some(v)),
    (8.0, |o, v| o.min_length_px = Some(v)),
    (3.0, |o, v| o.gradient_ratio_max = Some(v)),
    (1.6, |o, v| o.depth_blind_gradient_ratio_max = Some(v)),
    (4.0, |o, v| o.neighbour_radius_px = Some(v)),
    (1.5, |o, v| o.max_residual_px = Some(v)),
    (0.3, |o, v| o.line_noise_px = Some(v)),
    (1.63, |o, v| o.list_push_px = Some(v)),
    (0.1, |o, v| o.list_shift_px = Some(v)),
    (180.0, |o, v| o.max_direction_sigma_deg = Some(v)),
    (2.0, |o, v| o.vertex_reach_px = Some(v)),
    (5.0, |o, v| o.gate_direction_deg = Some(v)),
    (0.02, |o, v| o.gate_position_m = Some(v)),
    (0.01, |o, v| o.gate_position_rel = Some(v)),
    (0.95, |o, v| o.gate_confidence = Some(v)),
];

pub(crate) fn options(o: &Options) -> pb::MatchOptions {
    let mut out = pb::MatchOptions {
        validate: o.validate,
        include_uncertain: o.include_uncertain,
        dominant_directions: o.dominant_directions,
        ..Default::default()
    };
    for (scaled, (default, set)) in o.scaled.iter().zip(NUMERIC) {
        if let Some(n) = scaled {
            set(&mut out, default * f64::from(*n) / 64.0);
        }
    }
    if let Some((i, v)) = o.raw {
        (NUMERIC[usize::from(i) % NUMERIC.len()].1)(&mut out, v);
    }
    out
}

/// The three cameras, or `None` where the seed makes an invalid one.
pub(crate) fn cameras(seed: &RigSeed) -> Option<[Camera; 3]> {
    let (w, h) = (
        16 + 4 * u32::from(seed.size[0]),
        16 + 4 * u32::from(seed.size[1]),
    );
    let side = f64::from(w.max(h));
    let f = side * (0.3 + f64::from(seed.focal) / 256.0);
    let k = Matrix3::new(
        f,
        0.0,
        f64::from(w) / 2.0 + f64::from(seed.principal[0]) * side / 1280.0,
        0.0,
        f,
        f64::from(h) / 2.0 + f64::from(seed.principal[1]) * side / 1280.0,
        0.0,
        0.0,
        1.0,
    );
    let b = (1.0 + f64::from(seed.baseline)) / 100.0;
    let o = seed.offset.map(|v| f64::from(v) / 100.0);
    let centres = [
        Vector3::zeros(),
        Vector3::new(b, 0.0, 0.0),
        Vector3::new(b / 2.0 + o[0], o[1], o[2]),
    ];
    // Rig (x right, y forward, z up) to camera (x right, y down, z forward).
    let base = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0);
    let distortion = seed.distortion.map(|k1| Distortion {
        k1: f64::from(k1) / 1000.0,
        k2: 0.0,
        p1: 0.0,
        p2: 0.0,
        k3: 0.0,
    });
    let mut built = Vec::with_capacity(3);
    for (i, c) in centres.iter().enumerate() {
        let [yaw, pitch, roll] = seed.tilt[i].map(|v| (f64::from(v) * 0.05).to_radians());
        let r = Rotation3::from_euler_angles(roll, pitch, yaw).into_inner() * base;
        let t = -(r * c);
        built.push(Camera::from_krt(format!("cam{}", i + 1), w, h, k, r, t, distortion).ok()?);
    }
    built.try_into().ok()
}

pub(crate) fn with_extra(mut s: pb::Segment, extra: Extra) -> pb::Segment {
    s.gradient = extra.gradient.map(f64::from);
    if let Some((offset, angle)) = extra.noise {
        s.offset_sigma_px = Some((1.0 + f64::from(offset)) / 64.0);
        s.angle_sigma_deg = Some((1.0 + f64::from(angle)) / 32.0);
    }
    s
}

pub(crate) fn segment(u1: f64, v1: f64, u2: f64, v2: f64) -> pb::Segment {
    pb::Segment {
        u1,
        v1,
        u2,
        v2,
        ..Default::default()
    }
}

fn lists(cams: &[Camera; 3], input: &Input) -> [Vec<pb::Segment>; 3] {
    let mut lists: [Vec<pb::Segment>; 3] = Default::default();
    for op in &input.ops {
        match op {
            Op::Line {
                a,
                b,
                noise,
                hidden,
                extra,
            } => {
                // Depth (rig y) 0.25 to 16 m; x and z within ±depth/2, in the views mostly.
                let point = |p: &[i8; 3]| {
                    let depth = 0.25 + f64::from(p[1] as u8) / 16.0;
                    Point3::new(
                        f64::from(p[0]) / 256.0 * depth,
                        depth,
                        f64::from(p[2]) / 256.0 * depth,
                    )
                };
                let (a, b) = (point(a), point(b));
                let hidden = if hidden >> 3 == 0 { *hidden } else { 0 };
                for (v, cam) in cams.iter().enumerate() {
                    if hidden & (1 << v) != 0 || lists[v].len() >= MAX_SEGMENTS {
                        continue;
                    }
                    let (Some(pa), Some(pb)) = (cam.project(&a), cam.project(&b)) else {
                        continue;
                    };
                    let n = noise[v].map(|e| f64::from(e) / 64.0);
                    let s = segment(pa.x + n[0], pa.y + n[1], pb.x + n[2], pb.y + n[3]);
                    let (w, h) = (f64::from(cam.width()), f64::from(cam.height()));
                    let inside = |u: f64, v: f64| (0.0..=w).contains(&u) && (0.0..=h).contains(&v);
                    if inside(s.u1, s.v1) && inside(s.u2, s.v2) {
                        lists[v].push(with_extra(s, *extra));
                    }
                }
            }
            Op::Stray { view, ends, extra } => {
                let v = usize::from(*view % 3);
                let (w, h) = (f64::from(cams[v].width()), f64::from(cams[v].height()));
                let at = |n: u16, side: f64| f64::from(n) / 65535.0 * side;
                if lists[v].len() < MAX_SEGMENTS {
                    let s = segment(
                        at(ends[0], w),
                        at(ends[1], h),
                        at(ends[2], w),
                        at(ends[3], h),
                    );
                    lists[v].push(with_extra(s, *extra));
                }
            }
            Op::Copy {
                view,
                index,
                reversed,
                jitter,
            } => {
                let v = usize::from(*view % 3);
                let list = &mut lists[v];
                if !list.is_empty() && list.len() < MAX_SEGMENTS {
                    let mut s = list[usize::from(*index) % list.len()];
                    if *reversed {
                        (s.u1, s.v1, s.u2, s.v2) = (s.u2, s.v2, s.u1, s.v1);
                    }
                    if let Some(j) = jitter {
                        let j = j.map(|e| f64::from(e) / 256.0);
                        (s.u1, s.v1, s.u2, s.v2) =
                            (s.u1 + j[0], s.v1 + j[1], s.u2 + j[2], s.v2 + j[3]);
                    }
                    list.push(s);
                }
            }
        }
    }
    if let Some(raw) = &input.head.raw {
        let list = &mut lists[usize::from(raw.view % 3)];
        if !list.is_empty() {
            let n = list.len();
            let s = &mut list[usize::from(raw.index) % n];
            match raw.field {
                0 => s.u1 = raw.value,
                1 => s.v1 = raw.value,
                2 => s.u2 = raw.value,
                3 => s.v2 = raw.value,
                4 => s.gradient = Some(raw.value),
                5 => s.offset_sigma_px = Some(raw.value),
                6 => s.angle_sigma_deg = Some(raw.value),
                7 => s.shift_sigma_px = Some(raw.value),
                _ => {}
            }
        }
    }
    lists
}

/// One input as libFuzzer's bytes: read as an [`Input`] the way `fuzz_target!` reads a typed
/// input (all the bytes; bytes that do not read as one are not run), then matched.
pub fn run(data: &[u8]) {
    if let Ok(input) = Input::arbitrary_take_rest(Unstructured::new(data)) {
        crate::debug(|| format!("{input:?}"));
        run_input(input);
    }
}

/// One structured input, matched and its answer checked.
pub fn run_input(input: Input) {
    let Some(cams) = cameras(&input.head.rig) else {
        return;
    };
    let lists = lists(&cams, &input);
    let lengths = lists.each_ref().map(|l| l.len());
    let request = pb::MatchRequest {
        calibration: Some(pb::Calibration {
            cameras: cams
                .iter()
                .map(|c| api::camera_to_pb(c, input.head.krt))
                .collect(),
        }),
        options: input.head.options.as_ref().map(options),
        input: Some(pb::match_request::Input::Segments(pb::SegmentTriplet {
            lists: lists
                .into_iter()
                .zip(input.head.oriented)
                .map(|(segments, oriented)| pb::SegmentList {
                    segments,
                    oriented,
                    background_gradient: None,
                })
                .collect(),
        })),
    };
    let checked = match api::match_request(&request, &crate::request_limits()) {
        Ok(checked) => checked,
        Err(e) => {
            crate::debug(|| format!("lists {lengths:?}: match_request: {e}"));
            return;
        }
    };
    let response = match checked.run_until(Checkpoint::NEVER) {
        Ok(response) => response,
        Err(RunError::Input(e)) => {
            crate::debug(|| format!("lists {lengths:?}: run: {e}"));
            return;
        }
        Err(e @ RunError::Stopped { .. }) => panic!("stopped with no checkpoint: {e}"),
    };
    // The answer refers to what was asked, and its numbers are numbers.
    for t in &response.triplets {
        for (v, s) in [t.s1, t.s2, t.s3].into_iter().enumerate() {
            assert!(
                (s as usize) < lengths[v],
                "triplet {t:?} outside list {v} of {}",
                lengths[v]
            );
        }
        assert!(t.residual_px.is_finite(), "{t:?}");
    }
    for s in &response.segments_3d {
        assert!((s.triplet as usize) < response.triplets.len(), "{s:?}");
        assert!(
            s.triplets
                .iter()
                .all(|&t| (t as usize) < response.triplets.len()),
            "{s:?}"
        );
        for p in [s.start, s.end] {
            let p = p.expect("both ends");
            assert!(
                p.x.is_finite() && p.y.is_finite() && p.z.is_finite(),
                "{s:?}"
            );
        }
    }
    crate::debug(|| {
        format!(
            "lists {lengths:?}: {} triplets, {} 3D segments",
            response.triplets.len(),
            response.segments_3d.len()
        )
    });
    let stats = response.stats.expect("stats");
    assert_eq!(stats.segments_in, lengths.map(|n| n as u32).to_vec());
}
