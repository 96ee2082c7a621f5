//! What every method takes and gives besides the frames: the client's [`Request`], the
//! per-pixel [`Diagnostics`], and the check of the output buffers they share. It sits below the
//! methods (`ours`, `backward_bidir`, `timewarp`) and below [`crate::method`], which dispatches to
//! them: they all import these from here, and none imports from another.

use rayon::prelude::*;

use crate::camera::Camera;
use crate::error::Result;
use crate::frame::check_len;
use crate::params::TILE;

/// What the client asks for: its actual camera at display time and `α`, the display time relative
/// to the pair: `α = (t − t_k)/(t_{k+1} − t_k)`. `α ∈ [0,1)` interpolates, `α ≥ 1` extrapolates
/// from the newer frame (seeds/000 §3.5).
#[derive(Debug, Clone, Copy)]
pub struct Request {
    /// The client camera `P_{t+α}`; its size is the output size.
    pub client: Camera,
    /// `α`.
    pub alpha: f32,
}

/// Largest `α` accepted: extrapolating more than two server intervals is never meaningful.
pub const MAX_ALPHA: f32 = 3.0;

/// Per-output-pixel diagnostics.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Diagnostics {
    /// Which source coloured the pixel: [`Diagnostics::NONE`] (kept the previous frame),
    /// [`Diagnostics::MAIN_OLDER`], [`Diagnostics::MAIN_NEWER`], or `AUX_BASE + 2·i (+1 for the
    /// newer frame)` for auxiliary camera `i`; [`Diagnostics::BLENDED`] is or-ed in when Algorithm 2
    /// blended the other frame's colour in.
    pub source: Vec<u8>,
    /// Reprojection error of the chosen match (NDC, aspect-scaled); NaN where none.
    pub error: Vec<f32>,
}

impl Diagnostics {
    /// No match: the previous client frame's colour was kept.
    pub const NONE: u8 = 0;
    /// The main camera of the older frame.
    pub const MAIN_OLDER: u8 = 1;
    /// The main camera of the newer frame.
    pub const MAIN_NEWER: u8 = 2;
    /// First auxiliary code: auxiliary camera `i` of the older frame is `AUX_BASE + 2i`.
    pub const AUX_BASE: u8 = 3;
    /// Flag: Algorithm 2 blended the other frame in.
    pub const BLENDED: u8 = 0x80;

    /// Diagnostics for `n` pixels, all "no match".
    pub fn new(n: usize) -> Diagnostics {
        Diagnostics {
            source: vec![Self::NONE; n],
            error: vec![f32::NAN; n],
        }
    }
}
/// Where a method writes one client frame: the image and, when asked for, its per-pixel
/// diagnostics. Every method takes the two together, so they travel as one value.
#[derive(Debug)]
pub struct Output<'a> {
    /// `H·W·3` RGB8 at the client camera's size. It holds the previous client frame on entry:
    /// pixels without a match keep it.
    pub image: &'a mut [u8],
    /// Per-pixel diagnostics (`H·W` entries each), written when given.
    pub diag: Option<&'a mut Diagnostics>,
}

impl<'a> Output<'a> {
    /// The image alone, without diagnostics.
    pub fn new(image: &'a mut [u8]) -> Output<'a> {
        Output { image, diag: None }
    }

    /// The image and its diagnostics.
    pub fn with_diagnostics(image: &'a mut [u8], diag: &'a mut Diagnostics) -> Output<'a> {
        Output {
            image,
            diag: Some(diag),
        }
    }

    /// Checks the image and the diagnostics against a `w × h` output. [`crate::reproject()`]
    /// checks them for every method; the methods' own public entry points repeat this O(1)
    /// check so that they stay panic-free when called directly.
    pub(crate) fn check(&self, w: usize, h: usize) -> Result<()> {
        let (out, diag) = (&*self.image, self.diag.as_deref());
        let n = w * h;
        check_len(
            out.len(),
            n * 3,
            || "previous client frame".into(),
            || format!("{h}x{w}x3"),
        )?;
        if let Some(d) = diag {
            for (what, len) in [("source", d.source.len()), ("error", d.error.len())] {
                check_len(
                    len,
                    n,
                    || format!("diagnostics.{what}"),
                    || format!("{h}x{w}"),
                )?;
            }
        }
        Ok(())
    }
}

/// Runs `rows(j0, image, diag)` in parallel for blocks of consecutive rows of a `w`-wide output
/// that cover it: `j0` is the block's first row, `image` its RGB8 rows, and `diag` (when
/// diagnostics are asked for) its rows of [`Diagnostics::source`] and [`Diagnostics::error`]. The
/// buffers' sizes are those [`Output::check`] accepts. The blocks are [`TILE`] rows, and shorter
/// towards the end ([`block_rows`]); `rows` must not depend on where a block starts or ends.
///
/// Each thread takes the next block from one queue, so the frame ends with the short blocks and
/// the threads finish within about one of those of each other. Halving the rows among the threads
/// (`par_chunks_mut`) left the last ranges of several blocks unsplittable, and one thread idle for
/// up to two 16-row blocks (1–2 ms at 1280×720) while the other finished them.
pub(crate) fn par_row_blocks<F>(out: Output, w: usize, rows: F)
where
    F: Fn(usize, &mut [u8], Option<(&mut [u8], &mut [f32])>) + Sync,
{
    let threads = rayon::current_num_threads();
    let h = out.image.len() / (3 * w).max(1);
    let mut image = out.image;
    let mut diag = out.diag.map(|d| (&mut d.source[..], &mut d.error[..]));
    let mut blocks = Vec::new();
    let mut j0 = 0;
    while j0 < h {
        let n = block_rows(h - j0, threads);
        let (o, rest) = std::mem::take(&mut image).split_at_mut(3 * n * w);
        image = rest;
        let d = diag.as_mut().map(|(s, e)| {
            let (s0, s1) = std::mem::take(s).split_at_mut(n * w);
            let (e0, e1) = std::mem::take(e).split_at_mut(n * w);
            (*s, *e) = (s1, e1);
            (s0, e0)
        });
        blocks.push((j0, o, d));
        j0 += n;
    }
    let queue = std::sync::Mutex::new(blocks.into_iter());
    (0..threads).into_par_iter().for_each(|_| loop {
        // The lock is held only to take the next block, not while it runs, so a panic in `rows`
        // cannot poison it (and the queue is still consistent if one ever did).
        let next = queue.lock().unwrap_or_else(|e| e.into_inner()).next();
        let Some((j0, o, d)) = next else { break };
        rows(j0, o, d);
    });
}

/// The rows of the next block of [`par_row_blocks`] when `left` rows remain: [`TILE`] while each
/// of the `threads` has at least four such blocks ahead, then halved down to 2 rows (even, so that
/// the blocks do not split the cells of a grid at half the output's resolution, which would be
/// searched by both).
fn block_rows(left: usize, threads: usize) -> usize {
    let mut n = TILE;
    while n > 2 && 4 * n * threads > left {
        n /= 2;
    }
    n.min(left)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::ReprojError;

    fn assert_sized(r: Result<()>, what: &str, expected: usize, actual: usize) {
        match r {
            Err(ReprojError::BufferSize {
                what: got,
                expected: e,
                actual: a,
                ..
            }) => assert_eq!((got.as_str(), e, a), (what, expected, actual)),
            other => panic!("{other:?}"),
        }
    }

    /// The output image must hold `w·h` RGB pixels and each diagnostics buffer `w·h` values:
    /// a wrong one is named with both counts, before any row is written.
    #[test]
    fn output_check_names_a_buffer_of_the_wrong_length() {
        let (w, h) = (4, 3);
        let mut image = vec![0u8; w * h * 3];
        Output::new(&mut image).check(w, h).unwrap();
        let mut short = vec![0u8; w * h * 3 - 1];
        let r = Output::new(&mut short).check(w, h);
        assert_sized(r, "previous client frame", 36, 35);
        for (source, error) in [(12, 12), (11, 12), (12, 13)] {
            let mut diag = Diagnostics {
                source: vec![0; source],
                error: vec![0.0; error],
            };
            let r = Output::with_diagnostics(&mut image, &mut diag).check(w, h);
            match (source, error) {
                (12, 12) => r.unwrap(),
                (12, _) => assert_sized(r, "diagnostics.error", 12, error),
                _ => assert_sized(r, "diagnostics.source", 12, source),
            }
        }
    }
}
