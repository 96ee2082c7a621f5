//! Times one client frame of `ours` and `forward_splat` at 1280×720 + 2×640×360 (a quick check;
//! the criterion bench is the reference figure).
use reproj_core::synthetic::{head_pose, rig, RenderedCamera, SyntheticScene};
use reproj_core::*;

fn cv(x: &(Camera, RenderedCamera), fwd: bool) -> CameraView<'_> {
    CameraView {
        camera: x.0,
        color: &x.1.color,
        depth: &x.1.depth,
        motion: Some(if fwd {
            &x.1.motion_fwd
        } else {
            &x.1.motion_bwd
        }),
        shadow: None,
    }
}

fn main() {
    let (w, h): (usize, usize) = match std::env::args().nth(2) {
        Some(s) => (s.parse().unwrap(), s.parse::<usize>().unwrap() * 9 / 16),
        None => (1280, 720),
    };
    let scene = SyntheticScene::new(true);
    let mk = |t: f64| {
        let (e, tg) = head_pose(t);
        let (m, a) = rig(e, tg, w, h);
        [m, a[0], a[1]].map(|c| (c, scene.render_server(&c, t, 0.1, 4)))
    };
    let f0 = mk(0.0);
    let f1 = mk(0.1);
    let older = FrameView {
        main: cv(&f0[0], true),
        aux: vec![cv(&f0[1], true), cv(&f0[2], true)],
    };
    let newer = FrameView {
        main: cv(&f1[0], false),
        aux: vec![cv(&f1[1], false), cv(&f1[2], false)],
    };
    let (e, tg) = head_pose(0.05);
    let req = Request {
        client: rig(e, tg, w, h).0,
        alpha: 0.5,
    };
    let mut out = vec![0u8; w * h * 3];
    let methods: Vec<Method> = match std::env::args().nth(1) {
        Some(m) => vec![m.parse().unwrap()],
        None => vec![Method::Ours, Method::ForwardSplat],
    };
    for method in methods {
        for use_aux in [false, true] {
            let p = Params {
                use_aux,
                splat_bidirectional: true,
                ..Params::default()
            };
            reproject(method, Some(&older), &newer, &req, &p, &mut out, None, None).unwrap();
            let t = std::time::Instant::now();
            for _ in 0..3 {
                reproject(method, Some(&older), &newer, &req, &p, &mut out, None, None).unwrap();
            }
            println!(
                "{method} aux={use_aux}: {:.1} ms",
                t.elapsed().as_secs_f64() * 1000.0 / 3.0
            );
        }
    }
}
