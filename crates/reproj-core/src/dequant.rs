//! Decoding side of the stream format (docs/stream-format.md, version 4): the 12-bit codes of
//! the geometry picture back to depth and motion, and the shadow colours back to RGB where their
//! bitfield is set.
//!
//! The encoder quantises a buffer `v` per channel as `code = rint((v − offset) / scale)`; the
//! decoder inverts it as `v = f32(code) · scale + offset`, in `float32`, multiply then add
//! (never fused), so that the code of 0 that the encoder chose gives exactly `0.0` (eq. "z0" of
//! the format). Motion travels at half resolution: each code covers the 2×2 client pixels
//! `(2y..2y+1, 2x..2x+1)`. Pixels flagged static get motion exactly `+0.0`, pixels flagged
//! invalid get NaN (the lossless masks win over the lossy codes).
//!
//! These loops ran as numpy expressions before (one temporary per step, a repeat for the 2×2
//! upsampling and an index gather for the shadow colours: about half of the decode time of a
//! 1280×720 server frame). They are sequential on purpose: decoding runs on the client's worker
//! thread, next to the display loop, and a frame's dequantisation is a few memory passes.

/// A rectangle of codes inside a decoded picture plane (row-major, `stride` codes per row).
#[derive(Clone, Copy, Debug)]
pub struct CodeTile<'a> {
    /// The whole plane.
    pub plane: &'a [u16],
    /// Codes per row of the plane (its line size, which may exceed its visible width).
    pub stride: usize,
    /// Left column of the tile in the plane.
    pub x: usize,
    /// Top row of the tile in the plane.
    pub y: usize,
}

impl CodeTile<'_> {
    /// Whether a `w × h` tile at `(x, y)` lies inside the plane.
    pub fn fits(&self, w: usize, h: usize) -> bool {
        let rows = self.plane.len().checked_div(self.stride).unwrap_or(0);
        self.x.checked_add(w).is_some_and(|r| r <= self.stride)
            && self.y.checked_add(h).is_some_and(|b| b <= rows)
    }

    fn row(&self, r: usize, w: usize) -> &[u16] {
        let start = (self.y + r) * self.stride + self.x;
        &self.plane[start..start + w]
    }
}

/// Depth of a `w × h` camera from its full-resolution tile:
/// `out = f32(code) · scale + offset`, NaN where `invalid` is set.
///
/// # Panics
/// If the tile does not fit its plane ([`CodeTile::fits`]) or `out`/`invalid` do not hold
/// `w · h` values; the bindings check both first.
pub fn depth_from_codes(
    codes: CodeTile<'_>,
    w: usize,
    h: usize,
    scale: f32,
    offset: f32,
    invalid: Option<&[bool]>,
    out: &mut [f32],
) {
    assert!(codes.fits(w, h) && out.len() == w * h);
    assert!(invalid.is_none_or(|m| m.len() == w * h));
    for (y, dst) in out.chunks_exact_mut(w.max(1)).enumerate().take(h) {
        for (d, &q) in dst.iter_mut().zip(codes.row(y, w)) {
            *d = f32::from(q) * scale + offset;
        }
        if let Some(inv) = invalid {
            for (d, &bad) in dst.iter_mut().zip(&inv[y * w..(y + 1) * w]) {
                if bad {
                    *d = f32::NAN;
                }
            }
        }
    }
}

/// Motion `float32[h, w, 3]` of a camera from its three half-resolution channel tiles
/// (`⌈w/2⌉ × ⌈h/2⌉` codes each): `m(y, x, c) = f32(code_c(y/2, x/2)) · scale_c + offset_c`,
/// `+0.0` where `static_` is set, NaN where `invalid` is set.
///
/// # Panics
/// If a tile does not fit its plane or `out`/the masks have the wrong length; the bindings
/// check both first.
#[allow(clippy::too_many_arguments)]
pub fn motion_from_half_codes(
    channels: [CodeTile<'_>; 3],
    w: usize,
    h: usize,
    scale: [f32; 3],
    offset: [f32; 3],
    static_: Option<&[bool]>,
    invalid: Option<&[bool]>,
    out: &mut [f32],
) {
    let (hw, hh) = (w.div_ceil(2), h.div_ceil(2));
    assert!(channels.iter().all(|t| t.fits(hw, hh)) && out.len() == w * h * 3);
    assert!(static_.is_none_or(|m| m.len() == w * h));
    assert!(invalid.is_none_or(|m| m.len() == w * h));
    let mut half = vec![[0.0f32; 3]; hw];
    // Masks absent: a row of `false` stands in, so that the loop has one shape.
    let none = vec![false; w];
    for (y, dst) in out.chunks_exact_mut(w * 3).enumerate().take(h) {
        if y % 2 == 0 {
            // One half-resolution row serves two client rows.
            for (c, t) in channels.iter().enumerate() {
                for (v, &q) in half.iter_mut().zip(t.row(y / 2, hw)) {
                    v[c] = f32::from(q) * scale[c] + offset[c];
                }
            }
        }
        let row = y * w..(y + 1) * w;
        let st = static_.map_or(&none[..], |m| &m[row.clone()]);
        let inv = invalid.map_or(&none[..], |m| &m[row]);
        for (x, px) in dst.chunks_exact_mut(3).enumerate() {
            let v = if inv[x] {
                [f32::NAN; 3]
            } else if st[x] {
                [0.0; 3]
            } else {
                half[x / 2]
            };
            px.copy_from_slice(&v);
        }
    }
}

/// One full-range BT.709 Y′CbCr picture (8-bit planes; chroma at full or half resolution).
#[derive(Clone, Copy, Debug)]
pub struct YCbCrPlanes<'a> {
    /// Luma, `stride[0]` samples per row.
    pub y: &'a [u8],
    /// Blue-difference chroma, `stride[1]` samples per row.
    pub cb: &'a [u8],
    /// Red-difference chroma, `stride[1]` samples per row.
    pub cr: &'a [u8],
    /// Samples per row of luma and of each chroma plane.
    pub stride: [usize; 2],
    /// 2 for 4:2:0 chroma, 1 for 4:4:4.
    pub sub: usize,
}

impl YCbCrPlanes<'_> {
    /// Whether a `w × h` luma rectangle at `(x, y)` and its chroma lie inside the planes.
    pub fn fits(&self, x: usize, y: usize, w: usize, h: usize) -> bool {
        let inside = |len: usize, stride: usize, x1: usize, y1: usize| {
            stride > 0 && x1 <= stride && y1.checked_mul(stride).is_some_and(|n| n <= len)
        };
        let (x1, y1) = (x.saturating_add(w), y.saturating_add(h));
        let s = self.sub.max(1);
        let (cx1, cy1) = (x1.div_ceil(s), y1.div_ceil(s));
        (self.sub == 1 || self.sub == 2)
            && inside(self.y.len(), self.stride[0], x1, y1)
            && inside(self.cb.len(), self.stride[1], cx1, cy1)
            && inside(self.cr.len(), self.stride[1], cx1, cy1)
    }
}

/// A shadow colour `uint8[h, w, 3]` of a `w × h` camera from its tile at `(x, y)` of its
/// picture, converted to RGB only where `bits` is non-zero (elsewhere 0; the reprojection never
/// reads it there): `R = Y + 1.5748·Cr′`, `G = Y − 0.187324·Cb′ − 0.468124·Cr′`,
/// `B = Y + 1.8556·Cb′` with `C′ = C − 128`, in `float32`, rounded half to even and clamped to
/// `[0, 255]`. The tile has one luma sample per `step × step` pixels (`⌈w/step⌉ × ⌈h/step⌉`
/// samples; `step` 1 or 2: stream format 4 sends shadow colours at half size, as motion), so
/// pixel `(r, c)` takes luma `(y + r/step, x + c/step)` and the chroma sample that covers that
/// luma sample (`/2` again for 4:2:0).
///
/// # Panics
/// If `step` is not 1 or 2, the tile does not fit ([`YCbCrPlanes::fits`]) or `bits`/`out` have
/// the wrong length.
#[allow(clippy::too_many_arguments)]
pub fn shadow_colour_from_ycbcr(
    planes: YCbCrPlanes<'_>,
    x: usize,
    y: usize,
    w: usize,
    h: usize,
    step: usize,
    bits: &[u32],
    out: &mut [u8],
) {
    assert!(step == 1 || step == 2);
    assert!(planes.fits(x, y, w.div_ceil(step), h.div_ceil(step)));
    assert!(bits.len() == w * h && out.len() == w * h * 3);
    out.fill(0);
    let s = planes.sub;
    for r in 0..h {
        let py = y + r / step;
        let cy = py / s;
        // Set bits are rare (shadow edges: 0.1–0.4 % of the pixels), so 64 of them are tested
        // at once (an OR the compiler vectorises) before single pixels are: the 12 tiles of a
        // 1280×720 server frame took 1.7–2.4 instead of 3.4 ms (same bytes).
        let set = bits[r * w..(r + 1) * w]
            .chunks(64)
            .enumerate()
            .filter(|(_, span)| span.iter().fold(0, |a, &b| a | b) != 0)
            .flat_map(|(k, span)| {
                let at = k * 64;
                span.iter()
                    .enumerate()
                    .filter(|(_, &b)| b != 0)
                    .map(move |(j, _)| at + j)
            });
        for c in set {
            let px = x + c / step;
            let cx = px / s;
            let luma = f32::from(planes.y[py * planes.stride[0] + px]);
            let cb = f32::from(planes.cb[cy * planes.stride[1] + cx]) - 128.0;
            let cr = f32::from(planes.cr[cy * planes.stride[1] + cx]) - 128.0;
            let rgb = [
                luma + 1.5748 * cr,
                luma - 0.187324 * cb - 0.468124 * cr,
                luma + 1.8556 * cb,
            ];
            let o = (r * w + c) * 3;
            for (dst, v) in out[o..o + 3].iter_mut().zip(rgb) {
                // In [0, 255] after the clamp, so the cast is exact.
                *dst = v.round_ties_even().clamp(0.0, 255.0) as u8;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn motion_code_of_zero_is_exactly_zero_and_masks_win() {
        // 3×3 client pixels from 2×2 half-resolution codes; code 7 is the code of 0.
        let plane: Vec<u16> = vec![7, 8, 9, 9, 7, 0, 5, 5];
        let t = CodeTile {
            plane: &plane,
            stride: 4,
            x: 0,
            y: 0,
        };
        let (scale, offset) = (0.5f32, -3.5f32);
        let mut out = vec![1.0f32; 27];
        let mut st = vec![false; 9];
        let mut inv = vec![false; 9];
        st[8] = true;
        inv[2] = true;
        st[2] = true;
        motion_from_half_codes(
            [t, t, t],
            3,
            3,
            [scale; 3],
            [offset; 3],
            Some(&st),
            Some(&inv),
            &mut out,
        );
        assert_eq!(
            out[0].to_bits(),
            0.0f32.to_bits(),
            "code of 0 decodes to +0.0"
        );
        assert_eq!(out[3], 0.0, "pixel (0, 1) shares the code of (0, 0)");
        assert!(
            out[6..9].iter().all(|v| v.is_nan()),
            "invalid wins over static"
        );
        assert_eq!(out[24..27], [0.0; 3], "static pixel is zeroed");
        // Pixel (1, 2): half (0, 1), code 8.
        assert_eq!(out[(3 + 2) * 3], 8.0 * 0.5 - 3.5);
        // Pixel (2, 0): half (1, 0), code 7 → 0.
        assert_eq!(out[(6) * 3], 0.0);
    }

    /// The decoder multiplies then adds, never fused: with the encoder's `offset = −(code₀ ·
    /// scale)` rounded to `f32`, the code of 0 gives `+0.0` exactly, which a fused multiply-add
    /// (the exact product minus its rounding) would not for a scale such as 0.1.
    #[test]
    fn the_code_of_zero_decodes_to_zero_unfused() {
        let (code0, scale) = (7u16, 0.1f32);
        let offset = -(f32::from(code0) * scale);
        assert_ne!(
            f32::from(code0).mul_add(scale, offset),
            0.0,
            "the case needs rounding"
        );
        let plane = [code0, 9, 9, 9];
        let t = CodeTile {
            plane: &plane,
            stride: 2,
            x: 0,
            y: 0,
        };
        let mut depth = [1.0f32; 4];
        depth_from_codes(t, 2, 2, scale, offset, None, &mut depth);
        assert_eq!(depth[0].to_bits(), 0.0f32.to_bits());
        let mut motion = [1.0f32; 3];
        motion_from_half_codes(
            [t; 3],
            1,
            1,
            [scale; 3],
            [offset; 3],
            None,
            None,
            &mut motion,
        );
        assert_eq!(motion.map(f32::to_bits), [0.0f32.to_bits(); 3]);
    }

    /// Each motion channel decodes its own tile (at its own place in its plane) with its own
    /// scale and offset.
    #[test]
    fn motion_channels_use_their_own_tile_scale_and_offset() {
        // Three planes of stride 4; the 1×1 tile of channel c is at (c, 1) and holds 10 + c.
        let planes: Vec<Vec<u16>> = (0..3u16)
            .map(|c| {
                let mut p = vec![0u16; 8];
                p[4 + usize::from(c)] = 10 + c;
                p
            })
            .collect();
        let tiles = [0, 1, 2].map(|c| CodeTile {
            plane: &planes[c],
            stride: 4,
            x: c,
            y: 1,
        });
        let mut out = [0.0f32; 6];
        let (scale, offset) = ([1.0, 2.0, 4.0], [-1.0, -2.0, -3.0]);
        motion_from_half_codes(tiles, 2, 1, scale, offset, None, None, &mut out);
        // 10·1 − 1, 11·2 − 2, 12·4 − 3, for both pixels of the 2×1 camera.
        assert_eq!(out, [9.0, 20.0, 45.0, 9.0, 20.0, 45.0]);
    }

    #[test]
    fn depth_respects_tile_offset_and_stride() {
        let plane: Vec<u16> = (0..20).collect();
        let t = CodeTile {
            plane: &plane,
            stride: 5,
            x: 1,
            y: 2,
        };
        let mut out = vec![0.0f32; 4];
        let inv = [false, false, true, false];
        depth_from_codes(t, 2, 2, 2.0, 1.0, Some(&inv), &mut out);
        assert_eq!(out[0], 11.0 * 2.0 + 1.0);
        assert_eq!(out[1], 12.0 * 2.0 + 1.0);
        assert!(out[2].is_nan());
        assert_eq!(out[3], 17.0 * 2.0 + 1.0);
    }

    #[test]
    fn tiles_outside_their_plane_do_not_fit() {
        let plane = vec![0u16; 12];
        let t = CodeTile {
            plane: &plane,
            stride: 4,
            x: 2,
            y: 1,
        };
        assert!(t.fits(2, 2));
        assert!(!t.fits(3, 2));
        assert!(!t.fits(2, 3));
        let huge = CodeTile {
            plane: &plane,
            stride: 4,
            x: usize::MAX,
            y: 0,
        };
        assert!(!huge.fits(1, 1));
    }

    fn planes<'a>(
        y: &'a [u8],
        cb: &'a [u8],
        cr: &'a [u8],
        stride: [usize; 2],
        sub: usize,
    ) -> YCbCrPlanes<'a> {
        YCbCrPlanes {
            y,
            cb,
            cr,
            stride,
            sub,
        }
    }

    #[test]
    fn shadow_colour_only_where_bits_are_set_with_shared_chroma() {
        let y = [100u8, 150, 200, 250];
        let (cb, cr) = ([128u8 + 10], [128u8 - 20]);
        let planes = planes(&y, &cb, &cr, [2, 1], 2);
        let bits = [1u32, 0, 0, 4];
        let mut out = [9u8; 12];
        shadow_colour_from_ycbcr(planes, 0, 0, 2, 2, 1, &bits, &mut out);
        assert_eq!(out[3..9], [0; 6], "pixels without bits stay 0");
        // By hand: Cb′ = 10, Cr′ = −20; R = Y − 31.496, G = Y + 7.48924, B = Y + 18.556.
        assert_eq!(out[0..3], [69, 107, 119]);
        assert_eq!(out[9..12], [219, 255, 255], "clamped to 255");
        assert!(!planes.fits(1, 1, 2, 2));
    }

    #[test]
    fn half_size_shadow_colour_covers_two_by_two_pixels() {
        // A 3×3 camera from a 2×2 tile at (1, 0) of a 3×2 luma plane; 4:4:4 chroma, neutral.
        let y = [0u8, 10, 20, 0, 30, 40];
        let c = [128u8; 6];
        let planes = planes(&y, &c, &c, [3, 3], 1);
        let bits = [1u32; 9];
        let mut out = [0u8; 27];
        shadow_colour_from_ycbcr(planes, 1, 0, 3, 3, 2, &bits, &mut out);
        let grey: Vec<u8> = out.chunks(3).map(|p| p[0]).collect();
        assert_eq!(grey, [10, 10, 20, 10, 10, 20, 30, 30, 40]);
        assert!(out.chunks(3).all(|p| p[0] == p[1] && p[1] == p[2]));
        assert!(
            !planes.fits(2, 0, 2, 2),
            "the tile of a 3×3 camera needs 2×2 samples"
        );
    }

    /// A wide tile (more than 64 pixels per row, so several spans of set bits) at an offset of
    /// a 4:2:0 picture, full and half size: every set pixel takes the luma and chroma samples
    /// that cover it, computed here sample by sample.
    #[test]
    fn shadow_colour_of_a_wide_tile_at_an_offset() {
        let (pw, ph) = (160usize, 12usize);
        let y: Vec<u8> = (0..pw * ph).map(|k| (k * 7 % 251) as u8).collect();
        let cb: Vec<u8> = (0..pw * ph / 4).map(|k| (k * 13 % 253) as u8).collect();
        let cr: Vec<u8> = (0..pw * ph / 4).map(|k| (k * 29 % 241) as u8).collect();
        let planes = planes(&y, &cb, &cr, [pw, pw / 2], 2);
        let (x0, y0, w, h) = (6, 2, 150, 5);
        let bits: Vec<u32> = (0..w * h).map(|k| u32::from(k % 37 == 3)).collect();
        for step in [1, 2] {
            let mut out = vec![7u8; w * h * 3];
            shadow_colour_from_ycbcr(planes, x0, y0, w, h, step, &bits, &mut out);
            let mut set = 0;
            for r in 0..h {
                for c in 0..w {
                    let k = r * w + c;
                    let got = &out[3 * k..3 * k + 3];
                    if bits[k] == 0 {
                        assert_eq!(got, [0; 3]);
                        continue;
                    }
                    set += usize::from(c >= 128);
                    let (ly, lx) = (y0 + r / step, x0 + c / step);
                    let luma = f32::from(y[ly * pw + lx]);
                    let ci = (ly / 2) * (pw / 2) + lx / 2;
                    let (u, v) = (f32::from(cb[ci]) - 128.0, f32::from(cr[ci]) - 128.0);
                    let want = [
                        luma + 1.5748 * v,
                        luma - 0.187324 * u - 0.468124 * v,
                        luma + 1.8556 * u,
                    ]
                    .map(|x| x.round_ties_even().clamp(0.0, 255.0) as u8);
                    assert_eq!(got, want, "step {step}, pixel ({c}, {r})");
                }
            }
            assert!(set >= 3, "set bits past two spans of 64: {set}");
        }
    }
}
