//! One server frame (main + two auxiliary cameras, every buffer, S = 4) and one ground-truth
//! client frame of the dynamic `courtyard` at 640×360 and 1280×720 (main camera size), colour
//! with the default sub-samples (3×3 and 2×2). One scene only, with criterion's minimum of 10
//! samples, to keep the whole bench near 4 minutes (the 1280×720 server frame alone takes about
//! 2); the `preview` example times all three scenes, `render_time` is a quicker check.
//!
//! `cargo bench -p reproj-scene --bench render`

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use reproj_scene::{builtin, render_client_frame, render_server_frame, Variant};

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("render");
    g.sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    for name in ["courtyard"] {
        let scene = builtin(name, Variant::Dynamic).expect("built-in scene");
        for scale in [0.25, 0.5] {
            let (w, h) = reproj_scene::main_size(scale).expect("scale");
            // Main plus two half-size auxiliary cameras.
            g.throughput(Throughput::Elements((w * h + 2 * (w / 2) * (h / 2)) as u64));
            g.bench_function(
                BenchmarkId::new(format!("server_{name}"), format!("{w}x{h}")),
                |b| {
                    b.iter(|| black_box(render_server_frame(&scene, black_box(20), scale, 10.0, 4)))
                },
            );
            g.throughput(Throughput::Elements((w * h) as u64));
            g.bench_function(
                BenchmarkId::new(format!("ground_truth_{name}"), format!("{w}x{h}")),
                |b| {
                    b.iter(|| {
                        black_box(render_client_frame(
                            &scene,
                            black_box(240),
                            scale,
                            120.0,
                            false,
                        ))
                    })
                },
            );
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
