//! Unit tests of `ours` and `forward_splat`: analytic scenes (a textured plane, a moving object)
//! and the equivalences the optimisations must keep (lazy auxiliary search, pair cache).

use super::auxiliary::EAGER_AUX;
use super::*;
use crate::camera::Mat4;
use crate::frame::FrameView;
use crate::{reproject, Diagnostics, Method};

/// A fronto-parallel textured plane at view depth `d` seen by `cam` (exact per pixel).
fn plane(cam: &Camera, d: f64) -> (Vec<u8>, Vec<f32>) {
    let vp = cam.view_proj();
    let inv = vp.inverse().unwrap();
    let (w, h) = (cam.width, cam.height);
    let mut color = vec![0u8; w * h * 3];
    let mut depth = vec![0f32; w * h];
    // The plane z = -d in world space (cameras below look down −z from z = 0).
    for j in 0..h {
        for i in 0..w {
            let [x, y] = crate::camera::ndc_of_pixel(i, j, w, h);
            let a = inv.mul_vec([x as f64, y as f64, 1.0, 1.0]);
            let b = inv.mul_vec([x as f64, y as f64, 0.0, 1.0]);
            let (a, b) = (
                [a[0] / a[3], a[1] / a[3], a[2] / a[3]],
                [b[0] / b[3], b[1] / b[3], b[2] / b[3]],
            );
            let s = (-d - a[2]) / (b[2] - a[2]);
            let p = [a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), -d];
            let c = vp.mul_vec([p[0], p[1], p[2], 1.0]);
            depth[j * w + i] = (c[2] / c[3]) as f32;
            // Cells of 0.25 m (≈3 px here) with hashed colours: piecewise constant, so nearest
            // sampling of a sub-pixel shift reproduces a colour of a neighbouring exact pixel.
            let (u, v) = ((p[0] * 4.0).floor() as i64, (p[1] * 4.0).floor() as i64);
            let hsh = (u.wrapping_mul(73_856_093) ^ v.wrapping_mul(19_349_663)) as u64;
            let (v, u) = ((hsh % 251) as u8, ((hsh >> 8) % 2) as i64);
            color[3 * (j * w + i)..3 * (j * w + i) + 3].copy_from_slice(&[
                v,
                (u * 200) as u8 + 20,
                255 - v,
            ]);
        }
    }
    (color, depth)
}

/// [`reproject`] with the default parameters, without diagnostics or history.
fn reproject_plain(
    method: Method,
    older: Option<&FrameView>,
    newer: &FrameView,
    req: &Request,
    out: &mut [u8],
) {
    let p = Params::default();
    reproject(method, older, newer, req, &p, Output::new(out), None).unwrap();
}

fn cam(x: f64, w: usize, h: usize) -> Camera {
    Camera::new(
        Mat4::look_at([x, 0.0, 0.0], [x, 0.0, -1.0], [0.0, 1.0, 0.0]),
        Mat4::perspective(60.0, w as f64 / h as f64, 0.1, 100.0),
        w,
        h,
        "test",
    )
    .unwrap()
}

/// A frame of the main camera alone (no shadows, no auxiliary cameras).
fn main_only<'a>(
    camera: Camera,
    color: &'a [u8],
    depth: &'a [f32],
    motion: Option<&'a [f32]>,
) -> FrameView<'a> {
    FrameView {
        main: CameraView {
            camera,
            color,
            depth,
            motion,
            shadow: None,
        },
        aux: vec![],
    }
}

#[test]
fn static_identity_reproduces_the_server_image() {
    let c = cam(0.0, 64, 48);
    let (color, depth) = plane(&c, 3.0);
    let f = main_only(c, &color, &depth, None);
    for alpha in [0.0, 0.3, 0.99] {
        let mut out = vec![0u8; color.len()];
        let req = Request { client: c, alpha };
        reproject_plain(Method::Ours, Some(&f), &f, &req, &mut out);
        assert_eq!(out, color, "alpha {alpha}");
    }
}

#[test]
fn camera_translation_matches_the_analytic_image() {
    let (w, h) = (96, 64);
    let c0 = cam(0.0, w, h);
    let c1 = cam(0.2, w, h);
    let ct = cam(0.13, w, h);
    let (col0, dep0) = plane(&c0, 4.0);
    let (col1, dep1) = plane(&c1, 4.0);
    let (gt, _) = plane(&ct, 4.0);
    let f0 = main_only(c0, &col0, &dep0, None);
    let f1 = main_only(c1, &col1, &dep1, None);
    let mut out = vec![0u8; w * h * 3];
    let mut diag = Diagnostics::new(w * h);
    let req = Request {
        client: ct,
        alpha: 0.4,
    };
    let params = Params {
        blend: false,
        ..Params::default()
    };
    reproject(
        Method::Ours,
        Some(&f0),
        &f1,
        &req,
        &params,
        Output::with_diagnostics(&mut out, &mut diag),
        None,
    )
    .unwrap();
    let matched = diag
        .source
        .iter()
        .filter(|&&s| s != Diagnostics::NONE)
        .count();
    assert!(matched > w * h * 95 / 100, "matched {matched}");
    // Within one pixel: the colour equals the exact image at the pixel or one of its
    // 8 neighbours (nearest sampling of a sub-pixel shift), checked away from the border.
    let within_one = |k: usize| {
        let (i, j) = ((k % w) as i64, (k / w) as i64);
        (-1..=1).any(|dj| {
            (-1..=1).any(|di| {
                let (x, y) = (i + di, j + dj);
                x >= 0 && y >= 0 && x < w as i64 && y < h as i64 && {
                    let q = (y as usize * w + x as usize) * 3;
                    out[3 * k..3 * k + 3] == gt[q..q + 3]
                }
            })
        })
    };
    let exact = (0..w * h)
        .filter(|&k| diag.source[k] != Diagnostics::NONE && within_one(k))
        .count();
    assert!(exact * 100 >= matched * 97, "exact {exact} of {matched}");
}

fn cam_fov(x: f64, fov: f64, w: usize, h: usize) -> Camera {
    Camera::new(
        Mat4::look_at([x, 0.0, 0.0], [x, 0.0, -1.0], [0.0, 1.0, 0.0]),
        Mat4::perspective(fov, w as f64 / h as f64, 0.1, 100.0),
        w,
        h,
        "test",
    )
    .unwrap()
}

#[test]
fn auxiliary_camera_with_non_integer_ratio_fills_holes() {
    let (w, h) = (80, 60);
    let c = cam_fov(0.0, 60.0, w, h);
    // 37×29: no integer ratio to 80×60, and a wider field of view.
    let ca = cam_fov(0.0, 80.0, 37, 29);
    let (color, mut depth) = plane(&c, 3.0);
    let (acolor, adepth) = plane(&ca, 3.0);
    // A hole in the main camera: invalid depth must never reach the output.
    for j in 20..40 {
        for i in 30..50 {
            depth[j * w + i] = f32::NAN;
        }
    }
    let main = CameraView {
        camera: c,
        color: &color,
        depth: &depth,
        motion: None,
        shadow: None,
    };
    let aux = CameraView {
        camera: ca,
        color: &acolor,
        depth: &adepth,
        motion: None,
        shadow: None,
    };
    let f = FrameView {
        main,
        aux: vec![aux],
    };
    let mut out = vec![7u8; w * h * 3];
    let mut diag = Diagnostics::new(w * h);
    let req = Request {
        client: c,
        alpha: 0.5,
    };
    reproject(
        Method::Ours,
        Some(&f),
        &f,
        &req,
        &Params::default(),
        Output::with_diagnostics(&mut out, &mut diag),
        None,
    )
    .unwrap();
    let mut from_aux = 0;
    for j in 20..40 {
        for i in 30..50 {
            let k = j * w + i;
            let code = diag.source[k] & !Diagnostics::BLENDED;
            assert!(
                code >= Diagnostics::AUX_BASE,
                "hole pixel ({i},{j}) not from aux: {code}"
            );
            from_aux += 1;
            // The aux sample is the plane's colour somewhere within an aux pixel (≈2.2 output
            // pixels) of the exact point: equal to an exact main colour within 2 px.
            let ok = (-2i64..=2).any(|dj| {
                (-2i64..=2).any(|di| {
                    let q = ((j as i64 + dj) as usize * w + (i as i64 + di) as usize) * 3;
                    out[3 * k..3 * k + 3] == color[q..q + 3]
                })
            });
            assert!(ok, "pixel ({i},{j}) colour not from the plane near it");
        }
    }
    assert_eq!(from_aux, 400);
    // Outside the hole the main camera wins.
    let code = diag.source[5 * w + 5] & !Diagnostics::BLENDED;
    assert!(
        code == Diagnostics::MAIN_OLDER || code == Diagnostics::MAIN_NEWER,
        "{code}"
    );
}

#[test]
fn extrapolation_of_a_static_scene_is_the_identity() {
    let c = cam(0.0, 48, 32);
    let (color, depth) = plane(&c, 2.0);
    let f = main_only(c, &color, &depth, None);
    for alpha in [1.0, 1.5, 2.9] {
        for m in [Method::Ours, Method::OursExtrapolate] {
            let mut out = vec![0u8; color.len()];
            let req = Request { client: c, alpha };
            reproject(
                m,
                None,
                &f,
                &req,
                &Params::default(),
                Output::new(&mut out),
                None,
            )
            .unwrap();
            assert_eq!(out, color, "{m} alpha {alpha}");
        }
    }
}

/// The synthetic scene's client at `alpha` of the pair, moved off the server's path (0.25 right,
/// 0.1 down), so that it sees what the main camera did not and the auxiliary cameras matter.
fn off_path_request(alpha: f32, w: usize, h: usize) -> Request {
    off_path_request_by(alpha, [0.25, -0.1], w, h)
}

/// [`off_path_request`] with the client moved by `(dx, dy)` off the server's path.
fn off_path_request_by(alpha: f32, [dx, dy]: [f64; 2], w: usize, h: usize) -> Request {
    use crate::synthetic::{head_pose, rig};
    let (mut e, tg) = head_pose(0.1 * f64::from(alpha));
    e[0] += dx;
    e[1] += dy;
    Request {
        client: rig(e, tg, w, h).0,
        alpha,
    }
}

/// The lazy auxiliary search ([`AuxGrid`]) skips cells whose match cannot reach the output;
/// it must give the same bytes as searching every cell, with and without the older frame.
#[test]
fn lazy_auxiliary_search_equals_searching_every_cell() {
    use crate::synthetic::{SyntheticFrame, SyntheticScene};
    let (w, h) = (192, 108);
    let scene = SyntheticScene::new(true);
    let f0 = SyntheticFrame::render(&scene, 0.0, w, h, 0.1, 4);
    let f1 = SyntheticFrame::render(&scene, 0.1, w, h, 0.1, 4);
    let (older, newer) = (f0.view(true), f1.view(false));
    let (mut aux_pixels, mut overrides) = (0, 0);
    // Off the path by (0.25, −0.1) most auxiliary matches fill pixels where main found nothing
    // (§3.5 rule 1), and the few that replace a main match (rule 2) lie in the grids' border
    // cells; by (0.5, 0) some lie inside, where only the landing points' flags
    // ([`AuxGrid::maybe`]) have the lazy search look.
    let cases = [
        (0.35f32, true, [0.25, -0.1]),
        (0.8, true, [0.25, -0.1]),
        (1.4, false, [0.25, -0.1]),
        (0.35, true, [0.5, 0.0]),
        (1.4, false, [0.5, 0.0]),
    ];
    for (alpha, pair, off) in cases {
        let req = off_path_request_by(alpha, off, w, h);
        let run = |eager: bool, use_aux: bool| {
            EAGER_AUX.with(|x| x.set(eager));
            let mut out = vec![9u8; w * h * 3];
            let mut diag = Diagnostics::new(w * h);
            let older = pair.then_some(&older);
            let p = Params {
                use_aux,
                ..Params::default()
            };
            reproject(
                Method::Ours,
                older,
                &newer,
                &req,
                &p,
                Output::with_diagnostics(&mut out, &mut diag),
                None,
            )
            .unwrap();
            EAGER_AUX.with(|x| x.set(false));
            (out, diag)
        };
        let (lazy, eager) = (run(false, true), run(true, true));
        assert_eq!(lazy.0, eager.0, "colour, alpha {alpha}");
        assert_eq!(lazy.1.source, eager.1.source, "sources, alpha {alpha}");
        let from_aux = |c: u8| c & !Diagnostics::BLENDED >= Diagnostics::AUX_BASE;
        aux_pixels += eager.1.source.iter().filter(|&&c| from_aux(c)).count();
        // Rule 2: an auxiliary match where the main camera alone found one.
        let main_only = run(false, false).1.source;
        overrides += (0..w * h)
            .filter(|&k| main_only[k] != Diagnostics::NONE && from_aux(eager.1.source[k]))
            .count();
    }
    // The scene must exercise the auxiliary cameras for the comparison to mean anything, both
    // where main found nothing and where an auxiliary match replaces main's (which only the
    // flagged cells can do).
    assert!(
        aux_pixels > 100 && overrides > 25,
        "{aux_pixels} pixels from auxiliary cameras, {overrides} of them over a main match"
    );
}

/// Three consecutive server frames (10 Hz) of the dynamic synthetic scene at `w × h`: two pairs.
fn three_frames(w: usize, h: usize) -> Vec<crate::synthetic::SyntheticFrame> {
    use crate::synthetic::{SyntheticFrame, SyntheticScene};
    let scene = SyntheticScene::new(true);
    (0..3)
        .map(|k| SyntheticFrame::render(&scene, 0.1 * k as f64, w, h, 0.1, 4))
        .collect()
}

/// One client frame of `method` with diagnostics (over an output that is not black, so that
/// the pixels left alone show): its image and the source of every pixel.
fn with_sources(
    method: Method,
    older: Option<&FrameView>,
    newer: &FrameView,
    req: &Request,
    params: &Params,
    history: Option<&mut crate::BidirHistory>,
) -> (Vec<u8>, Vec<u8>) {
    let (w, h) = (req.client.width, req.client.height);
    let mut out = vec![3u8; w * h * 3];
    let mut diag = Diagnostics::new(w * h);
    reproject(
        method,
        older,
        newer,
        req,
        params,
        Output::with_diagnostics(&mut out, &mut diag),
        history,
    )
    .unwrap();
    (out, diag.source)
}

/// A client keeps one history per server-frame pair: with it, `ours` computes the pair-level
/// state once; the bytes must equal those of calls without it, for every α of the pair, and a
/// different pair in the same history must not be served the old pair's state.
#[test]
fn pair_cache_gives_the_same_bytes_and_follows_the_pair() {
    use crate::synthetic::{head_pose, rig};
    use crate::BidirHistory;
    let (w, h) = (96, 54);
    let frames = three_frames(w, h);
    let mut history = BidirHistory::new();
    for pair in 0..2 {
        let (older, newer) = (frames[pair].view(true), frames[pair + 1].view(false));
        for (n, alpha) in [0.0f32, 0.25, 0.5, 0.75, 0.95, 1.3].into_iter().enumerate() {
            let (mut e, tg) = head_pose(0.1 * (pair as f64 + f64::from(alpha)));
            e[0] += 0.05 * n as f64;
            let req = Request {
                client: rig(e, tg, w, h).0,
                alpha,
            };
            let p = Params::default();
            let run = |hist: Option<&mut BidirHistory>| {
                with_sources(Method::Ours, Some(&older), &newer, &req, &p, hist)
            };
            // Deliberately no reset between the pairs: the cache must notice by itself.
            let cached = run(Some(&mut history));
            let fresh = run(None);
            assert_eq!(cached, fresh, "pair {pair}, alpha {alpha}");
        }
    }
}

/// The pair state holds each pixel's colour with its partner's (the colour stage's texels), so a
/// pair whose depth and motion buffers are the same but whose colours (or shadow bits) are other
/// buffers must not be served the old colours.
#[test]
fn pair_cache_follows_new_colour_buffers() {
    use crate::synthetic::{head_pose, rig};
    use crate::BidirHistory;
    let (w, h) = (96, 54);
    let frames = three_frames(w, h);
    let (older, newer) = (frames[0].view(true), frames[1].view(false));
    let (e, tg) = head_pose(0.05);
    let req = Request {
        client: rig(e, tg, w, h).0,
        alpha: 0.5,
    };
    let p = Params::default();
    let mut history = BidirHistory::new();
    let first = with_sources(
        Method::Ours,
        Some(&older),
        &newer,
        &req,
        &p,
        Some(&mut history),
    );
    // Every camera's colours inverted, in new buffers; one camera without its shadow bits.
    let inverted = |v: &crate::frame::CameraView| v.color.iter().map(|c| 255 - c).collect();
    let colours: Vec<Vec<u8>> = [&older, &newer]
        .iter()
        .flat_map(|f| std::iter::once(&f.main).chain(&f.aux))
        .map(inverted)
        .collect();
    let mut views = [older.clone(), newer.clone()];
    let mut next = colours.iter();
    for f in &mut views {
        for v in std::iter::once(&mut f.main).chain(&mut f.aux) {
            v.color = next.next().unwrap();
        }
    }
    views[1].main.shadow = None;
    let [o2, n2] = &views;
    let cached = with_sources(Method::Ours, Some(o2), n2, &req, &p, Some(&mut history));
    let fresh = with_sources(Method::Ours, Some(o2), n2, &req, &p, None);
    assert_ne!(cached.0, first.0, "the colours changed");
    assert_eq!(cached, fresh);
    assert_eq!(history.pair_builds(), 2);
}

/// `prepare_pair` computes the pair state that the client frames of the pair then use: none of
/// them rebuilds it, and their bytes equal those of calls without a history; a different pair
/// rebuilds; extrapolation (no older frame) prepares its own state; the methods without pair
/// state do nothing.
#[test]
fn prepare_pair_does_the_pair_work_of_the_next_frames() {
    use crate::synthetic::{head_pose, rig};
    use crate::{prepare_pair, BidirHistory};
    let (w, h) = (96, 54);
    let frames = three_frames(w, h);
    let p = Params::default();
    let client = |t: f64| {
        let (e, tg) = head_pose(t);
        rig(e, tg, w, h).0
    };
    let frame = |method: Method,
                 older: Option<&FrameView>,
                 newer: &FrameView,
                 alpha: f32,
                 hist: Option<&mut BidirHistory>| {
        let req = Request {
            client: client(0.1 * f64::from(alpha)),
            alpha,
        };
        with_sources(method, older, newer, &req, &p, hist)
    };
    let mut history = BidirHistory::new();
    for (pair, builds) in [(0, 1), (1, 2)] {
        let (older, newer) = (frames[pair].view(true), frames[pair + 1].view(false));
        prepare_pair(
            Method::Ours,
            Some(&older),
            &newer,
            &client(0.0),
            &p,
            &mut history,
        )
        .unwrap();
        assert_eq!(history.pair_builds(), builds, "pair {pair} prepared");
        // Preparing the same pair again keeps the work.
        prepare_pair(
            Method::Ours,
            Some(&older),
            &newer,
            &client(0.3),
            &p,
            &mut history,
        )
        .unwrap();
        for alpha in [0.0f32, 0.3, 0.6, 0.9] {
            let prepared = frame(
                Method::Ours,
                Some(&older),
                &newer,
                alpha,
                Some(&mut history),
            );
            let fresh = frame(Method::Ours, Some(&older), &newer, alpha, None);
            assert_eq!(prepared, fresh, "pair {pair}, alpha {alpha}");
            assert_eq!(history.pair_builds(), builds, "pair {pair}, alpha {alpha}");
        }
    }
    // Extrapolation from the newest frame alone has state of its own.
    let newer = frames[2].view(false);
    for method in [Method::OursExtrapolate, Method::ForwardSplat] {
        let mut history = BidirHistory::new();
        prepare_pair(method, None, &newer, &client(0.0), &p, &mut history).unwrap();
        assert_eq!(history.pair_builds(), 1, "{method}");
        for alpha in [1.0f32, 1.5] {
            let prepared = frame(method, None, &newer, alpha, Some(&mut history));
            assert_eq!(
                prepared,
                frame(method, None, &newer, alpha, None),
                "{method}"
            );
            assert_eq!(history.pair_builds(), 1, "{method}, alpha {alpha}");
        }
    }
    let older = frames[1].view(true);
    for method in [Method::Timewarp, Method::BackwardBidir] {
        let mut history = BidirHistory::new();
        prepare_pair(method, Some(&older), &newer, &client(0.0), &p, &mut history).unwrap();
        assert_eq!(history.pair_builds(), 0, "{method}");
    }
    // It checks its inputs as `reproject` does.
    let bad = Params {
        eps_z: -1.0,
        ..Params::default()
    };
    let mut history = BidirHistory::new();
    assert!(prepare_pair(
        Method::Ours,
        Some(&older),
        &newer,
        &client(0.0),
        &bad,
        &mut history
    )
    .is_err());
    assert!(prepare_pair(
        Method::BackwardBidir,
        None,
        &newer,
        &client(0.0),
        &p,
        &mut history
    )
    .is_err());
    assert_eq!(history.pair_builds(), 0);
}

#[test]
fn moving_object_is_extrapolated_along_its_motion() {
    // The whole plane moves +x by 0.4 NDC per server interval (backward motion of the newer
    // frame is −0.4). At α = 1.5 the content must appear shifted by +0.2 NDC.
    let (w, h) = (64, 48);
    let c = cam(0.0, w, h);
    let (color, depth) = plane(&c, 2.0);
    let motion: Vec<f32> = (0..w * h).flat_map(|_| [-0.4f32, 0.0, 0.0]).collect();
    let f = main_only(c, &color, &depth, Some(&motion));
    let mut out = vec![0u8; color.len()];
    let req = Request {
        client: c,
        alpha: 1.5,
    };
    reproject_plain(Method::OursExtrapolate, None, &f, &req, &mut out);
    // 0.2 NDC = 6.4 px: output pixel i shows source pixel i − 6 or i − 7.
    let mut ok = 0;
    let mut total = 0;
    for j in 4..h - 4 {
        for i in 12..w - 4 {
            total += 1;
            let o = &out[3 * (j * w + i)..3 * (j * w + i) + 3];
            if [6, 7]
                .iter()
                .any(|d| o == &color[3 * (j * w + i - d)..3 * (j * w + i - d) + 3])
            {
                ok += 1;
            }
        }
    }
    assert!(ok * 100 >= total * 98, "{ok} of {total}");
}

/// The pass 1 tests' source: a 100 × 70 camera over a textured plane at depth 3 ([`plane`]),
/// handed to `f` as a view.
fn with_plane_view<R>(f: impl FnOnce(CameraView) -> R) -> R {
    with_plane_of(100, 70, f)
}

/// [`with_plane_view`] of a `w × h` camera.
fn with_plane_of<R>(w: usize, h: usize, f: impl FnOnce(CameraView) -> R) -> R {
    let c = cam(0.0, w, h);
    let (color, depth) = plane(&c, 3.0);
    f(CameraView {
        camera: c,
        color: &color,
        depth: &depth,
        motion: None,
        shadow: None,
    })
}

/// A source of `view` with buffers of its size, as `run` makes it.
fn source_of(view: CameraView) -> Src {
    let c = view.camera;
    let mut src = Src::new(view, c.projector("source").unwrap(), None, Role::Older, 0);
    src.bufs.fit(c.width * c.height, 0);
    src
}

/// The NDC transfer from camera `c` to a client of its size at the origin that looks `up` (the y
/// of its direction: the image moves down) and rolls (`roll`: the x of its up vector).
fn to_client_looking(c: &Camera, up: f64, roll: f64) -> NdcTransfer {
    let (w, h) = (c.width, c.height);
    let client = Camera::new(
        Mat4::look_at([0.0, 0.0, 0.0], [0.0, up, -1.0], [roll, 1.0, 0.0]),
        Mat4::perspective(60.0, w as f64 / h as f64, 0.1, 100.0),
        w,
        h,
        "client",
    )
    .unwrap();
    NdcTransfer::new(&c.view_proj().inverse().unwrap(), &client.view_proj())
}

/// Pass 1 of a plane seen by a client that looks `up` (the image moves down) and rolls (`roll`:
/// the x of its up vector): the splat grid, with the points that its tasks splatted outside
/// their own band (the spill lists) applied, and the window filter over it, against a
/// brute-force window minimum over every point's cell, for several window radii. Returns how
/// many points were spilled, out of the 100 × 280 (a camera tall enough for several bands).
fn window_filter_against_brute_force(up: f64, roll: f64) -> usize {
    with_plane_of(100, 280, |view| window_filter_of(view, up, roll))
}

/// [`window_filter_against_brute_force`] of `view`.
fn window_filter_of(view: CameraView, up: f64, roll: f64) -> usize {
    let (w, h) = (view.camera.width, view.camera.height);
    let to_client = to_client_looking(&view.camera, up, roll);
    let mut src = source_of(view);
    scene_flow_and_splat(&mut src, &to_client, 0.0, None, None);
    // The complete grid: the bands' own cells with the spilled points added (again: the minimum
    // is idempotent).
    let mut grid = src.bufs.splat.clone();
    let mut spilled = 0;
    for &(c, key) in src.bufs.spill.iter().flatten() {
        grid[c as usize] = grid[c as usize].min(key);
        spilled += 1;
    }
    for wr in 0..3 {
        window_min(&mut src, wr);
        for j in 0..h {
            for i in 0..w {
                let mut m = EMPTY_SPLAT;
                for q in j.saturating_sub(wr)..(j + wr + 1).min(h) {
                    for p in i.saturating_sub(wr)..(i + wr + 1).min(w) {
                        m = m.min(grid[q * w + p]);
                    }
                }
                assert_eq!(
                    src.bufs.init[j * w + i],
                    splat_index(m),
                    "wr {wr} ({i}, {j})"
                );
            }
        }
    }
    spilled
}

/// The window filter equals a brute-force minimum where many points spill: the client rolls, so
/// that the image moves vertically by different amounts across its width and no one shift of the
/// bands keeps every point in its own.
#[test]
fn window_filter_with_spilled_points_equals_a_brute_force_minimum() {
    let spilled = window_filter_against_brute_force(0.4, 0.6);
    // 2253 of 28,000 with SPLAT_BAND = 64.
    assert!(spilled > 100 * 280 / 20, "only {spilled} points spilled");
}

/// The splat bands follow a vertical shift of the whole image ([`pass1`]'s `band_starts`): the
/// client looks up, the image moves down by about a third of its height (~90 rows), which with
/// the bands at their source rows sends most points to the next band; shifted, few are spilled.
#[test]
fn splat_bands_follow_a_vertical_shift_of_the_image() {
    let spilled = window_filter_against_brute_force(0.4, 0.0);
    // None with SPLAT_BAND = 64; 16,990 of 28,000 with the bands at their source rows.
    assert!(spilled < 100 * 280 / 50, "{spilled} points spilled");
}

/// The splat grid is filled once every four frames ([`SplatEpoch`]): over frames whose client
/// poses differ (so that each leaves keys in cells where the next splats nothing), the window
/// search of a source whose buffers carry over equals that of fresh buffers every frame, through
/// two fills.
#[test]
fn window_search_ignores_the_keys_of_earlier_frames() {
    with_plane_view(window_search_over_frames);
}

/// [`window_search_ignores_the_keys_of_earlier_frames`] with `view`.
fn window_search_over_frames(view: CameraView) {
    let mut kept = source_of(view);
    let mut frames_with_old_keys = 0;
    for (f, up) in [0.4, -0.3, 0.0, 0.6, -0.5, 0.2, 0.5, -0.2, 0.1]
        .into_iter()
        .enumerate()
    {
        let to_client = to_client_looking(&view.camera, up, 0.0);
        let mut fresh = source_of(view);
        scene_flow_and_splat(&mut kept, &to_client, 0.0, None, None);
        scene_flow_and_splat(&mut fresh, &to_client, 0.0, None, None);
        assert_eq!(kept.bufs.epoch, SplatEpoch(f as u8 % 4), "frame {f}");
        let bound = kept.bufs.epoch.bound();
        frames_with_old_keys += usize::from(
            kept.bufs
                .splat
                .iter()
                .any(|&k| k != EMPTY_SPLAT && k as i64 >= bound),
        );
        for wr in 0..2 {
            window_min(&mut kept, wr);
            window_min(&mut fresh, wr);
            assert!(kept.bufs.init == fresh.bufs.init, "frame {f}, wr {wr}");
        }
        assert!(fresh.bufs.init.iter().any(|&p| p != NO_SPLAT));
    }
    // Most frames between the fills (frames 0 and 4 fill) splat nothing in some cells where an
    // earlier frame did, so that their search had old keys to ignore (5 of the 7 here).
    assert!(frames_with_old_keys >= 4, "{frames_with_old_keys}");
}

/// The row loops run in the best build the processor has (AVX-512, AVX2 or the baseline, see
/// `simd`); every build must give the same bytes (colour, sources and errors), for `ours` with and
/// without the pair state and for `forward_splat`. On a processor without AVX-512 the tiers above
/// it run as the best one below, and the comparison covers what the processor has.
#[test]
fn every_simd_tier_gives_the_same_bytes() {
    use crate::synthetic::{head_pose, rig};
    use crate::BidirHistory;
    let (w, h) = (192, 108);
    let frames = three_frames(w, h);
    let (older, newer) = (frames[0].view(true), frames[1].view(false));
    let p = Params::default();
    let frame = |method, alpha: f32, history: Option<&mut BidirHistory>| {
        let (mut e, tg) = head_pose(0.1 * f64::from(alpha));
        e[0] += 0.2;
        let req = Request {
            client: rig(e, tg, w, h).0,
            alpha,
        };
        let mut out = vec![7u8; w * h * 3];
        let mut diag = Diagnostics::new(w * h);
        let o = (alpha < 1.0).then_some(&older);
        let sink = Output::with_diagnostics(&mut out, &mut diag);
        reproject(method, o, &newer, &req, &p, sink, history).unwrap();
        let errors: Vec<u32> = diag.error.iter().map(|e| e.to_bits()).collect();
        (out, diag.source, errors)
    };
    let run = |tier: Simd| {
        set_simd_limit(tier);
        assert!(simd_tier() <= tier);
        let mut history = BidirHistory::new();
        let mut frames = Vec::new();
        for alpha in [0.5f32, 1.4] {
            frames.push(frame(Method::Ours, alpha, None));
            // The second call of the pair uses the pair state the first one left.
            for _ in 0..2 {
                frames.push(frame(Method::Ours, alpha, Some(&mut history)));
            }
        }
        // Unidirectional splatting from the newer frame: extrapolation only.
        frames.push(frame(Method::ForwardSplat, 1.4, None));
        frames
    };
    let baseline = run(Simd::Baseline);
    for tier in [Simd::Avx2, Simd::Avx512] {
        let wide = run(tier);
        for (n, (a, b)) in baseline.iter().zip(&wide).enumerate() {
            assert!(a == b, "{tier:?} (as {:?}), frame {n}", simd_tier());
        }
    }
    set_simd_limit(Simd::Avx512);
}

/// The NDC x of the pixel centres of a row of a `sw × sh` source.
fn row_ndc_x(sw: usize, sh: usize) -> Vec<f32> {
    (0..sw)
        .map(|i| crate::camera::ndc_of_pixel(i, 0, sw, sh)[0])
        .collect()
}

/// Depths at and beyond the edges of a source's range `[0, 1]`: signed zeros, just above 1, a
/// subnormal, negative, NaN and infinite, which the row tests mix into their rows.
const EDGE_DEPTHS: [f32; 11] = [
    -0.0,
    0.0,
    0.25,
    0.9,
    1.0,
    1.000_001,
    -0.5,
    1e-40,
    f32::NAN,
    f32::INFINITY,
    f32::NEG_INFINITY,
];

/// One of `v`, drawn by `r`.
fn pick(r: u64, v: &[f32]) -> f32 {
    v[(r % v.len() as u64) as usize]
}

/// A transfer of sparse small entries (±0, ±1, 0.5, −2) drawn by `rnd`: sums that are signed
/// zeros, divisors that are zero, points behind the camera.
fn sparse_transfer(rnd: &mut impl FnMut() -> u64) -> NdcTransfer {
    let entries = [0.0, -0.0, 1.0, -1.0, 0.5, -2.0];
    let mut t = NdcTransfer {
        m: crate::camera::M4([0.0; 16]),
        w_row: [0.0; 4],
    };
    for e in t.m.0.iter_mut().chain(t.w_row.iter_mut()) {
        *e = pick(rnd(), &entries);
    }
    t
}

/// The flow of still points (motion +0, every bit clear), which `flow_row` computes with one
/// transfer instead of two, is the general path's to the byte: flow, client depth and cell, and
/// the key depth wherever there is a cell; and so is `full_flow_row`'s, which skips their motion.
/// Rows mix still and moving runs (chunks of either kind and chunks with both), with ±0, NaN and
/// infinite depths and motions, a middle column and row at NDC +0, `w` of both signs, and besides
/// the cameras' transfer, transfers of sparse small entries whose sums are signed zeros and whose
/// divisors are zero.
#[test]
fn still_points_flow_as_the_general_path() {
    let (sw, sh) = (3 * 32 + 13, 61);
    let x = row_ndc_x(sw, sh);
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut rnd = move || xorshift(&mut seed);
    let from_inv = cam(0.0, sw, sh).view_proj().inverse().unwrap();
    let real = NdcTransfer::new(&from_inv, &cam(0.3, sw, sh).view_proj());
    let motions = [0.01, -0.02, 1e-3, 0.3, 0.0, -0.0, f32::NAN, f32::INFINITY];
    let bits = |p: &([f32; 2], f32, u32, f32)| {
        let kz = (p.2 != NO_SPLAT).then_some(p.3.to_bits());
        (p.0.map(f32::to_bits), p.1.to_bits(), p.2, kz)
    };
    let (mut splats, mut signed_zeros, mut landed) = (0, 0, 0);
    for case in 0..600 {
        let to_client = if case % 4 == 0 {
            real
        } else {
            sparse_transfer(&mut rnd)
        };
        let w = pick(rnd(), &[0.5, 0.0, -0.0, -0.4, 1.5, 1.0]);
        let j = [0, sh / 2, sh - 1][case % 3];
        let depth: Vec<f32> = (0..sw)
            .map(|_| match rnd() {
                r if r % 3 == 0 => pick(r >> 8, &EDGE_DEPTHS),
                r => (r >> 40) as f32 / (1u64 << 24) as f32,
            })
            .collect();
        // Runs of 1 to 64 still or moving points (all still in every fifth case).
        let mut motion = vec![0.0f32; 3 * sw];
        let mut i = 0;
        while i < sw {
            let r = rnd();
            let n = 1 + (r % 64) as usize;
            if (r >> 8) & 1 == 1 && case % 5 != 0 {
                for v in &mut motion[3 * i..3 * (i + n).min(sw)] {
                    *v = pick(rnd(), &motions);
                }
            }
            i += n;
        }
        let row = SrcRow { j, sw, sh };
        for m in [Some(&motion[..]), None] {
            let [fast, general] = pass1::flow_row_and_general(row, &x, &depth, m, &to_client, w);
            for (i, (a, b)) in fast.iter().zip(&general).enumerate() {
                assert_eq!(bits(a), bits(b), "case {case}, point {i}: {a:?} {b:?}");
                splats += usize::from(a.2 != NO_SPLAT);
                signed_zeros += usize::from(a.1 == 0.0 && a.2 != NO_SPLAT);
            }
            // The full scene flow of the pair (Algorithm 2) skips the motion of still runs too.
            let other = (sw + 2 * (case % 2), sh);
            let [fast, general] =
                pair::full_flow_row_and_general(row, &depth, m, &to_client, other);
            for (i, (a, b)) in fast.iter().zip(&general).enumerate() {
                let (a, b) = (a.map(f32::to_bits), b.map(f32::to_bits));
                assert_eq!(a, b, "case {case}, point {i}: full flow");
                landed += usize::from(a[3] != NO_SPLAT);
            }
        }
    }
    // The cases reach what they are meant to: points that splat, at client depth ±0 too, and
    // full flows that land in the other image.
    assert!(
        splats > 10_000 && signed_zeros > 100 && landed > 10_000,
        "{splats} {signed_zeros} {landed}"
    );
}

/// "Visible in main" (§3.5 rule 2), which the pair computes for every auxiliary point in row
/// stages (where the points land in main, then main's depth there), is the per-point test's
/// (`visible_in`) at every tier: for the point where it is and moved by its motion (+0 without
/// one), with ±0, NaN, infinite and out-of-range depths and motions, main depths with NaN, a row
/// width that is not a multiple of the vectors, and besides a real transfer between two cameras,
/// transfers of sparse small entries (points behind the camera, zero and non-finite divisors).
#[test]
fn visibility_in_main_is_the_per_point_test() {
    let (sw, sh) = (3 * 32 + 13, 61);
    let (mw, mh) = (2 * sw + 3, 2 * sh + 1);
    let x = row_ndc_x(sw, sh);
    let mut seed = 0x51f1_5e3d_2c4b_a987u64;
    let mut rnd = move || xorshift(&mut seed);
    let from_inv = cam(0.0, sw, sh).view_proj().inverse().unwrap();
    let real = NdcTransfer::new(&from_inv, &cam(0.3, mw, mh).view_proj());
    let motions = [0.01, -0.02, 0.3, 0.0, -0.0, f32::NAN, f32::NEG_INFINITY];
    let main_depth: Vec<f32> = (0..mw * mh)
        .map(|_| match rnd() {
            r if r % 50 == 0 => f32::NAN,
            r => (r >> 40) as f32 / (1u64 << 24) as f32,
        })
        .collect();
    let (mut seen, mut hidden) = (0, 0);
    for tier in [Simd::Baseline, Simd::Avx2, Simd::Avx512] {
        set_simd_limit(tier);
        for case in 0..300 {
            let t = if case % 3 != 2 {
                real
            } else {
                sparse_transfer(&mut rnd)
            };
            // Rows cycle apart from the transfers: each kind of transfer meets each row.
            let y = crate::camera::ndc_of_pixel(0, [0, sh / 2, sh - 1][case / 3 % 3], sw, sh)[1];
            let depth: Vec<f32> = (0..sw)
                .map(|_| match rnd() {
                    r if r % 4 == 0 => pick(r >> 8, &EDGE_DEPTHS),
                    r => (r >> 40) as f32 / (1u64 << 24) as f32,
                })
                .collect();
            let motion: Vec<f32> = (0..3 * sw)
                .map(|_| match rnd() {
                    r if r % 3 == 0 => pick(r >> 8, &motions),
                    _ => 0.0,
                })
                .collect();
            let eps_z = pick(rnd(), &[0.004, 0.0, 1.0]);
            for (m, moved) in [(Some(&motion[..]), true), (None, true), (None, false)] {
                let [rows, reference] = pair::visibility_row_and_reference(
                    &x,
                    y,
                    &depth,
                    m,
                    moved,
                    &t,
                    (mw, mh),
                    &main_depth,
                    eps_z,
                );
                assert_eq!(rows, reference, "{tier:?}, case {case}, moved {moved}");
                seen += rows.iter().filter(|&&v| v).count();
                hidden += rows.iter().filter(|&&v| !v).count();
            }
        }
    }
    set_simd_limit(Simd::Avx512);
    // Both answers occur often.
    assert!(seen > 10_000 && hidden > 10_000, "{seen} {hidden}");
}

/// The colour stage takes each match's colour from its texel and blends the row as vectors,
/// sending the pixels without a match or with shadow bits (own or the partner's) to a scalar
/// path: at every tier it must give the bytes and diagnostics of the full path
/// (`Resolve::second_chance`, rounded; the previous colour where there is no match), for rows
/// that mix every case in chunks with and without rare pixels, a width that is not a multiple of
/// the vectors or chunks, and weights `ω` and `α` that are ±0, negative, above 1, infinite or NaN.
#[test]
fn colour_row_equals_the_full_path() {
    use super::pair::{texels, PairCache};
    use super::select::NO_SOURCE;
    use crate::shadow::round_rgb4;
    let (sw, sh, cw) = (12, 6, 70);
    let n = sw * sh;
    // A draw in `0..k`, and `len` random bytes.
    let mut seed = 0x9E37_79B9_7F4A_7C15u64;
    let mut rng = move |k: u64| draw(&mut seed, k);
    fn bytes(rng: &mut impl FnMut(u64) -> u64, len: usize) -> Vec<u8> {
        (0..len).map(|_| rng(256) as u8).collect()
    }
    let colours: Vec<Vec<u8>> = (0..4).map(|_| bytes(&mut rng, 3 * n)).collect();
    let (s_min, s_max) = (bytes(&mut rng, 3 * n), bytes(&mut rng, 3 * n));
    let depth = vec![0.5f32; n];
    let p = Params::default();
    let camera = cam(0.0, sw, sh);
    // Per trial: how many output pixels in 256 have no source, how many source pixels in 256
    // carry shadow bits, `ω` of the older and the newer sources, and `α`.
    for (trial, (none_in, shadow_in, omega, alpha)) in [
        (0, 0, [0.5f32, 0.5], 0.5f32),
        (0, 16, [0.25, 0.75], 0.25),
        (64, 0, [-0.0, 0.0], 1.5),
        (8, 4, [1.5, -0.5], 1.5),
        (128, 128, [f32::NAN, f32::INFINITY], f32::NAN),
        (4, 64, [f32::NEG_INFINITY, 1e-30], 0.0),
    ]
    .into_iter()
    .enumerate()
    {
        // Source 2 has no shadow buffers.
        let bits: Vec<Vec<u32>> = (0..4)
            .map(|_| {
                (0..n)
                    .map(|_| {
                        let hit = rng(256) < shadow_in;
                        if hit {
                            1 + rng(u64::from(u32::MAX)) as u32
                        } else {
                            0
                        }
                    })
                    .collect()
            })
            .collect();
        let views: Vec<CameraView> = (0..4)
            .map(|k| CameraView {
                camera,
                color: &colours[k],
                depth: &depth,
                motion: None,
                shadow: (k != 2).then(|| ShadowView {
                    bits: &bits[k],
                    s_min: &s_min,
                    s_max: &s_max,
                }),
            })
            .collect();
        let roles = [Role::Older, Role::Newer];
        let sources: Vec<Src> = views
            .iter()
            .enumerate()
            .map(|(k, v)| {
                Src::new(
                    *v,
                    camera.projector("test").unwrap(),
                    None,
                    roles[k % 2],
                    k / 2,
                )
            })
            .collect();
        // The main pair blends (partners in the other frame or none); the auxiliary pair does not.
        let partners: Vec<Vec<u32>> = (0..2)
            .map(|_| {
                (0..n)
                    .map(|_| {
                        if rng(3) == 0 {
                            NO_SPLAT
                        } else {
                            rng(n as u64) as u32
                        }
                    })
                    .collect()
            })
            .collect();
        let mut texel: Vec<Vec<u64>> = vec![Vec::new(); 4];
        for (k, t) in texel.iter_mut().enumerate() {
            let blend = (k < 2).then(|| (&partners[k][..], &sources[k ^ 1]));
            texels(&sources[k], blend, t);
        }
        let pair = PairCache::default();
        let r = Resolve {
            params: &p,
            alpha,
            client_w: cw,
            client_h: 1,
            sources: &sources,
            bidirectional: true,
            eps_e: 1.0,
            eps_e_aux: 1.0,
            eps_z: 1.0,
            eps_z_aux: 1.0,
            iterations: 0,
            aux: Vec::new(),
            client_ndc: NdcTable::new(cw, 1),
            pair: &pair,
            palettes: (0..4)
                .map(|k| Palette {
                    color: &colours[k],
                    shadow: views[k].shadow,
                    role: roles[k % 2],
                    partner: if k < 2 { &partners[k] } else { &[] },
                    other: k ^ 1,
                    texel: &texel[k],
                    omega: omega[k % 2],
                })
                .collect(),
        };
        let mut picks = super::select::Picks {
            src: (0..cw)
                .map(|_| {
                    if rng(256) < none_in {
                        NO_SOURCE
                    } else {
                        rng(4) as u8
                    }
                })
                .collect(),
            p: (0..cw).map(|_| rng(n as u64) as u32).collect(),
            e: (0..cw).map(|_| rng(1000) as f32 * 1e-3).collect(),
            z: vec![0.0; cw],
            ..Default::default()
        };
        let previous = bytes(&mut rng, 3 * cw);
        // The full path, pixel by pixel.
        let mut want = (previous.clone(), vec![0u8; cw], vec![0u32; cw]);
        for i in 0..cw {
            let s = picks.src[i];
            if s == NO_SOURCE {
                (want.1[i], want.2[i]) = (Diagnostics::NONE, f32::NAN.to_bits());
                continue;
            }
            let (c, blended) = r.second_chance(usize::from(s), picks.p[i] as usize);
            want.0[3 * i..3 * i + 3].copy_from_slice(&round_rgb4(c)[..3]);
            (want.1[i], want.2[i]) = (r.code_of(usize::from(s), blended), picks.e[i].to_bits());
        }
        for tier in [Simd::Baseline, Simd::Avx2, Simd::Avx512] {
            set_simd_limit(tier);
            let mut out = previous.clone();
            let (mut codes, mut err) = (vec![0u8; cw], vec![0f32; cw]);
            r.colour_row(&mut picks, &mut out, Some((&mut codes, &mut err)));
            let err: Vec<u32> = err.iter().map(|e| e.to_bits()).collect();
            assert!(
                (&out, &codes, &err) == (&want.0, &want.1, &want.2),
                "trial {trial}, {tier:?}"
            );
            let mut plain = previous.clone();
            r.colour_row(&mut picks, &mut plain, None);
            assert_eq!(
                plain, want.0,
                "trial {trial}, {tier:?}, without diagnostics"
            );
        }
    }
    set_simd_limit(Simd::Avx512);
}

/// [`Resolve::aux_row`](super::Resolve) merges the auxiliary cameras in runs of client columns
/// that fall in the same flagged cells of every grid, and in test builds checks every pixel
/// against the merge pixel by pixel (`check_merge`). Grids of different sizes make runs that end
/// inside another grid's cell (a 37×29 camera beside a 131×71 one, finer than the 96×54 client,
/// so that some of its cells hold no client column), and a hole in the main camera's depth leaves
/// pixels without a main match; with the lazy and the eager search, with and without the older
/// frame.
#[test]
fn auxiliary_merge_in_runs_with_grids_of_different_sizes() {
    use crate::frame::CameraBuffers;
    use crate::synthetic::{head_pose, rig, SyntheticScene};
    let (w, h) = (96, 54);
    let scene = SyntheticScene::new(true);
    let frame = |t: f64| -> Vec<(Camera, CameraBuffers)> {
        let (eye, target) = head_pose(t);
        let (main, [left, right]) = rig(eye, target, w, h);
        let sized = |c: Camera, width, height| Camera { width, height, ..c };
        [main, sized(left, 37, 29), sized(right, 131, 71)]
            .into_iter()
            .map(|c| {
                let mut b = scene.render_server(&c, t, 0.1, 4);
                if c.width == w {
                    for row in b.depth.chunks_mut(w).skip(20).take(14) {
                        row[40..60].fill(f32::NAN);
                    }
                }
                (c, b)
            })
            .collect()
    };
    fn view(f: &[(Camera, CameraBuffers)], forward: bool) -> FrameView<'_> {
        FrameView {
            main: f[0].1.view(f[0].0, forward),
            aux: f[1..].iter().map(|(c, b)| b.view(*c, forward)).collect(),
        }
    }
    let (f0, f1) = (frame(0.0), frame(0.1));
    let (older, newer) = (view(&f0, true), view(&f1, false));
    // Pixels per auxiliary camera, inside the hole and outside it.
    let mut from = [[0usize; 2]; 2];
    for (alpha, pair) in [(0.35f32, true), (1.4, false)] {
        let req = off_path_request(alpha, w, h);
        let mut runs = Vec::new();
        for eager in [false, true] {
            EAGER_AUX.with(|x| x.set(eager));
            let p = Params::default();
            runs.push(with_sources(
                Method::Ours,
                pair.then_some(&older),
                &newer,
                &req,
                &p,
                None,
            ));
            EAGER_AUX.with(|x| x.set(false));
        }
        assert!(runs[0] == runs[1], "lazy and eager search, alpha {alpha}");
        for (k, &code) in runs[0].1.iter().enumerate() {
            let code = code & !Diagnostics::BLENDED;
            if code >= Diagnostics::AUX_BASE {
                let (i, j) = (k % w, k / w);
                let hole = (40..60).contains(&i) && (20..34).contains(&j);
                from[usize::from((code - Diagnostics::AUX_BASE) / 2)][usize::from(hole)] += 1;
            }
        }
    }
    assert!(from.iter().flatten().all(|&n| n > 0), "{from:?}");
}

/// A client alternates between frames with both main sources (interpolating) and frames with one
/// (extrapolating while the next pair is prepared): every source of either kind of frame must
/// find buffers of its own size in the pool, so that no frame reallocates (and page-faults) them.
#[test]
fn buffer_pool_fits_sources_across_interpolation_and_extrapolation() {
    let (main, aux) = (64 * 36, 32 * 18);
    // (pixels, auxiliary) of each source, in the order of `sources`.
    let interpolate = [
        (main, false),
        (main, false),
        (aux, true),
        (aux, true),
        (aux, true),
        (aux, true),
    ];
    let extrapolate = [(main, false), (aux, true), (aux, true)];
    let mut pool: Vec<Buffers> = Vec::new();
    for (round, frame) in [
        &interpolate[..],
        &extrapolate,
        &interpolate,
        &extrapolate,
        &interpolate,
    ]
    .into_iter()
    .enumerate()
    {
        let mut taken = Vec::new();
        for &(n, is_aux) in frame {
            let mut b = take_buffers(&mut pool, n, is_aux);
            if round > 0 {
                assert_eq!(
                    b.flow.len(),
                    n,
                    "round {round}: a source got another size's buffers"
                );
                assert_eq!(
                    b.invisible.len(),
                    if is_aux { n } else { 0 },
                    "round {round}"
                );
            }
            b.fit(n, usize::from(is_aux));
            taken.push(b);
        }
        // As `run` hands them back.
        pool.extend(taken.into_iter().rev());
    }
    assert_eq!(pool.len(), interpolate.len());
}

/// A `w × h` camera over a textured plane at depth 4 ([`plane`]) with every colour replaced by
/// `rgb`: the frames of the blending test, whose colours tell the frames apart.
fn plane_of_one_colour(c: &Camera, rgb: [u8; 3]) -> (Vec<u8>, Vec<f32>) {
    let (_, depth) = plane(c, 4.0);
    (rgb.repeat(c.width * c.height), depth)
}

/// Algorithm 2 blends the kept match with its correspondence in the other frame by α: the older
/// frame's colour weighs `1 − α` and the newer's `α`, whichever frame's match is kept (its own
/// colour weighs `ω`: `1 − α` for the older, `α` for the newer). The camera moves between the
/// frames (so the full scene flows of the two frames cancel only as a sum, not as a difference),
/// and each frame has one colour: every blended pixel is `(1 − α)·A + α·B`, exactly.
#[test]
fn blending_weighs_the_frames_by_alpha() {
    let (w, h) = (64, 48);
    let (c0, c1, ct) = (cam(0.0, w, h), cam(0.2, w, h), cam(0.05, w, h));
    let (a, b) = ([0u8, 100, 200], [200u8, 100, 0]);
    let (col0, dep0) = plane_of_one_colour(&c0, a);
    let (col1, dep1) = plane_of_one_colour(&c1, b);
    let (f0, f1) = (
        main_only(c0, &col0, &dep0, None),
        main_only(c1, &col1, &dep1, None),
    );
    // (α, the blend (1 − α)·A + α·B, by hand).
    for (alpha, want) in [(0.25f32, [50u8, 100, 150]), (0.75, [150, 100, 50])] {
        let req = Request { client: ct, alpha };
        let (out, source) =
            with_sources(Method::Ours, Some(&f0), &f1, &req, &Params::default(), None);
        let mut blended = 0;
        for (k, &code) in source.iter().enumerate() {
            let px = &out[3 * k..3 * k + 3];
            match code {
                c if c & Diagnostics::BLENDED != 0 => {
                    assert_eq!(px, want, "alpha {alpha}, pixel {k}, code {c}");
                    blended += 1;
                }
                Diagnostics::MAIN_OLDER => assert_eq!(px, a, "alpha {alpha}, pixel {k}"),
                Diagnostics::MAIN_NEWER => assert_eq!(px, b, "alpha {alpha}, pixel {k}"),
                c => panic!("alpha {alpha}, pixel {k}: code {c}"),
            }
        }
        // Every pixel but a column at the border, where the point leaves the other image (3024
        // of 3072 here).
        assert!(
            blended * 100 >= w * h * 97,
            "alpha {alpha}: {blended} blended"
        );
    }
}

/// A moving plane between the frames (eqs. 12, 13): the older frame's points move by `α` of
/// their forward motion and the newer frame's by `1 − α` of their backward motion. Each frame is
/// tested alone (the other frame's depth invalid, so that Algorithm 1 can keep only its
/// matches): the plane moves +0.5 NDC (16 px) per interval, so at α = 0.25 output pixel `i`
/// shows the older frame's pixel `i − 4` and the newer frame's pixel `i + 12`, and the
/// diagnostics name the frame.
#[test]
fn moving_object_is_interpolated_along_its_motion() {
    let (w, h) = (64, 48);
    let c = cam(0.0, w, h);
    let (color, depth) = plane(&c, 2.0);
    let invalid = vec![f32::NAN; w * h];
    let forward: Vec<f32> = (0..w * h).flat_map(|_| [0.5f32, 0.0, 0.0]).collect();
    let backward: Vec<f32> = forward.iter().map(|m| -m).collect();
    let view = |depth, motion| main_only(c, &color, depth, Some(motion));
    let req = Request {
        client: c,
        alpha: 0.25,
    };
    // (older, newer, the source pixel column's offset, the code).
    let cases = [
        (
            view(&depth, &forward),
            view(&invalid, &backward),
            -4,
            Diagnostics::MAIN_OLDER,
        ),
        (
            view(&invalid, &forward),
            view(&depth, &backward),
            12,
            Diagnostics::MAIN_NEWER,
        ),
    ];
    for (older, newer, d, code) in cases {
        let (out, source) = with_sources(
            Method::Ours,
            Some(&older),
            &newer,
            &req,
            &Params::default(),
            None,
        );
        let mut total = 0;
        for j in 2..h - 2 {
            for i in 16..w - 16 {
                let k = j * w + i;
                let q = 3 * (k as i64 + d) as usize;
                assert_eq!(source[k], code, "offset {d}, pixel ({i}, {j})");
                assert_eq!(
                    out[3 * k..3 * k + 3],
                    color[q..q + 3],
                    "offset {d}, pixel ({i}, {j})"
                );
                total += 1;
            }
        }
        assert_eq!(total, (h - 4) * (w - 32));
    }
}

/// The splat keeps the nearest point of a cell (a key of reversed depth, nearest smallest): a
/// strip 1 m away in front of a plane 4 m away, seen from 0.3 m to the side, covers background
/// points that land in the same cells; where the strip is in the client's view (a pixel's ray
/// hits it, one pixel off its edges), the output is the strip's colour, which the background
/// never has.
#[test]
fn nearer_surface_wins_the_splat() {
    let (w, h) = (64, 48);
    let c = cam(0.0, w, h);
    let (mut color, mut depth) = plane(&c, 4.0);
    let (_, near) = plane(&c, 1.0);
    let red = [255u8, 0, 0];
    let cols = 20..30;
    for j in 0..h {
        for i in cols.clone() {
            depth[j * w + i] = near[j * w + i];
            color[3 * (j * w + i)..3 * (j * w + i) + 3].copy_from_slice(&red);
        }
    }
    let f = main_only(c, &color, &depth, None);
    let client = cam(0.3, w, h);
    // World x at 1 m of NDC x: tan(30°)·aspect.
    let half = (30f64.to_radians()).tan() * w as f64 / h as f64;
    let (lo, hi) = (
        (2.0 * cols.start as f64 / w as f64 - 1.0) * half,
        (2.0 * cols.end as f64 / w as f64 - 1.0) * half,
    );
    let px = 2.0 * half / w as f64;
    for method in [Method::Ours] {
        let req = Request { client, alpha: 1.0 };
        let (out, _) = with_sources(method, None, &f, &req, &Params::default(), None);
        let mut strip = 0;
        for i in 0..w {
            let ndc = (2 * i + 1) as f64 / w as f64 - 1.0;
            let x = 0.3 + ndc * half;
            if x < lo + px || x > hi - px {
                continue;
            }
            for j in 0..h {
                let k = j * w + i;
                assert_eq!(out[3 * k..3 * k + 3], red, "{method}: pixel ({i}, {j})");
                strip += 1;
            }
        }
        // Eight columns of the ten, the others within a pixel of the strip's edges.
        assert!(strip >= 8 * h, "{method}: {strip} strip pixels");
    }
}

/// A [`Resolve`] over `sources` for the selection tests: thresholds `ε_e = 1`, `ε_z = 0.1`.
fn selection<'a>(
    sources: &'a [Src<'a>],
    p: &'a Params,
    pair: &'a pair::PairCache,
    bidirectional: bool,
    cw: usize,
) -> Resolve<'a> {
    Resolve {
        params: p,
        alpha: 0.5,
        client_w: cw,
        client_h: 1,
        sources,
        bidirectional,
        eps_e: 1.0,
        eps_e_aux: 1.0,
        eps_z: 0.1,
        eps_z_aux: 0.1,
        iterations: 0,
        aux: Vec::new(),
        client_ndc: NdcTable::new(cw, 1),
        pair,
        palettes: Vec::new(),
    }
}

/// Algorithm 1, in the row form ([`Resolve::choose_row`]) and per match ([`Resolve::choose`]),
/// on cases worked by hand (`ε_e = 1`, `ε_z = 0.1`, depths reversed: larger is nearer): both
/// correspond at similar depths (`2·|Δz| < ε_z`): the smaller error; at other depths: the nearer,
/// whatever the errors; one corresponds (`e < ε_e`, strictly): that one; none: no source. Also
/// which frame's visibility in main the choice carries (§3.5 rule 2: a point visible in either
/// main frame; the other frame's counts only for the same point, at a similar depth).
#[test]
fn algorithm_1_keeps_the_better_match() {
    use super::select::{Picks, NO_SOURCE};
    const INF: f32 = f32::INFINITY;
    // (e_older, z_older, e_newer, z_newer, the source kept: 0 older, 1 newer, None).
    let cases: [(f32, f32, f32, f32, Option<u8>); 11] = [
        (0.2, 0.5, 0.3, 0.5, Some(0)),
        (0.3, 0.5, 0.2, 0.5, Some(1)),
        // 2·0.3 ≥ ε_z: the nearer, the newer, with the larger error; and the other way.
        (0.2, 0.3, 0.3, 0.6, Some(1)),
        (0.3, 0.6, 0.2, 0.3, Some(0)),
        // 2·0.07 ≥ ε_z although 0.07 < ε_z: the nearer (older), not the smaller error.
        (0.3, 0.57, 0.2, 0.5, Some(0)),
        // 2·0.04 < ε_z: the smaller error (newer), not the nearer.
        (0.3, 0.54, 0.2, 0.5, Some(1)),
        (0.2, 0.5, INF, f32::NAN, Some(0)),
        (INF, f32::NAN, 0.9, 0.2, Some(1)),
        // An error at ε_e does not correspond; the nearer one that does is kept anyway.
        (1.0, 0.9, 0.5, 0.1, Some(1)),
        (1.0, 0.5, INF, f32::NAN, None),
        (1.5, 0.5, 2.0, 0.5, None),
    ];
    let n = cases.len();
    let (p, pair) = (Params::default(), pair::PairCache::default());
    let mut sides = [super::search::SearchRow::default(), Default::default()];
    for (s, side) in sides.iter_mut().enumerate() {
        side.e = cases.iter().map(|c| [c.0, c.2][s]).collect();
        side.z = cases.iter().map(|c| [c.1, c.3][s]).collect();
        side.p = (0..n as u32).map(|i| 100 * s as u32 + i).collect();
    }
    let r = selection(&[], &p, &pair, true, n);
    let mut picks = Picks::default();
    r.choose_row(&sides, &mut picks);
    for (i, &(ef, zf, eb, zb, want)) in cases.iter().enumerate() {
        let got = (picks.src[i] != NO_SOURCE).then_some(picks.src[i]);
        assert_eq!(got, want, "choose_row, case {i}");
        if let Some(s) = want {
            let (e, z) = if s == 0 { (ef, zf) } else { (eb, zb) };
            let kept = (picks.p[i], picks.e[i], picks.z[i]);
            assert_eq!(kept, (100 * u32::from(s) + i as u32, e, z), "case {i}");
        }
        // Per match, for camera 1 (sources 2 and 3), with every visibility.
        for (vf, vb) in [(false, false), (true, false), (false, true)] {
            let m = |e: f32, z: f32, vis| (e.is_finite()).then_some(Match { p: 7, e, z, vis });
            let c = r.choose(1, m(ef, zf, vf), m(eb, zb, vb), 1.0, 0.1);
            assert_eq!(
                c.map(|c| c.src),
                want.map(|s| 2 + usize::from(s)),
                "case {i}"
            );
            if let (Some(c), Some(s)) = (c, want) {
                let (own, other) = if s == 0 { (vf, vb) } else { (vb, vf) };
                let same_point = ef < 1.0 && eb < 1.0 && 2.0 * (zf - zb).abs() < 0.1;
                assert_eq!(c.visible_in_main, own || (same_point && other), "case {i}");
            }
        }
    }
    // One frame (unidirectional): its match where `e < ε_e`.
    let r = selection(&[], &p, &pair, false, 3);
    let mut side = super::search::SearchRow::default();
    (side.e, side.z, side.p) = (
        vec![0.99, 1.0, INF],
        vec![0.5, 0.5, f32::NAN],
        vec![4, 5, 6],
    );
    r.choose_row(std::slice::from_ref(&side), &mut picks);
    assert_eq!(picks.src[..3], [0, NO_SOURCE, NO_SOURCE]);
    let m = Match {
        p: 4,
        e: 0.99,
        z: 0.5,
        vis: false,
    };
    assert_eq!(r.choose(1, Some(m), None, 1.0, 0.1).map(|c| c.src), Some(1));
    assert!(r
        .choose(1, Some(Match { e: 1.0, ..m }), None, 1.0, 0.1)
        .is_none());
}

/// The diagnostic code of a match names its camera and frame ([`Diagnostics`]): main older 1,
/// main newer 2, auxiliary camera `i` older `3 + 2i` and newer `4 + 2i`, with the blend flag.
#[test]
fn diagnostic_codes_name_the_camera_and_frame() {
    let c = cam(0.0, 4, 3);
    let (color, depth) = (vec![0u8; 36], vec![0.5f32; 12]);
    let view = CameraView {
        camera: c,
        color: &color,
        depth: &depth,
        motion: None,
        shadow: None,
    };
    let sources: Vec<Src> = (0..6)
        .map(|k| {
            let role = [Role::Older, Role::Newer][k % 2];
            Src::new(view, c.projector("test").unwrap(), None, role, k / 2)
        })
        .collect();
    let (p, pair) = (Params::default(), pair::PairCache::default());
    let r = selection(&sources, &p, &pair, true, 1);
    for (k, want) in [1u8, 2, 3, 4, 5, 6].into_iter().enumerate() {
        assert_eq!(r.code_of(k, false), want, "source {k}");
        assert_eq!(r.code_of(k, true), want | 0x80, "source {k}, blended");
    }
}

/// Which camera of the server frame sees the plane in [`errors_of_a_plane_moved_by`].
#[derive(Debug, Clone, Copy, PartialEq)]
enum Seen {
    /// The main camera.
    ByMain,
    /// An auxiliary camera of the main camera's pose and size, while the main camera looks the
    /// other way (its points lie behind the client and never splat): every match is the
    /// auxiliary camera's (§3.5 rule 1).
    ByAux,
}

/// The errors of eq. 7 where a server camera (60° vertical field, square pixels, main or
/// auxiliary as `seen`) sees a fronto-parallel plane 3 m away and the client is that camera
/// moved sideways and up so that the plane moves by `(ox, oy)` pixels in the image (less than
/// half a pixel, so every output pixel finds the source pixel of the same index): per output
/// pixel, its error, or `None` without a match. At 3 m a pixel is `2·3·tan 30° / h` metres on
/// both axes. Every match must come from the camera that sees the plane.
fn errors_of_a_plane_moved_by(
    (w, h): (usize, usize),
    [ox, oy]: [f64; 2],
    params: &Params,
    seen: Seen,
) -> Vec<Option<f32>> {
    let d = 3.0;
    let looking = |x: f64, y: f64, dz: f64| {
        Camera::new(
            Mat4::look_at([x, y, 0.0], [x, y, dz], [0.0, 1.0, 0.0]),
            Mat4::perspective(60.0, w as f64 / h as f64, 0.1, 100.0),
            w,
            h,
            "test",
        )
        .unwrap()
    };
    let server = looking(0.0, 0.0, -1.0);
    let (color, depth) = plane(&server, d);
    let plane_view = CameraView {
        camera: server,
        color: &color,
        depth: &depth,
        motion: None,
        shadow: None,
    };
    let away = vec![0.5f32; w * h];
    let f = match seen {
        Seen::ByMain => FrameView {
            main: plane_view,
            aux: vec![],
        },
        Seen::ByAux => FrameView {
            main: CameraView {
                camera: looking(0.0, 0.0, 1.0),
                depth: &away,
                ..plane_view
            },
            aux: vec![plane_view],
        },
    };
    let metres = 2.0 * d * 30f64.to_radians().tan() / h as f64;
    let req = Request {
        client: looking(ox * metres, oy * metres, -1.0),
        alpha: 1.0,
    };
    let mut out = vec![0u8; w * h * 3];
    let mut diag = Diagnostics::new(w * h);
    let o = Output::with_diagnostics(&mut out, &mut diag);
    reproject(Method::Ours, None, &f, &req, params, o, None).unwrap();
    let code = match seen {
        Seen::ByMain => Diagnostics::MAIN_NEWER,
        Seen::ByAux => Diagnostics::AUX_BASE + 1,
    };
    let sources = diag.source.iter();
    sources
        .zip(&diag.error)
        .map(|(&s, &e)| {
            assert!(s == code || s == Diagnostics::NONE, "{seen:?}: source {s}");
            (s != Diagnostics::NONE).then_some(e)
        })
        .collect()
}

/// The error of eq. 7 is aspect-scaled NDC, in units where 2 is the image's short side: a pixel
/// counts `2 / min(W, H)` on both axes (REFERENCE.md §2.5). A client that moves a plane by 0.45
/// pixels across and 0.15 down (worked from the geometry, see [`errors_of_a_plane_moved_by`])
/// gives every pixel the error `2·√(0.45² + 0.15²) / 32 = 0.029646` on 128×32 and 32×128 images,
/// through the main camera and through an auxiliary camera of the same size, within 6e-7 (twice
/// the 2.8e-7 the kernel's f32 arithmetic is off here). With the x and y factors swapped it would
/// be 0.0381 on the first (x counted in pixels of the long side, y in four times its pixels) and
/// 0.113 on the second (over `ε_e`: no match).
#[test]
fn matching_error_counts_pixels_of_either_axis_alike() {
    let want = 2.0 * (0.45f64.powi(2) + 0.15f64.powi(2)).sqrt() / 32.0;
    for seen in [Seen::ByMain, Seen::ByAux] {
        for size in [(128, 32), (32, 128)] {
            let p = Params::default();
            let errors = errors_of_a_plane_moved_by(size, [0.45, 0.15], &p, seen);
            for (k, e) in errors.iter().enumerate() {
                let e = e.unwrap_or_else(|| panic!("{seen:?}, {size:?}: pixel {k}: no match"));
                assert!(
                    (f64::from(e) - want).abs() < 6e-7,
                    "{seen:?}, {size:?}: pixel {k}: error {e}, not {want}"
                );
            }
        }
    }
}

/// `ε_e` keeps its size in pixels on every image (REFERENCE.md §2.5; it is given in units where 2
/// is the short side of a 1440-pixel image, and scaled by `1440 / min(W, H)`), so the main
/// camera's `ε_e = 0.4 / 720` is 0.4 pixels of the short side, and so is an auxiliary camera's
/// `aux_threshold_scale · ε_e` for `ε_e = 0.1 / 720` (on an auxiliary image of the client's
/// size): on 128×32 and 32×128 images a plane moved by 0.3 pixels (0.24 across, 0.18 down)
/// matches at every pixel, and one moved by 0.5 pixels (0.3 across, 0.4 down) at none. Scaled by
/// the long side instead, the threshold would be 0.1 pixels and the first would not match.
#[test]
fn error_threshold_is_the_same_number_of_pixels_on_every_image_shape() {
    for (seen, eps_e) in [(Seen::ByMain, 0.4 / 720.0), (Seen::ByAux, 0.1 / 720.0)] {
        let params = Params {
            eps_e,
            ..Params::default()
        };
        for size in [(128, 32), (32, 128)] {
            let near = errors_of_a_plane_moved_by(size, [0.24, 0.18], &params, seen);
            let unmatched = near.iter().filter(|e| e.is_none()).count();
            assert_eq!(unmatched, 0, "{seen:?}, {size:?}: 0.3 px, under 0.4 px");
            let far = errors_of_a_plane_moved_by(size, [0.3, 0.4], &params, seen);
            let matched = far.iter().filter(|e| e.is_some()).count();
            assert_eq!(matched, 0, "{seen:?}, {size:?}: 0.5 px, over 0.4 px");
        }
    }
}

/// "Visible in main" (§3.5 rule 2) on points worked by hand, in the row stages and the per-point
/// test alike: the transfer is the identity (an auxiliary point lands on the main pixel of its own
/// index, at its own depth 0.5), `ε_z = 0.004` (a reversed-depth difference counts twice). Depths
/// are reversed (larger is nearer): where main saw something nearer than the point by more than
/// `ε_z / 2` (0.6, 0.5025) the point is hidden; where main saw it (0.5), something within
/// `ε_z / 2` (0.5015) or something farther (0.3: main's depth there does not hide the point) it
/// is visible. A flipped comparison would hide the point in front of the far surface and show the
/// points behind the near ones.
#[test]
fn visible_in_main_hides_points_behind_what_main_saw_nearer() {
    let mut identity = crate::camera::M4([0.0; 16]);
    for i in 0..4 {
        identity.0[5 * i] = 1.0;
    }
    let t = NdcTransfer {
        m: identity,
        w_row: [0.0, 0.0, 0.0, 1.0],
    };
    let (sw, sh) = (5, 3);
    // (main's depth at the point's pixel, visible).
    let cases = [
        (0.6, false),
        (0.5025, false),
        (0.5, true),
        (0.5015, true),
        (0.3, true),
    ];
    let x = row_ndc_x(sw, sh);
    let depth = vec![0.5f32; sw];
    let want: Vec<bool> = cases.iter().map(|c| c.1).collect();
    for j in 0..sh {
        // Main's depths on row j (the points' row) are the cases; the other rows see nothing
        // nearer than the points.
        let mut main_depth = vec![0.1f32; sw * sh];
        for (i, c) in cases.iter().enumerate() {
            main_depth[j * sw + i] = c.0;
        }
        let y = crate::camera::ndc_of_pixel(0, j, sw, sh)[1];
        for tier in [Simd::Baseline, Simd::Avx2, Simd::Avx512] {
            set_simd_limit(tier);
            for moved in [false, true] {
                let [rows, reference] = pair::visibility_row_and_reference(
                    &x,
                    y,
                    &depth,
                    None,
                    moved,
                    &t,
                    (sw, sh),
                    &main_depth,
                    0.004,
                );
                assert_eq!(rows, want, "{tier:?}, row {j}, moved {moved}: row stages");
                assert_eq!(
                    reference, want,
                    "{tier:?}, row {j}, moved {moved}: per point"
                );
            }
        }
    }
    set_simd_limit(Simd::Avx512);
}
