//! Cameras with a side of zero or above `MAX_SIDE` are the CPU path's input error
//! (`GpuError::Input(ReprojError::BadSize)`), found before anything is asked of the device: not a
//! wgpu validation error for a zero-sized binding, not an overflow panic, not a render.
//!
//! Without an adapter the test prints why and passes, unless `REPROJ_WGPU_REQUIRE_ADAPTER=1`.

use reproj_core::{
    Camera, CameraBuffers, FrameView, Mat4, Method, Params, ReprojError, Request, MAX_SIDE,
};
use reproj_wgpu::{ContextOptions, GpuContext, GpuError, Previous, Reprojector};

fn camera(width: usize, height: usize) -> Camera {
    let view = Mat4::look_at([0.0, 0.0, 2.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    let proj = Mat4::perspective(60.0, 4.0 / 3.0, 0.1, 100.0);
    Camera {
        view,
        proj,
        width,
        height,
    }
}

fn is_bad_size<T: std::fmt::Debug>(r: &Result<T, GpuError>, width: usize, height: usize) -> bool {
    matches!(r, Err(GpuError::Input(ReprojError::BadSize { width: w, height: h, .. }))
        if (*w, *h) == (width, height))
}

#[test]
fn cameras_outside_1_to_max_side_are_input_errors() {
    let ctx = match GpuContext::new(&ContextOptions::default()) {
        Ok(c) => c,
        Err(e) => {
            if std::env::var_os("REPROJ_WGPU_REQUIRE_ADAPTER").is_some_and(|v| v == "1") {
                panic!("REPROJ_WGPU_REQUIRE_ADAPTER=1 but {e}");
            }
            eprintln!("skipping: {e}");
            return;
        }
    };
    let mut gpu = Reprojector::new(&ctx, &Default::default()).unwrap();
    let bufs = CameraBuffers::zeroed(8, 6);
    let frame = |c: Camera| FrameView {
        main: bufs.view(c, false),
        aux: vec![],
    };
    // A server camera whose element count overflows: refused before it is computed.
    let r = gpu.load(None, &frame(camera(usize::MAX, 2)));
    assert!(is_bad_size(&r, usize::MAX, 2), "{r:?}");
    gpu.load(None, &frame(camera(8, 6))).unwrap();
    let p = Params::default();
    for (w, h) in [(0, 6), (8, 0), (MAX_SIDE + 1, 1)] {
        let req = Request {
            client: camera(w, h),
            alpha: 1.0,
        };
        let mut out = vec![0u8; 3 * w * h];
        let r = gpu.render(
            0,
            Method::Ours,
            &req,
            &p,
            Previous::Black,
            Some(&mut out),
            None,
        );
        assert!(is_bad_size(&r, w, h), "{w}x{h}: {r:?}");
    }
}
