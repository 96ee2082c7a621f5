//! Parallel == serial: every method gives the same bytes (output colour and diagnostics) whether
//! rayon runs it on one thread or on four. The kernels split work into row blocks and tiles and
//! resolve splat races with an order-independent atomic minimum, so any difference here is a
//! scheduling dependence (a data race or an order-dependent reduction).

use proptest::prelude::*;
use reproj_core::synthetic::{head_pose, rig, SyntheticFrame, SyntheticScene};
use reproj_core::{
    reproject, BidirHistory, Diagnostics, FrameView, Method, Output, Params, Request,
};

/// Main camera size: small enough to keep the property fast in debug builds, and neither side a
/// multiple of the 16-pixel tile, so partial tiles and row blocks are exercised too.
const W: usize = 40;
const H: usize = 28;
const DT: f64 = 0.1;
const S: usize = 4;

/// `α` for `method` from a uniform `u ∈ [0, 1)`, inside the range the method accepts.
fn alpha_for(method: Method, u: f64, params: &Params) -> f64 {
    match method {
        Method::Ours => 1.5 * u,
        Method::OursExtrapolate => 1.0 + u,
        Method::ForwardSplat if params.splat_bidirectional => 1.5 * u,
        Method::ForwardSplat => 1.0 + u,
        Method::Timewarp => 2.0 * u,
        Method::BackwardBidir => u,
    }
}

/// Everything one run produces, in a form that compares bit for bit (NaN errors included).
type Outcome = Vec<std::result::Result<(Vec<u8>, Vec<u8>, Vec<u32>), String>>;

/// Two successive client frames with `method` (the second starts from the first's output and
/// history, as the client does), run inside `pool`.
fn run_in(
    pool: &rayon::ThreadPool,
    method: Method,
    older: &FrameView,
    newer: &FrameView,
    requests: &[Request],
    params: &Params,
) -> Outcome {
    pool.install(|| {
        let n = W * H;
        let mut out: Vec<u8> = (0..3 * n).map(|i| (i * 7 % 251) as u8).collect();
        let mut history = BidirHistory::new();
        requests
            .iter()
            .map(|req| {
                let mut diag = Diagnostics::new(n);
                reproject(
                    method,
                    Some(older),
                    newer,
                    req,
                    params,
                    Output::with_diagnostics(&mut out, &mut diag),
                    Some(&mut history),
                )
                .map(|()| {
                    let err = diag.error.iter().map(|e| e.to_bits()).collect();
                    (out.clone(), diag.source, err)
                })
                .map_err(|e| e.to_string())
            })
            .collect()
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 16, ..ProptestConfig::default() })]

    #[test]
    fn parallel_equals_serial_for_every_method(
        t0 in 0.0f64..3.0,
        u in proptest::collection::vec(0.0f64..1.0, 2),
        offset in -0.05f64..0.05,
        shadows in any::<bool>(),
        blend in any::<bool>(),
        splat_bidirectional in any::<bool>(),
    ) {
        let scene = SyntheticScene::new(true);
        let (f0, f1) = (
            SyntheticFrame::render(&scene, t0, W, H, DT, S),
            SyntheticFrame::render(&scene, t0 + DT, W, H, DT, S),
        );
        let (older, newer) = (f0.view(true), f1.view(false));
        let params = Params {
            use_shadows: shadows,
            blend,
            splat_bidirectional,
            ..Params::default()
        };
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let four = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap();
        for method in Method::ALL {
            // The client is where the head is at display time, off the server's prediction.
            let requests: Vec<Request> = u
                .iter()
                .map(|&ui| {
                    let a = alpha_for(method, ui, &params);
                    let (eye, target) = head_pose(t0 + a * DT + offset);
                    Request { client: rig(eye, target, W, H).0, alpha: a as f32 }
                })
                .collect();
            let serial = run_in(&one, method, &older, &newer, &requests, &params);
            let parallel = run_in(&four, method, &older, &newer, &requests, &params);
            for (k, (s, p)) in serial.iter().zip(&parallel).enumerate() {
                prop_assert!(s.is_ok(), "{method} frame {k} failed: {s:?}");
                prop_assert!(s == p, "{method} frame {k}: 1 thread != 4 threads");
            }
            if method == Method::Ours {
                // Guard against a vacuous comparison: `ours` matches most of the frame.
                let matched = serial[0].as_ref().map_or(0, |(_, src, _)| {
                    src.iter().filter(|&&c| c != Diagnostics::NONE).count()
                });
                prop_assert!(matched > W * H / 2, "ours matched only {matched} pixels");
            }
        }
    }
}

/// The splat bands of pass 1 (64 source rows each) and the points they spill into other bands'
/// rows: `ours` on a tall image (150 rows: three bands in the main sources, two in the 75-row
/// auxiliary ones), for a client off the server's path vertically (near and far points move
/// apart, so some land outside their band's rows), gives the same bytes on one thread and on
/// four. At [`H`] rows the property above has one band and no spill: spills applied to the wrong
/// range of the grid, or not at all in the last range, on more than one thread passed it.
#[test]
fn parallel_equals_serial_across_splat_bands() {
    let (w, h) = (24, 150);
    let scene = SyntheticScene::new(true);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let four = rayon::ThreadPoolBuilder::new()
        .num_threads(4)
        .build()
        .unwrap();
    for (t0, dx, dy) in [(0.3, 0.1, 0.3), (1.7, -0.2, -0.4)] {
        let (f0, f1) = (
            SyntheticFrame::render(&scene, t0, w, h, DT, S),
            SyntheticFrame::render(&scene, t0 + DT, w, h, DT, S),
        );
        let (older, newer) = (f0.view(true), f1.view(false));
        // Off the server's path, up or down and to the side: near and far points part vertically.
        let (mut eye, target) = head_pose(t0 + 0.6 * DT);
        eye[0] += dx;
        eye[1] += dy;
        let req = Request {
            client: rig(eye, target, w, h).0,
            alpha: 0.6,
        };
        let run = |pool: &rayon::ThreadPool| {
            pool.install(|| {
                let mut out = vec![7u8; 3 * w * h];
                let mut diag = Diagnostics::new(w * h);
                let o = Output::with_diagnostics(&mut out, &mut diag);
                reproject(
                    Method::Ours,
                    Some(&older),
                    &newer,
                    &req,
                    &Params::default(),
                    o,
                    None,
                )
                .unwrap();
                let err: Vec<u32> = diag.error.iter().map(|e| e.to_bits()).collect();
                (out, diag.source, err)
            })
        };
        let (serial, parallel) = (run(&one), run(&four));
        assert!(serial == parallel, "t0 {t0}: 1 thread != 4 threads");
        let matched = serial.1.iter().filter(|&&c| c != Diagnostics::NONE).count();
        assert!(
            matched > w * h / 2,
            "t0 {t0}: ours matched only {matched} pixels"
        );
    }
}
