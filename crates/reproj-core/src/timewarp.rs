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

use crate::camera::{pixel_index_of_ndc, pixel_of_ndc, Camera, Projector};
use crate::error::{ReprojError, Result};
use crate::frame::{CameraView, FrameView};
use crate::params::Params;
use crate::request::{par_row_blocks, Diagnostics, Output, Request};
use crate::simd::simd_dispatch;

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
/// inverted; [`ReprojError::BadSize`] for a camera with a side of zero or above
/// [`crate::MAX_SIDE`]; [`ReprojError::BufferSize`] when a buffer does not match its camera
/// (also checked by [`crate::reproject()`]). Nothing is written on error.
pub fn run(frame: &FrameView, request: &Request, params: &Params, out: Output) -> Result<()> {
    frame.validate("frame")?;
    request.client.check_size("client camera")?;
    out.check(request.client.width, request.client.height)?;
    let Some(warp) = Warp::new(frame, request, params)? else {
        // No valid depth: nothing can be warped, every pixel keeps the previous frame.
        if let Some(d) = out.diag {
            d.source.fill(Diagnostics::NONE);
            d.error.fill(f32::NAN);
        }
        return Ok(());
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
    let width = width.max(1);
    let rows: Vec<[(f64, u64); SUM_ROWS]> = depth
        .par_chunks(SUM_ROWS * width)
        .map(|rows| row_sums(rows, width))
        .collect();
    let (sum, count) = rows
        .iter()
        .flatten()
        .fold((0.0f64, 0u64), |(s, n), &(rs, rn)| (s + rs, n + rn));
    (count > 0).then(|| sum / count as f64)
}

/// Rows whose sums [`row_sums`] runs side by side.
const SUM_ROWS: usize = 4;

/// The `f64` sum of the valid depths of each of the (up to [`SUM_ROWS`]) rows of `rows`, each in
/// pixel order, and their count; `(0, 0)` for the rows past its end.
///
/// One row's sum is a chain of dependent `f64` additions (4 cycles each); the rows' chains are
/// independent, so running them side by side overlaps them, with each row's additions in the same
/// order as alone. An invalid depth adds `+0.0`, which leaves the sum's bits as they are: the sum
/// starts at `+0.0` and only grows (a valid `−0.0` gives `+0.0 + −0.0 = +0.0`).
fn row_sums(rows: &[f32], width: usize) -> [(f64, u64); SUM_ROWS] {
    let mut out = [(0.0f64, 0u64); SUM_ROWS];
    if rows.len() == SUM_ROWS * width {
        let (a, rest) = rows.split_at(width);
        let (b, rest) = rest.split_at(width);
        let (c, d) = rest.split_at(width);
        for (((a, b), c), d) in a.iter().zip(b).zip(c).zip(d) {
            for (o, &z) in out.iter_mut().zip([a, b, c, d]) {
                let valid = valid_depth(z);
                o.0 += if valid { f64::from(z) } else { 0.0 };
                o.1 += u64::from(valid);
            }
        }
    } else {
        for (o, row) in out.iter_mut().zip(rows.chunks(width)) {
            for &z in row.iter().filter(|z| valid_depth(**z)) {
                o.0 += f64::from(z);
                o.1 += 1;
            }
        }
    }
    out
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

/// The geometry of the warp: the client and server main cameras and the plane.
#[derive(Debug, Clone, Copy)]
struct Rays {
    client: Projector,
    server: Projector,
    plane: Plane,
}

/// Where output pixel `(i, j)`'s ray meets the plane, in world space and in the server main
/// camera's clip space, and whether it may be written: `(hit, h, ok)`.
///
/// `ok` is false where the ray is parallel to the plane (`|ray·N| < 1e-6`, or NaN), meets it
/// behind the client's near plane or not at a finite distance, or where the server's `w` is not
/// positive. Written without branches on the data, so that [`locate_row`]'s loop vectorises; the
/// scalar [`Warp::warp_pixel`] calls the same function, so both compute the same bytes.
#[inline(always)]
fn ray_hit(r: &Rays, i: usize, j: usize) -> ([f32; 3], [f32; 4], bool) {
    let [x, y] = r.client.ndc_of_pixel(i, j);
    // The ray runs from the near plane (Z = 1) to the far plane (Z = 0) of the client camera;
    // this needs no camera centre, so it holds for orthographic clients too.
    let o = r.client.unproject([x, y, 1.0]);
    let f = r.client.unproject([x, y, 0.0]);
    let d = [f[0] - o[0], f[1] - o[1], f[2] - o[2]];
    let len = dot(d, d).sqrt();
    let d = [d[0] / len, d[1] / len, d[2] / len];
    let n = r.plane.n;
    let dn = dot(d, n);
    let q = r.plane.q;
    let s = dot([q[0] - o[0], q[1] - o[1], q[2] - o[2]], n) / dn;
    let hit = [o[0] + s * d[0], o[1] + s * d[1], o[2] + s * d[2]];
    let h = r.server.vp.apply(hit);
    // NaN (a degenerate ray) fails these comparisons too. `s < 0`: behind the near plane, where
    // the client would clip it. Every point of the plane lies in front of the server camera (it
    // faces the camera along its own axis), so `w ≤ 0` means a degenerate matrix; do not guess.
    // `&`, not `&&`: short-circuit branches would keep the row loop from vectorising.
    let ok = (dn.abs() >= PARALLEL_EPS) & (s >= 0.0) & s.is_finite() & (h[3] > 0.0);
    (hit, h, ok)
}

/// [`locate_row`]'s code for a pixel that is not written.
const NOT_WRITTEN: u32 = u32::MAX;

/// [`locate_row`]'s code for a pixel whose hit lies outside the main image (or whose server NDC
/// is not finite): [`Warp::warp_pixel`] decides it (auxiliary camera 0, or main clamped).
const OUTSIDE_MAIN: u32 = u32::MAX - 1;

simd_dispatch! {
    /// For each output pixel `i` of row `j` of the client image (`out`, one per column), the
    /// index of the main pixel that its hit projects into, or [`NOT_WRITTEN`] or
    /// [`OUTSIDE_MAIN`]. Main indices are below `2²⁸` (sides are at most 16384), so never a code.
    ///
    /// The geometry of every pixel, without branches: nearly every pixel of a frame lands in
    /// main, and in vectors this costs a fraction of the scalar ray (two unprojections, a square
    /// root and five divisions per pixel). It runs in an AVX-512 or AVX2 build where the
    /// processor has it, with the same IEEE operations (no FMA contraction), so the bytes do not
    /// depend on the processor.
    fn locate_row / locate_row_avx2, locate_row_avx512 =>
        locate_row_impl(r: &Rays, j: usize, out: &mut [u32])
}

#[inline(always)]
fn locate_row_impl(r: &Rays, j: usize, out: &mut [u32]) {
    let (mw, mh) = (r.server.width, r.server.height);
    let (wf, hf) = (mw as i32 as f32, mh as i32 as f32);
    for (i, code) in out.iter_mut().enumerate() {
        let (_, h, ok) = ray_hit(r, i, j);
        let (sx, sy) = (h[0] / h[3], h[1] / h[3]);
        // The pixel `Warp::warp_pixel` finds with `pixel_of_ndc`, without branches.
        let (inside, idx) = pixel_index_of_ndc(sx, sy, wf, hf, mw as u32);
        *code = if !ok {
            NOT_WRITTEN
        } else if inside {
            idx
        } else {
            OUTSIDE_MAIN
        };
    }
}

/// Read-only context of the per-pixel warp.
struct Warp<'a> {
    rays: Rays,
    main: CameraView<'a>,
    aux: Option<(CameraView<'a>, Projector)>,
}

impl<'a> Warp<'a> {
    /// The warp of `frame` to `request`'s client: the cameras and the plane, or `None` when no
    /// main pixel has a valid depth (or the plane is degenerate).
    fn new(frame: &FrameView<'a>, request: &Request, params: &Params) -> Result<Option<Self>> {
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
        Ok(plane.map(|plane| Warp {
            rays: Rays {
                client,
                server,
                plane,
            },
            main,
            aux,
        }))
    }

    /// Warps the output rows starting at `j0` (a block of at most [`TILE`](crate::TILE) rows),
    /// row by row: [`locate_row`] finds the main pixel of every output pixel of the row, then
    /// each is sampled (and the few whose hit lies outside main go through
    /// [`Warp::warp_pixel`]).
    fn warp_rows(&self, j0: usize, out: &mut [u8], mut diag: Option<(&mut [u8], &mut [f32])>) {
        let cw = self.rays.client.width;
        let rows = out.len() / (3 * cw);
        let mut codes = vec![0u32; cw];
        for r in 0..rows {
            let j = j0 + r;
            locate_row(&self.rays, j, &mut codes);
            for (i, &code) in codes.iter().enumerate() {
                let local = r * cw + i;
                let hit = match code {
                    NOT_WRITTEN => None,
                    OUTSIDE_MAIN => self.warp_pixel(i, j),
                    idx => sample(&self.main, idx as usize).map(|c| (Diagnostics::MAIN_NEWER, c)),
                };
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

    /// The ray of output pixel `(i, j)` against the plane, then the sample: `(diagnostic code,
    /// colour)`, or `None` when the pixel is not written. The reference for [`locate_row`]
    /// (the same [`ray_hit`]); [`Warp::warp_rows`] calls it only where the hit misses main.
    #[inline]
    fn warp_pixel(&self, i: usize, j: usize) -> Option<(u8, [u8; 3])> {
        let (hit, h, ok) = ray_hit(&self.rays, i, j);
        if !ok {
            return None;
        }
        let server = &self.rays.server;
        let (sx, sy) = (h[0] / h[3], h[1] / h[3]);
        let (mw, mh) = (server.width, server.height);
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

    /// With a uniform depth the plane is the scene, so a client moved sideways and up by
    /// `(tx, ty)` from the server sees the server image shifted by exactly `f·t/d` in NDC: the
    /// centre of client pixel `(i, j)` lands at `(i + ½ + sx, j + ½ − sy)` server pixels. For
    /// a server at the origin looking down −z, and for one elsewhere, turned (the plane's point
    /// and normal must follow the camera, not the world origin).
    #[test]
    fn timewarp_translation_matches_analytic_shift() {
        let dist = 5.0;
        let (shift_x, shift_y) = (2.3, 1.6);
        // Focal lengths of the 60° camera, from the field of view (not from the matrix).
        let fy = 1.0 / 30f64.to_radians().tan();
        let fx = fy * H as f64 / W as f64;
        let (tx, ty) = (
            shift_x * (2.0 / W as f64) * dist / fx,
            shift_y * (2.0 / H as f64) * dist / fy,
        );
        let color = coded_color(W, H);
        let depth = vec![z_of(dist); W * H];
        for (eye, target) in [
            ([0.0, 0.0, 0.0], [0.0, 0.0, -1.0]),
            ([3.0, 1.0, 4.0], [0.5, 0.2, -2.0]),
        ] {
            let server = camera_at(eye, target, 60.0, W, H);
            let frame = FrameView {
                main: view(server, &color, &depth),
                aux: vec![],
            };
            // The server's x and y axes in world space: the first two rows of its view matrix.
            let (ax, ay) = (server.view.0[0], server.view.0[1]);
            let moved = |p: [f64; 3]| [0, 1, 2].map(|k| p[k] + tx * ax[k] + ty * ay[k]);
            let client = camera_at(moved(eye), moved(target), 60.0, W, H);
            let (out, diag) = run_tw(&frame, client, &Params::default());
            for j in 0..H {
                for i in 0..W {
                    let k = j * W + i;
                    assert_eq!(diag.source[k], Diagnostics::MAIN_NEWER);
                    let (si, sj) = (
                        usize::from(out[3 * k] / 7),
                        usize::from(out[3 * k + 1] / 10),
                    );
                    // Past the server image (no auxiliary camera): clamped to its border.
                    let want_i = ((i as f64 + 0.5 + shift_x).floor() as usize).min(W - 1);
                    let want_j = (j as f64 + 0.5 - shift_y).floor().max(0.0) as usize;
                    assert_eq!(
                        (si, sj),
                        (want_i, want_j),
                        "{eye:?}: client pixel ({i},{j})"
                    );
                }
            }
        }
    }

    /// Rays that meet the plane behind the client (a client turned away from it) are not
    /// written, and neither are those that only an auxiliary camera facing away from the hit
    /// would "see" through its mirrored projection: those fall back to main, clamped.
    #[test]
    fn timewarp_writes_nothing_behind_a_camera() {
        let server = camera_at([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 60.0, W, H);
        let color = coded_color(W, H);
        let depth = vec![z_of(5.0); W * H];
        let (aw, ah) = (W / 2, H / 2);
        let aux_color = vec![222u8; aw * ah * 3];
        let aux_depth = vec![0.5f32; aw * ah];
        // An auxiliary camera at the server's centre looking the other way (+z).
        let behind = camera_at([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 100.0, aw, ah);
        let frame = FrameView {
            main: view(server, &color, &depth),
            aux: vec![view(behind, &aux_color, &aux_depth)],
        };
        let away = camera_at([0.0, 0.0, 0.0], [0.2, 0.1, 1.0], 60.0, W, H);
        let (out, diag) = run_tw(&frame, away, &Params::default());
        assert!(out.iter().all(|&v| v == 3));
        assert!(diag.source.iter().all(|&s| s == Diagnostics::NONE));
        // Turned left past main's border: every hit lies in front of main, behind the aux.
        let left = camera_at([0.0, 0.0, 0.0], [-0.8, 0.0, -1.0], 60.0, W, H);
        let (out, diag) = run_tw(&frame, left, &Params::default());
        assert!(diag.source.iter().all(|&s| s == Diagnostics::MAIN_NEWER));
        assert!(out.chunks(3).all(|c| c[2] == 40));
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

    /// The row loop ([`locate_row`] at every SIMD tier, then the samples) writes what
    /// [`Warp::warp_pixel`] gives pixel by pixel, colour and source code, for clients that see
    /// the plane head on, past main's border into the auxiliary camera and beyond it (main
    /// clamped), and turned away from it (nothing written), with invalid depths and motions.
    #[test]
    fn timewarp_rows_equal_the_per_pixel_warp_at_every_tier() {
        use crate::ours::{set_simd_limit, Simd};
        let cam = camera_at([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 60.0, W, H);
        let color = coded_color(W, H);
        let mut depth: Vec<f32> = (0..W * H)
            .map(|k| z_of(3.0 + (k % 7) as f64 * 0.5))
            .collect();
        let mut motion = vec![0.0f32; 3 * W * H];
        for k in (0..W * H).step_by(11) {
            depth[k] = [f32::NAN, 1.5, -0.25][k % 3];
        }
        for k in (3..W * H).step_by(13) {
            motion[3 * k + k % 3] = [f32::NAN, f32::INFINITY][k % 2];
        }
        let (aw, ah) = (20, 14);
        let aux_color = vec![222u8; aw * ah * 3];
        let aux_depth = vec![z_of(4.0); aw * ah];
        let frame = FrameView {
            main: CameraView {
                motion: Some(&motion),
                ..view(cam, &color, &depth)
            },
            aux: vec![view(
                camera_at([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 110.0, aw, ah),
                &aux_color,
                &aux_depth,
            )],
        };
        // (eye, target, vertical field of view): head on, moved, turned past main's border
        // (into aux, and past aux), and turned away.
        let clients = [
            ([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 60.0),
            ([0.3, -0.2, 0.5], [0.1, 0.0, -1.0], 75.0),
            ([0.0, 0.0, 0.0], [0.8, 0.1, -1.0], 60.0),
            ([0.0, 0.1, 0.0], [-1.0, 0.6, -0.3], 90.0),
            ([0.0, 0.0, 0.0], [0.3, 0.0, 1.0], 60.0),
        ];
        let mut seen = [0usize; 3]; // main, aux, not written
        for (eye, target, fov) in clients {
            let client = camera_at(eye, target, fov, W, H);
            let request = Request { client, alpha: 0.5 };
            let warp = Warp::new(&frame, &request, &Params::default())
                .unwrap()
                .expect("a plane");
            let mut want = (vec![3u8; 3 * W * H], vec![Diagnostics::NONE; W * H]);
            for j in 0..H {
                for i in 0..W {
                    let k = j * W + i;
                    if let Some((code, rgb)) = warp.warp_pixel(i, j) {
                        want.0[3 * k..3 * k + 3].copy_from_slice(&rgb);
                        want.1[k] = code;
                    }
                    match want.1[k] {
                        Diagnostics::MAIN_NEWER => seen[0] += 1,
                        Diagnostics::NONE => seen[2] += 1,
                        _ => seen[1] += 1,
                    }
                }
            }
            for tier in [Simd::Baseline, Simd::Avx2, Simd::Avx512] {
                set_simd_limit(tier);
                let (out, diag) = run_tw(&frame, client, &Params::default());
                assert!(out == want.0, "{eye:?} → {target:?}, {tier:?}: colours");
                assert!(
                    diag.source == want.1,
                    "{eye:?} → {target:?}, {tier:?}: sources"
                );
                assert!(diag.error.iter().all(|e| e.is_nan()));
            }
        }
        set_simd_limit(Simd::Avx512);
        assert!(seen.iter().all(|&n| n > 20), "cases reached: {seen:?}");
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
        // The rows side by side (13 = 3 blocks of 4 and one row alone) add in the order of
        // each row alone, then of the rows; invalid depths (here every 10th) are skipped.
        let mut depth = depth;
        for (k, z) in depth.iter_mut().enumerate().step_by(10) {
            *z = [f32::NAN, -0.0, 1.5, f32::INFINITY][k % 4];
        }
        let (mut sum, mut n) = (0.0f64, 0u64);
        for row in depth.chunks(997) {
            let mut s = 0.0f64;
            for &z in row.iter().filter(|z| valid_depth(**z)) {
                (s, n) = (s + f64::from(z), n + 1);
            }
            sum += s;
        }
        let want = sum / n as f64;
        assert_eq!(mean_depth(&depth, 997).unwrap().to_bits(), want.to_bits());
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
