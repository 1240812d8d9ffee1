//! Pattern detection on one rendered 512 × 512 view of the default two-board pattern
//! (extraction included), one thread.
//!
//!     cargo bench --bench detect

use criterion::{criterion_group, criterion_main, Criterion};
use trinocular::calibrate::detect;
use trinocular::synth::{pattern_views, render_image, RenderParams};

fn bench(c: &mut Criterion) {
    let (scene, rig, pattern) = pattern_views(0);
    let image = render_image(&scene, rig.camera(0), &RenderParams::default(), 0);
    c.bench_function("detect/512", |b| {
        b.iter(|| detect(&image, &pattern).expect("pattern found"))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
