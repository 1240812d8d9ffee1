//! Calibration figures on rendered views of the default pattern (noise and blur): for each of
//! N random rigs, the time of one Calibrate call on its 512×512 PNG triplet (decoding,
//! detection and estimation of the three cameras) and, per camera, the RMS distance between
//! where the true and the recovered projection matrices put points of the scene around the
//! pattern (not its reference points).
//!
//!     cargo run --release --example calibration_figures -- [N]

use std::time::Instant;

use nalgebra::Point3;
use trinocular::api::{self, pb};
use trinocular::synth::{pattern_views, render_triplet, RenderParams, Rng};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let n: u64 = std::env::args().nth(1).map_or(Ok(10), |a| a.parse())?;
    let (mut ms, mut rms, mut fitted) = (Vec::new(), Vec::new(), Vec::new());
    for seed in 1..=n {
        let (scene, truth, _) = pattern_views(seed);
        let images = render_triplet(&scene, &truth, &RenderParams::default(), seed)
            .iter()
            .map(|image| {
                Ok(pb::Image {
                    source: Some(pb::image::Source::Encoded(trinocular::overlay::grey_png(
                        image,
                    )?)),
                })
            })
            .collect::<Result<Vec<_>, Box<dyn std::error::Error>>>()?;
        let request = pb::CalibrateRequest {
            input: Some(pb::calibrate_request::Input::Images(pb::ImageTriplet {
                images,
            })),
            ..Default::default()
        };
        // Best of three, so that one-off page faults do not count.
        let mut best = f64::INFINITY;
        let mut response = None;
        for _ in 0..3 {
            let t = Instant::now();
            let r = api::calibrate::calibrate_request(&request, &Default::default())?.run()?;
            best = best.min(t.elapsed().as_secs_f64() * 1e3);
            response = Some(r);
        }
        let response = response.expect("three runs");
        ms.push(best);
        let recovered = api::rig_from_calibration(response.calibration.as_ref())?;
        let mut rng = Rng::new(seed);
        for view in 0..3 {
            fitted.push(response.reports[view].rms_px);
            let (t, r) = (truth.camera(view), recovered.camera(view));
            let (mut sum, mut k) = (0.0, 0);
            while k < 500 {
                let p = Point3::new(
                    rng.range(-0.1, 0.6),
                    rng.range(-0.1, 0.6),
                    rng.range(-0.1, 0.7),
                );
                let (Some(a), Some(b)) = (t.project(&p), r.project(&p)) else {
                    continue;
                };
                if a.x < 0.0 || a.y < 0.0 || a.x >= t.width() as f64 || a.y >= t.height() as f64 {
                    continue;
                }
                sum += (a - b).norm_squared();
                k += 1;
            }
            rms.push((sum / k as f64).sqrt());
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
    println!(
        "{n} rigs, {} cameras: scene-point RMS against the true P median {:.3} px, max {:.3} px; \
         fit RMS median {:.3} px, max {:.3} px; Calibrate call (best of 3) median {:.1} ms, max {:.1} ms",
        rms.len(),
        median(&mut rms),
        max(&rms),
        median(&mut fitted),
        max(&fitted),
        median(&mut ms),
        max(&ms),
    );
    Ok(())
}
