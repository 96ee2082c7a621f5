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

use crate::camera::{pixel_of_ndc, NdcTable, Projector};
use crate::error::{ReprojError, Result};
use crate::frame::{CameraView, FrameView, GeometryKey};
use crate::ours::PairCache;
use crate::params::{Params, TILE};
use crate::request::{Diagnostics, Output, Request};
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
/// The same object carries `ours`' pair-level work ([`PairCache`]) and this method's full flows
/// of the pair: despite the name (kept for the API), it is the client's history for one
/// server-frame pair, whatever the method.
#[derive(Debug, Clone, Default)]
pub struct BidirHistory {
    width: usize,
    height: usize,
    alpha: f32,
    /// Per output pixel: `dᶠ.x, dᶠ.y, dᵇ.x, dᵇ.y` (NDC); NaN where that search found nothing.
    offsets: Vec<[f32; 4]>,
    /// `ours`' per-pair state.
    ours: PairCache,
    /// `backward_bidir`'s full flows of the pair, and a spare buffer for the offsets.
    flows: PairFlows,
}

/// The full flows `Vᶠ`, `Vᵇ` of a server-frame pair (pass 1 of [`run`]), kept in the history
/// for the pair's next client frames: they depend on the two frames alone, not on `α`, and were
/// a sixth of a 1280×720 frame's time. Also a spare buffer for the next frame's offsets (it
/// reads the previous frame's), so that no frame allocates and first-touches the 37 MB of flows
/// and offsets at that size.
#[derive(Debug, Clone, Default)]
struct PairFlows {
    /// What `vf` and `vb` were computed from; `None`: nothing (a new or reset history).
    key: Option<FlowKey>,
    vf: Vec<[f32; 3]>,
    vb: Vec<[f32; 3]>,
    spare: Vec<[f32; 4]>,
}

/// What the full flows depend on: the two main cameras' [`CameraView::geometry_key`] (older,
/// newer), as [`PairCache`] keys `ours`' pair state.
type FlowKey = [GeometryKey; 2];

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
        let mut flows = std::mem::take(&mut self.flows);
        flows.key = None;
        flows.spare = std::mem::take(&mut self.offsets);
        *self = Self {
            ours,
            flows,
            ..Self::default()
        };
    }

    /// `ours`' pair-level state.
    pub(crate) fn pair_cache(&mut self) -> &mut PairCache {
        &mut self.ours
    }

    /// How many times the pair-level state of `ours`, `ours_extrapolate` or `forward_splat` was
    /// computed into this history ([`crate::prepare_pair`], or lazily by
    /// [`crate::reproject()`] when the history did not hold the call's pair); not reset by
    /// [`BidirHistory::reset`].
    pub fn pair_builds(&self) -> u64 {
        self.ours.builds()
    }

    /// `α₀` of the stored B-frame, or `None` when the history is empty.
    pub fn alpha(&self) -> Option<f32> {
        (!self.offsets.is_empty()).then_some(self.alpha)
    }

    /// Whether the stored offsets apply to a `width × height` output at a later `alpha`.
    fn usable(&self, width: usize, height: usize, alpha: f32) -> bool {
        !self.offsets.is_empty()
            && self.width == width
            && self.height == height
            && self.offsets.len() == width * height
            && self.alpha.is_finite()
            && self.alpha < alpha
    }
}

/// Runs `backward_bidir`: synthesises the B-frame at `α ∈ [0, 1]` between `older` (`I_t` with its
/// forward motion `O_{t→t+1}`) and `newer` (`I_{t+1}` with its backward motion `O_{t+1→t}`).
/// See the module docs for the algorithm.
///
/// Only the main cameras are used. Every output pixel is written unless neither search found a
/// valid source pixel (invalid depth or motion everywhere it looked); those keep the previous
/// client frame. `out.diag` receives [`Diagnostics::MAIN_OLDER`]/[`Diagnostics::MAIN_NEWER`] for the
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
/// does not match its camera (also checked by [`crate::reproject()`]). Nothing is written to `out`
/// or `history` on error.
pub fn run(
    older: &FrameView,
    newer: &FrameView,
    request: &Request,
    params: &Params,
    out: Output,
    mut history: Option<&mut BidirHistory>,
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
    out.check(w, h)?;
    let op = ov.camera.projector("older.main camera")?;
    let np = nv.camera.projector("newer.main camera")?;

    // Nothing can fail from here on: the history's buffers are taken and given back at the end.
    let n = w * h;
    // `prev`: the previous frame's offsets; `a0`: its α where they apply (eqs. 18, 19).
    let (mut flows, prev, a0) = match history.as_deref_mut() {
        Some(hist) => {
            let a0 = hist.usable(w, h, alpha).then_some(hist.alpha);
            let offsets = std::mem::take(&mut hist.offsets);
            (std::mem::take(&mut hist.flows), offsets, a0)
        }
        None => (PairFlows::default(), Vec::new(), None),
    };

    // Pass 1: full flows Vᶠ (older → newer camera) and Vᵇ (newer → older camera), once per pair.
    let key = [ov.geometry_key(), nv.geometry_key()];
    if flows.key.as_ref() != Some(&key) {
        full_flow(&ov, &op, &np, &mut flows.vf);
        full_flow(&nv, &np, &op, &mut flows.vb);
        flows.key = Some(key);
    }

    // Pass 2: per output pixel, in row blocks of TILE rows. Every offset is written (`resize`
    // also shortens a longer spare).
    let mut offsets = std::mem::take(&mut flows.spare);
    offsets.resize(n, [f32::NAN; 4]);
    {
        let (vf, vb) = (&flows.vf, &flows.vb);
        let latest = a0.map(|a0| Latest {
            offsets: &prev,
            // α₀ = 0 stores zero forward offsets, which carry no motion and cannot be scaled.
            scale_f: (a0 > 0.0).then(|| alpha / a0),
            scale_b: (1.0 - alpha) / (1.0 - a0),
        });
        let ctx = Bidir::new([(ov, vf), (nv, vb)], alpha, params, latest);
        match out.diag {
            Some(d) => out
                .image
                .par_chunks_mut(TILE * w * 3)
                .zip(offsets.par_chunks_mut(TILE * w))
                .zip(d.source.par_chunks_mut(TILE * w))
                .zip(d.error.par_chunks_mut(TILE * w))
                .enumerate()
                .for_each(|(b, (((o, off), s), e))| {
                    ctx.resolve_rows(b * TILE, o, off, Some((s, e)))
                }),
            None => out
                .image
                .par_chunks_mut(TILE * w * 3)
                .zip(offsets.par_chunks_mut(TILE * w))
                .enumerate()
                .for_each(|(b, (o, off))| ctx.resolve_rows(b * TILE, o, off, None)),
        }
    }
    if let Some(hist) = history {
        let ours = std::mem::take(&mut hist.ours);
        // The previous offsets' buffer becomes the next frame's.
        flows.spare = prev;
        *hist = BidirHistory {
            width: w,
            height: h,
            alpha,
            offsets,
            ours,
            flows,
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
/// `[Δx, Δy, ΔZ]` per pixel into `flow` (resized; every entry written); NaN for invalid pixels.
fn full_flow(view: &CameraView, from: &Projector, to: &Projector, flow: &mut Vec<[f32; 3]>) {
    let w = from.width;
    flow.resize(w * from.height, [f32::NAN; 3]);
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
    q: Px,
    e: f32,
    z: f32,
}

/// A pixel of the server images: its column, row and flat index `j·W + i`.
#[derive(Debug, Clone, Copy)]
struct Px {
    i: usize,
    j: usize,
    p: usize,
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
    /// The NDC of the pixel centres: a search's pixel is kept as its column and row, so that its
    /// NDC needs no division of the flat index.
    ndc: NdcTable,
}

impl<'a> Bidir<'a> {
    /// The context at `alpha` for the two I-frames (of the same size) with their full flows:
    /// `[(older, Vᶠ), (newer, Vᵇ)]`.
    fn new(
        [(ov, vf), (nv, vb)]: [(CameraView<'a>, &'a [[f32; 3]]); 2],
        alpha: f32,
        params: &Params,
        latest: Option<Latest<'a>>,
    ) -> Bidir<'a> {
        let (w, h) = (ov.camera.width, ov.camera.height);
        let short = w.min(h) as f32;
        Bidir {
            older: Side {
                view: ov,
                flow: vf,
                w: alpha,
            },
            newer: Side {
                view: nv,
                flow: vb,
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
            ndc: NdcTable::new(w, h),
        }
    }
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

    /// The pixel containing NDC `(x, y)` ([`pixel_of_ndc`]).
    #[inline(always)]
    fn pixel(&self, x: f32, y: f32) -> Option<Px> {
        pixel_of_ndc(x, y, self.width, self.height).map(|(i, j)| Px {
            i,
            j,
            p: j * self.width + i,
        })
    }

    /// NDC of the centre of pixel `q` (the same values as
    /// [`ndc_of_pixel`](crate::camera::ndc_of_pixel)).
    #[inline(always)]
    fn ndc(&self, q: Px) -> [f32; 2] {
        self.ndc.at(q.i, q.j)
    }

    /// The iterative search of seeds/001 eqs. 5 / 9 in `side` from `p0`: `p ← pix(T − w·V[p].xy)`,
    /// keeping `p` when the step leaves the image (or `V[p]` is invalid), then the depth (eq. 6/11)
    /// and aspect-scaled error (eq. 7/12) of the final point.
    #[inline]
    fn search(&self, side: &Side, t: [f32; 2], p0: Px) -> Found {
        let mut q = p0;
        let mut v = side.flow[q.p];
        for _ in 0..self.iterations {
            // A step that stays on `q` (or leaves the image) would do so at every later one: the
            // step depends on `q` alone.
            match self.pixel(t[0] - side.w * v[0], t[1] - side.w * v[1]) {
                Some(next) if next.p != q.p => {
                    q = next;
                    v = side.flow[q.p];
                }
                _ => break,
            }
        }
        let [px, py] = self.ndc(q);
        let ex = (px + side.w * v[0] - t[0]) * self.scale[0];
        let ey = (py + side.w * v[1] - t[1]) * self.scale[1];
        let e = (ex * ex + ey * ey).sqrt();
        let z = side.view.depth[q.p] + side.w * v[2];
        if e.is_finite() && z.is_finite() {
            Found { q, e, z }
        } else {
            Found {
                q,
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
        let mut best = self.search(side, t, Px { i, j, p: tp });
        // The initial pixels searched so far. A search depends on its initial pixel alone, and
        // `better` is antisymmetric (never both `better(a, b)` and `better(b, a)`, nor
        // `better(a, a)`), so a result found again can never replace `best`: its search is
        // skipped. The dual and latest-frame guesses often fall on `T`'s own pixel.
        let mut tried = [tp, usize::MAX];
        let mut consider = |p0: Px| {
            if tried.contains(&p0.p) {
                return;
            }
            tried[1] = p0.p;
            let c = self.search(side, t, p0);
            if self.better(&c, &best) {
                best = c;
            }
        };
        // Dual initialisation (eqs. 16, 17): the opposing frame's velocity at T, scaled to this
        // side's time distance, guesses where the point was before this frame's flow is known.
        let vo = other.flow[tp];
        if let Some(p0) = self.pixel(t[0] + side.w * vo[0], t[1] + side.w * vo[1]) {
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
    fn latest_init(&self, dir: Dir, side: &Side, i: usize, j: usize, t: [f32; 2]) -> Option<Px> {
        let latest = self.latest.as_ref()?;
        let (scale, k) = match dir {
            Dir::Forward => (latest.scale_f?, 0),
            Dir::Backward => (latest.scale_b, 2),
        };
        let mut best: Option<(f32, Px)> = None;
        // The pixel whose depth was loaded last. Neighbours' offsets are nearly equal where the
        // motion is smooth, so most of the nine land on the same pixel; one already weighed has
        // the same depth, which cannot win (ties keep the first), so its loads are skipped.
        let mut last = usize::MAX;
        for qj in j.saturating_sub(1)..=(j + 1).min(self.height - 1) {
            for qi in i.saturating_sub(1)..=(i + 1).min(self.width - 1) {
                let d = latest.offsets[qj * self.width + qi];
                let Some(p0) = self.pixel(t[0] - scale * d[k], t[1] - scale * d[k + 1]) else {
                    continue; // NaN offsets land here too
                };
                if p0.p == last {
                    continue;
                }
                last = p0.p;
                let z = side.view.depth[p0.p] + side.w * side.flow[p0.p][2];
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
        let base = side.color(m.q.p);
        let v = side.flow[m.q.p];
        let [x, y] = self.ndc(m.q);
        let Some(q) = self.pixel(x + v[0], y + v[1]).map(|q| q.p) else {
            return (base, false);
        };
        let zq = other.view.depth[q];
        let predicted = side.view.depth[m.q.p] + v[2];
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
        let t = self.ndc.at(i, j);
        let f = self.direction(Dir::Forward, i, j, t);
        let b = self.direction(Dir::Backward, i, j, t);
        // The offset d_m = w·V[p_m].xy of eq. 5 / 9, i.e. T − p for the converged continuous
        // position p. Storing it rather than T − p̄_m (the pixel centre) keeps the sub-pixel
        // motion: early B-frames move less than half a pixel, and snapped offsets would be zero
        // there and stay zero however far eq. 18 scales them.
        let offset = |side: &Side, m: Found| -> [f32; 2] {
            if m.valid() {
                let v = side.flow[m.q.p];
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
                let rgb = self.blend(self.older.color(f.q.p), self.newer.color(b.q.p));
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
            (true, false) => Some((code(Dir::Forward), round_rgb(self.older.color(f.q.p)), f.e)),
            (false, true) => Some((code(Dir::Backward), round_rgb(self.newer.color(b.q.p)), b.e)),
            (false, false) => None,
        };
        (res, offsets)
    }
}

#[cfg(test)]
mod tests;
