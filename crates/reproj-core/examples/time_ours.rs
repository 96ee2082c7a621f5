//! Times one client frame of `ours` and `forward_splat` at 1280×720 + 2×640×360 (a quick check;
//! the criterion bench is the reference figure).
//!
//! `cargo run --release -p reproj-core --example time_ours [METHOD] [WIDTH]`; environment:
//! `ITERS` (timed calls, default 6), `SHADOWS=1` (keep the dynamic shadows, as the bench does),
//! `NOBLEND=1` (no Algorithm 2), `AUX_ONLY=1` (skip the run without auxiliary cameras). For instruction counts that do not depend on the machine's load:
//! `ITERS=4` and `ITERS=0` under `valgrind --tool=callgrind`, and the difference over 4.
use reproj_core::synthetic::{head_pose, rig, SyntheticFrame, SyntheticScene};
use reproj_core::*;

fn main() {
    let (w, h): (usize, usize) = match std::env::args().nth(2) {
        Some(s) => (s.parse().unwrap(), s.parse::<usize>().unwrap() * 9 / 16),
        None => (1280, 720),
    };
    let scene = SyntheticScene::new(true);
    // Shadows off: this times the reprojection core, not the shadow lookups.
    let f0 = SyntheticFrame::render(&scene, 0.0, w, h, 0.1, 4);
    let f1 = SyntheticFrame::render(&scene, 0.1, w, h, 0.1, 4);
    let (mut older, mut newer) = (f0.view(true), f1.view(false));
    for v in [&mut older, &mut newer]
        .into_iter()
        .filter(|_| std::env::var_os("SHADOWS").is_none())
    {
        v.main.shadow = None;
        v.aux.iter_mut().for_each(|a| a.shadow = None);
    }
    let (e, tg) = head_pose(0.05);
    let req = Request {
        client: rig(e, tg, w, h).0,
        alpha: 0.5,
    };
    let mut out = vec![0u8; w * h * 3];
    let iters: usize = std::env::var("ITERS").map_or(6, |s| s.parse().unwrap());
    let methods: Vec<Method> = match std::env::args().nth(1) {
        Some(m) => vec![m.parse().unwrap()],
        None => vec![Method::Ours, Method::ForwardSplat],
    };
    for method in methods {
        for use_aux in [false, true] {
            if !use_aux && std::env::var_os("AUX_ONLY").is_some() {
                continue;
            }
            let p = Params {
                use_aux,
                splat_bidirectional: true,
                blend: std::env::var_os("NOBLEND").is_none(),
                ..Params::default()
            };
            reproject(method, Some(&older), &newer, &req, &p, &mut out, None, None).unwrap();
            let t = std::time::Instant::now();
            for _ in 0..iters {
                reproject(method, Some(&older), &newer, &req, &p, &mut out, None, None).unwrap();
            }
            println!(
                "{method} aux={use_aux}: {:.1} ms",
                t.elapsed().as_secs_f64() * 1000.0 / iters as f64
            );
        }
    }
}
