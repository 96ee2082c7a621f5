//! The search in one source image (seeds/000 §3.1 with the changes of §3.5): the nearest splat in
//! the window around the target's cell (from `pass1`) initialises the fixed-point iteration
//! `p ← pix(T − M_cam[p])` (eq. 5, with the client-pose flows of eqs. 12 and 13 in place of eq. 4),
//! and the reprojection error and client depth of its result (eqs. 7, 8) are what Algorithm 1
//! compares. [`Resolve::search_row`] searches a row of targets in stages,
//! [`Resolve::search`] one target.

use crate::camera::{centre_quotient, pixel_of_ndc};

use super::{packed_cell, unpack_pixel, Cell, Match, Resolve, NO_SPLAT};
use crate::simd::{prefetch, simd_method};

/// How many output rows ahead [`Resolve::prefetch_ahead`] prefetches (1, 2 and 4 rows gave
/// 4–8 % of the frame at 1280×720 in one hour, 2 the most; 2.5–3.8 % in another).
const PREFETCH_ROWS: usize = 2;

/// The smallest main source (pixels) for which [`Resolve::prefetch_ahead`] prefetches. Measured
/// here, paired in one process, with and without: at 1280×720 (921,600 pixels) without is
/// 1.025–1.038 of the frame time with, at 640×360 (230,400) 0.968–0.979: there the lines are
/// more often still cached, and the prefetches only cost instructions and fill buffers.
const PREFETCH_MIN_PIXELS: usize = 1 << 19;

/// One output row's searches in one main source ([`Resolve::search_row`]), kept between rows.
#[derive(Debug, Default)]
pub(super) struct SearchRow {
    /// Per pixel: the packed source pixel while searching.
    pk: Vec<u32>,
    /// The source index of the match, or [`NO_SPLAT`] for no match.
    pub(super) p: Vec<u32>,
    /// The flow `M_cam` at the current source pixel.
    m: Vec<[f32; 2]>,
    /// Reprojection error (eq. 7), `INFINITY` for no match.
    pub(super) e: Vec<f32>,
    /// Client reversed depth (eq. 8).
    pub(super) z: Vec<f32>,
    /// The client depth at the last source pixel, as loaded.
    zg: Vec<f32>,
    /// The pixels whose fixed-point iteration is still moving.
    moving: Vec<u32>,
    /// Where an iteration moves each pixel, or [`NO_SPLAT`] where it stays.
    next: Vec<u32>,
    /// The flows and targets' NDC x of the pixels in `moving`, once listed.
    dm: Vec<[f32; 2]>,
    dx: Vec<f32>,
    /// The same for the previous iteration (before the first: the initial pixel).
    prev: Vec<u32>,
    /// Auxiliary sources: whether each match is visible in main (empty for main sources).
    vis: Vec<bool>,
    /// The window search of the source for the rows of the current block of output rows, from
    /// row `block_j0`, when pass 2 computes it per block ([`Src::window_in_blocks`](super::Src));
    /// else `block_j0` is `None` and the search reads the source's `init`.
    pub(super) block: Vec<u32>,
    pub(super) block_j0: Option<usize>,
}

impl SearchRow {
    /// The match of target `n` as [`Resolve::search`] returns it.
    #[inline(always)]
    pub(super) fn found(&self, n: usize) -> Option<Match> {
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
pub(super) struct Targets<'a> {
    pub(super) x: &'a [f32],
    pub(super) y: f32,
    pub(super) j: usize,
    pub(super) gw: usize,
    pub(super) gh: usize,
    /// The cell column of each target, or `None` when target `n` is in column `n`.
    pub(super) cols: Option<&'a [u32]>,
}

impl Resolve<'_> {
    simd_method! {
        /// [`Resolve::search`] in source `k` for every target of a row (the pixels of an output
        /// row for the main camera, the cells an output row needs for an auxiliary one), stage
        /// by stage: the windows' nearest splats and their flows for the whole row, then each
        /// fixed-point iteration for the targets still moving, then the errors and depths.
        ///
        /// The same arithmetic as one search per pixel, in another order. A search is a chain of
        /// dependent loads (init → flow → pixel → flow) of ~100 instructions; done pixel by pixel,
        /// the processor's reorder window holds less than one pixel's work and waits on each load.
        /// Row by row, every stage is a short loop over independent pixels whose loads overlap.
        /// Besides the wider vectors, the AVX2 and AVX-512 builds load by source pixel with gather
        /// instructions ([`Gathers`]).
        pub(super) fn search_row / search_row_avx2, search_row_avx512 => search_row_impl(&self, gathers, k: usize, t: &Targets, row: &mut SearchRow)
    }

    #[inline(always)]
    fn search_row_impl<G: Gathers>(&self, g: G, k: usize, t: &Targets, row: &mut SearchRow) {
        self.prefetch_ahead(k, t.j, row);
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
        if (t.gw, t.gh) == (sw, sh) {
            let cells = match row.block_j0 {
                Some(j0) => &row.block[(t.j - j0) * sw..(t.j - j0 + 1) * sw],
                None => &init[t.j * sw..(t.j + 1) * sw],
            };
            match t.cols {
                None => {
                    g.firsts(flow, sw, &cells[..cw], pks, ms);
                }
                Some(cols) => {
                    let first = &mut row.next[..cw];
                    for (q, &c) in first.iter_mut().zip(cols) {
                        *q = cells[c as usize];
                    }
                    g.firsts(flow, sw, first, pks, ms);
                }
            }
        } else {
            let first = &mut row.next[..cw];
            for (q, &x) in first.iter_mut().zip(tx) {
                *q = pixel_of_ndc(x, ty, sw, sh).map_or(NO_SPLAT, |(ci, cj)| init[cj * sw + ci]);
            }
            g.firsts(flow, sw, first, pks, ms);
        }
        // Stage 2: the fixed-point iteration p ← pix(T − M_cam[p]) (eq. 5 with the flows of eqs.
        // 12/13). Once p maps to itself every further iteration would too, so a pixel leaves the
        // iteration there (most converge after one step). An iteration is a step, one loop of
        // arithmetic without branches (vectorised, [`fixed_point_step`]), then the moves
        // ([`Gathers::moves`]). While many pixels move (nearly all do once: the window's nearest
        // splat is usually a neighbour of the fixed point; about one in fifty twice), both run
        // over the whole row; once few do, over a list of those with their state packed densely.
        // A pixel that stopped never moves again, so the list only shrinks.
        let (wf, hf) = (sw as i32 as f32, sh as i32 as f32);
        let mut n = cw;
        // Whether `moving[..n]` lists the pixels that moved in the last iteration, with their
        // pixels, flows and targets in `prev`, `dm` and `dx`. Before, the whole row iterates (the
        // first iteration always does), and `prev` marks the pixels that moved in the last one.
        let mut listed = false;
        for _ in 0..self.iterations {
            if n == 0 {
                break;
            }
            if 4 * n > cw {
                let next = &mut row.next[..cw];
                fixed_point_step(pks, ms, tx, ty, next, wf, hf);
                n = g.moves(flow, sw, next, pks, ms);
                std::mem::swap(&mut row.next, &mut row.prev);
            } else {
                if !listed {
                    // The pixels that moved in the last whole-row iteration (marked in `prev`).
                    let m = g.list(&row.prev[..cw], &mut row.moving[..cw]);
                    debug_assert_eq!(m, n);
                    row.dm.resize(n, [0.0; 2]);
                    row.dx.resize(n, 0.0);
                    for (a, &i) in row.moving[..n].iter().enumerate() {
                        let i = i as usize;
                        (row.prev[a], row.dm[a], row.dx[a]) = (pks[i], ms[i], tx[i]);
                    }
                    listed = true;
                }
                let (moving, dpk, next) =
                    (&mut row.moving[..n], &mut row.prev[..n], &mut row.next[..n]);
                let (dm, dx) = (&mut row.dm[..n], &mut row.dx[..n]);
                fixed_point_step(dpk, dm, dx, ty, next, wf, hf);
                g.moves(flow, sw, next, dpk, dm);
                // Back into the row, and the list without the pixels that stopped.
                let mut kept = 0;
                for a in 0..n {
                    let i = moving[a] as usize;
                    (pks[i], ms[i]) = (dpk[a], dm[a]);
                    (moving[kept], dpk[kept], dm[kept], dx[kept]) =
                        (moving[a], dpk[a], dm[a], dx[a]);
                    kept += usize::from(next[a] != NO_SPLAT);
                }
                n = kept;
            }
        }
        // Stage 3: the reprojection error and depth (eqs. 7, 8); the packed pixel becomes the
        // source index. The depth loads first ([`Gathers::depths`]), then the arithmetic as one
        // loop without branches.
        let zg = &mut row.zg[..cw];
        g.depths(&s.bufs.zc, sw, pks, zg);
        let (wf, hf) = (sw as i32 as f32, sh as i32 as f32);
        let (rw, rh) = (1.0 / wf, 1.0 / hf);
        let [ax, ay] = s.aspect;
        // Inputs and outputs in different arrays: an output written back over its input became
        // masked stores, which are slow on some processors.
        let (pks, ms, zg) = (&pks[..cw], &ms[..cw], &zg[..cw]);
        let (es, zs, ps) = (&mut row.e[..cw], &mut row.z[..cw], &mut row.p[..cw]);
        for i in 0..cw {
            let (pk, m, x, z) = (pks[i], ms[i], tx[i], zg[i]);
            let (pi, pj) = ((pk & 0xFFFF) as i32, (pk >> 16) as i32);
            // The pixel centre's NDC as [`crate::camera::ndc_of_pixel`] computes it (the same
            // quotients with or without FMA).
            let (oi, oj) = ((2 * pi + 1) as f32, (2 * pj + 1) as f32);
            let (qx, qy) = if G::FMA {
                (centre_quotient(oi, wf, rw), centre_quotient(oj, hf, rh))
            } else {
                (oi / wf, oj / hf)
            };
            let (px, py) = (qx - 1.0, 1.0 - qy);
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

    /// Prefetches, for the searches of output row `j + PREFETCH_ROWS` in main source `k`, what
    /// they load by source pixel: the flow and texel at the window's nearest splat of every
    /// eighth pixel (one cache line of flows or texels holds eight pixels), the client depth of
    /// every sixteenth, when pass 2 computes the window search per block ([`SearchRow::block`]),
    /// that row is in the block and the source has at least [`PREFETCH_MIN_PIXELS`].
    ///
    /// Why: the searches gather from buffers of 4–8 bytes per source pixel (at 1280×720, 7.4 MB
    /// of flows, 3.7 MB of depths and 7.4 MB of texels per main source) that pass 1 wrote or the
    /// pair built long before, so the loads miss the caches; a time profile put most of the
    /// searches' and `gather_texels`' samples on the gathers waiting for them. The fixed point is
    /// nearly always beside the window's splat, so these lines are the ones the row will load.
    /// Into L2, not L1: a row's lines for both main sources, two rows ahead, are ~100 KB.
    #[inline(always)]
    pub(super) fn prefetch_ahead(&self, k: usize, j: usize, row: &SearchRow) {
        if let Some(j0) = row.block_j0 {
            self.prefetch_block_row(k, j + PREFETCH_ROWS - j0, row);
        }
    }

    /// [`Resolve::prefetch_ahead`] for the first `PREFETCH_ROWS` rows of a block, which no row
    /// before them prefetches: called once the block's window search is done, before its first
    /// row is searched. The second row's lines then have a row's time to arrive (the first's
    /// hardly any). Paired in one process at 1280×720, with against without: 0.980–0.998 (ten
    /// runs), 0.988 on one thread.
    #[inline(always)]
    pub(super) fn prefetch_block_start(&self, k: usize, row: &SearchRow) {
        if row.block_j0.is_some() {
            for r in 0..PREFETCH_ROWS {
                self.prefetch_block_row(k, r, row);
            }
        }
    }

    /// The prefetches of [`Resolve::prefetch_ahead`] for row `r` of the block in `row`.
    #[inline(always)]
    fn prefetch_block_row(&self, k: usize, r: usize, row: &SearchRow) {
        let s = &self.sources[k];
        let (flow, zc) = (&s.bufs.flow[..], &s.bufs.zc[..]);
        if flow.len() < PREFETCH_MIN_PIXELS {
            return;
        }
        let sw = s.proj.width;
        let Some(cells) = row.block.get(r * sw..(r + 1) * sw) else {
            return;
        };
        let texel = &self.pair.sources[k].texel[..];
        for (n, &q) in cells.iter().step_by(8).enumerate() {
            let (qi, qj) = unpack_pixel(q);
            let p = qj * sw + qi;
            // NO_SPLAT unpacks to a pixel past the image: nothing to fetch.
            if p < flow.len() {
                prefetch(&flow[p]);
                // A line of depths holds 16 pixels: every other time (1–2 % faster than each).
                if n % 2 == 0 {
                    prefetch(&zc[p]);
                }
                if let Some(t) = texel.get(p) {
                    prefetch(t);
                }
            }
        }
    }

    /// The window search and fixed-point iteration in source `s` for the output pixel at NDC `t`,
    /// which is cell `cell = (i, j)` of a `gw × gh` grid (the client image or an auxiliary grid).
    #[inline(always)]
    pub(super) fn search(&self, k: usize, t: [f32; 2], cell: Cell) -> Option<Match> {
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
}

/// One fixed-point step p ← pix(T − M_cam\[p\]) for targets at NDC `(x[i], y)` from the source
/// pixels `pks` with flows `ms`: `next[i]` is the packed pixel of `T − m` where that is inside
/// the `wf × hf` source and not `pks[i]`, else [`NO_SPLAT`]. The arithmetic of [`pixel_of_ndc`],
/// without branches.
///
/// A target that stopped (or has no splat: its flow is NaN) stops again: the step depends on
/// its pixel and flow alone, which stay. So the whole row needs no mask of those still moving.
#[inline(always)]
fn fixed_point_step(
    pks: &[u32],
    ms: &[[f32; 2]],
    x: &[f32],
    y: f32,
    next: &mut [u32],
    wf: f32,
    hf: f32,
) {
    let len = next.len();
    let (pks, ms, x) = (&pks[..len], &ms[..len], &x[..len]);
    for i in 0..len {
        let (pk, m) = (pks[i], ms[i]);
        let fx = (x[i] - m[0] + 1.0) * 0.5 * wf;
        let fy = (1.0 - (y - m[1])) * 0.5 * hf;
        let inside = fx >= 0.0 && fy >= 0.0 && fx < wf && fy < hf;
        let c = packed_cell(inside, fx, fy);
        next[i] = if inside & (c != pk) { c } else { NO_SPLAT };
    }
}

/// The indices `i` with `q[i] != NO_SPLAT`, in order, written to `out[..n]`; returns `n`.
///
/// A mask per eight entries (`mask8`: bit `l` set where entry `l` is not [`NO_SPLAT`]), then a
/// step per set bit: the pixels still moving after a few iterations are few, so this reads the
/// row at a fraction of an instruction per pixel where a branch-free write per pixel costs
/// several.
#[inline(always)]
fn list_moving(q: &[u32], out: &mut [u32], mask8: impl Fn(&[u32; 8]) -> u32) -> usize {
    let mut n = 0;
    let chunks = q.chunks_exact(8);
    let tail = chunks.remainder();
    let mut put = |base: usize, mut bits: u32| {
        while bits != 0 {
            out[n] = (base + bits.trailing_zeros() as usize) as u32;
            n += 1;
            bits &= bits - 1;
        }
    };
    for (c, chunk) in chunks.enumerate() {
        put(8 * c, mask8(chunk.try_into().unwrap()));
    }
    put(q.len() - tail.len(), live_bits(tail));
    n
}

/// Bit `l` set where `q[l]` is not [`NO_SPLAT`] (`q` of at most 32 entries).
#[inline(always)]
fn live_bits(q: &[u32]) -> u32 {
    let mut bits = 0u32;
    for (l, &v) in q.iter().enumerate() {
        bits |= u32::from(v != NO_SPLAT) << l;
    }
    bits
}

/// The loops of [`Resolve::search_row`] that load by source pixel (gathers): the flow `M_cam` at
/// the pixels the targets move to, and the client depth at the pixels they end on.
///
/// Scalar loops cost ~10 instructions per load (unpack, multiply-add, bounds check, branch on
/// [`NO_SPLAT`]), and the compiler does not vectorise them for AVX2: LLVM emits gathers there
/// only for processors it tunes as having fast ones, which no target feature turns on. [`Portable`]
/// is the scalar loop, [`x86::Avx2`] the gather instructions; both load the same values, so every
/// build gives the same bytes. [`Resolve::gather_texels`](super::Resolve) loads the texels of a
/// row with them too ([`Gathers::texels`]).
pub(super) trait Gathers: Copy {
    /// Whether the build that holds this has fused multiply-add instructions (the AVX2 and
    /// AVX-512 tiers, which both use [`x86::Avx2`]): then the search's last stage computes its
    /// quotients by the source's sides with [`centre_quotient`], else with the divider.
    const FMA: bool;

    /// Where `next[i] != NO_SPLAT` the target moves there: `pks[i] = next[i]` and
    /// `ms[i] = flow[pix(next[i])]`; elsewhere both are kept. Returns how many moved.
    fn moves(
        self,
        flow: &[[f32; 2]],
        sw: usize,
        next: &[u32],
        pks: &mut [u32],
        ms: &mut [[f32; 2]],
    ) -> usize;

    /// Stage 1: `pks[i] = first[i]` and `ms[i] = flow[pix(first[i])]`, NaN where `first[i]` is
    /// [`NO_SPLAT`].
    fn firsts(
        self,
        flow: &[[f32; 2]],
        sw: usize,
        first: &[u32],
        pks: &mut [u32],
        ms: &mut [[f32; 2]],
    );

    /// `zg[i] = zc[pix(pks[i])]`, NaN where `pks[i] == NO_SPLAT`.
    fn depths(self, zc: &[f32], sw: usize, pks: &[u32], zg: &mut [f32]);

    /// [`list_moving`]: the indices of the entries of `q` that are not [`NO_SPLAT`].
    fn list(self, q: &[u32], out: &mut [u32]) -> usize;

    /// `out[i] = table[p[i]]` as two words, low first (the texels of a run of pixels with one
    /// source, [`texel`](super::pair::texel)). Every `p[i]` is below `table.len()`.
    fn texels(self, table: &[u64], p: &[u32], out: &mut [[u32; 2]]);
}

/// [`Gathers`] in plain Rust, for every processor.
#[derive(Clone, Copy)]
pub(super) struct Portable;

impl Gathers for Portable {
    const FMA: bool = false;

    #[inline(always)]
    fn moves(
        self,
        flow: &[[f32; 2]],
        sw: usize,
        next: &[u32],
        pks: &mut [u32],
        ms: &mut [[f32; 2]],
    ) -> usize {
        let mut n = 0;
        // Nearly every target moves in the first iteration and few in the later ones: either
        // way the branch is predictable, and cheaper than listing them.
        for ((pk, m), &q) in pks.iter_mut().zip(ms.iter_mut()).zip(next) {
            if q != NO_SPLAT {
                let (ni, nj) = unpack_pixel(q);
                *pk = q;
                *m = flow[nj * sw + ni];
                n += 1;
            }
        }
        n
    }

    #[inline(always)]
    fn firsts(
        self,
        flow: &[[f32; 2]],
        sw: usize,
        first: &[u32],
        pks: &mut [u32],
        ms: &mut [[f32; 2]],
    ) {
        for ((pk, m), &q) in pks.iter_mut().zip(ms.iter_mut()).zip(first) {
            *pk = q;
            *m = if q == NO_SPLAT {
                [f32::NAN; 2]
            } else {
                let (ni, nj) = unpack_pixel(q);
                flow[nj * sw + ni]
            };
        }
    }

    #[inline(always)]
    fn depths(self, zc: &[f32], sw: usize, pks: &[u32], zg: &mut [f32]) {
        for (z, &pk) in zg.iter_mut().zip(pks) {
            let (pi, pj) = unpack_pixel(pk);
            *z = if pk == NO_SPLAT {
                f32::NAN
            } else {
                zc[pj * sw + pi]
            };
        }
    }

    #[inline(always)]
    fn list(self, q: &[u32], out: &mut [u32]) -> usize {
        list_moving(q, out, |c| live_bits(c))
    }

    #[inline(always)]
    fn texels(self, table: &[u64], p: &[u32], out: &mut [[u32; 2]]) {
        for (t, &p) in out.iter_mut().zip(p) {
            let tex = table[p as usize];
            *t = [tex as u32, (tex >> 32) as u32];
        }
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) mod x86 {
    use std::arch::x86_64::*;

    use super::{Gathers, Portable, NO_SPLAT};

    /// [`Gathers`] with AVX2's gather instructions, eight targets at a time (the rest of a row
    /// as [`Portable`]). Only code compiled for AVX2 can make one ([`Avx2::new`]), and such code
    /// runs only where the processor has it, so holding one proves the instructions exist.
    #[derive(Clone, Copy)]
    pub(in crate::ours) struct Avx2 {
        _private: (),
    }

    impl Avx2 {
        #[target_feature(enable = "avx2")]
        pub(in crate::ours) fn new() -> Self {
            Avx2 { _private: () }
        }
    }

    impl Gathers for Avx2 {
        // Both tiers that hold an `Avx2` are built with FMA (`simd_method`), and `simd_tier`
        // picks them only where the processor has it.
        const FMA: bool = true;

        #[inline(always)]
        fn moves(
            self,
            flow: &[[f32; 2]],
            sw: usize,
            next: &[u32],
            pks: &mut [u32],
            ms: &mut [[f32; 2]],
        ) -> usize {
            // SAFETY: `self` exists, so the processor has AVX2 (see `Avx2`).
            unsafe { moves::<false>(flow, sw, next, pks, ms) }
        }

        #[inline(always)]
        fn firsts(
            self,
            flow: &[[f32; 2]],
            sw: usize,
            first: &[u32],
            pks: &mut [u32],
            ms: &mut [[f32; 2]],
        ) {
            // SAFETY: as in `moves`.
            unsafe { moves::<true>(flow, sw, first, pks, ms) };
        }

        #[inline(always)]
        fn depths(self, zc: &[f32], sw: usize, pks: &[u32], zg: &mut [f32]) {
            // SAFETY: as in `moves`.
            unsafe { depths(zc, sw, pks, zg) }
        }

        #[inline(always)]
        fn list(self, q: &[u32], out: &mut [u32]) -> usize {
            // SAFETY: as in `moves`.
            unsafe { list(q, out) }
        }

        #[inline(always)]
        fn texels(self, table: &[u64], p: &[u32], out: &mut [[u32; 2]]) {
            // SAFETY: as in `moves`.
            unsafe { texels(table, p, out) }
        }
    }

    /// Whether the gathers can index `len` entries: 32-bit signed indices, and at least one
    /// entry to clamp to. Else (never for images of at most 16384² pixels with a splat) the
    /// portable loop does the work, and panics where a target has a pixel outside the table.
    fn gatherable(len: usize) -> bool {
        len > 0 && len <= i32::MAX as usize
    }

    /// The row-major indices `j·sw + i` of eight packed pixels `j << 16 | i`, at most `last`.
    /// The clamp changes no pixel of the source (the window search only finds those); it keeps
    /// any other value from loading outside the table.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn index(pk: __m256i, sw: __m256i, last: __m256i) -> __m256i {
        let i = _mm256_and_si256(pk, _mm256_set1_epi32(0xFFFF));
        let j = _mm256_srli_epi32::<16>(pk);
        _mm256_min_epu32(_mm256_add_epi32(_mm256_mullo_epi32(j, sw), i), last)
    }

    /// [`Gathers::moves`], or with `FIRST` [`Gathers::firsts`] (returning how many have a
    /// pixel).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn moves<const FIRST: bool>(
        flow: &[[f32; 2]],
        sw: usize,
        next: &[u32],
        pks: &mut [u32],
        ms: &mut [[f32; 2]],
    ) -> usize {
        let len = next.len();
        let (pks, ms) = (&mut pks[..len], &mut ms[..len]);
        let portable = |next: &[u32], pks: &mut [u32], ms: &mut [[f32; 2]]| {
            if FIRST {
                Portable.firsts(flow, sw, next, pks, ms);
                next.iter().filter(|&&q| q != NO_SPLAT).count()
            } else {
                Portable.moves(flow, sw, next, pks, ms)
            }
        };
        if !gatherable(flow.len()) {
            return portable(next, pks, ms);
        }
        let last = _mm256_set1_epi32((flow.len() - 1) as i32);
        let swv = _mm256_set1_epi32(sw as i32);
        let none = _mm256_set1_epi32(NO_SPLAT as i32);
        let base = flow.as_ptr().cast::<i64>();
        let nan = _mm256_set1_ps(f32::NAN);
        // Per lane, minus the number of moves.
        let mut count = _mm256_setzero_si256();
        let body = len - len % 8;
        for o in (0..body).step_by(8) {
            // SAFETY: `o + 8 ≤ len`, the length of all three slices, so the loads and stores
            // (8 packed pixels, 8 flows = 64 bytes) stay inside them; the gathers load only in
            // lanes that move, at indices `≤ last < flow.len()`, 8 bytes each ([f32; 2]).
            unsafe {
                let q = _mm256_loadu_si256(next.as_ptr().add(o).cast());
                let stay = _mm256_cmpeq_epi32(q, none);
                let moved = _mm256_xor_si256(stay, none);
                count = _mm256_add_epi32(count, moved);
                let pp = pks.as_mut_ptr().add(o).cast::<__m256i>();
                let mp = ms.as_mut_ptr().add(o).cast::<__m256i>();
                // Where a target stays: its old pixel and flow, or none before the first.
                let (old, old_lo, old_hi) = if FIRST {
                    let nan = _mm256_castps_si256(nan);
                    (none, nan, nan)
                } else {
                    let old = _mm256_loadu_si256(pp);
                    (old, _mm256_loadu_si256(mp), _mm256_loadu_si256(mp.add(1)))
                };
                _mm256_storeu_si256(pp, _mm256_blendv_epi8(q, old, stay));
                let idx = index(q, swv, last);
                let lo = _mm256_mask_i32gather_epi64::<8>(
                    old_lo,
                    base,
                    _mm256_castsi256_si128(idx),
                    _mm256_cvtepi32_epi64(_mm256_castsi256_si128(moved)),
                );
                let hi = _mm256_mask_i32gather_epi64::<8>(
                    old_hi,
                    base,
                    _mm256_extracti128_si256::<1>(idx),
                    _mm256_cvtepi32_epi64(_mm256_extracti128_si256::<1>(moved)),
                );
                _mm256_storeu_si256(mp, lo);
                _mm256_storeu_si256(mp.add(1), hi);
            }
        }
        let mut lanes = [0i32; 8];
        // SAFETY: `lanes` is 32 bytes.
        unsafe { _mm256_storeu_si256(lanes.as_mut_ptr().cast(), count) };
        let n = lanes
            .iter()
            .map(|&c| c.unsigned_abs() as usize)
            .sum::<usize>();
        n + portable(&next[body..], &mut pks[body..], &mut ms[body..])
    }

    /// [`Gathers::list`]: the mask of eight entries from one compare.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn list(q: &[u32], out: &mut [u32]) -> usize {
        let none = _mm256_set1_epi32(NO_SPLAT as i32);
        super::list_moving(q, out, |c| {
            // SAFETY: `c` is 8 entries, 32 bytes.
            let v = unsafe { _mm256_loadu_si256(c.as_ptr().cast()) };
            let stay = _mm256_castsi256_ps(_mm256_cmpeq_epi32(v, none));
            _mm256_movemask_ps(stay) as u32 ^ 0xFF
        })
    }

    /// [`Gathers::depths`].
    #[inline]
    #[target_feature(enable = "avx2")]
    fn depths(zc: &[f32], sw: usize, pks: &[u32], zg: &mut [f32]) {
        let len = pks.len();
        let zg = &mut zg[..len];
        if !gatherable(zc.len()) {
            return Portable.depths(zc, sw, pks, zg);
        }
        let last = _mm256_set1_epi32((zc.len() - 1) as i32);
        let swv = _mm256_set1_epi32(sw as i32);
        let none = _mm256_set1_epi32(NO_SPLAT as i32);
        let nan = _mm256_set1_ps(f32::NAN);
        let body = len - len % 8;
        for o in (0..body).step_by(8) {
            // SAFETY: `o + 8 ≤ len`, the length of both slices; the gather loads only in lanes
            // with a pixel, at indices `≤ last < zc.len()`.
            unsafe {
                let pk = _mm256_loadu_si256(pks.as_ptr().add(o).cast());
                let valid = _mm256_xor_si256(_mm256_cmpeq_epi32(pk, none), none);
                let z = _mm256_mask_i32gather_ps::<4>(
                    nan,
                    zc.as_ptr(),
                    index(pk, swv, last),
                    _mm256_castsi256_ps(valid),
                );
                _mm256_storeu_ps(zg.as_mut_ptr().add(o), z);
            }
        }
        Portable.depths(zc, sw, &pks[body..], &mut zg[body..]);
    }

    /// [`Gathers::texels`]: eight texels (64 bytes) per two gathers. An index past the table,
    /// where the portable loop would panic, is clamped to its last entry instead.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn texels(table: &[u64], p: &[u32], out: &mut [[u32; 2]]) {
        let len = p.len();
        let out = &mut out[..len];
        if !gatherable(table.len()) {
            return Portable.texels(table, p, out);
        }
        let last = _mm256_set1_epi32((table.len() - 1) as i32);
        let base = table.as_ptr().cast::<i64>();
        let body = len - len % 8;
        for o in (0..body).step_by(8) {
            // SAFETY: `o + 8 ≤ len`, the length of both slices, so the load (8 indices) and the
            // stores (8 texels, 64 bytes) stay inside them; the gathers load 8 bytes at indices
            // `≤ last < table.len()` (unsigned minimum, so no index is negative as `i32`). A
            // texel `[lo, hi]` as two `u32` is the `u64`'s little-endian bytes.
            unsafe {
                let idx = _mm256_loadu_si256(p.as_ptr().add(o).cast());
                let idx = _mm256_min_epu32(idx, last);
                let lo = _mm256_i32gather_epi64::<8>(base, _mm256_castsi256_si128(idx));
                let hi = _mm256_i32gather_epi64::<8>(base, _mm256_extracti128_si256::<1>(idx));
                let op = out.as_mut_ptr().add(o).cast::<__m256i>();
                _mm256_storeu_si256(op, lo);
                _mm256_storeu_si256(op.add(1), hi);
            }
        }
        Portable.texels(table, &p[body..], &mut out[body..]);
    }
}

#[cfg(test)]
mod tests {
    use super::super::pair::PairCache;
    use super::super::{Cell, NdcTable, Params, Resolve, Src};
    use super::{Gathers, Portable, SearchRow, Targets, NO_SPLAT};
    use crate::camera::{Camera, Mat4};
    use crate::frame::CameraView;
    use crate::ours::{set_simd_limit, simd_tier, Simd};
    use crate::shadow::Role;

    use crate::ours::draw as rng;

    /// [`Resolve::search_row`] at every SIMD tier gives what [`Resolve::search`] gives for each
    /// target alone, to the bit (pixel, error, depth, visibility), for every way a row meets the
    /// source (the same grid by column, the same grid at listed cells, another grid by NDC,
    /// with NDC at the edges, ±0, ±∞ and NaN) and 0, 1, 3 and 32 iterations. The flows are
    /// random fields of a few pixels (so targets move once, several times or around a cycle)
    /// mixed with NaN, ±∞, ±0 and far-outside components; the depths mix NaN, ∞ and ±0; the
    /// windows have no splat for one cell in six. Rows of 37, 21 and 50 targets leave tails
    /// outside the vector loops, and the auxiliary source's matches carry visibility flags.
    #[test]
    fn search_row_equals_the_search_per_target_at_every_tier() {
        let (sw, sh) = (37, 23);
        let n = sw * sh;
        let mut seed = 0x2545_F491_4F6C_DD1Du64;
        let camera = Camera::new(
            Mat4::look_at([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]),
            Mat4::perspective(60.0, sw as f64 / sh as f64, 0.1, 100.0),
            sw,
            sh,
            "test",
        )
        .unwrap();
        let (color, depth) = (vec![0u8; 3 * n], vec![0.5f32; n]);
        let view = CameraView {
            camera,
            color: &color,
            depth: &depth,
            motion: None,
            shadow: None,
        };
        let special = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            1e30,
            -1e30,
            1.0,
            -1.0,
            2.0,
        ];
        let sources: Vec<Src> = (0..2)
            .map(|k| {
                let mut s = Src::new(
                    view,
                    camera.projector("test").unwrap(),
                    None,
                    Role::Older,
                    k,
                );
                s.bufs.fit(n, k);
                for p in 0..n {
                    let f = |seed: &mut u64, side: usize| {
                        if rng(seed, 12) == 0 {
                            special[rng(seed, special.len() as u64) as usize]
                        } else {
                            (rng(seed, 1201) as f32 - 600.0) / 100.0 * 2.0 / side as f32
                        }
                    };
                    s.bufs.flow[p] = [f(&mut seed, sw), f(&mut seed, sh)];
                    s.bufs.zc[p] = if rng(&mut seed, 8) == 0 {
                        special[rng(&mut seed, 5) as usize]
                    } else {
                        rng(&mut seed, 1000) as f32 / 1000.0
                    };
                    s.bufs.init[p] = if rng(&mut seed, 6) == 0 {
                        NO_SPLAT
                    } else {
                        let (i, j) = (p % sw, p / sw);
                        let near = |seed: &mut u64, c: usize, side: usize| {
                            (c + rng(seed, 5) as usize).saturating_sub(2).min(side - 1)
                        };
                        super::super::pack_pixel(near(&mut seed, i, sw), near(&mut seed, j, sh))
                    };
                }
                s
            })
            .collect();
        let mut pair = PairCache::default();
        pair.sources = vec![Default::default(), Default::default()];
        pair.sources[1].vis = (0..n).map(|_| rng(&mut seed, 2) as u8).collect();
        let p = Params::default();
        let resolve = |iterations| Resolve {
            params: &p,
            alpha: 0.5,
            client_w: sw,
            client_h: sh,
            sources: &sources,
            bidirectional: false,
            eps_e: 1.0,
            eps_e_aux: 1.0,
            eps_z: 1.0,
            eps_z_aux: 1.0,
            iterations,
            aux: Vec::new(),
            client_ndc: NdcTable::new(sw, sh),
            pair: &pair,
            palettes: Vec::new(),
        };
        // The rows: the source's own grid by column and at listed cells, and a 50×31 grid
        // found from NDC, whose targets include edge and special values.
        let own = NdcTable::new(sw, sh);
        let (gw, gh) = (50, 31);
        let other = NdcTable::new(gw, gh);
        let cols: Vec<u32> = (0..21).map(|_| rng(&mut seed, sw as u64) as u32).collect();
        let listed_x: Vec<f32> = cols.iter().map(|&c| own.x[c as usize]).collect();
        let mut other_x = other.x.clone();
        for (t, v) in [-1.0, 1.0, -0.0, 0.0, f32::NAN, f32::INFINITY, 0.999_999_9]
            .into_iter()
            .enumerate()
        {
            other_x[7 * t] = v;
        }
        let mut checked = 0;
        for iterations in [0, 1, 3, 32] {
            let r = resolve(iterations);
            for tier in [Simd::Baseline, Simd::Avx2, Simd::Avx512] {
                set_simd_limit(tier);
                let mut row = SearchRow::default();
                for k in 0..2 {
                    for j in 0..gh {
                        let mut cases = vec![(&other_x[..], other.y[j], j, gw, gh, None)];
                        if j < sh {
                            cases.push((&own.x[..], own.y[j], j, sw, sh, None));
                            cases.push((&listed_x[..], own.y[j], j, sw, sh, Some(&cols[..])));
                        }
                        // Once with a special y.
                        if j == gh - 1 {
                            cases.push((&other_x[..], f32::NAN, 0, gw, gh, None));
                            cases.push((&other_x[..], -1.0, 0, gw, gh, None));
                        }
                        for (x, y, j, gw, gh, cols) in cases {
                            let t = Targets {
                                x,
                                y,
                                j,
                                gw,
                                gh,
                                cols,
                            };
                            r.search_row(k, &t, &mut row);
                            for (m, &xm) in x.iter().enumerate() {
                                let i = cols.map_or(m, |c| c[m] as usize);
                                let want = r.search(k, [xm, y], Cell { i, j, gw, gh });
                                let got = row.found(m);
                                let bits = |o: Option<super::super::Match>| {
                                    o.map(|o| (o.p, o.e.to_bits(), o.z.to_bits(), o.vis))
                                };
                                assert_eq!(
                                    bits(got),
                                    bits(want),
                                    "{tier:?} (as {:?}), {iterations} iterations, source {k}, \
                                     row {j} of {gw}×{gh}, target {m}",
                                    simd_tier()
                                );
                                checked += usize::from(want.is_some());
                            }
                        }
                    }
                }
            }
        }
        set_simd_limit(Simd::Avx512);
        // The random fields leave most targets with a match.
        assert!(checked > 10_000, "{checked}");
    }

    /// The gathers of the AVX2 build ([`super::x86::Avx2`]) give the portable loops' results and
    /// counts, on rows of every length up to 40 (tails of every size) that mix targets with and
    /// without a pixel, and the list of those that are not [`NO_SPLAT`] is theirs.
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn avx2_gathers_equal_the_portable_loops() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        // SAFETY: the processor has AVX2 (checked above).
        let g = unsafe { super::x86::Avx2::new() };
        let (sw, sh) = (29, 7);
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let flow: Vec<[f32; 2]> = (0..sw * sh)
            .map(|_| [rng(&mut seed, 1000) as f32, -(rng(&mut seed, 1000) as f32)])
            .collect();
        let zc: Vec<f32> = (0..sw * sh).map(|_| rng(&mut seed, 1000) as f32).collect();
        for len in 0..=40 {
            for none_in in [0, 3, 8] {
                let pixels: Vec<u32> = (0..len)
                    .map(|_| {
                        if rng(&mut seed, 8) < none_in {
                            NO_SPLAT
                        } else {
                            let (i, j) = (rng(&mut seed, sw as u64), rng(&mut seed, sh as u64));
                            super::super::pack_pixel(i as usize, j as usize)
                        }
                    })
                    .collect();
                let start: Vec<u32> = (0..len).map(|_| rng(&mut seed, 99) as u32).collect();
                // Moves from `start` (or firsts), then the depths at the pixels and the list.
                let outcome = |g: &dyn Gathers2, first: bool| {
                    let (mut pk, mut m) = (start.clone(), vec![[0.5f32, -0.0]; len]);
                    let (mut z, mut list) = (vec![0f32; len], vec![0u32; len]);
                    let moved = if first {
                        g.firsts(&flow, sw, &pixels, &mut pk, &mut m);
                        0
                    } else {
                        g.moves(&flow, sw, &pixels, &mut pk, &mut m)
                    };
                    g.depths(&zc, sw, &pk, &mut z);
                    let listed = g.list(&pixels, &mut list);
                    let m: Vec<[u32; 2]> = m.iter().map(|m| m.map(f32::to_bits)).collect();
                    let z: Vec<u32> = z.iter().map(|z| z.to_bits()).collect();
                    (pk, m, z, list, moved, listed)
                };
                for first in [false, true] {
                    assert_eq!(
                        outcome(&g, first),
                        outcome(&Portable, first),
                        "{len} targets, {none_in} in 8 without a pixel, first {first}"
                    );
                }
            }
        }
    }

    /// [`Gathers`] as a trait object, so that one closure runs both builds.
    trait Gathers2 {
        fn moves(
            &self,
            f: &[[f32; 2]],
            sw: usize,
            q: &[u32],
            pk: &mut [u32],
            m: &mut [[f32; 2]],
        ) -> usize;
        fn firsts(&self, f: &[[f32; 2]], sw: usize, q: &[u32], pk: &mut [u32], m: &mut [[f32; 2]]);
        fn depths(&self, zc: &[f32], sw: usize, pk: &[u32], z: &mut [f32]);
        fn list(&self, q: &[u32], out: &mut [u32]) -> usize;
    }

    impl<G: Gathers> Gathers2 for G {
        fn moves(
            &self,
            f: &[[f32; 2]],
            sw: usize,
            q: &[u32],
            pk: &mut [u32],
            m: &mut [[f32; 2]],
        ) -> usize {
            Gathers::moves(*self, f, sw, q, pk, m)
        }
        fn firsts(&self, f: &[[f32; 2]], sw: usize, q: &[u32], pk: &mut [u32], m: &mut [[f32; 2]]) {
            Gathers::firsts(*self, f, sw, q, pk, m);
        }
        fn depths(&self, zc: &[f32], sw: usize, pk: &[u32], z: &mut [f32]) {
            Gathers::depths(*self, zc, sw, pk, z);
        }
        fn list(&self, q: &[u32], out: &mut [u32]) -> usize {
            Gathers::list(*self, q, out)
        }
    }
}
