//! Dynamic-shadow application, seeds/000 §3.3, eqs. 9–11.
//!
//! A source pixel carries a bitfield `Φ` with the quantised main-light shadow level `L_j ∈ 0..=3`
//! at each of `S` subframes (`L_j = (Φ ≫ 2j) & 3`, subframe 0 = the key frame) and the colours
//! `S_min`/`S_max` at the minimum and maximum level. The colour at subframe `j` is
//! `C(j) = lerp(A′, B′, τ_j)` with `τ_j = (L_j − L_min)/(L_max − L_min)` (eq. 10), where `A′`/`B′`
//! are `S_min`/`S_max`, or the key colour when that extreme is the key frame's own level. The colour
//! at `α` interpolates the two subframes around it, `lerp(C(j_lo), C(j_hi), τ_β)` (eqs. 9 and 11).
//!
//! Subframe times: for the older image (forward buffers) subframe `j` is at `t + j/S`; for the newer
//! image (backward buffers) at `t+1 − j/S`. The intervals that would need a subframe the buffer does
//! not hold (the last interval of the older image, the first of the newer) hold subframe `S−1`
//! (REFERENCE.md §2.9). When extrapolating (`α ≥ 1`) or at `α = 0` the key colour is used.
//!
//! Where we differ from the reference on purpose: when every level is equal (`L_max = L_min`) the
//! reference divides by zero; we return the key colour. Colours stay in `f32` here and are rounded
//! once, by the caller, after blending (the reference truncates twice).

/// Which image of the pair a shadow buffer belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// `I_t`, forward buffers: subframe `j` at `t + j/S`.
    Older,
    /// `I_{t+1}`, backward buffers: subframe `j` at `t+1 − j/S`.
    Newer,
}

/// The quantised level of subframe `j`.
///
/// # Panics
/// In debug builds, for `j ≥ 16` (the shift overflows; a bitfield holds 16 subframes).
#[inline(always)]
pub fn level(bits: u32, j: usize) -> u32 {
    (bits >> (2 * j)) & 3
}

/// `C(j)`, the colour of subframe `j` (eq. 10 and the `lerp` inside eq. 11).
///
/// # Panics
/// In debug builds, for `s > 16` ([`level`]); `s` is [`crate::Params::shadow_subframes`],
/// which [`crate::Params::validate`] keeps in `1..=16`.
#[inline]
pub fn subframe_color(
    base: [f32; 3],
    bits: u32,
    s_min: [u8; 3],
    s_max: [u8; 3],
    j: usize,
    s: usize,
) -> [f32; 3] {
    if j == 0 || j >= s || bits == 0 {
        return base;
    }
    let l0 = level(bits, 0);
    let (mut lmin, mut lmax) = (l0, l0);
    for i in 1..s {
        let l = level(bits, i);
        lmin = lmin.min(l);
        lmax = lmax.max(l);
    }
    if lmax == lmin {
        // All levels equal: nothing changes over the interval (the reference's 0/0).
        return base;
    }
    let tau = (level(bits, j) - lmin) as f32 / (lmax - lmin) as f32;
    let a = if lmin == l0 {
        base
    } else {
        s_min.map(f32::from)
    };
    let b = if lmax == l0 {
        base
    } else {
        s_max.map(f32::from)
    };
    [
        a[0] + tau * (b[0] - a[0]),
        a[1] + tau * (b[1] - a[1]),
        a[2] + tau * (b[2] - a[2]),
    ]
}

/// `c_S`, the colour of a source pixel at `α` with its dynamic shadow applied (eqs. 9–11).
///
/// # Panics
/// In debug builds, for `s > 16` ([`subframe_color`]).
#[inline]
pub fn shadow_color(
    base: [u8; 3],
    bits: u32,
    s_min: [u8; 3],
    s_max: [u8; 3],
    alpha: f32,
    s: usize,
    role: Role,
) -> [f32; 3] {
    let basef = base.map(f32::from);
    if bits == 0 {
        return basef;
    }
    let beta = s as f32 * alpha;
    let lo = beta.floor();
    let hi = beta.ceil();
    // lo ≥ S: extrapolation; hi ≤ 0: α = 0, the key frame time of the older image. Negative or NaN
    // α fails `hi > 0` and returns the key colour as well.
    if !(lo < s as f32 && hi > 0.0) {
        return basef;
    }
    let (lo_i, hi_i) = (lo as usize, hi as usize);
    let lambda = beta - lo;
    let (j_lo, j_hi) = match role {
        Role::Older => (lo_i, hi_i),
        Role::Newer => (s - lo_i, s - hi_i),
    };
    let c = |j| subframe_color(basef, bits, s_min, s_max, j, s);
    if j_lo == j_hi || j_hi >= s {
        c(j_lo)
    } else if j_lo >= s {
        c(j_hi)
    } else {
        let (a, b) = (c(j_lo), c(j_hi));
        [
            a[0] + lambda * (b[0] - a[0]),
            a[1] + lambda * (b[1] - a[1]),
            a[2] + lambda * (b[2] - a[2]),
        ]
    }
}

/// Rounds a colour in `[0,255]` floats to RGB8 (round half away from zero, clamped).
#[inline(always)]
pub fn round_rgb(c: [f32; 3]) -> [u8; 3] {
    c.map(round_channel)
}

/// [`round_rgb`] of four lanes (`[r, g, b, x]`), which the compiler does as one vector.
#[inline(always)]
pub fn round_rgb4(c: [f32; 4]) -> [u8; 4] {
    c.map(round_channel)
}

/// One channel of [`round_rgb`].
#[inline(always)]
fn round_channel(v: f32) -> u8 {
    // Half up after clamping to [0, 255] equals round-half-away-from-zero there, without a libm
    // `roundf` call. The clamp as two selects that map NaN to 0 (as the saturating cast of a
    // clamped NaN did): single `maxss`/`minss` instructions, where `f32::clamp` keeps NaN and the
    // cast then needs its NaN and range fix-ups.
    let v = if v > 0.0 { v } else { 0.0 };
    let v = if v < 255.0 { v } else { 255.0 };
    // SAFETY: 0.5 ≤ v + 0.5 ≤ 255.5, finite and in i32's range.
    unsafe { (v + 0.5).to_int_unchecked::<i32>() as u8 }
}

/// Applies the dynamic shadows of a whole image at `α` (eqs. 9–11) into `out` (`H·W·3`). Used by
/// tests and tools; the reprojection applies shadows per sampled pixel instead.
///
/// # Panics
/// When `bits` holds fewer than `out.len() / 3` values or `s_min`/`s_max` fewer than `out`'s
/// length (`color` and `out` are zipped: the shorter one sets the pixels written), or, in debug
/// builds, for `s > 16` ([`shadow_color`]); the Python binding checks all of them first.
pub fn apply_shadows(
    color: &[u8],
    bits: &[u32],
    s_min: &[u8],
    s_max: &[u8],
    alpha: f32,
    s: usize,
    role: Role,
    out: &mut [u8],
) {
    use rayon::prelude::*;
    out.par_chunks_mut(3)
        .zip(color.par_chunks(3))
        .enumerate()
        .for_each(|(i, (o, c))| {
            let rgb = |b: &[u8]| [b[3 * i], b[3 * i + 1], b[3 * i + 2]];
            let v = shadow_color(
                [c[0], c[1], c[2]],
                bits[i],
                rgb(s_min),
                rgb(s_max),
                alpha,
                s,
                role,
            );
            o.copy_from_slice(&round_rgb(v));
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: usize = 4;

    #[test]
    fn no_bits_is_base() {
        let c = shadow_color([10, 20, 30], 0, [0; 3], [0; 3], 0.4, S, Role::Older);
        assert_eq!(c, [10.0, 20.0, 30.0]);
    }

    #[test]
    fn equal_levels_do_not_divide_by_zero() {
        // Every subframe at level 2: the reference's τ = 0/0.
        let bits = 0b10_10_10_10;
        for role in [Role::Older, Role::Newer] {
            for k in 0..=8 {
                let c = shadow_color([10, 20, 30], bits, [1; 3], [2; 3], k as f32 / 8.0, S, role);
                assert_eq!(c, [10.0, 20.0, 30.0]);
            }
        }
    }

    #[test]
    fn paper_figure_5_pixel() {
        // 11 11 11 00: lit at t, fully shadowed for subframes 1..3 (Fig. 5). S_max is the shadowed
        // colour; S_min is the key frame's level, so the key colour is used for it.
        let bits = 0b11_11_11_00;
        let base = [200, 200, 200];
        let dark = [40, 40, 40];
        let at = |a: f32| shadow_color(base, bits, [0; 3], dark, a, S, Role::Older);
        assert_eq!(at(0.0), [200.0; 3]);
        assert_eq!(at(0.25), [40.0; 3]);
        assert_eq!(at(0.5), [40.0; 3]);
        // Half way between subframe 0 (lit) and 1 (dark).
        assert_eq!(at(0.125), [120.0; 3]);
        // The last interval holds subframe S−1.
        assert_eq!(at(0.9), [40.0; 3]);
        // Extrapolation uses the key colour.
        assert_eq!(at(1.2), [200.0; 3]);
    }

    #[test]
    fn newer_image_counts_backwards() {
        // Backward buffer: subframe j at t+1 − j/4. Dark at j = 2 only (t + 0.5).
        let bits = 0b00_11_00_00;
        let base = [100, 100, 100];
        let at = |a: f32| shadow_color(base, bits, [0; 3], [0, 0, 0], a, S, Role::Newer);
        assert_eq!(at(0.5), [0.0; 3]);
        assert_eq!(at(0.75), [100.0; 3]);
        assert_eq!(at(0.625), [50.0; 3]);
        // First interval holds subframe S−1 = 3 (level 0, key colour).
        assert_eq!(at(0.1), [100.0; 3]);
        // Off the middle of an interval: t + 0.55 is a fifth of the way from subframe 2 (t + 0.5,
        // dark) to subframe 1 (t + 0.75, lit).
        assert_close(at(0.55), [20.0; 3]);
        assert_close(at(0.7), [80.0; 3]);
    }

    fn assert_close(got: [f32; 3], want: [f32; 3]) {
        let ok = got.iter().zip(&want).all(|(g, w)| (g - w).abs() < 1e-3);
        assert!(ok, "{got:?} vs {want:?}");
    }

    #[test]
    fn older_image_interpolates_linearly_within_an_interval() {
        // Fig. 5's pixel: lit (200) at subframe 0, dark (40) from subframe 1 on.
        let bits = 0b11_11_11_00;
        let at = |a: f32| shadow_color([200; 3], bits, [0; 3], [40; 3], a, S, Role::Older);
        // β = 0.2 and 0.8 of the way from subframe 0 to subframe 1.
        assert_close(at(0.05), [168.0; 3]);
        assert_close(at(0.2), [72.0; 3]);
    }

    #[test]
    fn key_frame_in_shadow_lightens_toward_s_min() {
        // Levels 3, 1, 0, 0: the key frame is the most shadowed (its colour is B′, S_max is not
        // stored, here a poison value) and S_min is the lit colour.
        let bits = 0b00_00_01_11;
        let (key, s_min, poison) = ([30, 30, 30], [210, 180, 150], [1, 2, 3]);
        for role in [Role::Older, Role::Newer] {
            let at = |a: f32| shadow_color(key, bits, s_min, poison, a, S, role);
            let (sub1, sub2) = match role {
                Role::Older => (0.25, 0.5),
                Role::Newer => (0.75, 0.5),
            };
            // Subframe 2 at level 0 = L_min: S_min itself; subframe 1 at level 1: a third of
            // the way from S_min to the key colour.
            assert_close(at(sub2), [210.0, 180.0, 150.0]);
            assert_close(at(sub1), [150.0, 130.0, 110.0]);
        }
    }

    #[test]
    fn colours_round_half_away_from_zero_and_clamp() {
        assert_eq!(round_rgb([0.49, 0.5, 254.5]), [0, 1, 255]);
        assert_eq!(round_rgb([127.5, -3.0, 300.0]), [128, 0, 255]);
        assert_eq!(round_rgb([f32::NAN, 1.4999, 2.5]), [0, 1, 3]);
        assert_eq!(
            round_rgb4([0.5, 99.5, 254.49, f32::INFINITY]),
            [1, 100, 254, 255]
        );
    }

    #[test]
    fn apply_shadows_takes_each_pixels_own_buffers() {
        // Pixel 0: no dynamic shadow; pixel 1: Fig. 5 (S_max dark); pixel 2: shadowed key frame
        // (S_min lit). At α = 0.5 (subframe 2) every shadowed pixel shows its stored extreme.
        let color = [10, 20, 30, 200, 200, 200, 30, 30, 30];
        let bits = [0, 0b11_11_11_00, 0b00_00_01_11];
        let s_min = [9, 9, 9, 0, 0, 0, 210, 180, 150];
        let s_max = [9, 9, 9, 40, 41, 42, 0, 0, 0];
        let mut out = [0u8; 9];
        apply_shadows(&color, &bits, &s_min, &s_max, 0.5, S, Role::Older, &mut out);
        assert_eq!(out, [10, 20, 30, 40, 41, 42, 210, 180, 150]);
    }
}
