//! Rendering: every server buffer of one camera at one time, and ground-truth client frames.
//!
//! Geometry is sampled by one ray through each pixel centre, everything in `f64`, following
//! `reproj_core::synthetic`'s rules so every buffer agrees with every other:
//! - colour (server colour, `S_min`/`S_max`, ground truth): the box-filtered mean of an `n×n`
//!   ordered grid of sub-samples per pixel ([`default_samples`]), see "Colour supersampling";
//! - depth: reversed `Z` of the hit point `X_t` in this camera; `Z = 0` (far plane) for the sky;
//! - motion: the material point (object, object-space point) moved to `t ± Δ` by its object's
//!   transform and projected with this camera held fixed; exactly 0.0 on objects that do not move;
//! - shadow: the main light's shadow fraction of the material point at `t ± jΔ/S`, with the light
//!   and the occluders at that time, quantised to `round(3·f)`; `S_min`/`S_max` re-shade the key
//!   sample (albedo, normal, view and light direction of the key frame) at the extreme levels.
//!
//! ## Colour supersampling
//!
//! The procedural textures carry detail far below a pixel at the evaluation sizes (stripes of
//! 1/8 cell, speckle of 1/64 cell, thin mortar and grout lines), so one point sample per pixel is
//! an aliased, nearly uncorrelated signal that no reprojection can predict at a sub-pixel offset
//! (docs/quality-breakdown.md: a half-pixel shift of a perfect static view scored 24.8 dB).
//! Colour is therefore the mean of `n×n` sub-samples on an ordered grid inside the pixel (a box
//! filter; for odd `n` the middle one is the pixel centre), averaged on the RGB8 scale and rounded
//! once; `n = 1` is byte for byte the point-sampled renderer of recording format 1. Only colour is filtered: depth, motion and the shadow bits describe the one surface
//! point at the pixel centre, and an average of two surfaces' depths or motions is a point on
//! neither.
//!
//! Shadow rays are most of the render time (32 per shadow evaluation, `2S − 1` evaluations per
//! server pixel; on a still surface under a still light the still occluders are traced once for
//! all of them and only the moving ones per instant, see `server.rs`), and a soft shadow varies slowly across one pixel, so sub-samples do not shoot
//! their own: a sub-sample on the centre's surface (same object, normal within ~25°) takes the
//! centre's shadow fraction, and the quantised levels of `S_min`/`S_max` are applied to exactly
//! those sub-samples. A sub-sample on another surface (a silhouette, a box edge) takes the
//! shadow of the first sub-sample on that surface, computed once at that sub-sample; its
//! contribution to `S_min`/`S_max` is its key colour, since the bitfield follows only the centre's
//! material point. So the added cost is `n² − 1` primary rays and texture look-ups per pixel plus
//! a few shadow evaluations at edges, not `n²` times the shadow rays.
//!
//! ## Files
//!
//! This file holds what both passes share: the buffer types, the camera rays, what one pixel or
//! colour sub-sample sees and the colour filter; `server.rs` the server-buffer pass
//! ([`render_server`]), `truth.rs` the ground-truth pass ([`render_ground_truth`],
//! [`render_shadow_fraction`]), `eye.rs` the primary rays' per-tile object lists (the same hits
//! as the scene BVH, found faster), `tests.rs` the unit tests.

mod eye;
mod server;
#[cfg(test)]
mod tests;
mod truth;

pub(crate) use reproj_core::Rays;
pub use reproj_core::ShadowBuffers;
use reproj_core::{Camera, CameraBuffers, CameraView, Mat4};

use crate::error::{Result, SceneError};
use crate::material::Material;
use crate::math::{add, normalize, scale, V3};
use crate::scene::{Scene, Snapshot};
use eye::{EyeTile, EyeTiles};
pub use server::render_server;
pub use truth::{render_ground_truth, render_shadow_fraction};

/// Largest number of colour sub-samples per pixel side (64 per pixel).
pub const MAX_SAMPLES: usize = 8;

/// An upper bound of the bytes [`render_ground_truth`] allocates for `camera`: the RGB8 image
/// twice (rendered in row blocks, then joined), 7 bytes a pixel for the rest (the screen tiles'
/// object lists, at most 4.25 at their cap, and up to 2.4 measured beside them in the built-in
/// scenes) and [`FIXED_BYTES`](reproj_core::memory::FIXED_BYTES). For the server buffers,
/// [`reproj_core::memory::server_buffers_bytes`] holds (tests/peak_memory.rs checks both).
pub fn truth_bytes(camera: &Camera) -> u64 {
    13u64
        .saturating_mul(reproj_core::memory::pixels(camera))
        .saturating_add(reproj_core::memory::FIXED_BYTES)
}

/// Two samples lie on one surface (and share a shadow fraction) when they hit the same object
/// with normals within ~25° (cos 25° ≈ 0.9): box faces, mesh creases and sharp folds count as
/// different surfaces, a sphere or a smooth mesh across one pixel as the same.
const SAME_SURFACE_COS: f64 = 0.9;

/// The default colour sub-samples per pixel side for a `width×height` camera: 3 (9 per pixel)
/// up to 640×360 pixels, 2 (4 per pixel) above.
///
/// At 320×180 and 640×360 a texture's finest detail (1/64 of a cell) is several per pixel, and
/// 3×3 is what lifted `ours` from VMAF 65 to 81 in docs/quality-breakdown.md; from 1280×720 up a
/// pixel covers a quarter of the area, so 2×2 spans a similar footprint at less than half the
/// primary rays, and rendering time grows with the pixel count.
pub fn default_samples(width: usize, height: usize) -> usize {
    if width.saturating_mul(height) <= 640 * 360 {
        3
    } else {
        2
    }
}

fn check_samples(samples: usize) -> Result<usize> {
    if (1..=MAX_SAMPLES).contains(&samples) {
        Ok(samples)
    } else {
        Err(SceneError::BadSamples {
            samples,
            max: MAX_SAMPLES,
        })
    }
}

/// Rows per rayon task. Whole rows keep each task's writes contiguous; a server pixel casts up to
/// `(2S − 1)·32` shadow rays, so 16 rows are ample work per task, and the blocks are concatenated
/// in order, so the result does not depend on the thread count.
const BLOCK_ROWS: usize = 16;

/// Every server buffer of one camera at one time, with the camera it was rendered at.
#[derive(Debug, Clone, PartialEq)]
pub struct ServerBuffers {
    /// World → camera.
    pub view: Mat4,
    /// Camera → clip (reversed depth).
    pub proj: Mat4,
    /// The buffers (`width × height` pixels).
    pub buffers: CameraBuffers,
}

impl ServerBuffers {
    /// The camera the buffers were rendered at.
    pub fn camera(&self) -> Camera {
        Camera {
            view: self.view,
            proj: self.proj,
            width: self.buffers.width,
            height: self.buffers.height,
        }
    }

    /// The buffers as the older image of a pair (`forward = true`: forward motion and shadows)
    /// or the newer one (backward ones).
    pub fn camera_view(&self, forward: bool) -> CameraView<'_> {
        self.buffers.view(self.camera(), forward)
    }
}

/// Checks a time `t` (seconds) that a render function was given as `what`: finite, and every
/// object of `scene` at a finite position then (its world box is built in `f32`). A time the
/// animations take out of range (seconds far beyond any path, such as 1e300) is refused here
/// rather than building a BVH of infinite boxes. The scene itself must have been checked
/// ([`Scene::check`]: every render function does so first, once).
pub(crate) fn check_time(scene: &Scene, what: &str, t: f64) -> Result<()> {
    let finite = |v: &f64| (*v as f32).is_finite();
    let ok = t.is_finite()
        && scene
            .transforms(t)
            .iter()
            .all(|w| w.rot.iter().flatten().chain(&w.trans).all(finite));
    if ok {
        Ok(())
    } else {
        Err(SceneError::BadTime {
            what: what.to_string(),
            value: t,
            expected: "expected a finite time at which every object of the scene is at a \
                       finite position"
                .to_string(),
        })
    }
}

/// Checks a frame rate (frames per second) given as `what`: finite and positive.
pub(crate) fn check_rate(what: &str, rate: f64) -> Result<f64> {
    if rate.is_finite() && rate > 0.0 {
        Ok(rate)
    } else {
        Err(SceneError::BadTime {
            what: what.to_string(),
            value: rate,
            expected: "expected a finite frame rate > 0".to_string(),
        })
    }
}

/// `camera`'s rays, checking its size; `what` names it in errors.
pub(crate) fn camera_rays(camera: &Camera, what: &str) -> Result<Rays> {
    let bad = |why: &str| SceneError::BadCamera {
        what: what.to_string(),
        why: why.to_string(),
    };
    if camera.width == 0
        || camera.height == 0
        || camera.width > reproj_core::MAX_SIDE
        || camera.height > reproj_core::MAX_SIDE
    {
        return Err(bad(&format!(
            "size {}×{} outside 1..={}",
            camera.width,
            camera.height,
            reproj_core::MAX_SIDE
        )));
    }
    Rays::new(camera).map_err(bad)
}

/// What one pixel (or colour sub-sample) sees at the key time.
#[derive(Clone, Copy)]
pub(crate) struct Sample {
    /// Object index; `None` for the sky.
    pub obj: Option<usize>,
    /// Face or triangle of the object (deforming meshes track material points by it; the tests
    /// use it to skip creases).
    pub face: u32,
    /// World hit point.
    pub x: V3,
    /// Object-space normal (facing the camera).
    pub n_obj: V3,
    /// World normal (facing the camera).
    pub normal: V3,
    /// The primary ray's direction from the eye (not unit; [`Snapshot::shade`] forms the unit
    /// view direction from it where a highlight needs one).
    pub dir: V3,
    /// NaN where [`Needs::albedo`] was not asked for.
    pub albedo: V3,
    /// Continuous shadow fraction at the key time.
    pub shadow: f64,
}

pub(crate) fn sample(
    snap: &Snapshot<'_>,
    rays: &Rays,
    i: usize,
    j: usize,
    with_shadow: bool,
) -> Sample {
    let needs = Needs {
        shadow: with_shadow,
        albedo: true,
    };
    sample_ray(snap, rays, rays.ray(i, j), needs, None)
}

/// What [`sample_ray`] computes besides the hit's geometry.
#[derive(Clone, Copy)]
pub(crate) struct Needs {
    /// The shadow fraction at the key time (else 0).
    pub shadow: bool,
    /// The albedo (else NaN). The centre of an even sub-sample grid is not one of the colour
    /// sub-samples, so nothing reads its albedo, and a texture look-up is saved per pixel.
    pub albedo: bool,
}

impl Needs {
    /// A colour sub-sample: the albedo, and the shadow is shared ([`footprint`]).
    const COLOUR: Needs = Needs {
        shadow: false,
        albedo: true,
    };

    /// A pixel centre for `n×n` colour sub-samples: its albedo only where it is one of them
    /// (odd `n`).
    fn centre(shadow: bool, n: usize) -> Needs {
        Needs {
            shadow,
            albedo: n % 2 == 1,
        }
    }
}

/// What the ray `d` from the camera centre sees; `eye`: the camera's tile that `d` passes
/// through, for the faster search of [`EyeTiles`] (the same hit).
fn sample_ray(
    snap: &Snapshot<'_>,
    rays: &Rays,
    d: V3,
    needs: Needs,
    eye: Option<&EyeTile<'_, '_>>,
) -> Sample {
    let mut s = Sample::SKY;
    sample_ray_into(snap, rays, d, needs, eye, None, &mut s);
    s
}

/// [`sample_ray`] into `out`: a colour sub-sample is written straight into its place in the
/// pixel's list (returned, the sample was built aside and copied there, a `memcpy` call).
/// `like`: a sample of the same snapshot (the pixel centre's) whose world normal is taken where
/// the hit has its object and object-space normal.
fn sample_ray_into(
    snap: &Snapshot<'_>,
    rays: &Rays,
    d: V3,
    needs: Needs,
    eye: Option<&EyeTile<'_, '_>>,
    like: Option<&Sample>,
    out: &mut Sample,
) {
    // s ≥ 1: beyond the near plane; below the far plane (beyond it is sky at Z = 0).
    // `d_obj`: `d` in the hit object's space (the tile search has it already).
    let hit = match eye {
        Some(tile) => snap.trace_eye(tile, rays.origin, d, 1.0, tile.far),
        None => snap
            .trace(rays.origin, d, 1.0, far_s(snap))
            .map(|h| (h, snap.inv[h.obj].vector(d))),
    };
    let Some((hit, d_obj)) = hit else {
        *out = Sample::SKY;
        return;
    };
    let x = add(rays.origin, scale(d, hit.t));
    let o = &snap.scene.objects[hit.obj];
    let mut n_obj = hit.local.normal;
    // Two-sided: the normal faces the side the point is seen from.
    if crate::math::dot(n_obj, d_obj) > 0.0 {
        n_obj = scale(n_obj, -1.0);
    }
    // The world normal depends on the object and `n_obj` alone: a sub-sample on the centre's
    // plane (a box face, the ground: the same `n_obj` bit for bit) takes the centre's instead of
    // transforming and normalising it again.
    let normal = match like {
        Some(c)
            if c.obj == Some(hit.obj) && c.n_obj.map(f64::to_bits) == n_obj.map(f64::to_bits) =>
        {
            c.normal
        }
        _ => normalize(snap.world[hit.obj].vector(n_obj)),
    };
    let shadow = if needs.shadow {
        snap.shadow(hit.obj, x, normal)
    } else {
        0.0
    };
    *out = Sample {
        obj: Some(hit.obj),
        face: hit.local.face,
        x,
        n_obj,
        normal,
        dir: d,
        albedo: if needs.albedo {
            o.shape
                .own_albedo(hit.local.face, hit.local.uv)
                .unwrap_or_else(|| o.material.albedo(hit.local.uv))
        } else {
            [f64::NAN; 3]
        },
        shadow,
    };
}

/// The far plane's parameter `s` along a primary ray `o + s·d` ([`Rays`]): the ray at `s = 1` is
/// on the near plane and view depth is linear in `s`, so the far plane is at `far / near`.
fn far_s(snap: &Snapshot<'_>) -> f64 {
    snap.scene.far / snap.scene.near
}

fn material<'s>(snap: &Snapshot<'s>, s: &Sample) -> Option<&'s Material> {
    s.obj.map(|o| &snap.scene.objects[o].material)
}

/// A sample's colour at the key time on the RGB8 scale (unrounded).
fn key_color(snap: &Snapshot<'_>, s: &Sample) -> V3 {
    match material(snap, s) {
        Some(m) => snap.shade(m, s.albedo, s.normal, s.dir, s.shadow),
        None => snap.scene.sky.map(f64::from),
    }
}

/// Whether `a` and `b` lie on one surface (see [`SAME_SURFACE_COS`]).
fn same_surface(a: &Sample, b: &Sample) -> bool {
    a.obj.is_some() && a.obj == b.obj && crate::math::dot(a.normal, b.normal) >= SAME_SURFACE_COS
}

impl Sample {
    /// What a ray that meets nothing sees.
    const SKY: Sample = Sample {
        obj: None,
        face: 0,
        x: [0.0; 3],
        n_obj: [0.0; 3],
        normal: [0.0; 3],
        dir: [0.0; 3],
        albedo: [0.0; 3],
        shadow: 0.0,
    };
}

/// One colour sub-sample of a pixel.
#[derive(Clone, Copy)]
struct SubSample {
    s: Sample,
    /// On the pixel centre's surface: it took the centre's shadow, and the shadow levels of the
    /// centre's bitfield apply to it.
    on_centre: bool,
    /// Its colour at the key time.
    key: V3,
}

/// The rays of one camera's `n×n` sub-sample grid per pixel ([`Rays::sub_ray`]), with each grid
/// column's and grid row's share of the product with `P⁻¹` (a division and four products each)
/// computed once per frame instead of once per ray: the same rays bit for bit
/// ([`Rays::sub_ray_at`]). `n = 1` gives the pixel centres' rays ([`Rays::ray`]).
struct SubRays<'r> {
    rays: &'r Rays,
    n: usize,
    /// Grid column `n·i + a`'s share.
    columns: Vec<[f64; 4]>,
    /// Grid row `n·j + b`'s share.
    rows: Vec<[f64; 4]>,
}

impl<'r> SubRays<'r> {
    fn new(rays: &'r Rays, n: usize) -> SubRays<'r> {
        SubRays {
            rays,
            n,
            columns: (0..n * rays.width)
                .map(|c| rays.sub_ray_column(c / n, c % n, n))
                .collect(),
            rows: (0..n * rays.height)
                .map(|r| rays.sub_ray_row(r / n, r % n, n))
                .collect(),
        }
    }

    /// `rays.sub_ray(i, j, a, b, n)`.
    #[inline]
    fn ray(&self, (i, j): (usize, usize), a: usize, b: usize) -> V3 {
        let n = self.n;
        self.rays
            .sub_ray_at(self.columns[n * i + a], self.rows[n * j + b])
    }
}

/// The `n×n` colour sub-samples (`n = grid.n`) of pixel `(i, j)` (in the tile `eye`, where the
/// camera has tiles) whose centre sample (with its shadow) is `centre`, into `out` (made `n²`
/// long), in a fixed order. Shadows are shared as the module documentation says: the centre's on
/// its own surface, the first sub-sample's on any other.
fn footprint(
    snap: &Snapshot<'_>,
    grid: &SubRays<'_>,
    eye: Option<&EyeTile<'_, '_>>,
    (i, j): (usize, usize),
    centre: &Sample,
    out: &mut Vec<SubSample>,
) {
    let (rays, n) = (grid.rays, grid.n);
    // `n×n` entries, kept from pixel to pixel: every field of each is overwritten below (the
    // centre's copy, or `sample_ray_into`'s whole `Sample` then `on_centre` and `key`), so that a
    // sub-sample (some 180 bytes) is written straight into its place and not cleared first.
    if out.len() != n * n {
        let unset = SubSample {
            s: Sample::SKY,
            on_centre: false,
            key: [0.0; 3],
        };
        out.clear();
        out.resize(n * n, unset);
    }
    // The middle sub-sample of an odd grid is the centre itself, the same at every `(a, b)`.
    let mid = (n % 2 == 1).then_some(n * n / 2);
    if let Some(k) = mid {
        out[k] = SubSample {
            s: *centre,
            on_centre: centre.obj.is_some(),
            key: key_color(snap, centre),
        };
    }
    // The light terms of the centre's normal and shadow, computed at the first sub-sample that
    // has both: the sub-samples on the centre's plane have its normal bit for bit (taken from it
    // in `sample_ray_into`) and its shadow, so their terms are the centre's.
    let mut centre_light = None;
    for b in 0..n {
        for a in 0..n {
            let k = b * n + a;
            if mid == Some(k) {
                continue;
            }
            let d = grid.ray((i, j), a, b);
            let (earlier, rest) = out.split_at_mut(k);
            let p = &mut rest[0];
            sample_ray_into(snap, rays, d, Needs::COLOUR, eye, Some(centre), &mut p.s);
            p.on_centre = same_surface(centre, &p.s);
            if p.on_centre {
                p.s.shadow = centre.shadow;
            } else if let Some(obj) = p.s.obj {
                let s = &p.s;
                p.s.shadow = match earlier
                    .iter()
                    .find(|q| !q.on_centre && same_surface(&q.s, s))
                {
                    Some(q) => q.s.shadow,
                    None => snap.shadow(obj, s.x, s.normal),
                };
            }
            p.key = match material(snap, &p.s) {
                Some(m)
                    if p.on_centre
                        && p.s.normal.map(f64::to_bits) == centre.normal.map(f64::to_bits) =>
                {
                    let e = *centre_light
                        .get_or_insert_with(|| snap.light_at(centre.normal, centre.shadow));
                    snap.shade_lit(m, p.s.albedo, p.s.normal, p.s.dir, e)
                }
                _ => key_color(snap, &p.s),
            };
        }
    }
}

/// The box filter: the mean of `colors` on the RGB8 scale, rounded once.
fn mean_rgb8(colors: impl Iterator<Item = V3>) -> [u8; 3] {
    let (mut sum, mut count) = ([0.0; 3], 0usize);
    for c in colors {
        sum = add(sum, c);
        count += 1;
    }
    sum.map(|v| rgb8(v / count as f64))
}

/// `x.round().clamp(0.0, 255.0) as u8` without `round`, a library call on the x86-64 baseline
/// (three per pixel): at or below 0 (and NaN) 0, from 255 up 255; between, the truncation `t`,
/// one more where `x − t ≥ 0.5` (round half away from zero). `x − t` is exact (`t ≤ x < 2t`, or
/// `t = 0`), so the answer is the same for every `x` (tested against the library).
fn rgb8(x: f64) -> u8 {
    if !(x > 0.0) {
        return 0;
    }
    if x >= 255.0 {
        return 255;
    }
    let t = x as u8;
    t + u8::from(x - f64::from(t) >= 0.5)
}

/// The colour of a pixel from its sub-samples.
fn pixel_color(subs: &[SubSample]) -> [u8; 3] {
    mean_rgb8(subs.iter().map(|p| p.key))
}
