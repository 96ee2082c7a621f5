//! Times one client frame of `ours` and `forward_splat` at 1280×720 + 2×640×360 (a quick check;
//! the criterion bench is the reference figure).
//!
//! `cargo run --release -p reproj-core --example time_ours [METHOD] [WIDTH]`; environment:
//! `ITERS` (timed calls, default 6), `SHADOWS=1` (keep the dynamic shadows, as the bench does),
//! `NOBLEND=1` (no Algorithm 2), `AUX_ONLY=1` (skip the run without auxiliary cameras),
//! `MAIN_ONLY=1` (skip the run with them; against `AUX_ONLY=1`, what the auxiliary cameras cost),
//! `PAIR=1` (keep one `BidirHistory` across the calls, as a client does within a server-frame
//! pair, so the pair-level work is done once instead of per call), `PREPARE=1` (with `PAIR`: compute
//! the pair state with `prepare_pair` before the first call, as a real-time client does off the
//! display path, after one call without the history that warms the per-frame buffers;
//! `PREPARE=only`: those two and nothing else, to subtract them from an instruction count;
//! `PREPARE=time`: then `ITERS` more `prepare_pair` calls, each after `BidirHistory::reset`, so
//! that each computes the pair again into the same buffers as a client's next pair does, and
//! their median and minimum wall-clock time and CPU time per call; `RAYON_NUM_THREADS=1` for
//! the real-time client's one preparation thread).
//! For instruction counts that do not depend on the machine's load:
//! `ITERS=4` and `ITERS=0` under `valgrind --tool=callgrind`, and the difference over 4.
//!
//! Besides the wall-clock time it prints the process CPU time per call (Linux only: from
//! `/proc/self/stat`), which moves much less than wall-clock time when other jobs share the
//! machine (run with `RAYON_NUM_THREADS=1` for a per-core figure), the share of the machine's
//! CPU time that a virtual machine's host took meanwhile (`steal` in `/proc/stat`: other guests
//! on the same cores; the calls are slower for that), and a digest (FNV-1a) of the
//! output colour and diagnostics, so that a change meant to be exact can be checked to give the
//! same bytes (`ALPHA` sets α, default 0.5, and 1.5 for `ours_extrapolate`, which only
//! extrapolates).
//!
//! `PERIOD_MS=8.33` paces the timed calls as a display at 120 Hz does (each starts at its
//! refresh, the thread sleeps in between) and prints their median, p99 and maximum: a frame after
//! an idle gap costs more than one right after another, and a background job (a decoder at idle
//! priority) shows here.
//!
//! `SIMD=avx2` (or `baseline`, `avx512`) caps the instruction set of the row loops
//! ([`ours::set_simd_limit`]; the library's own `REPROJ_SIMD` does the same). With two or more
//! tiers (`SIMD=avx2,avx512`) the first one is timed as above, and then the tiers against each
//! other in this process, alternating frame by frame (the order rotated every round), each output
//! checked to be the same bytes; it prints the median of each tier's frame time over the first
//! tier's in the same round: separate processes of the same binary spread by ±20 % on a shared
//! machine, adjacent frames much less.
use reproj_core::synthetic::{head_pose, rig, SyntheticFrame, SyntheticScene};
use reproj_core::*;

const USAGE: &str = "usage: time_ours [METHOD] [WIDTH]  (METHOD: ours, ours_extrapolate, \
forward_splat, timewarp, backward_bidir; WIDTH: main camera width, 16..=16384, height 9/16 of it)";

/// Says why it cannot run, with the usage, and exits with status 2.
fn fail(why: String) -> ! {
    eprintln!("time_ours: error: {why}\n{USAGE}");
    std::process::exit(2)
}

/// The command line's method and main camera size, or the usage message and exit status 2.
fn parse_args() -> (Option<Method>, usize, usize) {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() > 2 {
        fail(format!("expected at most 2 arguments, got {}", args.len()));
    }
    let method = args
        .first()
        .map(|m| m.parse().unwrap_or_else(|e| fail(format!("{e}"))));
    let (w, h) = match args.get(1) {
        Some(s) => match s.parse::<usize>() {
            Ok(w) if (16..=MAX_SIDE).contains(&w) => (w, w * 9 / 16),
            _ => fail(format!(
                "WIDTH: expected an integer in 16..={MAX_SIDE}, got {s:?}"
            )),
        },
        None => (1280, 720),
    };
    (method, w, h)
}

fn main() {
    let (method, w, h) = parse_args();
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
    let alpha: Option<f32> = std::env::var("ALPHA").ok().map(|s| {
        s.parse()
            .unwrap_or_else(|_| fail(format!("ALPHA: expected a number, got {s:?}")))
    });
    let mut out = vec![0u8; w * h * 3];
    let iters: usize = std::env::var("ITERS").map_or(6, |s| {
        s.parse()
            .unwrap_or_else(|_| fail(format!("ITERS: expected a count, got {s:?}")))
    });
    let period = std::env::var("PERIOD_MS")
        .ok()
        .map(|s| match s.parse::<f64>() {
            Ok(ms) if ms.is_finite() && ms > 0.0 => std::time::Duration::from_secs_f64(ms / 1e3),
            _ => fail(format!(
                "PERIOD_MS: expected milliseconds above 0, got {s:?}"
            )),
        });
    let tiers: Vec<ours::Simd> = std::env::var("SIMD").map_or(Vec::new(), |s| {
        s.split(',')
            .map(|t| t.parse().unwrap_or_else(|e| fail(format!("SIMD: {e}"))))
            .collect()
    });
    if let Some(&t) = tiers.first() {
        ours::set_simd_limit(t);
    }
    let methods: Vec<Method> = match method {
        Some(m) => vec![m],
        None => vec![Method::Ours, Method::ForwardSplat],
    };
    for method in methods {
        // `ours_extrapolate` takes α ≥ 1 (from the newest frame, half a server period on); the
        // others interpolate at α = 0.5 (`forward_splat` splats both frames here).
        let extrapolates = method == Method::OursExtrapolate;
        let req = Request {
            client: rig(e, tg, w, h).0,
            alpha: alpha.unwrap_or(if extrapolates { 1.5 } else { 0.5 }),
        };
        for use_aux in [false, true] {
            if !use_aux && std::env::var_os("AUX_ONLY").is_some() {
                continue;
            }
            if use_aux && std::env::var_os("MAIN_ONLY").is_some() {
                continue;
            }
            let p = Params {
                use_aux,
                splat_bidirectional: true,
                blend: std::env::var_os("NOBLEND").is_none(),
                ..Params::default()
            };
            let mut history = BidirHistory::new();
            let keep = std::env::var_os("PAIR").is_some();
            let mut diag = Diagnostics::new(w * h);
            out.fill(0);
            // One client frame of this configuration.
            let frame = |out: Output, h: Option<&mut BidirHistory>| {
                reproject(method, Some(&older), &newer, &req, &p, out, h)
                    .unwrap_or_else(|e| fail(format!("{method}: {e}")))
            };
            let prepare = std::env::var("PREPARE").ok();
            let prepared = keep && prepare.is_some();
            if prepared {
                // A frame without the history first, as the previous pair's frames leave the
                // per-frame buffers warm in a client: what follows then counts the pair work
                // alone, not the first use of those buffers.
                frame(Output::new(&mut out), None);
                // The older frame only when interpolating: a late frame prepares extrapolation.
                let o = (req.alpha < 1.0).then_some(&older);
                prepare_pair(method, o, &newer, &req.client, &p, &mut history)
                    .unwrap_or_else(|e| fail(format!("{method}: {e}")));
                if prepare.as_deref() == Some("only") {
                    println!("{method} aux={use_aux}: prepared only");
                    continue;
                }
                if prepare.as_deref() == Some("time") {
                    let (cpu0, ticks0) = (cpu_seconds(), machine_ticks());
                    let mut ms: Vec<f64> = (0..iters)
                        .map(|_| {
                            history.reset();
                            let t = std::time::Instant::now();
                            prepare_pair(method, o, &newer, &req.client, &p, &mut history)
                                .unwrap_or_else(|e| fail(format!("{method}: {e}")));
                            t.elapsed().as_secs_f64() * 1000.0
                        })
                        .collect();
                    let cpu = (cpu_seconds() - cpu0) * 1000.0 / iters.max(1) as f64;
                    let steal = steal_share(ticks0, machine_ticks());
                    ms.sort_by(f64::total_cmp);
                    match ms.first() {
                        Some(min) => println!(
                            "{method} aux={use_aux}: prepare_pair {:.2} ms median, {min:.2} ms \
                             min, {cpu:.2} ms CPU per call ({iters} calls){}",
                            ms[ms.len() / 2],
                            host_share(steal)
                        ),
                        None => println!("{method} aux={use_aux}: ITERS=0, nothing timed"),
                    }
                    continue;
                }
            }
            let mut calls_ms: Vec<f64> = Vec::new();
            let mut timed = |history: &mut BidirHistory, out: &mut [u8]| {
                let (cpu0, faults0, ticks0) = (cpu_seconds(), minor_faults(), machine_ticks());
                let t = std::time::Instant::now();
                let mut busy = std::time::Duration::ZERO;
                for k in 0..iters {
                    if let Some(p) = period {
                        // Paced like a display: call k starts at its refresh, not at once.
                        let tick = t + p * k as u32;
                        std::thread::sleep(
                            tick.saturating_duration_since(std::time::Instant::now()),
                        );
                    }
                    let c = std::time::Instant::now();
                    let h = keep.then_some(&mut *history);
                    frame(Output::new(out), h);
                    busy += c.elapsed();
                    calls_ms.push(c.elapsed().as_secs_f64() * 1000.0);
                }
                let steal = steal_share(ticks0, machine_ticks());
                (busy, cpu_seconds() - cpu0, minor_faults() - faults0, steal)
            };
            // After a prepare the timed calls come first, so that the first of them is the
            // pair's first client frame (instruction counts: `ITERS=1` minus `ITERS=0`).
            let early = prepared.then(|| timed(&mut history, &mut out));
            let before = out.clone();
            let h = keep.then_some(&mut history);
            frame(Output::with_diagnostics(&mut out, &mut diag), h);
            let digest = fnv1a(
                out.iter()
                    .chain(&diag.source)
                    .copied()
                    .chain(diag.error.iter().flat_map(|e| e.to_bits().to_le_bytes())),
            );
            let (elapsed, cpu, faults, steal) = match early {
                Some(e) => {
                    // The same request on the same buffer (unmatched pixels keep its colour):
                    // the same bytes.
                    assert!(
                        iters == 0 || out == before,
                        "repeated call changed the output"
                    );
                    e
                }
                None => {
                    let first = out.clone();
                    let e = timed(&mut history, &mut out);
                    // The same request again (with the pair state warm when PAIR is set): the
                    // same bytes.
                    assert!(
                        iters == 0 || out == first,
                        "repeated call changed the output"
                    );
                    e
                }
            };
            if tiers.len() >= 2 {
                simd_ab(&tiers, iters, &out, |out| {
                    frame(Output::new(out), keep.then_some(&mut history));
                });
                ours::set_simd_limit(tiers[0]);
            }
            let n = iters.max(1) as f64;
            if period.is_some() {
                calls_ms.sort_by(f64::total_cmp);
                let at = |q: f64| calls_ms[((calls_ms.len() - 1) as f64 * q).round() as usize];
                if !calls_ms.is_empty() {
                    println!(
                        "  paced calls: p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
                        at(0.5),
                        at(0.99),
                        at(1.0)
                    );
                }
            }
            println!(
                "{method} aux={use_aux}: {:.1} ms wall, {:.1} ms CPU, {:.0} page faults per call; digest {digest:016x}; pair builds {}{}",
                elapsed.as_secs_f64() * 1000.0 / n,
                cpu * 1000.0 / n,
                faults / n,
                history.pair_builds(),
                host_share(steal)
            );
        }
    }
}

/// `SIMD` with several tiers: `iters` rounds of one frame per tier (the order rotated every
/// round), each output compared with `expect`; prints each tier's median frame time and the
/// median over rounds of its time over the first tier's.
fn simd_ab(tiers: &[ours::Simd], iters: usize, expect: &[u8], mut frame: impl FnMut(&mut [u8])) {
    let mut out = expect.to_vec();
    let mut ms = vec![Vec::new(); tiers.len()];
    for round in 0..iters {
        for k in (0..tiers.len()).map(|k| (k + round) % tiers.len()) {
            ours::set_simd_limit(tiers[k]);
            let t = std::time::Instant::now();
            frame(&mut out);
            ms[k].push(t.elapsed().as_secs_f64() * 1000.0);
            assert!(out == expect, "{:?} gave other bytes", tiers[k]);
        }
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    for (k, &t) in tiers.iter().enumerate() {
        ours::set_simd_limit(t);
        let ratio: Vec<f64> = ms[k].iter().zip(&ms[0]).map(|(a, b)| a / b).collect();
        println!(
            "  {t:?} (runs as {:?}): median {:.2} ms, paired median over {:?} {:.3}",
            ours::simd_tier(),
            median(ms[k].clone()),
            tiers[0],
            median(ratio)
        );
    }
}

/// FNV-1a over a byte stream.
fn fnv1a(bytes: impl Iterator<Item = u8>) -> u64 {
    bytes.fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Minor page faults of this process so far (Linux `/proc/self/stat`), or NaN.
fn minor_faults() -> f64 {
    stat_fields()
        .get(7)
        .and_then(|v| v.parse().ok())
        .unwrap_or(f64::NAN)
}

/// The fields of `/proc/self/stat` after the parenthesised command name (empty elsewhere).
fn stat_fields() -> Vec<String> {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return Vec::new();
    };
    let rest = &stat[stat.rfind(')').map_or(0, |k| k + 2)..];
    rest.split_whitespace().map(str::to_owned).collect()
}

/// The machine's CPU time in every state and the part of it its host took (`steal`), all CPUs
/// together, in clock ticks since boot: the first eight numbers of Linux `/proc/stat`'s `cpu`
/// line (the guest columns after them are already inside the first two). `None` elsewhere.
fn machine_ticks() -> Option<(u64, u64)> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let line = stat
        .lines()
        .find(|l| l.split_whitespace().next() == Some("cpu"))?;
    let ticks: Vec<u64> = line
        .split_whitespace()
        .skip(1)
        .take(8)
        .map(|t| t.parse().ok())
        .collect::<Option<_>>()?;
    (ticks.len() == 8).then(|| (ticks.iter().sum(), ticks[7]))
}

/// The share (0–1) of the machine's CPU time between two [`machine_ticks`] readings that its
/// host took: on a virtual machine whose host runs other guests on its cores, the calls are
/// slower for that, not for the kernel (`None` without readings or ticks between them).
fn steal_share(before: Option<(u64, u64)>, after: Option<(u64, u64)>) -> Option<f64> {
    let ((t0, s0), (t1, s1)) = (before?, after?);
    let (total, steal) = (t1.checked_sub(t0)?, s1.checked_sub(s0)?);
    (total > 0 && steal <= total).then(|| steal as f64 / total as f64)
}

/// "; the host took X % of the CPU time (steal)" where the share is known, else nothing.
fn host_share(steal: Option<f64>) -> String {
    steal.map_or(String::new(), |s| {
        format!("; the host took {:.1} % of the CPU time (steal)", s * 100.0)
    })
}

/// User + system CPU time of this process in seconds (Linux `/proc/self/stat`, clock ticks of
/// 1/100 s), or NaN where that file does not exist.
fn cpu_seconds() -> f64 {
    // utime and stime are fields 14 and 15 of the file.
    let f = stat_fields();
    let ticks = |k: usize| {
        f.get(k)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NAN)
    };
    (ticks(11) + ticks(12)) / 100.0
}
