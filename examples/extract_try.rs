use trinocular::extract::{extract, GreyImage, Params};
fn main() {
    let path = std::env::args().nth(1).unwrap();
    let img = image::open(&path).unwrap().to_luma8();
    let g = GreyImage::from_u8(img.width(), img.height(), img.as_raw()).unwrap();
    let mut p = Params::default();
    for a in std::env::args().skip(2) {
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
    let mut t = vec![];
    let mut last = None;
    for _ in 0..30 {
        let e = extract(&g, None, &p);
        t.push(e.stats.clone());
        last = Some(e);
    }
    t.sort_by(|a, b| a.total_ms.total_cmp(&b.total_ms));
    let e = last.unwrap();
    let s = &t[15];
    println!("segments {} graph {} points {} chains {} junctions {} | total {:.3} grad {:.3} edges {:.3} chain {:.3} poly {:.3} ms", e.segments.segments.len(), e.graph.len(), s.edge_points, s.chains, s.junctions, s.total_ms, s.gradient_ms, s.edges_ms, s.chain_ms, s.polygon_ms);
    let lens: Vec<f64> = e.segments.segments.iter().map(|s| s.length()).collect();
    println!("len>20: {}", lens.iter().filter(|&&l| l > 20.0).count());
    let labels: Vec<Option<usize>> = (0..e.segments.segments.len()).map(Some).collect();
    let pic = trinocular::overlay::triplet_overlay([&g; 3], [&e.segments; 3], [&labels[..]; 3]);
    std::fs::write("/tmp/extract.png", pic.to_png().unwrap()).unwrap();
}
#[allow(dead_code)]
fn unused() {}
