//! Match selection (seeds/000 §3.1): Algorithm 1 keeps, per camera, the better of the older
//! (forward) and newer (backward) match by reprojection error (`ε_e`) and depth (`ε_z`);
//! Algorithm 2 colours the kept match, blended with its correspondence in the other frame where the
//! pair state found one (the "second chance"), after the dynamic shadows of §3.3 (eqs. 9–11,
//! [`shadow_color`]) are applied to each colour; [`Resolve::colour_row`] does it for a row and
//! rounds the colours into the output. Also the diagnostic code of a match.

use crate::request::Diagnostics;
use crate::shadow::{round_rgb4, shadow_color, Role};

use super::pair::{TEXEL_BLEND, TEXEL_SHADOW};
#[cfg(target_arch = "x86_64")]
use super::search::{Gathers, SearchRow};
use super::{Cell, Choice, Match, Palette, Resolve, NO_SPLAT};
use crate::simd::{simd_dispatch, simd_method};

/// "No source" in [`Picks::src`].
pub(super) const NO_SOURCE: u8 = u8::MAX;

/// The texel [`Resolve::colour_row`] takes for a pixel without a source: of a kind above every
/// [`texel`](super::pair::texel)'s, so that the pixel goes to the rare path (which keeps its
/// previous colour).
const NO_TEXEL: u32 = u32::MAX;

/// Pixels per test for rare texels in [`Resolve::colour_row`].
const RARE_CHUNK: usize = 32;

/// The match each pixel of a row keeps: source index (or [`NO_SOURCE`]), source pixel, error and
/// client depth.
#[derive(Debug, Default)]
pub(super) struct Picks {
    pub(super) src: Vec<u8>,
    pub(super) p: Vec<u32>,
    pub(super) e: Vec<f32>,
    pub(super) z: Vec<f32>,
    /// Scratch of [`Resolve::colour_row`]: the texel of each pixel's match
    /// ([`texel`](super::pair::texel), as two words), its source's `ω`, and its colour as RGBX.
    pub(super) texel: Vec<[u32; 2]>,
    pub(super) omega: Vec<f32>,
    pub(super) rgb: Vec<u32>,
    /// Scratch of [`Resolve::aux_row`]: the pixels without a main match.
    pub(super) list: Vec<u32>,
}

impl Picks {
    fn resize(&mut self, n: usize) {
        self.src.resize(n, NO_SOURCE);
        self.p.resize(n, 0);
        self.e.resize(n, 0.0);
        self.z.resize(n, 0.0);
    }
}

impl Resolve<'_> {
    simd_method! {
        /// Algorithm 1 for the main camera over a row, from the searches of
        /// [`Resolve::search_row`]: the same decisions as [`Resolve::choose`], written as selects
        /// (and vectorised by the compiler).
        pub(super) fn choose_row / choose_row_avx2, choose_row_avx512 => choose_row_impl(&self, sides: &[SearchRow], picks: &mut Picks)
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

    simd_method! {
        /// The colours of a row (Algorithm 2 with the dynamic shadows) rounded into `out` (the
        /// row's `3·W` bytes; a pixel without a match keeps the previous frame's colour there),
        /// and the diagnostics when asked. The texel of each match first
        /// ([`Resolve::gather_texels`]), then each stage a loop over the row: every pixel's colour
        /// from its texel, without branches, so that the compiler vectorises it across pixels
        /// (AVX-512 / AVX2 like the other stages); the rare pixels (no match, or shadow bits,
        /// whose colour depends on α) by the full path ([`Resolve::second_chance`]), found a
        /// chunk at a time; the colours packed from four bytes to three. One loop per pixel that
        /// branched on the texel's kind and blended four lanes cost 89 instructions per output
        /// pixel, these 30 (AVX2, 640×360).
        pub(super) fn colour_row / colour_row_avx2, colour_row_avx512 => colour_row_impl(&self, picks: &mut Picks, out: &mut [u8], diag: Option<(&mut [u8], &mut [f32])>)
    }

    #[inline(always)]
    fn colour_row_impl(
        &self,
        picks: &mut Picks,
        out: &mut [u8],
        mut diag: Option<(&mut [u8], &mut [f32])>,
    ) {
        let cw = self.client_w;
        let out = &mut out[..3 * cw];
        picks.texel.resize(cw, [0; 2]);
        picks.omega.resize(cw, 0.0);
        picks.rgb.resize(cw, 0);
        let (src, p, texels, omega, rgb) = (
            &picks.src[..cw],
            &picks.p[..cw],
            &mut picks.texel[..cw],
            &mut picks.omega[..cw],
            &mut picks.rgb[..cw],
        );
        self.gather_texels(src, p, texels, omega);
        // The blend of `second_chance` where the texel says so, else the own colour, which
        // `f32::from` and `round_rgb4` give back unchanged.
        for ((c, &[own, oth]), &w) in rgb.iter_mut().zip(&*texels).zip(&*omega) {
            let ch = |x: u32, c: u32| f32::from((x >> (8 * c)) as u8);
            let base = [ch(own, 0), ch(own, 1), ch(own, 2), 0.0];
            let oc = [ch(oth, 0), ch(oth, 1), ch(oth, 2), 0.0];
            let b = u32::from_le_bytes(round_rgb4(blend(w, base, oc)));
            *c = if own >> 24 == u32::from(TEXEL_BLEND) {
                b
            } else {
                own
            };
        }
        if let Some((codes, err)) = diag.as_mut() {
            for i in 0..cw {
                (codes[i], err[i]) = if src[i] == NO_SOURCE {
                    (Diagnostics::NONE, f32::NAN)
                } else {
                    let blended = texels[i][0] >> 24 == u32::from(TEXEL_BLEND);
                    (self.code_of(usize::from(src[i]), blended), picks.e[i])
                };
            }
        }
        // The rare pixels that the blend loop does not colour: it kept their texels' kinds, the
        // largest, in the top byte (a blend leaves zero there). Tested a chunk at a time (a vector
        // reduction), then pixel by pixel.
        let rare = |c: u32| c >> 24 >= u32::from(TEXEL_SHADOW);
        for (k, chunk) in rgb.chunks_mut(RARE_CHUNK).enumerate() {
            if !chunk.iter().fold(false, |any, &c| any | rare(c)) {
                continue;
            }
            for (d, c) in chunk.iter_mut().enumerate().filter(|(_, c)| rare(**c)) {
                let i = k * RARE_CHUNK + d;
                let s = src[i];
                let [r, g, b, _] = if s == NO_SOURCE {
                    // The previous frame's colour.
                    [out[3 * i], out[3 * i + 1], out[3 * i + 2], 0]
                } else {
                    let (c, blended) = self.second_chance(usize::from(s), p[i] as usize);
                    if let Some((codes, _)) = diag.as_mut() {
                        codes[i] = self.code_of(usize::from(s), blended);
                    }
                    round_rgb4(c)
                };
                *c = u32::from_le_bytes([r, g, b, 0]);
            }
        }
        // RGBX to RGB, four pixels (three words) at a time.
        let mut quads = out.chunks_exact_mut(12);
        for (o, c) in (&mut quads).zip(rgb.chunks_exact(4)) {
            let w = [
                c[0] & 0xFF_FFFF | c[1] << 24,
                (c[1] >> 8) & 0xFFFF | c[2] << 16,
                (c[2] >> 16) & 0xFF | c[3] << 8,
            ];
            for (o, w) in o.chunks_exact_mut(4).zip(w) {
                o.copy_from_slice(&w.to_le_bytes());
            }
        }
        let tail = quads.into_remainder();
        for (o, c) in tail.chunks_exact_mut(3).zip(&rgb[cw / 4 * 4..]) {
            o.copy_from_slice(&c.to_le_bytes()[..3]);
        }
    }

    /// The first loop of [`Resolve::colour_row`]: the texel of each pixel's match (as two words,
    /// so that the loop over them has no 64-bit lanes and vectorises eight or sixteen wide) and
    /// its source's `ω`; [`NO_TEXEL`] where there is no match. A function of its own so that the
    /// other loops' pointers do not take its registers: inside `colour_row` it reloaded three of
    /// its own from the stack per pixel.
    ///
    /// The texels are loads at data-dependent indices, into the palette of the pixel's source. A
    /// row is mostly long runs of one source, so it goes run by run, each a loop of loads from
    /// one table ([`Gathers::texels`]: gather instructions in the AVX2 and AVX-512 builds,
    /// dispatched as [`Resolve::search_row`] is). Pixel by pixel it cost 18 instructions each, run
    /// by run 4.2 (AVX2, 640×360).
    #[inline(never)]
    fn gather_texels(&self, src: &[u8], p: &[u32], texels: &mut [[u32; 2]], omega: &mut [f32]) {
        gather_texels(&self.palettes, src, p, texels, omega);
    }

    /// Algorithm 1 for camera `cam`: the better of its older and newer match, or `None`.
    #[inline]
    pub(super) fn best_match(
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
    pub(super) fn choose(
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
    /// agree (precomputed for the pair, see [`PairCache`](super::PairCache)). Returns the colour (as
    /// [`Resolve::color_of`]) and whether it blended.
    #[inline(always)]
    pub(super) fn second_chance(&self, src: usize, p: usize) -> ([f32; 4], bool) {
        let pal = &self.palettes[src];
        let base = self.color_of(pal, p);
        // `partner` is empty when nothing blends (unidirectional, forward_splat, blending off).
        let q = match pal.partner.get(p) {
            Some(&q) if q != NO_SPLAT => q as usize,
            _ => return (base, false),
        };
        let oc = self.color_of(&self.palettes[pal.other], q);
        (blend(pal.omega, base, oc), true)
    }

    /// The diagnostic code of a match in source `src`.
    pub(super) fn code_of(&self, src: usize, blended: bool) -> u8 {
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
}

simd_dispatch! {
    /// [`Resolve::gather_texels`] with the palettes `pal`, by instruction set (the AVX2 and
    /// AVX-512 builds with gather instructions).
    fn gather_texels / gather_texels_avx2, gather_texels_avx512 => gather_texels_impl(
        gathers,
        pal: &[Palette],
        src: &[u8],
        p: &[u32],
        texels: &mut [[u32; 2]],
        omega: &mut [f32],
    )
}

/// [`Resolve::gather_texels`] run by run of pixels with one source.
#[inline(always)]
fn gather_texels_impl(
    g: impl Gathers,
    pal: &[Palette],
    src: &[u8],
    p: &[u32],
    texels: &mut [[u32; 2]],
    omega: &mut [f32],
) {
    let n = src.len();
    let (p, texels, omega) = (&p[..n], &mut texels[..n], &mut omega[..n]);
    let mut i = 0;
    while i < n {
        let s = src[i];
        let end = i + run_len(&src[i..], s);
        // `NO_SOURCE` is past the last palette.
        match pal.get(usize::from(s)) {
            Some(pal) => {
                g.texels(pal.texel, &p[i..end], &mut texels[i..end]);
                omega[i..end].fill(pal.omega);
            }
            None => {
                texels[i..end].fill([NO_TEXEL; 2]);
                omega[i..end].fill(0.0);
            }
        }
        i = end;
    }
}

/// How many bytes `src` starts with that equal `s` (at least one where `src[0] == s`), compared
/// eight at a time.
#[inline(always)]
fn run_len(src: &[u8], s: u8) -> usize {
    let splat = u64::from_le_bytes([s; 8]);
    let mut chunks = src.chunks_exact(8);
    let mut n = 0;
    for c in &mut chunks {
        let differ = u64::from_le_bytes(c.try_into().expect("eight bytes")) ^ splat;
        if differ != 0 {
            // The first differing byte is the lowest nonzero one (little-endian).
            return n + (differ.trailing_zeros() / 8) as usize;
        }
        n += 8;
    }
    n + chunks.remainder().iter().take_while(|&&b| b == s).count()
}

/// Algorithm 2's blend of a colour `base` with its correspondence's colour `oc`, `ω` the weight
/// of `base` (four lanes, as [`Resolve::color_of`] gives them).
#[inline(always)]
fn blend(omega: f32, base: [f32; 4], oc: [f32; 4]) -> [f32; 4] {
    let (w, v) = (omega, 1.0 - omega);
    [
        w * base[0] + v * oc[0],
        w * base[1] + v * oc[1],
        w * base[2] + v * oc[2],
        w * base[3] + v * oc[3],
    ]
}

#[cfg(test)]
mod tests {
    use super::super::search::Portable;
    use super::super::Palette;
    use super::{gather_texels, gather_texels_impl, run_len, NO_SOURCE};
    use crate::shadow::Role;
    use crate::simd::{set_simd_limit, simd_tier, Simd};

    /// A build of [`gather_texels`], as its arguments without the palettes.
    type Gather<'a> = &'a dyn Fn(&[u8], &[u32], &mut [[u32; 2]], &mut [f32]);

    /// The texels and `ω` of [`gather_texels`] at every tier (and of the AVX2 gathers called
    /// directly) are the portable loop's, on rows of every length up to 50 that mix both
    /// sources in runs of every length with pixels without one, and `run_len` counts runs.
    #[test]
    fn gathered_texels_equal_the_portable_loop() {
        let mut seed = 0x2545_F491_4F6C_DD1Du64;
        let mut rng = |n: u64| crate::ours::draw(&mut seed, n);
        // Two sources of different sizes, texels with distinct high and low words.
        let tables: Vec<Vec<u64>> = [37usize, 101]
            .iter()
            .map(|&n| (0..n).map(|_| rng(u64::MAX) | 1 << 63).collect())
            .collect();
        let pal: Vec<Palette> = tables
            .iter()
            .enumerate()
            .map(|(k, t)| Palette {
                color: &[],
                shadow: None,
                role: [Role::Older, Role::Newer][k],
                partner: &[],
                other: k ^ 1,
                texel: t,
                omega: [0.25, 0.75][k],
            })
            .collect();
        let outcome = |f: Gather, src: &[u8]| {
            let p: Vec<u32> = src
                .iter()
                .enumerate()
                .map(|(i, &s)| match s {
                    NO_SOURCE => u32::MAX,
                    s => (i * 7 + 3) as u32 % tables[usize::from(s)].len() as u32,
                })
                .collect();
            let (mut t, mut w) = (vec![[1u32, 2]; src.len()], vec![-1f32; src.len()]);
            f(src, &p, &mut t, &mut w);
            (t, w.iter().map(|w| w.to_bits()).collect::<Vec<_>>())
        };
        let mut checked = 0;
        for len in 0..=50 {
            for max_run in [1, 3, 9, 20] {
                // Runs of random length and source (0, 1 or none).
                let mut src = Vec::new();
                while src.len() < len {
                    let s = [0, 1, NO_SOURCE][rng(3) as usize];
                    let run = 1 + rng(max_run) as usize;
                    src.extend(std::iter::repeat_n(s, run.min(len - src.len())));
                }
                let mut i = 0;
                while i < len {
                    let n = run_len(&src[i..], src[i]);
                    assert!(n >= 1 && src[i..i + n].iter().all(|&b| b == src[i]));
                    assert!(i + n == len || src[i + n] != src[i]);
                    i += n;
                }
                let portable = outcome(
                    &|s, p, t, w| gather_texels_impl(Portable, &pal, s, p, t, w),
                    &src,
                );
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the processor has AVX2 (checked above).
                    let g = unsafe { super::super::search::x86::Avx2::new() };
                    let gathered =
                        outcome(&|s, p, t, w| gather_texels_impl(g, &pal, s, p, t, w), &src);
                    assert_eq!(gathered, portable, "AVX2, {src:?}");
                    checked += 1;
                }
                for tier in [Simd::Baseline, Simd::Avx2, Simd::Avx512] {
                    set_simd_limit(tier);
                    let tiered = outcome(&|s, p, t, w| gather_texels(&pal, s, p, t, w), &src);
                    assert_eq!(tiered, portable, "{tier:?} (as {:?}), {src:?}", simd_tier());
                }
                set_simd_limit(Simd::Avx512);
            }
        }
        assert!(checked == 0 || checked == 51 * 4);
    }
}
