//! Median wall time of one server frame (main + two auxiliary cameras, S = 4) and one
//! ground-truth client frame of the dynamic `courtyard` at 320×180 and 640×360, with the
//! default colour sub-samples: a quicker before/after check than the criterion bench.
//!
//! `cargo run --release -p reproj-scene --example render_time`

use std::hint::black_box;
use std::time::Instant;

use reproj_scene::{builtin, render_client_frame, render_server_frame, Variant};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    if std::env::args().len() > 1 {
        eprintln!("render_time: error: expected no arguments\nusage: render_time");
        std::process::exit(2);
    }
    let scene = builtin("courtyard", Variant::Dynamic)?;
    for scale in [0.125, 0.25] {
        let reps = if scale < 0.2 { 5 } else { 3 };
        let mut server = Vec::new();
        let mut truth = Vec::new();
        for r in 0..reps {
            let t = Instant::now();
            black_box(render_server_frame(&scene, 5 + r, scale, 10.0, 4)?);
            server.push(t.elapsed().as_secs_f64());
            let t = Instant::now();
            black_box(render_client_frame(&scene, 60 + r, scale, 120.0, false)?);
            truth.push(t.elapsed().as_secs_f64());
        }
        let (w, h) = reproj_scene::main_size(scale)?;
        println!(
            "{w}x{h}: server frame {:.3} s, ground truth {:.3} s (median of {reps})",
            median(server),
            median(truth)
        );
    }
    Ok(())
}
