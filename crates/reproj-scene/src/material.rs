//! Procedural materials: textured Lambert with an optional Blinn–Phong highlight.
//!
//! Every pattern carries detail at several scales down to a few centimetres (fine stripes, mortar
//! lines, hashed per-cell noise), so resampling errors of the client show in the metrics.

use std::cell::Cell;

use crate::math::{floor, floor_i64, hash, lerp, scale, V3};

/// The procedural pattern of a material, evaluated on the shape's UV (scaled by
/// [`Material::uv_scale`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pattern {
    /// Two colours on a checker of unit cells, fine diagonal stripes (period 1/8) and hashed noise
    /// per 1/4 cell (as `reproj_core::synthetic`).
    Checker,
    /// Running-bond bricks of 1 × 0.5 with mortar lines of 0.05 in colour `b` and a hashed tint per
    /// brick plus fine grain.
    Bricks,
    /// Square tiles of unit size with thin grout lines (`b`), a hashed tint per tile and a fine
    /// speckle.
    Tiles,
    /// Smooth value noise over three octaves blending `a` and `b`, with hashed speckle (grass,
    /// gravel, marble).
    Noise,
}

/// A material: pattern, its two colours (linear, `[0,1]`), UV scale, noise salt and the specular
/// term.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Which pattern.
    pub pattern: Pattern,
    /// Primary colour.
    pub a: V3,
    /// Secondary colour (checker's second colour, mortar, grout, noise blend target).
    pub b: V3,
    /// UV multiplier (pattern cells per UV unit).
    pub uv_scale: f64,
    /// Salt of the hashed noise, so that surfaces of the same pattern differ.
    pub salt: u64,
    /// Blinn–Phong specular strength (0 = pure Lambert).
    pub specular: f64,
    /// Blinn–Phong exponent.
    pub shininess: f64,
}

impl Material {
    /// A matte material.
    pub const fn matte(pattern: Pattern, a: V3, b: V3, uv_scale: f64, salt: u64) -> Material {
        Material {
            pattern,
            a,
            b,
            uv_scale,
            salt,
            specular: 0.0,
            shininess: 1.0,
        }
    }

    /// The same material with a specular highlight.
    pub const fn shiny(self, specular: f64, shininess: f64) -> Material {
        Material {
            specular,
            shininess,
            ..self
        }
    }

    /// Albedo at texture coordinates `uv`.
    pub fn albedo(&self, uv: [f64; 2]) -> V3 {
        let (u, v) = (uv[0] * self.uv_scale, uv[1] * self.uv_scale);
        let cell = |x: f64, y: f64, s: f64, salt: u64| {
            hash(floor_i64(x), floor_i64(y), s.to_bits() ^ salt)
        };
        // The same hash where the floors are at hand: `floor(x) as i64` is `floor_i64(x)` for
        // every `x` (see there).
        let cell_at =
            |fx: f64, fy: f64, s: f64, salt: u64| hash(fx as i64, fy as i64, s.to_bits() ^ salt);
        match self.pattern {
            Pattern::Checker => {
                let even = (floor_i64(u) + floor_i64(v)).rem_euclid(2) == 0;
                let base = if even { self.a } else { self.b };
                let st = if floor_i64((u + v) * 8.0) & 1 == 0 {
                    1.0
                } else {
                    0.82
                };
                let n = cell(u * 4.0, v * 4.0, 0.0, self.salt);
                scale(base, st * (0.8 + 0.2 * n))
            }
            Pattern::Bricks => {
                let row = floor(v * 2.0);
                let shift = if (row as i64).rem_euclid(2) == 1 {
                    0.5
                } else {
                    0.0
                };
                let x = u + shift;
                let xi = floor(x);
                let (fx, fy) = (x - xi, v * 2.0 - row);
                if fx < 0.05 || fy < 0.1 {
                    let g = cell(u * 40.0, v * 40.0, 1.0, self.salt);
                    return scale(self.b, 0.85 + 0.15 * g);
                }
                let tint = cell_at(xi, row, 2.0, self.salt);
                let grain = cell(u * 24.0, v * 24.0, 3.0, self.salt);
                scale(self.a, (0.75 + 0.25 * tint) * (0.88 + 0.12 * grain))
            }
            Pattern::Tiles => {
                let (ui, vi) = (floor(u), floor(v));
                let (fx, fy) = (u - ui, v - vi);
                if fx < 0.04 || fy < 0.04 {
                    return self.b;
                }
                let tint = cell_at(ui, vi, 4.0, self.salt);
                let speck = cell(u * 32.0, v * 32.0, 5.0, self.salt);
                let base = lerp(self.a, scale(self.a, 0.7), tint);
                scale(base, 0.9 + 0.1 * speck)
            }
            Pattern::Noise => {
                let mut n = 0.0;
                let mut amp = 0.5;
                let mut f = 1.0;
                for octave in 0..3 {
                    n += amp * value_noise(u * f, v * f, self.salt + octave, octave as usize);
                    amp *= 0.5;
                    f *= 2.0;
                }
                let speck = cell(u * 64.0, v * 64.0, 6.0, self.salt);
                scale(lerp(self.a, self.b, n / 0.875), 0.85 + 0.15 * speck)
            }
        }
    }
}

/// The hashes of one lattice cell's four corners: whether it holds a cell yet, the cell `(i, j)`,
/// the salt, and `[h00, h10, h01, h11]`.
type Corners = (bool, i64, i64, u64, [f64; 4]);

thread_local! {
    /// Per octave of [`Pattern::Noise`], the corners of the cell last looked up on this thread.
    /// A cell spans many pixels at every octave, so neighbouring sub-samples and pixels on the
    /// same surface mostly fall in the cell before and reuse its four hashes (the same values:
    /// a hash depends on the cell and salt alone) instead of computing them again.
    static LAST_CELL: [Cell<Corners>; 3] =
        const { [const { Cell::new((false, 0, 0, 0, [0.0; 4])) }; 3] };
}

/// The corner hashes of cell `(i, j)` under `salt`, through octave `slot`'s [`LAST_CELL`].
fn corners(i: i64, j: i64, salt: u64, slot: usize) -> [f64; 4] {
    // The cache read and written in two small accesses, the hashing between them: with the
    // hashing inside one access, the compiler may leave that access a call of its own.
    let (full, li, lj, ls, h) = LAST_CELL.with(|last| last[slot].get());
    if full && li == i && lj == j && ls == salt {
        return h;
    }
    let h = [
        hash(i, j, salt),
        hash(i + 1, j, salt),
        hash(i, j + 1, salt),
        hash(i + 1, j + 1, salt),
    ];
    LAST_CELL.with(|last| last[slot].set((true, i, j, salt, h)));
    h
}

/// Bilinearly interpolated hashed lattice noise with a smoothstep fade, in `[0, 1)`; `slot`
/// (the octave) names the cell cache [`LAST_CELL`] to use.
fn value_noise(x: f64, y: f64, salt: u64, slot: usize) -> f64 {
    let (xi, yi) = (floor(x), floor(y));
    let (fx, fy) = (x - xi, y - yi);
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let (i, j) = (xi as i64, yi as i64);
    let [h00, h10, h01, h11] = corners(i, j, salt, slot);
    let top = h00 + (h10 - h00) * sx;
    let bot = h01 + (h11 - h01) * sx;
    top + (bot - top) * sy
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn albedo_is_in_range_and_varies() {
        for pattern in [
            Pattern::Checker,
            Pattern::Bricks,
            Pattern::Tiles,
            Pattern::Noise,
        ] {
            let m = Material::matte(pattern, [0.9, 0.6, 0.4], [0.2, 0.3, 0.4], 2.0, 7);
            let mut seen = std::collections::BTreeSet::new();
            for k in 0..200 {
                let uv = [k as f64 * 0.0371, k as f64 * 0.0213];
                let c = m.albedo(uv);
                assert!(
                    c.iter().all(|&x| (0.0..=1.0).contains(&x)),
                    "{pattern:?} {c:?}"
                );
                seen.insert((c[0] * 1000.0) as i64);
            }
            assert!(seen.len() > 10, "{pattern:?} is too flat");
        }
    }

    /// The per-thread cache of lattice corners gives the hashes of the cell asked for: value
    /// noise over cells, salts and octave slots interleaved (each lookup after another cell,
    /// salt or slot) equals the smoothstep blend of the four corner hashes computed directly.
    #[test]
    fn noise_cache_gives_the_hashes_of_the_cell_asked_for() {
        let direct = |x: f64, y: f64, salt: u64| {
            let (i, j) = (x.floor() as i64, y.floor() as i64);
            let (fx, fy) = (x - x.floor(), y - y.floor());
            let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
            let h = |a: i64, b: i64| hash(a, b, salt);
            let top = h(i, j) + (h(i + 1, j) - h(i, j)) * sx;
            let bot = h(i, j + 1) + (h(i + 1, j + 1) - h(i, j + 1)) * sx;
            top + (bot - top) * sy
        };
        for k in 0..300 {
            let (x, y) = (f64::from(k) * 0.37 - 20.0, f64::from(k % 7) * 0.61 - 2.0);
            for (salt, slot) in [(7, 0), (8, 0), (7, 1), (7, 2), (8, 2), (7, 0)] {
                assert_eq!(
                    value_noise(x, y, salt, slot),
                    direct(x, y, salt),
                    "({x}, {y}) salt {salt} slot {slot}"
                );
            }
        }
    }
}
