//! The auxiliary cameras (seeds/000 §3.5): each is searched with the same initialisation and
//! fixed-point iteration as the main camera (eqs. 5, 7, 8) and Algorithm 1 with the auxiliary
//! thresholds, once per cell of its own grid ([`AuxGrid`]) and only where the result can reach the
//! output. The best auxiliary match (the nearer if the depths differ, else the smaller error) is
//! merged with the main camera's by §3.5's rules: 1. main found nothing: the auxiliary match;
//! 2. main found a match: the auxiliary one only if it is visible in neither main frame (and
//! nearer, at another depth); 3. neither found one: the previous client frame's colour stays.

use std::sync::atomic::Ordering;

use rayon::prelude::*;

use crate::camera::pixel_of_ndc;

use super::search::{SearchRow, Targets};
use super::select::{Picks, NO_SOURCE};
use super::{Cell, Choice, Match, NdcTable, Resolve, Src};

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
/// (see [`AuxGrid::new`]), and `maybe` is the grid of cells within `R` of a point that is not
/// visible in main. Elsewhere the search could not change a pixel, and skipping it gives the same
/// bytes as searching every cell.
#[derive(Debug)]
pub(super) struct AuxGrid {
    w: usize,
    h: usize,
    /// 1 where the cell may override a main match, else 0 (see above).
    pub(super) maybe: Vec<u8>,
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

impl AuxGrid {
    /// The grid of an auxiliary camera over a `cw × ch` client image, with the cells whose match
    /// may override a main match: `srcs` are the camera's sources (older and newer, or newer
    /// alone) after pass 1, `eps_e_aux` the auxiliary `ε_e` at the client's resolution
    /// ([`Resolve::eps_e_aux`]), `every_cell` asks for every cell to be searched (tests:
    /// [`eager_aux`] read on the caller's thread), and `maybe` is a buffer to reuse.
    pub(super) fn new(
        srcs: &[Src],
        eps_e_aux: f32,
        (cw, ch): (usize, usize),
        every_cell: bool,
        mut maybe: Vec<u8>,
    ) -> AuxGrid {
        // The newer frame's camera (the last source) is present in both modes; both frames share
        // the rig.
        let grid = &srcs[srcs.len() - 1];
        let (w, h) = (grid.proj.width, grid.proj.height);
        // An accepted auxiliary match has error e < ε_e·4 (aspect-scaled NDC, eq. 7), so each of
        // its pixel offsets from the cell centre is below r = ε_e·4·min(W, H)/2 source pixels and
        // its point lands within ⌈r⌉ cells of the cell; one more absorbs rounding.
        let same_grid = srcs.iter().all(|s| (s.proj.width, s.proj.height) == (w, h));
        let r = srcs
            .iter()
            .map(|s| eps_e_aux * s.proj.width.min(s.proj.height) as f32 / 2.0)
            .fold(0.0f32, f32::max);
        let reach = r.ceil() as usize + 1;
        maybe.clear();
        if !same_grid || !r.is_finite() || reach >= w.min(h) / 2 || every_cell {
            // The bound does not apply (or covers everything): search every cell.
            maybe.resize(w * h, 1);
        } else {
            maybe.resize(w * h, 0);
            dilate_flags(srcs, w, h, reach, &mut maybe);
        }
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
}

/// The auxiliary cells resolved while one block of output rows is resolved, for the grid rows
/// `row0..row0 + rows` that the block covers. Blocks resolve their cells independently (a cell on
/// the boundary of two blocks may be searched twice, with the same result), so the output does
/// not depend on how rayon schedules them.
#[derive(Debug, Default)]
pub(super) struct AuxBlock {
    row0: usize,
    rows: usize,
    /// 0: not searched yet; 1: searched, see `cells`.
    done: Vec<u8>,
    cells: Vec<Option<AuxCell>>,
}

impl AuxBlock {
    /// Prepares for the grid rows that output rows `j0..j1` fall on.
    pub(super) fn reset(&mut self, grid: &AuxGrid, j0: usize, j1: usize) {
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

/// The auxiliary cells one output row needs searched ([`Resolve::aux_row`]): their grid columns
/// and NDC x, and the searches in the camera's older and newer source.
#[derive(Debug, Default)]
pub(super) struct AuxRow {
    cols: Vec<u32>,
    x: Vec<f32>,
    sides: [SearchRow; 2],
}

impl Resolve<'_> {
    /// The auxiliary cameras over a row (§3.5): for the pixels where one can change the result
    /// (main found nothing, or a cell that may override main, see [`AuxGrid`]), the merged
    /// decision of [`Resolve::decide`] replaces the main camera's in `picks`.
    #[inline(never)]
    pub(super) fn aux_row(
        &self,
        j: usize,
        picks: &mut Picks,
        batch: &mut AuxRow,
        blocks: &mut [AuxBlock],
    ) {
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
    pub(super) static EAGER_AUX: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Whether every auxiliary cell is to be searched (tests only; read on the thread that calls
/// [`reproject`](crate::reproject), as the tests set it there).
#[inline]
pub(super) fn eager_aux() -> bool {
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
