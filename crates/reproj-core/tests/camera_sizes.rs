//! Camera sizes outside `1..=MAX_SIDE` are input errors at every public entry point that takes a
//! camera, never a panic or a silently wrong image. `Camera`'s fields are public, so a caller can
//! build one without `Camera::new`'s check; the kernels pack pixel columns in 16 bits and split
//! rows into blocks, so a side of zero or above `MAX_SIDE` must not reach them.

use std::panic::{catch_unwind, AssertUnwindSafe};

use reproj_core::memory::{pixels, reproject_bytes};
use reproj_core::{
    backward_bidir, prepare_pair, reproject, scene_flow, timewarp, BidirHistory, Camera,
    CameraBuffers, FrameView, Mat4, Method, Output, Params, ReprojError, Request, MAX_SIDE,
};

fn camera(width: usize, height: usize) -> Camera {
    let view = Mat4::look_at([0.0, 0.0, 2.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    let aspect = width.max(1) as f64 / height.max(1) as f64;
    let proj = Mat4::perspective(60.0, aspect, 0.1, 100.0);
    Camera {
        view,
        proj,
        width,
        height,
    }
}

/// The call's result, or the panic's message as an error that no `ReprojError` matches.
fn no_panic(f: impl FnOnce() -> Result<(), ReprojError>) -> Result<(), String> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r.map_err(|e| format!("{e:?}")),
        Err(p) => Err(format!(
            "PANIC: {}",
            p.downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default()
        )),
    }
}

fn is_bad_size(r: &Result<(), String>, width: usize, height: usize) -> bool {
    let want = format!("width: {width}, height: {height}, max: {MAX_SIDE}");
    matches!(r, Err(m) if m.starts_with("BadSize") && m.contains(&want))
}

#[test]
fn client_cameras_outside_1_to_max_side_are_bad_size_errors() {
    let (w, h) = (8, 6);
    let bufs = CameraBuffers::zeroed(w, h);
    let (older, newer) = (
        FrameView {
            main: bufs.view(camera(w, h), true),
            aux: vec![],
        },
        FrameView {
            main: bufs.view(camera(w, h), false),
            aux: vec![],
        },
    );
    let p = Params::default();
    // One past the largest side, a zero side each way: the output buffer matches, so only the
    // size can be refused.
    for (cw, ch) in [(MAX_SIDE + 1, 1), (0, 3), (4, 0)] {
        let client = camera(cw, ch);
        for m in Method::ALL {
            let alpha = if m == Method::BackwardBidir { 0.5 } else { 1.0 };
            let req = Request { client, alpha };
            let mut out = vec![0u8; 3 * cw * ch];
            let r = no_panic(|| {
                reproject(
                    m,
                    Some(&older),
                    &newer,
                    &req,
                    &p,
                    Output::new(&mut out),
                    None,
                )
            });
            assert!(is_bad_size(&r, cw, ch), "{m} {cw}x{ch}: {r:?}");
            let mut history = BidirHistory::new();
            let r = no_panic(|| prepare_pair(m, Some(&older), &newer, &client, &p, &mut history));
            assert!(is_bad_size(&r, cw, ch), "prepare_pair {m} {cw}x{ch}: {r:?}");
        }
        let req = Request { client, alpha: 0.5 };
        let mut out = vec![0u8; 3 * cw * ch];
        let r = no_panic(|| timewarp::run(&newer, &req, &p, Output::new(&mut out)));
        assert!(is_bad_size(&r, cw, ch), "timewarp::run {cw}x{ch}: {r:?}");
        let r = no_panic(|| scene_flow(&newer.main, &client, 0.5).map(drop));
        assert!(is_bad_size(&r, cw, ch), "scene_flow {cw}x{ch}: {r:?}");
    }
}

#[test]
fn server_cameras_outside_1_to_max_side_are_bad_size_errors() {
    let p = Params::default();
    let client = camera(8, 6);
    let good = CameraBuffers::zeroed(8, 6);
    let (empty_rgb, empty_z): (&[u8], &[f32]) = (&[], &[]);
    let wide = CameraBuffers::zeroed(MAX_SIDE + 1, 1);
    for (sw, sh) in [(0, 0), (MAX_SIDE + 1, 1), (usize::MAX, 2)] {
        // Buffers that match the size where it is small enough to hold them; for usize::MAX the
        // element count overflows and must be refused before it is computed.
        let mut bad = good.view(camera(sw, sh), false);
        if sw == 0 {
            (bad.color, bad.depth, bad.motion, bad.shadow) = (empty_rgb, empty_z, None, None);
        } else if sw == MAX_SIDE + 1 {
            bad = wide.view(camera(sw, sh), false);
        }
        let ok = good.view(camera(8, 6), true);
        // As the main camera of the newer frame, and as an auxiliary camera of both.
        let frames = [
            (
                FrameView {
                    main: ok,
                    aux: vec![],
                },
                FrameView {
                    main: bad,
                    aux: vec![],
                },
            ),
            (
                FrameView {
                    main: ok,
                    aux: vec![bad],
                },
                FrameView {
                    main: ok,
                    aux: vec![bad],
                },
            ),
        ];
        for (older, newer) in &frames {
            for m in Method::ALL {
                let alpha = if m == Method::BackwardBidir { 0.5 } else { 1.0 };
                let req = Request { client, alpha };
                let mut out = vec![0u8; 3 * 8 * 6];
                let r = no_panic(|| {
                    reproject(m, Some(older), newer, &req, &p, Output::new(&mut out), None)
                });
                assert!(is_bad_size(&r, sw, sh), "{m} server {sw}x{sh}: {r:?}");
            }
            let mut out = vec![0u8; 3 * 8 * 6];
            let req = Request { client, alpha: 0.5 };
            let r = no_panic(|| {
                backward_bidir::run(older, newer, &req, &p, Output::new(&mut out), None)
            });
            assert!(
                is_bad_size(&r, sw, sh),
                "backward_bidir::run {sw}x{sh}: {r:?}"
            );
        }
        let r = no_panic(|| scene_flow(&bad, &client, 0.5).map(drop));
        assert!(
            is_bad_size(&r, sw, sh),
            "scene_flow source {sw}x{sh}: {r:?}"
        );
    }
}

#[test]
fn memory_bounds_saturate_for_any_camera_size() {
    let huge = camera(usize::MAX, usize::MAX);
    let bufs = CameraBuffers::zeroed(8, 6);
    let frame = FrameView {
        main: bufs.view(huge, false),
        aux: vec![bufs.view(huge, false)],
    };
    let r = catch_unwind(|| (pixels(&huge), reproject_bytes(&frame, &huge)));
    assert_eq!(r.ok(), Some((u64::MAX, u64::MAX)));
}
