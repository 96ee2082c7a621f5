//! `backward_bidir`: image-space bidirectional reprojection of seeds/001 §5 (Yang et al. 2011), the
//! baseline of seeds/000 §4.2.
//!
//! The method interpolates linearly between the two server NDC spaces and ignores the client pose
//! (only the client camera's *size* is used, and it must equal the main camera's). Per frame:
//!
//! 1. **Full flows**, per source pixel (seeds/000 eqs. 2, 3): `Vᶠ[p] = P_{t+1}(X′) − p̄` for the
//!    pixels of `I_t`, with `X′ = P_t⁻¹(p̄ + O_{t→t+1}[p])`, and `Vᵇ[p] = P_t(X′_b) − p̄` for the
//!    pixels of `I_{t+1}`. NaN marks invalid pixels (non-finite or out-of-range depth, non-finite
//!    motion, a moved point behind the other camera).
//! 2. **Iterative search** per output pixel `p_{t+α}` (NDC `T`), seeds/001 §5.1: forward
//!    `p_{t,i} = T − α·Vᶠ[p_{t,i−1}].xy` (eqs. 4, 5), backward `p_{t+1,i} = T − (1−α)·Vᵇ[p_{t+1,i−1}].xy`
//!    (eqs. 8–10), `m =` [`Params::bidir_iterations`] steps, nearest-pixel lookups, a step that leaves
//!    the image keeps the previous point. Depth `zᶠ = Z_t[p] + α·Vᶠ.z` (eq. 6, eq. 11 backward) and
//!    error `eᶠ = ‖p + α·Vᶠ.xy − T‖` (eq. 7, eq. 12), aspect-scaled like [`crate::ours`]
//!    (2.0 = the image's short side).
//! 3. **Initialisations** (seeds/001 §5.3), each searched, the smallest error kept per direction
//!    (except that of two converged results at different depths the nearer is kept, see
//!    `Bidir::better`): the default `p_0 = T`; the dual initialisation `p′_{t,0} = T + α·Vᵇ[T]`,
//!    `p′_{t+1,0} = T + (1−α)·Vᶠ[T]` (eqs. 16, 17); and the latest-frame initialisation
//!    `p_{t,0} = T − (α/α₀)·dᶠ`, `p_{t+1,0} = T − ((1−α)/(1−α₀))·dᵇ` (eqs. 18, 19) from the offsets
//!    `d = w·V[p_m].xy` (eq. 5: `T − p` before `p` is snapped to a pixel) of the previous B-frame
//!    at `α₀ < α`, taking in the 3×3 neighbourhood of `T` the offset whose initial point is nearest
//!    (largest reversed depth at `t+α`).
//! 4. **Visibility and shading** (seeds/001 §5.2, eqs. 13–15) with the tolerance `e < 1` pixel and
//!    the depth similarity `2|zᶠ − zᵇ| < ε_z`:
//!    rule 1 (both within tolerance, similar depth): the smaller-error point, mapped into the other
//!    frame with its full flow and blended `(1−α)·I_t + α·I_{t+1}` if visible there (eqs. 14, 15),
//!    else that frame alone; rule 2 (both within, different depth): the nearer one, with the same
//!    "second chance" blend; only one within: that one, with the second chance; rule 3 (neither):
//!    the blend of both search results (eq. 13), or the one valid result, or no write. "Visible in
//!    the other frame" needs a valid pixel there (depth and motion) whose depth agrees within `ε_z`.
//!
//! Where we differ from the reference implementation (REFERENCE.md §3 mode 1) on purpose: it
//! splats and runs a 7×7 window search with 5 iterations and no seeds/001 initialisations; we
//! implement seeds/001 itself (its default, dual and latest-frame initialisations, its 3 iterations
//! and its shading rules). Invalid search results never contribute colour (the reference samples
//! zeros outside the texture); colours are rounded. No shadows and no auxiliary cameras are used
//! (the paper's baseline has none).

use rayon::prelude::*;

use crate::camera::{pixel_of_ndc, Projector};
use crate::error::{ReprojError, Result};
use crate::frame::{CameraView, FrameView};
use crate::ours::PairCache;
use crate::params::{Params, TILE};
use crate::request::{Diagnostics, Request};
use crate::shadow::round_rgb;

/// State carried from one client frame (B-frame) to the next for seeds/001's latest-frame
/// initialisation (eqs. 18, 19): the final search offsets `d_m = w·V[p_m].xy` of every output
/// pixel in both directions (eqs. 5, 9: `T − p` for the converged, unsnapped position `p`) and the
/// `α₀` they were found at.
///
/// The offsets only make sense within one server-frame pair: the caller must reset the history
/// ([`BidirHistory::reset`] or a fresh [`BidirHistory::new`]) whenever the pair changes. Within a
/// pair it is used only when the new `α` is larger than `α₀` and the output size is unchanged.
///
/// The same object carries `ours`' pair-level work ([`PairCache`]): despite the name (kept for
/// the API), it is the client's history for one server-frame pair, whatever the method.
#[derive(Debug, Clone, Default)]
pub struct BidirHistory {
    width: usize,
    height: usize,
    alpha: f32,
    /// Per output pixel: `dᶠ.x, dᶠ.y, dᵇ.x, dᵇ.y` (NDC); NaN where that search found nothing.
    offsets: Vec<[f32; 4]>,
    /// `ours`' per-pair state.
    ours: PairCache,
}

impl BidirHistory {
    /// An empty history (the first B-frame of a pair).
    pub fn new() -> Self {
        Self::default()
    }

    /// Forgets the stored offsets and pair state; call it when the server-frame pair changes.
    /// (The pair state's buffers are kept: first touches of fresh memory are slow.)
    pub fn reset(&mut self) {
        let mut ours = std::mem::take(&mut self.ours);
        ours.reset();
        *self = Self {
            ours,
            ..Self::default()
        };
    }

    /// `ours`' pair-level state.
    pub(crate) fn pair_cache(&mut self) -> &mut PairCache {
        &mut self.ours
    }

    /// `α₀` of the stored B-frame, or `None` when the history is empty.
    pub fn alpha(&self) -> Option<f32> {
        (!self.offsets.is_empty()).then_some(self.alpha)
    }

    /// The offsets stored for a `width × height` output at a later `alpha`, if they apply.
    fn usable(&self, width: usize, height: usize, alpha: f32) -> Option<(&[[f32; 4]], f32)> {
        let ok = !self.offsets.is_empty()
            && self.width == width
            && self.height == height
            && self.offsets.len() == width * height
            && self.alpha.is_finite()
            && self.alpha < alpha;
        ok.then_some((&self.offsets[..], self.alpha))
    }
}

/// Runs `backward_bidir`: synthesises the B-frame at `α ∈ [0, 1]` between `older` (`I_t` with its
/// forward motion `O_{t→t+1}`) and `newer` (`I_{t+1}` with its backward motion `O_{t+1→t}`).
/// See the module docs for the algorithm.
///
/// Only the main cameras are used. Every output pixel is written unless neither search found a
/// valid source pixel (invalid depth or motion everywhere it looked); those keep the previous
/// client frame. `diag` receives [`Diagnostics::MAIN_OLDER`]/[`Diagnostics::MAIN_NEWER`] for the
/// frame whose match was chosen (the smaller error under rule 3), or-ed with
/// [`Diagnostics::BLENDED`] when both frames were blended, and the error of that match.
///
/// `history`, when given, supplies the latest-frame initialisation (if it holds offsets of the
/// same output size at a smaller `α`) and receives this frame's offsets and `α` afterwards. The
/// caller resets it when the frame pair changes.
///
/// # Errors
/// [`ReprojError::CameraMismatch`] when the two main cameras, or the client camera and the main
/// camera, differ in size (the method works in the server images' pixel grid);
/// [`ReprojError::SingularMatrix`] when a main camera cannot be inverted;
/// [`ReprojError::AlphaRange`] for `α` outside `[0, 1]`; [`ReprojError::BufferSize`] when a buffer
/// does not match its camera (also checked by [`crate::reproject()`]). Nothing is written to `out`,
/// `diag` or `history` on error.
pub fn run(
    older: &FrameView,
    newer: &FrameView,
    request: &Request,
    params: &Params,
    out: &mut [u8],
    diag: Option<&mut Diagnostics>,
    history: Option<&mut BidirHistory>,
) -> Result<()> {
    older.validate("older")?;
    newer.validate("newer")?;
    let alpha = request.alpha;
    if !(alpha.is_finite() && (0.0..=1.0).contains(&alpha)) {
        return Err(ReprojError::AlphaRange {
            alpha,
            method: "backward_bidir".into(),
            range: "[0, 1] (backward_bidir only interpolates)".into(),
        });
    }
    let (ov, nv) = (older.main, newer.main);
    let (w, h) = (ov.camera.width, ov.camera.height);
    if (nv.camera.width, nv.camera.height) != (w, h) {
        return Err(ReprojError::CameraMismatch(format!(
            "backward_bidir: older main camera is {w}x{h} but newer main camera is {}x{}; the method needs both images on the same pixel grid",
            nv.camera.width, nv.camera.height
        )));
    }
    let (cw, ch) = (request.client.width, request.client.height);
    if (cw, ch) != (w, h) {
        return Err(ReprojError::CameraMismatch(format!(
            "backward_bidir: client camera is {cw}x{ch} but the main cameras are {w}x{h}; the method interpolates in the server images' pixel grid and ignores the client pose, so the output size must equal the main camera size"
        )));
    }
    crate::request::check_output(out, diag.as_deref(), w, h)?;
    let op = ov.camera.projector("older.main camera")?;
    let np = nv.camera.projector("newer.main camera")?;

    // Pass 1: full flows Vᶠ (older → newer camera) and Vᵇ (newer → older camera).
    let vf = full_flow(&ov, &op, &np);
    let vb = full_flow(&nv, &np, &op);

    // Pass 2: per output pixel, in row blocks of TILE rows.
    let n = w * h;
    let mut offsets = vec![[f32::NAN; 4]; n];
    {
        let latest = history
            .as_deref()
            .and_then(|hist| hist.usable(w, h, alpha))
            .map(|(d, a0)| Latest {
                offsets: d,
                // α₀ = 0 stores zero forward offsets, which carry no motion and cannot be scaled.
                scale_f: (a0 > 0.0).then(|| alpha / a0),
                scale_b: (1.0 - alpha) / (1.0 - a0),
            });
        let short = w.min(h) as f32;
        let ctx = Bidir {
            older: Side {
                view: ov,
                flow: &vf,
                w: alpha,
            },
            newer: Side {
                view: nv,
                flow: &vb,
                w: 1.0 - alpha,
            },
            width: w,
            height: h,
            alpha,
            iterations: params.bidir_iterations,
            tol_e: 2.0 / short,
            eps_z: params.eps_z,
            scale: [w as f32 / short, h as f32 / short],
            latest,
        };
        match diag {
            Some(d) => out
                .par_chunks_mut(TILE * w * 3)
                .zip(offsets.par_chunks_mut(TILE * w))
                .zip(d.source.par_chunks_mut(TILE * w))
                .zip(d.error.par_chunks_mut(TILE * w))
                .enumerate()
                .for_each(|(b, (((o, off), s), e))| {
                    ctx.resolve_rows(b * TILE, o, off, Some((s, e)))
                }),
            None => out
                .par_chunks_mut(TILE * w * 3)
                .zip(offsets.par_chunks_mut(TILE * w))
                .enumerate()
                .for_each(|(b, (o, off))| ctx.resolve_rows(b * TILE, o, off, None)),
        }
    }
    if let Some(hist) = history {
        let ours = std::mem::take(&mut hist.ours);
        *hist = BidirHistory {
            width: w,
            height: h,
            alpha,
            offsets,
            ours,
        };
    }
    Ok(())
}

/// A depth value that marks its pixel valid: finite and inside the reversed-depth range.
#[inline(always)]
fn valid_depth(z: f32) -> bool {
    z.is_finite() && (0.0..=1.0).contains(&z)
}

/// The full flow of every pixel of `view` into camera `to` (seeds/000 eqs. 2, 3): the pixel moved
/// by its object motion in its own NDC, unprojected with its own camera, projected with `to`.
/// `[Δx, Δy, ΔZ]` per pixel; NaN for invalid pixels.
fn full_flow(view: &CameraView, from: &Projector, to: &Projector) -> Vec<[f32; 3]> {
    let w = from.width;
    let mut flow = vec![[f32::NAN; 3]; w * from.height];
    flow.par_chunks_mut(TILE * w)
        .enumerate()
        .for_each(|(b, rows)| {
            for (r, row) in rows.chunks_mut(w).enumerate() {
                let j = b * TILE + r;
                for (i, f) in row.iter_mut().enumerate() {
                    *f = full_flow_of(view, from, to, i, j).unwrap_or([f32::NAN; 3]);
                }
            }
        });
    flow
}

/// The full flow of pixel `(i, j)`, or `None` when it is invalid.
#[inline]
fn full_flow_of(
    view: &CameraView,
    from: &Projector,
    to: &Projector,
    i: usize,
    j: usize,
) -> Option<[f32; 3]> {
    let idx = j * from.width + i;
    let z = view.depth[idx];
    let o = view.motion_at(idx);
    // Invalid depth or motion never reaches the output (DESIGN.md).
    if !valid_depth(z) || !o.iter().all(|v| v.is_finite()) {
        return None;
    }
    let [x, y] = from.ndc_of_pixel(i, j);
    let moved = from.unproject([x + o[0], y + o[1], z + o[2]]);
    let h = to.vp.apply(moved);
    // Behind the other camera the projection is mirrored: no flow.
    if !(h[3] > 0.0) {
        return None;
    }
    let v = [h[0] / h[3] - x, h[1] / h[3] - y, h[2] / h[3] - z];
    v.iter().all(|c| c.is_finite()).then_some(v)
}

/// One I-frame as seen from the B-frame: its image, its full flow toward the other I-frame and the
/// fraction `w` of that flow separating it from `t+α` (`α` for `I_t`, `1−α` for `I_{t+1}`).
struct Side<'a> {
    view: CameraView<'a>,
    flow: &'a [[f32; 3]],
    w: f32,
}

impl Side<'_> {
    /// Whether pixel `p` is valid: finite depth in `[0,1]` and finite motion (DESIGN.md).
    #[inline(always)]
    fn valid(&self, p: usize) -> bool {
        valid_depth(self.view.depth[p]) && self.view.motion_at(p).iter().all(|v| v.is_finite())
    }

    #[inline(always)]
    fn color(&self, p: usize) -> [f32; 3] {
        let c = &self.view.color[3 * p..3 * p + 3];
        [f32::from(c[0]), f32::from(c[1]), f32::from(c[2])]
    }
}

/// The previous B-frame's offsets and their scale factors for eqs. 18 (forward) and 19 (backward).
struct Latest<'a> {
    offsets: &'a [[f32; 4]],
    scale_f: Option<f32>,
    scale_b: f32,
}

/// The outcome of one iterative search: the final pixel `p_{·,m}`, its error and depth at `t+α`.
/// `e = ∞` marks a search that ended on an invalid pixel.
#[derive(Debug, Clone, Copy)]
struct Found {
    p: usize,
    e: f32,
    z: f32,
}

impl Found {
    #[inline(always)]
    fn valid(&self) -> bool {
        self.e.is_finite()
    }
}

/// The decision for one output pixel: diagnostic code, colour, error of the chosen match.
type Resolved = (u8, [u8; 3], f32);

/// Which I-frame a decision refers to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Dir {
    /// `I_t`, the forward search.
    Forward,
    /// `I_{t+1}`, the backward search.
    Backward,
}

/// Read-only context of pass 2.
struct Bidir<'a> {
    older: Side<'a>,
    newer: Side<'a>,
    width: usize,
    height: usize,
    alpha: f32,
    iterations: usize,
    /// One pixel in aspect-scaled NDC units: `2 / min(W, H)`.
    tol_e: f32,
    eps_z: f32,
    /// Aspect scaling of the error: `(W, H) / min(W, H)`.
    scale: [f32; 2],
    latest: Option<Latest<'a>>,
}

impl Bidir<'_> {
    /// Resolves the output rows starting at `j0`, in 16×16 tiles, writing colours, the offsets for
    /// the history and the diagnostics.
    fn resolve_rows(
        &self,
        j0: usize,
        out: &mut [u8],
        offsets: &mut [[f32; 4]],
        mut diag: Option<(&mut [u8], &mut [f32])>,
    ) {
        let w = self.width;
        let rows = out.len() / (3 * w);
        for i0 in (0..w).step_by(TILE) {
            for r in 0..rows {
                for i in i0..(i0 + TILE).min(w) {
                    let local = r * w + i;
                    let (res, off) = self.resolve_pixel(i, j0 + r);
                    offsets[local] = off;
                    if let Some((_, rgb, _)) = res {
                        out[3 * local..3 * local + 3].copy_from_slice(&rgb);
                    }
                    if let Some((s, e)) = diag.as_mut() {
                        s[local] = res.map_or(Diagnostics::NONE, |x| x.0);
                        e[local] = res.map_or(f32::NAN, |x| x.2);
                    }
                }
            }
        }
    }

    #[inline(always)]
    fn side(&self, dir: Dir) -> (&Side<'_>, &Side<'_>) {
        match dir {
            Dir::Forward => (&self.older, &self.newer),
            Dir::Backward => (&self.newer, &self.older),
        }
    }

    #[inline(always)]
    fn pixel_index(&self, x: f32, y: f32) -> Option<usize> {
        pixel_of_ndc(x, y, self.width, self.height).map(|(i, j)| j * self.width + i)
    }

    #[inline(always)]
    fn ndc(&self, p: usize) -> [f32; 2] {
        crate::camera::ndc_of_pixel(p % self.width, p / self.width, self.width, self.height)
    }

    /// The iterative search of seeds/001 eqs. 5 / 9 in `side` from `p0`: `p ← pix(T − w·V[p].xy)`,
    /// keeping `p` when the step leaves the image (or `V[p]` is invalid), then the depth (eq. 6/11)
    /// and aspect-scaled error (eq. 7/12) of the final point.
    #[inline]
    fn search(&self, side: &Side, t: [f32; 2], p0: usize) -> Found {
        let mut p = p0;
        for _ in 0..self.iterations {
            let v = side.flow[p];
            if let Some(q) = self.pixel_index(t[0] - side.w * v[0], t[1] - side.w * v[1]) {
                p = q;
            }
        }
        let v = side.flow[p];
        let [px, py] = self.ndc(p);
        let ex = (px + side.w * v[0] - t[0]) * self.scale[0];
        let ey = (py + side.w * v[1] - t[1]) * self.scale[1];
        let e = (ex * ex + ey * ey).sqrt();
        let z = side.view.depth[p] + side.w * v[2];
        if e.is_finite() && z.is_finite() {
            Found { p, e, z }
        } else {
            Found {
                p,
                e: f32::INFINITY,
                z: f32::NAN,
            }
        }
    }

    /// Whether search result `c` is better than `best`: the smaller error (seeds/001 §5.3), except
    /// that of two results within the tolerance at different depths the nearer one wins.
    ///
    /// Both are then exact solutions of eq. 3 ("multiple solutions may exist, since other points
    /// visible in F_t may also map to p_{t+α} but may be occluded", §5.1), and the nearer point
    /// occludes the farther one at `t+α`, as in rule 2. Without this a static background under
    /// `T` (error 0 from the default start) would always shadow the moving occluder that the dual
    /// or latest-frame initialisation found, also with error 0.
    #[inline]
    fn better(&self, c: &Found, best: &Found) -> bool {
        if c.e < self.tol_e && best.e < self.tol_e && !(2.0 * (c.z - best.z).abs() < self.eps_z) {
            c.z > best.z
        } else {
            c.e < best.e
        }
    }

    /// The best (see [`Bidir::better`]) of the default, dual and latest-frame initialisations in
    /// direction `dir` for the output pixel `(i, j)` at NDC `t`; ties keep the earlier strategy.
    fn direction(&self, dir: Dir, i: usize, j: usize, t: [f32; 2]) -> Found {
        let (side, other) = self.side(dir);
        let tp = j * self.width + i;
        // Default initialisation p_0 = T (eqs. 4, 8).
        let mut best = self.search(side, t, tp);
        let mut consider = |p0: usize| {
            let c = self.search(side, t, p0);
            if self.better(&c, &best) {
                best = c;
            }
        };
        // Dual initialisation (eqs. 16, 17): the opposing frame's velocity at T, scaled to this
        // side's time distance, guesses where the point was before this frame's flow is known.
        let vo = other.flow[tp];
        if let Some(p0) = self.pixel_index(t[0] + side.w * vo[0], t[1] + side.w * vo[1]) {
            consider(p0);
        }
        // Latest-frame initialisation (eqs. 18, 19).
        if let Some(p0) = self.latest_init(dir, side, i, j, t) {
            consider(p0);
        }
        best
    }

    /// The latest-frame initial point: among the previous B-frame's offsets in the 3×3
    /// neighbourhood of `(i, j)`, scaled to this `α`, the one whose initial point is nearest
    /// (largest reversed depth at `t+α`), which lets pixels near a silhouette pick up the motion of
    /// the occluding object (seeds/001 §5.3).
    fn latest_init(&self, dir: Dir, side: &Side, i: usize, j: usize, t: [f32; 2]) -> Option<usize> {
        let latest = self.latest.as_ref()?;
        let (scale, k) = match dir {
            Dir::Forward => (latest.scale_f?, 0),
            Dir::Backward => (latest.scale_b, 2),
        };
        let mut best: Option<(f32, usize)> = None;
        for qj in j.saturating_sub(1)..=(j + 1).min(self.height - 1) {
            for qi in i.saturating_sub(1)..=(i + 1).min(self.width - 1) {
                let d = latest.offsets[qj * self.width + qi];
                let Some(p0) = self.pixel_index(t[0] - scale * d[k], t[1] - scale * d[k + 1])
                else {
                    continue; // NaN offsets land here too
                };
                let z = side.view.depth[p0] + side.w * side.flow[p0][2];
                // NaN depth fails the comparison; ties keep the first in scan order.
                if z.is_finite() && best.is_none_or(|(bz, _)| z > bz) {
                    best = Some((z, p0));
                }
            }
        }
        best.map(|(_, p0)| p0)
    }

    /// The "second chance" of rules 1 and 2 (eqs. 14, 15): map the chosen point `m` of `dir` into
    /// the other I-frame with its full flow; if it is visible there (inside, and the depth there
    /// agrees within `ε_z`) blend `(1−α)·I_t + α·I_{t+1}`, else use the chosen frame alone.
    /// Returns the colour and whether it blended.
    fn second_chance(&self, dir: Dir, m: Found) -> ([f32; 3], bool) {
        let (side, other) = self.side(dir);
        let base = side.color(m.p);
        let v = side.flow[m.p];
        let [x, y] = self.ndc(m.p);
        let Some(q) = self.pixel_index(x + v[0], y + v[1]) else {
            return (base, false);
        };
        let zq = other.view.depth[q];
        let predicted = side.view.depth[m.p] + v[2];
        // An invalid pixel at q never lends its colour; a NaN difference fails `<`.
        if !(other.valid(q) && 2.0 * (zq - predicted).abs() < self.eps_z) {
            return (base, false);
        }
        let oc = other.color(q);
        let (ct, ct1) = match dir {
            Dir::Forward => (base, oc),
            Dir::Backward => (oc, base),
        };
        (self.blend(ct, ct1), true)
    }

    /// `(1−α)·c_t + α·c_{t+1}`.
    #[inline(always)]
    fn blend(&self, ct: [f32; 3], ct1: [f32; 3]) -> [f32; 3] {
        let a = self.alpha;
        [
            (1.0 - a) * ct[0] + a * ct1[0],
            (1.0 - a) * ct[1] + a * ct1[1],
            (1.0 - a) * ct[2] + a * ct1[2],
        ]
    }

    /// The whole per-pixel decision: the pixel's [`Resolved`] (`None`: not written) and its
    /// offsets `[dᶠ.x, dᶠ.y, dᵇ.x, dᵇ.y]` for the history.
    fn resolve_pixel(&self, i: usize, j: usize) -> (Option<Resolved>, [f32; 4]) {
        let t = self.ndc(j * self.width + i);
        let f = self.direction(Dir::Forward, i, j, t);
        let b = self.direction(Dir::Backward, i, j, t);
        // The offset d_m = w·V[p_m].xy of eq. 5 / 9, i.e. T − p for the converged continuous
        // position p. Storing it rather than T − p̄_m (the pixel centre) keeps the sub-pixel
        // motion: early B-frames move less than half a pixel, and snapped offsets would be zero
        // there and stay zero however far eq. 18 scales them.
        let offset = |side: &Side, m: Found| -> [f32; 2] {
            if m.valid() {
                let v = side.flow[m.p];
                [side.w * v[0], side.w * v[1]]
            } else {
                [f32::NAN; 2]
            }
        };
        let [dfx, dfy] = offset(&self.older, f);
        let [dbx, dby] = offset(&self.newer, b);
        let offsets = [dfx, dfy, dbx, dby];
        let code = |dir: Dir| match dir {
            Dir::Forward => Diagnostics::MAIN_OLDER,
            Dir::Backward => Diagnostics::MAIN_NEWER,
        };

        let (f_ok, b_ok) = (f.e < self.tol_e, b.e < self.tol_e);
        if f_ok || b_ok {
            let dir = if f_ok && b_ok {
                if 2.0 * (f.z - b.z).abs() < self.eps_z {
                    // Rule 1: the same surface point; the smaller error (eq. 14 if eᶠ < eᵇ, else
                    // eq. 15).
                    if f.e < b.e {
                        Dir::Forward
                    } else {
                        Dir::Backward
                    }
                } else if f.z > b.z {
                    // Rule 2: different points; the nearer one occludes the other.
                    Dir::Forward
                } else {
                    Dir::Backward
                }
            } else if f_ok {
                Dir::Forward
            } else {
                Dir::Backward
            };
            let m = if dir == Dir::Forward { f } else { b };
            let (rgb, blended) = self.second_chance(dir, m);
            let c = code(dir) | if blended { Diagnostics::BLENDED } else { 0 };
            return (Some((c, round_rgb(rgb), m.e)), offsets);
        }
        // Rule 3: neither search converged; blend what they found (eq. 13).
        let res = match (f.valid(), b.valid()) {
            (true, true) => {
                let rgb = self.blend(self.older.color(f.p), self.newer.color(b.p));
                let dir = if f.e <= b.e {
                    Dir::Forward
                } else {
                    Dir::Backward
                };
                Some((
                    code(dir) | Diagnostics::BLENDED,
                    round_rgb(rgb),
                    f.e.min(b.e),
                ))
            }
            (true, false) => Some((code(Dir::Forward), round_rgb(self.older.color(f.p)), f.e)),
            (false, true) => Some((code(Dir::Backward), round_rgb(self.newer.color(b.p)), b.e)),
            (false, false) => None,
        };
        (res, offsets)
    }
}

#[cfg(test)]
mod tests {
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
            &mut out,
            Some(&mut diag),
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
                let inside =
                    (pos.0..pos.0 + SIDE).contains(&i) && (pos.1..pos.1 + SIDE).contains(&j);
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
        let inside =
            |(x, y): (usize, usize)| (x..x + SIDE).contains(&i) && (y..y + SIDE).contains(&j);
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
            (min_i as f32 - ex).abs() <= 1.0
                && (max_i as f32 - (ex + SIDE as f32 - 1.0)).abs() <= 1.0,
            "x {min_i}..{max_i}, expected {ex}"
        );
        assert!(
            (min_j as f32 - ey).abs() <= 1.0
                && (max_j as f32 - (ey + SIDE as f32 - 1.0)).abs() <= 1.0,
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
        let mut out = vec![0u8; 16 * 12 * 3];
        let request = Request {
            client: camera(16, 12),
            alpha: 0.5,
        };
        let r = run(
            &older.frame(),
            &newer.frame(),
            &request,
            &Params::default(),
            &mut out,
            None,
            None,
        );
        assert!(matches!(r, Err(ReprojError::CameraMismatch(_))));
        assert!(out.iter().all(|&v| v == 0));
        let small = Img {
            cam: camera(16, 12),
            color: vec![0; 16 * 12 * 3],
            depth: vec![0.5; 16 * 12],
            motion: vec![0.0; 16 * 12 * 3],
        };
        let request = Request {
            client: older.cam,
            alpha: 0.5,
        };
        let mut out = vec![0u8; W * H * 3];
        let r = run(
            &older.frame(),
            &small.frame(),
            &request,
            &Params::default(),
            &mut out,
            None,
            None,
        );
        assert!(matches!(r, Err(ReprojError::CameraMismatch(_))));
    }

    #[test]
    fn backward_bidir_same_result_for_1_and_4_threads() {
        let (w, h) = (67, 45);
        let cam = camera(w, h);
        let mut seed = 0x2545_f491_u32;
        let mut rnd = move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed as f32 / u32::MAX as f32
        };
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
}
