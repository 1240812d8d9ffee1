//! A whole session through the real HTTP router: a rig from a few numbers (as `match_whole`
//! builds it), a small world of 3D segments, then two to four captures of it from poses a
//! few metres apart, each posted as an AddCapture of segment lists with a prior that is off
//! by a little or by anything (now and then one raw number in the pose or its covariance),
//! and the map read back in every format, its poses solved. `multipart_body` reaches
//! AddCapture too, but always on an empty session: here the later captures are registered to
//! a map, paired with the earlier ones and tied into the pose graph, which is where a hostile
//! client's segments and priors meet the session's numerics. Whatever the input, every answer
//! is a client error or a success, never a 5xx; an accepted capture answers a registration.

use arbitrary::{Arbitrary, Unstructured};
use axum::body::Body;
use axum::http::{Request, StatusCode};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use trinocular::api::{self, pb};
use trinocular::geometry::Camera;

use crate::match_whole::{self, Extra, Options, RigSeed};
use crate::Http;

/// Most segments per list (each capture's), so that one execution stays short.
const MAX_SEGMENTS: usize = 120;
/// Most captures per input.
const MAX_CAPTURES: usize = 4;
/// Most world lines per input.
const MAX_LINES: usize = 160;

#[derive(Arbitrary, Debug)]
struct Head {
    rig: RigSeed,
    oriented: [bool; 3],
    /// The session's match options, one time in eight (most of them refuse the session).
    options: (u8, Options),
    captures: [CaptureSeed; MAX_CAPTURES],
    /// How many of `captures` are posted: 2 + this modulo 3.
    count: u8,
}

/// Where one capture is taken from, and what its odometry says.
#[derive(Arbitrary, Debug)]
struct CaptureSeed {
    /// The true pose from the previous capture's (the first's from the world's origin): x and
    /// y in 4-mm steps (±0.5 m), heading in 0.2-degree steps (±25°), so that captures overlap.
    step: [i8; 3],
    /// The prior's error: heading in 0.1-degree steps, x and y in millimetres.
    off: [i8; 3],
    covariance: Covariance,
    /// One number of the pose as sent (its 16 matrix entries) set to anything, one time in
    /// sixteen.
    raw_pose: (u8, u8, f64),
    /// A capture sent with no pose (refused, naming it) when 0: one time in 256.
    no_pose: u8,
}

/// The prior's covariance as sent, by `kind`: none (the service's default) for 0–127, else
/// diagonal with each standard deviation 10^(-diagonal/32) (1 down to 1e-8) up to 223, the
/// default odometry's diagonal with the number `raw.0` (of 36) set to `raw.1` up to 239, and
/// `raw.0` modulo 40 numbers (a wrong count, mostly) for the rest.
#[derive(Arbitrary, Debug)]
struct Covariance {
    kind: u8,
    diagonal: [u8; 6],
    raw: (u8, f64),
}

#[derive(Debug)]
pub struct Input {
    head: Head,
    ops: Vec<Op>,
}

impl<'a> Arbitrary<'a> for Input {
    fn arbitrary(u: &mut Unstructured<'a>) -> arbitrary::Result<Input> {
        let head = Head::arbitrary(u)?;
        let ops = crate::ops_until_exhausted(u, MAX_LINES)?;
        Ok(Input { head, ops })
    }
}

#[derive(Arbitrary, Debug)]
enum Op {
    /// A 3D segment of the world ahead of the first capture (y 0.5 to 16.4 m, x and the
    /// height above the rig within ±y/2), seen by every capture that has it in front of its
    /// cameras, with pixel noise (1/64 px steps, the same for every capture).
    Line {
        a: (i8, u8, i8),
        b: (i8, u8, i8),
        noise: [[i8; 4]; 3],
        extra: Extra,
    },
    /// A segment in one view of one capture only (1/65535 of a side steps).
    Stray {
        capture: u8,
        view: u8,
        ends: [u16; 4],
        extra: Extra,
    },
}

/// The captures' true rig-to-world poses: the rig's x right, y forward, z up, 1.2 m above
/// the floor, each a step (and a turn about the vertical) from the one before.
fn truths(seeds: &[CaptureSeed]) -> Vec<Isometry3<f64>> {
    let mut pose = Isometry3::translation(0.0, 0.0, 1.2);
    let mut out = Vec::with_capacity(seeds.len());
    for (i, seed) in seeds.iter().enumerate() {
        if i > 0 {
            let [x, y, yaw] = seed.step.map(f64::from);
            pose *= Isometry3::from_parts(
                Translation3::new(x * 0.004, y * 0.004, 0.0),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), (yaw * 0.2).to_radians()),
            );
        }
        out.push(pose);
    }
    out
}

/// The pose the robot believes: the truth moved by the seed's error.
fn prior(truth: &Isometry3<f64>, seed: &CaptureSeed) -> Isometry3<f64> {
    let [yaw, x, y] = seed.off.map(f64::from);
    Isometry3::from_parts(
        Translation3::new(
            truth.translation.x + x / 1000.0,
            truth.translation.y + y / 1000.0,
            truth.translation.z,
        ),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), (yaw * 0.1).to_radians())
            * truth.rotation,
    )
}

fn pose_pb(truth: &Isometry3<f64>, seed: &CaptureSeed) -> pb::Pose {
    let m = prior(truth, seed).to_homogeneous();
    let mut matrix: Vec<f64> = (0..16).map(|i| m[(i / 4, i % 4)]).collect();
    let (chance, i, value) = seed.raw_pose;
    if chance < 16 {
        matrix[usize::from(i) % 16] = value;
    }
    pb::Pose {
        matrix,
        ..Default::default()
    }
}

fn covariance(c: &Covariance) -> Vec<f64> {
    let diagonal = |sigmas: [f64; 6]| {
        let mut m = vec![0.0; 36];
        for (i, s) in sigmas.iter().enumerate() {
            m[i * 7] = s * s;
        }
        m
    };
    let odometry = [
        0.3f64.to_radians(),
        0.3f64.to_radians(),
        3f64.to_radians(),
        0.05,
        0.05,
        0.01,
    ];
    let (i, value) = c.raw;
    match c.kind {
        0..=127 => Vec::new(),
        128..=223 => diagonal(c.diagonal.map(|e| 10f64.powf(-f64::from(e) / 32.0))),
        224..=239 => {
            let mut m = diagonal(odometry);
            m[usize::from(i) % 36] = value;
            m
        }
        _ => vec![1e-4; usize::from(i) % 40],
    }
}

/// Each capture's three lists: the world's lines in its views, and its strays.
fn lists(
    cams: &[Camera; 3],
    input: &Input,
    truths: &[Isometry3<f64>],
) -> Vec<[Vec<pb::Segment>; 3]> {
    let captures = truths.len();
    let mut out: Vec<[Vec<pb::Segment>; 3]> = vec![Default::default(); captures];
    for (c, lists) in out.iter_mut().enumerate() {
        let world_to_rig = truths[c].inverse();
        for op in &input.ops {
            match op {
                Op::Line { a, b, noise, extra } => {
                    let point = |&(x, y, z): &(i8, u8, i8)| {
                        let y = 0.5 + f64::from(y) / 16.0;
                        let across = |n: i8| f64::from(n) / 256.0 * y;
                        world_to_rig * Point3::new(across(x), y, 1.2 + across(z))
                    };
                    let (a, b) = (point(a), point(b));
                    for (v, cam) in cams.iter().enumerate() {
                        if lists[v].len() >= MAX_SEGMENTS {
                            continue;
                        }
                        let (Some(pa), Some(pb)) = (cam.project(&a), cam.project(&b)) else {
                            continue;
                        };
                        let n = noise[v].map(|e| f64::from(e) / 64.0);
                        let s = match_whole::segment(
                            pa.x + n[0],
                            pa.y + n[1],
                            pb.x + n[2],
                            pb.y + n[3],
                        );
                        let (w, h) = (f64::from(cam.width()), f64::from(cam.height()));
                        let inside =
                            |u: f64, v: f64| (0.0..=w).contains(&u) && (0.0..=h).contains(&v);
                        if inside(s.u1, s.v1) && inside(s.u2, s.v2) {
                            lists[v].push(match_whole::with_extra(s, *extra));
                        }
                    }
                }
                Op::Stray {
                    capture,
                    view,
                    ends,
                    extra,
                } => {
                    let v = usize::from(*view % 3);
                    if usize::from(*capture) % captures != c || lists[v].len() >= MAX_SEGMENTS {
                        continue;
                    }
                    let (w, h) = (f64::from(cams[v].width()), f64::from(cams[v].height()));
                    let at = |n: u16, side: f64| f64::from(n) / 65535.0 * side;
                    let s = match_whole::segment(
                        at(ends[0], w),
                        at(ends[1], h),
                        at(ends[2], w),
                        at(ends[3], h),
                    );
                    lists[v].push(match_whole::with_extra(s, *extra));
                }
            }
        }
    }
    out
}

fn send(http: &Http, request: Request<Body>) -> (StatusCode, Vec<u8>) {
    let answer = http.send_checked(request);
    (answer.status, answer.body)
}

fn post_json(http: &Http, uri: &str, json: String) -> (StatusCode, Vec<u8>) {
    send(
        http,
        Request::post(uri)
            .header("content-type", "application/json")
            .body(Body::from(json))
            .unwrap(),
    )
}

/// One input as libFuzzer's bytes (read as `match_whole` reads its own).
pub fn run(data: &[u8]) {
    if let Ok(input) = Input::arbitrary_take_rest(Unstructured::new(data)) {
        crate::debug(|| format!("{input:?}"));
        run_input(input);
    }
}

/// One structured input: the session created, its captures added, its map read, deleted.
pub fn run_input(input: Input) {
    let Some(cams) = match_whole::cameras(&input.head.rig) else {
        return;
    };
    let http = Http::get();
    let create = pb::CreateSessionRequest {
        name: "fuzz".into(),
        calibration: Some(pb::Calibration {
            cameras: cams.iter().map(|c| api::camera_to_pb(c, true)).collect(),
        }),
        options: (input.head.options.0 < 32).then(|| match_whole::options(&input.head.options.1)),
        map_options: None,
        session_id: String::new(),
    };
    let (status, body) = post_json(http, "/v1/sessions", api::to_json(&create));
    if status != StatusCode::OK {
        return;
    }
    let session: pb::Session = api::from_json("session", std::str::from_utf8(&body).unwrap())
        .expect("an accepted session answers a Session");
    let captures = 2 + usize::from(input.head.count) % (MAX_CAPTURES - 1);
    let truths = truths(&input.head.captures[..captures]);
    let lists = lists(&cams, &input, &truths);
    let uri = format!("/v1/sessions/{}/captures", session.id);
    for ((seed, truth), lists) in input.head.captures.iter().zip(&truths).zip(lists) {
        let request = pb::AddCaptureRequest {
            session_id: session.id.clone(),
            rig_to_world: (seed.no_pose != 0).then(|| pose_pb(truth, seed)),
            input: Some(pb::add_capture_request::Input::Segments(
                pb::SegmentTriplet {
                    lists: lists
                        .into_iter()
                        .zip(input.head.oriented)
                        .map(|(segments, oriented)| pb::SegmentList {
                            segments,
                            oriented,
                            background_gradient: None,
                        })
                        .collect(),
                },
            )),
            rig_to_world_covariance: covariance(&seed.covariance),
            capture_id: String::new(),
        };
        let (status, body) = post_json(http, &uri, api::to_json(&request));
        if status == StatusCode::OK {
            let added: pb::AddCaptureResponse =
                api::from_json("answer", std::str::from_utf8(&body).unwrap())
                    .expect("an accepted capture answers an AddCaptureResponse");
            let registration = added.registration.expect("an added capture's registration");
            crate::debug(|| {
                format!(
                    "capture {}: {} 3D segments, registration {:?}, {} inliers",
                    added.capture_index,
                    added.r#match.as_ref().map_or(0, |m| m.segments_3d.len()),
                    registration.status(),
                    registration.inliers
                )
            });
        }
    }
    for format in ["json", "svg", "png", "ply"] {
        send(
            http,
            Request::get(format!("/v1/sessions/{}/map?format={format}", session.id))
                .body(Body::empty())
                .unwrap(),
        );
    }
    let (status, _) = send(
        http,
        Request::delete(format!("/v1/sessions/{}", session.id))
            .body(Body::empty())
            .unwrap(),
    );
    assert_eq!(status, StatusCode::OK, "deleting the session");
}
