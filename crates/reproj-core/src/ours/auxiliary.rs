//! The auxiliary cameras (seeds/000 §3.5): each is searched with the same initialisation and
//! fixed-point iteration as the main camera (eqs. 5, 7, 8) and Algorithm 1 with the auxiliary
//! thresholds, once per cell of its own grid ([`AuxGrid`]) and only where the result can reach the
//! output. The best auxiliary match (the nearer if the depths differ, else the smaller error) is
//! merged with the main camera's by §3.5's rules: 1. main found nothing: the auxiliary match;
//! 2. main found a match: the auxiliary one only if it is visible in neither main frame (and
//! nearer, at another depth); 3. neither found one: the previous client frame's colour stays.

use std::sync::atomic::AtomicU8;

use rayon::prelude::*;

use crate::camera::pixel_of_ndc;

use super::search::{SearchRow, Targets};
use super::select::{Picks, NO_SOURCE};
use super::{Cell, Choice, NdcTable, Resolve, Src};

/// The auxiliary match of one cell: Algorithm 1's [`Choice`] without what the merge does not
/// read, in 16 bytes (the merge copies and compares a few of these per run of pixels). Its colour
/// (Algorithm 2) is found only where an output pixel takes it: most cells lose to the main camera
/// (§3.5 rule 2).
#[derive(Debug, Clone, Copy)]
struct AuxCell {
    /// Source index: below 2·(1 + MAX_AUX) < 255 (`FrameView::validate`).
    src: u8,
    visible_in_main: bool,
    p: u32,
    e: f32,
    z: f32,
}

impl AuxCell {
    fn new(c: Choice) -> AuxCell {
        AuxCell {
            src: c.src as u8,
            visible_in_main: c.visible_in_main,
            p: c.m.p,
            e: c.m.e,
            z: c.m.z,
        }
    }
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
        srcs: &mut [Src],
        eps_e_aux: f32,
        (cw, ch): (usize, usize),
        every_cell: bool,
        mut maybe: Vec<u8>,
    ) -> AuxGrid {
        // The newer frame's camera (the last source) is present in both modes; both frames share
        // the rig.
        let grid = &srcs[srcs.len() - 1];
        let (w, h) = (grid.proj.width, grid.proj.height);
        // An accepted auxiliary match has error e < ε_e·4 (aspect-scaled NDC, eq. 7): its point
        // lies less than r cells from the cell's centre ([`Reach::radius`]), so it lands in a
        // cell near that one ([`Reach`]), or outside the grid near its edge.
        let same_grid = srcs.iter().all(|s| (s.proj.width, s.proj.height) == (w, h));
        let r = srcs
            .iter()
            .map(|s| Reach::radius(eps_e_aux, s.proj.width, s.proj.height))
            .fold(0.0f32, f32::max);
        // A border as deep as half the grid would flag every cell anyway.
        let reach = Reach::new(r).filter(|k| k.border < w.min(h) / 2);
        maybe.clear();
        match reach {
            Some(reach) if same_grid && !every_cell => {
                maybe.resize(w * h, 0);
                let flags = srcs.iter_mut().map(|s| s.bufs.invisible.as_mut_slice());
                dilate_flags(flags, w, h, &reach, &mut maybe);
            }
            // The bound does not apply (or covers everything): search every cell.
            _ => maybe.resize(w * h, 1),
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
        }
        AuxGrid {
            w,
            h,
            maybe,
            col_of,
            row_of,
            cols_of_cell,
            ndc: NdcTable::new(w, h),
        }
    }
}

/// For more than two auxiliary cameras, makes the grids' [`AuxGrid::maybe`] one set: a cell is
/// flagged in every grid when it is in any (grids of different sizes cover the client image with
/// different cells, so all of theirs are searched).
///
/// Why: the merge takes the best auxiliary match over every grid (§3.5) before it asks whether
/// that match is visible in main, and "best" (the nearer unless the depths are similar, then the
/// smaller error; [`better_aux`]) is not transitive. A cell that is not flagged holds no match
/// that could override main itself, but its match can still change which of the others is best.
/// With two grids that can only turn an override into none, which [`Resolve::aux_row`] rechecks
/// where it happens; with three or more, the best of the flagged cells can differ from the best
/// of every cell either way. Flagging a cell in every grid or in none makes the matches the
/// merge compares over each pixel those of every cell. (Done for two grids too, at 1280×720 it
/// cost 4.7 % more instructions per frame than the recheck.)
pub(super) fn unite_maybe(grids: &mut [AuxGrid]) {
    if grids.len() <= 2 {
        return;
    }
    let (head, rest) = grids.split_first_mut().expect("more than two grids");
    if rest.iter().any(|g| (g.w, g.h) != (head.w, head.h)) {
        for g in std::iter::once(head).chain(rest) {
            g.maybe.fill(1);
        }
        return;
    }
    for g in rest.iter() {
        for (m, v) in head.maybe.iter_mut().zip(&g.maybe) {
            *m |= v;
        }
    }
    for g in rest {
        g.maybe.copy_from_slice(&head.maybe);
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
    /// The cells of grid row `spans_row` that may override main ([`AuxGrid::maybe`]), in order,
    /// kept for the next output row: output rows outnumber grid rows, and neighbouring output
    /// rows fall on the same grid row.
    spans: Vec<Span>,
    spans_row: usize,
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
        self.spans_row = usize::MAX;
    }
}

/// The auxiliary cells one output row needs searched ([`Resolve::aux_row`]): their grid columns
/// and NDC x, and the searches in the camera's older and newer source; then each grid's place in
/// the merge.
#[derive(Debug, Default)]
pub(super) struct AuxRow {
    cols: Vec<u32>,
    x: Vec<f32>,
    sides: [SearchRow; 2],
    grids: Vec<GridRow>,
    /// The pixels whose override of main is decided over every grid's cell ([`Resolve::aux_row`]).
    recheck: Vec<u32>,
}

/// A cell of an auxiliary grid that may override main: the client columns `s..e` that fall in it
/// (never empty) and its index `k` in the block's cells.
#[derive(Debug, Clone, Copy)]
struct Span {
    s: u32,
    e: u32,
    k: u32,
}

impl Span {
    /// After a grid's last span: it starts and ends after every client column.
    const PAST: Span = Span {
        s: u32::MAX,
        e: u32::MAX,
        k: 0,
    };
}

/// One grid's place in the merge of a row: `cur` is its first span not yet merged (or
/// [`Span::PAST`]), `next` the index of the one after it in the block's spans.
#[derive(Debug, Clone, Copy)]
struct GridRow {
    cur: Span,
    next: usize,
}

impl GridRow {
    /// At the first of `spans`.
    fn new(spans: &[Span]) -> GridRow {
        let mut r = GridRow {
            cur: Span::PAST,
            next: 0,
        };
        r.advance(spans);
        r
    }

    fn advance(&mut self, spans: &[Span]) {
        self.cur = spans.get(self.next).copied().unwrap_or(Span::PAST);
        self.next += 1;
    }
}

/// Rule 2 of §3.5 for an auxiliary match `a` that is not visible in main, over a pixel whose main
/// match has depth `z`: it overrides main when nearer and at another depth.
#[inline(always)]
fn overrides_main(a: &AuxCell, z: f32, eps_z_aux: f32) -> bool {
    let sim = 2.0 * (a.z - z).abs() < eps_z_aux;
    !sim && a.z > z
}

/// The best of two auxiliary matches for one pixel (§3.5): the nearer if the depths differ, else
/// the smaller error; `b`, from an earlier grid, stays on ties.
#[inline(always)]
fn better_aux<'a>(b: Option<&'a AuxCell>, c: &'a AuxCell, eps_z_aux: f32) -> &'a AuxCell {
    match b {
        None => c,
        Some(b) => {
            let sim = 2.0 * (c.z - b.z).abs() < eps_z_aux;
            if (!sim && c.z > b.z) || (sim && c.e < b.e) {
                c
            } else {
                b
            }
        }
    }
}

/// Calls `f(s..e, aux)` for each run `s..e` of client columns that fall in the same flagged cells
/// of every grid, in order, where `aux` is the best auxiliary match of those cells (in grid order,
/// as the ties need; `None` if none of them found one). `grids[g]` starts at the first of
/// `blocks[g].spans`; columns in no flagged cell are in no run.
///
/// A sweep over every grid's flagged cells at once: a run starts at the first flagged column not
/// merged yet and ends where a cell that covers it ends or another grid's next cell begins.
#[inline(always)]
fn for_each_run<'a>(
    grids: &mut [GridRow],
    blocks: &'a [AuxBlock],
    eps_z_aux: f32,
    mut f: impl FnMut(std::ops::Range<usize>, Option<&'a AuxCell>),
) {
    let mut pos = grids.iter().map(|r| r.cur.s).min().unwrap_or(u32::MAX);
    while pos != u32::MAX {
        let mut end = u32::MAX;
        let mut aux: Option<&AuxCell> = None;
        for (r, block) in grids.iter().zip(blocks) {
            if r.cur.s > pos {
                end = end.min(r.cur.s);
                continue;
            }
            end = end.min(r.cur.e);
            debug_assert!(block.done[r.cur.k as usize] != 0);
            if let Some(c) = &block.cells[r.cur.k as usize] {
                aux = Some(better_aux(aux, c, eps_z_aux));
            }
        }
        f(pos as usize..end as usize, aux);
        // The cells that end here are done; the next run starts here if a cell still covers
        // this column, else at the next flagged one.
        let mut next = u32::MAX;
        for (r, block) in grids.iter_mut().zip(blocks) {
            if r.cur.e == end {
                r.advance(&block.spans);
            }
            next = next.min(r.cur.s);
        }
        pos = end.max(next);
    }
}

/// Calls `f` with the index of each byte of `bytes` whose lane of `mask(word)` has its high bit
/// set, eight bytes to a word (lanes above `bytes.len()` are read as 0). The bytes looked for
/// (flagged cells, pixels without a main match) are a minority: the listing it replaced, a
/// branch-free step per client pixel, cost 13 instructions per pixel (3.0 M per 640×360 frame).
#[inline(always)]
fn for_each_byte(bytes: &[u8], mask: impl Fn(u64) -> u64, mut f: impl FnMut(usize)) {
    let mut visit = |n: usize, w: u64| {
        let mut m = mask(w) & HIGH_BITS;
        while m != 0 {
            f(8 * n + m.trailing_zeros() as usize / 8);
            m &= m - 1;
        }
    };
    let mut words = bytes.chunks_exact(8);
    for (n, c) in words.by_ref().enumerate() {
        visit(n, u64::from_le_bytes(c.try_into().expect("eight bytes")));
    }
    let rest = words.remainder();
    if !rest.is_empty() {
        let mut last = [0u8; 8];
        last[..rest.len()].copy_from_slice(rest);
        visit(bytes.len() / 8, u64::from_le_bytes(last));
    }
}

/// The high bit of each byte of a word.
const HIGH_BITS: u64 = 0x8080_8080_8080_8080;

/// The high bit of each byte of the result is set where that byte of `w` is nonzero (exact:
/// the low seven bits of a byte plus `0x7f` carry into its high bit and never beyond it).
#[inline(always)]
fn nonzero_bytes(w: u64) -> u64 {
    const LOW: u64 = !HIGH_BITS;
    ((w & LOW) + LOW) | w
}

impl Resolve<'_> {
    /// The auxiliary cameras over a row (§3.5): for the pixels where one can change the result
    /// (main found nothing, or a cell that may override main, see [`AuxGrid`]), the merge of the
    /// auxiliary matches with the main camera's replaces main's in `picks`.
    ///
    /// Merged per run of pixels, not per pixel: where main found a match, the auxiliary match
    /// that competes with it is the best of the flagged cells that cover the pixel, the same for
    /// every pixel of a run that falls in the same cells (two or more client pixels per cell), and
    /// only one that is not visible in main (rule 2) can replace main at all, so most runs need no
    /// per-pixel work. The pixels without a main match are merged one by one, except that one in
    /// the same cells as the pixel before it takes that pixel's result.
    #[inline(never)]
    pub(super) fn aux_row(
        &self,
        j: usize,
        picks: &mut Picks,
        batch: &mut AuxRow,
        blocks: &mut [AuxBlock],
    ) {
        let cw = self.client_w;
        #[cfg(test)]
        let main = (
            picks.src[..cw].to_vec(),
            picks.p[..cw].to_vec(),
            picks.e[..cw].to_vec(),
            picks.z[..cw].to_vec(),
        );
        // The pixels without a main match: each covering grid's cell is searched for them.
        let mut none = std::mem::take(&mut picks.list);
        none.clear();
        for_each_byte(
            &picks.src[..cw],
            |w| !nonzero_bytes(!w),
            |i| none.push(i as u32),
        );
        let AuxRow {
            cols,
            x,
            sides,
            grids,
            recheck,
        } = batch;
        grids.clear();
        // Per grid, the flagged cells (whose client columns may take the auxiliary match over
        // main's) and the cells of the pixels without a main match; those the block has not
        // searched yet are searched together (stage by stage, as the main camera's), so that
        // their loads overlap.
        for (g, (grid, block)) in self.aux.iter().zip(blocks.iter_mut()).enumerate() {
            let aj = grid.row_of[j];
            if aj == u32::MAX {
                grids.push(GridRow::new(&[]));
                continue;
            }
            let aj = aj as usize;
            let base = (aj - block.row0) * grid.w;
            let done = &mut block.done[base..base + grid.w];
            cols.clear();
            if block.spans_row != aj {
                block.spans.clear();
                let maybe = &grid.maybe[aj * grid.w..(aj + 1) * grid.w];
                for_each_byte(maybe, nonzero_bytes, |c| {
                    let (s, e) = grid.cols_of_cell[c];
                    if s < e {
                        block.spans.push(Span {
                            s,
                            e,
                            k: (base + c) as u32,
                        });
                        if done[c] == 0 {
                            done[c] = 1;
                            cols.push(c as u32);
                        }
                    }
                });
                block.spans_row = aj;
            }
            for &i in &none {
                let c = grid.col_of[i as usize];
                if c != u32::MAX && done[c as usize] == 0 {
                    done[c as usize] = 1;
                    cols.push(c);
                }
            }
            grids.push(GridRow::new(&block.spans));
            if cols.is_empty() {
                continue;
            }
            x.clear();
            x.extend(cols.iter().map(|&c| grid.ndc.x[c as usize]));
            let targets = Targets {
                x,
                y: grid.ndc.y[aj],
                j: aj,
                gw: grid.w,
                gh: grid.h,
                cols: Some(cols),
            };
            let cam = 1 + g;
            let srcs = if self.bidirectional {
                2 * cam..2 * cam + 2
            } else {
                cam..cam + 1
            };
            for (k, side) in srcs.zip(sides.iter_mut()) {
                self.search_row(k, &targets, side);
            }
            let [f, b] = &*sides;
            for (nth, &c) in cols.iter().enumerate() {
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
                block.cells[base + c as usize] = choice.map(AuxCell::new);
            }
        }
        let eps_z = self.eps_z_aux;
        let (src, p, e, z) = (
            &mut picks.src[..cw],
            &mut picks.p[..cw],
            &mut picks.e[..cw],
            &mut picks.z[..cw],
        );
        // Where main found a match (§3.5 rule 2): main wins unless the auxiliary point is not
        // visible in the main camera, nearer, and at another depth.
        //
        // The best match of the flagged cells over a pixel is the best of every cell over it
        // except where a grid's cell over it is not flagged: that cell's match, if any, is
        // visible in main and cannot override main itself, but it may be the better one (the
        // order of `better_aux` is not transitive) and so keep the flagged cell's match from
        // overriding. With two grids that changes an override into none and nothing else, so an
        // override is rechecked over every grid's cell where one of them is not flagged (rare:
        // overrides are); with more grids the flags are one set ([`unite_maybe`]) and the
        // recheck never happens.
        recheck.clear();
        let flagged_everywhere = |i: usize| {
            self.aux.iter().all(|g| {
                let (ai, aj) = (g.col_of[i], g.row_of[j]);
                ai == u32::MAX || aj == u32::MAX || g.maybe[aj as usize * g.w + ai as usize] != 0
            })
        };
        for_each_run(grids, blocks, eps_z, |run, aux| {
            let Some(&a) = aux.filter(|a| !a.visible_in_main) else {
                return;
            };
            for i in run {
                if src[i] != NO_SOURCE && overrides_main(&a, z[i], eps_z) {
                    if flagged_everywhere(i) {
                        (src[i], p[i], e[i], z[i]) = (a.src, a.p, a.e, a.z);
                    } else {
                        recheck.push(i as u32);
                    }
                }
            }
        });
        for &i in recheck.iter() {
            let i = i as usize;
            let best = self.best_of_every_grid(i, j, blocks);
            if let Some(a) = best.and_then(|(g, k)| blocks[g].cells[k].as_ref()) {
                if !a.visible_in_main && overrides_main(a, z[i], eps_z) {
                    (src[i], p[i], e[i], z[i]) = (a.src, a.p, a.e, a.z);
                }
            }
        }
        // Where main found nothing (rule 1): the best auxiliary match of any covering grid. A
        // pixel in the same cell of every grid as the pixel before it (a cell covers two or more
        // client columns) takes that pixel's result: the cells were searched for it, so the
        // merge would read and combine the same values again.
        let mut last: Option<(usize, Option<(usize, usize)>)> = None;
        for &i in &none {
            let i = i as usize;
            let best = match last {
                Some((l, best)) if self.aux.iter().all(|g| g.col_of[i] == g.col_of[l]) => best,
                _ => self.best_of_every_grid(i, j, blocks),
            };
            last = Some((i, best));
            if let Some(a) = best.and_then(|(g, k)| blocks[g].cells[k].as_ref()) {
                (src[i], p[i], e[i], z[i]) = (a.src, a.p, a.e, a.z);
            }
        }
        picks.list = none;
        #[cfg(test)]
        self.check_merge(j, main, picks, blocks);
    }

    /// The best auxiliary match over client pixel `(i, j)` of every grid's cell that covers it
    /// (searched where the block has not yet), as (grid, index in its block's cells), or `None`.
    ///
    /// Its fields are read where they lie, one at a time: a copy of the whole cell loads 16
    /// bytes that the search has just stored field by field, which waits for those stores to
    /// complete (no store forwarding); that wait took about a sixth of `aux_row` in
    /// `forward_splat`, whose main camera leaves the most pixels without a match.
    fn best_of_every_grid(
        &self,
        i: usize,
        j: usize,
        blocks: &mut [AuxBlock],
    ) -> Option<(usize, usize)> {
        let mut best: Option<(usize, usize)> = None;
        for (g, grid) in self.aux.iter().enumerate() {
            let (ai, aj) = (grid.col_of[i], grid.row_of[j]);
            if ai == u32::MAX || aj == u32::MAX {
                continue;
            }
            let k = self.searched_cell(1 + g, grid, &mut blocks[g], ai as usize, aj as usize);
            if let Some(c) = &blocks[g].cells[k] {
                let b = best.and_then(|(bg, bk)| blocks[bg].cells[bk].as_ref());
                if std::ptr::eq(better_aux(b, c, self.eps_z_aux), c) {
                    best = Some((g, k));
                }
            }
        }
        best
    }

    /// The index in `block.cells` of cell `(ai, aj)` of auxiliary camera `cam`'s grid (`1 +
    /// grid index`), whose Algorithm 1 result is searched on first use within the block.
    #[inline]
    fn searched_cell(
        &self,
        cam: usize,
        grid: &AuxGrid,
        block: &mut AuxBlock,
        ai: usize,
        aj: usize,
    ) -> usize {
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
                .map(AuxCell::new);
            block.done[k] = 1;
        }
        k
    }
}

/// Main's matches on a row (`Picks::src`, `p`, `e`, `z`), as `aux_row` found them.
#[cfg(test)]
type MainMatches = (Vec<u8>, Vec<u32>, Vec<f32>, Vec<f32>);

#[cfg(test)]
impl Resolve<'_> {
    /// The match pixel `(i, j)` keeps, or `None` for no match: `main` is Algorithm 1's choice for
    /// the main camera ([`Resolve::choose_row`]), merged with the auxiliary cameras' (§3.5) pixel
    /// by pixel: the reference that the runs of [`Resolve::aux_row`] must equal.
    fn decide(
        &self,
        i: usize,
        j: usize,
        main: Option<AuxCell>,
        blocks: &mut [AuxBlock],
    ) -> Option<AuxCell> {
        // Best auxiliary match (§3.5): the nearer if depths differ, else the smaller error.
        let mut aux: Option<AuxCell> = None;
        for (g, (grid, block)) in self.aux.iter().zip(blocks.iter_mut()).enumerate() {
            let (ai, aj) = (grid.col_of[i], grid.row_of[j]);
            if ai == u32::MAX || aj == u32::MAX {
                continue;
            }
            // Every cell over the pixel, flagged or not (searched here where `aux_row` did not):
            // the merge must decide as if every cell were searched.
            let k = self.searched_cell(1 + g, grid, block, ai as usize, aj as usize);
            if let Some(c) = block.cells[k] {
                aux = Some(*better_aux(aux.as_ref(), &c, self.eps_z_aux));
            }
        }
        // Merge with main (§3.5 rules 1–3): main wins unless it found nothing, or the auxiliary
        // point is nearer, at a different depth, and not visible in the main camera.
        let use_aux = match (&main, &aux) {
            (Some(m), Some(a)) => !a.visible_in_main && overrides_main(a, m.z, self.eps_z_aux),
            (None, Some(_)) => true,
            (_, None) => false,
        };
        if use_aux {
            aux
        } else {
            main
        }
    }

    /// Asserts that [`Resolve::aux_row`] left in `picks` what [`Resolve::decide`] gives for
    /// every pixel of row `j` from main's matches, bit for bit.
    fn check_merge(
        &self,
        j: usize,
        (src, p, e, z): MainMatches,
        picks: &Picks,
        blocks: &mut [AuxBlock],
    ) {
        for i in 0..self.client_w {
            let main = (src[i] != NO_SOURCE).then_some(AuxCell {
                src: src[i],
                // Not read for main (only an auxiliary match's decides the merge).
                visible_in_main: true,
                p: p[i],
                e: e[i],
                z: z[i],
            });
            let want = self
                .decide(i, j, main, blocks)
                .map(|c| (c.src, c.p, c.e.to_bits(), c.z.to_bits()));
            let got = (picks.src[i] != NO_SOURCE).then(|| {
                (
                    picks.src[i],
                    picks.p[i],
                    picks.e[i].to_bits(),
                    picks.z[i].to_bits(),
                )
            });
            assert_eq!(got, want, "pixel ({i}, {j})");
        }
    }
}

#[cfg(test)]
thread_local! {
    /// Tests set this to search every auxiliary cell, the reference the lazy search must equal.
    pub(super) static EAGER_AUX: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Whether every auxiliary cell is to be searched (tests only; read on the thread that calls
/// [`reproject`](crate::reproject()), as the tests set it there).
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

/// Which cells a point can be matched from: the cells whose centre lies less than `r` cells
/// from some position in the cell the point lands in, i.e. the offsets `(di, dj)` with
/// `max(|di| − ½, 0)² + max(|dj| − ½, 0)² < r'²` for `r' = r +` [`Reach::MARGIN`], a disk with
/// square corners; and the cells whose centre lies less than `r'` from the grid's edge, which
/// points just outside the grid can reach (pass 1 flags only points that land inside it). The
/// search's error is the Euclidean distance of the matched point from the cell centre (eq. 7),
/// so the set is round: at the default thresholds and 1280×720 (r = 2.88 cells) it holds 37
/// cells and the border is 3 cells deep, where the square of side `2⌈r⌉ + 3` that `maybe` was
/// dilated by before held 81 cells, and its border was 4 deep.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct Reach {
    /// The stencil as a union of centred rectangles of half-widths `(a, b)`: `a` across the row,
    /// `b` down the column, `a` rising and `b` falling.
    rects: Vec<(usize, usize)>,
    /// Cells from each edge of the grid that points outside it can reach.
    border: usize,
}

impl Reach {
    /// How far, in cells, the computed positions may be from where exact arithmetic puts them:
    /// the search's error and the landing cell are each a few f32 roundings of NDC values of
    /// magnitude about 1 (about 10⁻⁴ of a cell at 16384 cells across); a hundredth of a cell
    /// covers them with room to spare.
    const MARGIN: f64 = 0.01;

    /// The distance `r` in cells of a `w × h` grid below which an auxiliary match with error
    /// below `eps_e_aux` lies from its cell's centre: the error (eq. 7) is aspect-scaled NDC, in
    /// which a cell measures `2 / min(w, h)` on both axes.
    pub(super) fn radius(eps_e_aux: f32, w: usize, h: usize) -> f32 {
        eps_e_aux * w.min(h) as f32 / 2.0
    }

    /// The reach of matches less than `r` cells from their cell's centre, or `None` when `r` is
    /// not finite.
    pub(super) fn new(r: f32) -> Option<Reach> {
        if !r.is_finite() {
            return None;
        }
        let r2 = (f64::from(r.max(0.0)) + Reach::MARGIN).powi(2);
        let gap = |d: usize| (d as f64 - 0.5).max(0.0);
        // Half-width `b` down the column at half-width `a` across the row: the largest with
        // the corner (a, b) inside.
        let down = |a: usize| -> Option<usize> {
            let da = gap(a).powi(2);
            (da < r2).then(|| {
                let mut b = 0;
                while da + gap(b + 1).powi(2) < r2 {
                    b += 1;
                }
                b
            })
        };
        let mut rects: Vec<(usize, usize)> = Vec::new();
        let mut a = 0;
        while let Some(b) = down(a) {
            // A wider rectangle of the same height contains the narrower one.
            if rects.last().is_some_and(|&(_, pb)| pb == b) {
                rects.pop();
            }
            rects.push((a, b));
            a += 1;
        }
        let mut border = 0;
        while (border as f64 + 0.5).powi(2) < r2 {
            border += 1;
        }
        Some(Reach { rects, border })
    }

    /// The largest offset on either axis (the stencil is symmetric).
    #[cfg(test)]
    fn widest(&self) -> usize {
        self.rects.last().map_or(0, |r| r.0)
    }

    /// Whether offset `(di, dj)` is in the stencil.
    #[cfg(test)]
    fn covers(&self, di: usize, dj: usize) -> bool {
        self.rects.iter().any(|&(a, b)| di <= a && dj <= b)
    }
}

/// `maybe[c] = 1` for every cell `c` of the `w × h` grid that `reach` reaches from a cell
/// flagged in any source's `invisible` buffer (`flags`, one per source), or from outside the
/// grid (points just outside it are not flagged); `maybe` arrives zeroed.
fn dilate_flags<'a>(
    flags: impl IntoIterator<Item = &'a mut [AtomicU8]>,
    w: usize,
    h: usize,
    reach: &Reach,
    maybe: &mut [u8],
) {
    // The flags are 0 or 1, so "any" is a bitwise or: each output row is the or of whole input
    // rows, shifted across for the widening, which vectorise, instead of a search per cell.
    //
    // The sources' flags first, or'ed into `base`. Pass 1 wrote them atomically from its bands;
    // it is over, and with `&mut` access (`AtomicU8::get_mut`) they are plain bytes, so this
    // loop vectorises. Read with atomic loads (byte by byte, inside the parallel row pass) they
    // cost 0.6 M instructions per 640×360 frame; here too few to measure.
    //
    // The scratch is taken out of its thread-local, not borrowed across the parallel rows: a
    // thread waiting for them may run another grid's `AuxGrid::new`, which would find it
    // borrowed.
    let mut base = DILATE_SCRATCH.with(|cell| std::mem::take(&mut *cell.borrow_mut()));
    base.clear();
    base.resize(w * h, 0);
    for invisible in flags {
        for (f, v) in base.iter_mut().zip(&mut invisible[..w * h]) {
            *f |= *v.get_mut();
        }
    }
    maybe
        .par_chunks_mut(w)
        .enumerate()
        .with_min_len(16)
        .for_each_init(
            || vec![0u8; w],
            |col, (j, out)| dilate_row(&base, (w, h), j, &reach.rects, col, out),
        );
    DILATE_SCRATCH.with(|cell| *cell.borrow_mut() = base);
    mark_border(w, h, reach.border, maybe);
}

/// `maybe[c] = 1` for the cells less than `border` cells from an edge of the `w × h` grid.
fn mark_border(w: usize, h: usize, border: usize, maybe: &mut [u8]) {
    let (bw, bh) = (border.min(w), border.min(h));
    maybe[..bh * w].fill(1);
    maybe[(h - bh) * w..].fill(1);
    for row in maybe.chunks_mut(w) {
        row[..bw].fill(1);
        row[w - bw..].fill(1);
    }
}

thread_local! {
    /// The sources' flags of [`dilate_flags`], reused.
    static DILATE_SCRATCH: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Row `j` of [`dilate_flags`] into `out`: the or over the rectangles `(a, b)` (`a` rising, `b`
/// falling) of the flags in `base` of rows `j − b ..= j + b`, widened by `a` across the row.
/// `col` is scratch of one row. The rows are or'ed into `col` as `b` grows (the rectangles in
/// reverse), so each input row is read once.
fn dilate_row(
    base: &[u8],
    (w, h): (usize, usize),
    j: usize,
    rects: &[(usize, usize)],
    col: &mut [u8],
    out: &mut [u8],
) {
    let row = |q: usize| &base[q * w..(q + 1) * w];
    let or = |acc: &mut [u8], r: &[u8]| {
        for (m, v) in acc.iter_mut().zip(r) {
            *m |= v;
        }
    };
    col.copy_from_slice(row(j));
    out.fill(0);
    let mut rows = 0;
    for &(a, b) in rects.iter().rev() {
        while rows < b {
            rows += 1;
            if let Some(q) = j.checked_sub(rows) {
                or(col, row(q));
            }
            if j + rows < h {
                or(col, row(j + rows));
            }
        }
        // `out |=` the or of `col` over `i − a ..= i + a` (clipped to the row).
        or(out, col);
        for d in 1..=a.min(w.saturating_sub(1)) {
            or(&mut out[..w - d], &col[d..]);
            or(&mut out[d..], &col[..w - d]);
        }
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::{
        better_aux, dilate_flags, for_each_run, overrides_main, unite_maybe, AuxBlock, AuxCell,
        AuxGrid, GridRow, Reach, Span,
    };

    /// The match of cell `k` of test grid `g` with depth and error in tenths and its visibility
    /// in main.
    fn test_cell(g: usize, k: usize, (z, e, vis): (u8, u8, bool)) -> AuxCell {
        AuxCell {
            src: g as u8,
            visible_in_main: vis,
            p: k as u32,
            e: f32::from(e) * 0.1,
            z: f32::from(z) * 0.1,
        }
    }

    /// A `w × h` test grid with the flags `maybe` and no client pixels mapped to it (the merge
    /// tests give the cells' client columns themselves).
    fn flag_grid(w: usize, h: usize, maybe: Vec<u8>) -> AuxGrid {
        AuxGrid {
            w,
            h,
            maybe,
            col_of: Vec::new(),
            row_of: Vec::new(),
            cols_of_cell: Vec::new(),
            ndc: crate::camera::NdcTable::new(w, h),
        }
    }

    /// A cell of a test grid: how many client columns fall in it, whether it is flagged, and
    /// its match's depth and error (in tenths), if it has one.
    type TestCell = (usize, bool, Option<(u8, u8)>);

    /// One grid on a row of `n` client columns: cells of 0–3 columns each (0: a cell that holds
    /// no client column, as in a grid finer than the client), a flag and a match per cell
    /// (depths and errors from small sets, so that the depth tests and the ties are exercised).
    fn grid(n: usize) -> impl Strategy<Value = Vec<TestCell>> {
        prop::collection::vec(
            (0usize..4, any::<bool>(), prop::option::of((0u8..4, 0u8..3))),
            n + 1,
        )
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

        /// The runs of [`for_each_run`] cover exactly the flagged columns, in order, and give each
        /// the best match of the flagged cells over it in grid order, as the merge pixel by pixel
        /// ([`Resolve::decide`](super::Resolve)) finds it.
        #[test]
        fn runs_give_each_column_the_best_match_of_its_flagged_cells(
            n in 1usize..40,
            grids in prop::collection::vec(grid(40), 1..4),
        ) {
            let eps_z = 0.15;
            let mut blocks = Vec::new();
            // Per column, the cells that cover it, grid by grid: (block index, cell index).
            let mut cover = vec![Vec::new(); n];
            for (g, cells) in grids.iter().enumerate() {
                let mut block = AuxBlock::default();
                let mut s = 0;
                for (k, &(len, flagged, m)) in cells.iter().enumerate() {
                    let e = (s + len).min(n);
                    block.cells.push(m.map(|(z, e)| test_cell(g, k, (z, e, false))));
                    block.done.push(1);
                    if flagged && s < e {
                        block.spans.push(Span { s: s as u32, e: e as u32, k: k as u32 });
                        for c in &mut cover[s..e] {
                            c.push((g, k));
                        }
                    }
                    s = e;
                }
                blocks.push(block);
            }
            let mut rows: Vec<GridRow> = blocks.iter().map(|b| GridRow::new(&b.spans)).collect();
            let mut got = vec![None; n];
            let mut last = 0;
            for_each_run(&mut rows, &blocks, eps_z, |run, aux| {
                assert!(run.start >= last && run.start < run.end && run.end <= n, "{run:?}");
                last = run.end;
                for col in &mut got[run] {
                    *col = Some(aux.map(|a| (a.src, a.p)));
                }
            });
            for (i, c) in cover.iter().enumerate() {
                let mut want: Option<&AuxCell> = None;
                for &(g, k) in c {
                    if let Some(a) = &blocks[g].cells[k] {
                        want = Some(better_aux(want, a, eps_z));
                    }
                }
                let want = (!c.is_empty()).then(|| want.map(|a| (a.src, a.p)));
                prop_assert_eq!(got[i], want, "column {}", i);
            }
        }
    }

    /// A cell of a test grid for the merge: its match's depth and error (in tenths) and whether
    /// it is visible in main, if it has one, and whether it is flagged besides (a cell whose
    /// match is not visible in main always is, as [`AuxGrid::maybe`](super::AuxGrid) flags it).
    type MergeCell = (Option<(u8, u8, bool)>, bool);

    fn merge_grid(cells: usize) -> impl Strategy<Value = Vec<MergeCell>> {
        prop::collection::vec(
            (
                prop::option::of((0u8..4, 0u8..3, any::<bool>())),
                any::<bool>(),
            ),
            cells,
        )
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

        /// What [`Resolve::aux_row`]'s merge where main found a match relies on: the merge of the
        /// flagged cells decides every pixel as the merge of every cell does, although the best
        /// match ([`better_aux`]) is not transitive, except where it overrides main over a cell
        /// of some grid that is not flagged (which `aux_row` rechecks over every cell), and
        /// with more than two grids only once the flags are one set ([`unite_maybe`]).
        #[test]
        fn flagged_cells_merge_as_every_cell_does_but_for_the_rechecked(
            lens in prop::collection::vec(1usize..4, 1..12),
            grids in prop::collection::vec(merge_grid(12), 1..4),
            main in prop::collection::vec(0u8..4, 40),
        ) {
            let eps_z = 0.15;
            let n: usize = lens.iter().sum();
            let w = lens.len();
            let mut maybe: Vec<AuxGrid> = grids
                .iter()
                .map(|cells| {
                    let flags = cells[..w]
                        .iter()
                        .map(|&(m, f)| u8::from(f || m.is_some_and(|(_, _, vis)| !vis)));
                    flag_grid(w, 1, flags.collect())
                })
                .collect();
            unite_maybe(&mut maybe);
            let decide = |flagged: &dyn Fn(usize, usize) -> bool| -> Vec<bool> {
                let mut blocks = Vec::new();
                for (g, cells) in grids.iter().enumerate() {
                    let mut block = AuxBlock::default();
                    let mut s = 0;
                    for (k, &(m, _)) in cells[..w].iter().enumerate() {
                        let e = s + lens[k];
                        block.cells.push(m.map(|m| test_cell(g, k, m)));
                        block.done.push(1);
                        if flagged(g, k) {
                            block.spans.push(Span { s: s as u32, e: e as u32, k: k as u32 });
                        }
                        s = e;
                    }
                    blocks.push(block);
                }
                let mut rows: Vec<GridRow> =
                    blocks.iter().map(|b| GridRow::new(&b.spans)).collect();
                let mut out = vec![false; n];
                for_each_run(&mut rows, &blocks, eps_z, |run, aux| {
                    for i in run {
                        // Rule 2 of §3.5 with the best match over the column.
                        let main_z = f32::from(main[i]) * 0.1;
                        out[i] = aux.is_some_and(|a| {
                            !a.visible_in_main && overrides_main(a, main_z, eps_z)
                        });
                    }
                });
                out
            };
            let lazy = decide(&|g, k| maybe[g].maybe[k] != 0);
            let eager = decide(&|_, _| true);
            // The cell of each column (the grids share their cells).
            let cell: Vec<usize> = lens.iter().enumerate().flat_map(|(k, &l)| vec![k; l]).collect();
            for i in 0..n {
                let everywhere = maybe.iter().all(|g| g.maybe[cell[i]] != 0);
                prop_assert!(
                    lazy[i] == eager[i] || (lazy[i] && !everywhere && grids.len() <= 2),
                    "column {}: flagged cells {}, every cell {}", i, lazy[i], eager[i]
                );
            }
        }
    }

    /// The merge's two comparisons (§3.5) on cases worked by hand (`ε_z = 0.15`, depths
    /// reversed: larger is nearer, similar when `2·|Δz| < ε_z`): an auxiliary match replaces a
    /// main match ([`overrides_main`]) only when nearer and not similar; of two auxiliary
    /// matches ([`better_aux`]) the nearer wins when the depths differ, else the smaller error,
    /// and the earlier grid's on a tie. (The merge tests above take both as their reference.)
    #[test]
    fn merge_keeps_the_nearer_else_the_smaller_error() {
        let eps_z = 0.15;
        let cell = |z: f32, e: f32| AuxCell {
            src: 2,
            visible_in_main: false,
            p: 0,
            e,
            z,
        };
        // (auxiliary depth, main depth, overrides).
        for (az, mz, want) in [
            (0.5, 0.3, true),
            (0.3, 0.5, false),
            (0.35, 0.3, false),
            // 2·0.1 ≥ ε_z although 0.1 < ε_z: not similar.
            (0.4, 0.3, true),
            (0.3, 0.3, false),
        ] {
            assert_eq!(
                overrides_main(&cell(az, 0.1), mz, eps_z),
                want,
                "{az} over {mz}"
            );
        }
        // (earlier grid's depth and error, later grid's, whether the later one is kept).
        for ((bz, be), (cz, ce), later) in [
            ((0.3, 0.1), (0.5, 0.2), true),
            ((0.5, 0.1), (0.3, 0.05), false),
            ((0.3, 0.2), (0.4, 0.1), true),
            ((0.4, 0.2), (0.3, 0.1), false),
            ((0.3, 0.2), (0.35, 0.1), true),
            ((0.35, 0.1), (0.3, 0.2), false),
            ((0.3, 0.1), (0.32, 0.1), false),
        ] {
            let (b, c) = (cell(bz, be), cell(cz, ce));
            let kept = better_aux(Some(&b), &c, eps_z);
            assert_eq!(
                std::ptr::eq(kept, &c),
                later,
                "{:?} then {:?}",
                (bz, be),
                (cz, ce)
            );
        }
        let c = cell(0.1, 0.9);
        assert!(std::ptr::eq(better_aux(None, &c, eps_z), &c));
    }

    /// [`unite_maybe`] flags a cell in every grid of three or more when any flags it, and every
    /// cell when the grids differ in size; two grids keep their own flags.
    #[test]
    fn united_flags_are_the_union_or_every_cell() {
        let three = |last: usize| {
            let mut g = vec![
                flag_grid(3, 1, vec![1, 0, 0]),
                flag_grid(3, 1, vec![0, 0, 1]),
            ];
            g.push(flag_grid(last, 1, vec![0; last]));
            g
        };
        let mut same = three(3);
        unite_maybe(&mut same);
        assert!(same.iter().all(|g| g.maybe == [1, 0, 1]));
        let mut mixed = three(2);
        unite_maybe(&mut mixed);
        assert!(mixed.iter().all(|g| g.maybe.iter().all(|&m| m == 1)));
        // Two grids keep their own flags (the merge rechecks instead).
        let mut two = three(3);
        two.pop();
        unite_maybe(&mut two);
        assert_eq!(
            (&two[0].maybe[..], &two[1].maybe[..]),
            (&[1, 0, 0][..], &[0, 0, 1][..])
        );
    }

    /// [`Reach`] is the set its docs define: an offset is covered exactly when the square cell
    /// that far away comes nearer than `r` plus the margin to the cell's centre, the border is
    /// the cells whose centre is that near the grid's edge, and the rectangles are the fewest
    /// (`a` rising, `b` falling).
    #[test]
    fn reach_is_the_cells_a_match_can_lie_in() {
        let gap = |d: usize| (d as f64 - 0.5).max(0.0);
        for r in [0.0f32, 0.2, 0.5, 0.6, 1.0, 1.49, 2.0, 2.88, 3.5, 6.25] {
            let k = Reach::new(r).unwrap();
            let r2 = (f64::from(r) + Reach::MARGIN).powi(2);
            for di in 0..12 {
                for dj in 0..12 {
                    let want = gap(di).powi(2) + gap(dj).powi(2) < r2;
                    assert_eq!(k.covers(di, dj), want, "r {r}, offset ({di}, {dj})");
                }
            }
            let border = (0..12).filter(|&i| (i as f64 + 0.5).powi(2) < r2).count();
            assert_eq!(k.border, border, "r {r}");
            for p in k.rects.windows(2) {
                assert!(p[0].0 < p[1].0 && p[0].1 > p[1].1, "r {r}: {:?}", k.rects);
            }
        }
        let k = Reach::new(2.88).unwrap();
        assert_eq!((k.rects, k.border), (vec![(1, 3), (2, 2), (3, 1)], 3));
        assert_eq!(Reach::new(f32::NAN), None);
        assert_eq!(Reach::new(f32::INFINITY), None);
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 1024, ..ProptestConfig::default() })]

        /// What [`AuxGrid::maybe`](super::AuxGrid) relies on: a point less than `r` cells from
        /// the centre of a cell (as the search's error measures it, eq. 7) lands in a cell of
        /// the grid from which [`Reach`] covers that one, found from its NDC as pass 1 finds it
        /// ([`pixel_index_of_ndc`](crate::camera::pixel_index_of_ndc)), or outside the grid with
        /// that cell in the border.
        #[test]
        fn a_point_near_a_cell_centre_lands_where_the_reach_covers_it(
            r in 0.0f32..6.0,
            (w, h) in (1usize..50, 1usize..40),
            (ci, cj) in (0usize..50, 0usize..40),
            (angle, frac) in (0.0f64..std::f64::consts::TAU, 0.0f64..1.0),
        ) {
            let (ci, cj) = (ci % w, cj % h);
            let k = Reach::new(r).unwrap();
            // A point at distance frac·r from the centre of cell (ci, cj), in cell units, then in
            // NDC as the search measures it.
            let d = frac * f64::from(r);
            let (px, py) = (ci as f64 + 0.5 + d * angle.cos(), cj as f64 + 0.5 + d * angle.sin());
            let (x, y) = ((2.0 * px / w as f64 - 1.0) as f32, (1.0 - 2.0 * py / h as f64) as f32);
            let (inside, c) =
                crate::camera::pixel_index_of_ndc(x, y, w as f32, h as f32, w as u32);
            if inside {
                let (li, lj) = (c as usize % w, c as usize / w);
                prop_assert!(
                    k.covers(ci.abs_diff(li), cj.abs_diff(lj)),
                    "{:?} lands in ({}, {}), out of reach of ({}, {})", (px, py), li, lj, ci, cj
                );
            } else {
                let edge = ci.min(w - 1 - ci).min(cj).min(h - 1 - cj);
                prop_assert!(edge < k.border, "{:?} outside, ({}, {}) not in the border", (px, py), ci, cj);
            }
        }
    }

    /// [`dilate_flags`] flags exactly the cells that [`Reach`] covers from a cell flagged in any
    /// source, or its border, on grids of many shapes with sparse and dense flags.
    #[test]
    fn dilated_flags_are_the_cells_a_flag_or_the_border_reaches() {
        use std::sync::atomic::AtomicU8;
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let mut rng = |n: u64| crate::ours::draw(&mut seed, n);
        for (w, h) in [(1, 1), (3, 9), (17, 5), (33, 21), (40, 40)] {
            for r in [0.0f32, 0.7, 1.6, 2.88, 3.3] {
                let reach = Reach::new(r).unwrap();
                let (b, far) = (reach.border, reach.widest() + 1);
                for (n_src, dense) in [(1, 2), (2, 30), (2, 200), (1, 1000)] {
                    let mut flags: Vec<Vec<AtomicU8>> = (0..n_src)
                        .map(|_| {
                            (0..w * h)
                                .map(|_| AtomicU8::new(u8::from(rng(1000) < dense)))
                                .collect()
                        })
                        .collect();
                    let set: Vec<Vec<u8>> = flags
                        .iter_mut()
                        .map(|f| f.iter_mut().map(|v| *v.get_mut()).collect())
                        .collect();
                    let mut maybe = vec![0u8; w * h];
                    let views = flags.iter_mut().map(|f| f.as_mut_slice());
                    dilate_flags(views, w, h, &reach, &mut maybe);
                    for j in 0..h {
                        for i in 0..w {
                            let border = i < b || i + b >= w || j < b || j + b >= h;
                            let near = (j.saturating_sub(far)..(j + far).min(h)).any(|q| {
                                (i.saturating_sub(far)..(i + far).min(w)).any(|p| {
                                    reach.covers(i.abs_diff(p), j.abs_diff(q))
                                        && set.iter().any(|s| s[q * w + p] == 1)
                                })
                            });
                            assert_eq!(
                                maybe[j * w + i],
                                u8::from(border || near),
                                "{w}x{h}, r {r}, cell ({i}, {j}), {n_src} sources"
                            );
                        }
                    }
                }
            }
        }
    }
}
