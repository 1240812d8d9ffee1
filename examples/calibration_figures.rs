//! Calibration figures on rendered views of the default pattern (noise and blur): for each of
//! N random rigs, the time of one Calibrate call on its 512×512 PNG triplet (decoding,
//! detection and estimation of the three cameras) and, per camera, the RMS distance between
//! where the true and the recovered projection matrices put points of the scene around the
//! pattern (not its reference points); and the 3D reconstruction of the synthetic room
//! (`Defects::noisy` lists, as the README's figures were measured) seen by the rig, matched
//! once with the true and once with the
//! recovered calibration: median endpoint distance to the true edges, and their ratio.
//!
//!     cargo run --release --example calibration_figures -- [N]

use std::time::Instant;

use nalgebra::{Matrix3, Matrix4, Point3, Vector3};
use trinocular::api::{self, pb, RunCalibration};
use trinocular::geometry::{Camera, Rig};
use trinocular::matching::MatchParams;
use trinocular::pipeline::{self, Input, Options};
use trinocular::synth::{
    eligible_intervals, observe, pattern_views, render_triplet, rig_centre, score, Defects,
    RenderParams, Rng, Scene, STANDARD_RIG_POSITION,
};

/// `rig`'s cameras composed with `g` (they then map the points `g` maps from).
fn composed(rig: &Rig, g: &Matrix4<f64>) -> Result<Rig, Box<dyn std::error::Error>> {
    let c = |i: usize| -> Result<Camera, Box<dyn std::error::Error>> {
        let c = rig.camera(i);
        Ok(Camera::from_projection(
            c.name().to_string(),
            c.width(),
            c.height(),
            c.projection() * g,
            c.distortion().cloned(),
        )?)
    };
    Ok(Rig::new([c(0)?, c(1)?, c(2)?])?)
}

/// The median endpoint error (mm) of the room matched with `with`, seen by `truth`.
fn room_error_mm(truth: &Rig, with: &Rig, seed: u64) -> f64 {
    let scene = Scene::room(seed);
    let obs = observe(&scene, truth, &Defects::noisy(), seed);
    let output = pipeline::run(
        with,
        Input::lists(&obs.lists),
        &Options::with(MatchParams::default()),
    )
    .map(|m| m.output)
    .expect("valid");
    let segments: Vec<_> = output.segments();
    let s = score(
        &segments,
        &obs.ground_truth,
        &eligible_intervals(&obs),
        rig_centre(truth),
    );
    s.acc_median_mm.unwrap_or(f64::NAN)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let n: u64 = std::env::args().nth(1).map_or(Ok(10), |a| a.parse())?;
    let (mut ms, mut rms, mut fitted) = (Vec::new(), Vec::new(), Vec::new());
    let (mut with_truth, mut with_recovered) = (Vec::new(), Vec::new());
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

        // The rig carried into the room: camera 1 at the standard position looking along +y,
        // the same carriage for the true and the recovered calibration.
        let c1 = truth.camera(0);
        let mut pattern_to_cam1 = Matrix4::identity();
        pattern_to_cam1
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(c1.rotation());
        pattern_to_cam1
            .fixed_view_mut::<3, 1>(0, 3)
            .copy_from(c1.translation());
        let look = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0);
        let mut room_to_cam1 = Matrix4::identity();
        room_to_cam1.fixed_view_mut::<3, 3>(0, 0).copy_from(&look);
        room_to_cam1
            .fixed_view_mut::<3, 1>(0, 3)
            .copy_from(&(-look * Vector3::from(STANDARD_RIG_POSITION)));
        let g = pattern_to_cam1.try_inverse().ok_or("singular pose")? * room_to_cam1;
        let (truth_room, recovered_room) = (composed(&truth, &g)?, composed(&recovered, &g)?);
        with_truth.push(room_error_mm(&truth_room, &truth_room, seed));
        with_recovered.push(room_error_mm(&truth_room, &recovered_room, seed));

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
    let ratios: Vec<f64> = with_recovered
        .iter()
        .zip(&with_truth)
        .map(|(r, t)| r / t)
        .collect();
    println!(
        "room reconstruction, median endpoint error: true calibration {:.2} mm, recovered {:.2} mm \
         (medians over rigs); per-rig ratio median {:.3}, max {:.3}",
        median(&mut with_truth.clone()),
        median(&mut with_recovered.clone()),
        median(&mut ratios.clone()),
        max(&ratios),
    );
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
