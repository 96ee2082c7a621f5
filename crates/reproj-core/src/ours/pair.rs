//! The pair-level work of `ours` ([`PairCache`]): what does not depend on the client pose or α,
//! done once per server-frame pair. Algorithm 2's correspondences (seeds/000 §3.1) from the full
//! scene flows of eqs. 2 and 3, with the motion-cancel and depth checks of §3.5
//! (`‖M_full_s(p) + M_full_o(q)‖ < ε_O`), the auxiliary points' visibility in the main camera
//! (§3.5 rule 2), and the colours Algorithm 2 blends, packed per pixel for the colour stage.

use rayon::prelude::*;

#[cfg(test)]
use crate::camera::pixel_of_ndc;
use crate::camera::{pixel_index_of_ndc, NdcTransfer, Projector};
use crate::frame::{CameraView, GeometryKey};
use crate::params::{Params, TILE};

use super::{packed_cell, unpack_pixel, Mode, Src, SrcRow, NO_SPLAT};
use crate::simd::{prefetch, simd_dispatch};

/// What `ours` computes once per server-frame pair and reuses for every client frame between the
/// two server frames (12 at 120/10 Hz): none of it depends on the client pose or `α`.
///
/// Per source image (main and auxiliary cameras of both frames):
/// - Algorithm 2's correspondence: the pixel `q` of the same camera in the other frame that the
///   full scene flow (eqs. 2, 3) of each pixel `p` lands on, kept only where the motions cancel
///   (`‖M_full_s(p) + M_full_o(q)‖ < ε_O`) and the depths agree (`< ε_z`, `ε_z·4` for the
///   auxiliary cameras);
/// - for the auxiliary cameras, whether each point is visible in the main camera (§3.5 rule 2);
/// - each pixel's colour beside its partner's colour (`texel`), so that the colour stage reads
///   one value per match.
///
/// The cache recomputes itself when the cameras, the buffers (depth, motion, colour and shadow
/// bits, by address and length) or the
/// parameters it depends on change, so a new pair is never served stale data. A caller that
/// rewrites the *same* buffers in place with a new frame must reset it
/// ([`crate::BidirHistory::reset`]).
#[derive(Debug, Default, Clone)]
pub struct PairCache {
    pub(super) key: Option<PairKey>,
    pub(super) sources: Vec<PairSource>,
    /// How many times the state was computed ([`PairCache::builds`]).
    builds: u64,
}

/// The pair-level state of one source image ([`PairCache`]).
#[derive(Debug, Default, Clone)]
pub(super) struct PairSource {
    /// Packed pixel index `q` in the other frame, or [`NO_SPLAT`]; empty when nothing blends.
    pub(super) partner: Vec<u32>,
    /// Auxiliary sources: 1 where the point is visible in main, else 0; empty for main sources.
    pub(super) vis: Vec<u8>,
    /// Which chunks of each row move ([`moving_chunks`](super::pass1::moving_chunks)), so that
    /// pass 1 reads the motion of those only; empty when the source has no motion.
    pub(super) moving: Vec<u8>,
    /// What the colour stage reads of each pixel, in one load ([`texel`]): its colour, its
    /// partner's colour and which of the two Algorithm 2 takes. Without it the stage loaded the
    /// colour, the shadow bits and the partner of the match, then (depending on the partner) the
    /// partner's colour and shadow bits: five loads from five arrays, two of them dependent.
    pub(super) texel: Vec<u64>,
}

/// [`texel`]: the pixel's own colour alone (no partner, no shadow bits).
pub(super) const TEXEL_OWN: u8 = 0;
/// [`texel`]: blended with the partner's colour (no shadow bits on either).
pub(super) const TEXEL_BLEND: u8 = 1;
/// [`texel`]: the pixel or its partner carries shadow bits; the colour stage takes the full path
/// (`Resolve::second_chance`), whose shadows depend on α.
pub(super) const TEXEL_SHADOW: u8 = 2;

/// The texel of a pixel with colour `own`, its partner's colour `other` (zero without one) and
/// `kind` ([`TEXEL_OWN`], [`TEXEL_BLEND`] or [`TEXEL_SHADOW`]): bytes `r, g, b, kind, r', g', b', 0`
/// of a little-endian `u64`.
#[inline(always)]
pub(super) fn texel(own: [u8; 3], kind: u8, other: [u8; 3]) -> u64 {
    u64::from_le_bytes([
        own[0], own[1], own[2], kind, other[0], other[1], other[2], 0,
    ])
}

/// What a [`PairCache`]'s contents depend on.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct PairKey {
    mode: Mode,
    blends: bool,
    /// `ε_z`, `ε_O`, the auxiliary threshold scale, as bits.
    eps: [u32; 3],
    /// Per source.
    sources: Vec<SourceKey>,
}

/// What a [`PairKey`] records of one source: its camera matrix, size, and the depth and motion
/// buffers' addresses and lengths ([`CameraView::geometry_key`]).
#[derive(Debug, Clone, PartialEq)]
struct SourceKey {
    geometry: GeometryKey,
    /// The colour and shadow-bit buffers' addresses and lengths (the texels copy them).
    colours: [usize; 4],
}

impl PairKey {
    pub(super) fn of(sources: &[Src], mode: Mode, params: &Params, blends: bool) -> PairKey {
        PairKey {
            mode,
            blends,
            eps: [
                params.eps_z.to_bits(),
                params.eps_o.to_bits(),
                params.aux_threshold_scale.to_bits(),
            ],
            sources: sources
                .iter()
                .map(|s| {
                    let v = &s.view;
                    let (bp, bl) = v
                        .shadow
                        .map_or((0, 0), |sh| (sh.bits.as_ptr() as usize, sh.bits.len()));
                    SourceKey {
                        geometry: v.geometry_key(),
                        colours: [v.color.as_ptr() as usize, v.color.len(), bp, bl],
                    }
                })
                .collect(),
        }
    }
}

thread_local! {
    /// The buffers of a [`PairCache`] for calls without one (see BUFFER_POOL on page faults).
    pub(super) static PAIR_POOL: std::cell::RefCell<PairCache> = std::cell::RefCell::new(PairCache::default());
    /// Full scene flows while a [`PairCache`] is computed, reused.
    static FULL_POOL: std::cell::RefCell<Vec<Vec<[f32; 4]>>> = const { std::cell::RefCell::new(Vec::new()) };
}

impl PairCache {
    /// An empty cache.
    pub fn new() -> PairCache {
        PairCache::default()
    }

    /// Forgets the pair (its buffers are kept for the next one, and the count of
    /// [`PairCache::builds`] goes on).
    pub fn reset(&mut self) {
        self.key = None;
    }

    /// How many times this cache has computed its state (for a first pair or a changed one), so
    /// that a caller can see whether a call did pair-level work.
    pub fn builds(&self) -> u64 {
        self.builds
    }

    /// Fills the cache for `sources` (in the order of [`run`](super::run): (older, newer) per camera when
    /// `blends`); `vis_ctx[k]` is set for the auxiliary sources.
    pub(super) fn compute(
        &mut self,
        sources: &[Src],
        vis_ctx: &[Option<VisCtx>],
        blends: bool,
        params: &Params,
    ) {
        self.builds += 1;
        self.sources.resize_with(sources.len(), PairSource::default);
        // Every source at once (each with parallel rows inside), as pass 1 of `run`.
        self.sources
            .par_iter_mut()
            .zip(sources.par_iter().zip(vis_ctx.par_iter()))
            .for_each(|(ps, (src, ctx))| {
                match ctx {
                    Some(ctx) => visible_in_main_flags(src, ctx, &mut ps.vis),
                    None => ps.vis.clear(),
                }
                match src.view.motion {
                    Some(mo) => super::pass1::moving_chunks(
                        mo,
                        src.proj.width,
                        src.proj.height,
                        &mut ps.moving,
                    ),
                    None => ps.moving.clear(),
                }
            });
        if !blends {
            self.sources.iter_mut().for_each(|ps| ps.partner.clear());
            self.sources
                .par_iter_mut()
                .zip(sources.par_iter())
                .for_each(|(ps, s)| texels(s, None, &mut ps.texel));
            return;
        }
        let mut fulls = FULL_POOL.with(|p| std::mem::take(&mut *p.borrow_mut()));
        fulls.resize_with(sources.len(), Vec::new);
        fulls
            .par_iter_mut()
            .zip(sources.par_iter())
            .for_each(|(full, src)| {
                let other = src.other.as_ref().expect("blending sources come in pairs");
                let ctx = FullCtx {
                    to_other: other.to_other,
                    ow: other.proj.width,
                    oh: other.proj.height,
                };
                full_flows(src, &ctx, full);
            });
        let eps_o2 = params.eps_o * params.eps_o;
        self.sources.par_iter_mut().enumerate().for_each(|(k, ps)| {
            let (s, o) = (&sources[k], &sources[k ^ 1]);
            let (s_full, o_full) = (&fulls[k], &fulls[k ^ 1]);
            let eps_z = if s.camera == 0 {
                params.eps_z
            } else {
                params.eps_z_aux()
            };
            let ctx = CorrCtx {
                s_depth: s.view.depth,
                o_full,
                o_depth: o.view.depth,
                ow: o.proj.width,
                eps_o2,
                eps_z,
            };
            let block = TILE * s.proj.width;
            ps.partner.resize(s.proj.width * s.proj.height, NO_SPLAT);
            ps.partner
                .par_chunks_mut(block)
                .zip(s_full.par_chunks(block))
                .enumerate()
                .for_each(|(b, (out, full))| correspondence_row(&ctx, b * block, full, out));
        });
        FULL_POOL.with(|p| *p.borrow_mut() = fulls);
        let mut texel_bufs: Vec<Vec<u64>> = self
            .sources
            .iter_mut()
            .map(|ps| std::mem::take(&mut ps.texel))
            .collect();
        let partners: Vec<&[u32]> = self.sources.iter().map(|ps| &ps.partner[..]).collect();
        texel_bufs
            .par_iter_mut()
            .enumerate()
            .for_each(|(k, t)| texels(&sources[k], Some((partners[k], &sources[k ^ 1])), t));
        for (ps, t) in self.sources.iter_mut().zip(texel_bufs) {
            ps.texel = t;
        }
    }
}

/// The [`texel`] of every pixel of `s`, with its partners `q` in `o` when blending.
///
/// Row by row in three loops, each without a test of which buffers exist: the own colours, then
/// the partners' colours and kinds, then the own shadow bits (a pixel with shadow bits, its own or
/// its partner's, takes [`TEXEL_SHADOW`] whatever else the texel holds). One loop per pixel with
/// those tests inside cost ~90 instructions per pixel, half the pair's other work.
pub(super) fn texels(s: &Src, blend: Option<(&[u32], &Src)>, out: &mut Vec<u64>) {
    let sw = s.proj.width;
    out.resize(sw * s.proj.height, 0);
    let own_bits = s.view.shadow.map(|sh| sh.bits);
    let other = blend.map(|(partner, o)| (partner, o.view.color, o.view.shadow.map(|sh| sh.bits)));
    out.par_chunks_mut(sw).enumerate().for_each(|(j, row)| {
        let r = j * sw..(j + 1) * sw;
        let colours = s.view.color[3 * r.start..3 * r.end].chunks_exact(3);
        for (t, c) in row.iter_mut().zip(colours) {
            *t = texel([c[0], c[1], c[2]], TEXEL_OWN, [0; 3]);
        }
        if let Some((partner, oc, ob)) = other {
            let partner = &partner[r.clone()];
            // The partners' colours and shadow bits are scattered over the other image: the
            // lines of every sixteenth are asked for before the row's loop reads them (the loop
            // went slower with the requests inside it). NO_SPLAT is past both: no request.
            for &q in partner.iter().step_by(16) {
                if let Some(c) = oc.get(3 * q as usize) {
                    prefetch(c);
                }
                if let Some(b) = ob.and_then(|b| b.get(q as usize)) {
                    prefetch(b);
                }
            }
            for (t, &q) in row.iter_mut().zip(partner) {
                if q != NO_SPLAT {
                    let q = q as usize;
                    let kind = if ob.is_some_and(|b| b[q] != 0) {
                        TEXEL_SHADOW
                    } else {
                        TEXEL_BLEND
                    };
                    *t |= texel([0; 3], kind, [oc[3 * q], oc[3 * q + 1], oc[3 * q + 2]]);
                }
            }
        }
        if let Some(bits) = own_bits {
            const KIND: u64 = 0xFF << 24;
            for (t, &b) in row.iter_mut().zip(&bits[r]) {
                if b != 0 {
                    *t = (*t & !KIND) | u64::from(TEXEL_SHADOW) << 24;
                }
            }
        }
    });
}

/// The full scene flow of every pixel of `src` into the other frame ([`full_flow_row`]).
fn full_flows(src: &Src, ctx: &FullCtx, full: &mut Vec<[f32; 4]>) {
    let (sw, sh) = (src.proj.width, src.proj.height);
    full.resize(sw * sh, [f32::NAN; 4]);
    let view = src.view;
    full.par_chunks_mut(sw).enumerate().for_each(|(j, row)| {
        let depth = &view.depth[j * sw..(j + 1) * sw];
        let motion = view.motion.map(|m| &m[3 * j * sw..3 * (j + 1) * sw]);
        full_flow_row(SrcRow { j, sw, sh }, depth, motion, ctx, row);
    });
}

/// Whether each point of auxiliary source `src` is visible in the main camera (§3.5 rule 2),
/// tested at the source's time and at the other frame's time: 1 or 0 per pixel.
///
/// Row by row in two stages per test: where the row's points land in the main camera
/// ([`main_landing_row`]: two transfers' arithmetic and three divisions per point, without
/// branches, so that it vectorises), then the main depth at those pixels ([`not_occluded`], one
/// load each). One test per point with early returns (`visible_in`, now the tests' reference)
/// ran as scalar code: on one thread at 1280×720 (courtyard), the extrapolation pair (one test
/// per point) took 5.9–6.5 ms with it and 2.7–2.9 ms with these stages, the interpolation pair
/// 53.1–53.3 and 48.9–49.6 ms.
fn visible_in_main_flags(src: &Src, ctx: &VisCtx, vis: &mut Vec<u8>) {
    let (sw, sh) = (src.proj.width, src.proj.height);
    vis.resize(sw * sh, 0);
    let view = src.view;
    let tests = [(&ctx.same, false), (&ctx.other, true)];
    vis.par_chunks_mut(sw).enumerate().for_each_init(
        || (vec![NO_SPLAT; sw], vec![0.0f32; sw]),
        |(idx, cz), (j, row)| {
            row.fill(0);
            let r = j * sw..(j + 1) * sw;
            let input = LandingInput {
                x: &src.ndc.x,
                y: src.ndc.y[j],
                depth: &view.depth[r.clone()],
                motion: view.motion.map(|m| &m[3 * r.start..3 * r.end]),
            };
            for (test, moved) in tests {
                let Some((mv, mp, t)) = test else { continue };
                main_landing_row(&input, moved, t, (mp.width, mp.height), idx, cz);
                not_occluded(idx, cz, mv.depth, ctx.eps_z, row);
            }
        },
    );
}

/// The second stage of [`visible_in_main_flags`]: `v[i] |= 1` where point `i` landed in the
/// main camera (`idx[i]`, [`main_landing_row`]) and main saw nothing nearer there (larger reversed
/// depth) by more than `eps_z` (NDC units).
#[inline]
fn not_occluded(idx: &[u32], cz: &[f32], main_depth: &[f32], eps_z: f32, v: &mut [u8]) {
    for (v, (&q, &z)) in v.iter_mut().zip(idx.iter().zip(cz)) {
        if q != NO_SPLAT {
            let zm = main_depth[q as usize];
            *v |= u8::from(!(2.0 * (zm - z) > eps_z));
        }
    }
}

/// For the tests: whether each point of an auxiliary source row (NDC x `x`, y `y`, `depth`,
/// `motion`, optionally `moved` by it) is visible in a main camera of `size` with `main_depth`,
/// as [`visible_in_main_flags`] finds it, and as [`visible_in`] does point by point.
#[cfg(test)]
#[allow(clippy::too_many_arguments)]
pub(super) fn visibility_row_and_reference(
    x: &[f32],
    y: f32,
    depth: &[f32],
    motion: Option<&[f32]>,
    moved: bool,
    t: &NdcTransfer,
    size: (usize, usize),
    main_depth: &[f32],
    eps_z: f32,
) -> [Vec<bool>; 2] {
    let n = depth.len();
    let (mut idx, mut cz, mut v) = (vec![0; n], vec![0.0; n], vec![0u8; n]);
    let input = LandingInput {
        x,
        y,
        depth,
        motion,
    };
    main_landing_row(&input, moved, t, size, &mut idx, &mut cz);
    not_occluded(&idx, &cz, main_depth, eps_z, &mut v);
    let reference = (0..n).map(|i| {
        let o = motion.map_or([0.0; 3], |m| [m[3 * i], m[3 * i + 1], m[3 * i + 2]]);
        let c = if moved {
            [x[i] + o[0], y + o[1], depth[i] + o[2]]
        } else {
            [x[i], y, depth[i]]
        };
        visible_in(main_depth, size, t.clip(c), eps_z)
    });
    [v.iter().map(|&b| b != 0).collect(), reference.collect()]
}

/// One auxiliary source row for [`main_landing_row`]: the NDC x of its columns, the row's NDC
/// y, and its depths and motions (3 per point).
struct LandingInput<'a> {
    x: &'a [f32],
    y: f32,
    depth: &'a [f32],
    motion: Option<&'a [f32]>,
}

simd_dispatch! {
    /// Where the points of an auxiliary source row land in a main camera of `size` (whose
    /// transfer from the source's NDC is `t`), as the per-point test `visible_in` finds it:
    /// `idx[i]` the main pixel (row-major) where the point is in front of the camera and strictly
    /// inside its frustum, else [`NO_SPLAT`], and `cz[i]` its main NDC depth. `moved`: the point
    /// moved by its object motion first (`X + O`, +0 without motion), as at the other frame's
    /// time.
    fn main_landing_row / main_landing_row_avx2, main_landing_row_avx512 => main_landing_row_impl(
        input: &LandingInput,
        moved: bool,
        t: &NdcTransfer,
        size: (usize, usize),
        idx: &mut [u32],
        cz: &mut [f32],
    )
}

#[inline(always)]
fn main_landing_row_impl(
    input: &LandingInput,
    moved: bool,
    t: &NdcTransfer,
    (mw, mh): (usize, usize),
    idx: &mut [u32],
    cz: &mut [f32],
) {
    let (wf, hf) = (mw as i32 as f32, mh as i32 as f32);
    let y = input.y;
    let n = input.depth.len();
    let (xs, zs, idx, cz) = (&input.x[..n], input.depth, &mut idx[..n], &mut cz[..n]);
    // The arithmetic of `visible_in` without its early returns: every test is computed, and a
    // point that fails one gets no pixel.
    let land = |c: [f32; 3]| -> (u32, f32) {
        let h = t.clip(c);
        let c = [h[0] / h[3], h[1] / h[3], h[2] / h[3]];
        let (inside, q) = pixel_index_of_ndc(c[0], c[1], wf, hf, mw as u32);
        let ok = (h[3] > 0.0)
            & (c[0].abs() < FRUSTUM_LIMIT)
            & (c[1].abs() < FRUSTUM_LIMIT)
            & (c[2] > 0.0)
            & (c[2] < 1.0)
            & inside;
        (if ok { q } else { NO_SPLAT }, c[2])
    };
    let out = idx.iter_mut().zip(cz.iter_mut());
    match (input.motion, moved) {
        (Some(mo), true) => {
            for ((d, z), ((x, z0), o)) in out.zip(xs.iter().zip(zs).zip(mo.chunks_exact(3))) {
                (*d, *z) = land([x + o[0], y + o[1], z0 + o[2]]);
            }
        }
        // Without motion the moved point is `X + 0`, as in the per-point test (a depth of −0
        // becomes +0).
        (None, true) => {
            for ((d, z), (x, z0)) in out.zip(xs.iter().zip(zs)) {
                (*d, *z) = land([x + 0.0, y + 0.0, z0 + 0.0]);
            }
        }
        (_, false) => {
            for ((d, z), (x, z0)) in out.zip(xs.iter().zip(zs)) {
                (*d, *z) = land([*x, y, *z0]);
            }
        }
    }
}

/// "Inside the frustum" for the visibility test: strictly within ±0.999 in NDC x and y, as the
/// reference.
const FRUSTUM_LIMIT: f32 = 0.999;

/// What "visible in main" is tested against for an auxiliary source.
pub(super) struct VisCtx<'a> {
    /// The main camera at the source's time, and the transfer from the source's NDC to it.
    pub(super) same: Option<(CameraView<'a>, Projector, NdcTransfer)>,
    /// The main camera at the other frame's time (bidirectional only).
    pub(super) other: Option<(CameraView<'a>, Projector, NdcTransfer)>,
    pub(super) eps_z: f32,
}

/// Whether the point with clip coordinates `h` in the main camera is inside its frustum
/// (strictly inside ±0.999, as the reference) and not behind its depth buffer by more than `eps_z`
/// (NDC units). The tests' reference for [`visible_in_main_flags`].
#[cfg(test)]
fn visible_in(main_depth: &[f32], (w, h_px): (usize, usize), h: [f32; 4], eps_z: f32) -> bool {
    if !(h[3] > 0.0) {
        return false;
    }
    let c = [h[0] / h[3], h[1] / h[3], h[2] / h[3]];
    let lim = FRUSTUM_LIMIT;
    if !(c[0].abs() < lim && c[1].abs() < lim && c[2] > 0.0 && c[2] < 1.0) {
        return false;
    }
    match pixel_of_ndc(c[0], c[1], w, h_px) {
        Some((i, j)) => {
            let zm = main_depth[j * w + i];
            // Occluded when main saw something nearer (larger reversed depth) at that pixel.
            !(2.0 * (zm - c[2]) > eps_z)
        }
        None => false,
    }
}

/// The full scene flow of a source into the same camera at the other frame's time (eqs. 2, 3),
/// for Algorithm 2: the transfer and the other camera's size.
struct FullCtx {
    to_other: NdcTransfer,
    ow: usize,
    oh: usize,
}

simd_dispatch! {
    /// The full scene flow of one source row (eqs. 2, 3): `[Δx, Δy, ΔZ, q]` with `q` the packed
    /// pixel ([`pack_pixel`](super::pack_pixel)) it lands on in the other camera, stored as `f32` bits
    /// ([`NO_SPLAT`] outside the image); NaN flow where invalid. [`correspondence`] reads it for
    /// the chosen match; computing every pixel with vector instructions is cheaper than two
    /// scalar evaluations per match.
    fn full_flow_row / full_flow_row_avx2, full_flow_row_avx512 => full_flow_row_impl(
        row: SrcRow,
        depth: &[f32],
        motion: Option<&[f32]>,
        ctx: &FullCtx,
        out: &mut [[f32; 4]],
    )
}

#[inline(always)]
fn full_flow_row_impl(
    row: SrcRow,
    depth: &[f32],
    motion: Option<&[f32]>,
    ctx: &FullCtx,
    out: &mut [[f32; 4]],
) {
    let k = FullRow::new(row, ctx);
    let Some(mo) = motion else {
        return full_span(&k, 0, depth, None, out);
    };
    // As in `flow_row`: runs of still chunks (every motion bit clear) skip loading, deinterleaving
    // and adding the motion, with the same bytes (`full_point` of the same values): 24.3 -> 22.6 M
    // instructions in time_ours's `PREPARE=only` at 640 (AVX2, 1 thread).
    let mut s = 0;
    while s < row.sw {
        let (e, moving) = super::pass1::motion_run(mo, s, row.sw, None);
        let m = moving.then_some(&mo[3 * s..3 * e]);
        full_span(&k, s, &depth[s..e], m, &mut out[s..e]);
        s = e;
    }
}

/// [`full_flow_row`] for the points `i0..` of a row with depths `depth`: [`full_point`] with
/// their `motion`, or +0 where it is `None`.
#[inline(always)]
fn full_span(k: &FullRow, i0: usize, depth: &[f32], motion: Option<&[f32]>, out: &mut [[f32; 4]]) {
    // The column as i32 from the start (sides are at most MAX_SIDE): from `i0 + i` in usize the
    // compiler kept two vectors of 64-bit lanes, 2.0 M instructions more in that run.
    let cols = i0 as i32..;
    match motion {
        Some(mo) => {
            for (i, (d, (z, o))) in
                cols.zip(out.iter_mut().zip(depth.iter().zip(mo.chunks_exact(3))))
            {
                *d = full_point(k, i, *z, [o[0], o[1], o[2]]);
            }
        }
        None => {
            for (i, (d, z)) in cols.zip(out.iter_mut().zip(depth)) {
                *d = full_point(k, i, *z, [0.0; 3]);
            }
        }
    }
}

/// For the tests: [`full_flow_row`] of a source row into a camera of `ow × oh`, and the same row
/// point by point through [`full_point`] with each point's motion (+0 without `motion`).
#[cfg(test)]
pub(super) fn full_flow_row_and_general(
    row: SrcRow,
    depth: &[f32],
    motion: Option<&[f32]>,
    to_other: &NdcTransfer,
    (ow, oh): (usize, usize),
) -> [Vec<[f32; 4]>; 2] {
    let ctx = FullCtx {
        to_other: *to_other,
        ow,
        oh,
    };
    let mut fast = vec![[0.0; 4]; row.sw];
    full_flow_row(row, depth, motion, &ctx, &mut fast);
    let k = FullRow::new(row, &ctx);
    let general = (0..row.sw)
        .map(|i| {
            let o = motion.map_or([0.0; 3], |m| [m[3 * i], m[3 * i + 1], m[3 * i + 2]]);
            full_point(&k, i as i32, depth[i], o)
        })
        .collect();
    [fast, general]
}

/// What [`full_point`] needs of its row: the row's NDC y, the source width and the other camera's
/// size as floats, and the transfer to the other camera.
struct FullRow {
    y: f32,
    wf: f32,
    owf: f32,
    ohf: f32,
    to_other: NdcTransfer,
}

impl FullRow {
    #[inline(always)]
    fn new(row: SrcRow, ctx: &FullCtx) -> FullRow {
        FullRow {
            y: row.ndc_y(),
            wf: row.sw as i32 as f32,
            owf: ctx.ow as i32 as f32,
            ohf: ctx.oh as i32 as f32,
            to_other: ctx.to_other,
        }
    }
}

/// One entry of [`full_flow_row`].
#[inline(always)]
fn full_point(k: &FullRow, i: i32, z: f32, o: [f32; 3]) -> [f32; 4] {
    let (y, wf, owf, ohf) = (k.y, k.wf, k.owf, k.ohf);
    let x = (2 * i + 1) as f32 / wf - 1.0;
    let c = [x + o[0], y + o[1], z + o[2]];
    let h = k.to_other.clip(c);
    let iw = 1.0 / h[3];
    let f = [h[0] * iw - x, h[1] * iw - y, h[2] * iw - z];
    let ok = h[3] > 0.0 && f[0].is_finite() && f[1].is_finite() && f[2].is_finite();
    // The pixel the point lands on in the other camera (`pixel_of_ndc` without branches).
    let fx = (x + f[0] + 1.0) * 0.5 * owf;
    let fy = (1.0 - (y + f[1])) * 0.5 * ohf;
    let inside = fx >= 0.0 && fy >= 0.0 && fx < owf && fy < ohf;
    let q = packed_cell(inside, fx, fy);
    if ok {
        [
            f[0],
            f[1],
            f[2],
            f32::from_bits(if inside { q } else { NO_SPLAT }),
        ]
    } else {
        [f32::NAN, f32::NAN, f32::NAN, f32::from_bits(NO_SPLAT)]
    }
}

/// What [`correspondence_row`] reads besides the source's full flows: the source's depth, the
/// other frame's full flows, depth and width, and the thresholds `ε_O²` and `ε_z`.
struct CorrCtx<'a> {
    s_depth: &'a [f32],
    o_full: &'a [[f32; 4]],
    o_depth: &'a [f32],
    ow: usize,
    eps_o2: f32,
    eps_z: f32,
}

/// How many points ahead of the one it computes [`correspondence_row`] asks for the lines of the
/// other frame's full flow and depth at that point's partner. Those loads are gathers (at `q`, not
/// `p`) from buffers far larger than the caches, and the processor does not fetch them ahead by
/// itself: a line-level profile put 35 % of the stage's samples on the load of the other full
/// flow. On one thread at 1280×720 (courtyard), asking 32 points ahead took the stage from 21 to
/// 17 ms, 128 to 15 ms, 256–1024 to 14.5–15 ms; asking also for the source's own full flows and
/// depths, which are read in order, changed nothing.
const PREFETCH_AHEAD: usize = 256;

/// Algorithm 2's partners ([`correspondence`]) of the source points `p0..p0 + out.len()`, whose
/// full flows are `full` ([`full_flow_row`]).
fn correspondence_row(ctx: &CorrCtx, p0: usize, full: &[[f32; 4]], out: &mut [u32]) {
    let depth = &ctx.s_depth[p0..p0 + out.len()];
    for (i, ((o, ms), z)) in out.iter_mut().zip(full).zip(depth).enumerate() {
        // A line holds four full flows and sixteen depths; a partner's neighbours are usually
        // the next point's partners. NO_SPLAT unpacks to a pixel past the image: no request.
        if i % 4 == 0 {
            if let Some(ahead) = full.get(i + PREFETCH_AHEAD) {
                let (qi, qj) = unpack_pixel(ahead[3].to_bits());
                let q = qj * ctx.ow + qi;
                if let Some(f) = ctx.o_full.get(q) {
                    prefetch(f);
                }
                if i % 16 == 0 {
                    if let Some(d) = ctx.o_depth.get(q) {
                        prefetch(d);
                    }
                }
            }
        }
        *o = correspondence(ctx, *ms, *z);
    }
}

/// The correspondence of a source point at depth `z` with full flow `ms` (Algorithm 2): the
/// pixel `q` of the other frame that its full scene flow (eqs. 2, 3) lands on, where the motions
/// cancel (`‖M_full_s(p) + M_full_o(q)‖ < ε_O`, z in [−1,1]-NDC units, so 2·ΔZ) and the depths
/// agree (`2·|Z_o(q) − P.z| < ε_z`, `P.z` the predicted depth); else [`NO_SPLAT`], also when the
/// point leaves the other image or either flow is invalid.
#[inline(always)]
fn correspondence(ctx: &CorrCtx, ms: [f32; 4], z: f32) -> u32 {
    let qk = ms[3].to_bits();
    if qk == NO_SPLAT {
        return NO_SPLAT;
    }
    let (qi, qj) = unpack_pixel(qk);
    let q = qj * ctx.ow + qi;
    let (zq, mo) = (ctx.o_depth[q], ctx.o_full[q]);
    // NaN elsewhere in `mo` (an invalid point) fails the threshold test below.
    if !(zq.is_finite() && mo[0].is_finite()) {
        return NO_SPLAT;
    }
    let pz = z + ms[2];
    let m = [ms[0] + mo[0], ms[1] + mo[1], ms[2] + mo[2]];
    if m[0] * m[0] + m[1] * m[1] + 4.0 * m[2] * m[2] < ctx.eps_o2
        && 2.0 * (zq - pz).abs() < ctx.eps_z
    {
        q as u32
    } else {
        NO_SPLAT
    }
}
