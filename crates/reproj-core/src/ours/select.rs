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

/// The match each pixel of a row keeps: source index (or [`NO_SOURCE`]), source pixel, error and
/// client depth.
#[derive(Debug, Default)]
pub(super) struct Picks {
    pub(super) src: Vec<u8>,
    pub(super) p: Vec<u32>,
    pub(super) e: Vec<f32>,
    pub(super) z: Vec<f32>,
    /// The colour of each kept match ([`Resolve::second_chance`]).
    pub(super) rgb: Vec<[f32; 4]>,
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
        /// The colours of a row: Algorithm 2 ([`Resolve::second_chance`]) for every pixel that
        /// kept a match, then their rounding into `out` (the row's `3·W` bytes; a pixel without a
        /// match keeps the previous frame's colour there), and the diagnostics when asked. Two
        /// loops, so that the float-to-byte conversions of a pixel do not wait behind its colour
        /// loads, compiled for AVX-512 / AVX2 like the other stages (the colours' conversions and
        /// blends are four-lane vectors).
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
        picks.rgb.resize(cw, [0.0; 4]);
        for i in 0..cw {
            let src = picks.src[i];
            if src == NO_SOURCE {
                if let Some((s, err)) = diag.as_mut() {
                    s[i] = Diagnostics::NONE;
                    err[i] = f32::NAN;
                }
                continue;
            }
            let (rgb, blended) = self.colour_of_match(usize::from(src), picks.p[i] as usize);
            picks.rgb[i] = rgb;
            if let Some((s, err)) = diag.as_mut() {
                s[i] = self.code_of(usize::from(src), blended);
                err[i] = picks.e[i];
            }
        }
        for ((o, &src), &rgb) in out
            .chunks_exact_mut(3)
            .zip(&picks.src[..cw])
            .zip(&picks.rgb[..cw])
        {
            if src != NO_SOURCE {
                o.copy_from_slice(&round_rgb4(rgb)[..3]);
            }
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

    /// [`Resolve::second_chance`] from the pair's texel of the match (one load): the same
    /// colour, computed by the same operations, except where shadow bits make it depend on α.
    #[inline(always)]
    fn colour_of_match(&self, src: usize, p: usize) -> ([f32; 4], bool) {
        let pal = &self.palettes[src];
        let t = pal.texel[p].to_le_bytes();
        if t[3] == TEXEL_SHADOW {
            return self.second_chance(src, p);
        }
        let base = [t[0], t[1], t[2], 0].map(f32::from);
        if t[3] != TEXEL_BLEND {
            return (base, false);
        }
        let oc = [t[4], t[5], t[6], 0].map(f32::from);
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
