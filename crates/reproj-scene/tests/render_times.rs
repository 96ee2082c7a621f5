//! Times and rates the render functions refuse with `SceneError::BadTime` rather than panic on
//! (a debug build's BVH assertion on NaN boxes) or render a scene whose objects are nowhere:
//! non-finite `t` or `interval`, a time at which an animated object leaves the finite range
//! (-1e300 s in the dynamic courtyard), and frame rates that are not finite and positive.

use reproj_scene::{
    builtin, default_samples, mono, render_client_frame, render_ground_truth, render_server,
    render_server_frame, render_shadow_fraction, truth_bytes, SceneError, Variant,
};

fn bad_time(r: Result<(), SceneError>, what: &str) -> bool {
    matches!(r, Err(SceneError::BadTime { what: w, .. }) if w == what)
}

#[test]
fn render_functions_refuse_times_at_which_the_scene_is_not_finite() {
    let scene = builtin("courtyard", Variant::Dynamic).unwrap();
    let pose = scene.path.client_pose(0.1);
    let cam = mono(&pose, 8, 6, scene.near, scene.far);
    for t in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -1e300] {
        let r = render_server(&scene, &cam, t, 0.1, 4, 1).map(drop);
        assert!(bad_time(r.clone(), "t"), "render_server t={t}: {r:?}");
        let r = render_ground_truth(&scene, &cam, t, 1).map(drop);
        assert!(bad_time(r.clone(), "t"), "render_ground_truth t={t}: {r:?}");
        let r = render_shadow_fraction(&scene, &cam, t).map(drop);
        assert!(
            bad_time(r.clone(), "t"),
            "render_shadow_fraction t={t}: {r:?}"
        );
    }
    for interval in [f64::NAN, f64::INFINITY] {
        let r = render_server(&scene, &cam, 0.1, interval, 4, 1).map(drop);
        assert!(
            bad_time(r.clone(), "interval"),
            "interval={interval}: {r:?}"
        );
    }
    // The message says what was wrong and what is expected.
    let e = render_ground_truth(&scene, &cam, f64::NAN, 1).unwrap_err();
    assert!(
        e.to_string().starts_with("t = NaN: expected a finite time"),
        "{e}"
    );
}

#[test]
fn frame_functions_refuse_rates_that_are_not_finite_and_positive() {
    let scene = builtin("courtyard", Variant::Dynamic).unwrap();
    let scale = 8.0 / 2560.0;
    for rate in [0.0, -10.0, f64::NAN, f64::INFINITY] {
        let r = render_server_frame(&scene, 1, scale, rate, 4).map(drop);
        assert!(bad_time(r.clone(), "fs"), "fs={rate}: {r:?}");
        let r = render_client_frame(&scene, 1, scale, rate, false).map(drop);
        assert!(bad_time(r.clone(), "fc"), "fc={rate}: {r:?}");
    }
    // A rate so small that `k / fs` is out of the scene's range.
    let r = render_server_frame(&scene, 1, scale, 1e-300, 4).map(drop);
    assert!(bad_time(r.clone(), "t"), "fs=1e-300: {r:?}");
}

#[test]
fn size_helpers_do_not_overflow() {
    let scene = builtin("courtyard", Variant::Static).unwrap();
    let pose = scene.path.client_pose(0.1);
    let mut cam = mono(&pose, 8, 6, scene.near, scene.far);
    (cam.width, cam.height) = (usize::MAX, usize::MAX);
    let r = std::panic::catch_unwind(|| (truth_bytes(&cam), default_samples(usize::MAX, 3)));
    assert_eq!(r.ok(), Some((u64::MAX, 2)));
}
