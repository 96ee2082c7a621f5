//! Writes the main-camera colour of server frame `k` of each built-in dynamic scene as PPM files
//! (`preview_<scene>.ppm` in the current directory), for a quick look.
//!
//! `cargo run --release -p reproj-scene --example preview -- [k] [scale]`

use reproj_scene::{builtin, render_server_frame, Variant, SCENE_NAMES};

const USAGE: &str = "usage: preview [K] [SCALE]  (K: server frame index, default 10; SCALE: of \
2560x1440, default 0.125)";

/// Argument `i`'s value, `default` without it; the usage and exit status 2 for one that does not
/// parse or is one too many.
fn arg<T: std::str::FromStr>(args: &[String], i: usize, name: &str, default: T) -> T {
    if args.len() > 2 {
        fail(&format!("expected at most 2 arguments, got {}", args.len()));
    }
    args.get(i).map_or(default, |s| {
        s.parse()
            .unwrap_or_else(|_| fail(&format!("{name}: cannot read {s:?}")))
    })
}

fn fail(why: &str) -> ! {
    eprintln!("preview: error: {why}\n{USAGE}");
    std::process::exit(2)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let k: usize = arg(&args, 0, "K", 10);
    let scale: f64 = arg(&args, 1, "SCALE", 0.125);
    for name in SCENE_NAMES {
        let scene = builtin(name, Variant::Dynamic)?;
        let t0 = std::time::Instant::now();
        let f = render_server_frame(&scene, k, scale, 10.0, 4)?;
        let m = &f.main.buffers;
        let mut out = format!("P6 {} {} 255\n", m.width, m.height).into_bytes();
        out.extend_from_slice(&m.color);
        std::fs::write(format!("preview_{name}.ppm"), out)?;
        let moving = m
            .motion_fwd
            .chunks(3)
            .filter(|c| c.iter().any(|&v| v != 0.0))
            .count();
        let bits = m.shadow_fwd.bits.iter().filter(|&&b| b != 0).count();
        println!(
            "{name}: {}x{} in {:.2?}; moving pixels {moving}, shadow-bit pixels {bits}",
            m.width,
            m.height,
            t0.elapsed()
        );
    }
    Ok(())
}
