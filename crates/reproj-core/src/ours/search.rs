//! The search in one source image (seeds/000 §3.1 with the changes of §3.5): the nearest splat in
//! the window around the target's cell (from `pass1`) initialises the fixed-point iteration
//! `p ← pix(T − M_cam[p])` (eq. 5, with the client-pose flows of eqs. 12 and 13 in place of eq. 4),
//! and the reprojection error and client depth of its result (eqs. 7, 8) are what Algorithm 1
//! compares. [`Resolve::search_row`] searches a row of targets in stages,
//! [`Resolve::search`] one target.

use crate::camera::pixel_of_ndc;

use super::simd::simd_method;
use super::{pack_pixel, packed_cell, unpack_pixel, Cell, Match, Resolve, NO_SPLAT};

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
    /// The same for the previous iteration (before the first: the initial pixel).
    prev: Vec<u32>,
    /// Auxiliary sources: whether each match is visible in main (empty for main sources).
    vis: Vec<bool>,
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
        pub(super) fn search_row / search_row_avx2, search_row_avx512 => search_row_impl(&self, k: usize, t: &Targets, row: &mut SearchRow)
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
