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
//!    filter over the splat grid (`window_min`; for a main source whose grid is the client's,
//!    by each block of pass 2 for its own rows).
//! 2. **Resolve**, per output pixel over blocks of 16 rows: the nearest splat in the window
//!    initialises the fixed-point iteration `p ← pix(T − M_cam[p])` (eq. 5 with eqs. 12/13), then
//!    the reprojection error and depth (eqs. 7, 8) feed Algorithm 1 per camera, the auxiliary
//!    cameras (searched once per cell of their own grid, and only where the result can reach the
//!    output, see `AuxGrid`) are merged (§3.5 rules 1–3), and Algorithm 2 blends in the other
//!    frame for the match that was kept. Each row goes through these steps as stages, each a
//!    short loop over the row's pixels (`Resolve::resolve_rows`), so that the dependent loads
//!    of neighbouring pixels overlap and the arithmetic vectorises.
//!
//! What does not depend on the client pose or α — Algorithm 2's correspondences from the full
//! scene flows (eqs. 2, 3) with the motion-cancel check, the auxiliary points' visibility in
//! main, and each pixel's colour packed with its partner's for the colour stage — is computed once
//! per server-frame pair ([`PairCache`], kept in the client's history).
//!
//! The row loops of pass 1 and of the window filter are written without data-dependent branches
//! and run in an AVX-512 or AVX2 build on processors that have it (no FMA contraction, so the output
//! bytes do not depend on the processor; [`set_simd_limit`] caps the instruction set).
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
//!
//! The stages live in one module each: `pass1` (scene flow, splatting and the window minimum),
//! `search` (the window initialisation and the fixed-point iteration, eqs. 5, 7, 8), `select`
//! (Algorithms 1 and 2), `auxiliary` (the auxiliary cameras and the merge rules of §3.5) and `pair`
//! (the pair-level state, [`PairCache`]); `crate::simd` holds the instruction-set dispatch of the
//! row loops. This module holds what they share, the entry `run` and the driver of pass 2
//! (`Resolve`).

mod auxiliary;
mod pair;
mod pass1;
mod search;
mod select;

pub use crate::simd::{set_simd_limit, simd_tier, Simd};

use std::sync::atomic::AtomicU8;

use rayon::prelude::*;

use crate::camera::{Camera, Mat4, NdcTable, NdcTransfer, Projector};
use crate::error::{ReprojError, Result};
use crate::frame::{CameraView, FrameView, ShadowView};
use crate::params::Params;
use crate::request::{par_row_blocks, Output, Request};
use crate::shadow::Role;

use auxiliary::{AuxBlock, AuxGrid, AuxRow};
pub use pair::PairCache;
use pair::{PairKey, VisCtx, PAIR_POOL};
use pass1::{scene_flow_and_splat, window_min};
use search::{SearchRow, Targets};
use select::Picks;

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

/// An empty splat cell: larger than every real key of every epoch (`SplatEpoch`) as the
/// signed integers the splat compares them as, and its low half is [`NO_SPLAT`].
pub const EMPTY_SPLAT: u64 = i64::MAX as u64;

/// No splat in the window of a cell (see `Buffers::init`).
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

/// Which of four classes the splat keys of a client frame are stored in, so that the splat grid
/// is filled with [`EMPTY_SPLAT`] once every four frames instead of every frame.
///
/// A [`splat_key`] has its top two bits set (its high half is `!z.to_bits()` with `0 ≤ z ≤ 1`,
/// whose bits are below 2³⁰). The grid stores it with those two bits replaced by the epoch's
/// (an exclusive or, [`SplatEpoch::stored`]) and compares stored keys as signed integers; the four
/// classes of top bits order as `01 > 00 > 11 > 10`, and epochs 0, 1, 2, 3 use them in that
/// order. Within an epoch the order is the keys' own; every key left in the grid by an earlier
/// epoch since the last fill (and [`EMPTY_SPLAT`], the largest value of class `01`) is larger
/// than every key of the current one, so the splat's minimum never picks it, and the window
/// search ([`pass1::window_min`]) tells an empty window by a minimum at or above
/// [`SplatEpoch::bound`]. Epoch 0 fills the grid first. At 1280×720 with two auxiliary cameras
/// that fill was 22 MB per frame (5 % of the frame's time in a profile).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct SplatEpoch(u8);

impl SplatEpoch {
    /// The epoch before the first: the next is 0, which fills the grid.
    const BEFORE_FILL: SplatEpoch = SplatEpoch(3);

    /// The epoch after this one.
    fn next(self) -> SplatEpoch {
        SplatEpoch((self.0 + 1) % 4)
    }

    /// Whether the grid is filled with [`EMPTY_SPLAT`] before this epoch's splat.
    fn fills(self) -> bool {
        self.0 == 0
    }

    /// What turns a [`splat_key`] (top bits `11`) into its stored form in this epoch.
    #[inline(always)]
    fn stored(self) -> u64 {
        // Top bits 01, 00, 11, 10.
        [0b10u64, 0b11, 0b00, 0b01][usize::from(self.0)] << 62
    }

    /// Every stored key of this epoch is below this (as `i64`); [`EMPTY_SPLAT`] and every key of
    /// the earlier epochs since the fill are at or above it.
    #[inline(always)]
    fn bound(self) -> i64 {
        [i64::MAX, 1 << 62, 0, -(1 << 62)][usize::from(self.0)]
    }
}

impl Default for SplatEpoch {
    fn default() -> Self {
        SplatEpoch::BEFORE_FILL
    }
}

/// The packed source pixel stored in a splat key.
#[inline(always)]
pub fn splat_index(key: u64) -> u32 {
    key as u32
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
    /// The window search of this source is done by pass 2's blocks for their own rows
    /// ([`pass1::window_rows`]) instead of for the whole grid before pass 2 ([`window_min`]):
    /// the main sources when their grid is the client's.
    window_in_blocks: bool,
}

/// Row `j` of a `sw × sh` source image: where a row kernel ([`pass1`], [`pair`]) works. One
/// value instead of three arguments, so that each kernel and its SIMD dispatch name them once.
#[derive(Debug, Clone, Copy)]
struct SrcRow {
    j: usize,
    sw: usize,
    sh: usize,
}

impl SrcRow {
    /// NDC y of the row's pixel centres ([`crate::camera::ndc_of_pixel`]).
    #[inline(always)]
    fn ndc_y(self) -> f32 {
        crate::camera::ndc_of_pixel(0, self.j, self.sw, self.sh)[1]
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
    /// Splat keys ([`splat_key`]) in their stored form of `epoch`, reset to [`EMPTY_SPLAT`]
    /// every four frames ([`SplatEpoch`]; band by band, by the task that splats the band, see
    /// [`scene_flow_and_splat`]).
    splat: Vec<u64>,
    /// The epoch of the keys in `splat` (of the last frame splatted).
    epoch: SplatEpoch,
    /// The window search done for every cell at once ([`window_min`]): the packed source pixel
    /// of the smallest splat key in the `(2W+1)²` window around the cell, or [`NO_SPLAT`].
    /// Every entry is rewritten each frame, except for a source whose window search pass 2
    /// does per block ([`Src::window_in_blocks`]), which leaves it unused.
    init: Vec<u32>,
    /// Auxiliary sources only: 1 where a point that is *not* visible in the main camera lands in
    /// the client grid (its splat cell), else 0; reset every frame. An auxiliary match can only
    /// override a main match near such a cell (see [`AuxGrid::maybe`]).
    invisible: Vec<AtomicU8>,
    /// Per splat band (`SPLAT_BAND` source rows), its points that land outside the band's own rows
    /// of the grid (see [`scene_flow_and_splat`]).
    spill: Vec<Vec<(u32, u64)>>,
}

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

/// The source images of a call (main and auxiliary cameras, (older, newer) per camera when
/// `older` is given), in the order every per-source list follows, without their per-frame
/// buffers. Every camera's projector is built first, so that a singular matrix is reported
/// before any work.
fn sources<'a>(
    older: Option<&FrameView<'a>>,
    newer: &FrameView<'a>,
    params: &Params,
) -> Result<Vec<Src<'a>>> {
    let mut sources: Vec<Src> = Vec::new();
    let n_aux = if params.use_aux { newer.aux.len() } else { 0 };
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
            sources.push(Src::new(ov, op, Some(other_of_o), Role::Older, cam));
            sources.push(Src::new(nv, np, Some(other_of_n), Role::Newer, cam));
        } else {
            sources.push(Src::new(nv, np, None, Role::Newer, cam));
        }
    }
    Ok(sources)
}

/// The inverse view-projection of every source (its NDC → world).
fn inverses(sources: &[Src]) -> Result<Vec<Mat4>> {
    sources
        .iter()
        .map(|src| {
            src.view
                .camera
                .view_proj()
                .inverse()
                .ok_or_else(|| ReprojError::SingularMatrix {
                    what: "source camera".into(),
                })
        })
        .collect()
}

/// Brings `pair` up to date for `sources`: what does not depend on the client pose or α
/// ([`PairCache`]), computed only when the cache holds another pair (or nothing).
fn ensure_pair<'a>(
    sources: &[Src<'a>],
    inverses: &[Mat4],
    mode: Mode,
    params: &Params,
    pair: &mut PairCache,
) {
    // Main sources are 0 and (if bidirectional) 1; visibility in main is needed for the
    // auxiliary sources only.
    let bidirectional = sources.get(1).is_some_and(|s| s.camera == 0);
    let blends = mode == Mode::Ours && params.blend && bidirectional;
    let key = PairKey::of(sources, mode, params, blends);
    if pair.key.as_ref() == Some(&key) {
        return;
    }
    pair.key = None;
    let n_main = if bidirectional { 2 } else { 1 };
    let mains = &sources[..n_main];
    let to_main = |k: usize, m: &Src<'a>| {
        (
            m.view,
            m.proj,
            NdcTransfer::new(&inverses[k], &m.view.camera.view_proj()),
        )
    };
    let vis_ctx: Vec<Option<VisCtx>> = sources
        .iter()
        .enumerate()
        .map(|(k, src)| {
            (src.camera > 0).then(|| VisCtx {
                same: mains
                    .iter()
                    .find(|m| m.role == src.role)
                    .map(|m| to_main(k, m)),
                other: mains
                    .iter()
                    .find(|m| m.role != src.role)
                    .map(|m| to_main(k, m)),
                eps_z: params.eps_z_aux(),
            })
        })
        .collect();
    pair.compute(sources, &vis_ctx, blends, params);
    pair.key = Some(key);
}

/// The pair-level state alone ([`crate::prepare_pair`]): what [`run`] with the same mode, frames
/// and parameters would compute into `pair` (`older` is the frame `run` uses, `None` when
/// extrapolating), and no client frame.
pub(crate) fn prepare(
    mode: Mode,
    older: Option<&FrameView>,
    newer: &FrameView,
    params: &Params,
    pair: &mut PairCache,
) -> Result<()> {
    let sources = sources(older, newer, params)?;
    let inverses = inverses(&sources)?;
    ensure_pair(&sources, &inverses, mode, params, pair);
    Ok(())
}

/// Runs `ours` or `forward_splat`. `older = None` (or `α ≥ 1`) means unidirectional from `newer`.
pub(crate) fn run<'a>(
    mode: Mode,
    older: Option<&FrameView<'a>>,
    newer: &FrameView<'a>,
    request: &Request,
    params: &Params,
    out: Output,
    pair: Option<&mut PairCache>,
) -> Result<()> {
    let alpha = request.alpha;
    request.client.projector("client camera")?;
    let older = if alpha < 1.0 { older } else { None };
    let bidirectional = older.is_some();
    let mut sources = sources(older, newer, params)?;
    let n_aux = if params.use_aux { newer.aux.len() } else { 0 };
    let eps_z_aux = params.eps_z_aux();
    let client_vp = request.client.view_proj();
    let inverses = inverses(&sources)?;
    let mut pool = BUFFER_POOL.with(|p| std::mem::take(&mut *p.borrow_mut()));
    for src in &mut sources {
        let n = src.view.camera.width * src.view.camera.height;
        src.bufs = take_buffers(&mut pool, n, src.camera > 0);
        src.bufs.fit(n, src.camera);
        // A main source's window minimum is read row by row by pass 2 for the same rows of the
        // client image: each block of output rows computes it for its rows while the splat
        // grid's rows are hot, instead of a pass over the grid that writes `init` (4 bytes per
        // cell) for pass 2 to read back (at 1280×720, 15 MB of traffic per frame).
        src.window_in_blocks = src.camera == 0
            && (src.view.camera.width, src.view.camera.height)
                == (request.client.width, request.client.height);
    }

    // What does not depend on the client pose or α: computed once per server-frame pair when the
    // caller keeps a `PairCache` for the pair, else for this frame alone.
    let blends = mode == Mode::Ours && params.blend && bidirectional;
    let mut own_pair = None;
    let pair: &mut PairCache = match pair {
        Some(p) => p,
        None => own_pair.insert(PAIR_POOL.with(|p| std::mem::take(&mut *p.borrow_mut()))),
    };
    ensure_pair(&sources, &inverses, mode, params, pair);

    let pair: &PairCache = pair;
    let mut aux_pool = AUX_POOL.with(|p| std::mem::take(&mut *p.borrow_mut()));
    let aux_bufs: Vec<Vec<u8>> = (0..n_aux)
        .map(|_| aux_pool.pop().unwrap_or_default())
        .collect();
    // The rest of the frame is three parallel regions (pass 1, the auxiliary grids, pass 2) with
    // a little serial work between them. Entered from a thread outside the pool (the client's),
    // each region would be handed to the pool as a job, and the caller put to sleep and woken
    // again at its end (tens of µs to over 100 µs each on a VM); as one job on the pool, the
    // regions are forks of a worker while the other worker is still looking for work, and the
    // caller waits once. The thread-local pools stay the caller's: what is taken from them is
    // handed in and back.
    let (cw, ch) = (request.client.width, request.client.height);
    let eps_scale = REFERENCE_SHORT_SIDE / cw.min(ch) as f32;
    let eps_e_aux = params.eps_e * eps_scale * params.aux_threshold_scale;
    // Read here, not in the job: the tests set it on the thread that calls `reproject`.
    let every_cell = auxiliary::eager_aux();
    let srcs = &mut sources;
    let aux_bufs = rayon::scope(move |_| {
        let sources = srcs;
        // Pass 1: scene flow and splatting of one source.
        let pass1 = |k: usize, src: &mut Src| {
            let w = match src.role {
                Role::Older => alpha,
                Role::Newer => 1.0 - alpha,
            };
            let to_client = NdcTransfer::new(&inverses[k], &client_vp);
            let vis = (src.camera > 0).then(|| pair.sources[k].vis.as_slice());
            let moving = Some(pair.sources[k].moving.as_slice()).filter(|m| !m.is_empty());
            scene_flow_and_splat(src, &to_client, w, vis, moving);
            if !src.window_in_blocks {
                window_min(src, params.window);
            }
        };
        // Every source at once, each with its own parallel bands inside: one wait for the slowest
        // task per frame instead of two per source (the small auxiliary grids have too few bands
        // to keep both cores busy on their own). Every source and band is a job of its own
        // (`with_max_len(1)`): rayon otherwise stops splitting a range after a few halvings, and a
        // thread that finds nothing to steal waits while the other runs several bands in a row.
        // The auxiliary grids need only the auxiliary sources' pass 1, so they are built while
        // the main sources' pass 1 still runs, instead of between the two passes.
        let n_main = if bidirectional { 2 } else { 1 };
        let (mains, auxes) = sources.split_at_mut(n_main);
        let ((), mut aux_grids) = rayon::join(
            || {
                mains
                    .par_iter_mut()
                    .enumerate()
                    .with_max_len(1)
                    .for_each(|(k, src)| pass1(k, src))
            },
            || {
                auxes
                    .par_iter_mut()
                    .enumerate()
                    .with_max_len(1)
                    .for_each(|(k, src)| pass1(n_main + k, src));
                auxes
                    .par_chunks_mut(n_main)
                    .zip(aux_bufs)
                    .with_max_len(1)
                    .map(|(srcs, maybe)| AuxGrid::new(srcs, eps_e_aux, (cw, ch), every_cell, maybe))
                    .collect::<Vec<_>>()
            },
        );
        auxiliary::unite_maybe(&mut aux_grids);
        let sources: &[Src] = sources;

        // Pass 2: resolve per output tile.
        let ctx = Resolve {
            params,
            alpha,
            client_w: cw,
            client_h: ch,
            sources,
            bidirectional,
            eps_e: params.eps_e * eps_scale,
            eps_e_aux,
            eps_z: params.eps_z,
            eps_z_aux,
            iterations: if mode == Mode::Ours {
                params.fpi_iterations
            } else {
                0
            },
            aux: aux_grids,
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
                    texel: &pair.sources[k].texel,
                    omega: match s.role {
                        Role::Older => 1.0 - alpha,
                        Role::Newer => alpha,
                    },
                })
                .collect(),
        };
        par_row_blocks(out, cw, |j0, o, d| ctx.resolve_rows(j0, o, d));
        ctx.aux.into_iter().map(|g| g.maybe).collect::<Vec<_>>()
    });
    // Back to the pools in reverse, so that the next frame pops them in the same order and each
    // source gets a buffer of its own size again.
    aux_pool.extend(aux_bufs.into_iter().rev());
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
    /// A source without its per-frame buffers (see [`Buffers::fit`]).
    fn new(
        view: CameraView<'a>,
        proj: Projector,
        other: Option<Other>,
        role: Role,
        camera: usize,
    ) -> Self {
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
            bufs: Buffers::default(),
            window_in_blocks: false,
        }
    }
}

/// The buffers in `pool` that fit a source of `n` pixels (an auxiliary one if `aux`) best: the
/// same size and kind, else the same size, else any (resized by [`Buffers::fit`]).
///
/// A client alternates between frames with both main sources and frames with one (interpolating,
/// then extrapolating while the next pair is prepared), so the pool does not hold the buffers in
/// the order of the next frame's sources. Taken by position, a main source would get an
/// auxiliary source's buffers after every switch, and reallocating them costs more than the
/// frame (first-touch page faults, see [`BUFFER_POOL`]).
fn take_buffers(pool: &mut Vec<Buffers>, n: usize, aux: bool) -> Buffers {
    let fits = |b: &Buffers| b.flow.len() == n;
    let at = pool
        .iter()
        .rposition(|b| fits(b) && b.invisible.is_empty() != aux)
        .or_else(|| pool.iter().rposition(fits))
        .or_else(|| pool.len().checked_sub(1));
    at.map(|i| pool.remove(i)).unwrap_or_default()
}

impl Buffers {
    /// Sizes the buffers for a source of `n` pixels (`camera` as [`Src::camera`]), reusing
    /// their memory when the size is unchanged, and clears the auxiliary flags.
    fn fit(&mut self, n: usize, camera: usize) {
        if self.flow.len() != n {
            self.flow = Vec::new();
            self.flow.resize(n, [f32::NAN; 2]);
            self.zc = Vec::new();
            self.zc.resize(n, f32::NAN);
            self.splat = Vec::new();
            self.splat.resize(n, EMPTY_SPLAT);
            self.epoch = SplatEpoch::BEFORE_FILL;
            self.init = Vec::new();
            self.init.resize(n, NO_SPLAT);
        }
        if camera > 0 {
            if self.invisible.len() != n {
                self.invisible = Vec::new();
                self.invisible.resize_with(n, || AtomicU8::new(0));
            } else {
                // Exclusive access: plain stores, which the compiler turns into a memset (an
                // atomic store per flag would not vectorise). A quarter of a byte per output
                // pixel, so one thread.
                self.invisible.iter_mut().for_each(|f| *f.get_mut() = 0);
            }
        }
    }
}

/// Read-only context of pass 2.
struct Resolve<'a> {
    params: &'a Params,
    alpha: f32,
    client_w: usize,
    client_h: usize,
    sources: &'a [Src<'a>],
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

/// The per-row state of [`Resolve::resolve_rows`], kept between rows and frames.
#[derive(Debug, Default)]
struct RowState {
    /// The searches in each main source.
    sides: Vec<SearchRow>,
    picks: Picks,
    aux: AuxRow,
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
    /// Algorithm 2's correspondence of each pixel in the other frame ([`PairSource::partner`](pair::PairSource::partner));
    /// empty when nothing blends.
    partner: &'a [u32],
    /// The source index of the same camera in the other frame (only read through `partner`).
    other: usize,
    /// Per pixel, its colour with its partner's and what Algorithm 2 does with them (from the
    /// pair, [`texel`](pair::texel)).
    texel: &'a [u64],
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
        for (k, side) in sides.iter_mut().enumerate() {
            let s = &self.sources[k];
            side.block_j0 = s.window_in_blocks.then_some(j0);
            if s.window_in_blocks {
                pass1::window_rows(s, j0, rows, self.params.window, &mut side.block);
            }
        }
        for (k, side) in sides.iter().enumerate() {
            self.prefetch_block_start(k, side);
        }
        // Scanlines inside the block of 16 rows: the reads of `init`, `flow` and the colours then
        // run along rows of the sources, a few sequential streams that the hardware prefetcher
        // follows, where a 16×16 tile order starts 16 new rows every 16 pixels.
        //
        // Each row goes through stages, each a loop over the row's pixels: the main camera's
        // searches ([`Resolve::search_row`]), Algorithm 1 for them without branches on the data
        // ([`Resolve::choose_row`]; which frame wins is close to random from pixel to pixel, so
        // a branch on it would be mispredicted about half the time), the auxiliary cameras where
        // they can change the pixel, and the colours (Algorithm 2, [`Resolve::colour_row`]).
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
            let row_diag = diag
                .as_mut()
                .map(|(s, e)| (&mut s[r * cw..(r + 1) * cw], &mut e[r * cw..(r + 1) * cw]));
            self.colour_row(picks, &mut out[3 * r * cw..3 * (r + 1) * cw], row_diag);
        }
        ROW_STATE.with(|b| *b.borrow_mut() = scratch);
        AUX_BLOCKS.with(|b| *b.borrow_mut() = blocks);
    }
}

/// The camera scene flow `M_cam` of every pixel of one source image to `client` with a fraction
/// `w` of its object motion applied (eq. 1; eq. 12 with `w = α` for the older frame, eq. 13 with
/// `w = 1−α` for the newer one): `P_client(X + w·(P⁻¹(p̄ + O[p]) − P⁻¹(p̄))) − p̄`.
///
/// Returns `H·W` entries of `[Δx, Δy, ΔZ]`; NaN where the pixel is invalid (non-finite depth or
/// motion, depth outside `[0,1]`) or the moved point is behind the client camera.
///
/// # Errors
/// Size and buffer-size errors of `view` and `client` ([`ReprojError::BadSize`],
/// [`ReprojError::BufferSize`]), singular matrices.
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
    let mut src = Src::new(*view, proj, None, Role::Older, 0);
    src.bufs.fit(view.camera.width * view.camera.height, 0);
    scene_flow_and_splat(&mut src, &to_client, w, None, None);
    Ok(src
        .bufs
        .flow
        .into_iter()
        .zip(src.bufs.zc)
        .zip(view.depth)
        .map(|((f, zc), z)| [f[0], f[1], zc - z])
        .collect())
}

/// The tests' xorshift64 generator (shifts 13, 7, 17): the next state of `seed`, so that every
/// run draws the same cases.
#[cfg(test)]
fn xorshift(seed: &mut u64) -> u64 {
    *seed ^= *seed << 13;
    *seed ^= *seed >> 7;
    *seed ^= *seed << 17;
    *seed
}

/// A draw in `0..n` from [`xorshift`].
#[cfg(test)]
fn draw(seed: &mut u64, n: u64) -> u64 {
    xorshift(seed) % n
}

#[cfg(test)]
mod tests;
