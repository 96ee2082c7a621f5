//! The server-buffer pass ([`render_server`]): every buffer of one camera at one time, that is
//! colour, depth, the motion of the material point carried to `t ± Δ`, and the dynamic-shadow
//! bitfields with their `S_min`/`S_max` colours, rendered in blocks of rows.

use rayon::prelude::*;
use reproj_core::{Camera, CameraBuffers};

use super::{
    camera_rays, check_samples, check_time, footprint, material, mean_rgb8, pixel_color,
    sample_ray, EyeTiles, Needs, Sample, ServerBuffers, SubRays, SubSample, BLOCK_ROWS,
};
use crate::error::{Result, SceneError};
use crate::math::{normalize, V3};
use crate::scene::{shadow_fraction, Occluders, Scene, Snapshot, Variant};
use crate::shape::Shape;

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
/// pixel's colour sub-samples `fp` on the centre's surface at the extreme levels. `still`: for a
/// point on a still object under a still light, the shadow rays that still objects block (the
/// same at every instant) and the moving casters that may shadow it at some instant, so that
/// only those are traced per subframe.
fn shadow_field(
    key: &Snapshot<'_>,
    subs: &[Snapshot<'_>],
    s: &Sample,
    fp: &[SubSample],
    still: Option<(u32, &[usize])>,
) -> (u32, [u8; 3], [u8; 3]) {
    let (Some(obj), Some(m)) = (s.obj, material(key, s)) else {
        return (0, [0; 3], [0; 3]);
    };
    let l0 = quantise(s.shadow);
    let (mut bits, mut lmin, mut lmax) = (l0, l0, l0);
    for (j, sub) in subs.iter().enumerate() {
        let (xj, nj) = carry(key, sub, obj, s.face, s.x, s.n_obj, s.normal);
        let level = quantise(match still {
            Some((known, [])) => shadow_fraction(known),
            Some((known, movers)) => {
                let near = Occluders::Moving(movers);
                shadow_fraction(sub.blocked_rays(obj, xj, nj, near, Some(known)))
            }
            None => sub.shadow(obj, xj, nj),
        });
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
                key.shade(m, p.s.albedo, p.s.normal, p.s.dir, l as f64 / 3.0)
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
/// or its matrices cannot be inverted; [`SceneError::BadTime`] when `t` or `interval` is not
/// finite, or an object of the scene is not at a finite position at `t` or `t ± interval`;
/// the errors of [`Scene::check`].
///
/// [`default_samples`]: super::default_samples
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
    let rays = camera_rays(camera, "server")?;
    scene.check()?;
    check_time(scene, "t", t)?;
    if !interval.is_finite() {
        return Err(SceneError::BadTime {
            what: "interval".into(),
            value: interval,
            expected: "expected a finite number of seconds".into(),
        });
    }
    check_time(scene, "t + interval", t + interval)?;
    check_time(scene, "t - interval", t - interval)?;
    let (w, h) = (camera.width, camera.height);
    let key = scene.at(t);
    let eye = EyeTiles::new(&key, camera, &rays);
    let (next, prev) = (scene.at(t + interval), scene.at(t - interval));
    let step = interval / subframes as f64;
    let fwd: Vec<Snapshot<'_>> = (1..subframes)
        .map(|j| scene.at(t + step * j as f64))
        .collect();
    let bwd: Vec<Snapshot<'_>> = (1..subframes)
        .map(|j| scene.at(t - step * j as f64))
        .collect();
    // With the light the same at every subframe, a point on a still object casts the same shadow
    // rays at every instant, and the still objects block the same ones (see
    // `Snapshot::blocked_rays`): they are traced once per pixel instead of once per instant. The
    // moving casters that may shadow the point at some instant are found once per pixel too,
    // from spheres around their bounding spheres at all of them (`Snapshot::movers_near`).
    let others: Vec<&Snapshot<'_>> = fwd.iter().chain(&bwd).collect();
    let swept = (scene.variant == Variant::Dynamic && others.iter().all(|s| key.same_light(s)))
        .then(|| key.swept_casters(&others));
    let (centres, grid) = (SubRays::new(&rays, 1), SubRays::new(&rays, n));
    let blocks: Vec<CameraBuffers> = (0..h.div_ceil(BLOCK_ROWS))
        .into_par_iter()
        .map(|b| {
            let rows = BLOCK_ROWS.min(h - b * BLOCK_ROWS);
            let mut blk = CameraBuffers::zeroed(w, rows);
            let mut fp = Vec::with_capacity(n * n);
            let mut movers = Vec::new();
            for r in 0..rows {
                for i in 0..w {
                    let k = r * w + i;
                    let j = b * BLOCK_ROWS + r;
                    let tile = eye.as_ref().map(|e| e.tile((i, j)));
                    let centre = Needs::centre(false, n);
                    let mut s = sample_ray(
                        &key,
                        &rays,
                        centres.ray((i, j), 0, 0),
                        centre,
                        tile.as_ref(),
                    );
                    let mut still = None;
                    if let Some(obj) = s.obj {
                        let (x, n) = (s.x, s.normal);
                        s.shadow = if let (Some(swept), false) = (&swept, scene.moves(obj)) {
                            let known = key.blocked_rays(obj, x, n, Occluders::Still, None);
                            key.movers_near(swept, x, &mut movers);
                            still = Some(known);
                            shadow_fraction(if movers.is_empty() {
                                known
                            } else {
                                let near = Occluders::Moving(&movers);
                                key.blocked_rays(obj, x, n, near, Some(known))
                            })
                        } else {
                            key.shadow(obj, x, n)
                        };
                    }
                    footprint(&key, &grid, tile.as_ref(), (i, j), &s, &mut fp);
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
                    for (subs, sb) in [(&fwd, &mut blk.shadow_fwd), (&bwd, &mut blk.shadow_bwd)] {
                        let (bf, mn, mx) =
                            shadow_field(&key, subs, &s, &fp, still.map(|k| (k, &movers[..])));
                        sb.bits[k] = bf;
                        sb.s_min[3 * k..3 * k + 3].copy_from_slice(&mn);
                        sb.s_max[3 * k..3 * k + 3].copy_from_slice(&mx);
                    }
                }
            }
            blk
        })
        .collect();
    Ok(ServerBuffers {
        view: camera.view,
        proj: camera.proj,
        buffers: CameraBuffers::from_row_blocks(w, h, blocks),
    })
}
