//! Writes the images `benches/extract.rs` measures on (camera 1 of the standard room at 512
//! and 1024 px), so that peers outside Rust (OpenCV, `tools/peer_opencv.py`) can be timed on
//! the very same pixels.
//!
//!     cargo run --release --example bench_images -- DIR

use trinocular::synth::{bench_capture, render_triplet, RenderParams};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| ".".into()));
    std::fs::create_dir_all(&dir)?;
    for scale in [1u32, 2] {
        let (scene, rig) = bench_capture(1, f64::from(scale));
        let images = render_triplet(&scene, &rig, &RenderParams::default(), 1);
        let img = &images[0];
        let path = dir.join(format!("room_{}.png", img.width()));
        std::fs::write(&path, trinocular::overlay::grey_png(img)?)?;
        println!("{}", path.display());
    }
    Ok(())
}
