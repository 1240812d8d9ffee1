//! Writes the two `MatchRequest`s the load figures are measured with, in proto3 JSON:
//!
//! - `segments600.json`: 600 segments per image (the `match/600` bench's scattered capture);
//! - `images512.json`: a 512×512 PNG triplet of the standard rendered room.
//!
//!     cargo run --release --example load_requests -- DIR

use trinocular::api::{self, pb};
use trinocular::synth::{bench_capture, render_triplet, scattered_capture, RenderParams};

fn write(path: std::path::PathBuf, request: &pb::MatchRequest) -> std::io::Result<()> {
    std::fs::write(&path, api::to_json(request) + "\n")?;
    println!("{}", path.display());
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| ".".into()));
    std::fs::create_dir_all(&dir)?;

    let (rig, lists) = scattered_capture(600, 0.3, 0.2, 1);
    let segments = pb::MatchRequest {
        calibration: Some(api::calibration_to_pb(&rig)),
        options: None,
        input: Some(pb::match_request::Input::Segments(pb::SegmentTriplet {
            lists: lists.iter().map(api::segment_list_to_pb).collect(),
        })),
    };
    write(dir.join("segments600.json"), &segments)?;

    let (scene, rig) = bench_capture(1, 1.0);
    let images = render_triplet(&scene, &rig, &RenderParams::default(), 1)
        .iter()
        .map(|image| {
            Ok(pb::Image {
                source: Some(pb::image::Source::Encoded(trinocular::overlay::grey_png(
                    image,
                )?)),
            })
        })
        .collect::<Result<Vec<_>, Box<dyn std::error::Error>>>()?;
    let images = pb::MatchRequest {
        calibration: Some(api::calibration_to_pb(&rig)),
        options: None,
        input: Some(pb::match_request::Input::Images(pb::ImageTriplet {
            images,
        })),
    };
    write(dir.join("images512.json"), &images)?;
    Ok(())
}
