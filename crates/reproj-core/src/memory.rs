//! Upper bounds of the bytes a call allocates at its peak, for callers that check they can have
//! them before they start.
//!
//! In Rust an allocation that fails aborts the process ("memory allocation of N bytes failed"
//! and a backtrace on stderr): it cannot be caught. Sizes are legal up to [`MAX_SIDE`] a side,
//! far beyond what most machines hold (a 16384×16384 server camera needs some 30 GB), so the
//! Python binding reserves a call's bound first and raises an error when it cannot, before
//! anything is allocated. Each bound is linear in the pixels with a constant for what does not
//! grow with them (per-thread scratch); `tests/peak_memory.rs` of reproj-scene measures the
//! peaks with a counting allocator and checks every bound against them, on one thread and on
//! four, and (on one thread) that their growth with the pixels is within the bounds'.
//!
//! The reference renderer's screen tiles list the objects each tile may meet (16 bytes an object
//! a tile of 8×8 or 16×16 pixels); the lists stop at an eighth of an entry a pixel on average
//! and leave the rays to the scene's BVH beyond (a scene of hundreds of objects overlapping on
//! screen), so that they too take at most a few bytes a pixel.
//!
//! [`MAX_SIDE`]: crate::MAX_SIDE

use crate::{Camera, FrameView};

/// The part of every bound that does not grow with the pixels: per-thread scratch, tile and
/// block lists (the largest measured by the tests is under 5 MiB, on one thread or four).
pub const FIXED_BYTES: u64 = 16 << 20;

/// Bytes per server pixel (every camera of a frame, counted once) that [`crate::reproject()`] or
/// [`crate::prepare_pair`] may allocate: `ours`' pair state (Algorithm 2's correspondences,
/// auxiliary visibility) and per-source splat buffers are the largest: at 1280×720 with both
/// auxiliary cameras and a client of the same size, 128 MB with the output, 92 bytes a server
/// pixel. The tests' small sizes need more: with a client of half the sides `ours`' peak grows
/// by 100 bytes a server pixel on one thread (beside 56 a client pixel, the output's included)
/// and on four by 100 to 113 (it varies from run to run with the way the work is split), so the
/// constant has a margin over that.
pub const REPROJECT_BYTES_PER_SERVER_PIXEL: u64 = 128;

/// Bytes per client pixel the same calls may allocate (splat targets, per-pixel sources and
/// weights), beside the output and diagnostics the caller allocates: 48 bounds every method.
pub const REPROJECT_BYTES_PER_CLIENT_PIXEL: u64 = 48;

/// The pixels of `camera`, as `u64`.
pub fn pixels(camera: &Camera) -> u64 {
    // Saturating: a camera's fields are public and a bound must not overflow for any of them
    // (the kernels refuse sides above `MAX_SIDE` anyway).
    (camera.width as u64).saturating_mul(camera.height as u64)
}

/// An upper bound of the bytes [`crate::reproject()`] or [`crate::prepare_pair`] allocates for
/// `newer` (and `older`) seen from `client`, not counting the output and the diagnostics the
/// caller passes (`3 + 5` bytes a client pixel).
///
/// `128 · Σ server pixels + 48 · client pixels + 16 MiB`; the server pixels are those of the
/// newer frame's cameras, as the older frame's are the same sizes (the kernels refuse others).
pub fn reproject_bytes(newer: &FrameView<'_>, client: &Camera) -> u64 {
    let server = std::iter::once(&newer.main)
        .chain(&newer.aux)
        .fold(0u64, |sum, c| sum.saturating_add(pixels(&c.camera)));
    REPROJECT_BYTES_PER_SERVER_PIXEL
        .saturating_mul(server)
        .saturating_add(REPROJECT_BYTES_PER_CLIENT_PIXEL.saturating_mul(pixels(client)))
        .saturating_add(FIXED_BYTES)
}

/// Bytes a pixel of [`crate::CameraBuffers`] holds: colour 3, depth 4, two motions 12 each,
/// and per direction shadow bits 4 and `S_min`/`S_max` 3 each.
pub const SERVER_BUFFER_BYTES_PER_PIXEL: u64 = 3 + 4 + 2 * 12 + 2 * (4 + 3 + 3);

/// An upper bound of the bytes a renderer allocates for one camera's server buffers of `pixels`
/// pixels: the buffers twice (rendered in row blocks, then joined), 10 bytes a pixel for the
/// rest (up to 5.6 measured in the built-in scenes, reproj-scene's screen tiles' object lists
/// included, which take at most 4.25 at their cap) and the fixed part. Holds for
/// [`crate::synthetic::SyntheticScene::render_server`] and reproj-scene's `render_server`.
pub fn server_buffers_bytes(pixels: u64) -> u64 {
    (2 * SERVER_BUFFER_BYTES_PER_PIXEL + 10)
        .saturating_mul(pixels)
        .saturating_add(FIXED_BYTES)
}

/// An upper bound of the bytes [`crate::synthetic::SyntheticScene::render_ground_truth`]
/// allocates for an image of `pixels` pixels: the RGB8 image (written in place) and one byte a
/// pixel to spare, and the fixed part.
pub fn synthetic_truth_bytes(pixels: u64) -> u64 {
    4u64.saturating_mul(pixels).saturating_add(FIXED_BYTES)
}
