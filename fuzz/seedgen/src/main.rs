//! Writes the hand-made seeds of fuzz/corpus/<target>/ (files named `seed-*`): small valid
//! inputs of every kind each target reads, built from the synthetic room so that matching
//! finds something. `cargo run --release` in fuzz/seedgen; the fuzzers' own finds are added
//! and the whole corpus minimised with `.ci/fuzz minimise TARGET` (see docs/FUZZING.md).

use std::io::Cursor;
use std::path::PathBuf;

use image::{DynamicImage, GrayImage, ImageFormat, Luma, Rgb, RgbImage, Rgba};
use prost::Message;
use trinocular::api::{self, pb};
use trinocular::geometry::Rig;
use trinocular::segment::SegmentList;
use trinocular::synth;

fn corpus(target: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../corpus")
        .join(target);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn write(target: &str, name: &str, bytes: &[u8]) {
    let path = corpus(target).join(format!("seed-{name}"));
    std::fs::write(&path, bytes).unwrap();
    println!("{:>6} B  {target}/seed-{name}", bytes.len());
}

/// Seeds `random-LEN` of `target`: xorshift bytes from `state`, one string per length in turn.
fn random_seeds(target: &str, mut state: u64, lengths: &[usize]) {
    for &len in lengths {
        let bytes: Vec<u8> = (0..len)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 24) as u8
            })
            .collect();
        write(target, &format!("random-{len}"), &bytes);
    }
}

fn encoded(image: &DynamicImage, format: ImageFormat) -> Vec<u8> {
    let mut out = Cursor::new(Vec::new());
    image.write_to(&mut out, format).unwrap();
    out.into_inner()
}

/// The segments of `lists` that come from the first `edges` ground-truth edges seen in list 0:
/// lists that match each other, small enough for a seed.
fn trimmed(obs: &synth::Observation, edges: usize) -> [SegmentList; 3] {
    let mut keep: Vec<usize> = Vec::new();
    for t in obs.truth[0].iter().flatten() {
        if !keep.contains(t) && keep.len() < edges {
            keep.push(*t);
        }
    }
    std::array::from_fn(|v| SegmentList {
        oriented: obs.lists[v].oriented,
        background_gradient: None,
        segments: obs.lists[v]
            .segments
            .iter()
            .zip(&obs.truth[v])
            .filter(|(_, t)| t.is_some_and(|t| keep.contains(&t)))
            .map(|(s, _)| *s)
            .collect(),
    })
}

fn triplet(lists: &[SegmentList; 3]) -> pb::SegmentTriplet {
    pb::SegmentTriplet {
        lists: lists.iter().map(api::segment_list_to_pb).collect(),
    }
}

/// The three rendered views of the synthetic room by `rig`, as grey images.
fn rendered(scene: &synth::Scene, rig: &Rig) -> [GrayImage; 3] {
    std::array::from_fn(|i| {
        let cam = rig.camera(i);
        GrayImage::from_raw(cam.width(), cam.height(), synth::render(scene, cam)).unwrap()
    })
}

fn png(image: &GrayImage) -> Vec<u8> {
    encoded(&DynamicImage::ImageLuma8(image.clone()), ImageFormat::Png)
}

/// A `multipart/form-data` body with boundary `X`: (name, file name, bytes) per part.
fn multipart(parts: &[(&str, Option<&str>, &[u8])]) -> Vec<u8> {
    let mut body = Vec::new();
    for (name, file, bytes) in parts {
        body.extend_from_slice(b"--X\r\n");
        match file {
            Some(f) => body.extend_from_slice(
                format!(
                    "Content-Disposition: form-data; name=\"{name}\"; filename=\"{f}\"\r\n\
                     Content-Type: application/octet-stream\r\n\r\n"
                )
                .as_bytes(),
            ),
            None => body.extend_from_slice(
                format!("Content-Disposition: form-data; name=\"{name}\"\r\n\r\n").as_bytes(),
            ),
        }
        body.extend_from_slice(bytes);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(b"--X--\r\n");
    body
}

fn json<T: serde::Serialize>(message: &T) -> Vec<u8> {
    serde_json::to_vec(message).unwrap()
}

fn main() {
    // The room seen at full size (512 x 512): a dozen edges' segments in each view.
    let (_, rig, obs) = synth::standard_capture(1, synth::Defects::clean(), false);
    let lists = trimmed(&obs, 12);
    let calibration = api::calibration_to_pb(&rig);
    let calibration_krt = pb::Calibration {
        cameras: rig
            .cameras()
            .iter()
            .map(|c| api::camera_to_pb(c, true))
            .collect(),
    };
    let plain = pb::MatchRequest {
        calibration: Some(calibration.clone()),
        options: None,
        input: Some(pb::match_request::Input::Segments(triplet(&lists))),
    };
    // Every option, K R t, and segments with gradients and their own noise.
    let mut noisy = triplet(&lists);
    for (i, s) in noisy
        .lists
        .iter_mut()
        .flat_map(|l| &mut l.segments)
        .enumerate()
    {
        s.gradient = Some(20.0 + i as f64);
        if i % 2 == 0 {
            s.offset_sigma_px = Some(0.2);
            s.angle_sigma_deg = Some(0.3);
        }
    }
    let options = pb::MatchOptions {
        depth_min_m: Some(0.5),
        depth_max_m: Some(12.0),
        tolerance_px: Some(2.5),
        angle_tolerance_deg: Some(25.0),
        verify_angle_tolerance_deg: Some(4.0),
        min_length_px: Some(6.0),
        gradient_ratio_max: Some(3.0),
        depth_blind_gradient_ratio_max: Some(1.6),
        validate: Some(true),
        neighbour_radius_px: Some(4.0),
        max_residual_px: Some(1.5),
        line_noise_px: Some(0.3),
        min_gradient: Some(1.0),
        min_gradient_to_background: Some(2.5),
        max_direction_sigma_deg: Some(90.0),
        vertex_reach_px: Some(2.0),
        dominant_directions: Some(true),
        extract: Some(pb::ExtractOptions {
            smoothing_sigma_px: Some(1.0),
            gradient_low: Some(2.0),
            gradient_high: Some(5.0),
            max_deviation_px: Some(0.8),
            min_segment_px: Some(6.0),
        }),
        return_extracted: Some(true),
        gate_direction_deg: Some(5.0),
        gate_position_m: Some(0.02),
        gate_position_rel: Some(0.01),
        gate_confidence: Some(0.95),
        include_uncertain: Some(true),
        list_push_px: Some(1.63),
        list_shift_px: Some(0.1),
    };
    let full = pb::MatchRequest {
        calibration: Some(calibration_krt.clone()),
        options: Some(options),
        input: Some(pb::match_request::Input::Segments(noisy)),
    };

    // The room at 1/16 (32 x 32) and 1/8 (64 x 64, the rig of the HTTP target's session).
    let (scene, tiny) = synth::bench_capture(1, 0.0625);
    let tiny_views = rendered(&scene, &tiny);
    let (_, small) = synth::bench_capture(1, 0.125);
    let small_views = rendered(&scene, &small);
    let small_obs = synth::observe(&scene, &small, &synth::Defects::clean(), 1);
    let raw_images = pb::MatchRequest {
        calibration: Some(api::calibration_to_pb(&tiny)),
        options: Some(pb::MatchOptions {
            return_extracted: Some(true),
            ..Default::default()
        }),
        input: Some(pb::match_request::Input::Images(pb::ImageTriplet {
            images: tiny_views
                .iter()
                .map(|im| pb::Image {
                    source: Some(pb::image::Source::Raw(pb::RawImage {
                        width: im.width(),
                        height: im.height(),
                        data: im.as_raw().clone(),
                    })),
                })
                .collect(),
        })),
    };
    let png_images = pb::MatchRequest {
        calibration: Some(api::calibration_to_pb(&tiny)),
        options: None,
        input: Some(pb::match_request::Input::Images(pb::ImageTriplet {
            images: tiny_views
                .iter()
                .map(|im| pb::Image {
                    source: Some(pb::image::Source::Encoded(png(im))),
                })
                .collect(),
        })),
    };

    // json_body: the plain form (the fast path), every field, images, pbjson-only forms.
    write("json_body", "plain.json", &json(&plain));
    write("json_body", "options-krt.json", &json(&full));
    write("json_body", "raw-images.json", &json(&raw_images));
    write("json_body", "png-images.json", &json(&png_images));
    write(
        "json_body",
        "pbjson-forms.json",
        br#"{"calibration": {"cameras": [{"name": "c", "width": 10, "height": 10, "projection": [1,0,0,0, 0,1,0,0, 0,0,1,0]}, {"width": 10, "height": 10, "projection": ["1","0","0","-0.1", 0,1,0,0, 0,0,1,0], "distortion": {"k1": 0.01}}, {"width": 10, "height": 10, "projection": [1,0,0,0, 0,1,0,-0.1, 0,0,1,0]}]}, "options": {"tolerance_px": 2, "validate": false}, "segments": {"lists": [{"segments": [{"u1": "NaN", "v1": "1.5", "u2": 3, "v2": 4, "offset_sigma_px": 0.1, "angleSigmaDeg": 1}], "oriented": true}, {"segments": [{"u1": 1, "v1": 2, "u2": 3, "v2": 4, "gradient": null}]}, {}]}}"#,
    );

    // protobuf_body: each request message.
    write("protobuf_body", "match.pb", &plain.encode_to_vec());
    write(
        "protobuf_body",
        "match-options-krt.pb",
        &full.encode_to_vec(),
    );
    write(
        "protobuf_body",
        "match-raw-images.pb",
        &raw_images.encode_to_vec(),
    );
    write(
        "protobuf_body",
        "match-png-images.pb",
        &png_images.encode_to_vec(),
    );
    let (_, pattern_rig, pattern) = synth::pattern_views(1);
    let reference = pattern.reference_points();
    // Every 7th corner: both boards, not coplanar, a seed of 3 KB.
    let chosen: Vec<_> = reference.iter().step_by(7).map(|(_, p)| *p).collect();
    let calibrate = pb::CalibrateRequest {
        pattern: None,
        input: Some(pb::calibrate_request::Input::Correspondences(
            pb::Correspondences {
                points_3d: chosen
                    .iter()
                    .map(|p| pb::Point3 {
                        x: p.x,
                        y: p.y,
                        z: p.z,
                    })
                    .collect(),
                points_2d: pattern_rig
                    .cameras()
                    .iter()
                    .map(|c| pb::ImagePoints {
                        points: chosen
                            .iter()
                            .map(|p| {
                                let q = c.project(p).unwrap();
                                pb::Point2 { u: q.x, v: q.y }
                            })
                            .collect(),
                        width: c.width(),
                        height: c.height(),
                    })
                    .collect(),
            },
        )),
        pattern_to_rig: Some(pb::Pose {
            matrix: vec![
                0.0, -1.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.1, 0.0, 0.0, 0.0, 1.0,
            ],
            ..pb::Pose::default()
        }),
        options: Some(pb::CalibrateOptions {
            distortion: Some(true),
            extract: None,
        }),
        camera_names: vec!["left".into(), "right".into(), "top".into()],
    };
    write(
        "protobuf_body",
        "calibrate-correspondences.pb",
        &calibrate.encode_to_vec(),
    );
    let board = pb::GridBoard {
        origin: Some(pb::Point3::default()),
        u_axis: Some(pb::Point3 {
            x: 1.0,
            y: 0.0,
            z: 0.0,
        }),
        v_axis: Some(pb::Point3 {
            x: 0.0,
            y: 0.0,
            z: -1.0,
        }),
        rows: 3,
        cols: 4,
        square: 0.04,
        pitch: 0.06,
        missing: vec![pb::GridCell { row: 1, col: 2 }],
    };
    let calibrate_images = pb::CalibrateRequest {
        pattern: Some(pb::CalibrationPattern {
            boards: vec![board],
        }),
        input: Some(pb::calibrate_request::Input::Images(pb::ImageTriplet {
            images: small_views
                .iter()
                .map(|im| pb::Image {
                    source: Some(pb::image::Source::Encoded(png(im))),
                })
                .collect(),
        })),
        pattern_to_rig: None,
        options: None,
        camera_names: Vec::new(),
    };
    write(
        "protobuf_body",
        "calibrate-images.pb",
        &calibrate_images.encode_to_vec(),
    );
    let small_lists = trimmed(&small_obs, 20);
    let capture = pb::AddCaptureRequest {
        session_id: "0123456789abcdef0123456789abcdef".into(),
        rig_to_world: Some(pb::Pose {
            matrix: vec![
                1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
            ],
            ..pb::Pose::default()
        }),
        input: Some(pb::add_capture_request::Input::Segments(triplet(
            &small_lists,
        ))),
        rig_to_world_covariance: Vec::new(),
        capture_id: "robot-7/capture-0001".into(),
    };
    write("protobuf_body", "capture.pb", &capture.encode_to_vec());
    let session = pb::CreateSessionRequest {
        name: "room".into(),
        calibration: Some(calibration.clone()),
        options: Some(options),
        map_options: Some(pb::MapOptions {
            min_observations: Some(2),
            // Unset, as before the field existed: the seed's bytes are unchanged.
            refine_poses: None,
        }),
        session_id: String::new(),
    };
    write(
        "protobuf_body",
        "create-session.pb",
        &session.encode_to_vec(),
    );

    // image_decode: every format and depth the decoder takes, a few bytes each.
    let grey = GrayImage::from_fn(8, 8, |x, y| Luma([(x * 32 + y * 4) as u8]));
    let rgb = RgbImage::from_fn(8, 8, |x, y| Rgb([(x * 32) as u8, (y * 32) as u8, 128]));
    let rgba16 = image::ImageBuffer::<Rgba<u16>, Vec<u16>>::from_fn(4, 4, |x, y| {
        Rgba([(x * 16000) as u16, (y * 16000) as u16, 500, 40000])
    });
    let grey16 = image::ImageBuffer::<Luma<u16>, Vec<u16>>::from_fn(6, 5, |x, y| {
        Luma([(x * 9000 + y * 100) as u16])
    });
    let grey_alpha = image::ImageBuffer::<image::LumaA<u8>, Vec<u8>>::from_fn(5, 5, |x, y| {
        image::LumaA([(x * 50) as u8, (y * 60) as u8])
    });
    let images: [(&str, DynamicImage, ImageFormat); 14] = [
        (
            "grey.png",
            DynamicImage::ImageLuma8(grey.clone()),
            ImageFormat::Png,
        ),
        (
            "rgb.png",
            DynamicImage::ImageRgb8(rgb.clone()),
            ImageFormat::Png,
        ),
        (
            "rgba16.png",
            DynamicImage::ImageRgba16(rgba16.clone()),
            ImageFormat::Png,
        ),
        (
            "grey16.png",
            DynamicImage::ImageLuma16(grey16.clone()),
            ImageFormat::Png,
        ),
        (
            "grey-alpha.png",
            DynamicImage::ImageLumaA8(grey_alpha),
            ImageFormat::Png,
        ),
        (
            "grey.jpg",
            DynamicImage::ImageLuma8(grey.clone()),
            ImageFormat::Jpeg,
        ),
        (
            "rgb.jpg",
            DynamicImage::ImageRgb8(rgb.clone()),
            ImageFormat::Jpeg,
        ),
        (
            "grey.pgm",
            DynamicImage::ImageLuma8(grey.clone()),
            ImageFormat::Pnm,
        ),
        (
            "rgb.ppm",
            DynamicImage::ImageRgb8(rgb.clone()),
            ImageFormat::Pnm,
        ),
        (
            "grey16.pgm",
            DynamicImage::ImageLuma16(grey16.clone()),
            ImageFormat::Pnm,
        ),
        (
            "grey.tiff",
            DynamicImage::ImageLuma8(grey.clone()),
            ImageFormat::Tiff,
        ),
        (
            "rgb.tiff",
            DynamicImage::ImageRgb8(rgb.clone()),
            ImageFormat::Tiff,
        ),
        (
            "grey.bmp",
            DynamicImage::ImageLuma8(grey.clone()),
            ImageFormat::Bmp,
        ),
        ("rgb.bmp", DynamicImage::ImageRgb8(rgb), ImageFormat::Bmp),
    ];
    for (name, image, format) in &images {
        write("image_decode", name, &encoded(image, *format));
    }
    write(
        "image_decode",
        "ascii.pgm",
        b"P2\n# comment\n3 2\n255\n0 128 255\n12 34 56\n",
    );
    write("image_decode", "bitmap.pbm", b"P1\n4 2\n0 1 0 1\n1 0 1 0\n");
    write("image_decode", "tiny-room.png", &png(&tiny_views[0]));
    write("image_decode", "small-room.png", &png(&small_views[1]));
    // A bright square with a diagonal: edges the extractor chains into segments.
    let shapes = GrayImage::from_fn(40, 40, |x, y| {
        let inside = (8..28).contains(&x) && (10..30).contains(&y);
        let diagonal = x.abs_diff(y) <= 1;
        Luma([if inside {
            200
        } else if diagonal {
            120
        } else {
            30
        }])
    });
    write("image_decode", "shapes.png", &png(&shapes));

    // multipart_body: uploads to /v1/match and to a session's captures.
    let tiny_pngs: Vec<Vec<u8>> = tiny_views.iter().map(png).collect();
    let small_pngs: Vec<Vec<u8>> = small_views.iter().map(png).collect();
    let small_calibration = api::calibration_to_pb(&small);
    write(
        "multipart_body",
        "match-segments",
        &multipart(&[
            ("calibration", None, &json(&small_calibration)),
            (
                "options",
                None,
                br#"{"tolerancePx": 2.5, "validate": true}"#,
            ),
            ("segments", None, &json(&triplet(&small_lists))),
        ]),
    );
    write(
        "multipart_body",
        "match-images",
        &multipart(&[
            ("calibration", None, &json(&api::calibration_to_pb(&tiny))),
            ("options", None, br#"{"returnExtracted": true}"#),
            ("image1", Some("1.png"), &tiny_pngs[0]),
            ("image2", Some("2.png"), &tiny_pngs[1]),
            ("image3", Some("3.png"), &tiny_pngs[2]),
        ]),
    );
    write(
        "multipart_body",
        "capture-segments",
        &multipart(&[
            ("pose", None, b"[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]"),
            ("segments", None, &json(&triplet(&small_lists))),
        ]),
    );
    write(
        "multipart_body",
        "capture-images",
        &multipart(&[
            (
                "pose",
                None,
                br#"{"matrix": [0,-1,0,0.2, 1,0,0,0, 0,0,1,0, 0,0,0,1]}"#,
            ),
            ("image1", Some("1.png"), &small_pngs[0]),
            ("image2", Some("2.png"), &small_pngs[1]),
            ("image3", Some("3.png"), &small_pngs[2]),
        ]),
    );

    // match_whole and session_whole read structured input (the `arbitrary` crate): any bytes
    // are an input, so a few pseudo-random strings of several lengths start them.
    // session_whole's structure puts the captures a step apart and the world's lines ahead of
    // them, so that random bytes already make sessions whose captures register.
    random_seeds("match_whole", 0x9E37_79B9_7F4A_7C15, &[64, 512, 2048, 8192]);
    random_seeds(
        "session_whole",
        0x2545_F491_4F6C_DD1D,
        &[256, 1024, 4096, 16384],
    );
}
