//! `timewarp`: planar reprojection of one server frame at its average depth (DESIGN.md "Methods";
//! the baseline of seeds/000 §4.2).
//!
//! The whole main image is treated as a single plane facing the server camera: the plane passes
//! through `Q = P⁻¹(0, 0, Z̄)`, the world point on the server camera's optical axis at the mean
//! reversed depth `Z̄` of the valid main pixels, and its normal `N` is the server camera's viewing
//! direction in world space. Every output pixel casts the client camera's ray through its centre,
//! intersects the plane, projects the hit into the server main camera and samples it (nearest).
//! The client pose is thus honoured for rotation exactly and for translation only at depth `Z̄`.
//!
//! Sampling order for the hit point `H`:
//! 1. inside the main image: main, nearest pixel;
//! 2. otherwise, when the frame has auxiliary cameras and [`Params::use_aux`]: auxiliary camera 0,
//!    nearest pixel, if `H` projects inside it (and in front of it);
//! 3. otherwise main with the pixel clamped to the image border.
//!
//! Where we differ from the reference implementation on purpose (REFERENCE.md §3 mode 4, §8.4):
//! - the plane is well formed: `Q` is `P⁻¹(0,0,Z̄)` *with* the perspective division and `N` is the
//!   camera's view direction, so the plane no longer depends on where the world origin is;
//! - `Z̄` averages only valid depths (finite, in `[0,1]`), in a fixed summation order (per row in
//!   `f64`, then rows in order), so the result is bit-identical for any thread count;
//! - auxiliary camera 0 is used only when the hit lies outside the main image, and only where it
//!   actually sees the hit (the reference samples it clamped wherever main misses);
//! - rays that hit the plane behind the client's near plane are not written, like rays parallel to
//!   the plane (`|ray·N| < 1e-6`);
//! - a sampled pixel whose depth (NaN, infinite or outside `[0,1]`) or motion (non-finite) is
//!   invalid does not colour the output: the pixel keeps the previous client frame (DESIGN.md:
//!   invalid pixels never reach the output). If no main pixel is valid there is no plane and nothing is written.
//!
//! No shadows and no object motion are applied: the method warps one image as it is.

use rayon::prelude::*;

use crate::camera::{pixel_of_ndc, Camera, Projector};
use crate::error::{ReprojError, Result};
use crate::frame::{CameraView, FrameView};
use crate::params::{Params, TILE};
use crate::request::{par_row_blocks, Diagnostics, Output, Request};

/// Rays more parallel to the plane than this (`|ray·N|`, unit vectors) are not written.
const PARALLEL_EPS: f32 = 1e-6;

/// A depth value that marks its pixel valid: finite and inside the reversed-depth range.
#[inline(always)]
fn valid_depth(z: f32) -> bool {
    z.is_finite() && (0.0..=1.0).contains(&z)
}

/// The warp plane in world space: a point on it and its unit normal.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Plane {
    q: [f32; 3],
    n: [f32; 3],
}

/// Runs `timewarp` from `frame` (its main camera, and its auxiliary camera 0 where main does not
/// see the hit) to the client camera of `request`. `α` is not used: the frame is shown as it is.
///
/// Every output pixel whose ray meets the plane in front of the client and whose sampled source
/// pixel is valid is written; the others keep the previous client frame in `out.image`. `out.diag`,
/// when given, receives [`Diagnostics::MAIN_NEWER`] for main samples ("the current frame"),
/// `AUX_BASE + 1` for auxiliary samples, [`Diagnostics::NONE`] elsewhere; the error is always NaN.
///
/// # Errors
/// [`ReprojError::SingularMatrix`] when a camera of `frame` or the client camera cannot be
/// inverted; [`ReprojError::BufferSize`] when a buffer does not match its camera (also checked by
/// [`crate::reproject()`]). Nothing is written on error.
pub fn run(frame: &FrameView, request: &Request, params: &Params, out: Output) -> Result<()> {
    frame.validate("frame")?;
    out.check(request.client.width, request.client.height)?;
    let main = frame.main;
    let server = main.camera.projector("timewarp frame main camera")?;
    let client = request.client.projector("client camera")?;
    let aux = match frame.aux.first() {
        Some(a) if params.use_aux => {
            Some((*a, a.camera.projector("timewarp frame aux[0] camera")?))
        }
        _ => None,
    };
    let plane = match mean_depth(main.depth, main.camera.width) {
        Some(zbar) => warp_plane(&main.camera, zbar)?,
        None => None,
    };
    let Some(plane) = plane else {
        // No valid depth: nothing can be warped, every pixel keeps the previous frame.
        if let Some(d) = out.diag {
            d.source.fill(Diagnostics::NONE);
            d.error.fill(f32::NAN);
        }
        return Ok(());
    };

    let warp = Warp {
        client,
        server,
        main,
        aux,
        plane,
    };
    let cw = request.client.width;
    par_row_blocks(out, cw, |j0, o, d| warp.warp_rows(j0, o, d));
    Ok(())
}

/// Mean reversed depth `Z̄` over the valid pixels of a `width`-wide depth buffer, or `None` when
/// none is valid.
///
/// Each row is summed in `f64` in pixel order and the row sums are added in row order, so the
/// result does not depend on how rayon splits the work (a parallel `f32` reduction, as the
/// reference's atomic float sum, would change with the thread count).
fn mean_depth(depth: &[f32], width: usize) -> Option<f64> {
    let rows: Vec<(f64, u64)> = depth
        .par_chunks(width.max(1))
        .map(|row| {
            row.iter()
                .filter(|z| valid_depth(**z))
                .fold((0.0f64, 0u64), |(s, n), &z| (s + f64::from(z), n + 1))
        })
        .collect();
    let (sum, count) = rows
        .iter()
        .fold((0.0f64, 0u64), |(s, n), &(rs, rn)| (s + rs, n + rn));
    (count > 0).then(|| sum / count as f64)
}

/// The plane through `Q = P⁻¹(0, 0, Z̄)` (with the perspective division) whose normal is the
/// camera's viewing direction `−z` of its own frame, in world space. Computed in `f64`.
///
/// Returns `Ok(None)` when the plane is degenerate (non-finite point or zero direction), which
/// only malformed matrices produce.
///
/// # Errors
/// [`ReprojError::SingularMatrix`] when `P` or the view matrix cannot be inverted.
fn warp_plane(camera: &Camera, zbar: f64) -> Result<Option<Plane>> {
    let singular = || ReprojError::SingularMatrix {
        what: "timewarp frame main camera".into(),
    };
    let inv_vp = camera.view_proj().inverse().ok_or_else(singular)?;
    let inv_view = camera.view.inverse().ok_or_else(singular)?;
    let h = inv_vp.mul_vec([0.0, 0.0, zbar, 1.0]);
    let q = [h[0] / h[3], h[1] / h[3], h[2] / h[3]];
    // The camera looks along its own −z; as a direction (w = 0) it ignores the translation.
    let f = inv_view.mul_vec([0.0, 0.0, -1.0, 0.0]);
    let len = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
    if !(q.iter().all(|v| v.is_finite()) && len.is_finite() && len > 0.0) {
        return Ok(None);
    }
    Ok(Some(Plane {
        q: q.map(|v| v as f32),
        n: [f[0] / len, f[1] / len, f[2] / len].map(|v| v as f32),
    }))
}

/// The pixel of a `w × h` image nearest to NDC `(x, y)` with the coordinates clamped to the
/// border; `None` only for NaN or infinite input.
#[inline(always)]
fn clamped_pixel(x: f32, y: f32, w: usize, h: usize) -> Option<(usize, usize)> {
    if !(x.is_finite() && y.is_finite()) {
        return None;
    }
    let fx = ((x + 1.0) * 0.5 * w as f32)
        .floor()
        .clamp(0.0, (w - 1) as f32);
    let fy = ((1.0 - y) * 0.5 * h as f32)
        .floor()
        .clamp(0.0, (h - 1) as f32);
    Some((fx as usize, fy as usize))
}

#[inline(always)]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Read-only context of the per-pixel warp.
struct Warp<'a> {
    client: Projector,
    server: Projector,
    main: CameraView<'a>,
    aux: Option<(CameraView<'a>, Projector)>,
    plane: Plane,
}

impl Warp<'_> {
    /// Warps the output rows starting at `j0` (a block of at most [`TILE`] rows), in 16×16 tiles.
    fn warp_rows(&self, j0: usize, out: &mut [u8], mut diag: Option<(&mut [u8], &mut [f32])>) {
        let cw = self.client.width;
        let rows = out.len() / (3 * cw);
        for i0 in (0..cw).step_by(TILE) {
            for r in 0..rows {
                for i in i0..(i0 + TILE).min(cw) {
                    let local = r * cw + i;
                    let hit = self.warp_pixel(i, j0 + r);
                    if let Some((_, rgb)) = hit {
                        out[3 * local..3 * local + 3].copy_from_slice(&rgb);
                    }
                    if let Some((s, e)) = diag.as_mut() {
                        s[local] = hit.map_or(Diagnostics::NONE, |h| h.0);
                        e[local] = f32::NAN;
                    }
                }
            }
        }
    }

    /// The ray of output pixel `(i, j)` against the plane, then the sample: `(diagnostic code,
    /// colour)`, or `None` when the pixel is not written.
    #[inline]
    fn warp_pixel(&self, i: usize, j: usize) -> Option<(u8, [u8; 3])> {
        let [x, y] = self.client.ndc_of_pixel(i, j);
        // The ray runs from the near plane (Z = 1) to the far plane (Z = 0) of the client camera;
        // this needs no camera centre, so it holds for orthographic clients too.
        let o = self.client.unproject([x, y, 1.0]);
        let f = self.client.unproject([x, y, 0.0]);
        let d = [f[0] - o[0], f[1] - o[1], f[2] - o[2]];
        let len = dot(d, d).sqrt();
        let d = [d[0] / len, d[1] / len, d[2] / len];
        let n = self.plane.n;
        let dn = dot(d, n);
        // NaN (degenerate ray) fails this comparison too.
        if !(dn.abs() >= PARALLEL_EPS) {
            return None;
        }
        let q = self.plane.q;
        let s = dot([q[0] - o[0], q[1] - o[1], q[2] - o[2]], n) / dn;
        // Behind the near plane: the client would clip it.
        if !(s >= 0.0 && s.is_finite()) {
            return None;
        }
        let hit = [o[0] + s * d[0], o[1] + s * d[1], o[2] + s * d[2]];

        let h = self.server.vp.apply(hit);
        // Every point of the plane lies in front of the server camera (it faces the camera along
        // its own axis), so `w ≤ 0` means a degenerate matrix; do not guess.
        if !(h[3] > 0.0) {
            return None;
        }
        let (sx, sy) = (h[0] / h[3], h[1] / h[3]);
        let (mw, mh) = (self.server.width, self.server.height);
        if let Some((pi, pj)) = pixel_of_ndc(sx, sy, mw, mh) {
            return sample(&self.main, pj * mw + pi).map(|c| (Diagnostics::MAIN_NEWER, c));
        }
        if let Some((av, ap)) = &self.aux {
            let ha = ap.vp.apply(hit);
            if ha[3] > 0.0 {
                if let Some((ai, aj)) =
                    pixel_of_ndc(ha[0] / ha[3], ha[1] / ha[3], ap.width, ap.height)
                {
                    return sample(av, aj * ap.width + ai).map(|c| (Diagnostics::AUX_BASE + 1, c));
                }
            }
        }
        let (pi, pj) = clamped_pixel(sx, sy, mw, mh)?;
        sample(&self.main, pj * mw + pi).map(|c| (Diagnostics::MAIN_NEWER, c))
    }
}

/// The colour of pixel `idx` of `view`, or `None` when its depth or motion marks it invalid
/// (timewarp does not use the motion, but DESIGN.md makes such a pixel invalid for every method).
#[inline(always)]
fn sample(view: &CameraView, idx: usize) -> Option<[u8; 3]> {
    let motion_ok = view.motion_at(idx).iter().all(|v| v.is_finite());
    (valid_depth(view.depth[idx]) && motion_ok).then(|| {
        [
            view.color[3 * idx],
            view.color[3 * idx + 1],
            view.color[3 * idx + 2],
        ]
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Mat4;

    const W: usize = 32;
    const H: usize = 24;

    fn camera_at(eye: [f64; 3], target: [f64; 3], fov: f64, w: usize, h: usize) -> Camera {
        Camera::new(
            Mat4::look_at(eye, target, [0.0, 1.0, 0.0]),
            Mat4::perspective(fov, w as f64 / h as f64, 0.1, 100.0),
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

    /// A texture that encodes the pixel: r = 7i, g = 10j, b = 40.
    fn coded_color(w: usize, h: usize) -> Vec<u8> {
        let mut c = Vec::with_capacity(w * h * 3);
        for j in 0..h {
            for i in 0..w {
                c.extend_from_slice(&[(7 * i) as u8, (10 * j) as u8, 40]);
            }
        }
        c
    }

    fn view<'a>(camera: Camera, color: &'a [u8], depth: &'a [f32]) -> CameraView<'a> {
        CameraView {
            camera,
            color,
            depth,
            motion: None,
            shadow: None,
        }
    }

    fn run_tw(frame: &FrameView, client: Camera, params: &Params) -> (Vec<u8>, Diagnostics) {
        let n = client.width * client.height;
        let mut out = vec![3u8; n * 3];
        let mut diag = Diagnostics::new(n);
        let request = Request { client, alpha: 0.5 };
        run(
            frame,
            &request,
            params,
            Output::with_diagnostics(&mut out, &mut diag),
        )
        .unwrap();
        (out, diag)
    }

    #[test]
    fn timewarp_identity_reproduces_image() {
        let cam = camera_at([1.0, 0.5, 2.0], [0.0, 0.0, -3.0], 60.0, W, H);
        let color = coded_color(W, H);
        // Uneven depth: the plane sits at the mean, and the identity warp must not care.
        let depth: Vec<f32> = (0..W * H).map(|k| z_of(3.0 + (k % 7) as f64)).collect();
        let frame = FrameView {
            main: view(cam, &color, &depth),
            aux: vec![],
        };
        let (out, diag) = run_tw(&frame, cam, &Params::default());
        assert_eq!(out, color);
        assert!(diag.source.iter().all(|&s| s == Diagnostics::MAIN_NEWER));
        assert!(diag.error.iter().all(|e| e.is_nan()));
    }

    #[test]
    fn timewarp_translation_matches_analytic_shift() {
        let dist = 5.0;
        let server = camera_at([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 60.0, W, H);
        let color = coded_color(W, H);
        let depth = vec![z_of(dist); W * H];
        let frame = FrameView {
            main: view(server, &color, &depth),
            aux: vec![],
        };
        // Moving the client right by tx shifts the plane left by tx·f_x/d in NDC: the client pixel
        // i sees server pixel i + shift.
        let shift_px = 2.3;
        let fx = server.proj.0[0][0];
        let tx = shift_px * (2.0 / W as f64) * dist / fx;
        let client = camera_at([tx, 0.0, 0.0], [tx, 0.0, -1.0], 60.0, W, H);
        let (out, diag) = run_tw(&frame, client, &Params::default());
        for j in 0..H {
            for i in 0..W {
                let k = j * W + i;
                assert_eq!(diag.source[k], Diagnostics::MAIN_NEWER);
                let (si, sj) = (out[3 * k] as f64 / 7.0, out[3 * k + 1] as usize / 10);
                assert_eq!(sj, j, "row at ({i},{j})");
                let expect = i as f64 + shift_px;
                if expect <= (W - 1) as f64 {
                    assert!(
                        (si - expect).abs() <= 1.0,
                        "({i},{j}): got column {si}, expected {expect}"
                    );
                } else {
                    // Beyond the server image with no auxiliary camera: clamped to the border.
                    assert_eq!(si, (W - 1) as f64);
                }
            }
        }
    }

    #[test]
    fn timewarp_uses_aux_outside_main_only() {
        let server = camera_at([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 60.0, W, H);
        let color = coded_color(W, H);
        let depth = vec![z_of(5.0); W * H];
        let (aw, ah) = (W / 2, H / 2);
        let aux_cam = camera_at([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 100.0, aw, ah);
        let aux_color = vec![222u8; aw * ah * 3];
        let aux_depth = vec![0.5f32; aw * ah];
        let frame = FrameView {
            main: view(server, &color, &depth),
            aux: vec![view(aux_cam, &aux_color, &aux_depth)],
        };
        // A client turned left: its left part sees beyond main's frustum.
        let client = camera_at([0.0, 0.0, 0.0], [-0.5, 0.0, -1.0], 60.0, W, H);
        let (out, diag) = run_tw(&frame, client, &Params::default());
        let aux_px = diag
            .source
            .iter()
            .filter(|&&s| s == Diagnostics::AUX_BASE + 1)
            .count();
        assert!(aux_px > 0 && aux_px < W * H);
        for (k, &s) in diag.source.iter().enumerate() {
            let c = &out[3 * k..3 * k + 3];
            match s {
                s if s == Diagnostics::AUX_BASE + 1 => assert_eq!(c, [222, 222, 222]),
                Diagnostics::MAIN_NEWER => assert_eq!(c[2], 40),
                other => panic!("unexpected source {other}"),
            }
        }
        // Without aux the same pixels come from main, clamped to its left border.
        let params = Params {
            use_aux: false,
            ..Params::default()
        };
        let (out2, diag2) = run_tw(&frame, client, &params);
        for k in 0..W * H {
            assert_eq!(diag2.source[k], Diagnostics::MAIN_NEWER);
            if diag.source[k] == Diagnostics::AUX_BASE + 1 {
                // Clamped to main's border: the left column, or the top or bottom row.
                let (ci, cj) = (out2[3 * k] / 7, out2[3 * k + 1] / 10);
                assert!(
                    ci == 0 || cj == 0 || cj as usize == H - 1,
                    "not on the border: ({ci},{cj})"
                );
            } else {
                assert_eq!(out2[3 * k..3 * k + 3], out[3 * k..3 * k + 3]);
            }
        }
    }

    #[test]
    fn timewarp_invalid_depth_never_reaches_output() {
        let cam = camera_at([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 60.0, W, H);
        let mut color = coded_color(W, H);
        let mut depth = vec![z_of(4.0); W * H];
        let bad = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.5, 1.5];
        for k in (0..W * H).step_by(5) {
            depth[k] = bad[k % bad.len()];
            color[3 * k..3 * k + 3].copy_from_slice(&[255, 255, 255]);
        }
        let frame = FrameView {
            main: view(cam, &color, &depth),
            aux: vec![],
        };
        let client = camera_at([0.1, 0.05, 0.0], [0.0, 0.0, -1.0], 60.0, W, H);
        let (out, diag) = run_tw(&frame, client, &Params::default());
        for k in 0..W * H {
            let c = &out[3 * k..3 * k + 3];
            assert_ne!(c, [255, 255, 255], "invalid pixel leaked at {k}");
            if diag.source[k] == Diagnostics::NONE {
                assert_eq!(c, [3, 3, 3]);
            }
        }
        assert!(diag.source.contains(&Diagnostics::NONE));
        assert!(diag.source.contains(&Diagnostics::MAIN_NEWER));

        // No valid depth at all: nothing is written.
        let all_nan = vec![f32::NAN; W * H];
        let frame = FrameView {
            main: view(cam, &color, &all_nan),
            aux: vec![],
        };
        let (out, diag) = run_tw(&frame, client, &Params::default());
        assert!(out.iter().all(|&v| v == 3));
        assert!(diag.source.iter().all(|&s| s == Diagnostics::NONE));
    }

    #[test]
    fn timewarp_mean_depth_is_order_independent() {
        let depth: Vec<f32> = (0..997 * 13)
            .map(|k| ((k * 7919) % 1000) as f32 / 1000.0)
            .collect();
        let a = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| mean_depth(&depth, 997));
        let b = rayon::ThreadPoolBuilder::new()
            .num_threads(4)
            .build()
            .unwrap()
            .install(|| mean_depth(&depth, 997));
        assert_eq!(a.unwrap().to_bits(), b.unwrap().to_bits());
        assert_eq!(mean_depth(&[f32::NAN, 2.0], 2), None);
    }

    #[test]
    fn timewarp_same_result_for_1_and_4_threads() {
        let (w, h) = (67, 45);
        let server = camera_at([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 60.0, w, h);
        let color: Vec<u8> = (0..w * h * 3).map(|k| ((k * 31) % 251) as u8).collect();
        let depth: Vec<f32> = (0..w * h)
            .map(|k| {
                if k % 11 == 0 {
                    f32::NAN
                } else {
                    z_of(2.0 + (k % 13) as f64)
                }
            })
            .collect();
        let (aw, ah) = (33, 22);
        let aux_cam = camera_at([0.2, 0.0, 0.0], [1.0, 0.0, -3.0], 80.0, aw, ah);
        let aux_color: Vec<u8> = (0..aw * ah * 3).map(|k| ((k * 17) % 253) as u8).collect();
        let aux_depth = vec![0.3f32; aw * ah];
        let frame = FrameView {
            main: view(server, &color, &depth),
            aux: vec![view(aux_cam, &aux_color, &aux_depth)],
        };
        let client = camera_at([0.3, -0.1, 0.2], [0.6, 0.1, -1.0], 60.0, 50, 37);
        let run_in = |n: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
                .install(|| run_tw(&frame, client, &Params::default()))
        };
        let (o1, d1) = run_in(1);
        let (o4, d4) = run_in(4);
        assert_eq!(o1, o4);
        assert_eq!(d1.source, d4.source);
    }
}
