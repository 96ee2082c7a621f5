//! Milliseconds per client frame of the GPU path on the dynamic `courtyard` at 640×360 and
//! 1280×720 (main camera; plus two half-size auxiliary cameras, shadows on): the pair is loaded
//! once, then every iteration uploads the client pose and `α` and runs the frame,
//!
//! - `ours/<atomics>/download`: and downloads the image (what `splitrender bench --backend wgpu`
//!   times);
//! - `ours/<atomics>/on_device`: and leaves it on the device (a presenting caller), waiting for
//!   the GPU to finish;
//!
//! with the 64-bit splat where the adapter has it and the 32-bit fallback; `ours_cpu` is
//! reproj-core on the same frames for comparison (the naive baseline beside the fast one).
//!
//! What a new pair costs, with the default splat:
//!
//! - `upload`: [`Uploader::upload`] of the pair (every camera of both frames packed and copied
//!   to the device, what a real-time client's worker does on arrival), waiting until the copy is
//!   done and freeing the pair;
//! - `ours/<atomics>/install_on_device`: the first frame of a pair, [`Reprojector::install`] of
//!   an uploaded pair (alternating between two, so that every iteration switches) and one frame
//!   left on the device; beside `on_device` it shows whether the first frame of a pair costs
//!   more than the others.
//!
//! `cargo bench -p reproj-wgpu --bench reproject_gpu` (needs an adapter; on a machine without a
//! GPU, Mesa's lavapipe: `apt-get install mesa-vulkan-drivers`). `REPROJ_GPU_SCALES=1.0,0.5`
//! picks the scales of the 2560×1440 base (default `0.25,0.5`): 1.0 is DESIGN.md's GPU target,
//! 2560×1440 with two 1280×720 auxiliary cameras.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use reproj_core::{Method, Output, Params, Request};
use reproj_scene::{builtin, mono, render_server_frame, Variant};
use reproj_wgpu::{
    ContextOptions, GpuContext, Previous, Reprojector, ReprojectorOptions, Uploader,
};

fn bench(c: &mut Criterion) {
    let ctx = match GpuContext::new(&ContextOptions::default()) {
        Ok(ctx) => ctx,
        Err(e) => {
            eprintln!("no GPU benchmark: {e}");
            return;
        }
    };
    eprintln!("adapter: {}", ctx.describe());
    let scene = builtin("courtyard", Variant::Dynamic).expect("built-in scene");
    let mut g = c.benchmark_group("reproject_gpu");
    g.sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(4));
    let params = Params::default();
    for scale in scales() {
        let f0 = render_server_frame(&scene, 2, scale, 10.0, 4).expect("render");
        let f1 = render_server_frame(&scene, 3, scale, 10.0, 4).expect("render");
        let (w, h) = (f0.main.buffers.width, f0.main.buffers.height);
        let size = format!("{w}x{h}");
        let (older, newer) = (f0.view(true), f1.view(false));
        let alpha = 5.0 / 12.0;
        let client = mono(
            &scene.path.client_pose(0.2 + f64::from(alpha) / 10.0),
            w,
            h,
            scene.near,
            scene.far,
        );
        let request = Request { client, alpha };
        g.throughput(Throughput::Elements((w * h) as u64));
        let mut out = vec![0u8; w * h * 3];
        for force in [false, true] {
            if force && !ctx.int64_atomics() {
                continue; // the default already is the fallback
            }
            let mut gpu = Reprojector::new(
                &ctx,
                &ReprojectorOptions {
                    force_32bit_atomics: force,
                },
            )
            .expect("pipelines");
            gpu.load(Some(&older), &newer).expect("load");
            let name = gpu.atomics().name();
            // One client frame, into `out` (downloaded) or left on the device.
            let mut frame = |out: Option<&mut [u8]>| {
                gpu.render(
                    0,
                    Method::Ours,
                    black_box(&request),
                    &params,
                    Previous::Keep,
                    out,
                    None,
                )
                .expect("render")
            };
            g.bench_function(
                BenchmarkId::new(format!("ours/{name}/download"), &size),
                |b| b.iter(|| frame(Some(&mut out))),
            );
            g.bench_function(
                BenchmarkId::new(format!("ours/{name}/on_device"), &size),
                |b| {
                    b.iter(|| {
                        frame(None);
                        ctx.device.poll(wgpu::PollType::Wait).expect("device poll")
                    })
                },
            );
            if force {
                continue; // a new pair's costs are timed with the default splat only
            }
            let uploader: Uploader = gpu.uploader();
            g.bench_function(BenchmarkId::new("upload", &size), |b| {
                b.iter(|| {
                    let pair = uploader.upload(Some(&older), &newer).expect("upload");
                    ctx.device.poll(wgpu::PollType::Wait).expect("device poll");
                    pair
                })
            });
            let pairs = [(); 2].map(|()| {
                std::sync::Arc::new(uploader.upload(Some(&older), &newer).expect("upload"))
            });
            let mut next = 0;
            g.bench_function(
                BenchmarkId::new(format!("ours/{name}/install_on_device"), &size),
                |b| {
                    b.iter(|| {
                        gpu.install(pairs[next].clone()).expect("install");
                        next ^= 1;
                        gpu.render(
                            0,
                            Method::Ours,
                            black_box(&request),
                            &params,
                            Previous::Keep,
                            None,
                            None,
                        )
                        .expect("render");
                        ctx.device.poll(wgpu::PollType::Wait).expect("device poll")
                    })
                },
            );
        }
        g.bench_function(BenchmarkId::new("ours_cpu", &size), |b| {
            b.iter(|| {
                reproj_core::reproject(
                    Method::Ours,
                    Some(&older),
                    &newer,
                    black_box(&request),
                    &params,
                    Output::new(&mut out),
                    None,
                )
                .expect("cpu")
            })
        });
    }
    g.finish();
}

/// The scales to time, from `REPROJ_GPU_SCALES` (a comma-separated list), else 0.25 and 0.5.
fn scales() -> Vec<f64> {
    match std::env::var("REPROJ_GPU_SCALES") {
        Ok(list) => list
            .split(',')
            .map(|s| {
                s.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|&x| x > 0.0 && x <= 1.0)
                    .unwrap_or_else(|| panic!("REPROJ_GPU_SCALES: {s:?} is not a scale in (0, 1]"))
            })
            .collect(),
        Err(_) => vec![0.25, 0.5],
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
