//! A lost device (a driver reset, a removed GPU; here `wgpu::Device::destroy`): every operation
//! of a reprojector made on a [`GpuContext`] then fails with [`GpuError::Lost`], never a panic.
//! Before, an upload mapped a buffer that the loss had made invalid, and wgpu panicked.
//!
//! Its own device (the loss is for good), on the adapter the parity tests use; skipped without
//! one unless `REPROJ_WGPU_REQUIRE_ADAPTER=1`.

use reproj_core::{Method, Params, Request};
use reproj_scene::{builtin, mono, render_server_frame, Variant};
use reproj_wgpu::{
    ContextOptions, GpuContext, GpuError, Previous, Reprojector, ReprojectorOptions,
};

#[test]
fn every_operation_on_a_lost_device_fails_as_lost() {
    let ctx = match GpuContext::new(&ContextOptions::default()) {
        Ok(c) => c,
        Err(e) if std::env::var_os("REPROJ_WGPU_REQUIRE_ADAPTER").is_some_and(|v| v == "1") => {
            panic!("REPROJ_WGPU_REQUIRE_ADAPTER=1 but {e}")
        }
        Err(e) => return eprintln!("skipping: {e}"),
    };
    let scene = builtin("courtyard", Variant::Dynamic).expect("built-in scene");
    let f0 = render_server_frame(&scene, 0, 0.03, 10.0, 1).expect("render");
    let f1 = render_server_frame(&scene, 1, 0.03, 10.0, 1).expect("render");
    let (older, newer) = (f0.view(true), f1.view(false));
    let (w, h) = (f0.main.buffers.width, f0.main.buffers.height);
    let request = Request {
        client: mono(&scene.path.client_pose(0.05), w, h, scene.near, scene.far),
        alpha: 0.5,
    };
    let mut gpu = Reprojector::new(&ctx, &ReprojectorOptions::default()).expect("pipelines");
    let uploader = gpu.uploader();
    let mut img = vec![0u8; w * h * 3];
    let render = |gpu: &mut Reprojector, img: &mut [u8]| {
        let p = Params::default();
        gpu.render(
            0,
            Method::Ours,
            &request,
            &p,
            Previous::Black,
            Some(img),
            None,
        )
    };
    gpu.load(Some(&older), &newer).expect("load");
    render(&mut gpu, &mut img).expect("render");
    let spare = std::sync::Arc::new(uploader.upload(Some(&older), &newer).expect("upload"));
    assert_eq!(gpu.lost(), None);

    ctx.device.destroy();
    let lost = |r: Result<(), GpuError>, what: &str| match r {
        Err(GpuError::Lost(why)) => assert_eq!(why, "Destroyed", "{what}"),
        other => panic!("{what}: expected GpuError::Lost, got {other:?}"),
    };
    lost(render(&mut gpu, &mut img), "render");
    lost(uploader.upload(Some(&older), &newer).map(drop), "upload");
    lost(gpu.load(Some(&older), &newer), "load");
    lost(gpu.install(spare).map(drop), "install");
    lost(
        Reprojector::new(&ctx, &ReprojectorOptions::default()).map(drop),
        "a new reprojector on the lost device",
    );
    assert_eq!(gpu.lost(), Some("Destroyed"));
    assert_eq!(ctx.loss.reason(), Some("Destroyed"));
    // A new device works.
    let again = GpuContext::new(&ContextOptions::default()).expect("a new device");
    let mut gpu = Reprojector::new(&again, &ReprojectorOptions::default()).expect("pipelines");
    gpu.load(Some(&older), &newer).expect("load");
    render(&mut gpu, &mut img).expect("render on the new device");
}
