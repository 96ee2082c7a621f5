//! GPU against CPU on the built-in dynamic scenes (`courtyard`, `colonnade`, `lab`, rendered by
//! reproj-scene at 150×84 with two 75×42 auxiliary cameras, every buffer, S = 4; no side a
//! multiple of the 16×16 workgroup, so that a dispatch rounded down or an invocation guard off by
//! one at the right or bottom edge drops pixels): for `ours` (interpolating and extrapolating,
//! with a strict ε_E that leaves the auxiliary cameras thousands of pixels and some pixels
//! unmatched, to α = 3 without auxiliary cameras, into a 131×79 client camera of another size
//! than the server's), `ours_extrapolate` and `forward_splat` (unidirectional and bidirectional),
//! the wgpu output equals reproj-core's, pixels, source codes and reprojection errors, within
//! [`Tolerance`]: on lavapipe (what CI runs) exactly, on other adapters 99.5 % of the pixels and
//! source codes and a mean absolute difference below 0.5/255. The 64-bit and the 32-bit splat
//! give identical images.
//!
//! Without an adapter the tests print why and pass, unless `REPROJ_WGPU_REQUIRE_ADAPTER=1` (set by
//! CI, which installs lavapipe) makes that a failure.

use std::sync::OnceLock;

use reproj_core::{Diagnostics, Method, Output, Params, Request};
use reproj_scene::{builtin, mono, render_server_frame, Variant};
use reproj_wgpu::{
    Atomics, ContextOptions, GpuContext, GpuError, Previous, Reprojector, ReprojectorOptions,
};

/// 2560·0.05859375 × 1440·0.05859375 = 150×84 (auxiliary cameras 75×42).
const SCALE: f64 = 0.05859375;
const FS: f64 = 10.0;
const SUBFRAMES: usize = 4;
/// A client camera of another size than the server's, its sides prime: of its pixel centres only
/// the central row's and column's (NDC 0, exact in f32) lie on a pixel edge of the 150×84 or
/// 75×42 sources (see [`Case::client`]).
const OTHER_CLIENT: (usize, usize) = (131, 79);

/// How close the GPU's output must be to reproj-core's.
///
/// On lavapipe every case here is bit-identical (Mesa 22.3.6, LLVM 15: images, source codes,
/// reprojection errors; also at 160×90 and 128×72), so it must stay so: a kernel that is wrong
/// in a handful of pixels (an auxiliary camera's rare branch, the last column of a tile, the
/// unmatched pixels) fails. A share-of-pixels bound let such bugs through: 0.1 % of 150×84 is
/// 12 pixels, more than the auxiliary cameras colour in some interpolating cases. Other adapters
/// (FMA contraction, other rounding) keep a looser bound, which has not been measured against.
#[derive(Debug, Clone, Copy)]
struct Tolerance {
    /// Everything bit-identical (lavapipe).
    exact: bool,
    /// Least share of identical pixels (and of identical source codes).
    min_equal: f64,
    /// Largest mean absolute difference, in 8-bit units.
    max_mad: f64,
}

impl Tolerance {
    fn of(ctx: &GpuContext) -> Tolerance {
        if ctx.info.name.contains("llvmpipe") {
            Tolerance {
                exact: true,
                min_equal: 1.0,
                max_mad: 0.0,
            }
        } else {
            Tolerance {
                exact: false,
                min_equal: 0.995,
                max_mad: 0.5,
            }
        }
    }

    fn holds(self, d: &Diff) -> bool {
        if self.exact {
            return d.pixels == 0 && d.codes == 0 && d.errors == 0;
        }
        let n = d.n as f64;
        1.0 - d.pixels as f64 / n >= self.min_equal
            && 1.0 - d.codes as f64 / n >= self.min_equal
            && d.mad < self.max_mad
    }
}

fn context() -> Option<&'static GpuContext> {
    static CTX: OnceLock<Option<GpuContext>> = OnceLock::new();
    CTX.get_or_init(|| match GpuContext::new(&ContextOptions::default()) {
        Ok(c) => {
            eprintln!("wgpu adapter: {}", c.describe());
            Some(c)
        }
        Err(e) => {
            if std::env::var_os("REPROJ_WGPU_REQUIRE_ADAPTER").is_some_and(|v| v == "1") {
                panic!("REPROJ_WGPU_REQUIRE_ADAPTER=1 but {e}");
            }
            eprintln!("skipping the GPU parity tests: {e}");
            None
        }
    })
    .as_ref()
}

struct Case {
    name: &'static str,
    method: Method,
    alpha: f32,
    params: Params,
    /// Give the GPU and the CPU the older frame.
    with_older: bool,
    /// The client camera's size when not the server's. A client whose pixel centres fall exactly
    /// on the sources' pixel edges (e.g. 131×77 against 84 rows: row 5 at y = 1 − 11/77, exactly
    /// the edge of source row 6 in real arithmetic) differs on lavapipe in that row and only
    /// there: the GPU's and the CPU's last-bit f32 rounding put it on different sides of the
    /// edge. [`OTHER_CLIENT`] has no such centre.
    client: Option<(usize, usize)>,
}

fn cases() -> Vec<Case> {
    let p = Params::default();
    let bi = Params {
        splat_bidirectional: true,
        ..p
    };
    let case = |name, method, alpha, params, with_older| Case {
        name,
        method,
        alpha,
        params,
        with_older,
        client: None,
    };
    vec![
        case("ours interpolating", Method::Ours, 5.0 / 12.0, p, true),
        case("ours extrapolating", Method::Ours, 1.25, p, true),
        case("ours_extrapolate", Method::OursExtrapolate, 1.5, p, false),
        case("forward_splat", Method::ForwardSplat, 1.25, p, false),
        case(
            "forward_splat bidirectional",
            Method::ForwardSplat,
            7.0 / 12.0,
            bi,
            true,
        ),
        // 0.15 × the default ε_E: the main camera's matches fail in most pixels, so that the
        // auxiliary cameras (their bidirectional search, Algorithm 2 and the merge) colour about
        // 7,000 and over 2,000 keep the previous frame.
        case(
            "ours interpolating, strict eps_e",
            Method::Ours,
            0.5,
            Params { eps_e: 0.0003, ..p },
            true,
        ),
        // Far ahead without auxiliary cameras: hundreds of pixels unmatched at the borders.
        case(
            "ours extrapolating to alpha 3, no aux",
            Method::Ours,
            3.0,
            Params {
                use_aux: false,
                ..p
            },
            false,
        ),
        Case {
            client: Some(OTHER_CLIENT),
            ..case(
                "ours interpolating, other client size",
                Method::Ours,
                0.5,
                p,
                true,
            )
        },
    ]
}

/// How a GPU output differs from the CPU's.
#[derive(Debug)]
struct Diff {
    /// Pixels.
    n: usize,
    /// Pixels with another colour.
    pixels: usize,
    /// Mean absolute difference (8-bit units, over channels).
    mad: f64,
    /// Pixels with another source code.
    codes: usize,
    /// Pixels with another reprojection error (bits; any NaN equals any NaN).
    errors: usize,
    /// The first differing pixel (colour, code or error), (column, row).
    first: Option<(usize, usize)>,
}

fn compare(w: usize, a: (&[u8], &Diagnostics), b: (&[u8], &Diagnostics)) -> Diff {
    let n = a.0.len() / 3;
    let mut d = Diff {
        n,
        pixels: 0,
        mad: 0.0,
        codes: 0,
        errors: 0,
        first: None,
    };
    let mut sad = 0u64;
    for k in 0..n {
        let (x, y) = (&a.0[3 * k..3 * k + 3], &b.0[3 * k..3 * k + 3]);
        sad += x
            .iter()
            .zip(y)
            .map(|(&p, &q)| u64::from(p.abs_diff(q)))
            .sum::<u64>();
        let (ea, eb) = (a.1.error[k], b.1.error[k]);
        let pixel = x != y;
        let code = a.1.source[k] != b.1.source[k];
        let error = ea.to_bits() != eb.to_bits() && !(ea.is_nan() && eb.is_nan());
        d.pixels += usize::from(pixel);
        d.codes += usize::from(code);
        d.errors += usize::from(error);
        if (pixel || code || error) && d.first.is_none() {
            d.first = Some((k % w, k / w));
        }
    }
    d.mad = sad as f64 / a.0.len() as f64;
    d
}

fn check_scene(name: &str) {
    let Some(ctx) = context() else { return };
    let tol = Tolerance::of(ctx);
    let scene = builtin(name, Variant::Dynamic).expect("built-in scene");
    let k = 2;
    let f0 = render_server_frame(&scene, k, SCALE, FS, SUBFRAMES).expect("render");
    let f1 = render_server_frame(&scene, k + 1, SCALE, FS, SUBFRAMES).expect("render");
    let (sw, sh) = (f0.main.buffers.width, f0.main.buffers.height);
    assert_eq!((sw, sh), (150, 84));
    let older = f0.view(true);
    let newer = f1.view(false);
    let mut gpus: Vec<Reprojector> = vec![Reprojector::new(
        ctx,
        &ReprojectorOptions {
            force_32bit_atomics: true,
        },
    )
    .expect("pipelines")];
    let native = Reprojector::new(ctx, &ReprojectorOptions::default()).expect("pipelines");
    if native.atomics() == Atomics::Int64 {
        gpus.push(native);
    } else {
        eprintln!(
            "{name}: the adapter has no 64-bit atomic min/max; testing the 32-bit splat only"
        );
    }
    let mut failures = Vec::new();
    // Pixels over all cases that kept the previous frame, and that an auxiliary camera coloured
    // while interpolating.
    let (mut kept, mut aux_interpolated) = (0, 0);
    for case in cases() {
        let (w, h) = case.client.unwrap_or((sw, sh));
        // A previous frame that is not black, so that "unmatched pixels keep it" is compared too.
        let previous: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 251) as u8).collect();
        let t = (k as f64 + f64::from(case.alpha)) / FS;
        let client = mono(&scene.path.client_pose(t), w, h, scene.near, scene.far);
        let request = Request {
            client,
            alpha: case.alpha,
        };
        let older_arg = case.with_older.then_some(&older);
        let mut cpu = previous.clone();
        let mut cpu_diag = Diagnostics::new(w * h);
        reproj_core::reproject(
            case.method,
            older_arg,
            &newer,
            &request,
            &case.params,
            Output::with_diagnostics(&mut cpu, &mut cpu_diag),
            None,
        )
        .expect("cpu");
        let unmatched = cpu_diag
            .source
            .iter()
            .filter(|&&s| s == Diagnostics::NONE)
            .count();
        kept += unmatched;
        if case.with_older && case.alpha < 1.0 && case.method == Method::Ours {
            aux_interpolated += cpu_diag
                .source
                .iter()
                .filter(|&&s| s & !Diagnostics::BLENDED >= Diagnostics::AUX_BASE)
                .count();
        }
        let mut images = Vec::new();
        for gpu in gpus.iter_mut() {
            gpu.load(older_arg, &newer).expect("load");
            let mut img = vec![0u8; w * h * 3];
            let mut diag = Diagnostics::new(w * h);
            gpu.render(
                0,
                case.method,
                &request,
                &case.params,
                Previous::Image(&previous),
                Some(&mut img),
                Some(&mut diag),
            )
            .expect("gpu");
            let d = compare(w, (&img, &diag), (&cpu, &cpu_diag));
            let line = format!(
                "{name} {} ({}, {w}x{h}): {} pixels, {} source codes, {} errors differ (first at \
                 {:?}), MAD {:.4}/255; {unmatched} unmatched",
                case.name,
                gpu.atomics().name(),
                d.pixels,
                d.codes,
                d.errors,
                d.first,
                d.mad,
            );
            eprintln!("{line}");
            if !tol.holds(&d) {
                failures.push(format!("{line} (tolerance {tol:?})"));
            }
            // A scene where nothing matches would make the comparison vacuous.
            assert!(
                unmatched * 2 < w * h,
                "{name} {}: {unmatched} of {} unmatched",
                case.name,
                w * h
            );
            images.push(img);
        }
        if images.len() == 2 {
            assert!(
                images[0] == images[1],
                "{name} {}: the 32-bit and 64-bit splats differ",
                case.name
            );
        }
    }
    // Otherwise "unmatched pixels keep the previous frame" and the auxiliary cameras' share of an
    // interpolated frame would go untested (measured: 2,621 to 3,678 and 6,961 to 8,200).
    assert!(
        kept >= 1000,
        "{name}: only {kept} pixels kept the previous frame"
    );
    assert!(
        aux_interpolated >= 3000,
        "{name}: only {aux_interpolated} interpolated pixels from an auxiliary camera"
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn courtyard_matches_the_cpu() {
    check_scene("courtyard");
}

#[test]
fn colonnade_matches_the_cpu() {
    check_scene("colonnade");
}

#[test]
fn lab_matches_the_cpu() {
    check_scene("lab");
}

/// The device keeps the previous frame: rendering twice into one slot with `Previous::Keep`
/// equals the CPU fed its own previous output (with a strict ε_E, so that thousands of pixels
/// are unmatched and keep it), and the errors of the CPU path come through.
#[test]
fn device_resident_frames_and_errors() {
    let Some(ctx) = context() else { return };
    let scene = builtin("courtyard", Variant::Dynamic).expect("built-in scene");
    let f0 = render_server_frame(&scene, 1, SCALE, FS, SUBFRAMES).expect("render");
    let f1 = render_server_frame(&scene, 2, SCALE, FS, SUBFRAMES).expect("render");
    let (w, h) = (f0.main.buffers.width, f0.main.buffers.height);
    let older = f0.view(true);
    let newer = f1.view(false);
    let mut gpu = Reprojector::new(ctx, &ReprojectorOptions::default()).expect("pipelines");
    let p = Params {
        eps_e: 0.0003,
        ..Params::default()
    };
    let request = |n: usize| {
        let alpha = n as f32 / 12.0;
        let t = 0.1 + f64::from(alpha) / FS;
        Request {
            client: mono(&scene.path.client_pose(t), w, h, scene.near, scene.far),
            alpha,
        }
    };
    // Before load: a state error, not a panic.
    let mut img = vec![0u8; w * h * 3];
    assert!(matches!(
        gpu.render(
            0,
            Method::Ours,
            &request(3),
            &p,
            Previous::Black,
            Some(&mut img),
            None
        ),
        Err(GpuError::Order(_))
    ));
    gpu.load(Some(&older), &newer).expect("load");
    let mut cpu = vec![0u8; w * h * 3];
    let mut cpu_diag = Diagnostics::new(w * h);
    let mut diag = Diagnostics::new(w * h);
    // Something to keep: the first frame over a previous image, not black.
    img.iter_mut()
        .enumerate()
        .for_each(|(i, v)| *v = (i * 7 % 251) as u8);
    cpu.copy_from_slice(&img);
    for n in [3, 4, 9] {
        reproj_core::reproject(
            Method::Ours,
            Some(&older),
            &newer,
            &request(n),
            &p,
            Output::with_diagnostics(&mut cpu, &mut cpu_diag),
            None,
        )
        .expect("cpu");
        let first = img.clone();
        let prev = if n == 3 {
            Previous::Image(&first)
        } else {
            Previous::Keep
        };
        gpu.render(
            0,
            Method::Ours,
            &request(n),
            &p,
            prev,
            Some(&mut img),
            Some(&mut diag),
        )
        .expect("gpu");
        let d = compare(w, (&img, &diag), (&cpu, &cpu_diag));
        assert!(Tolerance::of(ctx).holds(&d), "frame {n}: {d:?}");
        let kept = cpu_diag
            .source
            .iter()
            .filter(|&&s| s == Diagnostics::NONE)
            .count();
        assert!(kept * 20 > w * h, "frame {n}: only {kept} pixels kept");
    }
    // The frame stays on the device for a presenter.
    let (buf, bw, bh) = gpu.output_buffer(0).expect("output");
    assert_eq!((bw, bh), (w, h));
    assert_eq!(buf.size(), (w * h * 4) as u64);
    // Input errors carry the CPU path's messages.
    let cpu_err = reproj_core::reproject(
        Method::OursExtrapolate,
        Some(&older),
        &newer,
        &request(3),
        &p,
        Output::new(&mut cpu),
        None,
    )
    .expect_err("alpha < 1");
    let gpu_err = gpu
        .render(
            0,
            Method::OursExtrapolate,
            &request(3),
            &p,
            Previous::Keep,
            Some(&mut img),
            None,
        )
        .expect_err("alpha < 1");
    assert_eq!(gpu_err, GpuError::Input(cpu_err));
    assert!(matches!(
        gpu.render(
            0,
            Method::Timewarp,
            &request(3),
            &p,
            Previous::Keep,
            Some(&mut img),
            None
        ),
        Err(GpuError::Unsupported(_))
    ));
    let mut short = vec![0u8; 5];
    assert!(matches!(
        gpu.render(
            0,
            Method::Ours,
            &request(3),
            &p,
            Previous::Keep,
            Some(&mut short),
            None
        ),
        Err(GpuError::Input(reproj_core::ReprojError::BufferSize { .. }))
    ));
}

/// A pair uploaded on another thread while the reprojector renders, then installed, gives the
/// same bytes as loading it; installing pairs back and forth needs no upload, and each install
/// renders its own pair (the bind groups follow it).
#[test]
fn uploaded_pairs_render_as_loaded_ones() {
    let Some(ctx) = context() else { return };
    let scene = builtin("courtyard", Variant::Dynamic).expect("built-in scene");
    let frames: Vec<_> = (1..4)
        .map(|k| render_server_frame(&scene, k, SCALE, FS, SUBFRAMES).expect("render"))
        .collect();
    let (w, h) = (frames[0].main.buffers.width, frames[0].main.buffers.height);
    let p = Params::default();
    // Client frame `n` of the pair that ends at frame `k` (α = n/12 after frame k − 1).
    let request = |k: usize, n: usize| {
        let alpha = n as f32 / 12.0;
        let t = (k as f64 - 1.0 + f64::from(alpha)) / FS;
        Request {
            client: mono(&scene.path.client_pose(t), w, h, scene.near, scene.far),
            alpha,
        }
    };
    let render = |gpu: &mut Reprojector, r: &Request| {
        let mut img = vec![0u8; w * h * 3];
        gpu.render(
            0,
            Method::Ours,
            r,
            &p,
            Previous::Black,
            Some(&mut img),
            None,
        )
        .expect("render");
        img
    };
    // What loading each pair gives (pair a: frames 1, 2; pair b: frames 2, 3).
    let mut loaded = Reprojector::new(ctx, &ReprojectorOptions::default()).expect("pipelines");
    loaded
        .load(Some(&frames[0].view(true)), &frames[1].view(false))
        .expect("load");
    let want_a = render(&mut loaded, &request(2, 5));
    loaded
        .load(Some(&frames[1].view(true)), &frames[2].view(false))
        .expect("load");
    let want_b = render(&mut loaded, &request(3, 5));
    assert_ne!(want_a, want_b, "the two pairs must give different images");

    let mut gpu = Reprojector::new(ctx, &ReprojectorOptions::default()).expect("pipelines");
    let uploader = gpu.uploader();
    let a = std::sync::Arc::new(
        uploader
            .upload(Some(&frames[0].view(true)), &frames[1].view(false))
            .expect("upload a"),
    );
    assert!(a.has_older());
    assert!(a.device_bytes() >= (w * h * 2 * 32) as u64);
    assert!(gpu.install(a.clone()).expect("install a").is_none());
    // Pair b goes up on another thread while this one renders pair a.
    let b = std::thread::scope(|s| {
        let up = s.spawn(|| uploader.upload(Some(&frames[1].view(true)), &frames[2].view(false)));
        for n in 1..6 {
            render(&mut gpu, &request(2, n));
        }
        up.join().expect("upload thread").expect("upload b")
    });
    let b = std::sync::Arc::new(b);
    assert_eq!(render(&mut gpu, &request(2, 5)), want_a);
    // Installing hands back the pair that was current.
    let previous = gpu
        .install(b.clone())
        .expect("install b")
        .expect("a was current");
    assert!(std::sync::Arc::ptr_eq(&previous, &a));
    assert_eq!(render(&mut gpu, &request(3, 5)), want_b);
    gpu.install(a).expect("install a again");
    assert_eq!(render(&mut gpu, &request(2, 5)), want_a);
    // An extrapolation-only pair (no older frame) installs the same way.
    let only = uploader
        .upload(None, &frames[2].view(false))
        .expect("upload");
    assert!(!only.has_older());
    gpu.install(std::sync::Arc::new(only)).expect("install");
    let extrapolated = Request {
        alpha: 1.25,
        ..request(3, 0)
    };
    render(&mut gpu, &extrapolated);
    let mut img = vec![0u8; w * h * 3];
    // Interpolating needs the older frame: the CPU path's error, not a panic.
    assert!(matches!(
        gpu.render(
            0,
            Method::Ours,
            &request(3, 5),
            &p,
            Previous::Black,
            Some(&mut img),
            None
        ),
        Err(GpuError::Input(reproj_core::ReprojError::MissingFrame(_)))
    ));
}
