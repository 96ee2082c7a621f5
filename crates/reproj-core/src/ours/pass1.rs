//! Pass 1 of `ours` and `forward_splat`, per source image (seeds/000 §3.5: "depth-aware forward
//! point splatting based on these flow fields, combined with a 3×3 window search"): the camera
//! scene flow `M_cam` towards the client pose (eq. 1 with `w = α` / `1−α`, i.e. the flows of eqs.
//! 12 and 13), the client's reversed depth of each point (the `z` of eq. 8, kept whole), the
//! depth-aware splat of the points into a grid over the client image, and the window search for
//! every cell at once as a separable minimum filter ([`window_min`]), which initialises the
//! fixed-point iteration of `search`. For an auxiliary source it also flags the cells where its
//! points that are not visible in the main camera land (§3.5 rule 2, read by `auxiliary`).

use std::sync::atomic::Ordering;

use rayon::prelude::*;

use crate::camera::{pixel_index_of_ndc, NdcTransfer};
use crate::params::TILE;

use super::{pack_pixel, splat_index, splat_key, Src, SrcRow, EMPTY_SPLAT, NO_SPLAT};
use crate::simd::simd_dispatch;

/// Source rows per task of the splatting pass. Points that land outside their task's rows are
/// applied after the parallel pass; taller bands leave fewer of them (a vertical flow of `d` rows
/// spills about `d / SPLAT_BAND` of the points), and an auxiliary camera, whose wider view lands
/// stretched and curved in the client grid, spills most at the bands' edges. In time_ours's
/// scene at 1280×720 + 2×640×360, 32 rows spilled 1.2 % of a main source's points and 11–12 %
/// of an auxiliary one's; 64 rows 0.5 % and 5.7 %. A band's grid cells (64 rows of 1280 keys,
/// 655 KB) still fit in a core's L2. Paired in one process against 32 rows: 0.960–0.968 of the
/// frame at 1280×720 (2 threads), 0.974 on one thread, 0.987–0.991 at 640×360.
const SPLAT_BAND: usize = 64;

/// Pass 1 for one source image: `M_cam` (eqs. 1, 12, 13) and the depth-aware splat.
///
/// `w` is the fraction of the object motion applied: `α` for the older frame, `1−α` for the newer
/// one (negative when extrapolating). `moving`: the source's [`moving_chunks`] when the caller
/// has them (from the pair), else they are tested on the motion as the rows go.
pub(super) fn scene_flow_and_splat(
    src: &mut Src,
    to_client: &NdcTransfer,
    w: f32,
    vis: Option<&[u8]>,
    moving: Option<&[u8]>,
) {
    let (sw, sh) = (src.proj.width, src.proj.height);
    let view = src.view;
    // Set before the splat: a frame that stops half-way leaves keys of its own epoch, which the
    // next frame's (a later one) ignores.
    let epoch = src.bufs.epoch.next();
    src.bufs.epoch = epoch;
    let stored = epoch.stored();
    let invisible = &src.bufs.invisible;
    let xs = &src.ndc.x;
    let nc = sw.div_ceil(STILL_CHUNK);
    // The splat is a minimum per cell, so the order of the updates does not matter. Each task owns
    // the splat cells of its own SPLAT_BAND rows (its band): it resets them when the epoch fills
    // the grid (SplatEpoch; while they are hot in its cache, instead of a separate pass over the
    // grid) and updates them with plain loads and stores. A point that lands in another band is
    // kept aside and applied after the parallel pass, when every band is reset. A `lock cmpxchg`
    // per point would cost more than the point's whole scene flow.
    //
    // A task's band is where most of its SPLAT_BAND source rows land ([`band_starts`]), so that
    // a head turn that moves the image vertically, or an auxiliary camera's wider view, does not
    // make the points of every band land in another one.
    let nb = sh.div_ceil(SPLAT_BAND);
    let starts = band_starts(src, to_client, w, nb);
    let mut bands: Vec<(usize, &mut [u64])> = Vec::with_capacity(nb);
    let mut rest = &mut src.bufs.splat[..];
    for (b, &start) in starts.iter().enumerate() {
        let end = starts.get(b + 1).map_or(sh, |&e| e.max(start));
        let (band, tail) = rest.split_at_mut((end - start) * sw);
        bands.push((start, band));
        rest = tail;
    }
    let block = |b: usize,
                 rows: &mut [[f32; 2]],
                 zrows: &mut [f32],
                 (start, band): (usize, &mut [u64]),
                 spill: &mut Vec<(u32, u64)>| {
        if epoch.fills() {
            band.fill(EMPTY_SPLAT);
        }
        spill.clear();
        // Row-major cell indices order like the packed pixels: the band is one range of them.
        let base = (start * sw) as u32;
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
                    moving: moving.map(|m| &m[j * nc..(j + 1) * nc]),
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
                splat_row(j, &scratch.cell, &scratch.kz, stored, base, band, spill);
                if let Some(vis) = vis {
                    // Auxiliary sources: flag where the points not visible in main land.
                    let v = &vis[j * sw..(j + 1) * sw];
                    landing_row(SrcRow { j, sw, sh }, xs, row, v, &mut scratch.inv);
                    flag_cells(&scratch.inv, invisible);
                }
            }
        });
    };
    // One spill list per block, kept with the buffers (see BUFFER_POOL on page faults).
    let mut spills = std::mem::take(&mut src.bufs.spill);
    spills.resize_with(nb, Vec::new);
    src.bufs
        .flow
        .par_chunks_mut(SPLAT_BAND * sw)
        .zip(src.bufs.zc.par_chunks_mut(SPLAT_BAND * sw))
        .zip(bands.into_par_iter())
        .zip(spills.par_iter_mut())
        .enumerate()
        // One job per band, so that an idle thread can always take one (see `run`).
        .with_max_len(1)
        .for_each(|(b, (((rows, zrows), band), spill))| block(b, rows, zrows, band, spill));
    // The parallel pass has finished: every band is reset (or holds only earlier epochs' keys).
    // The spilled points are applied by one task per range of the grid (one per thread), each
    // reading every list and taking the cells of its own range, so that no two tasks write the
    // same cell.
    let parts = rayon::current_num_threads().clamp(1, 16);
    let part = (sw * sh).div_ceil(parts).max(1);
    src.bufs
        .splat
        .par_chunks_mut(part)
        .enumerate()
        .for_each(|(q, cells)| {
            let lo = (q * part) as u32;
            // Nested loops, not `flatten`: its state check per point cost as much as the update.
            for spill in &spills {
                for &(c, key) in spill {
                    if let Some(s) = cells.get_mut(c.wrapping_sub(lo) as usize) {
                        *s = key_min(*s, key);
                    }
                }
            }
        });
    src.bufs.spill = spills;
}

/// Sample points per row [`band_starts`] looks at.
const SHIFT_SAMPLES: usize = 9;

/// The first client row of each of the `nb` splat bands of a source (the first is 0, they do
/// not decrease, the last band ends at the grid's last row): where band `b`'s first source row,
/// `b · SPLAT_BAND`, lands in the client image, the median over sample points of that row of
/// `M_cam`'s vertical part (unchanged where none is valid).
///
/// Pass 1 owns the splat cells by bands of rows; a point that lands outside its task's band is
/// set aside and applied afterwards, one random access to the grid per point. With the bands at
/// the source rows, a head turn that moves the image `d` rows vertically sends about
/// `d / SPLAT_BAND` of the points to the next band, and an auxiliary camera, whose wider view
/// lands stretched in the client grid, sends most of its points elsewhere. The grid is the same
/// whichever task applies a point, so the estimate only has to be typical.
fn band_starts(src: &Src, to_client: &NdcTransfer, w: f32, nb: usize) -> Vec<usize> {
    let (sw, sh) = (src.proj.width, src.proj.height);
    let view = src.view;
    let mut dy: Vec<f32> = Vec::with_capacity(SHIFT_SAMPLES);
    let mut starts = Vec::with_capacity(nb);
    let mut prev = 0;
    for b in 0..nb {
        let j = b * SPLAT_BAND;
        let k = PointCtx::new(SrcRow { j, sw, sh }, to_client, w);
        dy.clear();
        for si in 0..SHIFT_SAMPLES {
            let i = (2 * si + 1) * sw / (2 * SHIFT_SAMPLES);
            let p = j * sw + i;
            let o = view
                .motion
                .map_or([0.0; 3], |m| [m[3 * p], m[3 * p + 1], m[3 * p + 2]]);
            let f = flow_point(&k, src.ndc.x[i], view.depth[p], o).flow[1];
            // NDC y points up, rows down.
            let rows = -f * 0.5 * sh as f32;
            if rows.is_finite() {
                dy.push(rows);
            }
        }
        let start = if b == 0 || dy.is_empty() {
            j
        } else {
            let mid = dy.len() / 2;
            let (_, m, _) = dy.select_nth_unstable_by(mid, f32::total_cmp);
            (j as f32 + m.round()).clamp(0.0, sh as f32) as usize
        };
        // The first band starts the grid; none starts before the one above it.
        prev = if b == 0 { 0 } else { start.max(prev) };
        starts.push(prev);
    }
    starts
}

/// Points per chunk of [`flag_cells`]: one AVX2 vector.
const FLAG_CHUNK: usize = 8;

simd_dispatch! {
    /// Sets the flag of every cell of `inv` ([`RowScratch::inv`]) other than [`NO_SPLAT`] in
    /// `invisible`. Few points of an auxiliary source are not visible in the main camera (4 % in
    /// time_ours's scene, and 94 % of the chunks of 8 have none), so whole chunks without any
    /// are skipped after one test.
    fn flag_cells / flag_cells_avx2, flag_cells_avx512 => flag_cells_impl(
        inv: &[u32],
        invisible: &[std::sync::atomic::AtomicU8],
    )
}

#[inline(always)]
fn flag_cells_impl(inv: &[u32], invisible: &[std::sync::atomic::AtomicU8]) {
    let flag = |c: &[u32]| {
        for &c in c {
            if c != NO_SPLAT {
                // A plain store on x86-64: setting a flag needs no read-modify-write.
                invisible[c as usize].store(1, Ordering::Relaxed);
            }
        }
    };
    let chunks = inv.chunks_exact(FLAG_CHUNK);
    let tail = chunks.remainder();
    for c in chunks {
        // One vector compare and test (a fold was done in scalars, a longer array with a call).
        if *c != [NO_SPLAT; FLAG_CHUNK] {
            flag(c);
        }
    }
    flag(tail);
}

/// Points per chunk of [`splat_row`]: one vector of cells, two of keys on AVX2.
const SPLAT_CHUNK: usize = 8;

simd_dispatch! {
    /// Splats one source row `j` whose points' cells and key depths are `cell` and `kz`
    /// ([`RowScratch`]): into `band`, the cells `base..` of the grid, or else onto `spill`, each
    /// key in its stored form (`key ^ stored`, [`SplatEpoch::stored`](super::SplatEpoch::stored)).
    ///
    /// Neighbouring points of a row mostly land in neighbouring cells: in time_ours's scene, 93 %
    /// of the chunks of 8 points of a main source land in 8 consecutive cells of their band, and
    /// 47 % of those of an auxiliary source do not splat at all. Such a chunk is one vector
    /// minimum with the band's cells (its keys put together in vectors too), or nothing; the
    /// others take the point by point path ([`splat_points`]). The minimum does not depend on the
    /// order of the updates, so the grid is the same. Per 640×360 frame (AVX2), 4.9 M
    /// instructions against 10.8 M for the keys and the splat point by point.
    fn splat_row / splat_row_avx2, splat_row_avx512 => splat_row_impl(
        j: usize,
        cell: &[u32],
        kz: &[f32],
        stored: u64,
        base: u32,
        band: &mut [u64],
        spill: &mut Vec<(u32, u64)>,
    )
}

#[inline(always)]
fn splat_row_impl(
    j: usize,
    cell: &[u32],
    kz: &[f32],
    stored: u64,
    base: u32,
    band: &mut [u64],
    spill: &mut Vec<(u32, u64)>,
) {
    let cells = cell.chunks_exact(SPLAT_CHUNK);
    let done = cell.len() - cells.remainder().len();
    // The packed pixels of the chunk's points.
    let mut pks: [u64; SPLAT_CHUNK] = std::array::from_fn(|i| u64::from(pack_pixel(i, j)));
    for (c, z) in cells.zip(kz.chunks_exact(SPLAT_CHUNK)) {
        // Whole-array comparisons: one vector compare and test each.
        let c: &[u32; SPLAT_CHUNK] = c.try_into().unwrap();
        let z: &[f32; SPLAT_CHUNK] = z.try_into().unwrap();
        let next = pks.map(|p| p + SPLAT_CHUNK as u64);
        let pks = std::mem::replace(&mut pks, next);
        if *c == [NO_SPLAT; SPLAT_CHUNK] {
            continue;
        }
        // `splat_key(z, pk)`, with the packed pixels kept in 64-bit lanes across chunks.
        let key: [u64; SPLAT_CHUNK] =
            std::array::from_fn(|i| (splat_key(z[i], 0) | pks[i]) ^ stored);
        let run: [u32; SPLAT_CHUNK] = std::array::from_fn(|i| c[0].wrapping_add(i as u32));
        // A run that wraps past NO_SPLAT starts more than 2³¹ − 8 cells from every band.
        let rel = c[0].wrapping_sub(base) as usize;
        if *c == run {
            if let Some(dst) = band.get_mut(rel..rel + SPLAT_CHUNK) {
                for (d, &k) in dst.iter_mut().zip(&key) {
                    *d = key_min(*d, k);
                }
                continue;
            }
        }
        splat_points(c, &key, base, band, spill);
    }
    for (i, (&c, &z)) in cell.iter().zip(kz).enumerate().skip(done) {
        let key = splat_key(z, pack_pixel(i, j)) ^ stored;
        splat_points(&[c], &[key], base, band, spill);
    }
}

/// [`splat_row`] point by point, for the points in `cell` with stored keys `key`.
#[inline(always)]
fn splat_points(
    cell: &[u32],
    key: &[u64],
    base: u32,
    band: &mut [u64],
    spill: &mut Vec<(u32, u64)>,
) {
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

thread_local! {
    /// Splat targets of one source row ([`RowScratch`]), reused.
    static ROW_SCRATCH: std::cell::RefCell<RowScratch> = const {
        std::cell::RefCell::new(RowScratch { cell: Vec::new(), kz: Vec::new(), inv: Vec::new() })
    };
}

/// What [`flow_row`] computes per point of a row besides the flow, for the scalar loop that
/// splats: one array per field, so that the vector loop stores whole registers.
struct RowScratch {
    /// The client cell (row-major index in the source-sized grid) the point splats into, or
    /// [`NO_SPLAT`].
    cell: Vec<u32>,
    /// Its key depth, the `z` of [`splat_key`] (unspecified where `cell` is [`NO_SPLAT`]). The
    /// key itself is put together by [`splat_row`]: 64-bit lanes in [`flow_row`] made the
    /// compiler halve its vector width.
    kz: Vec<f32>,
    /// Auxiliary sources: the cell the point lands in when it is valid and not visible in the
    /// main camera (whether or not it splats; see [`Buffers::invisible`](super::Buffers::invisible)), else [`NO_SPLAT`].
    inv: Vec<u32>,
}

impl RowScratch {
    fn resize(&mut self, n: usize) {
        self.cell.resize(n, NO_SPLAT);
        self.kz.resize(n, 0.0);
        self.inv.resize(n, NO_SPLAT);
    }
}

/// The inputs of [`flow_row`]: one row `j` of a `sw × sh` source image.
struct FlowRow<'a> {
    j: usize,
    sw: usize,
    sh: usize,
    /// NDC x of the pixel centres ([`NdcTable`](crate::camera::NdcTable)).
    x: &'a [f32],
    depth: &'a [f32],
    /// The row's object motion, `3·sw` values, or `None` for a static frame.
    motion: Option<&'a [f32]>,
    /// The row's [`moving_chunks`], when known: the motion is then read only where it moves.
    moving: Option<&'a [u8]>,
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

simd_dispatch! {
    /// `M_cam` of one source row (eqs. 1, 12, 13) and where each point splats.
    ///
    /// Written without branches on the data so that the compiler vectorises it; on x86-64 it
    /// runs in an AVX-512 or AVX2 build where the processor has it (the same IEEE operations, no
    /// FMA contraction, so the bytes do not depend on the processor).
    fn flow_row / flow_row_avx2, flow_row_avx512 => flow_row_impl(row: FlowRow, out: RowOut)
}

/// Points per chunk of a row whose motion [`flow_row`] tests for being all +0. On time_ours's
/// synthetic scene 97 % of the points are still, and 95 % lie in still chunks of 32 (96 % of 16,
/// 93 % of 64, 66 % of whole rows). Per 640×360 frame (AVX2), `flow_row` costs 12.07 M
/// instructions with chunks of 16, 11.49 M with 32 and 11.44 M with 64, which leaves 2 % more of
/// the points to the general path here, and more in scenes with more moving objects.
const STILL_CHUNK: usize = 32;

#[inline(always)]
fn flow_row_impl(row: FlowRow, out: RowOut) {
    let FlowRow {
        j,
        sw,
        sh,
        x,
        depth,
        motion,
        moving,
        to_client,
        w,
    } = row;
    let k = PointCtx::new(SrcRow { j, sw, sh }, to_client, w);
    let Some(mo) = motion else {
        return flow_span(&k, x, depth, None, out);
    };
    // Most points of a scene do not move: their motion is exactly +0 (the renderer writes 0.0,
    // decoded streams have static-motion masks), and for them [`still_point`] gives the same
    // bytes as [`flow_point`] at half the cost. A chunk of STILL_CHUNK points is still when all
    // of its motion bits are clear (−0.0 is not: it takes the general path); each run of chunks
    // of one kind is one loop: a loop per chunk cost 0.5 M instructions more per 640×360 frame
    // (bounds checks and loop set-up).
    let mut s = 0;
    while s < sw {
        let (e, moving) = motion_run(mo, s, sw, moving);
        let out = RowOut {
            flow: &mut out.flow[s..e],
            zc: &mut out.zc[s..e],
            cell: &mut out.cell[s..e],
            kz: &mut out.kz[s..e],
        };
        let m = moving.then_some(&mo[3 * s..3 * e]);
        flow_span(&k, &x[s..e], &depth[s..e], m, out);
        s = e;
    }
}

/// The run of chunks of one kind (still: every motion bit clear; or moving) that starts at point
/// `s` of a row of `sw` points with motion `mo` (3 values per point): its end, and whether it
/// moves. `flags`: the row's [`moving_chunks`], read instead of the motion when given.
#[inline(always)]
pub(super) fn motion_run(mo: &[f32], s: usize, sw: usize, flags: Option<&[u8]>) -> (usize, bool) {
    let end = |s: usize| (s + STILL_CHUNK).min(sw);
    let test = |s: usize| match flags {
        Some(f) => f[s / STILL_CHUNK] != 0,
        None => chunk_moving(mo, s, sw),
    };
    let moving = test(s);
    let mut e = end(s);
    while e < sw && moving == test(e) {
        e = end(e);
    }
    (e, moving)
}

/// Whether each chunk of [`STILL_CHUNK`] points of each row of an `sw × sh` source with motion
/// `mo` (3 values per point) moves (1) or is still (0: every motion bit clear), row by row
/// (`sw.div_ceil(STILL_CHUNK)` per row) into `out`.
///
/// What [`flow_row`] would otherwise test every client frame, reading the whole motion buffer
/// (12 bytes per point, most of a still point's input) to find the few points that move; it
/// depends on the frame alone, so the pair computes it once ([`PairSource::moving`](super::pair::PairSource::moving)).
pub(super) fn moving_chunks(mo: &[f32], sw: usize, sh: usize, out: &mut Vec<u8>) {
    let nc = sw.div_ceil(STILL_CHUNK);
    out.clear();
    out.resize(nc * sh, 0);
    out.par_chunks_mut(nc)
        .zip(mo.par_chunks(3 * sw))
        .for_each(|(flags, m)| {
            for (c, f) in flags.iter_mut().enumerate() {
                *f = u8::from(chunk_moving(m, c * STILL_CHUNK, sw));
            }
        });
}

/// Whether any motion value of the chunk of points `s..` of a row of `sw` (`mo`, 3 per point)
/// has a bit set, i.e. is not +0. Whole chunks have a constant length, so that their test is
/// a straight sequence of vector ORs.
#[inline(always)]
fn chunk_moving(mo: &[f32], s: usize, sw: usize) -> bool {
    let bits = |m: &[f32]| m.iter().fold(0, |acc, v| acc | v.to_bits());
    let m = if s + STILL_CHUNK <= sw {
        bits(&mo[3 * s..3 * (s + STILL_CHUNK)])
    } else {
        bits(&mo[3 * s..3 * sw])
    };
    m != 0
}

/// [`flow_row`] for the points of a span of a row: [`flow_point`] with their `motion`, or
/// [`still_point`] where it is `None` (all +0).
#[inline(always)]
fn flow_span(k: &PointCtx, x: &[f32], depth: &[f32], motion: Option<&[f32]>, out: RowOut) {
    let RowOut { flow, zc, cell, kz } = out;
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
                put(d, flow_point(k, *x, *z, [o[0], o[1], o[2]]));
            }
        }
        None => {
            for (d, (x, z)) in outs.zip(x.iter().zip(depth)) {
                put(d, still_point(k, *x, *z));
            }
        }
    }
}

/// For the tests: [`flow_row`] of a source row, and the same row point by point through
/// [`flow_point`] with each point's motion (+0 without `motion`), i.e. without [`still_point`]:
/// `(flow, zc, cell, kz)` of each point, twice.
#[cfg(test)]
#[allow(clippy::type_complexity)]
pub(super) fn flow_row_and_general(
    row: SrcRow,
    x: &[f32],
    depth: &[f32],
    motion: Option<&[f32]>,
    to_client: &NdcTransfer,
    w: f32,
) -> [Vec<([f32; 2], f32, u32, f32)>; 2] {
    let SrcRow { j, sw, sh } = row;
    let (mut flow, mut zc) = (vec![[0.0; 2]; sw], vec![0.0; sw]);
    let (mut cell, mut kz) = (vec![0; sw], vec![0.0; sw]);
    let mut flags = Vec::new();
    if let Some(m) = motion {
        moving_chunks(m, sw, 1, &mut flags);
    }
    let mut fast = Vec::new();
    // With the chunks tested as the row goes, and with them from `moving_chunks`.
    for moving in [None, motion.map(|_| &flags[..])] {
        let input = FlowRow {
            j,
            sw,
            sh,
            x,
            depth,
            motion,
            moving,
            to_client,
            w,
        };
        let out = RowOut {
            flow: &mut flow,
            zc: &mut zc,
            cell: &mut cell,
            kz: &mut kz,
        };
        flow_row(input, out);
        fast.push(
            (0..sw)
                .map(|i| (flow[i], zc[i], cell[i], kz[i]))
                .collect::<Vec<_>>(),
        );
    }
    let bits = |v: &[([f32; 2], f32, u32, f32)]| {
        v.iter()
            .map(|(f, z, c, k)| (f.map(f32::to_bits), z.to_bits(), *c, k.to_bits()))
            .collect::<Vec<_>>()
    };
    let with_flags = fast.pop().unwrap();
    let fast = fast.pop().unwrap();
    assert!(
        bits(&fast) == bits(&with_flags),
        "flow_row with moving_chunks differs"
    );
    let k = PointCtx::new(row, to_client, w);
    let general = (0..sw)
        .map(|i| {
            let o = motion.map_or([0.0; 3], |m| [m[3 * i], m[3 * i + 1], m[3 * i + 2]]);
            let p = flow_point(&k, x[i], depth[i], o);
            (p.flow, p.zc, p.cell, p.kz)
        })
        .collect();
    [fast, general]
}

simd_dispatch! {
    /// For an auxiliary source, the cell each point of row `j` lands in as the resolve pass sees
    /// it, `pixel_of_ndc(x + M_cam)`, where the point is valid and not visible in the main camera
    /// (`vis`, one byte per pixel, from the pair), else [`NO_SPLAT`] ([`RowScratch::inv`]).
    /// Whether or not the point splats: the FPI can reach points that do not (e.g. nearer than
    /// the client's near plane). Points just outside the grid need no flag: the cells along the
    /// grid's border are always searched.
    fn landing_row / landing_row_avx2, landing_row_avx512 => landing_row_impl(
        row: SrcRow,
        x: &[f32],
        flow: &[[f32; 2]],
        vis: &[u8],
        inv: &mut [u32],
    )
}

#[inline(always)]
fn landing_row_impl(row: SrcRow, x: &[f32], flow: &[[f32; 2]], vis: &[u8], inv: &mut [u32]) {
    let (y, sw, sh) = (row.ndc_y(), row.sw, row.sh);
    let (wf, hf) = (sw as i32 as f32, sh as i32 as f32);
    for (d, ((x, f), v)) in inv.iter_mut().zip(x.iter().zip(flow).zip(vis)) {
        // NaN (invalid) flow lands nowhere.
        let (inside, c) = pixel_index_of_ndc(x + f[0], y + f[1], wf, hf, sw as u32);
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
    /// `w · 0`: the blend's increment for a point that does not move ([`still_point`]).
    still: f32,
}

impl PointCtx {
    #[inline(always)]
    fn new(row: SrcRow, to_client: &NdcTransfer, w: f32) -> PointCtx {
        PointCtx {
            y: row.ndc_y(),
            wf: row.sw as i32 as f32,
            hf: row.sh as i32 as f32,
            sw: row.sw as u32,
            to_client: *to_client,
            w,
            still: w * 0.0,
        }
    }
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
    // Finite motions too large to add up are rejected (they lie far outside NDC).
    point_of_clip(k, x, z, h, (o[0] + o[1] + o[2]).is_finite())
}

/// [`flow_point`] for a point whose motion is `[+0.0; 3]` (every bit clear), with one transfer
/// instead of two and the same output bytes. Flow, client depth and cell are the same; the key
/// depth too wherever there is a cell (it is unspecified elsewhere).
///
/// Why: the moved point `(x + 0, y + 0, z + 0)` is the point itself, bit for bit, except for
/// `z = −0` (`+0` then; `x` and `y` are never −0, see
/// [`ndc_of_pixel`](crate::camera::ndc_of_pixel)) and a signalling NaN `z` (quieted). So `b = a`,
/// and for a finite `a[i]`, `b[i] − a[i] = +0` and `h[i] = a[i] + w·(+0) = a[i] + still`: the same
/// operations on the same operands. For `z = −0`, the terms `m·z` of the transfer's dot products
/// (numerators and divisor) differ only in the sign of a zero, which changes a sum only where it
/// is zero, and then only its sign: `b[i]` is `a[i]`, or the other zero where `a[i] = ±0`, and
/// not finite where `a[i]` is not. With `a[i] = ±0`, `b[i] − a[i]` is `+0` (as above) unless
/// `a[i] = +0`, where `h[i] = +0 + w·(±0) = +0 = a[i] + still` either way. Where some `a[i]` is
/// not finite (invalid depth, a degenerate transfer), [`flow_point`]'s `h[i]` is NaN (`∞ − ∞`)
/// and this one is `a[i]`, infinite or NaN: both reject the point (`h.w` not in `(0, ∞)`, or
/// `h[i]·(1/h.w)` not finite), so only the unused key depth can differ. A NaN `z` is rejected by
/// both. `still_points_flow_as_the_general_path` (tests) checks all of these cases.
#[inline(always)]
fn still_point(k: &PointCtx, x: f32, z: f32) -> FlowPoint {
    let a = k.to_client.clip([x, k.y, z]);
    let h = [
        a[0] + k.still,
        a[1] + k.still,
        a[2] + k.still,
        a[3] + k.still,
    ];
    point_of_clip(k, x, z, h, true)
}

/// The outputs of [`flow_point`] for the blended clip coordinates `h` of the point at NDC x `x`
/// and depth `z`; `motion_ok` is whether its motion adds up to a finite sum.
#[inline(always)]
fn point_of_clip(k: &PointCtx, x: f32, z: f32, h: [f32; 4], motion_ok: bool) -> FlowPoint {
    let y = k.y;
    let iw = 1.0 / h[3];
    let cc = [h[0] * iw, h[1] * iw, h[2] * iw];
    // Invalid depth or motion never reaches the output (DESIGN.md): NaN or infinite inputs make
    // `cc` or the sum of the motion non-finite. Points behind the client camera (or degenerate)
    // have `h.w ≤ 0`. `h.w ≤ f32::MAX` is `h.w < ∞`: written as `< ∞`, the two bounds became
    // a class test in integer instructions on AVX2, 11 instructions instead of 3 (−0.9 M per
    // 640×360 frame).
    let ok = (0.0..=1.0).contains(&z)
        && h[3] > 0.0
        && h[3] <= f32::MAX
        && cc[0].is_finite()
        && cc[1].is_finite()
        && cc[2].is_finite()
        && motion_ok;
    let (f, zc) = if ok {
        ([cc[0] - x, cc[1] - y], cc[2])
    } else {
        ([f32::NAN; 2], f32::NAN)
    };
    // In front of the client and not nearer than its near plane (with a margin for the f32 round
    // trip of points on it). Points at or beyond the far plane (the background lies at Z = 0) are
    // kept, their key depth clamped to exactly +0 (−0 or negative bits would sort as nearest).
    let (inside, cell) = pixel_index_of_ndc(cc[0], cc[1], k.wf, k.hf, k.sw);
    let splats = ok & inside & (cc[2] <= 1.0 + 1e-5);
    let kz = if cc[2] > 0.0 { cc[2].min(1.0) } else { 0.0 };
    FlowPoint {
        flow: f,
        zc,
        cell: if splats { cell } else { NO_SPLAT },
        kz,
    }
}

thread_local! {
    /// The working rows of [`window_block`], reused across blocks and frames.
    static WINDOW_ROWS: std::cell::RefCell<Vec<u64>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The window search of every cell at once: `init[c]` = the packed source pixel of the smallest
/// splat key of the grid's epoch in the `(2W+1)²` window around cell `c` (clipped to the grid),
/// or [`NO_SPLAT`].
///
/// Searching per output pixel reads nine keys for each of the two frames; the minimum is
/// separable, so a column pass and a row pass give every cell's answer with about `4W+2`
/// comparisons on sequential memory, and the resolve pass then reads one `u32` per search.
pub(super) fn window_min(src: &mut Src, wr: usize) {
    let (sw, sh) = (src.proj.width, src.proj.height);
    let splat = &src.bufs.splat;
    let bound = src.bufs.epoch.bound();
    src.bufs
        .init
        .par_chunks_mut(TILE * sw)
        .enumerate()
        // One job per block, as the bands of `scene_flow_and_splat`.
        .with_max_len(1)
        .for_each(|(b, out)| {
            WINDOW_ROWS.with(|cell| {
                let first = SrcRow {
                    j: b * TILE,
                    sw,
                    sh,
                };
                window_block(splat, bound, first, wr, out, &mut cell.borrow_mut())
            })
        });
}

/// [`window_min`] for the `rows` cells rows from `j0` only, into `out` (`rows · W` entries):
/// what pass 2 reads for a block of output rows of a source whose grid is the client's.
pub(super) fn window_rows(src: &Src, j0: usize, rows: usize, wr: usize, out: &mut Vec<u32>) {
    let (sw, sh) = (src.proj.width, src.proj.height);
    out.resize(rows * sw, NO_SPLAT);
    let first = SrcRow { j: j0, sw, sh };
    let bound = src.bufs.epoch.bound();
    WINDOW_ROWS.with(|cell| {
        window_block(
            &src.bufs.splat,
            bound,
            first,
            wr,
            &mut out[..rows * sw],
            &mut cell.borrow_mut(),
        )
    });
}

simd_dispatch! {
    /// [`window_min`] for the output rows starting at `first`; `scratch` holds two working rows. A
    /// minimum at or above `bound` ([`SplatEpoch::bound`](super::SplatEpoch::bound)) is an empty window.
    fn window_block / window_block_avx2, window_block_avx512 => window_block_impl(
        splat: &[u64],
        bound: i64,
        first: SrcRow,
        wr: usize,
        out: &mut [u32],
        scratch: &mut Vec<u64>,
    )
}

#[inline(always)]
fn window_block_impl(
    splat: &[u64],
    bound: i64,
    first: SrcRow,
    wr: usize,
    out: &mut [u32],
    scratch: &mut Vec<u64>,
) {
    let SrcRow { j: j0, sw, sh } = first;
    // Each output row: the minimum down the window's rows of the grid first, into one row of
    // working space, then across it. The rows read for one output row are read again for the
    // next two, while they are in L1, and the working row stays there too. (The order the other
    // way round, a row pass over all the block's grid rows into a buffer of row minima and then
    // the minimum down it, wrote and read back 200 KB per block at 1280×720: paired in one
    // process, this order took 0.958–0.965 of the frame there, 0.946 on one thread.) The minimum
    // of integers is exact in any order, so the result is the same.
    scratch.resize(2 * sw, EMPTY_SPLAT);
    let (acc, tmp) = scratch.split_at_mut(sw);
    let row = |q: usize| &splat[q * sw..(q + 1) * sw];
    // The low half of a key is its packed pixel; a minimum of earlier epochs or EMPTY_SPLAT is
    // no splat.
    let init = |m: u64| {
        if (m as i64) < bound {
            splat_index(m)
        } else {
            NO_SPLAT
        }
    };
    for (r, o) in out.chunks_mut(sw).enumerate() {
        let j = j0 + r;
        let (a, z) = (j.saturating_sub(wr), (j + wr).min(sh - 1));
        if z == a + 2 {
            // Three rows (wr = 1 away from the border): one pass.
            for (d, ((x, y), w)) in acc
                .iter_mut()
                .zip(row(a).iter().zip(row(a + 1)).zip(row(z)))
            {
                *d = key_min(key_min(*x, *y), *w);
            }
        } else {
            acc.copy_from_slice(row(a));
            for q in a + 1..=z {
                for (m, v) in acc.iter_mut().zip(row(q)) {
                    *m = key_min(*m, *v);
                }
            }
        }
        // Each step across widens the minimum by one pixel on both sides; the last one writes
        // the output.
        for _ in 1..wr {
            tmp.copy_from_slice(acc);
            min3(tmp, acc);
        }
        if wr == 0 || sw < 2 {
            for (d, m) in o.iter_mut().zip(acc.iter()) {
                *d = init(*m);
            }
        } else {
            o[0] = init(key_min(acc[0], acc[1]));
            o[sw - 1] = init(key_min(acc[sw - 2], acc[sw - 1]));
            for (d, ((x, y), w)) in o[1..sw - 1]
                .iter_mut()
                .zip(acc[..sw - 2].iter().zip(&acc[1..sw - 1]).zip(&acc[2..]))
            {
                *d = init(key_min(key_min(*x, *y), *w));
            }
        }
    }
}

/// The smaller of two stored splat keys ([`SplatEpoch`](super::SplatEpoch)) or [`EMPTY_SPLAT`],
/// compared as `i64` (the stored form makes the signed order the one the splat needs; AVX2 has a
/// signed 64-bit compare but no unsigned one).
#[inline(always)]
pub(super) fn key_min(a: u64, b: u64) -> u64 {
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

#[cfg(test)]
mod tests {
    use super::super::{set_simd_limit, Simd};
    use super::*;
    use std::sync::atomic::AtomicU8;

    /// The tests' generator ([`draw`](super::super::draw)) around its state.
    struct Rng(u64);

    impl Rng {
        fn below(&mut self, n: u64) -> u64 {
            super::super::draw(&mut self.0, n)
        }
    }

    /// [`splat_row`] at every tier leaves the band and the spill list (as a multiset) of the
    /// plain splat, point by point: the nearest key per cell of the band, the points of other
    /// cells kept aside, those without a cell dropped. The rows mix every kind of chunk: runs of
    /// consecutive cells inside the band, across its first or last cell and outside it, no
    /// splat, repeated or skipped cells (points that spread out or crowd), cells in another band,
    /// runs that wrap past [`NO_SPLAT`], and a run broken by one point; key depths include ±0,
    /// ±∞, NaN and subnormals, and equal depths (ties go to the smaller pixel); rows of every
    /// length modulo the chunk; keys stored in every epoch, over a band that holds empty cells
    /// and keys of the epoch.
    #[test]
    fn splat_row_equals_the_point_by_point_splat_at_every_tier() {
        let mut rng = Rng(0x2545_f491_4f6c_dd1d);
        let (base, n) = (400u32, 300usize);
        let depths = [
            0.0,
            -0.0,
            1.0,
            0.25,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE / 4.0,
        ];
        // Chunks that took the vector path and chunks without a splat, over all rows.
        let (mut runs, mut empty) = (0, 0);
        for trial in 0..300 {
            let sw = [203, 5, 64, 8, 1 + rng.below(120) as usize][trial % 5];
            let j = rng.below(1 << 14) as usize;
            let mut cell = Vec::with_capacity(sw + 32);
            while cell.len() < sw {
                let len = 1 + rng.below(24) as usize;
                let start = (base as u64 + rng.below(n as u64 + 40)) as u32 - 20;
                match rng.below(7) {
                    0 | 1 => cell.extend((0..len as u32).map(|k| start + k)),
                    2 => cell.extend(std::iter::repeat_n(NO_SPLAT, len)),
                    3 => {
                        let step = [0.0, 0.5, 1.5, 2.0, -1.0][rng.below(5) as usize];
                        cell.extend((0..len).map(|k| (start as f32 + k as f32 * step) as u32));
                    }
                    4 => cell.extend((0..len).map(|_| rng.below(3 * n as u64) as u32)),
                    5 => {
                        let from = NO_SPLAT - rng.below(10) as u32;
                        cell.extend((0..len as u32).map(|k| from.wrapping_add(k)));
                    }
                    _ => {
                        let at = cell.len() + rng.below(len as u64) as usize;
                        cell.extend((0..len as u32).map(|k| start + k));
                        cell[at] = [NO_SPLAT, base + n as u32 + 7][rng.below(2) as usize];
                    }
                }
            }
            cell.truncate(sw);
            let kz: Vec<f32> = (0..sw)
                .map(|_| match rng.below(3) {
                    0 => depths[rng.below(depths.len() as u64) as usize],
                    _ => rng.below(1 << 10) as f32 / 1024.0,
                })
                .collect();
            let stored = super::super::SplatEpoch(rng.below(4) as u8).stored();
            let start: Vec<u64> = (0..n)
                .map(|c| match rng.below(3) {
                    0 => EMPTY_SPLAT,
                    _ => splat_key(rng.below(1 << 10) as f32 / 1024.0, c as u32) ^ stored,
                })
                .collect();
            let (mut band, mut spill) = (start.clone(), Vec::new());
            for (i, (&c, &z)) in cell.iter().zip(&kz).enumerate() {
                let key = splat_key(z, pack_pixel(i, j)) ^ stored;
                match (c.wrapping_sub(base) as usize) < n {
                    true => band[(c - base) as usize] = key_min(band[(c - base) as usize], key),
                    false if c != NO_SPLAT => spill.push((c, key)),
                    false => {}
                }
            }
            spill.sort_unstable();
            for c in cell.chunks_exact(SPLAT_CHUNK) {
                let inside = (c[0].wrapping_sub(base) as usize) + SPLAT_CHUNK <= n;
                runs += usize::from(inside && c.windows(2).all(|p| p[1] == p[0] + 1));
                empty += usize::from(c.iter().all(|&c| c == NO_SPLAT));
            }
            for tier in [Simd::Baseline, Simd::Avx2, Simd::Avx512] {
                set_simd_limit(tier);
                let (mut got, mut got_spill) = (start.clone(), Vec::new());
                splat_row(j, &cell, &kz, stored, base, &mut got, &mut got_spill);
                got_spill.sort_unstable();
                assert!(got == band, "trial {trial}, {tier:?}: band");
                assert!(got_spill == spill, "trial {trial}, {tier:?}: spill");
            }
        }
        set_simd_limit(Simd::Avx512);
        assert!(runs > 300 && empty > 100, "{runs} {empty}");
    }

    /// [`flag_cells`] at every tier sets exactly the flags of the cells in the row other than
    /// [`NO_SPLAT`], for rows of every length modulo the chunk, with chunks that have none, one
    /// or several such cells (repeated ones too).
    #[test]
    fn flag_cells_flags_exactly_the_cells_of_the_row() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let cells = 500;
        for trial in 0..200 {
            let len = rng.below(70) as usize;
            let sparse = rng.below(4);
            let inv: Vec<u32> = (0..len)
                .map(|_| match rng.below(16) < sparse {
                    true => rng.below(cells) as u32,
                    false => NO_SPLAT,
                })
                .collect();
            for tier in [Simd::Baseline, Simd::Avx2, Simd::Avx512] {
                set_simd_limit(tier);
                let flags: Vec<AtomicU8> = (0..cells).map(|_| AtomicU8::new(0)).collect();
                flag_cells(&inv, &flags);
                for (c, f) in flags.iter().enumerate() {
                    let want = inv.contains(&(c as u32));
                    assert_eq!(
                        f.load(Ordering::Relaxed),
                        u8::from(want),
                        "trial {trial}, {tier:?}, cell {c}"
                    );
                }
            }
        }
        set_simd_limit(Simd::Avx512);
    }
}
