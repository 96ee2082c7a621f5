//! The ground-truth pass: colour at a client camera ([`render_ground_truth`], the same shading
//! and filter as the server colour) and the continuous shadow fraction
//! ([`render_shadow_fraction`]), mapped per pixel over blocks of rows.

use rayon::prelude::*;
use reproj_core::Camera;

use super::{
    camera_rays, check_samples, check_time, footprint, pixel_color, sample, sample_ray, EyeTiles,
    Needs, Rays, SubRays,
};
use crate::error::Result;
use crate::scene::Scene;

/// Rows per rayon task of a ground-truth frame. A pixel costs some 5 primary rays and one shadow
/// evaluation, and the rows through the houses cost about three times the rows of sky or ground:
/// with the server's blocks of 16 rows (45 at 1280×720) the last, heaviest block left one of two
/// threads idle for up to 30 ms of a 400 ms frame. Two rows, each block a task of its own, leave
/// at most a few milliseconds.
const TRUTH_ROWS: usize = 2;

/// Per-pixel map over row blocks in parallel, concatenated in order (thread-count independent);
/// `f` gets a scratch value of its own per block (reused from pixel to pixel, not reallocated).
fn per_pixel<T: Copy + Default + Send, S: Default, const C: usize>(
    rays: &Rays,
    f: impl Fn(&mut S, usize, usize) -> [T; C] + Sync,
) -> Vec<T> {
    let (w, h) = (rays.width, rays.height);
    let mut out = vec![T::default(); C * w * h];
    // `with_max_len(1)`: rayon otherwise takes runs of blocks as one unsplittable job each, and a
    // thread left without work waits for the other's whole run.
    out.par_chunks_mut(C * w * TRUTH_ROWS)
        .with_max_len(1)
        .enumerate()
        .for_each(|(b, chunk)| {
            let mut scratch = S::default();
            for (k, px) in chunk.chunks_exact_mut(C).enumerate() {
                px.copy_from_slice(&f(&mut scratch, k % w, b * TRUTH_ROWS + k / w));
            }
        });
    out
}

/// Ground-truth colour (`H·W·3` RGB8) at the client `camera` and time `t`, from `samples ×
/// samples` sub-samples per pixel: the same shading and filter as the server colour, so at a
/// server camera and time (and the same `samples`) it equals that colour byte for byte.
///
/// # Errors
/// [`SceneError::BadSamples`] when `samples ∉ 1..=MAX_SAMPLES`; [`SceneError::BadCamera`] when
/// the camera's size is out of range or its matrices cannot be inverted;
/// [`SceneError::BadTime`] when `t` is not finite or an object of the scene is not at a finite
/// position then; the errors of [`Scene::check`].
///
/// [`SceneError::BadSamples`]: crate::SceneError::BadSamples
/// [`SceneError::BadCamera`]: crate::SceneError::BadCamera
/// [`SceneError::BadTime`]: crate::SceneError::BadTime
pub fn render_ground_truth(
    scene: &Scene,
    camera: &Camera,
    t: f64,
    samples: usize,
) -> Result<Vec<u8>> {
    let n = check_samples(samples)?;
    let rays = camera_rays(camera, "client")?;
    scene.check()?;
    check_time(scene, "t", t)?;
    let snap = scene.at(t);
    let eye = EyeTiles::new(&snap, camera, &rays);
    let (centres, grid) = (SubRays::new(&rays, 1), SubRays::new(&rays, n));
    Ok(per_pixel(&rays, |fp: &mut Vec<_>, i, j| {
        let tile = eye.as_ref().map(|e| e.tile((i, j)));
        let centre = sample_ray(
            &snap,
            &rays,
            centres.ray((i, j), 0, 0),
            Needs::centre(true, n),
            tile.as_ref(),
        );
        footprint(&snap, &grid, tile.as_ref(), (i, j), &centre, fp);
        pixel_color(fp)
    }))
}

/// The continuous main-light shadow fraction (`H·W`, 0 lit … 1 shadowed, 0 for the sky) seen by
/// `camera` at time `t`: the quantity the shadow bitfields quantise, for evaluation and tests.
///
/// # Errors
/// As [`render_ground_truth`].
pub fn render_shadow_fraction(scene: &Scene, camera: &Camera, t: f64) -> Result<Vec<f32>> {
    let rays = camera_rays(camera, "shadow")?;
    scene.check()?;
    check_time(scene, "t", t)?;
    let snap = scene.at(t);
    Ok(per_pixel(&rays, |_: &mut (), i, j| {
        [sample(&snap, &rays, i, j, true).shadow as f32]
    }))
}
