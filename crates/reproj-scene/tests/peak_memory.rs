//! The memory bounds of `reproj_core::memory` (and reproj-scene's `truth_bytes`) hold: the peak
//! of the bytes a call keeps allocated, counted by a global allocator that tracks the live
//! bytes, stays within the call's bound on one thread and on four, for every method and
//! renderer; on one thread, between two sizes, it grows by no more than the bound (so a
//! per-pixel constant too small fails even where the fixed part dwarfs it at these sizes), and
//! the heaviest call's by at least half as much (the constants are not loose).
//!
//! The growth is compared on one thread only: there the peaks are the same bytes every run. On
//! four they vary from run to run with the way the work is split (each thread's scratch grows to
//! the largest piece it took), and a difference of two such peaks measures that as much as the
//! pixels (`ours` to a half-size client grew by 100 to 113 bytes a server pixel on four threads
//! where it grows by 100 on one).
//!
//! The Python binding reserves these bounds before a call and raises an error when it cannot
//! (an allocation failing inside Rust aborts the process), so a bound below the true peak lets
//! the abort through, and one far above refuses work the machine could do.

use std::alloc::{GlobalAlloc, Layout, System};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Mutex, MutexGuard};

use reproj_core::memory::{pixels, reproject_bytes, server_buffers_bytes, synthetic_truth_bytes};
use reproj_core::synthetic::{head_pose, rig, SyntheticFrame, SyntheticScene};
use reproj_core::{
    prepare_pair, reproject, BidirHistory, Camera, Diagnostics, Method, Output, Params, Request,
};
use reproj_scene as rs;

/// The system allocator, counting the bytes live and their highest value since the last reset.
struct Counting;

static LIVE: AtomicU64 = AtomicU64::new(0);
static PEAK: AtomicU64 = AtomicU64::new(0);

fn grew(by: usize) {
    let live = LIVE.fetch_add(by as u64, Relaxed) + by as u64;
    PEAK.fetch_max(live, Relaxed);
}

// SAFETY: every call is forwarded to `System` with the caller's arguments unchanged; the
// counting only reads the layouts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded as given (the caller upholds `alloc`'s contract).
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as `alloc`.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from this allocator with `layout` (the caller's contract).
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size() as u64, Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as `dealloc`, with a `new_size` the caller checked.
        let q = unsafe { System.realloc(ptr, layout, new_size) };
        if !q.is_null() {
            // Counted as a new block beside the old one: a copy holds both for a moment.
            grew(new_size);
            LIVE.fetch_sub(layout.size() as u64, Relaxed);
        }
        q
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Held by each test from its start: the counters are the process's, and the harness runs the
/// tests on parallel threads, whose allocations would count in another test's measurement.
static SERIAL: Mutex<()> = Mutex::new(());

fn alone() -> MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// The peak bytes `f` keeps allocated beyond those live before it (the caller holds [`alone`]),
/// with what it returns still held at the end, run on a pool of `threads` whose threads are
/// joined before this returns: the kernels keep scratch in thread-locals (freed as a thread
/// exits), which must neither be inherited by the next measurement nor freed during it.
fn peak_of<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> u64 {
    let mut peak = 0;
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_scoped(
            |thread| thread.run(),
            |pool| {
                // Every worker started (and done with its own allocations) first.
                pool.broadcast(|_| ());
                let before = LIVE.load(Relaxed);
                PEAK.store(before, Relaxed);
                let kept = pool.install(f);
                peak = PEAK.load(Relaxed) - before;
                drop(kept);
            },
        )
        .unwrap();
    peak
}

const THREADS: [usize; 2] = [1, 4];
/// Two main-camera sizes, the second four times the pixels of the first (the auxiliary cameras
/// follow the rig): small enough for debug builds, large enough for the per-pixel part to show.
const SIZES: [(usize, usize); 2] = [(80, 45), (160, 90)];

/// `α` inside the range `method` accepts.
fn alpha(method: Method) -> f32 {
    match method {
        Method::OursExtrapolate | Method::ForwardSplat => 1.5,
        _ => 0.5,
    }
}

/// Client cameras of the same size as the main camera, twice its sides and half of them (the
/// last two only where the method accepts another size).
fn clients(method: Method, w: usize, h: usize) -> Vec<Camera> {
    let (eye, target) = head_pose(0.05);
    let sizes = if method == Method::BackwardBidir {
        vec![(w, h)]
    } else {
        vec![(w, h), (2 * w, 2 * h), (w / 2, h / 2)]
    };
    sizes
        .into_iter()
        .map(|(cw, ch)| rig(eye, target, cw, ch).0)
        .collect()
}

/// Each call's peak and bound at the two sizes ([`SIZES`]), by the call's name without the
/// size.
#[derive(Default)]
struct Peaks(BTreeMap<String, Vec<(u64, u64)>>);

impl Peaks {
    /// Records a call's peak against its bound, asserting the first is within the second.
    fn add(&mut self, call: String, (w, h): (usize, usize), peak: u64, bound: u64) {
        assert!(
            peak <= bound,
            "{call} at {w}x{h}: peak {peak} B above its bound {bound} B"
        );
        self.0.entry(call).or_default().push((peak, bound));
    }

    /// Between the two sizes every one-thread call's peak grows by at most its bound's growth
    /// (the per-pixel constants cover it: at these sizes the fixed part dwarfs them, so the
    /// peaks alone would not show a constant too small), and the `heaviest` call's by at least
    /// half (the constants are not loose). Calls on more threads are left out (see the top).
    fn check_growth(&self, heaviest: &str) {
        assert!(self.0.contains_key(heaviest), "no call {heaviest}");
        let one_thread = self
            .0
            .iter()
            .filter(|(call, _)| call.ends_with(" on 1 threads"));
        assert_eq!(
            one_thread.clone().count() * THREADS.len(),
            self.0.len(),
            "calls by threads"
        );
        for (call, v) in one_thread {
            let [(p0, b0), (p1, b1)] = v[..] else {
                panic!("{call}: expected one measurement at each size, got {v:?}")
            };
            let (grown, allowed) = (p1 as i64 - p0 as i64, (b1 - b0) as i64);
            assert!(
                grown <= allowed,
                "{call}: the peak grew {grown} B, more than its bound's {allowed} B"
            );
            assert!(
                call != heaviest || 2 * grown >= allowed,
                "{call}: the peak grew {grown} B where its bound grew {allowed} B (loose)"
            );
        }
    }
}

#[test]
fn reproject_and_prepare_pair_stay_within_their_bound_for_every_method_and_client_size() {
    let _alone = alone();
    let scene = SyntheticScene::new(true);
    let params = Params::default();
    let mut peaks = Peaks::default();
    for size @ (w, h) in SIZES {
        let f0 = SyntheticFrame::render(&scene, 0.0, w, h, 0.1, 4);
        let f1 = SyntheticFrame::render(&scene, 0.1, w, h, 0.1, 4);
        let (older, newer) = (f0.view(true), f1.view(false));
        for threads in THREADS {
            for method in Method::ALL {
                for (k, client) in clients(method, w, h).into_iter().enumerate() {
                    let call = format!("{method} to client {k} on {threads} threads");
                    let n = pixels(&client) as usize;
                    // The binding's own output and diagnostics (3 + 1 + 4 bytes a pixel).
                    let bound = reproject_bytes(&newer, &client) + 8 * n as u64;
                    let request = Request {
                        client,
                        alpha: alpha(method),
                    };
                    let peak = peak_of(threads, || {
                        let mut out = vec![0u8; 3 * n];
                        let mut diag = Diagnostics::new(n);
                        let mut history = BidirHistory::new();
                        let output = Output::with_diagnostics(&mut out, &mut diag);
                        let hist = Some(&mut history);
                        reproject(
                            method,
                            Some(&older),
                            &newer,
                            &request,
                            &params,
                            output,
                            hist,
                        )
                        .unwrap();
                        (out, diag, history)
                    });
                    peaks.add(call.clone(), size, peak, bound);
                    let peak = peak_of(threads, || {
                        let mut history = BidirHistory::new();
                        prepare_pair(method, Some(&older), &newer, &client, &params, &mut history)
                            .unwrap();
                        history
                    });
                    peaks.add(format!("prepare_pair {call}"), size, peak, bound);
                }
            }
        }
    }
    peaks.check_growth("ours to client 0 on 1 threads");
}

#[test]
fn the_synthetic_scenes_buffers_stay_within_their_bound() {
    let _alone = alone();
    let scene = SyntheticScene::new(true);
    let (mut server, mut truth) = (Peaks::default(), Peaks::default());
    for size @ (w, h) in SIZES {
        let (eye, target) = head_pose(0.3);
        let camera = rig(eye, target, w, h).0;
        let px = pixels(&camera);
        for threads in THREADS {
            let call = format!("synthetic on {threads} threads");
            let peak = peak_of(threads, || scene.render_server(&camera, 0.3, 0.1, 16));
            server.add(call.clone(), size, peak, server_buffers_bytes(px));
            let peak = peak_of(threads, || scene.render_ground_truth(&camera, 0.3));
            truth.add(call, size, peak, synthetic_truth_bytes(px));
        }
    }
    server.check_growth("synthetic on 1 threads");
    truth.check_growth("synthetic on 1 threads");
}

#[test]
fn the_reference_renderers_buffers_stay_within_their_bound_in_every_scene() {
    let _alone = alone();
    let (mut server, mut truth) = (Peaks::default(), Peaks::default());
    for name in rs::SCENE_NAMES {
        let scene = rs::builtin(name, rs::Variant::Dynamic).unwrap();
        for size @ (w, h) in SIZES {
            let pose = scene.path.server_pose(3, 10.0);
            let camera = rs::mono(&pose, w, h, scene.near, scene.far);
            let px = pixels(&camera);
            for threads in THREADS {
                let call = format!("{name} on {threads} threads");
                // The most subframes and sub-samples: their scratch is per thread.
                let peak = peak_of(threads, || {
                    rs::render_server(&scene, &camera, 0.3, 0.1, 16, rs::MAX_SAMPLES).unwrap()
                });
                server.add(call.clone(), size, peak, server_buffers_bytes(px));
                let peak = peak_of(threads, || {
                    rs::render_ground_truth(&scene, &camera, 0.3, rs::MAX_SAMPLES).unwrap()
                });
                truth.add(call, size, peak, rs::truth_bytes(&camera));
            }
        }
    }
    server.check_growth("courtyard on 1 threads");
    truth.check_growth("courtyard on 1 threads");
}
