//! SSIM, the structural similarity of the evaluation (seeds/000 §4.2, REFERENCE.md §6).
//!
//! Per pixel and channel (Wang et al. 2004):
//!
//! ```text
//! SSIM = (2·μx·μy + C1)(2·σxy + C2) / ((μx² + μy² + C1)(σx² + σy² + C2))
//! μx = G∗x,  σx² = G∗x² − μx²,  σxy = G∗(x·y) − μx·μy
//! ```
//!
//! with `G` the normalised 11×11 Gaussian (σ = 1.5) applied as two 11-tap passes (rows, then
//! columns), zero padding at the borders (the reference's `conv2d`, so the borders count with
//! their partial windows), `C1 = 0.01²`, `C2 = 0.03²`, values in `[0, 1]`. The image's SSIM is the
//! mean of the map over pixels and channels.
//!
//! This ran as numpy/scipy expressions before (ten full-image passes and a dozen float64
//! temporaries: 0.5–1.4 s per 1280×720 frame, a third of the scoring time of an evaluation at
//! that size). Here each output row is one task: the vertical pass of its 11 input rows for the
//! five moments, then the horizontal pass and the map, in `f64`. The mean is summed per row and
//! the rows in order, so the result does not depend on the number of threads.

use rayon::prelude::*;

use crate::error::{ReprojError, Result};
use crate::frame::check_len;

/// Half-width of the Gaussian window (11 taps).
pub const RADIUS: usize = 5;
/// Standard deviation of the Gaussian window, in pixels.
pub const SIGMA: f64 = 1.5;
/// Stabiliser of the luminance term, `(0.01 · L)²` with `L = 1`.
pub const C1: f64 = 0.01 * 0.01;
/// Stabiliser of the contrast–structure term, `(0.03 · L)²`.
pub const C2: f64 = 0.03 * 0.03;

const TAPS: usize = 2 * RADIUS + 1;
/// The five local moments: x, y, x², y², x·y.
const MOMENTS: usize = 5;

/// The normalised Gaussian taps `g[k] ∝ exp(−(k − R)² / 2σ²)`.
pub fn taps() -> [f64; TAPS] {
    let mut g = [0.0; TAPS];
    for (k, v) in g.iter_mut().enumerate() {
        let d = k as f64 - RADIUS as f64;
        *v = (-(d * d) / (2.0 * SIGMA * SIGMA)).exp();
    }
    let sum: f64 = g.iter().sum();
    g.iter_mut().for_each(|v| *v /= sum);
    g
}

/// SSIM of `x` against `y`, both `height × width × channels` (row-major, channels interleaved)
/// in `[0, 1]`. Writes the per-pixel, per-channel map into `map` when given (the same layout) and
/// returns its mean.
pub fn ssim(
    x: &[f64],
    y: &[f64],
    height: usize,
    width: usize,
    channels: usize,
    map: Option<&mut [f64]>,
) -> Result<f64> {
    let n = height
        .checked_mul(width)
        .and_then(|p| p.checked_mul(channels))
        .filter(|&n| n > 0)
        .ok_or_else(|| {
            ReprojError::CameraMismatch(format!(
                "ssim: expected a non-empty image, got {height}x{width}x{channels}"
            ))
        })?;
    for (what, len) in [("x", x.len()), ("y", y.len())]
        .into_iter()
        .chain(map.as_ref().map(|m| ("map", m.len())))
    {
        check_len(
            len,
            n,
            || format!("ssim {what}"),
            || format!("{height}x{width}x{channels}"),
        )?;
    }
    let g = taps();
    let row_len = width * channels;
    let mut sums = vec![0.0f64; height];
    let rows = Rows {
        x,
        y,
        height,
        channels,
        row_len,
        g: &g,
    };
    // Scratch per rayon task, reused from row to row: a fresh buffer per row would be a fresh
    // mmap (above malloc's threshold) and its page faults.
    let scratch = || Scratch {
        v: vec![0.0; MOMENTS * (row_len + 2 * RADIUS * channels)],
        h: vec![0.0; MOMENTS * row_len],
    };
    match map {
        Some(map) => map
            .par_chunks_mut(row_len)
            .zip(sums.par_iter_mut())
            .enumerate()
            .for_each_init(scratch, |s, (r, (out, sum))| *sum = rows.row(r, out, s)),
        None => sums.par_iter_mut().enumerate().for_each_init(
            || (vec![0.0f64; row_len], scratch()),
            |(out, s), (r, sum)| *sum = rows.row(r, out, s),
        ),
    }
    Ok(sums.iter().sum::<f64>() / n as f64)
}

struct Rows<'a> {
    x: &'a [f64],
    y: &'a [f64],
    height: usize,
    channels: usize,
    row_len: usize,
    g: &'a [f64; TAPS],
}

/// One task's buffers: the five moments after the vertical pass (`v`, padded), then after the
/// horizontal pass (`h`).
struct Scratch {
    v: Vec<f64>,
    h: Vec<f64>,
}

impl Rows<'_> {
    /// Output row `r` of the map into `out`; returns its sum. Every loop runs over a whole row
    /// of contiguous samples, so that it vectorises.
    fn row(&self, r: usize, out: &mut [f64], s: &mut Scratch) -> f64 {
        let (c, len) = (self.channels, self.row_len);
        // The vertical pass of the five moments, each padded with RADIUS pixels of zeros on
        // both sides so that the horizontal pass needs no bounds tests.
        let pad = RADIUS * c;
        let stride = len + 2 * pad;
        s.v.fill(0.0);
        let (first, last) = (r.saturating_sub(RADIUS), (r + RADIUS).min(self.height - 1));
        for rr in first..=last {
            let w = self.g[rr + RADIUS - r];
            let xs = &self.x[rr * len..(rr + 1) * len];
            let ys = &self.y[rr * len..(rr + 1) * len];
            let mut moments = s.v.chunks_exact_mut(stride).map(|m| &mut m[pad..pad + len]);
            let mut next = || moments.next().expect("five moments");
            for (d, a) in next().iter_mut().zip(xs) {
                *d += w * a;
            }
            for (d, b) in next().iter_mut().zip(ys) {
                *d += w * b;
            }
            for (d, a) in next().iter_mut().zip(xs) {
                *d += w * (a * a);
            }
            for (d, b) in next().iter_mut().zip(ys) {
                *d += w * (b * b);
            }
            for ((d, a), b) in next().iter_mut().zip(xs).zip(ys) {
                *d += w * (a * b);
            }
        }
        // The horizontal pass: sample i of the row takes the padded samples i + k·c.
        s.h.fill(0.0);
        for (hm, vm) in s.h.chunks_exact_mut(len).zip(s.v.chunks_exact(stride)) {
            for (k, w) in self.g.iter().enumerate() {
                for (d, v) in hm.iter_mut().zip(&vm[k * c..k * c + len]) {
                    *d += w * v;
                }
            }
        }
        let (mx, rest) = s.h.split_at(len);
        let (my, rest) = rest.split_at(len);
        let (ex2, rest) = rest.split_at(len);
        let (ey2, exy) = rest.split_at(len);
        for (i, o) in out.iter_mut().enumerate() {
            let (mx, my) = (mx[i], my[i]);
            let var_x = ex2[i] - mx * mx;
            let var_y = ey2[i] - my * my;
            let cov = exy[i] - mx * my;
            let num = (2.0 * mx * my + C1) * (2.0 * cov + C2);
            let den = (mx * mx + my * my + C1) * (var_x + var_y + C2);
            *o = num / den;
        }
        out.iter().sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `C1 = (0.01·L)²`, `C2 = (0.03·L)²` with `L = 1`, written out here rather than taken from
    /// the code under test.
    const K1: f64 = 1e-4;
    const K2: f64 = 9e-4;

    /// The 11 taps of the normalised Gaussian of σ = 1.5, written out here (not [`taps`]).
    fn gauss() -> Vec<f64> {
        let g: Vec<f64> = (-5..=5)
            .map(|d: i32| (-f64::from(d * d) / 4.5).exp())
            .collect();
        let sum: f64 = g.iter().sum();
        g.iter().map(|v| v / sum).collect()
    }

    #[test]
    fn the_window_is_the_normalised_gaussian_of_sigma_1_5() {
        let (g, want) = (taps(), gauss());
        for (a, b) in g.iter().zip(&want) {
            assert!((a - b).abs() < 1e-15, "{g:?}");
        }
        // The centre and first side taps of the usual 11-tap σ = 1.5 window.
        assert!((g[5] - 0.266_011_72).abs() < 1e-8 && (g[4] - 0.213_005_54).abs() < 1e-8);
    }

    /// On constant images the contrast–structure term is 1 and, where the whole window lies
    /// inside the image, the means are the values: SSIM = (2ab + C1) / (a² + b² + C1).
    #[test]
    fn constant_images_score_the_luminance_term_inside() {
        let (h, w, a, b) = (13, 12, 0.2, 0.3);
        let (x, y) = (vec![a; h * w], vec![b; h * w]);
        let mut map = vec![0.0; h * w];
        ssim(&x, &y, h, w, 1, Some(&mut map)).unwrap();
        let want = (2.0 * a * b + K1) / (a * a + b * b + K1);
        for r in RADIUS..h - RADIUS {
            for col in RADIUS..w - RADIUS {
                let got = map[r * w + col];
                assert!((got - want).abs() < 1e-12, "({r},{col}): {got} vs {want}");
            }
        }
        // At a corner the zero padding darkens both means (and adds structure): not the same.
        assert!((map[0] - want).abs() > 1e-3);
    }

    /// The definition with a full 11×11 window and explicit zero padding, pixel by pixel, with
    /// its own window and constants.
    fn direct(x: &[f64], y: &[f64], h: usize, w: usize, c: usize) -> Vec<f64> {
        let g = gauss();
        let at = |img: &[f64], r: isize, col: isize, ch: usize| -> f64 {
            if r < 0 || col < 0 || r >= h as isize || col >= w as isize {
                0.0
            } else {
                img[(r as usize * w + col as usize) * c + ch]
            }
        };
        let mut out = vec![0.0; h * w * c];
        for r in 0..h {
            for col in 0..w {
                for ch in 0..c {
                    let mut m = [0.0f64; 5];
                    for (i, gi) in g.iter().enumerate() {
                        for (j, gj) in g.iter().enumerate() {
                            let rr = r as isize + i as isize - RADIUS as isize;
                            let cc = col as isize + j as isize - RADIUS as isize;
                            let (a, b) = (at(x, rr, cc, ch), at(y, rr, cc, ch));
                            let wgt = gi * gj;
                            m[0] += wgt * a;
                            m[1] += wgt * b;
                            m[2] += wgt * a * a;
                            m[3] += wgt * b * b;
                            m[4] += wgt * a * b;
                        }
                    }
                    let (vx, vy, cov) =
                        (m[2] - m[0] * m[0], m[3] - m[1] * m[1], m[4] - m[0] * m[1]);
                    out[(r * w + col) * c + ch] = ((2.0 * m[0] * m[1] + K1) * (2.0 * cov + K2))
                        / ((m[0] * m[0] + m[1] * m[1] + K1) * (vx + vy + K2));
                }
            }
        }
        out
    }

    fn image(h: usize, w: usize, c: usize, seed: u64) -> Vec<f64> {
        // A smooth pattern plus a deterministic hash, so that every window has structure.
        (0..h * w * c)
            .map(|i| {
                let k = (i as u64 ^ seed).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40;
                0.5 + 0.3 * ((i / c) as f64 * 0.05).sin() + 0.2 * (k as f64 / (1u64 << 24) as f64)
                    - 0.1
            })
            .collect()
    }

    #[test]
    fn the_map_is_the_definition_with_a_full_window_and_zero_padding() {
        // Sides smaller and larger than the window, one and three channels.
        for &(h, w, c) in &[(1, 1, 1), (3, 17, 3), (14, 9, 3), (23, 31, 1)] {
            let (x, y) = (image(h, w, c, 1), image(h, w, c, 2));
            let mut map = vec![0.0; h * w * c];
            let mean = ssim(&x, &y, h, w, c, Some(&mut map)).unwrap();
            let want = direct(&x, &y, h, w, c);
            for (i, (a, b)) in map.iter().zip(&want).enumerate() {
                assert!((a - b).abs() < 1e-12, "{h}x{w}x{c} sample {i}: {a} vs {b}");
            }
            let want_mean = want.iter().sum::<f64>() / want.len() as f64;
            assert!((mean - want_mean).abs() < 1e-12);
            assert_eq!(ssim(&x, &y, h, w, c, None).unwrap(), mean);
        }
    }

    #[test]
    fn identical_images_score_one_and_the_score_is_symmetric() {
        let (x, y) = (image(20, 30, 3, 7), image(20, 30, 3, 8));
        assert!((ssim(&x, &x, 20, 30, 3, None).unwrap() - 1.0).abs() < 1e-12);
        let (a, b) = (
            ssim(&x, &y, 20, 30, 3, None).unwrap(),
            ssim(&y, &x, 20, 30, 3, None).unwrap(),
        );
        assert!(a < 0.99 && (a - b).abs() < 1e-12, "{a} {b}");
    }

    #[test]
    fn the_mean_does_not_depend_on_the_thread_count() {
        let (x, y) = (image(64, 48, 3, 3), image(64, 48, 3, 4));
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| ssim(&x, &y, 64, 48, 3, None).unwrap());
        let three = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap()
            .install(|| ssim(&x, &y, 64, 48, 3, None).unwrap());
        assert_eq!(one.to_bits(), three.to_bits());
    }

    #[test]
    fn wrong_sizes_are_errors() {
        let x = vec![0.5; 12];
        assert!(ssim(&x, &x, 2, 2, 3, None).is_ok());
        assert!(matches!(
            ssim(&x, &x[..11], 2, 2, 3, None),
            Err(ReprojError::BufferSize { .. })
        ));
        assert!(ssim(&x, &x, 0, 2, 3, None).is_err());
        let mut map = vec![0.0; 11];
        assert!(ssim(&x, &x, 2, 2, 3, Some(&mut map)).is_err());
    }
}
