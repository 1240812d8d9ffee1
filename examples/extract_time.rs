use trinocular::extract::{extract, Params};
use trinocular::synth::{bench_capture, render_image, RenderParams};
fn main() {
    for scale in [1.0, 2.0] {
        let (scene, rig) = bench_capture(1, scale);
        let img = render_image(&scene, rig.camera(0), &RenderParams::default(), 1);
        let mut st = Vec::new();
        if std::env::var("ONLY512").is_ok() && scale > 1.0 {
            continue;
        }
        let mut n = 0;
        for _ in 0..std::env::var("REPS")
            .ok()
            .and_then(|r| r.parse().ok())
            .unwrap_or(21)
        {
            let e = extract(&img, Some(rig.camera(0)), &Params::default());
            n = e.segments.segments.len();
            st.push(e.stats);
        }
        st.sort_by(|a, b| a.total_ms.total_cmp(&b.total_ms));
        let s = &st[10];
        println!("{}: segs {n} points {} chains {} | total {:.3} grad {:.3} edges {:.3} chain {:.3} poly {:.3}", img.width(), s.edge_points, s.chains, s.total_ms, s.smooth_ms, s.edges_ms, s.chain_ms, s.polygon_ms);
    }
}
