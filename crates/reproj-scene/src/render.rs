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
//! server pixel), and a soft shadow varies slowly across one pixel, so sub-samples do not shoot
//! their own: a sub-sample on the centre's surface (same object, normal within ~25°) takes the
//! centre's shadow fraction, and the quantised levels of `S_min`/`S_max` are applied to exactly
//! those sub-samples. A sub-sample on another surface (a silhouette, a box edge) takes the
//! shadow of the first sub-sample on that surface, computed once at that sub-sample; its
//! contribution to `S_min`/`S_max` is its key colour, since the bitfield follows only the centre's
//! material point. So the added cost is `n² − 1` primary rays and texture look-ups per pixel plus
//! a few shadow evaluations at edges, not `n²` times the shadow rays.

use rayon::prelude::*;
use reproj_core::{Camera, Mat4};

use crate::error::{Result, SceneError};
use crate::material::Material;
use crate::math::{add, normalize, scale, sub, V3};
use crate::scene::{Scene, Snapshot, Variant};
use crate::shape::Shape;

/// Largest number of colour sub-samples per pixel side (64 per pixel).
pub const MAX_SAMPLES: usize = 8;

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
    if width * height <= 640 * 360 {
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

/// The dynamic-shadow buffers of one direction (DESIGN.md "Dynamic shadows").
#[derive(Debug, Clone, PartialEq)]
pub struct ShadowBuffers {
    /// `H·W` bitfields: 2 bits per subframe, subframe `j` in bits `2j, 2j+1`; 0 where the level is
    /// the same at every subframe.
    pub bits: Vec<u32>,
    /// `H·W·3` RGB8 colour at the minimum level; 0 where that level is subframe 0's or bits = 0.
    pub s_min: Vec<u8>,
    /// `H·W·3` RGB8 colour at the maximum level; 0 where that level is subframe 0's or bits = 0.
    pub s_max: Vec<u8>,
}

/// Every server buffer of one camera at one time.
#[derive(Debug, Clone, PartialEq)]
pub struct ServerBuffers {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// World → camera.
    pub view: Mat4,
    /// Camera → clip (reversed depth).
    pub proj: Mat4,
    /// `H·W·3` RGB8 colour (continuous soft shadow).
    pub color: Vec<u8>,
    /// `H·W` reversed depth; 0 for the sky.
    pub depth: Vec<f32>,
    /// `H·W·3` object motion `P(X_{t+Δ}) − P(X_t)` in this camera's NDC, camera held fixed.
    pub motion_fwd: Vec<f32>,
    /// `H·W·3` object motion `P(X_{t−Δ}) − P(X_t)` in this camera's NDC, camera held fixed.
    pub motion_bwd: Vec<f32>,
    /// Shadow buffers toward `t + Δ`: subframe `j` at `t + jΔ/S`.
    pub shadow_fwd: ShadowBuffers,
    /// Shadow buffers toward `t − Δ`: subframe `j` at `t − jΔ/S`.
    pub shadow_bwd: ShadowBuffers,
}

/// A camera's rays: its centre and `P⁻¹` for the pixel directions.
pub(crate) struct Rays {
    vp: Mat4,
    inv_vp: Mat4,
    pub origin: V3,
    pub width: usize,
    pub height: usize,
}

impl Rays {
    pub(crate) fn new(camera: &Camera, what: &str) -> Result<Rays> {
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
        let vp = camera.view_proj();
        let inv_vp = vp
            .inverse()
            .ok_or_else(|| bad("singular view-projection"))?;
        let iv = camera.view.inverse().ok_or_else(|| bad("singular view"))?;
        let o = iv.mul_vec([0.0, 0.0, 0.0, 1.0]);
        Ok(Rays {
            vp,
            inv_vp,
            origin: [o[0] / o[3], o[1] / o[3], o[2] / o[3]],
            width: camera.width,
            height: camera.height,
        })
    }

    /// The ray through the centre of pixel `(i, j)`, scaled so that `s = 1` is the near plane.
    pub(crate) fn ray(&self, i: usize, j: usize) -> V3 {
        self.sub_ray(i, j, 0, 0, 1)
    }

    /// The ray through sub-sample `(a, b)` of the `n×n` ordered grid of pixel `(i, j)`, at
    /// `(i + (a + ½)/n, j + (b + ½)/n)` pixels. Numerator and denominator are integers, so the
    /// middle sub-sample of an odd grid is the pixel-centre ray bit for bit.
    pub(crate) fn sub_ray(&self, i: usize, j: usize, a: usize, b: usize, n: usize) -> V3 {
        let x = (2 * n * i + 2 * a + 1) as f64 / (n * self.width) as f64 - 1.0;
        let y = 1.0 - (2 * n * j + 2 * b + 1) as f64 / (n * self.height) as f64;
        let h = self.inv_vp.mul_vec([x, y, 1.0, 1.0]);
        sub([h[0] / h[3], h[1] / h[3], h[2] / h[3]], self.origin)
    }

    /// The ray parameter of the far plane along `d` (the ray at `s = 1` is on the near plane, and
    /// view depth is linear in `s`).
    fn far_param(&self, scene: &Scene) -> f64 {
        scene.far / scene.near
    }

    /// `P(X)` with the perspective division.
    pub(crate) fn project(&self, x: V3) -> V3 {
        let h = self.vp.mul_vec([x[0], x[1], x[2], 1.0]);
        [h[0] / h[3], h[1] / h[3], h[2] / h[3]]
    }
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
    /// Unit direction from the point toward the eye.
    pub view: V3,
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
    sample_ray(snap, rays, rays.ray(i, j), with_shadow)
}

/// What the ray `d` from the camera centre sees.
fn sample_ray(snap: &Snapshot<'_>, rays: &Rays, d: V3, with_shadow: bool) -> Sample {
    let sky = Sample {
        obj: None,
        face: 0,
        x: [0.0; 3],
        n_obj: [0.0; 3],
        normal: [0.0; 3],
        view: [0.0; 3],
        albedo: [0.0; 3],
        shadow: 0.0,
    };
    // s ≥ 1: beyond the near plane; below the far plane (beyond it is sky at Z = 0).
    let Some(hit) = snap.trace(rays.origin, d, 1.0, rays.far_param(snap.scene)) else {
        return sky;
    };
    let x = add(rays.origin, scale(d, hit.t));
    let o = &snap.scene.objects[hit.obj];
    let mut n_obj = hit.local.normal;
    let d_obj = snap.inv[hit.obj].vector(d);
    // Two-sided: the normal faces the side the point is seen from.
    if crate::math::dot(n_obj, d_obj) > 0.0 {
        n_obj = scale(n_obj, -1.0);
    }
    let normal = normalize(snap.world[hit.obj].vector(n_obj));
    let shadow = if with_shadow {
        snap.shadow(hit.obj, x, normal)
    } else {
        0.0
    };
    Sample {
        obj: Some(hit.obj),
        face: hit.local.face,
        x,
        n_obj,
        normal,
        view: normalize(scale(d, -1.0)),
        albedo: o
            .shape
            .own_albedo(hit.local.face, hit.local.uv)
            .unwrap_or_else(|| o.material.albedo(hit.local.uv)),
        shadow,
    }
}

fn material<'s>(snap: &Snapshot<'s>, s: &Sample) -> Option<&'s Material> {
    s.obj.map(|o| &snap.scene.objects[o].material)
}

/// A sample's colour at the key time on the RGB8 scale (unrounded).
fn key_color(snap: &Snapshot<'_>, s: &Sample) -> V3 {
    match material(snap, s) {
        Some(m) => snap.shade(m, s.albedo, s.normal, s.view, s.shadow),
        None => snap.scene.sky.map(f64::from),
    }
}

/// Whether `a` and `b` lie on one surface (see [`SAME_SURFACE_COS`]).
fn same_surface(a: &Sample, b: &Sample) -> bool {
    a.obj.is_some() && a.obj == b.obj && crate::math::dot(a.normal, b.normal) >= SAME_SURFACE_COS
}

/// One colour sub-sample of a pixel.
struct SubSample {
    s: Sample,
    /// On the pixel centre's surface: it took the centre's shadow, and the shadow levels of the
    /// centre's bitfield apply to it.
    on_centre: bool,
    /// Its colour at the key time.
    key: V3,
}

/// The `n×n` colour sub-samples of pixel `(i, j)` whose centre sample (with its shadow) is
/// `centre`, into `out` (cleared first), in a fixed order. Shadows are shared as the module
/// documentation says: the centre's on its own surface, the first sub-sample's on any other.
fn footprint(
    snap: &Snapshot<'_>,
    rays: &Rays,
    (i, j): (usize, usize),
    n: usize,
    centre: &Sample,
    out: &mut Vec<SubSample>,
) {
    out.clear();
    for b in 0..n {
        for a in 0..n {
            if n % 2 == 1 && a == n / 2 && b == n / 2 {
                out.push(SubSample {
                    s: *centre,
                    on_centre: centre.obj.is_some(),
                    key: key_color(snap, centre),
                });
                continue;
            }
            let mut s = sample_ray(snap, rays, rays.sub_ray(i, j, a, b, n), false);
            let on_centre = same_surface(centre, &s);
            if on_centre {
                s.shadow = centre.shadow;
            } else if let Some(obj) = s.obj {
                s.shadow = match out.iter().find(|p| !p.on_centre && same_surface(&p.s, &s)) {
                    Some(p) => p.s.shadow,
                    None => snap.shadow(obj, s.x, s.normal),
                };
            }
            out.push(SubSample {
                s,
                on_centre,
                key: key_color(snap, &s),
            });
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
    sum.map(|v| (v / count as f64).round().clamp(0.0, 255.0) as u8)
}

/// The colour of a pixel from its sub-samples.
fn pixel_color(subs: &[SubSample]) -> [u8; 3] {
    mean_rgb8(subs.iter().map(|p| p.key))
}

/// Where the material point `x` (seen on `obj`, triangle or face `face`, in `key`) is in
/// snapshot `to`, with its normal. A still object returns `x` and `n` themselves, so its motion
/// is exactly zero. On a deforming mesh the material point is (triangle, barycentrics), carried to
/// the mesh posed at `to`'s time.
fn carry(
    key: &Snapshot<'_>,
    to: &Snapshot<'_>,
    obj: usize,
    face: u32,
    x: V3,
    n_obj: V3,
    n: V3,
) -> (V3, V3) {
    if !key.scene.moves(obj) {
        return (x, n);
    }
    let local = key.inv[obj].point(x);
    if let (Shape::Mesh(from), Shape::Mesh(dest)) = (key.shape(obj), to.shape(obj)) {
        if key.scene.objects[obj].shape.deforms() {
            let (p, nl) = crate::mesh::carry_on_mesh(from, dest, face, local, n_obj);
            return (to.world[obj].point(p), normalize(to.world[obj].vector(nl)));
        }
    }
    (
        to.world[obj].point(local),
        normalize(to.world[obj].vector(n_obj)),
    )
}

fn quantise(f: f64) -> u32 {
    (f * 3.0).round().clamp(0.0, 3.0) as u32
}

/// Bitfield and `S_min`/`S_max` of the pixel-centre sample `s` following its material point over
/// `subs` (the snapshots at subframes `1..S`; subframe 0 is the key); `S_min`/`S_max` re-shade the
/// pixel's colour sub-samples `fp` on the centre's surface at the extreme levels.
fn shadow_field(
    key: &Snapshot<'_>,
    subs: &[Snapshot<'_>],
    s: &Sample,
    fp: &[SubSample],
) -> (u32, [u8; 3], [u8; 3]) {
    let (Some(obj), Some(m)) = (s.obj, material(key, s)) else {
        return (0, [0; 3], [0; 3]);
    };
    let l0 = quantise(s.shadow);
    let (mut bits, mut lmin, mut lmax) = (l0, l0, l0);
    for (j, sub) in subs.iter().enumerate() {
        let (xj, nj) = carry(key, sub, obj, s.face, s.x, s.n_obj, s.normal);
        let level = quantise(sub.shadow(obj, xj, nj));
        bits |= level << (2 * (j + 1));
        lmin = lmin.min(level);
        lmax = lmax.max(level);
    }
    if lmin == lmax {
        return (0, [0; 3], [0; 3]);
    }
    // Only the shadow is re-applied (the client's eqs. 9–11 only interpolate the shadow).
    // Sub-samples on the centre's surface share its object, hence its material `m`.
    let at = |l: u32| {
        mean_rgb8(fp.iter().map(|p| {
            if p.on_centre {
                key.shade(m, p.s.albedo, p.s.normal, p.s.view, l as f64 / 3.0)
            } else {
                p.key
            }
        }))
    };
    let smin = if lmin == l0 { [0; 3] } else { at(lmin) };
    let smax = if lmax == l0 { [0; 3] } else { at(lmax) };
    (bits, smin, smax)
}

/// Every server buffer of `camera` at time `t` (seconds): `interval` = Δ = 1/f_s, `subframes` =
/// S = f_d/f_s, colour from `samples × samples` sub-samples per pixel ([`default_samples`]).
///
/// # Errors
/// [`SceneError::BadSubframes`] when `subframes ∉ 1..=16`; [`SceneError::BadSamples`] when
/// `samples ∉ 1..=MAX_SAMPLES`; [`SceneError::BadCamera`] when the camera's size is out of range
/// or its matrices cannot be inverted.
pub fn render_server(
    scene: &Scene,
    camera: &Camera,
    t: f64,
    interval: f64,
    subframes: usize,
    samples: usize,
) -> Result<ServerBuffers> {
    if !(1..=16).contains(&subframes) {
        return Err(SceneError::BadSubframes { subframes });
    }
    let n = check_samples(samples)?;
    let rays = Rays::new(camera, "server")?;
    let (w, h) = (camera.width, camera.height);
    let key = scene.at(t);
    let (next, prev) = (scene.at(t + interval), scene.at(t - interval));
    let step = interval / subframes as f64;
    let fwd: Vec<Snapshot<'_>> = (1..subframes)
        .map(|j| scene.at(t + step * j as f64))
        .collect();
    let bwd: Vec<Snapshot<'_>> = (1..subframes)
        .map(|j| scene.at(t - step * j as f64))
        .collect();
    let blocks: Vec<Block> = (0..h.div_ceil(BLOCK_ROWS))
        .into_par_iter()
        .map(|b| {
            let rows = BLOCK_ROWS.min(h - b * BLOCK_ROWS);
            let mut blk = Block::new(rows * w);
            let mut fp = Vec::with_capacity(n * n);
            for r in 0..rows {
                for i in 0..w {
                    let k = r * w + i;
                    let j = b * BLOCK_ROWS + r;
                    let s = sample(&key, &rays, i, j, true);
                    footprint(&key, &rays, (i, j), n, &s, &mut fp);
                    blk.color[3 * k..3 * k + 3].copy_from_slice(&pixel_color(&fp));
                    let Some(obj) = s.obj else {
                        continue; // Sky: Z = 0, zero motion, no dynamic shadow.
                    };
                    let p = rays.project(s.x);
                    blk.depth[k] = p[2] as f32;
                    if scene.variant == Variant::Static {
                        continue; // Nothing moves and the light is still: all zero.
                    }
                    if scene.moves(obj) {
                        let pf =
                            rays.project(carry(&key, &next, obj, s.face, s.x, s.n_obj, s.normal).0);
                        let pb =
                            rays.project(carry(&key, &prev, obj, s.face, s.x, s.n_obj, s.normal).0);
                        for c in 0..3 {
                            blk.motion_fwd[3 * k + c] = (pf[c] - p[c]) as f32;
                            blk.motion_bwd[3 * k + c] = (pb[c] - p[c]) as f32;
                        }
                    }
                    for (subs, bits, smin, smax) in [
                        (
                            &fwd,
                            &mut blk.bits_fwd,
                            &mut blk.smin_fwd,
                            &mut blk.smax_fwd,
                        ),
                        (
                            &bwd,
                            &mut blk.bits_bwd,
                            &mut blk.smin_bwd,
                            &mut blk.smax_bwd,
                        ),
                    ] {
                        let (bf, mn, mx) = shadow_field(&key, subs, &s, &fp);
                        bits[k] = bf;
                        smin[3 * k..3 * k + 3].copy_from_slice(&mn);
                        smax[3 * k..3 * k + 3].copy_from_slice(&mx);
                    }
                }
            }
            blk
        })
        .collect();
    let n = w * h;
    let shadow = || ShadowBuffers {
        bits: Vec::with_capacity(n),
        s_min: Vec::with_capacity(3 * n),
        s_max: Vec::with_capacity(3 * n),
    };
    let mut out = ServerBuffers {
        width: w,
        height: h,
        view: camera.view,
        proj: camera.proj,
        color: Vec::with_capacity(3 * n),
        depth: Vec::with_capacity(n),
        motion_fwd: Vec::with_capacity(3 * n),
        motion_bwd: Vec::with_capacity(3 * n),
        shadow_fwd: shadow(),
        shadow_bwd: shadow(),
    };
    for b in blocks {
        out.color.extend_from_slice(&b.color);
        out.depth.extend_from_slice(&b.depth);
        out.motion_fwd.extend_from_slice(&b.motion_fwd);
        out.motion_bwd.extend_from_slice(&b.motion_bwd);
        out.shadow_fwd.bits.extend_from_slice(&b.bits_fwd);
        out.shadow_fwd.s_min.extend_from_slice(&b.smin_fwd);
        out.shadow_fwd.s_max.extend_from_slice(&b.smax_fwd);
        out.shadow_bwd.bits.extend_from_slice(&b.bits_bwd);
        out.shadow_bwd.s_min.extend_from_slice(&b.smin_bwd);
        out.shadow_bwd.s_max.extend_from_slice(&b.smax_bwd);
    }
    Ok(out)
}

/// Per-pixel map over row blocks in parallel, concatenated in order (thread-count independent).
fn per_pixel<T: Copy + Default + Send, const C: usize>(
    rays: &Rays,
    f: impl Fn(usize, usize) -> [T; C] + Sync,
) -> Vec<T> {
    let (w, h) = (rays.width, rays.height);
    let mut out = vec![T::default(); C * w * h];
    out.par_chunks_mut(C * w * BLOCK_ROWS)
        .enumerate()
        .for_each(|(b, chunk)| {
            for (k, px) in chunk.chunks_exact_mut(C).enumerate() {
                px.copy_from_slice(&f(k % w, b * BLOCK_ROWS + k / w));
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
/// the camera's size is out of range or its matrices cannot be inverted.
pub fn render_ground_truth(
    scene: &Scene,
    camera: &Camera,
    t: f64,
    samples: usize,
) -> Result<Vec<u8>> {
    let n = check_samples(samples)?;
    let rays = Rays::new(camera, "client")?;
    let snap = scene.at(t);
    Ok(per_pixel(&rays, |i, j| {
        let mut fp = Vec::with_capacity(n * n);
        footprint(
            &snap,
            &rays,
            (i, j),
            n,
            &sample(&snap, &rays, i, j, true),
            &mut fp,
        );
        pixel_color(&fp)
    }))
}

/// The continuous main-light shadow fraction (`H·W`, 0 lit … 1 shadowed, 0 for the sky) seen by
/// `camera` at time `t`: the quantity the shadow bitfields quantise, for evaluation and tests.
///
/// # Errors
/// As [`render_ground_truth`].
pub fn render_shadow_fraction(scene: &Scene, camera: &Camera, t: f64) -> Result<Vec<f32>> {
    let rays = Rays::new(camera, "shadow")?;
    let snap = scene.at(t);
    Ok(per_pixel(&rays, |i, j| {
        [sample(&snap, &rays, i, j, true).shadow as f32]
    }))
}

/// The buffers of one block of rows, concatenated in order afterwards.
struct Block {
    color: Vec<u8>,
    depth: Vec<f32>,
    motion_fwd: Vec<f32>,
    motion_bwd: Vec<f32>,
    bits_fwd: Vec<u32>,
    smin_fwd: Vec<u8>,
    smax_fwd: Vec<u8>,
    bits_bwd: Vec<u32>,
    smin_bwd: Vec<u8>,
    smax_bwd: Vec<u8>,
}

impl Block {
    fn new(n: usize) -> Self {
        Block {
            color: vec![0; 3 * n],
            depth: vec![0.0; n],
            motion_fwd: vec![0.0; 3 * n],
            motion_bwd: vec![0.0; 3 * n],
            bits_fwd: vec![0; n],
            smin_fwd: vec![0; 3 * n],
            smax_fwd: vec![0; 3 * n],
            bits_bwd: vec![0; n],
            smin_bwd: vec![0; 3 * n],
            smax_bwd: vec![0; 3 * n],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::rig;
    use crate::scenes::builtin;

    const DT: f64 = 0.1;
    const S: usize = 4;

    /// The main camera of server frame `k` at `w×h`.
    fn camera(scene: &Scene, k: usize, w: usize, h: usize) -> Camera {
        rig(
            &scene.path.server_pose(k, 10.0),
            w,
            h,
            scene.near,
            scene.far,
        )
        .main
    }

    /// `(object, face)` seen at each pixel (`None` for the sky).
    fn ids(scene: &Scene, cam: &Camera, t: f64) -> Vec<Option<(usize, u32)>> {
        let rays = Rays::new(cam, "test").unwrap();
        let snap = scene.at(t);
        let mut out = Vec::new();
        for j in 0..cam.height {
            for i in 0..cam.width {
                let s = sample(&snap, &rays, i, j, false);
                // A smooth mesh counts as one surface: its triangles are smaller than a pixel
                // here, and bilinear interpolation across them errs only to second order.
                out.push(s.obj.map(|o| {
                    let mesh = matches!(scene.objects[o].shape, crate::shape::Shape::Mesh(_));
                    (o, if mesh { 0 } else { s.face })
                }));
            }
        }
        out
    }

    fn f32_bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn rendering_is_deterministic_and_independent_of_the_thread_count() {
        let scene = builtin("courtyard", Variant::Dynamic).unwrap();
        let cam = camera(&scene, 12, 61, 35);
        let t = 1.2;
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                (
                    render_server(&scene, &cam, t, DT, S, 3).unwrap(),
                    render_ground_truth(&scene, &cam, t, 3).unwrap(),
                )
            })
        };
        let (a, ga) = run(1);
        let (b, gb) = run(4);
        let (c, gc) = run(4);
        for (x, gx) in [(&b, &gb), (&c, &gc)] {
            assert_eq!(&ga, gx);
            assert_eq!(a.color, x.color);
            assert_eq!(f32_bits(&a.depth), f32_bits(&x.depth));
            assert_eq!(f32_bits(&a.motion_fwd), f32_bits(&x.motion_fwd));
            assert_eq!(f32_bits(&a.motion_bwd), f32_bits(&x.motion_bwd));
            assert_eq!(a.shadow_fwd, x.shadow_fwd);
            assert_eq!(a.shadow_bwd, x.shadow_bwd);
        }
        // The ground truth at a server camera and time is the server colour, byte for byte.
        assert_eq!(ga, a.color);
    }

    #[test]
    fn static_variants_have_no_motion_and_no_dynamic_shadow() {
        for name in crate::scenes::SCENE_NAMES {
            let scene = builtin(name, Variant::Static).unwrap();
            let cam = camera(&scene, 7, 48, 27);
            let r = render_server(&scene, &cam, 0.7, DT, S, 2).unwrap();
            assert!(r.motion_fwd.iter().chain(&r.motion_bwd).all(|&m| m == 0.0));
            for sb in [&r.shadow_fwd, &r.shadow_bwd] {
                assert!(sb.bits.iter().all(|&b| b == 0), "{name}");
                assert!(sb.s_min.iter().chain(&sb.s_max).all(|&c| c == 0), "{name}");
            }
            assert!(r.depth.iter().any(|&z| z > 0.0), "{name} sees nothing");
        }
    }

    /// Bilinear sample of `depth` at NDC `(x, y)` and the four pixels it reads, or `None` when the
    /// footprint leaves the image.
    fn bilinear(depth: &[f32], w: usize, h: usize, x: f64, y: f64) -> Option<(f64, [usize; 4])> {
        let fx = (x + 1.0) * 0.5 * w as f64 - 0.5;
        let fy = (1.0 - y) * 0.5 * h as f64 - 0.5;
        let (i0, j0) = (fx.floor(), fy.floor());
        if !(i0 >= 0.0 && j0 >= 0.0 && i0 + 1.0 < w as f64 && j0 + 1.0 < h as f64) {
            return None;
        }
        let (i0, j0) = (i0 as usize, j0 as usize);
        let (ax, ay) = (fx - i0 as f64, fy - j0 as f64);
        let k = [
            j0 * w + i0,
            j0 * w + i0 + 1,
            (j0 + 1) * w + i0,
            (j0 + 1) * w + i0 + 1,
        ];
        let z = |n: usize| f64::from(depth[k[n]]);
        let top = z(0) + (z(1) - z(0)) * ax;
        let bot = z(2) + (z(3) - z(2)) * ax;
        Some((top + (bot - top) * ay, k))
    }

    /// Moving every visible point of one frame by its motion lands it on the other frame's surface
    /// (camera held fixed). The other frame is sampled bilinearly at the exact landing point, not
    /// at the nearest pixel centre (which sees a neighbouring material point whose depth differs
    /// by the depth gradient); footprints that straddle another object or face (silhouettes,
    /// creases, occlusion at the other time) are skipped.
    fn check_motion_consistency(name: &str, k: usize) {
        let scene = builtin(name, Variant::Dynamic).unwrap();
        let (w, h) = (96, 54);
        let cam = camera(&scene, k, w, h);
        let t = k as f64 * DT;
        let a = render_server(&scene, &cam, t, DT, 1, 1).unwrap();
        let b = render_server(&scene, &cam, t + DT, DT, 1, 1).unwrap();
        let (ia, ib) = (ids(&scene, &cam, t), ids(&scene, &cam, t + DT));
        for (src, dst, ids_src, ids_dst, motion) in [
            (&a, &b, &ia, &ib, &a.motion_fwd),
            (&b, &a, &ib, &ia, &b.motion_bwd),
        ] {
            let (mut comparable, mut good, mut moving, mut moving_good) = (0usize, 0, 0, 0);
            for j in 0..h {
                for i in 0..w {
                    let p = j * w + i;
                    let Some(id) = ids_src[p] else { continue };
                    let o = &motion[3 * p..3 * p + 3];
                    if !scene.moves(id.0) {
                        assert_eq!(o, &[0.0; 3], "{name}: still object moves at {i},{j}");
                    }
                    let x = (2 * i + 1) as f64 / w as f64 - 1.0 + f64::from(o[0]);
                    let y = 1.0 - (2 * j + 1) as f64 / h as f64 + f64::from(o[1]);
                    let z = f64::from(src.depth[p]) + f64::from(o[2]);
                    let Some((zi, quad)) = bilinear(&dst.depth, w, h, x, y) else {
                        continue;
                    };
                    if quad.iter().any(|&q| ids_dst[q] != Some(id)) {
                        continue;
                    }
                    comparable += 1;
                    let ok = (zi - z).abs() <= 1e-4;
                    good += usize::from(ok);
                    // Thin curved meshes (a 9 cm tube two pixels wide) are beyond what a bilinear
                    // footprint resolves; `motion_unprojects_to_the_moved_material_point` covers them.
                    let mesh = matches!(scene.objects[id.0].shape, crate::shape::Shape::Mesh(_));
                    if scene.moves(id.0) && !mesh {
                        moving += 1;
                        moving_good += usize::from(ok);
                    }
                }
            }
            assert!(
                moving >= 10,
                "{name}: only {moving} moving comparable pixels"
            );
            // The still pixels pass trivially, so the moving ones are held to a bar of their own.
            assert!(
                moving_good as f64 >= 0.9 * moving as f64,
                "{name}: {moving_good} of {moving} moving pixels within 1e-4"
            );
            assert!(
                good as f64 >= 0.99 * comparable as f64,
                "{name}: {good} of {comparable} within 1e-4"
            );
        }
    }

    /// `P⁻¹(p̄ + O[p])` is the material point seen at `p` moved by its object's transforms,
    /// written out independently of the renderer's `carry`.
    #[test]
    fn motion_unprojects_to_the_moved_material_point() {
        let scene = builtin("lab", Variant::Dynamic).unwrap();
        let (w, h) = (96, 54);
        let cam = camera(&scene, 12, w, h);
        let t = 1.2;
        let r = render_server(&scene, &cam, t, DT, 1, 1).unwrap();
        let inv_vp = cam.view_proj().inverse().unwrap();
        let unproject = |x: f64, y: f64, z: f64| {
            let q = inv_vp.mul_vec([x, y, z, 1.0]);
            [q[0] / q[3], q[1] / q[3], q[2] / q[3]]
        };
        let ids_t = ids(&scene, &cam, t);
        let w0 = scene.transforms(t);
        let mut checked = 0;
        for (motion, dt) in [(&r.motion_fwd, DT), (&r.motion_bwd, -DT)] {
            let w1 = scene.transforms(t + dt);
            for p in 0..w * h {
                let Some((obj, _)) = ids_t[p] else { continue };
                if !scene.moves(obj) {
                    continue;
                }
                let (i, j) = (p % w, p / w);
                let x = (2 * i + 1) as f64 / w as f64 - 1.0;
                let y = 1.0 - (2 * j + 1) as f64 / h as f64;
                let z = f64::from(r.depth[p]);
                let x0 = unproject(x, y, z);
                let expect = w1[obj].point(w0[obj].inverse().point(x0));
                let o = &motion[3 * p..3 * p + 3];
                let moved = unproject(
                    x + f64::from(o[0]),
                    y + f64::from(o[1]),
                    z + f64::from(o[2]),
                );
                let err = (0..3)
                    .map(|k| (moved[k] - expect[k]).abs())
                    .fold(0.0, f64::max);
                assert!(err < 2e-3, "pixel {i},{j}: {moved:?} vs {expect:?}");
                checked += 1;
            }
        }
        assert!(checked > 100, "{checked}");
    }

    #[test]
    fn motion_moves_points_onto_the_next_and_previous_frames_surfaces() {
        check_motion_consistency("courtyard", 10);
        check_motion_consistency("lab", 12);
        check_motion_consistency("colonnade", 5);
    }

    /// On still objects the bitfield's subframe `j` is exactly the quantised shadow observed when
    /// the scene is rendered directly at `t ± jΔ/S` from the same camera; subframe 0 (and every
    /// subframe, where the bits are 0) is the key frame's.
    #[test]
    fn shadow_bits_match_directly_rendered_subframes() {
        let scene = builtin("lab", Variant::Dynamic).unwrap();
        let (w, h) = (64, 36);
        let cam = camera(&scene, 20, w, h);
        let t = 2.0;
        let r = render_server(&scene, &cam, t, DT, S, 1).unwrap();
        let key = ids(&scene, &cam, t);
        let q = |f: f32| (f64::from(f) * 3.0).round() as u32;
        let mut changing = 0;
        for (sb, sign) in [(&r.shadow_fwd, 1.0), (&r.shadow_bwd, -1.0)] {
            for j in 0..S {
                let tj = t + sign * DT / S as f64 * j as f64;
                let direct = render_shadow_fraction(&scene, &cam, tj).unwrap();
                let at_j = ids(&scene, &cam, tj);
                for p in 0..w * h {
                    let Some(id) = key[p] else { continue };
                    if scene.moves(id.0) || at_j[p] != key[p] {
                        continue;
                    }
                    let bits = sb.bits[p];
                    let level = if bits == 0 {
                        let key_f = render_shadow_fraction_at(&scene, &cam, t, p);
                        q(key_f)
                    } else {
                        (bits >> (2 * j)) & 3
                    };
                    assert_eq!(level, q(direct[p]), "pixel {p}, subframe {j}, sign {sign}");
                    changing += usize::from(bits != 0 && j == 1);
                }
            }
        }
        assert!(
            changing > 10,
            "only {changing} still pixels with a changing shadow"
        );
    }

    fn render_shadow_fraction_at(scene: &Scene, cam: &Camera, t: f64, p: usize) -> f32 {
        let rays = Rays::new(cam, "test").unwrap();
        let snap = scene.at(t);
        sample(&snap, &rays, p % cam.width, p / cam.width, true).shadow as f32
    }

    #[test]
    fn shadow_colours_follow_the_levels_and_the_sky_is_far_and_still() {
        let scene = builtin("courtyard", Variant::Dynamic).unwrap();
        let cam = camera(&scene, 10, 80, 45);
        let r = render_server(&scene, &cam, 1.0, DT, S, 3).unwrap();
        let mut with_bits = 0;
        for sb in [&r.shadow_fwd, &r.shadow_bwd] {
            for p in 0..80 * 45 {
                let bits = sb.bits[p];
                let (smin, smax) = (&sb.s_min[3 * p..3 * p + 3], &sb.s_max[3 * p..3 * p + 3]);
                if bits == 0 {
                    assert!(smin == [0; 3] && smax == [0; 3]);
                    continue;
                }
                with_bits += 1;
                assert_eq!(bits >> (2 * S), 0);
                let levels: Vec<u32> = (0..S).map(|j| (bits >> (2 * j)) & 3).collect();
                let (lo, hi) = (*levels.iter().min().unwrap(), *levels.iter().max().unwrap());
                assert!(lo < hi);
                assert_eq!(smin == [0; 3], lo == levels[0]);
                assert_eq!(smax == [0; 3], hi == levels[0]);
            }
        }
        assert!(with_bits > 10, "{with_bits}");
        let mut sky = 0;
        // Point-sampled, so that a sky pixel is sky in all of its colour (supersampled, a thin
        // pole between two pixel centres would tint it).
        let r = render_server(&scene, &cam, 1.0, DT, S, 1).unwrap();
        for p in 0..80 * 45 {
            if r.depth[p] == 0.0 {
                sky += 1;
                assert_eq!(&r.color[3 * p..3 * p + 3], &scene.sky);
                assert_eq!(&r.motion_fwd[3 * p..3 * p + 3], &[0.0; 3]);
                assert_eq!(r.shadow_fwd.bits[p], 0);
            } else {
                assert!(r.depth[p] > 0.0 && r.depth[p] <= 1.0);
            }
        }
        assert!(sky > 0);
    }

    #[test]
    fn bad_inputs_are_errors() {
        let scene = builtin("lab", Variant::Static).unwrap();
        let cam = camera(&scene, 0, 8, 8);
        assert!(matches!(
            render_server(&scene, &cam, 0.0, DT, 17, 1),
            Err(SceneError::BadSubframes { subframes: 17 })
        ));
        for n in [0, MAX_SAMPLES + 1] {
            assert!(matches!(
                render_server(&scene, &cam, 0.0, DT, 4, n),
                Err(SceneError::BadSamples { samples, .. }) if samples == n
            ));
            assert!(matches!(
                render_ground_truth(&scene, &cam, 0.0, n),
                Err(SceneError::BadSamples { .. })
            ));
        }
        let mut bad = cam;
        bad.view = Mat4([[0.0; 4]; 4]);
        assert!(matches!(
            render_ground_truth(&scene, &bad, 0.0, 1),
            Err(SceneError::BadCamera { .. })
        ));
    }

    /// Supersampling filters colour only: for every sample count the ground truth at the server
    /// camera and time is the server colour byte for byte, and depth, motion and the shadow
    /// bitfields are bit-identical to the point-sampled render (they stay at the pixel centre).
    #[test]
    fn sample_count_keeps_the_identity_and_leaves_geometry_alone() {
        for (name, k) in [("courtyard", 10), ("lab", 20), ("colonnade", 5)] {
            let scene = builtin(name, Variant::Dynamic).unwrap();
            let cam = camera(&scene, k, 48, 27);
            let t = k as f64 * DT;
            let renders: Vec<ServerBuffers> = [1, 2, 3]
                .iter()
                .map(|&n| {
                    let r = render_server(&scene, &cam, t, DT, S, n).unwrap();
                    assert_eq!(
                        render_ground_truth(&scene, &cam, t, n).unwrap(),
                        r.color,
                        "{name}, {n}×{n}: the ground truth at the server camera is not the colour"
                    );
                    r
                })
                .collect();
            let point = &renders[0];
            for (r, n) in renders[1..].iter().zip(2..) {
                assert_ne!(r.color, point.color, "{name}: {n}×{n} filters nothing");
                assert_eq!(f32_bits(&r.depth), f32_bits(&point.depth), "{name} {n}");
                assert_eq!(
                    f32_bits(&r.motion_fwd),
                    f32_bits(&point.motion_fwd),
                    "{name} {n}"
                );
                assert_eq!(
                    f32_bits(&r.motion_bwd),
                    f32_bits(&point.motion_bwd),
                    "{name} {n}"
                );
                for (a, b) in [
                    (&r.shadow_fwd, &point.shadow_fwd),
                    (&r.shadow_bwd, &point.shadow_bwd),
                ] {
                    assert_eq!(a.bits, b.bits, "{name} {n}");
                    // S_min/S_max are colours (filtered), but present exactly where the bits are.
                    for p in 0..a.bits.len() {
                        let (mn, mx) = (&a.s_min[3 * p..3 * p + 3], &a.s_max[3 * p..3 * p + 3]);
                        let (pmn, pmx) = (&b.s_min[3 * p..3 * p + 3], &b.s_max[3 * p..3 * p + 3]);
                        assert_eq!(mn == [0; 3], pmn == [0; 3], "{name} {n} pixel {p}");
                        assert_eq!(mx == [0; 3], pmx == [0; 3], "{name} {n} pixel {p}");
                    }
                }
            }
        }
    }

    /// Where a pixel's whole footprint lies on one flat, one-colour surface, the supersampled
    /// colour is the point-sampled one: the filter blurs texture, it does not shift or darken
    /// colour. Every material is made one colour (`uv_scale` 0 puts every point at uv (0, 0),
    /// inside a grout line) and matte, the scene static; the pixels compared are those whose
    /// `n×n` sub-sample rays all hit the same face of the same box or quad.
    #[test]
    fn supersampled_flat_colour_equals_the_point_sample() {
        let mut scene = builtin("courtyard", Variant::Static).unwrap();
        for o in &mut scene.objects {
            o.material = Material::matte(
                crate::material::Pattern::Tiles,
                [0.2, 0.3, 0.4],
                [0.55, 0.45, 0.35],
                0.0,
                0,
            );
        }
        let (w, h, t) = (64, 36, 0.4);
        let cam = camera(&scene, 4, w, h);
        let rays = Rays::new(&cam, "test").unwrap();
        let snap = scene.at(t);
        let point = render_ground_truth(&scene, &cam, t, 1).unwrap();
        let mut flat = 0;
        for n in [2, 3, 4] {
            let fine = render_ground_truth(&scene, &cam, t, n).unwrap();
            for j in 0..h {
                for i in 0..w {
                    let c = sample(&snap, &rays, i, j, false);
                    let Some(o) = c.obj else { continue };
                    let planar = matches!(
                        scene.objects[o].shape,
                        Shape::Cuboid { .. } | Shape::Quad { .. }
                    );
                    let one_face = (0..n * n).all(|q| {
                        let s =
                            sample_ray(&snap, &rays, rays.sub_ray(i, j, q % n, q / n, n), false);
                        s.obj == c.obj && s.face == c.face
                    });
                    if !planar || !one_face {
                        continue;
                    }
                    flat += 1;
                    let p = 3 * (j * w + i);
                    assert_eq!(fine[p..p + 3], point[p..p + 3], "{n}×{n} at pixel {i},{j}");
                }
            }
        }
        assert!(flat > 1000, "only {flat} flat pixels compared");
    }
}
