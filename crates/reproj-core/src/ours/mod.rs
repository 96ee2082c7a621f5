//! `ours` (seeds/000 §3.5) and `forward_splat`: splat-initialised fixed-point search at the client
//! pose, best-match selection (Algorithm 1), second-chance blending (Algorithm 2), auxiliary
//! cameras, dynamic shadows and extrapolation.
//!
//! One client frame runs in two passes:
//! 1. **Scene flow and splatting**, per source image (main and auxiliary cameras of the older and
//!    newer frame): every source pixel `p` is moved linearly in world space by its object motion,
//!    `X(w) = X + w·(P⁻¹(p̄ + O[p]) − P⁻¹(p̄))`, and projected into the client camera, giving the
//!    camera flow `M_cam[p] = P_{t+α}(X(w)) − p̄` (eqs. 1, 12, 13; `w = α` for the older and `1−α`
//!    for the newer frame). The point is splatted into a grid over the client image at the source's
//!    resolution with a minimum of the 64-bit key `(depth, source pixel)`, so the nearest point
//!    wins. The 3×3 window search is then done for every cell at once, as a separable minimum
//!    filter over the splat grid ([`window_min`]).
//! 2. **Resolve**, per output pixel over blocks of 16 rows: the nearest splat in the window
//!    initialises the fixed-point iteration `p ← pix(T − M_cam[p])` (eq. 5 with eqs. 12/13), then
//!    the reprojection error and depth (eqs. 7, 8) feed Algorithm 1 per camera, the auxiliary
//!    cameras (searched once per cell of their own grid, and only where the result can reach the
//!    output, see [`AuxGrid`]) are merged (§3.5 rules 1–3), and Algorithm 2 blends in the other
//!    frame for the match that was kept. Each row goes through these steps as stages, each a
//!    short loop over the row's pixels ([`Resolve::resolve_rows`]), so that the dependent loads
//!    of neighbouring pixels overlap and the arithmetic vectorises.
//!
//! What does not depend on the client pose or α — Algorithm 2's correspondences from the full
//! scene flows (eqs. 2, 3) with the motion-cancel check, and the auxiliary points' visibility in
//! main — is computed once per server-frame pair ([`PairCache`], kept in the client's history).
//!
//! The row loops of pass 1 and of the window filter are written without data-dependent branches
//! and run in an AVX2 build on processors that have it (no FMA contraction, so the output bytes do
//! not depend on the processor).
//!
//! Where we differ from the reference implementation on purpose (REFERENCE.md §8):
//! - colours are rounded, not truncated;
//! - points behind the client camera (`w ≤ 0`) are never splatted;
//! - auxiliary grids may have any resolution ratio to the output (cells are found from NDC, not
//!   by integer division), and their error is measured against the output pixel centre the FPI
//!   aims at, not the auxiliary pixel centre;
//! - "visible in main" (§3.5 rule 2) tests the main camera's frustum *and* its depth buffer, at the
//!   source's time and (when both frames are present) at the other frame's time, as the paper says;
//! - `ε_e` keeps its pixel size across resolutions (see [`Params::eps_e`]);
//! - blending happens for every `α < 1`, not only while `round(12α) < 12`.

use std::sync::atomic::{AtomicU8, Ordering};

use rayon::prelude::*;

use crate::camera::{pixel_of_ndc, Camera, NdcTransfer, Projector};
use crate::error::{ReprojError, Result};
use crate::frame::{CameraView, FrameView, ShadowView};
use crate::params::{Params, TILE};
use crate::request::{Diagnostics, Request};
use crate::shadow::{round_rgb4, shadow_color, Role};

/// Defines `$name`, which runs the `#[inline(always)]` function `$imp` compiled for AVX2 (as
/// `$avx`) where the processor has it and for the baseline otherwise. The body is written once;
/// the AVX2 build lets the compiler use 256-bit vectors for its row loops. Neither build contracts
/// multiplies and adds into FMA, so both give the same bytes.
macro_rules! avx2_dispatch {
    ($(#[$doc:meta])* fn $name:ident / $avx:ident => $imp:ident($($arg:ident: $ty:ty),* $(,)?)) => {
        $(#[$doc])*
        #[inline]
        fn $name($($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            {
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the processor supports AVX2 (checked just above).
                    unsafe { $avx($($arg),*) };
                    return;
                }
            }
            $imp($($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        fn $avx($($arg: $ty),*) {
            $imp($($arg),*)
        }
    };
}

/// [`avx2_dispatch`] for a method of [`Resolve`]: `$name` runs the `#[inline(always)]` method
/// `$imp` compiled for AVX2 (as `$avx`) where the processor has it.
macro_rules! avx2_method {
    ($(#[$doc:meta])* fn $name:ident / $avx:ident => $imp:ident(&self, $($arg:ident: $ty:ty),* $(,)?)) => {
        $(#[$doc])*
        #[inline(never)]
        fn $name(&self, $($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            {
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the processor supports AVX2 (checked just above).
                    unsafe { self.$avx($($arg),*) };
                    return;
                }
            }
            self.$imp($($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        fn $avx(&self, $($arg: $ty),*) {
            self.$imp($($arg),*)
        }
    };
}

/// Which pipeline [`run`] executes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Mode {
    /// The full method.
    Ours,
    /// Splat + window search only: no FPI, no shadows, no blending.
    ForwardSplat,
}

/// Short side of the paper's main camera (2560×1440). `ε_e` is given at this resolution.
pub const REFERENCE_SHORT_SIDE: f32 = 1440.0;

/// An empty splat cell: larger than every real key.
pub const EMPTY_SPLAT: u64 = u64::MAX;

/// No splat in the window of a cell (see [`Buffers::init`]).
pub const NO_SPLAT: u32 = u32::MAX;

/// A source pixel `(i, j)` packed as `j << 16 | i` (sides are at most 16384). Packed pixels order
/// like row-major indices, and unpacking needs no division (the splat keys carry them).
#[inline(always)]
pub fn pack_pixel(i: usize, j: usize) -> u32 {
    ((j as u32) << 16) | i as u32
}

/// The `(i, j)` of a pixel packed by [`pack_pixel`].
#[inline(always)]
pub fn unpack_pixel(pk: u32) -> (usize, usize) {
    ((pk & 0xFFFF) as usize, (pk >> 16) as usize)
}

/// The splat key of a point at client reversed depth `z` (`0 ≤ z ≤ 1`) from the source pixel
/// packed as `pk` ([`pack_pixel`]).
///
/// Positive IEEE floats order like their bit patterns, and reversed depth is larger for nearer
/// points, so `!bits` makes the nearest point the smallest key; ties go to the smaller source
/// pixel in row-major order, which keeps the result independent of thread scheduling.
#[inline(always)]
pub fn splat_key(z: f32, pk: u32) -> u64 {
    (u64::from(!z.to_bits()) << 32) | u64::from(pk)
}

/// The packed source pixel stored in a splat key.
#[inline(always)]
pub fn splat_index(key: u64) -> u32 {
    key as u32
}

/// Everything the kernels need of one source image.
struct Src<'a> {
    view: CameraView<'a>,
    proj: Projector,
    /// The same camera in the other frame of the pair, for Algorithm 2.
    other: Option<Other>,
    role: Role,
    /// `0` for main, `1 + i` for auxiliary camera `i`.
    camera: usize,
    /// `(W, H) / min(W, H)`: NDC differences times these are in units where 2 is the short side
    /// (the error of eq. 7, REFERENCE.md §2.5).
    aspect: [f32; 2],
    /// NDC of the pixel centres.
    ndc: NdcTable,
    bufs: Buffers,
}

/// The NDC of every pixel centre of a `W × H` image, by column (x) and by row (y): the same values
/// as [`crate::camera::ndc_of_pixel`], looked up instead of divided for each search.
#[derive(Debug, Clone, Default)]
struct NdcTable {
    x: Vec<f32>,
    y: Vec<f32>,
}

impl NdcTable {
    fn new(w: usize, h: usize) -> NdcTable {
        NdcTable {
            x: (0..w)
                .map(|i| crate::camera::ndc_of_pixel(i, 0, w, h)[0])
                .collect(),
            y: (0..h)
                .map(|j| crate::camera::ndc_of_pixel(0, j, w, h)[1])
                .collect(),
        }
    }

    #[inline(always)]
    fn at(&self, i: usize, j: usize) -> [f32; 2] {
        [self.x[i], self.y[j]]
    }
}

/// The same camera in the other frame of the pair, with the NDC transfer to it (the full scene
/// flow of eqs. 2 and 3, used by Algorithm 2).
#[derive(Debug, Clone, Copy)]
struct Other {
    proj: Projector,
    /// This camera's NDC → the other camera's clip space.
    to_other: NdcTransfer,
}

/// The per-source buffers of one client frame, kept between frames (see [`BUFFER_POOL`]).
#[derive(Debug, Default)]
struct Buffers {
    /// `M_cam`: x, y = the NDC flow to the client; NaN = invalid. Every entry is rewritten by the
    /// splatting pass, so it needs no reset. Kept apart from `zc` so that the fixed-point steps,
    /// which read only the flow, touch half the cache lines.
    flow: Vec<[f32; 2]>,
    /// The client's reversed depth of each point (eq. 8; the source depth plus the z flow, kept
    /// whole); NaN = invalid. Rewritten every frame.
    zc: Vec<f32>,
    /// Splat keys ([`splat_key`]), reset to [`EMPTY_SPLAT`] every frame (band by band, by the
    /// task that splats the band, see [`scene_flow_and_splat`]).
    splat: Vec<u64>,
    /// The window search done for every cell at once ([`window_min`]): the packed source pixel
    /// of the smallest splat key in the `(2W+1)²` window around the cell, or [`NO_SPLAT`].
    /// Every entry is rewritten each frame.
    init: Vec<u32>,
    /// Auxiliary sources only: 1 where a point that is *not* visible in the main camera lands in
    /// the client grid (its splat cell), else 0; reset every frame. An auxiliary match can only
    /// override a main match near such a cell (see [`AuxGrid::maybe`]).
    invisible: Vec<AtomicU8>,
    /// Per block of 16 source rows, the splats that land outside the block's own rows
    /// (see [`scene_flow_and_splat`]).
    spill: Vec<Vec<(u32, u64)>>,
}

/// Source rows per task of the splatting pass. Points that land outside their task's rows are
/// applied after the parallel pass; taller bands leave fewer of them (a vertical flow of `d` rows
/// spills about `d / SPLAT_BAND` of the points).
const SPLAT_BAND: usize = 32;

thread_local! {
    /// Buffers of the previous client frame rendered on this thread, reused by the next one.
    ///
    /// First-touch page faults dominate a fresh 60 MB allocation on virtual machines (measured here:
    /// 0.3 GB/s for a first fill against 12–17 GB/s for a reused buffer), so allocating per frame
    /// would cost more than the reprojection itself. The pool holds at most one frame's worth of
    /// buffers per calling thread (about 24 bytes per source pixel).
    static BUFFER_POOL: std::cell::RefCell<Vec<Buffers>> = const { std::cell::RefCell::new(Vec::new()) };
    /// The auxiliary grids' "may override main" flags, kept for the same reason.
    static AUX_POOL: std::cell::RefCell<Vec<Vec<u8>>> = const { std::cell::RefCell::new(Vec::new()) };
    /// The auxiliary cells resolved by one block of output rows ([`AuxBlock`]), one per camera.
    static AUX_BLOCKS: std::cell::RefCell<Vec<AuxBlock>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The outcome of the search in one source image for one output pixel.
#[derive(Debug, Clone, Copy)]
struct Match {
    /// Source pixel index.
    p: u32,
    /// Reprojection error (eq. 7), aspect-scaled NDC; `INFINITY` when invalid.
    e: f32,
    /// Client reversed depth (eq. 8).
    z: f32,
    /// Visible in the main camera (only meaningful for auxiliary sources).
    vis: bool,
}

/// Output cell `(i, j)` of a `gw × gh` grid that a search aims at.
#[derive(Debug, Clone, Copy)]
struct Cell {
    i: usize,
    j: usize,
    gw: usize,
    gh: usize,
}

/// A per-camera decision of Algorithm 1: which source (index into the source list) and its match,
/// plus the other side's match when both correspond to the same point.
#[derive(Debug, Clone, Copy)]
struct Choice {
    src: usize,
    m: Match,
    visible_in_main: bool,
}

/// Runs `ours` or `forward_splat`. `older = None` (or `α ≥ 1`) means unidirectional from `newer`.
pub(crate) fn run<'a>(
    mode: Mode,
    older: Option<&FrameView<'a>>,
    newer: &FrameView<'a>,
    request: &Request,
    params: &Params,
    out: &mut [u8],
    diag: Option<&mut Diagnostics>,
    pair: Option<&mut PairCache>,
) -> Result<()> {
    let alpha = request.alpha;
    request.client.projector("client camera")?;
    let older = if alpha < 1.0 { older } else { None };
    let bidirectional = older.is_some();
    let use_aux = params.use_aux;

    let mut pool = BUFFER_POOL.with(|p| std::mem::take(&mut *p.borrow_mut()));
    let mut take = || pool.pop().unwrap_or_default();
    // Projectors of every camera first, so that a singular matrix is reported before any work.
    let mut sources: Vec<Src> = Vec::new();
    let n_aux = if use_aux { newer.aux.len() } else { 0 };
    for cam in 0..=n_aux {
        let pick = |f: &FrameView<'a>| -> CameraView<'a> {
            if cam == 0 {
                f.main
            } else {
                f.aux[cam - 1]
            }
        };
        let name = |which: &str| {
            if cam == 0 {
                format!("{which}.main")
            } else {
                format!("{which}.aux[{}]", cam - 1)
            }
        };
        let nv = pick(newer);
        let np = nv.camera.projector(&name("newer"))?;
        if let Some(o) = older {
            let ov = pick(o);
            let op = ov.camera.projector(&name("older"))?;
            let (n_vp, o_vp) = (nv.camera.view_proj(), ov.camera.view_proj());
            // Both invertible: checked by `projector` above.
            let (n_inv, o_inv) = (n_vp.inverse(), o_vp.inverse());
            let (Some(n_inv), Some(o_inv)) = (n_inv, o_inv) else {
                return Err(ReprojError::SingularMatrix {
                    what: name("older"),
                });
            };
            let o_to_n = NdcTransfer::new(&o_inv, &n_vp);
            let n_to_o = NdcTransfer::new(&n_inv, &o_vp);
            let other_of_o = Other {
                proj: np,
                to_other: o_to_n,
            };
            let other_of_n = Other {
                proj: op,
                to_other: n_to_o,
            };
            sources.push(Src::new(ov, op, Some(other_of_o), Role::Older, cam, take()));
            sources.push(Src::new(nv, np, Some(other_of_n), Role::Newer, cam, take()));
        } else {
            sources.push(Src::new(nv, np, None, Role::Newer, cam, take()));
        }
    }

    // Pass 1: scene flow and splatting. Visibility in main is needed for auxiliary sources only;
    // main sources are 0 and (if bidirectional) 1.
    let n_main = if bidirectional { 2 } else { 1 };
    let mains: Vec<(CameraView, Projector, Role)> = sources[..n_main]
        .iter()
        .map(|s| (s.view, s.proj, s.role))
        .collect();
    let eps_z_aux = params.eps_z * params.aux_threshold_scale;
    let client_vp = request.client.view_proj();
    let mut inverses = Vec::with_capacity(sources.len());
    for src in &sources {
        let Some(inv) = src.view.camera.view_proj().inverse() else {
            return Err(ReprojError::SingularMatrix {
                what: "source camera".into(),
            });
        };
        inverses.push(inv);
    }

    // What does not depend on the client pose or α: computed once per server-frame pair when the
    // caller keeps a `PairCache` for the pair, else for this frame alone.
    let blends = mode == Mode::Ours && params.blend && bidirectional;
    let mut own_pair = None;
    let pair: &mut PairCache = match pair {
        Some(p) => p,
        None => own_pair.insert(PAIR_POOL.with(|p| std::mem::take(&mut *p.borrow_mut()))),
    };
    let key = PairKey::of(&sources, mode, params, blends);
    if pair.key.as_ref() != Some(&key) {
        pair.key = None;
        let to_main = |k: usize, m: &(CameraView<'a>, Projector, Role)| {
            (
                m.0,
                m.1,
                NdcTransfer::new(&inverses[k], &m.0.camera.view_proj()),
            )
        };
        let vis_ctx: Vec<Option<VisCtx>> = sources
            .iter()
            .enumerate()
            .map(|(k, src)| {
                (src.camera > 0).then(|| VisCtx {
                    same: mains
                        .iter()
                        .find(|m| m.2 == src.role)
                        .map(|m| to_main(k, m)),
                    other: mains
                        .iter()
                        .find(|m| m.2 != src.role)
                        .map(|m| to_main(k, m)),
                    eps_z: eps_z_aux,
                })
            })
            .collect();
        pair.compute(&sources, &vis_ctx, blends, params);
        pair.key = Some(key);
    }

    let pair: &PairCache = pair;
    // Every source at once, each with its own parallel bands inside: one wait for the slowest
    // task per frame instead of two per source (the small auxiliary grids have too few bands to
    // keep both cores busy on their own).
    sources.par_iter_mut().enumerate().for_each(|(k, src)| {
        let w = match src.role {
            Role::Older => alpha,
            Role::Newer => 1.0 - alpha,
        };
        let to_client = NdcTransfer::new(&inverses[k], &client_vp);
        let vis = (src.camera > 0).then(|| pair.sources[k].vis.as_slice());
        scene_flow_and_splat(src, &to_client, w, vis);
        window_min(src, params.window);
    });

    // Pass 2: resolve per output tile.
    let (cw, ch) = (request.client.width, request.client.height);
    let eps_scale = REFERENCE_SHORT_SIDE / cw.min(ch) as f32;
    let ctx = Resolve {
        params,
        alpha,
        client_w: cw,
        client_h: ch,
        sources: &sources,
        n_cams: 1 + n_aux,
        bidirectional,
        eps_e: params.eps_e * eps_scale,
        eps_e_aux: params.eps_e * eps_scale * params.aux_threshold_scale,
        eps_z: params.eps_z,
        eps_z_aux,
        iterations: if mode == Mode::Ours {
            params.fpi_iterations
        } else {
            0
        },
        aux: Vec::new(),
        client_ndc: NdcTable::new(cw, ch),
        pair,
        palettes: sources
            .iter()
            .enumerate()
            .map(|(k, s)| Palette {
                color: s.view.color,
                shadow: s
                    .view
                    .shadow
                    .filter(|_| mode == Mode::Ours && params.use_shadows),
                role: s.role,
                partner: if blends {
                    &pair.sources[k].partner
                } else {
                    &[]
                },
                other: k ^ 1,
                omega: match s.role {
                    Role::Older => 1.0 - alpha,
                    Role::Newer => alpha,
                },
            })
            .collect(),
    };
    let mut aux_pool = AUX_POOL.with(|p| std::mem::take(&mut *p.borrow_mut()));
    let aux_grids = (1..ctx.n_cams)
        .map(|cam| ctx.aux_grid(cam, aux_pool.pop().unwrap_or_default()))
        .collect();
    let ctx = Resolve {
        aux: aux_grids,
        ..ctx
    };
    let rows_per_task = TILE;
    match diag {
        Some(d) => out
            .par_chunks_mut(rows_per_task * cw * 3)
            .zip(d.source.par_chunks_mut(rows_per_task * cw))
            .zip(d.error.par_chunks_mut(rows_per_task * cw))
            .enumerate()
            .for_each(|(b, ((o, s), e))| ctx.resolve_rows(b * rows_per_task, o, Some((s, e)))),
        None => out
            .par_chunks_mut(rows_per_task * cw * 3)
            .enumerate()
            .for_each(|(b, o)| ctx.resolve_rows(b * rows_per_task, o, None)),
    }
    // Back to the pools in reverse, so that the next frame pops them in the same order and each
    // source gets a buffer of its own size again.
    aux_pool.extend(ctx.aux.into_iter().rev().map(|g| g.maybe));
    AUX_POOL.with(|p| *p.borrow_mut() = aux_pool);
    for src in sources.into_iter().rev() {
        pool.push(src.bufs);
    }
    BUFFER_POOL.with(|p| *p.borrow_mut() = pool);
    if let Some(mut own) = own_pair {
        // Kept for its buffers only: without a caller's cache nothing says the next call's
        // frames are the same.
        own.key = None;
        PAIR_POOL.with(|p| *p.borrow_mut() = own);
    }
    Ok(())
}

impl<'a> Src<'a> {
    fn new(
        view: CameraView<'a>,
        proj: Projector,
        other: Option<Other>,
        role: Role,
        camera: usize,
        mut bufs: Buffers,
    ) -> Self {
        let n = view.camera.width * view.camera.height;
        if bufs.flow.len() != n {
            bufs.flow = Vec::new();
            bufs.flow.resize(n, [f32::NAN; 2]);
            bufs.zc = Vec::new();
            bufs.zc.resize(n, f32::NAN);
            bufs.splat = Vec::new();
            bufs.splat.resize(n, EMPTY_SPLAT);
            bufs.init = Vec::new();
            bufs.init.resize(n, NO_SPLAT);
        }
        if camera > 0 {
            if bufs.invisible.len() != n {
                bufs.invisible = Vec::new();
                bufs.invisible.resize_with(n, || AtomicU8::new(0));
            } else {
                // Exclusive access: plain stores, which the compiler turns into a memset (an
                // atomic store per flag would not vectorise). A quarter of a byte per output
                // pixel, so one thread.
                bufs.invisible.iter_mut().for_each(|f| *f.get_mut() = 0);
            }
        }
        let short = view.camera.width.min(view.camera.height) as f32;
        Src {
            view,
            proj,
            other,
            role,
            camera,
            aspect: [
                view.camera.width as f32 / short,
                view.camera.height as f32 / short,
            ],
            ndc: NdcTable::new(view.camera.width, view.camera.height),
            bufs,
        }
    }
}

/// What `ours` computes once per server-frame pair and reuses for every client frame between the
/// two server frames (12 at 120/10 Hz): none of it depends on the client pose or `α`.
///
/// Per source image (main and auxiliary cameras of both frames):
/// - Algorithm 2's correspondence: the pixel `q` of the same camera in the other frame that the
///   full scene flow (eqs. 2, 3) of each pixel `p` lands on, kept only where the motions cancel
///   (`‖M_full_s(p) + M_full_o(q)‖ < ε_O`) and the depths agree (`< ε_z`, `ε_z·4` for the
///   auxiliary cameras);
/// - for the auxiliary cameras, whether each point is visible in the main camera (§3.5 rule 2).
///
/// The cache recomputes itself when the cameras, the buffers (by address and length) or the
/// parameters it depends on change, so a new pair is never served stale data. A caller that
/// rewrites the *same* buffers in place with a new frame must reset it
/// ([`crate::BidirHistory::reset`]).
#[derive(Debug, Default, Clone)]
pub struct PairCache {
    key: Option<PairKey>,
    sources: Vec<PairSource>,
}

/// The pair-level state of one source image ([`PairCache`]).
#[derive(Debug, Default, Clone)]
struct PairSource {
    /// Packed pixel index `q` in the other frame, or [`NO_SPLAT`]; empty when nothing blends.
    partner: Vec<u32>,
    /// Auxiliary sources: 1 where the point is visible in main, else 0; empty for main sources.
    vis: Vec<u8>,
}

/// What a [`PairCache`]'s contents depend on.
#[derive(Debug, Clone, PartialEq)]
struct PairKey {
    mode: Mode,
    blends: bool,
    /// `ε_z`, `ε_O`, the auxiliary threshold scale, as bits.
    eps: [u32; 3],
    /// Per source.
    sources: Vec<SourceKey>,
}

/// What a [`PairKey`] records of one source: its camera matrix, size, and the depth and motion
/// buffers' addresses and lengths.
#[derive(Debug, Clone, PartialEq)]
struct SourceKey {
    view_proj: [[f64; 4]; 4],
    size: [usize; 2],
    buffers: [usize; 4],
}

impl PairKey {
    fn of(sources: &[Src], mode: Mode, params: &Params, blends: bool) -> PairKey {
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
                    let (mp, ml) = v.motion.map_or((0, 0), |m| (m.as_ptr() as usize, m.len()));
                    SourceKey {
                        view_proj: v.camera.view_proj().0,
                        size: [s.proj.width, s.proj.height],
                        buffers: [v.depth.as_ptr() as usize, v.depth.len(), mp, ml],
                    }
                })
                .collect(),
        }
    }
}

thread_local! {
    /// The buffers of a [`PairCache`] for calls without one (see BUFFER_POOL on page faults).
    static PAIR_POOL: std::cell::RefCell<PairCache> = std::cell::RefCell::new(PairCache::default());
    /// Full scene flows while a [`PairCache`] is computed, reused.
    static FULL_POOL: std::cell::RefCell<Vec<Vec<[f32; 4]>>> = const { std::cell::RefCell::new(Vec::new()) };
}

impl PairCache {
    /// An empty cache.
    pub fn new() -> PairCache {
        PairCache::default()
    }

    /// Forgets the pair (its buffers are kept for the next one).
    pub fn reset(&mut self) {
        self.key = None;
    }

    /// Fills the cache for `sources` (in the order of [`run`]: (older, newer) per camera when
    /// `blends`); `vis_ctx[k]` is set for the auxiliary sources.
    fn compute(
        &mut self,
        sources: &[Src],
        vis_ctx: &[Option<VisCtx>],
        blends: bool,
        params: &Params,
    ) {
        self.sources.resize_with(sources.len(), PairSource::default);
        // Every source at once (each with parallel rows inside), as pass 1 of `run`.
        self.sources
            .par_iter_mut()
            .zip(sources.par_iter().zip(vis_ctx.par_iter()))
            .for_each(|(ps, (src, ctx))| match ctx {
                Some(ctx) => visible_in_main_flags(src, ctx, &mut ps.vis),
                None => ps.vis.clear(),
            });
        if !blends {
            self.sources.iter_mut().for_each(|ps| ps.partner.clear());
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
                params.eps_z * params.aux_threshold_scale
            };
            let n = s.proj.width * s.proj.height;
            ps.partner.resize(n, NO_SPLAT);
            ps.partner
                .par_chunks_mut(TILE * s.proj.width)
                .enumerate()
                .for_each(|(b, chunk)| {
                    let p0 = b * TILE * s.proj.width;
                    for (d, out) in chunk.iter_mut().enumerate() {
                        let p = p0 + d;
                        *out = match correspondence(s, s_full, o, o_full, p) {
                            // ‖M_full_s(p) + M_full_o(q)‖ < ε_O, z in [−1,1]-NDC units (2·ΔZ).
                            Some((q, m, zq, pz))
                                if m[0] * m[0] + m[1] * m[1] + 4.0 * m[2] * m[2] < eps_o2
                                    && 2.0 * (zq - pz).abs() < eps_z =>
                            {
                                q as u32
                            }
                            _ => NO_SPLAT,
                        };
                    }
                });
        });
        FULL_POOL.with(|p| *p.borrow_mut() = fulls);
    }
}

/// The full scene flow of every pixel of `src` into the other frame ([`full_flow_row`]).
fn full_flows(src: &Src, ctx: &FullCtx, full: &mut Vec<[f32; 4]>) {
    let (sw, sh) = (src.proj.width, src.proj.height);
    full.resize(sw * sh, [f32::NAN; 4]);
    let view = src.view;
    full.par_chunks_mut(sw).enumerate().for_each(|(j, row)| {
        let depth = &view.depth[j * sw..(j + 1) * sw];
        let motion = view.motion.map(|m| &m[3 * j * sw..3 * (j + 1) * sw]);
        full_flow_row(j, sw, sh, depth, motion, ctx, row);
    });
}

/// Whether each point of auxiliary source `src` is visible in the main camera (§3.5 rule 2),
/// tested at the source's time and at the other frame's time: 1 or 0 per pixel.
fn visible_in_main_flags(src: &Src, ctx: &VisCtx, vis: &mut Vec<u8>) {
    let (sw, sh) = (src.proj.width, src.proj.height);
    vis.resize(sw * sh, 0);
    let view = src.view;
    vis.par_chunks_mut(sw).enumerate().for_each(|(j, row)| {
        for (i, v) in row.iter_mut().enumerate() {
            let idx = j * sw + i;
            let [x, y] = src.ndc.at(i, j);
            let z = view.depth[idx];
            let o = view.motion_at(idx);
            let c = [x, y, z];
            let c2 = [x + o[0], y + o[1], z + o[2]];
            let visible = ctx
                .same
                .as_ref()
                .is_some_and(|(mv, mp, t)| visible_in(mv, mp, t.clip(c), ctx.eps_z))
                || ctx
                    .other
                    .as_ref()
                    .is_some_and(|(mv, mp, t)| visible_in(mv, mp, t.clip(c2), ctx.eps_z));
            *v = u8::from(visible);
        }
    });
}

/// What "visible in main" is tested against for an auxiliary source.
struct VisCtx<'a> {
    /// The main camera at the source's time, and the transfer from the source's NDC to it.
    same: Option<(CameraView<'a>, Projector, NdcTransfer)>,
    /// The main camera at the other frame's time (bidirectional only).
    other: Option<(CameraView<'a>, Projector, NdcTransfer)>,
    eps_z: f32,
}

/// Whether the point with clip coordinates `h` in the main camera is inside its frustum
/// (strictly inside ±0.999, as the reference) and not behind its depth buffer by more than `eps_z`
/// (NDC units).
#[inline]
fn visible_in(view: &CameraView, proj: &Projector, h: [f32; 4], eps_z: f32) -> bool {
    if !(h[3] > 0.0) {
        return false;
    }
    let c = [h[0] / h[3], h[1] / h[3], h[2] / h[3]];
    const LIM: f32 = 0.999;
    if !(c[0].abs() < LIM && c[1].abs() < LIM && c[2] > 0.0 && c[2] < 1.0) {
        return false;
    }
    match pixel_of_ndc(c[0], c[1], proj.width, proj.height) {
        Some((i, j)) => {
            let zm = view.depth[j * proj.width + i];
            // Occluded when main saw something nearer (larger reversed depth) at that pixel.
            !(2.0 * (zm - c[2]) > eps_z)
        }
        None => false,
    }
}

/// Pass 1 for one source image: `M_cam` (eqs. 1, 12, 13) and the depth-aware splat.
///
/// `w` is the fraction of the object motion applied: `α` for the older frame, `1−α` for the newer
/// one (negative when extrapolating).
fn scene_flow_and_splat(src: &mut Src, to_client: &NdcTransfer, w: f32, vis: Option<&[u8]>) {
    let (sw, sh) = (src.proj.width, src.proj.height);
    let view = src.view;
    let invisible = &src.bufs.invisible;
    let xs = &src.ndc.x;
    // The splat is a minimum per cell, so the order of the updates does not matter. Each task owns
    // the splat cells of its own SPLAT_BAND rows (its band): it resets them (while they are hot
    // in its cache, instead of a separate pass over the grid) and updates them with plain loads
    // and stores. A point that lands in another band is kept aside and applied after the parallel
    // pass, when every band is reset. A `lock cmpxchg` per point would cost more than the point's
    // whole scene flow.
    let block = |b: usize,
                 rows: &mut [[f32; 2]],
                 zrows: &mut [f32],
                 band: &mut [u64],
                 spill: &mut Vec<(u32, u64)>| {
        band.fill(EMPTY_SPLAT);
        spill.clear();
        // Row-major cell indices order like the packed pixels: the band is one range of them.
        let base = (b * SPLAT_BAND * sw) as u32;
        ROW_SCRATCH.with(|cell| {
            let scratch = &mut *cell.borrow_mut();
            scratch.resize(sw);
            for (r, (row, zrow)) in rows.chunks_mut(sw).zip(zrows.chunks_mut(sw)).enumerate() {
                let j = b * SPLAT_BAND + r;
                let depth = &view.depth[j * sw..(j + 1) * sw];
                let motion = view.motion.map(|m| &m[3 * j * sw..(3 * j + 3) * sw]);
                let input = FlowRow {
                    j,
                    sw,
                    sh,
                    x: xs,
                    depth,
                    motion,
                    to_client,
                    w,
                };
                let out = RowOut {
                    flow: row,
                    zc: zrow,
                    cell: &mut scratch.cell,
                    kz: &mut scratch.kz,
                };
                flow_row(input, out);
                row_keys(&scratch.kz, pack_pixel(0, j), &mut scratch.key);
                splat_row(&scratch.cell, &scratch.key, base, band, spill);
                if let Some(vis) = vis {
                    // Auxiliary sources: flag where the points not visible in main land.
                    let v = &vis[j * sw..(j + 1) * sw];
                    landing_row(j, sw, sh, xs, row, v, &mut scratch.inv);
                    for &c in &scratch.inv {
                        if c != NO_SPLAT {
                            // A plain store on x86-64: setting a flag needs no read-modify-write.
                            invisible[c as usize].store(1, Ordering::Relaxed);
                        }
                    }
                }
            }
        });
    };
    // One spill list per block, kept with the buffers (see BUFFER_POOL on page faults).
    let mut spills = std::mem::take(&mut src.bufs.spill);
    spills.resize_with(sh.div_ceil(SPLAT_BAND), Vec::new);
    src.bufs
        .flow
        .par_chunks_mut(SPLAT_BAND * sw)
        .zip(src.bufs.zc.par_chunks_mut(SPLAT_BAND * sw))
        .zip(src.bufs.splat.par_chunks_mut(SPLAT_BAND * sw))
        .zip(spills.par_iter_mut())
        .enumerate()
        .for_each(|(b, (((rows, zrows), band), spill))| block(b, rows, zrows, band, spill));
    // The parallel pass has finished: every band is reset. The spilled points are applied by
    // one task per range of the grid (one per thread), each reading every list and taking the
    // cells of its own range, so that no two tasks write the same cell.
    let parts = rayon::current_num_threads().clamp(1, 16);
    let part = (sw * sh).div_ceil(parts).max(1);
    src.bufs
        .splat
        .par_chunks_mut(part)
        .enumerate()
        .for_each(|(q, cells)| {
            let lo = (q * part) as u32;
            for &(c, key) in spills.iter().flatten() {
                if let Some(s) = cells.get_mut(c.wrapping_sub(lo) as usize) {
                    *s = key_min(*s, key);
                }
            }
        });
    src.bufs.spill = spills;
}

avx2_dispatch! {
    /// The splat keys ([`splat_key`]) of one source row from its key depths `kz` and the packed
    /// pixel of its first point `pk_row` ([`pack_pixel`]). Four keys per vector instruction here,
    /// against four scalar instructions per key in [`splat_row`].
    fn row_keys / row_keys_avx2 => row_keys_impl(kz: &[f32], pk_row: u32, key: &mut [u64])
}

#[inline(always)]
fn row_keys_impl(kz: &[f32], pk_row: u32, key: &mut [u64]) {
    for (i, (k, z)) in key.iter_mut().zip(kz).enumerate() {
        *k = splat_key(*z, pk_row | i as u32);
    }
}

/// Splats one source row whose points' cells and keys are `cell` and `key` ([`RowScratch`]):
/// into `band`, the cells `base..` of the grid, or else onto `spill`.
///
/// A function of its own, not inlined: inside the closure of [`scene_flow_and_splat`] the
/// compiler kept the band's pointer, length and base on the stack and reloaded them for every
/// point.
#[inline(never)]
fn splat_row(cell: &[u32], key: &[u64], base: u32, band: &mut [u64], spill: &mut Vec<(u32, u64)>) {
    for (&c, &key) in cell.iter().zip(key) {
        // NO_SPLAT wraps to beyond every band (grids have fewer than 2³¹ cells).
        let rel = c.wrapping_sub(base) as usize;
        if let Some(s) = band.get_mut(rel) {
            // Only this task writes this band during the parallel pass.
            *s = key_min(*s, key);
        } else if c != NO_SPLAT {
            spill.push((c, key));
        }
    }
}

/// The full scene flow of a source into the same camera at the other frame's time (eqs. 2, 3),
/// for Algorithm 2: the transfer and the other camera's size.
struct FullCtx {
    to_other: NdcTransfer,
    ow: usize,
    oh: usize,
}

avx2_dispatch! {
    /// The full scene flow of one source row (eqs. 2, 3): `[Δx, Δy, ΔZ, q]` with `q` the packed
    /// pixel ([`pack_pixel`]) it lands on in the other camera, stored as `f32` bits
    /// ([`NO_SPLAT`] outside the image); NaN flow where invalid. [`correspondence`] reads it for
    /// the chosen match; computing every pixel with vector instructions is cheaper than two
    /// scalar evaluations per match.
    fn full_flow_row / full_flow_row_avx2 => full_flow_row_impl(
        j: usize,
        sw: usize,
        sh: usize,
        depth: &[f32],
        motion: Option<&[f32]>,
        ctx: &FullCtx,
        out: &mut [[f32; 4]],
    )
}

#[inline(always)]
fn full_flow_row_impl(
    j: usize,
    sw: usize,
    sh: usize,
    depth: &[f32],
    motion: Option<&[f32]>,
    ctx: &FullCtx,
    out: &mut [[f32; 4]],
) {
    let y = crate::camera::ndc_of_pixel(0, j, sw, sh)[1];
    let k = FullRow {
        y,
        wf: sw as i32 as f32,
        owf: ctx.ow as i32 as f32,
        ohf: ctx.oh as i32 as f32,
        to_other: ctx.to_other,
    };
    match motion {
        Some(mo) => {
            for (i, (d, (z, o))) in out
                .iter_mut()
                .zip(depth.iter().zip(mo.chunks_exact(3)))
                .enumerate()
            {
                *d = full_point(&k, i, *z, [o[0], o[1], o[2]]);
            }
        }
        None => {
            for (i, (d, z)) in out.iter_mut().zip(depth).enumerate() {
                *d = full_point(&k, i, *z, [0.0; 3]);
            }
        }
    }
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

/// One entry of [`full_flow_row`].
#[inline(always)]
fn full_point(k: &FullRow, i: usize, z: f32, o: [f32; 3]) -> [f32; 4] {
    let (y, wf, owf, ohf) = (k.y, k.wf, k.owf, k.ohf);
    let x = (2 * i as i32 + 1) as f32 / wf - 1.0;
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

thread_local! {
    /// Splat targets of one source row ([`RowScratch`]), reused.
    static ROW_SCRATCH: std::cell::RefCell<RowScratch> = const {
        std::cell::RefCell::new(RowScratch { cell: Vec::new(), kz: Vec::new(), key: Vec::new(), inv: Vec::new() })
    };
}

/// What [`flow_row`] computes per point of a row besides the flow, for the scalar loop that
/// splats: one array per field, so that the vector loop stores whole registers.
struct RowScratch {
    /// The client cell (row-major index in the source-sized grid) the point splats into, or
    /// [`NO_SPLAT`].
    cell: Vec<u32>,
    /// Its key depth, the `z` of [`splat_key`] (unspecified where `cell` is [`NO_SPLAT`]). The
    /// key itself is put together by [`row_keys`]: 64-bit lanes in [`flow_row`] made the
    /// compiler halve its vector width.
    kz: Vec<f32>,
    /// The splat keys ([`row_keys`]).
    key: Vec<u64>,
    /// Auxiliary sources: the cell the point lands in when it is valid and not visible in the
    /// main camera (whether or not it splats; see [`Buffers::invisible`]), else [`NO_SPLAT`].
    inv: Vec<u32>,
}

impl RowScratch {
    fn resize(&mut self, n: usize) {
        self.cell.resize(n, NO_SPLAT);
        self.kz.resize(n, 0.0);
        self.key.resize(n, EMPTY_SPLAT);
        self.inv.resize(n, NO_SPLAT);
    }
}

/// The inputs of [`flow_row`]: one row `j` of a `sw × sh` source image.
struct FlowRow<'a> {
    j: usize,
    sw: usize,
    sh: usize,
    /// NDC x of the pixel centres ([`NdcTable`]).
    x: &'a [f32],
    depth: &'a [f32],
    /// The row's object motion, `3·sw` values, or `None` for a static frame.
    motion: Option<&'a [f32]>,
    to_client: &'a NdcTransfer,
    w: f32,
}

/// The outputs of [`flow_row`] for one row: `M_cam` and the client depth (written to the
/// source's buffers), and the splat targets ([`RowScratch`]).
struct RowOut<'a> {
    flow: &'a mut [[f32; 2]],
    zc: &'a mut [f32],
    cell: &'a mut [u32],
    kz: &'a mut [f32],
}

avx2_dispatch! {
    /// `M_cam` of one source row (eqs. 1, 12, 13) and where each point splats.
    ///
    /// Written without branches on the data so that the compiler vectorises it; on x86-64 it
    /// runs in an AVX2 build where the processor has it (the same IEEE operations, no FMA
    /// contraction, so the bytes do not depend on the processor).
    fn flow_row / flow_row_avx2 => flow_row_impl(row: FlowRow, out: RowOut)
}

#[inline(always)]
fn flow_row_impl(row: FlowRow, out: RowOut) {
    let FlowRow {
        j,
        sw,
        sh,
        x,
        depth,
        motion,
        to_client,
        w,
    } = row;
    let RowOut { flow, zc, cell, kz } = out;
    let k = PointCtx {
        y: crate::camera::ndc_of_pixel(0, j, sw, sh)[1],
        wf: sw as i32 as f32,
        hf: sh as i32 as f32,
        sw: sw as u32,
        to_client: *to_client,
        w,
    };
    let outs = flow
        .iter_mut()
        .zip(zc.iter_mut())
        .zip(cell.iter_mut())
        .zip(kz.iter_mut());
    let put = |(((f, zo), c), k): (((&mut [f32; 2], &mut f32), &mut u32), &mut f32),
               p: FlowPoint| {
        (*f, *zo, *c, *k) = (p.flow, p.zc, p.cell, p.kz);
    };
    match motion {
        Some(mo) => {
            for (d, (x, (z, o))) in outs.zip(x.iter().zip(depth.iter().zip(mo.chunks_exact(3)))) {
                put(d, flow_point(&k, *x, *z, [o[0], o[1], o[2]]));
            }
        }
        None => {
            for (d, (x, z)) in outs.zip(x.iter().zip(depth)) {
                put(d, flow_point(&k, *x, *z, [0.0; 3]));
            }
        }
    }
}

avx2_dispatch! {
    /// For an auxiliary source, the cell each point of row `j` lands in as the resolve pass sees
    /// it, `pixel_of_ndc(x + M_cam)`, where the point is valid and not visible in the main camera
    /// (`vis`, one byte per pixel, from the pair), else [`NO_SPLAT`] ([`RowScratch::inv`]).
    /// Whether or not the point splats: the FPI can reach points that do not (e.g. nearer than
    /// the client's near plane). Points just outside the grid need no flag: the cells along the
    /// grid's border are always searched.
    fn landing_row / landing_row_avx2 => landing_row_impl(
        j: usize,
        sw: usize,
        sh: usize,
        x: &[f32],
        flow: &[[f32; 2]],
        vis: &[u8],
        inv: &mut [u32],
    )
}

#[inline(always)]
fn landing_row_impl(
    j: usize,
    sw: usize,
    sh: usize,
    x: &[f32],
    flow: &[[f32; 2]],
    vis: &[u8],
    inv: &mut [u32],
) {
    let y = crate::camera::ndc_of_pixel(0, j, sw, sh)[1];
    let (wf, hf) = (sw as i32 as f32, sh as i32 as f32);
    for (d, ((x, f), v)) in inv.iter_mut().zip(x.iter().zip(flow).zip(vis)) {
        // `pixel_of_ndc` without branches; NaN (invalid) flow fails every comparison.
        let fx = (x + f[0] + 1.0) * 0.5 * wf;
        let fy = (1.0 - (y + f[1])) * 0.5 * hf;
        // `&`, not `&&`: short-circuit branches here keep the loop from vectorising.
        let inside = (fx >= 0.0) & (fy >= 0.0) & (fx < wf) & (fy < hf);
        let c = cell_index(inside, fx, fy, sw as u32);
        *d = if inside & (*v == 0) { c } else { NO_SPLAT };
    }
}

/// What [`flow_point`] needs of its row.
struct PointCtx {
    /// NDC y of the row.
    y: f32,
    /// Source width and height as floats.
    wf: f32,
    hf: f32,
    /// Source width.
    sw: u32,
    /// The source → client NDC transfer.
    to_client: NdcTransfer,
    /// The fraction of the object motion applied.
    w: f32,
}

/// What [`flow_point`] gives for one source pixel.
struct FlowPoint {
    /// `M_cam`, NaN when invalid.
    flow: [f32; 2],
    /// The client's reversed depth (eq. 8), NaN when invalid.
    zc: f32,
    /// The splat cell (row-major index) or [`NO_SPLAT`].
    cell: u32,
    /// The key depth ([`RowScratch::kz`]), unspecified without a cell.
    kz: f32,
}

/// `M_cam` of source pixel `(i, y)` (NDC x `x`) with depth `z` and object motion `o` (eqs. 1, 12,
/// 13), the client's reversed depth of the point (eq. 8), and its splat cell and key.
#[inline(always)]
fn flow_point(k: &PointCtx, x: f32, z: f32, o: [f32; 3]) -> FlowPoint {
    let (y, w) = (k.y, k.w);
    let clip = |c: [f32; 3]| k.to_client.clip(c);
    // P_{t+α}(X + w·(X' − X)) = P X + w·(P X' − P X): the world-space blend of eq. 1 done on
    // clip coordinates, each already divided by its world w ([`NdcTransfer::clip`]).
    let a = clip([x, y, z]);
    let b = clip([x + o[0], y + o[1], z + o[2]]);
    let h = [
        a[0] + w * (b[0] - a[0]),
        a[1] + w * (b[1] - a[1]),
        a[2] + w * (b[2] - a[2]),
        a[3] + w * (b[3] - a[3]),
    ];
    let iw = 1.0 / h[3];
    let cc = [h[0] * iw, h[1] * iw, h[2] * iw];
    // Invalid depth or motion never reaches the output (DESIGN.md): NaN or infinite inputs make
    // `cc` or the sum of the motion non-finite (finite motions too large to add up are rejected
    // as well; they lie far outside NDC). Points behind the client camera (or degenerate) have `h.w ≤ 0`.
    let ok = (0.0..=1.0).contains(&z)
        && h[3] > 0.0
        && h[3] < f32::INFINITY
        && cc[0].is_finite()
        && cc[1].is_finite()
        && cc[2].is_finite()
        && (o[0] + o[1] + o[2]).is_finite();
    let (f, zc) = if ok {
        ([cc[0] - x, cc[1] - y], cc[2])
    } else {
        ([f32::NAN; 2], f32::NAN)
    };
    // In front of the client and not nearer than its near plane (with a margin for the f32 round
    // trip of points on it). Points at or beyond the far plane (the background lies at Z = 0) are
    // kept, their key depth clamped to exactly +0 (−0 or negative bits would sort as nearest).
    // The target cell is `pixel_of_ndc` without branches.
    let fx = (cc[0] + 1.0) * 0.5 * k.wf;
    let fy = (1.0 - cc[1]) * 0.5 * k.hf;
    let inside = (fx >= 0.0) & (fy >= 0.0) & (fx < k.wf) & (fy < k.hf);
    let splats = ok & inside & (cc[2] <= 1.0 + 1e-5);
    let kz = if cc[2] > 0.0 { cc[2].min(1.0) } else { 0.0 };
    FlowPoint {
        flow: f,
        zc,
        cell: if splats {
            cell_index(inside, fx, fy, k.sw)
        } else {
            NO_SPLAT
        },
        kz,
    }
}

/// The row-major index `⌊fy⌋·sw + ⌊fx⌋` when `inside` (`0 ≤ fx < sw`, `0 ≤ fy < H`), else an
/// unspecified value the caller discards (see [`packed_cell`]).
#[inline(always)]
fn cell_index(inside: bool, fx: f32, fy: f32, sw: u32) -> u32 {
    let (fx, fy) = if inside { (fx, fy) } else { (0.0, 0.0) };
    // SAFETY: both are in `[0, 2¹⁶)` here (sides are at most 16384), so finite and in i32 range.
    let (qi, qj) = unsafe { (fx.to_int_unchecked::<i32>(), fy.to_int_unchecked::<i32>()) };
    qj as u32 * sw + qi as u32
}

/// The packed cell ([`pack_pixel`]) `(⌊fx⌋, ⌊fy⌋)` when `inside` (`0 ≤ fx < W`, `0 ≤ fy < H`),
/// else an unspecified value the caller discards.
///
/// A saturating `f32 as i32` costs a compare and a blend per lane for NaN and overflow; selecting
/// an in-range value first lets the truncation be the single conversion instruction.
#[inline(always)]
fn packed_cell(inside: bool, fx: f32, fy: f32) -> u32 {
    let (fx, fy) = if inside { (fx, fy) } else { (0.0, 0.0) };
    // SAFETY: both are in `[0, 2¹⁶)` here (sides are at most 16384), so finite and in i32 range.
    let (qi, qj) = unsafe { (fx.to_int_unchecked::<i32>(), fy.to_int_unchecked::<i32>()) };
    ((qj as u32) << 16) | qi as u32
}

thread_local! {
    /// Row minima of one block of [`window_min`], reused across blocks and frames.
    static ROW_MIN: std::cell::RefCell<Vec<u64>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The window search of every cell at once: `init[c]` = the packed source pixel of the smallest
/// splat key in the `(2W+1)²` window around cell `c` (clipped to the grid), or [`NO_SPLAT`].
///
/// Searching per output pixel reads nine keys for each of the two frames; the minimum is
/// separable, so a row pass and a column pass give every cell's answer with about `4W+2`
/// comparisons on sequential memory, and the resolve pass then reads one `u32` per search.
fn window_min(src: &mut Src, wr: usize) {
    let (sw, sh) = (src.proj.width, src.proj.height);
    let splat = &src.bufs.splat;
    src.bufs
        .init
        .par_chunks_mut(TILE * sw)
        .enumerate()
        .for_each(|(b, out)| {
            ROW_MIN
                .with(|cell| window_block(splat, sw, sh, wr, b * TILE, out, &mut cell.borrow_mut()))
        });
}

avx2_dispatch! {
    /// [`window_min`] for the output rows starting at `j0`; `scratch` holds row minima.
    fn window_block / window_block_avx2 => window_block_impl(
        splat: &[u64],
        sw: usize,
        sh: usize,
        wr: usize,
        j0: usize,
        out: &mut [u32],
        scratch: &mut Vec<u64>,
    )
}

#[inline(always)]
fn window_block_impl(
    splat: &[u64],
    sw: usize,
    sh: usize,
    wr: usize,
    j0: usize,
    out: &mut [u32],
    scratch: &mut Vec<u64>,
) {
    let j1 = j0 + out.len() / sw;
    let (lo, hi) = (j0.saturating_sub(wr), (j1 + wr).min(sh));
    // Layout: the horizontal minima of rows lo..hi, then two rows of working space. Every entry
    // is written before it is read, so the buffer needs no fill.
    scratch.resize((hi - lo + 2) * sw, EMPTY_SPLAT);
    let (rows, work) = scratch.split_at_mut((hi - lo) * sw);
    let (acc, tmp) = work.split_at_mut(sw);
    for (r, dst) in rows.chunks_mut(sw).enumerate() {
        let src = &splat[(lo + r) * sw..(lo + r + 1) * sw];
        // Each step widens the minimum by one pixel on both sides; the first reads the grid
        // directly (the default window, wr = 1, needs no copy).
        if wr == 0 {
            dst.copy_from_slice(src);
        } else {
            min3(src, dst);
        }
        for _ in 1..wr {
            tmp.copy_from_slice(dst);
            min3(tmp, dst);
        }
    }
    for (r, o) in out.chunks_mut(sw).enumerate() {
        let j = j0 + r;
        let (a, z) = (j.saturating_sub(wr) - lo, (j + wr).min(sh - 1) - lo);
        let row = |q: usize| &rows[q * sw..(q + 1) * sw];
        // The low half of a key is its packed pixel, and that of EMPTY_SPLAT is NO_SPLAT (packed
        // pixels stay below 2³⁰).
        if z == a + 2 {
            // Three rows (wr = 1 away from the border): one pass, no accumulator.
            for (d, ((x, y), w)) in o.iter_mut().zip(row(a).iter().zip(row(a + 1)).zip(row(z))) {
                *d = splat_index(key_min(key_min(*x, *y), *w));
            }
        } else {
            acc.copy_from_slice(row(a));
            for q in a + 1..=z {
                for (m, v) in acc.iter_mut().zip(row(q)) {
                    *m = key_min(*m, *v);
                }
            }
            for (d, m) in o.iter_mut().zip(acc.iter()) {
                *d = splat_index(*m);
            }
        }
    }
}

/// The smaller of two splat keys ([`splat_key`] or [`EMPTY_SPLAT`]).
///
/// Every such key has its top bit set (the high half is `!z.to_bits()` with `0 ≤ z ≤ 1`, whose
/// bits are below 2³¹), and among integers that share the top bit the signed order is the
/// unsigned one. AVX2 has a signed 64-bit compare but no unsigned one, so comparing as `i64`
/// saves flipping the sign bit of both operands.
#[inline(always)]
fn key_min(a: u64, b: u64) -> u64 {
    (a as i64).min(b as i64) as u64
}

/// `dst[i] = min(src[i−1], src[i], src[i+1])`, clipped at the ends.
#[inline(always)]
fn min3(src: &[u64], dst: &mut [u64]) {
    let n = src.len();
    if n < 2 {
        dst.copy_from_slice(src);
        return;
    }
    dst[0] = key_min(src[0], src[1]);
    dst[n - 1] = key_min(src[n - 2], src[n - 1]);
    for (d, ((a, b), c)) in dst[1..n - 1]
        .iter_mut()
        .zip(src[..n - 2].iter().zip(&src[1..n - 1]).zip(&src[2..]))
    {
        *d = key_min(key_min(*a, *b), *c);
    }
}

/// Read-only context of pass 2.
struct Resolve<'a> {
    params: &'a Params,
    alpha: f32,
    client_w: usize,
    client_h: usize,
    sources: &'a [Src<'a>],
    n_cams: usize,
    bidirectional: bool,
    eps_e: f32,
    eps_e_aux: f32,
    eps_z: f32,
    eps_z_aux: f32,
    iterations: usize,
    /// Per auxiliary camera, its grid over the client image.
    aux: Vec<AuxGrid>,
    /// NDC of the client's pixel centres.
    client_ndc: NdcTable,
    /// The pair-level state (Algorithm 2's correspondences).
    pair: &'a PairCache,
    /// Per source, what its colours need.
    palettes: Vec<Palette<'a>>,
}

/// The auxiliary match of one cell. Its colour (Algorithm 2) is found only where an output pixel
/// takes it: most cells lose to the main camera (§3.5 rule 2).
#[derive(Debug, Clone, Copy)]
struct AuxCell {
    choice: Choice,
}

/// An auxiliary camera's view of the client image discretised at that camera's resolution.
///
/// The auxiliary cameras have a quarter of the main camera's pixels, so searching them once per
/// *output* pixel would repeat the same window search and FPI for the 2×2 output pixels of each
/// cell. A cell is resolved once, aiming at the cell centre (which is also where the reference
/// measures the auxiliary error, REFERENCE.md §2.5), and the output pixels of the cell share it.
///
/// A cell is resolved only where its result can reach the output: where the main camera found no
/// match for one of its pixels, or where [`AuxGrid::maybe`] says it may override a main match. By
/// §3.5 an auxiliary match replaces a main one only when it is not visible in the main camera; its
/// reprojection error is below `ε_e·4`, so the point lies within `R` cells of the cell it matched
/// (see [`Resolve::aux_grid`]), and `maybe` is the grid of cells within `R` of a point that is not
/// visible in main. Elsewhere the search could not change a pixel, and skipping it gives the same
/// bytes as searching every cell.
#[derive(Debug)]
struct AuxGrid {
    w: usize,
    h: usize,
    /// 1 where the cell may override a main match, else 0 (see above).
    maybe: Vec<u8>,
    /// The grid column of each client column (`pixel_of_ndc` is separable), or `u32::MAX`
    /// outside the grid.
    col_of: Vec<u32>,
    /// The grid row of each client row, or `u32::MAX`.
    row_of: Vec<u32>,
    /// The client columns `start..end` that fall in each grid column (`col_of` is monotonic, so
    /// they are contiguous; empty where none do).
    cols_of_cell: Vec<(u32, u32)>,
    /// The client columns that fall in the grid at all.
    covered: std::ops::Range<usize>,
    /// NDC of the cell centres.
    ndc: NdcTable,
}

/// The auxiliary cells resolved while one block of output rows is resolved, for the grid rows
/// `row0..row0 + rows` that the block covers. Blocks resolve their cells independently (a cell on
/// the boundary of two blocks may be searched twice, with the same result), so the output does
/// not depend on how rayon schedules them.
#[derive(Debug, Default)]
struct AuxBlock {
    row0: usize,
    rows: usize,
    /// 0: not searched yet; 1: searched, see `cells`.
    done: Vec<u8>,
    cells: Vec<Option<AuxCell>>,
}

impl AuxBlock {
    /// Prepares for the grid rows that output rows `j0..j1` fall on.
    fn reset(&mut self, grid: &AuxGrid, j0: usize, j1: usize) {
        let rows = grid.row_of[j0..j1].iter().filter(|&&r| r != u32::MAX);
        let (lo, hi) = rows.fold((u32::MAX, 0), |(lo, hi), &r| (lo.min(r), hi.max(r)));
        (self.row0, self.rows) = if lo <= hi {
            (lo as usize, (hi - lo + 1) as usize)
        } else {
            (0, 0)
        };
        let n = self.rows * grid.w;
        self.done.clear();
        self.done.resize(n, 0);
        if self.cells.len() < n {
            self.cells.resize(n, None);
        }
    }
}

/// One output row's searches in one main source ([`Resolve::search_row`]), kept between rows.
#[derive(Debug, Default)]
struct SearchRow {
    /// Per pixel: the packed source pixel while searching.
    pk: Vec<u32>,
    /// The source index of the match, or [`NO_SPLAT`] for no match.
    p: Vec<u32>,
    /// The flow `M_cam` at the current source pixel.
    m: Vec<[f32; 2]>,
    /// Reprojection error (eq. 7), `INFINITY` for no match.
    e: Vec<f32>,
    /// Client reversed depth (eq. 8).
    z: Vec<f32>,
    /// The client depth at the last source pixel, as loaded.
    zg: Vec<f32>,
    /// The pixels whose fixed-point iteration is still moving.
    moving: Vec<u32>,
    /// Where an iteration moves each pixel, or [`NO_SPLAT`] where it stays.
    next: Vec<u32>,
    /// The same for the previous iteration (before the first: the initial pixel).
    prev: Vec<u32>,
    /// Auxiliary sources: whether each match is visible in main (empty for main sources).
    vis: Vec<bool>,
}

impl SearchRow {
    /// The match of target `n` as [`Resolve::search`] returns it.
    #[inline(always)]
    fn found(&self, n: usize) -> Option<Match> {
        (self.p[n] != NO_SPLAT).then(|| Match {
            p: self.p[n],
            e: self.e[n],
            z: self.z[n],
            vis: self.vis.get(n).is_none_or(|&v| v),
        })
    }
}

/// The targets of one [`Resolve::search_row`]: points at NDC `(x[n], y)` in cells `(col(n), j)`
/// of a `gw × gh` grid (the client image or an auxiliary grid).
struct Targets<'a> {
    x: &'a [f32],
    y: f32,
    j: usize,
    gw: usize,
    gh: usize,
    /// The cell column of each target, or `None` when target `n` is in column `n`.
    cols: Option<&'a [u32]>,
}

/// "No source" in [`Picks::src`].
const NO_SOURCE: u8 = u8::MAX;

/// The match each pixel of a row keeps: source index (or [`NO_SOURCE`]), source pixel, error and
/// client depth.
#[derive(Debug, Default)]
struct Picks {
    src: Vec<u8>,
    p: Vec<u32>,
    e: Vec<f32>,
    z: Vec<f32>,
    /// The colour of each kept match ([`Resolve::second_chance`]).
    rgb: Vec<[f32; 4]>,
    /// Scratch of [`Resolve::aux_row`]: which auxiliary grids may matter per pixel, and the list
    /// of pixels where they do.
    need: Vec<u8>,
    list: Vec<u32>,
}

impl Picks {
    fn resize(&mut self, n: usize) {
        self.src.resize(n, NO_SOURCE);
        self.p.resize(n, 0);
        self.e.resize(n, 0.0);
        self.z.resize(n, 0.0);
    }
}

/// The per-row state of [`Resolve::resolve_rows`], kept between rows and frames.
#[derive(Debug, Default)]
struct RowState {
    /// The searches in each main source.
    sides: Vec<SearchRow>,
    picks: Picks,
    aux: AuxRow,
}

/// The auxiliary cells one output row needs searched ([`Resolve::aux_row`]): their grid columns
/// and NDC x, and the searches in the camera's older and newer source.
#[derive(Debug, Default)]
struct AuxRow {
    cols: Vec<u32>,
    x: Vec<f32>,
    sides: [SearchRow; 2],
}

thread_local! {
    /// The row state of [`Resolve::resolve_rows`], reused.
    static ROW_STATE: std::cell::RefCell<RowState> = std::cell::RefCell::new(RowState::default());
}

/// What the colour of a match needs of its source (Algorithm 2 and the dynamic shadows), looked
/// up by source index so that the colour loop does not branch on which source won.
#[derive(Debug, Clone, Copy)]
struct Palette<'a> {
    /// RGB8, `3·W·H` bytes.
    color: &'a [u8],
    /// The dynamic shadows to apply (`None` when absent or not applied).
    shadow: Option<ShadowView<'a>>,
    role: Role,
    /// Algorithm 2's correspondence of each pixel in the other frame ([`PairSource::partner`]);
    /// empty when nothing blends.
    partner: &'a [u32],
    /// The source index of the same camera in the other frame (only read through `partner`).
    other: usize,
    /// ω: the weight of the source's own colour when blending.
    omega: f32,
}

impl Resolve<'_> {
    fn resolve_rows(&self, j0: usize, out: &mut [u8], mut diag: Option<(&mut [u8], &mut [f32])>) {
        let cw = self.client_w;
        let rows = out.len() / (3 * cw);
        let mut blocks = AUX_BLOCKS.with(|b| std::mem::take(&mut *b.borrow_mut()));
        blocks.resize_with(self.aux.len(), AuxBlock::default);
        for (b, grid) in blocks.iter_mut().zip(&self.aux) {
            b.reset(grid, j0, j0 + rows);
        }
        let n_main = if self.bidirectional { 2 } else { 1 };
        let mut scratch = ROW_STATE.with(|b| std::mem::take(&mut *b.borrow_mut()));
        let RowState { sides, picks, aux } = &mut scratch;
        sides.resize_with(n_main, SearchRow::default);
        // Scanlines inside the block of 16 rows: the reads of `init`, `flow` and the colours then
        // run along rows of the sources, a few sequential streams that the hardware prefetcher
        // follows, where a 16×16 tile order starts 16 new rows every 16 pixels.
        //
        // Each row goes through stages, each a loop over the row's pixels: the main camera's
        // searches ([`Resolve::search_row`]), Algorithm 1 for them without branches on the data
        // ([`Resolve::choose_row`]; which frame wins is close to random from pixel to pixel, so
        // a branch on it would be mispredicted about half the time), the auxiliary cameras where
        // they can change the pixel, and the colours (Algorithm 2).
        for r in 0..rows {
            let j = j0 + r;
            let targets = Targets {
                x: &self.client_ndc.x[..cw],
                y: self.client_ndc.y[j],
                j,
                gw: cw,
                gh: self.client_h,
                cols: None,
            };
            for (k, side) in sides.iter_mut().enumerate() {
                self.search_row(k, &targets, side);
            }
            self.choose_row(sides, picks);
            self.aux_row(j, picks, aux, &mut blocks);
            // The colours of the row, then their rounding into the output: the float-to-byte
            // conversions of one pixel no longer wait behind its colour loads.
            picks.rgb.resize(cw, [0.0; 4]);
            for i in 0..cw {
                let src = picks.src[i];
                let local = r * cw + i;
                if src == NO_SOURCE {
                    if let Some((s, err)) = diag.as_mut() {
                        s[local] = Diagnostics::NONE;
                        err[local] = f32::NAN;
                    }
                    continue;
                }
                let (rgb, blended) = self.second_chance(usize::from(src), picks.p[i] as usize);
                picks.rgb[i] = rgb;
                if let Some((s, err)) = diag.as_mut() {
                    s[local] = self.code_of(usize::from(src), blended);
                    err[local] = picks.e[i];
                }
            }
            let row_out = &mut out[3 * r * cw..3 * (r + 1) * cw];
            for ((o, &src), &rgb) in row_out
                .chunks_exact_mut(3)
                .zip(&picks.src[..cw])
                .zip(&picks.rgb[..cw])
            {
                // No match keeps the previous client frame's colour.
                if src != NO_SOURCE {
                    o.copy_from_slice(&round_rgb4(rgb)[..3]);
                }
            }
        }
        ROW_STATE.with(|b| *b.borrow_mut() = scratch);
        AUX_BLOCKS.with(|b| *b.borrow_mut() = blocks);
    }

    avx2_method! {
        /// Algorithm 1 for the main camera over a row, from the searches of
        /// [`Resolve::search_row`]: the same decisions as [`Resolve::choose`], written as selects
        /// (and vectorised by the compiler).
        fn choose_row / choose_row_avx2 => choose_row_impl(&self, sides: &[SearchRow], picks: &mut Picks)
    }

    #[inline(always)]
    fn choose_row_impl(&self, sides: &[SearchRow], picks: &mut Picks) {
        let cw = self.client_w;
        picks.resize(cw);
        let (eps_e, eps_z) = (self.eps_e, self.eps_z);
        // Every slice cut to the row's length, so that the loops need no bounds checks.
        let (src, p, e, z) = (
            &mut picks.src[..cw],
            &mut picks.p[..cw],
            &mut picks.e[..cw],
            &mut picks.z[..cw],
        );
        let f = &sides[0];
        let (ef, zf, pf) = (&f.e[..cw], &f.z[..cw], &f.p[..cw]);
        if !self.bidirectional {
            for i in 0..cw {
                src[i] = if ef[i] < eps_e { 0 } else { NO_SOURCE };
                (p[i], e[i], z[i]) = (pf[i], ef[i], zf[i]);
            }
            return;
        }
        let b = &sides[1];
        let (eb, zb, pb) = (&b.e[..cw], &b.z[..cw], &b.p[..cw]);
        for i in 0..cw {
            let (f_ok, b_ok) = (ef[i] < eps_e, eb[i] < eps_e);
            let both = f_ok & b_ok;
            // No match is `e = ∞` (and NaN depth, which only matters where `both` holds).
            let sim = both & (2.0 * (zf[i] - zb[i]).abs() < eps_z);
            // Both correspond but differ in depth: the nearer (larger reversed depth) occludes.
            // Otherwise the smaller error (which is the only corresponding one if just one does:
            // the other's error is at least ε_e).
            let older = (both & !sim & (zf[i] > zb[i])) | ((!both | sim) & (ef[i] < eb[i]));
            // 0 (older), 1 (newer) or NO_SOURCE (= 0xFF), as arithmetic so that the loop
            // vectorises (nested `if`s became branches).
            src[i] = u8::from(!older) | (u8::from(!(f_ok | b_ok)) * NO_SOURCE);
            p[i] = if older { pf[i] } else { pb[i] };
            e[i] = if older { ef[i] } else { eb[i] };
            z[i] = if older { zf[i] } else { zb[i] };
        }
    }

    /// The auxiliary cameras over a row (§3.5): for the pixels where one can change the result
    /// (main found nothing, or a cell that may override main, see [`AuxGrid`]), the merged
    /// decision of [`Resolve::decide`] replaces the main camera's in `picks`.
    #[inline(never)]
    fn aux_row(&self, j: usize, picks: &mut Picks, batch: &mut AuxRow, blocks: &mut [AuxBlock]) {
        let cw = self.client_w;
        // Per pixel, bit 0: some grid covers it; bit 1: some grid's cell may override main there
        // (set over the client columns of each flagged cell). Then the pixels that need the
        // auxiliary cameras are listed without branches (a branch per pixel on the dilated flags
        // was mispredicted at every edge).
        picks.need.clear();
        picks.need.resize(cw, 0);
        for g in &self.aux {
            let aj = g.row_of[j];
            if aj == u32::MAX || g.covered.is_empty() {
                continue;
            }
            picks.need[g.covered.clone()]
                .iter_mut()
                .for_each(|n| *n |= 1);
            let maybe = &g.maybe[aj as usize * g.w..(aj as usize + 1) * g.w];
            for (&m, &(s, e)) in maybe.iter().zip(&g.cols_of_cell) {
                if m != 0 {
                    picks.need[s as usize..e as usize]
                        .iter_mut()
                        .for_each(|n| *n |= 2);
                }
            }
        }
        let mut list = std::mem::take(&mut picks.list);
        list.resize(cw, 0);
        let mut n = 0;
        for (i, (&need, &src)) in picks.need.iter().zip(&picks.src[..cw]).enumerate() {
            list[n] = i as u32;
            // No main match: any covering grid; else a cell that may override main.
            let bit = if src == NO_SOURCE { 1 } else { 2 };
            n += usize::from(need & bit != 0);
        }
        // The cells these pixels need that the block has not searched yet, searched together
        // per grid (stage by stage, as the main camera's), so that their loads overlap.
        for (g, (grid, block)) in self.aux.iter().zip(blocks.iter_mut()).enumerate() {
            let aj = grid.row_of[j];
            if aj == u32::MAX {
                continue;
            }
            let aj = aj as usize;
            let base = (aj - block.row0) * grid.w;
            batch.cols.clear();
            for &i in &list[..n] {
                let ai = grid.col_of[i as usize];
                if ai == u32::MAX {
                    continue;
                }
                let none = picks.src[i as usize] == NO_SOURCE;
                let c = ai as usize;
                if (none || grid.maybe[aj * grid.w + c] != 0) && block.done[base + c] == 0 {
                    block.done[base + c] = 1;
                    batch.cols.push(ai);
                }
            }
            if batch.cols.is_empty() {
                continue;
            }
            batch.x.clear();
            batch
                .x
                .extend(batch.cols.iter().map(|&c| grid.ndc.x[c as usize]));
            let targets = Targets {
                x: &batch.x,
                y: grid.ndc.y[aj],
                j: aj,
                gw: grid.w,
                gh: grid.h,
                cols: Some(&batch.cols),
            };
            let cam = 1 + g;
            let srcs = if self.bidirectional {
                2 * cam..2 * cam + 2
            } else {
                cam..cam + 1
            };
            for (k, side) in srcs.zip(batch.sides.iter_mut()) {
                self.search_row(k, &targets, side);
            }
            let [f, b] = &batch.sides;
            for (nth, &c) in batch.cols.iter().enumerate() {
                let choice = if self.bidirectional {
                    self.choose(
                        cam,
                        f.found(nth),
                        b.found(nth),
                        self.eps_e_aux,
                        self.eps_z_aux,
                    )
                } else {
                    self.choose(cam, f.found(nth), None, self.eps_e_aux, self.eps_z_aux)
                };
                block.cells[base + c as usize] = choice.map(|choice| AuxCell { choice });
            }
        }
        for &i in &list[..n] {
            let i = i as usize;
            let none = picks.src[i] == NO_SOURCE;
            let main = (!none).then(|| Choice {
                src: usize::from(picks.src[i]),
                m: Match {
                    p: picks.p[i],
                    e: picks.e[i],
                    z: picks.z[i],
                    vis: true,
                },
                // Not read for main choices (only an auxiliary one's decides the merge).
                visible_in_main: true,
            });
            match self.decide(i, j, main, blocks) {
                Some(c) => {
                    // Source indices are below 2·(1 + MAX_AUX) < 255 (`FrameView::validate`).
                    picks.src[i] = c.src as u8;
                    picks.p[i] = c.m.p;
                    picks.e[i] = c.m.e;
                    picks.z[i] = c.m.z;
                }
                None => picks.src[i] = NO_SOURCE,
            }
        }
        picks.list = list;
    }

    avx2_method! {
        /// [`Resolve::search`] in source `k` for every target of a row (the pixels of an output
        /// row for the main camera, the cells an output row needs for an auxiliary one), stage
        /// by stage: the windows' nearest splats and their flows for the whole row, then each
        /// fixed-point iteration for the targets still moving, then the errors and depths.
        ///
        /// The same arithmetic as one search per pixel, in another order. A search is a chain of
        /// dependent loads (init → flow → pixel → flow) of ~100 instructions; done pixel by pixel,
        /// the processor's reorder window holds less than one pixel's work and waits on each load.
        /// Row by row, every stage is a short loop over independent pixels whose loads overlap.
        fn search_row / search_row_avx2 => search_row_impl(&self, k: usize, t: &Targets, row: &mut SearchRow)
    }

    #[inline(always)]
    fn search_row_impl(&self, k: usize, t: &Targets, row: &mut SearchRow) {
        let s = &self.sources[k];
        let (sw, sh) = (s.proj.width, s.proj.height);
        let cw = t.x.len();
        let (tx, ty) = (t.x, t.y);
        let (flow, init) = (&s.bufs.flow[..], &s.bufs.init[..]);
        // Slices of the row's length, written by position (no pushes: their length checks would
        // reload the vectors' lengths on every pixel).
        for v in [&mut row.pk, &mut row.moving, &mut row.next, &mut row.prev] {
            v.resize(cw, 0);
        }
        row.m.resize(cw, [0.0; 2]);
        row.p.resize(cw, 0);
        row.e.resize(cw, 0.0);
        row.z.resize(cw, 0.0);
        row.zg.resize(cw, 0.0);
        let (pks, ms) = (&mut row.pk[..cw], &mut row.m[..cw]);
        // Stage 1: the nearest splat in the window around each pixel's source cell (the same cell
        // when the grids agree, else found from NDC) and its flow.
        let first = |pk: u32| -> (u32, [f32; 2]) {
            if pk == NO_SPLAT {
                (NO_SPLAT, [f32::NAN; 2])
            } else {
                let (pi, pj) = unpack_pixel(pk);
                (pk, flow[pj * sw + pi])
            }
        };
        if (t.gw, t.gh) == (sw, sh) {
            let cells = &init[t.j * sw..(t.j + 1) * sw];
            match t.cols {
                None => {
                    for ((pk, m), &c) in pks.iter_mut().zip(ms.iter_mut()).zip(cells) {
                        (*pk, *m) = first(c);
                    }
                }
                Some(cols) => {
                    for ((pk, m), &c) in pks.iter_mut().zip(ms.iter_mut()).zip(cols) {
                        (*pk, *m) = first(cells[c as usize]);
                    }
                }
            }
        } else {
            for ((pk, m), &x) in pks.iter_mut().zip(ms.iter_mut()).zip(tx) {
                let c = pixel_of_ndc(x, ty, sw, sh).map_or(NO_SPLAT, |(ci, cj)| init[cj * sw + ci]);
                (*pk, *m) = first(c);
            }
        }
        // Stage 2: the fixed-point iteration p ← pix(T − M_cam[p]) (eq. 5 with the flows of eqs.
        // 12/13). Once p maps to itself every further iteration would too, so a pixel leaves the
        // list of moving ones there (most converge after one step).
        let step = |x: f32, pk: &mut u32, m: &mut [f32; 2]| -> bool {
            match pixel_of_ndc(x - m[0], ty - m[1], sw, sh) {
                Some((ni, nj)) if pack_pixel(ni, nj) != *pk => {
                    *pk = pack_pixel(ni, nj);
                    *m = flow[nj * sw + ni];
                    true
                }
                _ => false,
            }
        };
        // While many pixels still move (nearly all do once: the window's nearest splat is
        // usually a neighbour of the fixed point), an iteration is one loop of arithmetic over
        // the whole row without branches (vectorised), then the flow loads for the pixels that
        // moved. Once few move, the rest is done for those alone. A pixel that stopped never
        // moves again, so the list only shrinks.
        let (wf, hf) = (sw as i32 as f32, sh as i32 as f32);
        // `prev[i] != NO_SPLAT`: pixel `i` is still iterating (it has a splat, and moved in the
        // last iteration).
        row.prev[..cw].copy_from_slice(pks);
        let mut n = cw;
        // Whether `moving[..n]` lists the pixels that moved in the last iteration.
        let mut listed = false;
        for it in 0..self.iterations {
            if n == 0 {
                break;
            }
            if 4 * n > cw {
                let (next, prev) = (&mut row.next[..cw], &row.prev[..cw]);
                let (pks_in, ms_in) = (&pks[..cw], &ms[..cw]);
                for i in 0..cw {
                    let (pk, m, x) = (pks_in[i], ms_in[i], tx[i]);
                    // `pixel_of_ndc(x − m.x, ty − m.y)` without branches.
                    let fx = (x - m[0] + 1.0) * 0.5 * wf;
                    let fy = (1.0 - (ty - m[1])) * 0.5 * hf;
                    let inside = fx >= 0.0 && fy >= 0.0 && fx < wf && fy < hf;
                    let c = packed_cell(inside, fx, fy);
                    next[i] = if inside & (prev[i] != NO_SPLAT) & (c != pk) {
                        c
                    } else {
                        NO_SPLAT
                    };
                }
                n = 0;
                if it == 0 {
                    // Nearly every pixel moves in the first iteration: a branch on it is
                    // predictable, and cheaper than listing them.
                    for i in 0..cw {
                        let q = next[i];
                        if q != NO_SPLAT {
                            let (ni, nj) = unpack_pixel(q);
                            pks[i] = q;
                            ms[i] = flow[nj * sw + ni];
                            n += 1;
                        }
                    }
                    listed = false;
                } else {
                    let moving = &mut row.moving[..cw];
                    for (i, &q) in next.iter().enumerate() {
                        // Listed in order: the list is written no faster than read.
                        moving[n] = i as u32;
                        n += usize::from(q != NO_SPLAT);
                    }
                    for &i in &moving[..n] {
                        let i = i as usize;
                        let (ni, nj) = unpack_pixel(next[i]);
                        pks[i] = next[i];
                        ms[i] = flow[nj * sw + ni];
                    }
                    listed = true;
                }
                std::mem::swap(&mut row.next, &mut row.prev);
            } else {
                let moving = &mut row.moving[..cw];
                if !listed {
                    // The pixels that moved in the last whole-row iteration (marked in `prev`).
                    let mut m = 0;
                    for (i, &q) in row.prev[..cw].iter().enumerate() {
                        moving[m] = i as u32;
                        m += usize::from(q != NO_SPLAT);
                    }
                    debug_assert_eq!(m, n);
                    listed = true;
                }
                let mut kept = 0;
                for a in 0..n {
                    let i = moving[a] as usize;
                    moving[kept] = i as u32;
                    kept += usize::from(step(tx[i], &mut pks[i], &mut ms[i]));
                }
                n = kept;
            }
        }
        // Stage 3: the reprojection error and depth (eqs. 7, 8); the packed pixel becomes the
        // source index. The depth loads first, then the arithmetic as one loop without branches.
        let zc = &s.bufs.zc[..];
        let zg = &mut row.zg[..cw];
        for (z, &pk) in zg.iter_mut().zip(pks.iter()) {
            let (pi, pj) = unpack_pixel(pk);
            *z = if pk == NO_SPLAT {
                f32::NAN
            } else {
                zc[pj * sw + pi]
            };
        }
        let (wf, hf) = (sw as i32 as f32, sh as i32 as f32);
        let [ax, ay] = s.aspect;
        // Inputs and outputs in different arrays: an output written back over its input became
        // masked stores, which are slow on some processors.
        let (pks, ms, zg) = (&pks[..cw], &ms[..cw], &zg[..cw]);
        let (es, zs, ps) = (&mut row.e[..cw], &mut row.z[..cw], &mut row.p[..cw]);
        for i in 0..cw {
            let (pk, m, x, z) = (pks[i], ms[i], tx[i], zg[i]);
            let (pi, pj) = ((pk & 0xFFFF) as i32, (pk >> 16) as i32);
            // The pixel centre's NDC as [`crate::camera::ndc_of_pixel`] computes it.
            let px = (2 * pi + 1) as f32 / wf - 1.0;
            let py = 1.0 - (2 * pj + 1) as f32 / hf;
            let ex = (px + m[0] - x) * ax;
            let ey = (py + m[1] - ty) * ay;
            let er = (ex * ex + ey * ey).sqrt();
            let ok = (pk != NO_SPLAT) & er.is_finite() & z.is_finite();
            let p = pj as u32 * sw as u32 + pi as u32;
            es[i] = if ok { er } else { f32::INFINITY };
            zs[i] = if ok { z } else { f32::NAN };
            ps[i] = if ok { p } else { NO_SPLAT };
        }
        // Visibility in main (§3.5 rule 2) matters for the auxiliary sources only (from the pair
        // state); main sources carry no flags.
        let flags = &self.pair.sources[k].vis;
        row.vis.clear();
        if !flags.is_empty() {
            row.vis
                .extend(ps.iter().map(|&p| p == NO_SPLAT || flags[p as usize] != 0));
        }
    }

    /// The window search and fixed-point iteration in source `s` for the output pixel at NDC `t`,
    /// which is cell `cell = (i, j)` of a `gw × gh` grid (the client image or an auxiliary grid).
    #[inline(always)]
    fn search(&self, k: usize, t: [f32; 2], cell: Cell) -> Option<Match> {
        let s = &self.sources[k];
        let (sw, sh) = (s.proj.width, s.proj.height);
        // The source cell containing `t`: the same cell when the grids agree (the usual case, and
        // exact: a pixel centre lies inside its pixel), else found from NDC.
        let (ci, cj) = if (cell.gw, cell.gh) == (sw, sh) {
            (cell.i, cell.j)
        } else {
            pixel_of_ndc(t[0], t[1], sw, sh)?
        };
        // The nearest splat in the window around the cell (precomputed by `window_min`).
        let pk = s.bufs.init[cj * sw + ci];
        if pk == NO_SPLAT {
            return None;
        }
        let (mut pi, mut pj) = unpack_pixel(pk);
        let mut p = pj * sw + pi;
        // Fixed-point iteration p ← pix(T − M_cam[p]) (eq. 5 with the flows of eqs. 12/13). Once
        // p maps to itself every further iteration would too, so stopping there gives the same
        // result as running all of them (most pixels converge after one step).
        let mut m = s.bufs.flow[p];
        for _ in 0..self.iterations {
            match pixel_of_ndc(t[0] - m[0], t[1] - m[1], sw, sh) {
                Some((ni, nj)) if (ni, nj) != (pi, pj) => {
                    (pi, pj) = (ni, nj);
                    p = pj * sw + pi;
                    m = s.bufs.flow[p];
                }
                _ => break,
            }
        }
        let [px, py] = s.ndc.at(pi, pj);
        let ex = (px + m[0] - t[0]) * s.aspect[0];
        let ey = (py + m[1] - t[1]) * s.aspect[1];
        let e = (ex * ex + ey * ey).sqrt();
        let z = s.bufs.zc[p];
        if !(e.is_finite() && z.is_finite()) {
            return None;
        }
        // Visibility in main matters for the auxiliary sources only (from the pair state).
        let vis = self.pair.sources[k].vis.get(p).is_none_or(|&v| v != 0);
        Some(Match {
            p: p as u32,
            e,
            z,
            vis,
        })
    }

    /// Algorithm 1 for camera `cam`: the better of its older and newer match, or `None`.
    #[inline]
    fn best_match(
        &self,
        cam: usize,
        t: [f32; 2],
        cell: Cell,
        eps_e: f32,
        eps_z: f32,
    ) -> Option<Choice> {
        if self.bidirectional {
            let f = self.search(2 * cam, t, cell);
            let b = self.search(2 * cam + 1, t, cell);
            self.choose(cam, f, b, eps_e, eps_z)
        } else {
            self.choose(cam, self.search(cam, t, cell), None, eps_e, eps_z)
        }
    }

    /// Algorithm 1 for camera `cam` from its searches: `f` in the older and `b` in the newer
    /// source when bidirectional, else `f` in the only one.
    #[inline(always)]
    fn choose(
        &self,
        cam: usize,
        f: Option<Match>,
        b: Option<Match>,
        eps_e: f32,
        eps_z: f32,
    ) -> Option<Choice> {
        if self.bidirectional {
            let (fi, bi) = (2 * cam, 2 * cam + 1);
            let ef = f.map_or(f32::INFINITY, |m| m.e);
            let eb = b.map_or(f32::INFINITY, |m| m.e);
            let (f_ok, b_ok) = (ef < eps_e, eb < eps_e);
            if !f_ok && !b_ok {
                return None;
            }
            let both = f_ok && b_ok;
            let (zf, zb) = (f.map_or(0.0, |m| m.z), b.map_or(0.0, |m| m.z));
            let sim = both && 2.0 * (zf - zb).abs() < eps_z;
            // Both correspond but differ in depth: the nearer (larger reversed depth) occludes.
            // Otherwise the smaller error (which is the only corresponding one if just one does).
            let older = (both && !sim && zf > zb) || ((!both || sim) && ef < eb);
            let (src, m, other) = if older { (fi, f?, b) } else { (bi, b?, f) };
            let visible_in_main = m.vis || (sim && other.is_some_and(|o| o.vis));
            Some(Choice {
                src,
                m,
                visible_in_main,
            })
        } else {
            let m = f?;
            (m.e < eps_e).then_some(Choice {
                src: cam,
                m,
                visible_in_main: m.vis,
            })
        }
    }

    /// Colour of the source with palette `pal` at pixel `p`, its dynamic shadow applied at `α`,
    /// as `[r, g, b, 0]`: four lanes, so that the colour stays in one vector register (three
    /// `f32`s went through the stack, and reading them back stalled on store forwarding).
    #[inline(always)]
    fn color_of(&self, pal: &Palette, p: usize) -> [f32; 4] {
        let base: [u8; 3] = pal.color[3 * p..3 * p + 3]
            .try_into()
            .expect("three channels");
        let c = match pal.shadow {
            // Most pixels carry no dynamic shadow: skip the six shadow-colour loads for them.
            Some(sh) if sh.bits[p] != 0 => {
                let rgb = |b: &[u8]| [b[3 * p], b[3 * p + 1], b[3 * p + 2]];
                shadow_color(
                    base,
                    sh.bits[p],
                    rgb(sh.s_min),
                    rgb(sh.s_max),
                    self.alpha,
                    self.params.shadow_subframes,
                    pal.role,
                )
            }
            _ => base.map(f32::from),
        };
        [c[0], c[1], c[2], 0.0]
    }

    /// Algorithm 2: colour of the match at pixel `p` of source `src`, blended with its
    /// correspondence in the other frame when forward and backward motion cancel and depths
    /// agree (precomputed for the pair, see [`PairCache`]). Returns the colour (as
    /// [`Resolve::color_of`]) and whether it blended.
    #[inline(always)]
    fn second_chance(&self, src: usize, p: usize) -> ([f32; 4], bool) {
        let pal = &self.palettes[src];
        let base = self.color_of(pal, p);
        // `partner` is empty when nothing blends (unidirectional, forward_splat, blending off).
        let q = match pal.partner.get(p) {
            Some(&q) if q != NO_SPLAT => q as usize,
            _ => return (base, false),
        };
        let oc = self.color_of(&self.palettes[pal.other], q);
        let (w, v) = (pal.omega, 1.0 - pal.omega);
        (
            [
                w * base[0] + v * oc[0],
                w * base[1] + v * oc[1],
                w * base[2] + v * oc[2],
                w * base[3] + v * oc[3],
            ],
            true,
        )
    }

    /// The diagnostic code of a match in source `src`.
    fn code_of(&self, src: usize, blended: bool) -> u8 {
        let s = &self.sources[src];
        let code = if s.camera == 0 {
            match s.role {
                Role::Older => Diagnostics::MAIN_OLDER,
                Role::Newer => Diagnostics::MAIN_NEWER,
            }
        } else {
            Diagnostics::AUX_BASE + 2 * (s.camera as u8 - 1) + u8::from(s.role == Role::Newer)
        };
        if blended {
            code | Diagnostics::BLENDED
        } else {
            code
        }
    }

    /// The grid of auxiliary camera `cam` over the client image, with the cells whose match may
    /// override a main match ([`AuxGrid`]); `maybe` is a buffer to reuse.
    fn aux_grid(&self, cam: usize, mut maybe: Vec<u8>) -> AuxGrid {
        // The newer frame's camera is present in both modes; both frames share the rig.
        let grid_src = if self.bidirectional { 2 * cam + 1 } else { cam };
        let (w, h) = (
            self.sources[grid_src].proj.width,
            self.sources[grid_src].proj.height,
        );
        let srcs: &[Src] = if self.bidirectional {
            &self.sources[2 * cam..2 * cam + 2]
        } else {
            &self.sources[cam..cam + 1]
        };
        // An accepted auxiliary match has error e < ε_e·4 (aspect-scaled NDC, eq. 7), so each of
        // its pixel offsets from the cell centre is below r = ε_e·4·min(W, H)/2 source pixels and
        // its point lands within ⌈r⌉ cells of the cell; one more absorbs rounding.
        let same_grid = srcs.iter().all(|s| (s.proj.width, s.proj.height) == (w, h));
        let r = srcs
            .iter()
            .map(|s| self.eps_e_aux * s.proj.width.min(s.proj.height) as f32 / 2.0)
            .fold(0.0f32, f32::max);
        let reach = r.ceil() as usize + 1;
        maybe.clear();
        if !same_grid || !r.is_finite() || reach >= w.min(h) / 2 || eager_aux() {
            // The bound does not apply (or covers everything): search every cell.
            maybe.resize(w * h, 1);
        } else {
            maybe.resize(w * h, 0);
            dilate_flags(srcs, w, h, reach, &mut maybe);
        }
        let (cw, ch) = (self.client_w, self.client_h);
        let lookup = |n: usize, f: &dyn Fn(usize) -> Option<usize>| -> Vec<u32> {
            (0..n)
                .map(|k| f(k).map_or(u32::MAX, |v| v as u32))
                .collect()
        };
        // NDC x of a client pixel centre depends on its column only, y on its row only.
        let col_of = lookup(cw, &|i| {
            pixel_of_ndc(crate::camera::ndc_of_pixel(i, 0, cw, ch)[0], 0.0, w, h).map(|c| c.0)
        });
        let row_of = lookup(ch, &|j| {
            pixel_of_ndc(0.0, crate::camera::ndc_of_pixel(0, j, cw, ch)[1], w, h).map(|c| c.1)
        });
        let mut cols_of_cell = vec![(0u32, 0u32); w];
        let mut covered = cw..0;
        for (i, &c) in col_of.iter().enumerate() {
            if c == u32::MAX {
                continue;
            }
            let r = &mut cols_of_cell[c as usize];
            *r = if r.0 == r.1 {
                (i as u32, i as u32 + 1)
            } else {
                (r.0, i as u32 + 1)
            };
            covered = covered.start.min(i)..covered.end.max(i + 1);
        }
        AuxGrid {
            w,
            h,
            maybe,
            col_of,
            row_of,
            cols_of_cell,
            covered,
            ndc: NdcTable::new(w, h),
        }
    }

    /// Algorithm 1 for auxiliary camera `cam` (`1 + grid index`) at cell `(ai, aj)` of its grid,
    /// searched on first use within the block.
    #[inline]
    fn aux_cell(
        &self,
        cam: usize,
        grid: &AuxGrid,
        block: &mut AuxBlock,
        ai: usize,
        aj: usize,
    ) -> Option<AuxCell> {
        let k = (aj - block.row0) * grid.w + ai;
        if block.done[k] == 0 {
            let t = grid.ndc.at(ai, aj);
            let cell = Cell {
                i: ai,
                j: aj,
                gw: grid.w,
                gh: grid.h,
            };
            block.cells[k] = self
                .best_match(cam, t, cell, self.eps_e_aux, self.eps_z_aux)
                .map(|choice| AuxCell { choice });
            block.done[k] = 1;
        }
        block.cells[k]
    }

    /// The match an output pixel keeps, or `None` for no match: `main` is Algorithm 1's choice
    /// for the main camera ([`Resolve::choose_row`]), merged with the auxiliary cameras' (§3.5).
    #[inline]
    fn decide(
        &self,
        i: usize,
        j: usize,
        main: Option<Choice>,
        blocks: &mut [AuxBlock],
    ) -> Option<Choice> {
        // Best auxiliary match (§3.5): the nearer if depths differ, else the smaller error.
        let mut aux: Option<AuxCell> = None;
        for (g, (grid, block)) in self.aux.iter().zip(blocks.iter_mut()).enumerate() {
            let (ai, aj) = (grid.col_of[i], grid.row_of[j]);
            if ai == u32::MAX || aj == u32::MAX {
                continue;
            }
            let (ai, aj) = (ai as usize, aj as usize);
            // Where main found a match, only a cell that may override it is searched.
            if main.is_some() && grid.maybe[aj * grid.w + ai] == 0 {
                continue;
            }
            if let Some(c) = self.aux_cell(1 + g, grid, block, ai, aj) {
                aux = match aux {
                    None => Some(c),
                    Some(b) => {
                        let sim = 2.0 * (c.choice.m.z - b.choice.m.z).abs() < self.eps_z_aux;
                        if (!sim && c.choice.m.z > b.choice.m.z)
                            || (sim && c.choice.m.e < b.choice.m.e)
                        {
                            Some(c)
                        } else {
                            Some(b)
                        }
                    }
                };
            }
        }
        // Merge with main (§3.5 rules 1–3): main wins unless it found nothing, or the auxiliary
        // point is nearer, at a different depth, and not visible in the main camera.
        let use_aux = match (&main, &aux) {
            (Some(m), Some(a)) => {
                let sim = 2.0 * (a.choice.m.z - m.m.z).abs() < self.eps_z_aux;
                !a.choice.visible_in_main && !sim && a.choice.m.z > m.m.z
            }
            (None, Some(_)) => true,
            (_, None) => false,
        };
        if use_aux {
            aux.map(|a| a.choice)
        } else {
            main
        }
    }
}

#[cfg(test)]
thread_local! {
    /// Tests set this to search every auxiliary cell, the reference the lazy search must equal.
    static EAGER_AUX: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Whether every auxiliary cell is to be searched (tests only).
#[inline]
fn eager_aux() -> bool {
    #[cfg(test)]
    {
        EAGER_AUX.with(|e| e.get())
    }
    #[cfg(not(test))]
    {
        false
    }
}

/// `maybe[c] = 1` for every cell `c` of the `w × h` grid within `reach` cells (Chebyshev distance)
/// of a cell flagged in any source's `invisible` buffer, or within `reach` of the grid's border
/// (points just outside the grid are not flagged); `maybe` arrives zeroed.
fn dilate_flags(srcs: &[Src], w: usize, h: usize, reach: usize, maybe: &mut [u8]) {
    // The flags are 0 or 1, so "any" is a bitwise or; both passes are ors of whole rows (shifted
    // for the row pass), which vectorise, instead of a search per cell.
    DILATE_SCRATCH.with(|cell| {
        let mut widened = cell.borrow_mut();
        widened.resize(w * h, 0);
        // Row pass: the flagged cells of each row (into `maybe`, as scratch), widened by `reach`
        // on both sides (into `widened`).
        maybe
            .par_chunks_mut(w)
            .zip(widened.par_chunks_mut(w))
            .enumerate()
            .with_min_len(16)
            .for_each(|(j, (flags, out))| {
                for s in srcs {
                    let inv = &s.bufs.invisible[j * w..(j + 1) * w];
                    for (f, v) in flags.iter_mut().zip(inv) {
                        *f |= v.load(Ordering::Relaxed);
                    }
                }
                widen_row(flags, reach, out);
            });
        column_pass(&widened, w, h, reach, maybe);
    });
}

/// `out[i]` = the or of `flags` over `i − reach ..= i + reach` (clipped to the row).
fn widen_row(flags: &[u8], reach: usize, out: &mut [u8]) {
    let n = flags.len();
    out.copy_from_slice(flags);
    for d in 1..=reach.min(n.saturating_sub(1)) {
        for (o, f) in out[..n - d].iter_mut().zip(&flags[d..]) {
            *o |= f;
        }
        for (o, f) in out[d..].iter_mut().zip(&flags[..n - d]) {
            *o |= f;
        }
    }
}

thread_local! {
    /// The row-widened flags of [`dilate_flags`], reused.
    static DILATE_SCRATCH: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The column half of [`dilate_flags`]: `maybe[c]` = any `widened` flag within `reach` rows, or
/// `c` within `reach` of the border.
fn column_pass(widened: &[u8], w: usize, h: usize, reach: usize, maybe: &mut [u8]) {
    maybe
        .par_chunks_mut(w)
        .enumerate()
        .with_min_len(16)
        .for_each(|(j, row)| {
            let (lo, hi) = (j.saturating_sub(reach), (j + reach).min(h - 1));
            if j < reach || j + reach >= h {
                row.fill(1);
                return;
            }
            row.copy_from_slice(&widened[lo * w..(lo + 1) * w]);
            for q in lo + 1..=hi {
                for (m, v) in row.iter_mut().zip(&widened[q * w..(q + 1) * w]) {
                    *m |= v;
                }
            }
            let r = reach.min(w);
            row[..r].fill(1);
            row[w - r..].fill(1);
        });
}

/// The correspondence of pixel `p` of source `s` in the other frame's source `o` (Algorithm 2):
/// the full scene flow of `p` (eqs. 2, 3, from [`full_flow_row`]) lands on pixel `q` of `o`.
/// Returns `q`, `M_full_s(p) + M_full_o(q)`, `Z_o(q)` and the predicted depth `P.z`; `None` when
/// out of view or invalid.
#[inline]
fn correspondence(
    s: &Src,
    s_full: &[[f32; 4]],
    o: &Src,
    o_full: &[[f32; 4]],
    p: usize,
) -> Option<(usize, [f32; 3], f32, f32)> {
    let ms = s_full[p];
    let qk = ms[3].to_bits();
    if qk == NO_SPLAT {
        return None;
    }
    let (qi, qj) = unpack_pixel(qk);
    let q = qj * o.proj.width + qi;
    let zq = o.view.depth[q];
    let mo = o_full[q];
    // NaN in `mo` (an invalid point) fails the caller's threshold test, as `None` would.
    if !(zq.is_finite() && mo[0].is_finite()) {
        return None;
    }
    let pz = s.view.depth[p] + ms[2];
    Some((q, [ms[0] + mo[0], ms[1] + mo[1], ms[2] + mo[2]], zq, pz))
}

/// The camera scene flow `M_cam` of every pixel of one source image to `client` with a fraction
/// `w` of its object motion applied (eq. 1; eq. 12 with `w = α` for the older frame, eq. 13 with
/// `w = 1−α` for the newer one): `P_client(X + w·(P⁻¹(p̄ + O[p]) − P⁻¹(p̄))) − p̄`.
///
/// Returns `H·W` entries of `[Δx, Δy, ΔZ]`; NaN where the pixel is invalid (non-finite depth or
/// motion, depth outside `[0,1]`) or the moved point is behind the client camera.
///
/// # Errors
/// Buffer-size errors of `view`, singular matrices.
pub fn scene_flow(view: &CameraView, client: &Camera, w: f32) -> Result<Vec<[f32; 3]>> {
    view.validate("source")?;
    let proj = view.camera.projector("source camera")?;
    client.projector("client camera")?;
    let inv = view
        .camera
        .view_proj()
        .inverse()
        .ok_or_else(|| ReprojError::SingularMatrix {
            what: "source camera".into(),
        })?;
    let to_client = NdcTransfer::new(&inv, &client.view_proj());
    let mut src = Src::new(*view, proj, None, Role::Older, 0, Buffers::default());
    scene_flow_and_splat(&mut src, &to_client, w, None);
    Ok(src
        .bufs
        .flow
        .into_iter()
        .zip(src.bufs.zc)
        .zip(view.depth)
        .map(|((f, zc), z)| [f[0], f[1], zc - z])
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Mat4;
    use crate::frame::FrameView;
    use crate::{reproject, Method};

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

    #[test]
    fn static_identity_reproduces_the_server_image() {
        let c = cam(0.0, 64, 48);
        let (color, depth) = plane(&c, 3.0);
        let view = CameraView {
            camera: c,
            color: &color,
            depth: &depth,
            motion: None,
            shadow: None,
        };
        let f = FrameView {
            main: view,
            aux: vec![],
        };
        for alpha in [0.0, 0.3, 0.99] {
            let mut out = vec![0u8; color.len()];
            let req = Request { client: c, alpha };
            reproject(
                Method::Ours,
                Some(&f),
                &f,
                &req,
                &Params::default(),
                &mut out,
                None,
                None,
            )
            .unwrap();
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
        let v = |c, col: &'static [u8], dep: &'static [f32]| FrameView {
            main: CameraView {
                camera: c,
                color: col,
                depth: dep,
                motion: None,
                shadow: None,
            },
            aux: vec![],
        };
        let (col0, dep0, col1, dep1) = (col0.leak(), dep0.leak(), col1.leak(), dep1.leak());
        let f0 = v(c0, col0, dep0);
        let f1 = v(c1, col1, dep1);
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
            &mut out,
            Some(&mut diag),
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
            &mut out,
            Some(&mut diag),
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
        let f = FrameView {
            main: CameraView {
                camera: c,
                color: &color,
                depth: &depth,
                motion: None,
                shadow: None,
            },
            aux: vec![],
        };
        for alpha in [1.0, 1.5, 2.9] {
            for m in [Method::Ours, Method::OursExtrapolate] {
                let mut out = vec![0u8; color.len()];
                let req = Request { client: c, alpha };
                reproject(m, None, &f, &req, &Params::default(), &mut out, None, None).unwrap();
                assert_eq!(out, color, "{m} alpha {alpha}");
            }
        }
    }

    /// The lazy auxiliary search ([`AuxGrid`]) skips cells whose match cannot reach the output;
    /// it must give the same bytes as searching every cell, with and without the older frame.
    #[test]
    fn lazy_auxiliary_search_equals_searching_every_cell() {
        use crate::synthetic::{head_pose, rig, SyntheticFrame, SyntheticScene};
        let (w, h) = (192, 108);
        let scene = SyntheticScene::new(true);
        let f0 = SyntheticFrame::render(&scene, 0.0, w, h, 0.1, 4);
        let f1 = SyntheticFrame::render(&scene, 0.1, w, h, 0.1, 4);
        let (older, newer) = (f0.view(true), f1.view(false));
        let mut aux_pixels = 0;
        for (alpha, pair) in [(0.35f32, true), (0.8, true), (1.4, false)] {
            // Off the server path, so that the client sees what the main camera did not.
            let (mut e, tg) = head_pose(0.1 * f64::from(alpha));
            e[0] += 0.25;
            e[1] -= 0.1;
            let req = Request {
                client: rig(e, tg, w, h).0,
                alpha,
            };
            let run = |eager: bool| {
                EAGER_AUX.with(|x| x.set(eager));
                let mut out = vec![9u8; w * h * 3];
                let mut diag = Diagnostics::new(w * h);
                let older = pair.then_some(&older);
                let p = Params::default();
                reproject(
                    Method::Ours,
                    older,
                    &newer,
                    &req,
                    &p,
                    &mut out,
                    Some(&mut diag),
                    None,
                )
                .unwrap();
                EAGER_AUX.with(|x| x.set(false));
                (out, diag)
            };
            let (lazy, eager) = (run(false), run(true));
            assert_eq!(lazy.0, eager.0, "colour, alpha {alpha}");
            assert_eq!(lazy.1.source, eager.1.source, "sources, alpha {alpha}");
            aux_pixels += eager
                .1
                .source
                .iter()
                .filter(|&&c| c & !Diagnostics::BLENDED >= Diagnostics::AUX_BASE)
                .count();
        }
        // The scene must exercise the auxiliary cameras for the comparison to mean anything.
        assert!(
            aux_pixels > 100,
            "only {aux_pixels} pixels from auxiliary cameras"
        );
    }

    /// A client keeps one history per server-frame pair: with it, `ours` computes the pair-level
    /// state once; the bytes must equal those of calls without it, for every α of the pair, and a
    /// different pair in the same history must not be served the old pair's state.
    #[test]
    fn pair_cache_gives_the_same_bytes_and_follows_the_pair() {
        use crate::synthetic::{head_pose, rig, SyntheticFrame, SyntheticScene};
        use crate::BidirHistory;
        let (w, h) = (96, 54);
        let scene = SyntheticScene::new(true);
        let frames: Vec<SyntheticFrame> = (0..3)
            .map(|k| SyntheticFrame::render(&scene, 0.1 * k as f64, w, h, 0.1, 4))
            .collect();
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
                let run = |hist: Option<&mut BidirHistory>| {
                    let mut out = vec![3u8; w * h * 3];
                    let mut diag = Diagnostics::new(w * h);
                    let p = Params::default();
                    reproject(
                        Method::Ours,
                        Some(&older),
                        &newer,
                        &req,
                        &p,
                        &mut out,
                        Some(&mut diag),
                        hist,
                    )
                    .unwrap();
                    (out, diag.source)
                };
                // Deliberately no reset between the pairs: the cache must notice by itself.
                let cached = run(Some(&mut history));
                let fresh = run(None);
                assert_eq!(cached, fresh, "pair {pair}, alpha {alpha}");
            }
        }
    }

    #[test]
    fn moving_object_is_extrapolated_along_its_motion() {
        // The whole plane moves +x by 0.4 NDC per server interval (backward motion of the newer
        // frame is −0.4). At α = 1.5 the content must appear shifted by +0.2 NDC.
        let (w, h) = (64, 48);
        let c = cam(0.0, w, h);
        let (color, depth) = plane(&c, 2.0);
        let motion: Vec<f32> = (0..w * h).flat_map(|_| [-0.4f32, 0.0, 0.0]).collect();
        let f = FrameView {
            main: CameraView {
                camera: c,
                color: &color,
                depth: &depth,
                motion: Some(&motion),
                shadow: None,
            },
            aux: vec![],
        };
        let mut out = vec![0u8; color.len()];
        let req = Request {
            client: c,
            alpha: 1.5,
        };
        reproject(
            Method::OursExtrapolate,
            None,
            &f,
            &req,
            &Params::default(),
            &mut out,
            None,
            None,
        )
        .unwrap();
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
}
