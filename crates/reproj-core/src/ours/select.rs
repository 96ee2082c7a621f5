//! Match selection (seeds/000 §3.1): Algorithm 1 keeps, per camera, the better of the older
//! (forward) and newer (backward) match by reprojection error (`ε_e`) and depth (`ε_z`);
//! Algorithm 2 colours the kept match, blended with its correspondence in the other frame where the
//! pair state found one (the "second chance"), after the dynamic shadows of §3.3 (eqs. 9–11,
//! [`shadow_color`]) are applied to each colour; [`Resolve::colour_row`] does it for a row and
//! rounds the colours into the output. Also the diagnostic code of a match.

use crate::request::Diagnostics;
use crate::shadow::{round_rgb4, shadow_color, Role};

use super::pair::{TEXEL_BLEND, TEXEL_SHADOW};
use super::search::SearchRow;
use super::simd::simd_method;
use super::{Cell, Choice, Match, Palette, Resolve, NO_SPLAT};

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
    /// its source's `ω`; [`NO_TEXEL`] where there is no match. Scalar (a load at a data-dependent
    /// index), and a function of its own so that the other loops' pointers do not take its
    /// registers: inside `colour_row` it reloaded three of its own from the stack per pixel.
    #[inline(never)]
    fn gather_texels(&self, src: &[u8], p: &[u32], texels: &mut [[u32; 2]], omega: &mut [f32]) {
        for ((t, w), (&s, &p)) in texels.iter_mut().zip(omega).zip(src.iter().zip(p)) {
            // `NO_SOURCE` is past the last palette.
            let Some(pal) = self.palettes.get(usize::from(s)) else {
                (*t, *w) = ([NO_TEXEL; 2], 0.0);
                continue;
            };
            let (tex, omega) = (pal.texel[p as usize], pal.omega);
            (*t, *w) = ([tex as u32, (tex >> 32) as u32], omega);
        }
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
