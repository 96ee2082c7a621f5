//! Client reprojection, every method, on the analytic scene (`reproj_core::synthetic`): the
//! DESIGN.md target configuration (main 1280×720 + two 640×360 auxiliary cameras, dynamic scene,
//! shadows on, S = 4) and a quarter-size one. Server frames at t = 0 and t = 0.1 s; the client at
//! the head pose of t = 0.05 s (α = 0.5), or of t = 0.15 s (α = 1.5) for the methods that only
//! extrapolate from the newest frame. Each method is timed as a client frame inside a server-frame
//! pair (its `BidirHistory` kept, as the client does); `ours_first_of_pair` is `ours` with the
//! pair-level work included (the first client frame of a pair). `ours_1thread` is the same `ours`
//! call inside a one-thread rayon pool: the naive baseline the tiled parallel kernels are measured
//! against. `prepare_pair_1thread` is that pair-level work alone (`prepare_pair`, each call after
//! `BidirHistory::reset`, into the same buffers) on one thread, as the real-time client's worker
//! does it when an interpolation pair's newer frame arrives; `prepare_extrapolation_1thread` the
//! same for the extrapolation from the newer frame (no older frame), which a late frame needs.
//!
//! `copy_floor_ours` is the memory-copy floor of `ours` in the same run: a copy of as many bytes
//! as one `ours` client frame reads and writes (as `splitrender bench` counts them: every
//! camera's colour, depth, motion and shadow buffers of the direction it reads, in both frames,
//! and the output image), split in equal parts over rayon's threads, the ones the frame runs on;
//! `copy_floor_ours_1thread` the same copy on one thread. No frame can touch its bytes faster
//! than they can be copied, so `ours` over `copy_floor_ours` is how far it is from the machine,
//! a ratio that drifts much less than either time (criterion prints the copies in bytes per
//! second).
//!
//! Throughput is output pixels, so criterion reports pixels per second beside the time per frame.
//! `cargo bench -p reproj-core` runs in about two minutes on two cores.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use rayon::prelude::*;
use reproj_core::synthetic::{head_pose, rig, SyntheticFrame, SyntheticScene};
use reproj_core::{
    prepare_pair, reproject, BidirHistory, CameraView, FrameView, Method, Output, Params, Request,
};

/// Server frame interval (f_s = 10) and dynamic-shadow subframes (f_d = 40).
const DT: f64 = 0.1;
const S: usize = 4;

/// The α each method is benchmarked at: 0.5 (between the frames) where the method accepts it,
/// 1.5 (late, extrapolating from the newest frame) for the unidirectional ones that require it.
fn alpha_of(method: Method) -> f64 {
    match method {
        Method::OursExtrapolate | Method::ForwardSplat => 1.5,
        Method::Ours | Method::Timewarp | Method::BackwardBidir => 0.5,
    }
}

fn request(alpha: f64, w: usize, h: usize) -> Request {
    let (eye, target) = head_pose(alpha * DT);
    Request {
        client: rig(eye, target, w, h).0,
        alpha: alpha as f32,
    }
}

/// One timed client frame with the pair's history.
fn client_frame(
    method: Method,
    older: &FrameView,
    newer: &FrameView,
    req: &Request,
    params: &Params,
    out: &mut [u8],
    history: &mut BidirHistory,
) -> reproj_core::Result<()> {
    reproject(
        method,
        black_box(Some(older)),
        black_box(newer),
        black_box(req),
        params,
        Output::new(black_box(out)),
        Some(history),
    )
}

/// The bytes one `ours` client frame of `w × h` reads and writes, as `splitrender bench` counts
/// them: every camera of both frames (the views hold the direction each frame is read in) and
/// the output image.
fn ours_bytes(older: &FrameView, newer: &FrameView, w: usize, h: usize) -> usize {
    let camera = |c: &CameraView| {
        let motion = c.motion.map_or(0, |m| 4 * m.len());
        let shadow = c
            .shadow
            .map_or(0, |s| 4 * s.bits.len() + s.s_min.len() + s.s_max.len());
        c.color.len() + 4 * c.depth.len() + motion + shadow
    };
    let cameras = |f: &FrameView| camera(&f.main) + f.aux.iter().map(camera).sum::<usize>();
    cameras(older) + cameras(newer) + 3 * w * h
}

fn bench_size(c: &mut Criterion, w: usize, h: usize) {
    let scene = SyntheticScene::new(true);
    let (f0, f1) = (
        SyntheticFrame::render(&scene, 0.0, w, h, DT, S),
        SyntheticFrame::render(&scene, DT, w, h, DT, S),
    );
    let (older, newer) = (f0.view(true), f1.view(false));
    let params = Params::default();
    let size = format!("{w}x{h}+2x{}x{}", w / 2, h / 2);

    let mut group = c.benchmark_group("reproject");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3))
        .throughput(Throughput::Elements((w * h) as u64));

    // The previous client frame: the ground truth at the pair's midpoint.
    let mut out = scene.render_ground_truth(&request(0.5, w, h).client, 0.05);
    for method in Method::ALL {
        let req = request(alpha_of(method), w, h);
        // A client frame inside a server-frame pair, as the client runs it: the pair's history
        // (BidirHistory) is kept across the calls, so the work that does not depend on the client
        // pose is done once per pair (12 client frames at 120/10 Hz), here by this first call,
        // which also fails loudly rather than time an error path.
        let mut history = BidirHistory::new();
        reproject(
            method,
            Some(&older),
            &newer,
            &req,
            &params,
            Output::new(&mut out),
            Some(&mut history),
        )
        .unwrap_or_else(|e| panic!("{method}: {e}"));
        group.bench_function(BenchmarkId::new(method.name(), &size), |b| {
            b.iter(|| {
                client_frame(
                    method,
                    &older,
                    &newer,
                    &req,
                    &params,
                    &mut out,
                    &mut history,
                )
            })
        });
    }

    // The first client frame of a pair: `ours` with the pair-level work included (a fresh history
    // every call; the same as calling without one).
    let req = request(0.5, w, h);
    let mut ours = |history: &mut BidirHistory| {
        client_frame(
            Method::Ours,
            &older,
            &newer,
            &req,
            &params,
            &mut out,
            history,
        )
    };
    group.bench_function(BenchmarkId::new("ours_first_of_pair", &size), |b| {
        let mut history = BidirHistory::new();
        b.iter(|| {
            history.reset();
            ours(&mut history)
        })
    });

    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("one-thread pool");
    let mut history = BidirHistory::new();
    group.bench_function(BenchmarkId::new("ours_1thread", &size), |b| {
        b.iter(|| one.install(|| ours(&mut history)))
    });

    // The pair-level work alone, on one thread (module doc). The pair's work goes to the pool the
    // call runs in: the one-thread pool, as the client's worker gives it one thread.
    let cases = [
        ("prepare_pair_1thread", Some(&older)),
        ("prepare_extrapolation_1thread", None),
    ];
    for (name, o) in cases {
        let mut history = BidirHistory::new();
        let prepare = |history: &mut BidirHistory| {
            history.reset();
            prepare_pair(
                Method::Ours,
                black_box(o),
                black_box(&newer),
                &req.client,
                &params,
                history,
            )
        };
        // Fails loudly rather than time an error path.
        one.install(|| prepare(&mut history))
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        group.bench_function(BenchmarkId::new(name, &size), |b| {
            b.iter(|| one.install(|| prepare(&mut history)))
        });
    }

    // The copy floor (module doc), between two buffers touched beforehand.
    let n = ours_bytes(&older, &newer, w, h);
    let src = vec![1u8; n];
    let mut dst = vec![0u8; n];
    let part = n.div_ceil(rayon::current_num_threads());
    group.throughput(Throughput::Bytes(n as u64));
    group.bench_function(BenchmarkId::new("copy_floor_ours", &size), |b| {
        b.iter(|| {
            dst.par_chunks_mut(part)
                .zip(src.par_chunks(part))
                .for_each(|(d, s)| d.copy_from_slice(black_box(s)))
        })
    });
    group.bench_function(BenchmarkId::new("copy_floor_ours_1thread", &size), |b| {
        b.iter(|| dst.copy_from_slice(black_box(&src)))
    });
    group.finish();
}

fn benches(c: &mut Criterion) {
    bench_size(c, 1280, 720);
    bench_size(c, 640, 360);
}

criterion_group!(reproject_benches, benches);
criterion_main!(reproject_benches);
