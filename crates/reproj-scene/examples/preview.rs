//! Writes the main-camera colour of server frame `k` of each built-in dynamic scene as PPM files
//! (`preview_<scene>.ppm` in the current directory), for a quick look.
//!
//! `cargo run --release -p reproj-scene --example preview -- [k] [scale]`

use reproj_scene::{builtin, render_server_frame, Variant, SCENE_NAMES};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let k: usize = args.next().map_or(Ok(10), |s| s.parse())?;
    let scale: f64 = args.next().map_or(Ok(0.125), |s| s.parse())?;
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
