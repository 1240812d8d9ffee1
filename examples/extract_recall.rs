//! Edge recall of the extractor on synthetic renders.
use trinocular::extract::{extract, Params};
use trinocular::synth::{edge_recall, render_image, standard_capture, Defects, RenderParams};
fn main() {
    let mut p = Params::default();
    for a in std::env::args().skip(1) {
        let (k, v) = a.split_once('=').unwrap();
        let v: f64 = v.parse().unwrap();
        match k {
            "lo" => p.gradient_low = v,
            "hi" => p.gradient_high = v,
            "dev" => p.max_deviation_px = v,
            "sigma" => p.smoothing_sigma_px = v,
            "min" => p.min_segment_px = v,
            _ => panic!(),
        }
    }
    let (mut f, mut t, mut f3, mut f1) = (0, 0, 0, 0);
    for seed in 1..=3 {
        let (scene, rig, obs) = standard_capture(seed, Defects::clean(), false);
        for cam in 0..3 {
            let img = render_image(
                &scene,
                &rig.cameras()[cam],
                &RenderParams::default(),
                seed * 10 + cam as u64,
            );
            let e = extract(&img, Some(&rig.cameras()[cam]), &p);
            let (a, b) = edge_recall(&e.segments, &obs, cam, 20.0, 10.0, 1.5);
            let (c, _) = edge_recall(&e.segments, &obs, cam, 20.0, 10.0, 3.0);
            let (d, _) = edge_recall(&e.segments, &obs, cam, 20.0, 10.0, 1.0);
            f += a;
            t += b;
            f3 += c;
            f1 += d;
        }
    }
    println!(
        "recall@1.5px {:.3} ({f}/{t}), @3px {:.3}, @1px {:.3}",
        f as f64 / t as f64,
        f3 as f64 / t as f64,
        f1 as f64 / t as f64
    );
}
