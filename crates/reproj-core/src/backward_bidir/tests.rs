//! Unit tests of `backward_bidir`.

use super::*;
use crate::camera::{Camera, Mat4};

const W: usize = 32;
const H: usize = 24;

fn camera(w: usize, h: usize) -> Camera {
    Camera::new(
        Mat4::look_at([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]),
        Mat4::perspective(60.0, w as f64 / h as f64, 0.1, 100.0),
        w,
        h,
        "test",
    )
    .unwrap()
}

/// Reversed depth of view distance `d` for the test projection (near 0.1, far 100).
fn z_of(d: f64) -> f32 {
    (0.1 * (100.0 - d) / (d * (100.0 - 0.1))) as f32
}

/// A xorshift generator of uniform values in `[0, 1]` from `seed` (not 0).
fn xorshift(mut seed: u32) -> impl FnMut() -> f32 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        seed as f32 / u32::MAX as f32
    }
}

/// Owned buffers of one synthetic I-frame.
#[derive(Clone)]
struct Img {
    cam: Camera,
    color: Vec<u8>,
    depth: Vec<f32>,
    motion: Vec<f32>,
}

impl Img {
    fn frame(&self) -> FrameView<'_> {
        FrameView {
            main: CameraView {
                camera: self.cam,
                color: &self.color,
                depth: &self.depth,
                motion: Some(&self.motion),
                shadow: None,
            },
            aux: vec![],
        }
    }
}

fn run_bb(
    older: &Img,
    newer: &Img,
    alpha: f32,
    history: Option<&mut BidirHistory>,
) -> (Vec<u8>, Diagnostics) {
    let (w, h) = (older.cam.width, older.cam.height);
    let mut out = vec![3u8; w * h * 3];
    let mut diag = Diagnostics::new(w * h);
    let request = Request {
        client: older.cam,
        alpha,
    };
    run(
        &older.frame(),
        &newer.frame(),
        &request,
        &Params::default(),
        Output::with_diagnostics(&mut out, &mut diag),
        history,
    )
    .unwrap();
    (out, diag)
}

/// Background texture (b = 50) and square texture (b = 200); r, g ≤ 200 so that blends can
/// never produce the poison colour (255, 0, 255) used for invalid pixels.
fn bg(i: usize, j: usize) -> [u8; 3] {
    [(5 * i) as u8, (7 * j) as u8, 50]
}
fn sq(u: usize, v: usize) -> [u8; 3] {
    [(100 + 9 * u) as u8, (110 + 11 * v) as u8, 200]
}

const SIDE: usize = 8;
const A: (usize, usize) = (6, 8);
const SHIFT: (usize, usize) = (6, 4);

/// A static textured background at 10 m and an 8×8 textured square at 5 m with its top-left
/// pixel at `pos`, moving by `SHIFT` pixels per server frame (motion `sign·SHIFT` in NDC).
fn square_frame(pos: (usize, usize), sign: f32) -> Img {
    let cam = camera(W, H);
    let (mut color, mut depth, mut motion) = (Vec::new(), Vec::new(), Vec::new());
    let (dx, dy) = (
        2.0 * SHIFT.0 as f32 / W as f32,
        -2.0 * SHIFT.1 as f32 / H as f32,
    );
    for j in 0..H {
        for i in 0..W {
            let inside = (pos.0..pos.0 + SIDE).contains(&i) && (pos.1..pos.1 + SIDE).contains(&j);
            if inside {
                color.extend_from_slice(&sq(i - pos.0, j - pos.1));
                depth.push(z_of(5.0));
                motion.extend_from_slice(&[sign * dx, sign * dy, 0.0]);
            } else {
                color.extend_from_slice(&bg(i, j));
                depth.push(z_of(10.0));
                motion.extend_from_slice(&[0.0; 3]);
            }
        }
    }
    Img {
        cam,
        color,
        depth,
        motion,
    }
}

fn square_pair() -> (Img, Img) {
    (
        square_frame(A, 1.0),
        square_frame((A.0 + SHIFT.0, A.1 + SHIFT.1), -1.0),
    )
}

/// Whether output pixel `(i, j)` is covered by the square in `I_t` or in `I_{t+1}`.
fn seen_by_an_i_frame(i: usize, j: usize) -> bool {
    let inside = |(x, y): (usize, usize)| (x..x + SIDE).contains(&i) && (y..y + SIDE).contains(&j);
    inside(A) || inside((A.0 + SHIFT.0, A.1 + SHIFT.1))
}

/// Asserts that the square sits at the analytic position for `alpha` within 1 px and that its
/// interior carries the right texture. Unless `all_texels`, texels that neither I-frame's
/// square covers are not checked: with diagonal motion the corners of the square at `t+α` lie
/// over background in both I-frames, where the searches from `T` (default and dual
/// initialisation) converge to the static background, a valid solution of eq. 3 (seeds/001
/// §5.1 notes such multiple solutions). The latest-frame initialisation repairs them.
fn assert_square_at(out: &[u8], alpha: f32, all_texels: bool) -> usize {
    let ex = A.0 as f32 + alpha * SHIFT.0 as f32;
    let ey = A.1 as f32 + alpha * SHIFT.1 as f32;
    let (mut min_i, mut max_i, mut min_j, mut max_j) = (W, 0, H, 0);
    for j in 0..H {
        for i in 0..W {
            if out[3 * (j * W + i) + 2] == 200 {
                min_i = min_i.min(i);
                max_i = max_i.max(i);
                min_j = min_j.min(j);
                max_j = max_j.max(j);
            }
        }
    }
    assert!(
        (min_i as f32 - ex).abs() <= 1.0 && (max_i as f32 - (ex + SIDE as f32 - 1.0)).abs() <= 1.0,
        "x {min_i}..{max_i}, expected {ex}"
    );
    assert!(
        (min_j as f32 - ey).abs() <= 1.0 && (max_j as f32 - (ey + SIDE as f32 - 1.0)).abs() <= 1.0,
        "y {min_j}..{max_j}, expected {ey}"
    );
    let mut unseen_wrong = 0;
    if ex.fract() == 0.0 && ey.fract() == 0.0 {
        let (x0, y0) = (ex as usize, ey as usize);
        for v in 0..SIDE {
            for u in 0..SIDE {
                let (i, j) = (x0 + u, y0 + v);
                let k = j * W + i;
                if !all_texels && !seen_by_an_i_frame(i, j) {
                    unseen_wrong += usize::from(out[3 * k..3 * k + 3] != sq(u, v));
                    continue;
                }
                assert_eq!(
                    out[3 * k..3 * k + 3],
                    sq(u, v),
                    "texel ({u},{v}) at alpha {alpha}"
                );
            }
        }
    }
    unseen_wrong
}

#[test]
fn backward_bidir_endpoints_reproduce_the_i_frames() {
    let cam = camera(W, H);
    let depth: Vec<f32> = (0..W * H)
        .map(|k| z_of(3.0 + (k % 5) as f64 * 0.7))
        .collect();
    let older = Img {
        cam,
        color: (0..W * H * 3).map(|k| (k % 200) as u8).collect(),
        depth: depth.clone(),
        motion: vec![0.0; W * H * 3],
    };
    let newer = Img {
        color: (0..W * H * 3).map(|k| ((k * 7 + 13) % 250) as u8).collect(),
        ..older.clone()
    };
    let (out0, d0) = run_bb(&older, &newer, 0.0, None);
    assert_eq!(out0, older.color);
    assert!(d0.source.iter().all(|&s| s != Diagnostics::NONE));
    let (out1, _) = run_bb(&older, &newer, 1.0, None);
    assert_eq!(out1, newer.color);
    // Halfway, a static scene is the plain blend (rounded).
    let (out5, d5) = run_bb(&older, &newer, 0.5, None);
    for ((&o, &a), &b) in out5.iter().zip(&older.color).zip(&newer.color) {
        assert_eq!(o, ((f32::from(a) + f32::from(b)) * 0.5).round() as u8);
    }
    assert!(d5.source.iter().all(|&s| s & Diagnostics::BLENDED != 0));
    assert!(d5.error.iter().all(|e| e.is_finite()));
}

#[test]
fn backward_bidir_tracks_translating_square() {
    let (older, newer) = square_pair();
    let (out, diag) = run_bb(&older, &newer, 0.5, None);
    assert_square_at(&out, 0.5, false);
    assert!(diag.source.iter().all(|&s| s != Diagnostics::NONE));
    // The endpoints show each I-frame's square, every texel.
    assert_square_at(&run_bb(&older, &newer, 0.0, None).0, 0.0, true);
    assert_square_at(&run_bb(&older, &newer, 1.0, None).0, 1.0, true);
    assert_square_at(&run_bb(&older, &newer, 0.25, None).0, 0.25, false);
}

#[test]
fn backward_bidir_latest_frame_history() {
    let (older, newer) = square_pair();
    let mut hist = BidirHistory::new();
    assert_eq!(hist.alpha(), None);
    // The B-frames of one server interval at a 120/10 FPS ratio, up to α = 5/12.
    for b in 0..=5 {
        let alpha = b as f32 / 12.0;
        let (out, _) = run_bb(&older, &newer, alpha, Some(&mut hist));
        assert_eq!(hist.alpha(), Some(alpha));
        assert_square_at(&out, alpha, false);
    }
    // The corners that neither I-frame covers were found through the previous offsets...
    let (with_history, _) = run_bb(&older, &newer, 0.5, Some(&mut hist.clone()));
    let missed_with = assert_square_at(&with_history, 0.5, false);
    // ...which the default and dual initialisations alone miss.
    let missed_without = assert_square_at(&run_bb(&older, &newer, 0.5, None).0, 0.5, false);
    assert_eq!(
        (missed_with, missed_without > 0),
        (0, true),
        "{missed_with} {missed_without}"
    );
    // A smaller α than the stored one ignores the history and then replaces it.
    let (out, _) = run_bb(&older, &newer, 0.25, Some(&mut hist));
    assert_square_at(&out, 0.25, false);
    assert_eq!(hist.alpha(), Some(0.25));
    hist.reset();
    assert_eq!(hist.alpha(), None);
}

/// The full flows are computed once per pair and kept in the history: a second frame of the pair
/// uses the first's (poisoned here, it shows), a history whose flows are recomputed before every
/// frame gives the same bytes as one that keeps them, and a new pair (other buffers) or a reset
/// recomputes them.
#[test]
fn backward_bidir_flows_are_kept_for_the_pair() {
    let (older, newer) = square_pair();
    let alphas = [0.2f32, 0.45, 0.7];
    let (mut kept, mut fresh) = (BidirHistory::new(), BidirHistory::new());
    for &alpha in &alphas {
        fresh.flows.key = None;
        let a = run_bb(&older, &newer, alpha, Some(&mut kept));
        let b = run_bb(&older, &newer, alpha, Some(&mut fresh));
        assert!(a.0 == b.0 && a.1.source == b.1.source, "α = {alpha}");
        assert!(kept.flows.key.is_some());
    }
    // Reused: NaN flows left in the history make the next frame of the pair write nothing.
    let mut poisoned = kept.clone();
    poisoned.flows.vf.fill([f32::NAN; 3]);
    poisoned.flows.vb.fill([f32::NAN; 3]);
    let (_, diag) = run_bb(&older, &newer, 0.9, Some(&mut poisoned));
    assert!(diag.source.iter().all(|&s| s == Diagnostics::NONE));
    // Another pair (other buffers, the square elsewhere) at a smaller α, so that the
    // stored offsets do not apply: the flows are the new pair's, with or without a reset.
    let (o2, n2) = (
        square_frame((A.0 + 2, A.1), 1.0),
        square_frame((A.0 + 2 + SHIFT.0, A.1 + SHIFT.1), -1.0),
    );
    let want = run_bb(&o2, &n2, 0.1, None);
    let mut not_reset = poisoned.clone();
    let got = run_bb(&o2, &n2, 0.1, Some(&mut not_reset));
    assert!(got.0 == want.0 && got.1.source == want.1.source);
    poisoned.reset();
    assert!(poisoned.flows.key.is_none());
    let got = run_bb(&o2, &n2, 0.1, Some(&mut poisoned));
    assert!(got.0 == want.0 && got.1.source == want.1.source);
}

#[test]
fn backward_bidir_invalid_inputs_never_reach_output() {
    let (mut older, mut newer) = square_pair();
    let poison = [255u8, 0, 255];
    let bad = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.25, 2.0];
    for (n, img) in [&mut older, &mut newer].into_iter().enumerate() {
        for k in (n..W * H).step_by(7) {
            img.depth[k] = bad[k % bad.len()];
            img.color[3 * k..3 * k + 3].copy_from_slice(&poison);
        }
        for k in (n + 3..W * H).step_by(11) {
            img.motion[3 * k + k % 3] = if k % 2 == 0 { f32::NAN } else { f32::INFINITY };
            img.color[3 * k..3 * k + 3].copy_from_slice(&poison);
        }
    }
    for alpha in [0.0, 0.3, 0.5, 1.0] {
        let (out, diag) = run_bb(&older, &newer, alpha, None);
        for k in 0..W * H {
            let c = &out[3 * k..3 * k + 3];
            assert_ne!(c, poison, "invalid pixel leaked at {k}, alpha {alpha}");
            if diag.source[k] == Diagnostics::NONE {
                assert_eq!(c, [3, 3, 3]);
                assert!(diag.error[k].is_nan());
            } else {
                assert!(diag.error[k].is_finite());
            }
        }
    }
    // Nothing valid at all: nothing is written.
    older.depth.fill(f32::NAN);
    newer.depth.fill(f32::NAN);
    let mut hist = BidirHistory::new();
    let (out, diag) = run_bb(&older, &newer, 0.5, Some(&mut hist));
    assert!(out.iter().all(|&v| v == 3));
    assert!(diag.source.iter().all(|&s| s == Diagnostics::NONE));
    assert!(hist.offsets.iter().flatten().all(|v| v.is_nan()));
}

#[test]
fn backward_bidir_rejects_size_mismatch() {
    let (older, newer) = square_pair();
    let call = |older: &Img, newer: &Img, client: Camera, out: &mut [u8]| {
        let request = Request { client, alpha: 0.5 };
        let params = Params::default();
        run(
            &older.frame(),
            &newer.frame(),
            &request,
            &params,
            Output::new(out),
            None,
        )
    };
    let mut out = vec![0u8; 16 * 12 * 3];
    let r = call(&older, &newer, camera(16, 12), &mut out);
    assert!(matches!(r, Err(ReprojError::CameraMismatch(_))));
    assert!(out.iter().all(|&v| v == 0));
    let small = Img {
        cam: camera(16, 12),
        color: vec![0; 16 * 12 * 3],
        depth: vec![0.5; 16 * 12],
        motion: vec![0.0; 16 * 12 * 3],
    };
    let mut out = vec![0u8; W * H * 3];
    let r = call(&older, &small, older.cam, &mut out);
    assert!(matches!(r, Err(ReprojError::CameraMismatch(_))));
}

#[test]
fn backward_bidir_same_result_for_1_and_4_threads() {
    let (w, h) = (67, 45);
    let cam = camera(w, h);
    let mut rnd = xorshift(0x2545_f491);
    let mut img = || Img {
        cam,
        color: (0..w * h * 3).map(|_| (rnd() * 255.0) as u8).collect(),
        depth: (0..w * h)
            .map(|k| {
                if k % 37 == 0 {
                    f32::NAN
                } else {
                    z_of(2.0 + 8.0 * f64::from(rnd()))
                }
            })
            .collect(),
        motion: (0..w * h * 3).map(|_| (rnd() - 0.5) * 0.2).collect(),
    };
    let (older, newer) = (img(), img());
    let run_in = |n: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
            .install(|| {
                let mut hist = BidirHistory::new();
                let first = run_bb(&older, &newer, 0.3, Some(&mut hist));
                let second = run_bb(&older, &newer, 0.6, Some(&mut hist));
                (first, second, hist)
            })
    };
    let (a1, a2, ha) = run_in(1);
    let (b1, b2, hb) = run_in(4);
    for ((oa, da), (ob, db)) in [(a1, b1), (a2, b2)] {
        assert_eq!(oa, ob);
        assert_eq!(da.source, db.source);
        let bits = |d: &Diagnostics| d.error.iter().map(|e| e.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&da), bits(&db));
    }
    let bits = |h: &BidirHistory| {
        h.offsets
            .iter()
            .flatten()
            .map(|v| v.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&ha), bits(&hb));
}

/// A pass-2 context over random flows for the search tests: `w × h` images whose flows are zero
/// at about half of the pixels (so that searches stop at once and guesses repeat), small
/// elsewhere, NaN at some and large (leaving the image) at others, with latest-frame offsets of
/// the same kinds.
struct SearchCase {
    img: Img,
    vf: Vec<[f32; 3]>,
    vb: Vec<[f32; 3]>,
    offsets: Vec<[f32; 4]>,
}

impl SearchCase {
    fn new(w: usize, h: usize, seed: u32) -> SearchCase {
        let mut rnd = xorshift(seed);
        let mut flow = |_| {
            let kind = rnd();
            let s = if kind < 0.4 {
                0.0
            } else if kind < 0.9 {
                0.3
            } else {
                3.0
            };
            let v = [(rnd() - 0.5) * s, (rnd() - 0.5) * s, (rnd() - 0.5) * 0.01];
            if kind > 0.97 {
                [f32::NAN; 3]
            } else {
                v
            }
        };
        let vf: Vec<[f32; 3]> = (0..w * h).map(&mut flow).collect();
        let vb: Vec<[f32; 3]> = (0..w * h).map(&mut flow).collect();
        let offsets = (0..w * h)
            .map(|_| {
                let [a, b, _] = flow(0);
                let [c, d, _] = flow(0);
                [a, b, c, d]
            })
            .collect();
        let img = Img {
            cam: camera(w, h),
            color: vec![0; w * h * 3],
            depth: (0..w * h)
                .map(|_| z_of(2.0 + 8.0 * f64::from(rnd())))
                .collect(),
            motion: vec![0.0; w * h * 3],
        };
        SearchCase {
            img,
            vf,
            vb,
            offsets,
        }
    }

    /// `tol_px`: the error tolerance in pixels (the method's is 1).
    fn context(&self, alpha: f32, iterations: usize, tol_px: f32) -> Bidir<'_> {
        let view = self.img.frame().main;
        let params = Params {
            bidir_iterations: iterations,
            ..Params::default()
        };
        let latest = Latest {
            offsets: &self.offsets,
            scale_f: Some(1.5),
            scale_b: 0.5,
        };
        let mut ctx = Bidir::new(
            [(view, &self.vf), (view, &self.vb)],
            alpha,
            &params,
            Some(latest),
        );
        ctx.tol_e *= tol_px;
        ctx
    }
}

/// Every target of a `w × h` [`SearchCase`]: its pixel index, column, row and pixel-centre NDC.
fn targets<'a>(
    ctx: &'a Bidir<'_>,
    w: usize,
    h: usize,
) -> impl Iterator<Item = (usize, usize, usize, [f32; 2])> + 'a {
    (0..w * h).map(move |p| (p, p % w, p / w, ctx.ndc.at(p % w, p / w)))
}

/// `Bidir::search` leaves the iteration once a step stays on its pixel (or would leave the
/// image): it ends on the pixel that every one of the `iterations` steps, taken to the end,
/// reaches.
#[test]
fn backward_bidir_search_ends_where_all_its_steps_would() {
    let (w, h) = (29, 17);
    let case = SearchCase::new(w, h, 0x9e37_79b9);
    let mut stopped_early = 0;
    for iterations in [0, 1, 3, 7] {
        let ctx = case.context(0.35, iterations, 1.0);
        for dir in [Dir::Forward, Dir::Backward] {
            let (side, _) = ctx.side(dir);
            for (p, _, _, t) in targets(&ctx, w, h) {
                // Start away from the target's pixel too.
                let p0 = (p * 7 + p % 5) % (w * h);
                let p0 = Px {
                    i: p0 % w,
                    j: p0 / w,
                    p: p0,
                };
                let (mut q, mut steps) = (p0, 0);
                for _ in 0..iterations {
                    let v = side.flow[q.p];
                    if let Some(next) = ctx.pixel(t[0] - side.w * v[0], t[1] - side.w * v[1]) {
                        steps += usize::from(next.p != q.p);
                        q = next;
                    }
                }
                stopped_early += usize::from(steps < iterations);
                let found = ctx.search(side, t, p0);
                assert_eq!((found.q.i, found.q.j, found.q.p), (q.i, q.j, q.p));
            }
        }
    }
    assert!(
        stopped_early > 1000,
        "the case must have searches that stop: {stopped_early}"
    );
}

/// `Bidir::better` is antisymmetric, and `Bidir::direction`, which skips the search of an
/// initial pixel already searched, gives what searching every initialisation gives.
#[test]
fn backward_bidir_direction_skips_only_repeated_searches() {
    let (w, h) = (61, 37);
    let case = SearchCase::new(w, h, 0x1234_5677);
    let ctx = case.context(0.6, 3, 3.0);
    let mut repeats = 0;
    let mut latest_decides = 0;
    for dir in [Dir::Forward, Dir::Backward] {
        let (side, other) = ctx.side(dir);
        for (p, i, j, t) in targets(&ctx, w, h) {
            let vo = other.flow[p];
            let guesses = [
                Some(Px { i, j, p }),
                ctx.pixel(t[0] + side.w * vo[0], t[1] + side.w * vo[1]),
                ctx.latest_init(dir, side, i, j, t),
            ];
            let found: Vec<Found> = guesses
                .iter()
                .flatten()
                .map(|&p0| ctx.search(side, t, p0))
                .collect();
            for a in &found {
                assert!(!ctx.better(a, a));
                for b in &found {
                    assert!(!(ctx.better(a, b) && ctx.better(b, a)));
                }
            }
            let mut best = found[0];
            for c in &found[1..] {
                if ctx.better(c, &best) {
                    best = *c;
                }
            }
            // The latest-frame guess decides where it differs from both others and beats them.
            if let [Some(a), Some(b), Some(c)] = guesses {
                let distinct = a.p != b.p && c.p != a.p && c.p != b.p;
                let beats = ctx.better(&found[2], &found[1]) && ctx.better(&found[2], &found[0]);
                latest_decides += usize::from(distinct && beats);
            }
            let got = ctx.direction(dir, i, j, t);
            assert_eq!(got.q.p, best.q.p);
            assert_eq!(
                (got.e.to_bits(), got.z.to_bits()),
                (best.e.to_bits(), best.z.to_bits())
            );
            let ps: Vec<usize> = guesses.iter().flatten().map(|q| q.p).collect();
            repeats += usize::from(ps[1..].iter().any(|q| ps[..1].contains(q)));
        }
    }
    // The case must have both: repeated guesses (skipped) and decisive distinct ones (searched).
    assert!(
        repeats > 300 && latest_decides > 100,
        "{repeats} repeats, {latest_decides} decisive"
    );
}

/// `Bidir::latest_init`, which weighs a pixel that the previous neighbour also landed on only
/// once, picks what weighing all nine neighbours' landing pixels picks: the largest finite
/// reversed depth at `t+α`, the first in scan order on ties.
#[test]
fn backward_bidir_latest_init_is_the_nearest_of_the_nine() {
    let (w, h) = (61, 37);
    let case = SearchCase::new(w, h, 0x0bad_cafe);
    let ctx = case.context(0.4, 3, 1.0);
    let latest = ctx.latest.as_ref().unwrap();
    let (mut repeats, mut chosen) = (0, 0);
    for (dir, scale, k) in [
        (Dir::Forward, latest.scale_f.unwrap(), 0),
        (Dir::Backward, latest.scale_b, 2),
    ] {
        let (side, _) = ctx.side(dir);
        for (p, i, j, t) in targets(&ctx, w, h) {
            let mut want: Option<(f32, usize)> = None;
            let mut landed = Vec::new();
            for qj in j.saturating_sub(1)..=(j + 1).min(h - 1) {
                for qi in i.saturating_sub(1)..=(i + 1).min(w - 1) {
                    let d = latest.offsets[qj * w + qi];
                    let Some(p0) = ctx.pixel(t[0] - scale * d[k], t[1] - scale * d[k + 1]) else {
                        continue;
                    };
                    repeats += usize::from(landed.last() == Some(&p0.p));
                    landed.push(p0.p);
                    let z = side.view.depth[p0.p] + side.w * side.flow[p0.p][2];
                    if z.is_finite() && want.is_none_or(|(bz, _)| z > bz) {
                        want = Some((z, p0.p));
                    }
                }
            }
            let got = ctx.latest_init(dir, side, i, j, t);
            assert_eq!(got.map(|q| q.p), want.map(|(_, q)| q), "pixel {p}, {dir:?}");
            chosen += usize::from(got.is_some());
        }
    }
    assert!(
        repeats > 1000 && chosen > 1000,
        "{repeats} repeats, {chosen} chosen"
    );
}

/// The full flow of a pixel is its object motion carried into the other camera: into its own
/// camera, exactly that motion; into a camera that has the point behind it, none (NaN), not the
/// mirrored projection.
#[test]
fn backward_bidir_full_flow_is_the_motion_and_none_behind_the_camera() {
    let img = square_frame(A, 1.0);
    let view = img.frame().main;
    let from = img.cam.projector("from").unwrap();
    let mut flow = Vec::new();
    full_flow(&view, &from, &from, &mut flow);
    for (k, f) in flow.iter().enumerate() {
        for c in 0..3 {
            let (got, want) = (f[c], img.motion[3 * k + c]);
            assert!((got - want).abs() < 1e-5, "pixel {k}: {f:?}");
        }
    }
    let back = Camera::new(
        Mat4::look_at([0.0; 3], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
        Mat4::perspective(60.0, W as f64 / H as f64, 0.1, 100.0),
        W,
        H,
        "back",
    )
    .unwrap()
    .projector("back")
    .unwrap();
    full_flow(&view, &from, &back, &mut flow);
    assert!(flow.iter().flatten().all(|v| v.is_nan()));
}

/// The shading rules of seeds/001 §5.2 on hand-made flows, one output pixel per case, at
/// α = 0.25 on a 16×8 grid (one pixel = 0.25 in aspect-scaled NDC units, the tolerance):
/// rule 1 keeps the smaller error and blends; rule 2 keeps the nearer point and blends only
/// where the other frame sees it at the predicted depth; a single result within the tolerance
/// is used (just outside it does not count); rule 3 blends both and reports the smaller error.
#[test]
fn backward_bidir_visibility_rules_on_hand_made_flows() {
    let (w, h, alpha) = (16, 8, 0.25f32);
    let cam = camera(w, h);
    let (px, py) = (2.0 / w as f32, 2.0 / h as f32);
    let (near, far) = (z_of(5.0), z_of(10.0));
    let at = |i: usize, j: usize| j * w + i;
    let mut older = Img {
        cam,
        color: (0..w * h * 3).map(|k| (k % 97) as u8).collect(),
        depth: vec![near; w * h],
        motion: vec![0.0; w * h * 3],
    };
    let mut newer = Img {
        color: (0..w * h * 3).map(|k| (100 + k % 89) as u8).collect(),
        ..older.clone()
    };
    let (mut vf, mut vb) = (vec![[0.0f32; 3]; w * h], vec![[0.0f32; 3]; w * h]);
    // Rule 1: the same depth, sub-pixel flows; errors 0.25·(0.3, 0.2) px and 0.75·(0.3, 0.2) px.
    vf[at(2, 2)] = [0.3 * px, 0.2 * py, 0.0];
    vb[at(2, 2)] = [-0.3 * px, -0.2 * py, 0.0];
    // Rule 2: older nearer at (6, 2), newer nearer at (7, 2); no second chance (the other
    // frame's depth differs).
    newer.depth[at(6, 2)] = far;
    older.depth[at(7, 2)] = far;
    // Rule 2 with the second chance: older nearer at (10, 2), flowing one pixel right, where
    // the newer frame sees it at the same depth.
    newer.depth[at(10, 2)] = far;
    vf[at(10, 2)] = [px, 0.0, 0.0];
    // One within: the forward step leaves the image 1.3 px past the left border (error 1.3 px);
    // the backward one converges on a farther point, which it keeps.
    vf[at(0, 3)] = [0.65, 0.0, 0.0];
    newer.depth[at(0, 3)] = far;
    // Rule 3: both steps leave the image: errors 16 px (forward) and 24 px (backward).
    vf[at(6, 5)] = [8.0, 0.0, 0.0];
    vb[at(6, 5)] = [-4.0, 0.0, 0.0];
    let ctx = Bidir::new(
        [(older.frame().main, &vf), (newer.frame().main, &vb)],
        alpha,
        &Params::default(),
        None,
    );
    let a = |i, j| &older.color[3 * at(i, j)..3 * at(i, j) + 3];
    let b = |i, j| &newer.color[3 * at(i, j)..3 * at(i, j) + 3];
    let blend = |x: &[u8], y: &[u8]| -> Vec<u8> {
        x.iter()
            .zip(y)
            .map(|(&x, &y)| (0.75 * f32::from(x) + 0.25 * f32::from(y)).round() as u8)
            .collect()
    };
    let (old, new, both) = (
        Diagnostics::MAIN_OLDER,
        Diagnostics::MAIN_NEWER,
        Diagnostics::BLENDED,
    );
    let px_err = 2.0 / h as f32;
    // (pixel, diagnostic code, colour, error in pixels)
    let cases = [
        (
            (2, 2),
            old | both,
            blend(a(2, 2), b(2, 2)),
            0.25 * 0.13f32.sqrt(),
        ),
        ((6, 2), old, a(6, 2).to_vec(), 0.0),
        ((7, 2), new, b(7, 2).to_vec(), 0.0),
        ((10, 2), old | both, blend(a(10, 2), b(11, 2)), 0.25),
        ((0, 3), new, b(0, 3).to_vec(), 0.0),
        ((6, 5), old | both, blend(a(6, 5), b(6, 5)), 16.0),
        ((3, 6), new | both, blend(a(3, 6), b(3, 6)), 0.0),
    ];
    for ((i, j), code, rgb, err_px) in cases {
        let (res, _) = ctx.resolve_pixel(i, j);
        let (c, got, e) = res.expect("written");
        assert_eq!((c, got.to_vec()), (code, rgb), "pixel ({i}, {j})");
        assert!(
            (e - err_px * px_err).abs() < 1e-6,
            "pixel ({i}, {j}): error {e}"
        );
    }
}

/// After a B-frame at α₀ = 0 only the backward offsets apply (the forward ones are zero and
/// cannot be scaled): scaled by `(1−α)/(1−α₀)` (eq. 19) they find square texels at α = 0.5 that
/// neither I-frame covers and the other initialisations miss (5 of 12 when measured).
#[test]
fn backward_bidir_latest_frame_backward_offsets_are_scaled() {
    let (older, newer) = square_pair();
    let mut hist = BidirHistory::new();
    run_bb(&older, &newer, 0.0, Some(&mut hist));
    let (out, _) = run_bb(&older, &newer, 0.5, Some(&mut hist));
    let missed_with = assert_square_at(&out, 0.5, false);
    let missed_without = assert_square_at(&run_bb(&older, &newer, 0.5, None).0, 0.5, false);
    assert!(
        missed_with + 4 <= missed_without,
        "{missed_with} missed with the history, {missed_without} without"
    );
}
