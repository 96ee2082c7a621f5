//! One server frame (main + two auxiliary cameras, every buffer, S = 4) and one ground-truth
//! client frame of a built-in scene at a reduced size but with the colour sub-samples of
//! 1280×720 (2×2 on the main camera and the ground truth, 3×3 on the 640×360 auxiliary cameras),
//! with an FNV-1a digest of each, for counting instructions per frame under a profiler (the
//! per-pixel work is that of a 1280×720 frame; scale the count by the pixel ratio) and for
//! checking that a speed-up leaves the bytes alone.
//!
//! `cargo run --release -p reproj-scene --example render_count -- [scene] [scale] [server|truth|both]`

use reproj_scene::{builtin, main_size, mono, render_ground_truth, render_server, rig, Variant};

fn fnv1a(h: u64, bytes: &[u8]) -> u64 {
    bytes.iter().fold(h, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

const USAGE: &str = "usage: render_count [SCENE] [SCALE] [server|truth|both]  (defaults: \
courtyard 0.05 both)";

fn fail(why: &str) -> ! {
    eprintln!("render_count: error: {why}\n{USAGE}");
    std::process::exit(2)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() > 4 {
        fail(&format!(
            "expected at most 3 arguments, got {}",
            args.len() - 1
        ));
    }
    let name = args.get(1).map_or("courtyard", String::as_str);
    let scale: f64 = args.get(2).map_or(0.05, |s| {
        s.parse()
            .unwrap_or_else(|_| fail(&format!("SCALE: cannot read {s:?}")))
    });
    let what = args.get(3).map_or("both", String::as_str);
    if !["server", "truth", "both"].contains(&what) {
        fail(&format!("expected server, truth or both, got {what:?}"));
    }
    let scene = builtin(name, Variant::Dynamic)?;
    let (w, h) = main_size(scale)?;
    let (fs, k, fc, n) = (10.0, 20, 120.0, 240);
    if what != "truth" {
        let pose = scene.path.server_pose(k, fs);
        let r = rig(&pose, w, h, scene.near, scene.far);
        let t = k as f64 / fs;
        let mut d = 0xcbf2_9ce4_8422_2325;
        for (cam, samples) in [(&r.main, 2), (&r.aux[0], 3), (&r.aux[1], 3)] {
            let b = render_server(&scene, cam, t, 1.0 / fs, 4, samples)?.buffers;
            let floats = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
            d = fnv1a(d, &b.color);
            d = fnv1a(d, &floats(&b.depth));
            d = fnv1a(d, &floats(&b.motion_fwd));
            d = fnv1a(d, &floats(&b.motion_bwd));
            for sb in [&b.shadow_fwd, &b.shadow_bwd] {
                let bits: Vec<u8> = sb.bits.iter().flat_map(|x| x.to_le_bytes()).collect();
                d = fnv1a(d, &bits);
                d = fnv1a(d, &sb.s_min);
                d = fnv1a(d, &sb.s_max);
            }
        }
        println!("{name} {w}x{h} server frame {k}: {d:016x}");
    }
    if what != "server" {
        let t = n as f64 / fc;
        let cam = mono(&scene.path.client_pose(t), w, h, scene.near, scene.far);
        let img = render_ground_truth(&scene, &cam, t, 2)?;
        println!(
            "{name} {w}x{h} ground truth {n}: {:016x}",
            fnv1a(0xcbf2_9ce4_8422_2325, &img)
        );
    }
    Ok(())
}
