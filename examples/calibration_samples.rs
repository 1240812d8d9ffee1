//! Writes the sample calibration pictures shipped in `examples/calibration/`: what three
//! cameras see of the default pattern (`trinocular pattern` prints it), rendered with more
//! blur and noise than the tests use (1.0 px, 4 grey levels), and the cameras they were
//! rendered with. `trinocular calibrate` on the three pictures recovers those cameras; the
//! test `the_shipped_sample_pictures_calibrate_to_their_cameras` holds it.
//!
//!     cargo run --release --example calibration_samples

use std::path::Path;

use trinocular::api;
use trinocular::synth::{pattern_views, render_triplet, RenderParams};

/// The pose drawn for the samples (any seed gives a valid view; this one is well inside the
/// range `pattern_views` draws from).
const SEED: u64 = 11;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/calibration");
    std::fs::create_dir_all(&dir)?;
    let (scene, rig, _) = pattern_views(SEED);
    let params = RenderParams {
        blur_sigma_px: 1.0,
        noise_sigma: 4.0,
        ..RenderParams::default()
    };
    for (i, image) in render_triplet(&scene, &rig, &params, SEED)
        .iter()
        .enumerate()
    {
        let path = dir.join(format!("camera{}.png", i + 1));
        std::fs::write(&path, trinocular::overlay::grey_png(image)?)?;
        println!("{}", path.display());
    }
    let truth = dir.join("true_calibration.json");
    std::fs::write(&truth, api::to_json(&api::calibration_to_pb(&rig)) + "\n")?;
    println!("{}", truth.display());
    Ok(())
}
