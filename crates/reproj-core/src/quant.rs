//! Encoding side of the stream format (docs/stream-format.md, version 4): the half-size buffers.
//!
//! Motion and the shadow colours travel at half resolution, one sample per 2×2 pixels
//! `(2y..2y+1, 2x..2x+1)`, and the decoder gives every pixel of a block its block's sample
//! ([`crate::dequant`]). The sample is the mean of the block's pixels that the decoder will
//! read (moving pixels for motion, set bitfields for shadow colours), so that the others
//! (static, invalid, unshadowed: the lossless masks decide those) do not drag it.
//!
//! This ran as numpy expressions before, and was 60 % of encoding a 1280×720 server frame
//! (a reduction over two short axes of a strided view: ~20 ms a buffer, 30 buffers a frame).

/// Per 2×2 block of a `w × h` image of `c` channels (row-major, channels innermost; an odd side
/// is padded with pixels that are not weighted), the mean over the block's weighted pixels:
///
/// `mean[y, x] = Σ_{p ∈ B(y, x), weight[p]} a[p] / max(1, #{p ∈ B(y, x) : weight[p]})`
///
/// with `B(y, x) = {2y, 2y+1} × {2x, 2x+1}`: 0 where no pixel is weighted, which `any[y, x]`
/// tells. The sum is taken in `f64` (four finite `f32` near the largest overflow an `f32`
/// sum, and their mean is finite), in the order `(0,0), (0,1), (1,0), (1,1)`, and the mean
/// rounded to `f32` once. A pixel that is not weighted is never read (a NaN there does not
/// reach the mean). The outputs are `⌈h/2⌉ × ⌈w/2⌉` (`× c` for `mean`).
///
/// # Panics
/// If `a`, `weight`, `mean` or `any` do not have those lengths; the bindings check first.
pub fn block_mean(
    a: &[f32],
    w: usize,
    h: usize,
    c: usize,
    weight: &[bool],
    mean: &mut [f32],
    any: &mut [bool],
) {
    let (hw, hh) = (w.div_ceil(2), h.div_ceil(2));
    assert!(a.len() == w * h * c && weight.len() == w * h);
    assert!(mean.len() == hw * hh * c && any.len() == hw * hh);
    let mut sums = vec![0.0f64; c];
    for by in 0..hh {
        let rows = (2 * by)..(2 * by + 2).min(h);
        for bx in 0..hw {
            let cols = (2 * bx)..(2 * bx + 2).min(w);
            sums.fill(0.0);
            let mut count = 0u32;
            for r in rows.clone() {
                for x in cols.clone() {
                    let p = r * w + x;
                    if weight[p] {
                        count += 1;
                        for (s, &v) in sums.iter_mut().zip(&a[p * c..(p + 1) * c]) {
                            *s += f64::from(v);
                        }
                    }
                }
            }
            let b = by * hw + bx;
            any[b] = count > 0;
            let n = f64::from(count.max(1));
            for (m, s) in mean[b * c..(b + 1) * c].iter_mut().zip(&sums) {
                *m = (s / n) as f32;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn run(a: &[f32], w: usize, h: usize, c: usize, weight: &[bool]) -> (Vec<f32>, Vec<bool>) {
        let n = w.div_ceil(2) * h.div_ceil(2);
        let (mut mean, mut any) = (vec![f32::NAN; n * c], vec![true; n]);
        block_mean(a, w, h, c, weight, &mut mean, &mut any);
        (mean, any)
    }

    #[test]
    fn mean_of_the_weighted_pixels_of_each_block_with_odd_sides_padded() {
        // 3×3, one channel: blocks {0,1,3,4}, {2,5}, {6,7}, {8}.
        let a = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, f32::NAN];
        let weight = [true, true, false, false, true, false, true, false, false];
        let (mean, any) = run(&a, 3, 3, 1, &weight);
        assert_eq!(mean, [(1.0 + 2.0 + 5.0) / 3.0, 0.0, 7.0, 0.0]);
        assert_eq!(any, [true, false, true, false]);
    }

    #[test]
    fn sums_in_f64_so_a_mean_of_huge_values_stays_finite() {
        let big = f32::MAX;
        let (mean, _) = run(&[big; 4], 2, 2, 1, &[true; 4]);
        assert_eq!(mean, [big]);
        // In f32 the first two already overflow.
        assert!((big + big).is_infinite());
    }

    proptest! {
        /// Against the definition with the block's pixels gathered first (and each channel
        /// apart): the same bytes, NaN where a weighted pixel is NaN.
        #[test]
        fn equals_the_definition(
            w in 1usize..9, h in 1usize..9, c in 1usize..4,
            seed in any::<u64>(),
        ) {
            let mut s = seed | 1;
            let mut next = || { s ^= s << 13; s ^= s >> 7; s ^= s << 17; s };
            // NaN and -0.0 among values of either sign.
            let a: Vec<f32> = (0..w * h * c)
                .map(|_| match next() % 9 {
                    0 => f32::NAN,
                    1 => -0.0,
                    k => (next() % 2001) as f32 * 0.37 - 370.0 * k as f32,
                })
                .collect();
            let weight: Vec<bool> = (0..w * h).map(|_| next() % 3 != 0).collect();
            let (mean, any) = run(&a, w, h, c, &weight);
            let hw = w.div_ceil(2);
            for by in 0..h.div_ceil(2) {
                for bx in 0..hw {
                    let on: Vec<usize> = [(0, 0), (0, 1), (1, 0), (1, 1)]
                        .iter()
                        .map(|(dy, dx)| (2 * by + dy, 2 * bx + dx))
                        .filter(|&(y, x)| y < h && x < w && weight[y * w + x])
                        .map(|(y, x)| y * w + x)
                        .collect();
                    prop_assert_eq!(any[by * hw + bx], !on.is_empty());
                    for ch in 0..c {
                        // From +0.0, as the kernel (and numpy's zeros) start: Rust's
                        // `sum` starts at -0.0, which a block of only -0.0 would keep.
                        let sum = on.iter().fold(0.0f64, |s, &p| s + f64::from(a[p * c + ch]));
                        let want = (sum / on.len().max(1) as f64) as f32;
                        let got = mean[(by * hw + bx) * c + ch];
                        prop_assert!(
                            got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                            "block ({}, {}) channel {}: {} != {}", by, bx, ch, got, want
                        );
                    }
                }
            }
        }
    }
}
