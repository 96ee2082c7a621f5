//! A small analytic scene: the fixture of the tests, the benchmarks, the Python example and the
//! Python tests.
//!
//! Everything is ray cast analytically in `f64`, one ray through each pixel centre, so every buffer
//! is exactly consistent with every other: the depth unprojects to the point whose colour is
//! stored, the motion moves that material point to where the scene puts it at `t ± Δ`, and the
//! ground truth at a server camera and time is the server colour, byte for byte.
//!
//! The scene (world: +y up, metres; the cameras of [`head_pose`] stand near `z = 2.5` and look
//! along −z):
//! - a back wall, the plane `z = −6` for `x ∈ [−7, 7]`, `y ∈ [−1, 4]`;
//! - a floor, the plane `y = −1` for `x ∈ [−7, 7]`, `z ∈ [−6, 4]`;
//! - a sphere of radius 0.6 centred at `(2 sin(0.75 t), 0.6, −3)`, so it crosses the view at up to
//!   1.5 m/s, spinning at 4 rad/s about a tilted axis so that its surface texture moves too;
//! - an axis-aligned cube of half-side 0.3 at `(1.8, −0.3 + 0.35 sin(3 t), −1.5)`, bobbing up and
//!   down at up to 1.05 m/s;
//! - a constant sky colour wherever nothing is hit, at `Z = 0` (the far plane) with zero motion.
//!
//! Every surface carries a procedural texture (a checker, fine stripes and hashed per-cell noise) so
//! that resampling errors are visible. Shading is Lambert under one directional light of angular
//! radius [`LIGHT_RADIUS`] plus ambient. The sphere and the cube cast soft shadows on everything
//! else: the sphere's occlusion is the analytic overlap of its angular disc with the light's disc,
//! the cube's is the fraction of 32 fixed rays over the light's disc that it blocks. With
//! `dynamic = false` both objects stay where they are at `t = 0` and nothing moves.

use std::f64::consts::PI;
use std::sync::OnceLock;

use rayon::prelude::*;

use crate::camera::{Camera, Mat4, Rays};
use crate::frame::FrameView;
pub use crate::frame::{CameraBuffers, ShadowBuffers};

/// Near plane of every camera of the rig (metres).
pub const NEAR: f64 = 0.1;
/// Far plane of every camera of the rig (metres). Finite, so the sky unprojects to it.
pub const FAR: f64 = 100.0;
/// Angular radius of the light's disc (radians); sets the width of the penumbrae.
pub const LIGHT_RADIUS: f64 = 0.05;
/// Colour of every pixel where no surface is hit.
pub const SKY: [u8; 3] = [150, 190, 230];

/// Rows per rayon task. Whole rows keep each task's writes contiguous; 16 rows are enough work
/// per task (every pixel casts up to `2S − 1` shadow queries) to hide rayon's overhead, and the
/// blocks are concatenated in order, so the result does not depend on the thread count.
const BLOCK_ROWS: usize = 16;
const AMBIENT: f64 = 0.25;
const DIFFUSE: f64 = 0.85;
const SPHERE_RADIUS: f64 = 0.6;
const SPHERE_SPIN: f64 = 4.0;
const BOX_HALF: f64 = 0.3;
const BOX_SAMPLES: usize = 32;
const WALL_Z: f64 = -6.0;
const FLOOR_Y: f64 = -1.0;

type V3 = [f64; 3];

#[inline(always)]
fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline(always)]
fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline(always)]
fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline(always)]
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline(always)]
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline(always)]
fn normalize(a: V3) -> V3 {
    scale(a, 1.0 / dot(a, a).sqrt())
}

/// Unit vector toward the light: from behind the camera, above and to the left, so that shadows
/// fall back and to the right onto the wall and the floor.
fn light_dir() -> V3 {
    static L: OnceLock<V3> = OnceLock::new();
    *L.get_or_init(|| normalize([-0.6, 0.45, 1.0]))
}

/// `(sin, cos)` of [`LIGHT_RADIUS`], computed once (it sits in the hottest test).
fn light_radius_sin_cos() -> (f64, f64) {
    static SC: OnceLock<(f64, f64)> = OnceLock::new();
    *SC.get_or_init(|| LIGHT_RADIUS.sin_cos())
}

/// The sphere's spin axis (unit).
fn spin_axis() -> V3 {
    normalize([0.25, 1.0, 0.15])
}

/// Rotation of `v` by `angle` about the unit `axis` (Rodrigues).
fn rotate(v: V3, axis: V3, angle: f64) -> V3 {
    let (s, c) = angle.sin_cos();
    let kv = cross(axis, v);
    let kd = dot(axis, v) * (1.0 - c);
    [
        v[0] * c + kv[0] * s + axis[0] * kd,
        v[1] * c + kv[1] * s + axis[1] * kd,
        v[2] * c + kv[2] * s + axis[2] * kd,
    ]
}

/// Deterministic hash of an integer cell to `[0, 1)` (splitmix64 finaliser). Public because the
/// reference renderer (reproj-scene) draws its textures and head-path deviations from the same
/// values, so that its rig matches this scene's.
pub fn hash(a: i64, b: i64, salt: u64) -> f64 {
    let mut x = (a as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (b as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ salt.wrapping_mul(0x1656_67B1_9E37_79F9);
    x ^= x >> 30;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 27;
    x = x.wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 31;
    (x >> 11) as f64 / (1u64 << 53) as f64
}

/// Checker parity of `(u, v)` at cell size `cell`.
fn checker(u: f64, v: f64, cell: f64) -> bool {
    ((u / cell).floor() as i64 + (v / cell).floor() as i64).rem_euclid(2) == 0
}

/// A texture's constants: colours `a` and `b`, checker cell, stripe period, noise cell.
type Texture = (V3, V3, f64, f64, f64);

/// The textures of the wall, floor, sphere and cube.
const WALL: Texture = ([0.92, 0.9, 0.82], [0.45, 0.5, 0.62], 0.5, 0.05, 0.1);
const FLOOR: Texture = ([0.95, 0.95, 0.95], [0.35, 0.55, 0.35], 0.5, 0.04, 0.125);
const SPHERE: Texture = ([0.95, 0.3, 0.2], [0.98, 0.85, 0.3], 1.0, 0.125, 0.25);
const CUBE: Texture = ([0.25, 0.3, 0.85], [0.9, 0.9, 0.95], 0.1, 0.025, 0.05);

/// A texture: two colours on a checker of `cell`, fine stripes of period `stripe` along `u + v`,
/// and a hashed brightness per `noise` cell.
fn texture(u: f64, v: f64, (a, b, cell, stripe, noise): Texture, salt: u64) -> V3 {
    let base = if checker(u, v, cell) { a } else { b };
    let st = if ((u + v) / stripe).floor() as i64 & 1 == 0 {
        1.0
    } else {
        0.82
    };
    let n = hash((u / noise).floor() as i64, (v / noise).floor() as i64, salt);
    scale(base, st * (0.8 + 0.2 * n))
}

/// What a ray hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Obj {
    Sky,
    Wall,
    Floor,
    Sphere,
    Cube,
}

impl Obj {
    fn moves(self) -> bool {
        matches!(self, Obj::Sphere | Obj::Cube)
    }
}

/// Where the moving objects are at one instant.
#[derive(Debug, Clone, Copy)]
struct Pose {
    sphere: V3,
    spin: f64,
    cube: V3,
}

/// The analytic scene (see the module docs).
#[derive(Debug, Clone)]
pub struct SyntheticScene {
    /// Whether the sphere and the cube move; `false` freezes them at their `t = 0` pose.
    pub dynamic: bool,
}

/// Directions of the cube's shadow rays over the light's disc: a Vogel spiral, fixed once, so the
/// cube's shadow is soft yet deterministic.
fn light_samples() -> &'static [V3; BOX_SAMPLES] {
    static SAMPLES: OnceLock<[V3; BOX_SAMPLES]> = OnceLock::new();
    SAMPLES.get_or_init(|| {
        let l = light_dir();
        let e1 = normalize(cross(l, [0.0, 1.0, 0.0]));
        let e2 = cross(e1, l);
        let golden = PI * (3.0 - 5f64.sqrt());
        let mut out = [[0.0; 3]; BOX_SAMPLES];
        for (k, o) in out.iter_mut().enumerate() {
            let r = LIGHT_RADIUS * ((k as f64 + 0.5) / BOX_SAMPLES as f64).sqrt();
            let (s, c) = (k as f64 * golden).sin_cos();
            *o = normalize(add(l, add(scale(e1, r * c), scale(e2, r * s))));
        }
        out
    })
}

/// Whether a sphere of `radius` at offset `v` (length `dist > radius`) from a receiver is certainly
/// clear of the light's disc as seen from it: the angle `γ` between `v` and the light exceeds the
/// sum of the two angular radii. Tested on cosines, without `acos`/`asin`, because almost every
/// shadow query ends here; the margin sends borderline cases to the exact test, so the result is
/// the same as without this shortcut.
fn misses_light(v: V3, dist: f64, radius: f64, l: V3) -> bool {
    let cos_gamma = dot(v, l) / dist;
    let sin_b = radius / dist;
    let cos_b = (1.0 - sin_b * sin_b).max(0.0).sqrt();
    let (sin_a, cos_a) = light_radius_sin_cos();
    cos_gamma < cos_a * cos_b - sin_a * sin_b - 1e-9
}

/// Area of the intersection of two discs of radii `a`, `b` whose centres are `d` apart.
fn disc_overlap(a: f64, b: f64, d: f64) -> f64 {
    if d >= a + b {
        return 0.0;
    }
    if d <= (a - b).abs() {
        let m = a.min(b);
        return PI * m * m;
    }
    let ca = ((d * d + a * a - b * b) / (2.0 * d * a)).clamp(-1.0, 1.0);
    let cb = ((d * d + b * b - a * a) / (2.0 * d * b)).clamp(-1.0, 1.0);
    let k = ((-d + a + b) * (d + a - b) * (d - a + b) * (d + a + b)).max(0.0);
    a * a * ca.acos() + b * b * cb.acos() - 0.5 * k.sqrt()
}

/// Entry and exit parameters of the ray `o + s·d` through the cube centred at `c`, if it hits.
fn slab(o: V3, d: V3, c: V3) -> Option<(f64, f64, usize)> {
    let (mut t0, mut t1, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
    for k in 0..3 {
        let lo = c[k] - BOX_HALF - o[k];
        let hi = c[k] + BOX_HALF - o[k];
        if d[k] == 0.0 {
            if lo > 0.0 || hi < 0.0 {
                return None;
            }
            continue;
        }
        let (mut a, mut b) = (lo / d[k], hi / d[k]);
        if a > b {
            std::mem::swap(&mut a, &mut b);
        }
        if a > t0 {
            t0 = a;
            axis = k;
        }
        t1 = t1.min(b);
    }
    (t0 <= t1).then_some((t0, t1, axis))
}

/// One pixel's key-frame sample: what it sees and how it is lit.
struct Sample {
    obj: Obj,
    x: V3,
    albedo: V3,
    normal: V3,
    shadow: f64,
}

impl SyntheticScene {
    /// A scene; `dynamic = false` keeps every object still.
    pub fn new(dynamic: bool) -> Self {
        SyntheticScene { dynamic }
    }

    /// Where the moving objects are at time `t` (their `t = 0` pose when static).
    fn pose(&self, t: f64) -> Pose {
        let t = if self.dynamic { t } else { 0.0 };
        Pose {
            sphere: [2.0 * (0.75 * t).sin(), 0.6, -3.0],
            spin: SPHERE_SPIN * t,
            cube: [1.8, -0.3 + 0.35 * (3.0 * t).sin(), -1.5],
        }
    }

    /// The nearest surface along `o + s·d` with `s ≥ 1` (beyond the near plane).
    fn trace(&self, pose: &Pose, o: V3, d: V3) -> (Obj, f64) {
        let mut best = (Obj::Sky, f64::INFINITY);
        if d[2] != 0.0 {
            let s = (WALL_Z - o[2]) / d[2];
            let p = add(o, scale(d, s));
            if s >= 1.0 && s < best.1 && p[0].abs() <= 7.0 && (FLOOR_Y..=4.0).contains(&p[1]) {
                best = (Obj::Wall, s);
            }
        }
        if d[1] != 0.0 {
            let s = (FLOOR_Y - o[1]) / d[1];
            let p = add(o, scale(d, s));
            if s >= 1.0 && s < best.1 && p[0].abs() <= 7.0 && (WALL_Z..=4.0).contains(&p[2]) {
                best = (Obj::Floor, s);
            }
        }
        {
            let oc = sub(o, pose.sphere);
            let a = dot(d, d);
            let b = dot(d, oc);
            let c = dot(oc, oc) - SPHERE_RADIUS * SPHERE_RADIUS;
            let disc = b * b - a * c;
            if disc >= 0.0 {
                // The front surface only: a sphere cut by the near plane is not drawn.
                let s = (-b - disc.sqrt()) / a;
                if s >= 1.0 && s < best.1 {
                    best = (Obj::Sphere, s);
                }
            }
        }
        if let Some((s, _, _)) = slab(o, d, pose.cube) {
            if s >= 1.0 && s < best.1 {
                best = (Obj::Cube, s);
            }
        }
        best
    }

    /// Albedo (linear, `[0,1]`) and unit normal of `obj` at `x`.
    fn surface(&self, obj: Obj, x: V3, pose: &Pose) -> (V3, V3) {
        match obj {
            Obj::Sky => ([0.0; 3], [0.0, 0.0, 1.0]),
            Obj::Wall => (texture(x[0], x[1], WALL, 1), [0.0, 0.0, 1.0]),
            Obj::Floor => (texture(x[0], x[2], FLOOR, 2), [0.0, 1.0, 0.0]),
            Obj::Sphere => {
                let n = normalize(sub(x, pose.sphere));
                // Texture in the sphere's own frame, so that it turns with the spin.
                let u = rotate(n, spin_axis(), -pose.spin);
                let lon = u[2].atan2(u[0]) / (2.0 * PI) + 0.5;
                let lat = u[1].clamp(-1.0, 1.0).asin() / PI + 0.5;
                let alb = texture(lon * 16.0, lat * 8.0, SPHERE, 3);
                (alb, n)
            }
            Obj::Cube => {
                let l = sub(x, pose.cube);
                let k = (0..3)
                    .max_by(|&a, &b| l[a].abs().total_cmp(&l[b].abs()))
                    .unwrap_or(0);
                let mut n = [0.0; 3];
                n[k] = l[k].signum();
                // The two in-face coordinates, in the cube's frame (it moves with the cube).
                let (u, v) = (l[(k + 1) % 3], l[(k + 2) % 3]);
                let alb = texture(u, v, CUBE, 4 + k as u64);
                (alb, n)
            }
        }
    }

    /// Fraction of the light's disc that the moving objects hide from point `x` on `obj`
    /// (0 lit … 1 fully shadowed). An object does not shadow itself; its Lambert term already
    /// darkens the side turned away from the light.
    fn shadow(&self, obj: Obj, x: V3, pose: &Pose) -> f64 {
        if obj == Obj::Sky {
            return 0.0;
        }
        let l = light_dir();
        let mut lit = 1.0;
        if obj != Obj::Sphere {
            let v = sub(pose.sphere, x);
            let dist = dot(v, v).sqrt();
            let f = if dist <= SPHERE_RADIUS {
                1.0
            } else if misses_light(v, dist, SPHERE_RADIUS, l) {
                0.0
            } else {
                let b = (SPHERE_RADIUS / dist).asin();
                let gamma = (dot(v, l) / dist).clamp(-1.0, 1.0).acos();
                let a = LIGHT_RADIUS;
                (disc_overlap(a, b, gamma) / (PI * a * a)).clamp(0.0, 1.0)
            };
            lit *= 1.0 - f;
        }
        if obj != Obj::Cube {
            let v = sub(pose.cube, x);
            let dist = dot(v, v).sqrt();
            let bound = BOX_HALF * 3f64.sqrt();
            if dist <= bound || !misses_light(v, dist, bound, l) {
                let hits = light_samples()
                    .iter()
                    .filter(|&&d| slab(x, d, pose.cube).is_some_and(|(_, t1, _)| t1 > 0.0))
                    .count();
                lit *= 1.0 - hits as f64 / BOX_SAMPLES as f64;
            }
        }
        1.0 - lit
    }

    /// Lambert + ambient with shadow fraction `f`, rounded to RGB8.
    fn shade(albedo: V3, normal: V3, f: f64) -> [u8; 3] {
        let k = AMBIENT + DIFFUSE * (1.0 - f) * dot(normal, light_dir()).max(0.0);
        albedo.map(|a| (a * k * 255.0).round().clamp(0.0, 255.0) as u8)
    }

    /// Where the material point at `x` on `obj` at time `from` is at time `to`. Static geometry
    /// (and everything in the static variant) returns `x` itself, so its motion is exactly zero.
    #[cfg(test)]
    fn carry(&self, obj: Obj, x: V3, from: f64, to: f64) -> V3 {
        self.carry_between(obj, x, &self.pose(from), &self.pose(to))
    }

    /// Where the material point at `x` on `obj` at pose `p0` is at pose `p1` (the tests' `carry`
    /// between two precomputed poses).
    fn carry_between(&self, obj: Obj, x: V3, p0: &Pose, p1: &Pose) -> V3 {
        if !self.dynamic || !obj.moves() {
            return x;
        }
        match obj {
            Obj::Sphere => add(
                p1.sphere,
                rotate(sub(x, p0.sphere), spin_axis(), p1.spin - p0.spin),
            ),
            Obj::Cube => add(x, sub(p1.cube, p0.cube)),
            _ => x,
        }
    }

    /// The key sample of pixel `(i, j)` at time `t`.
    fn sample(&self, rays: &Rays, pose: &Pose, i: usize, j: usize) -> Sample {
        let d = rays.ray(i, j);
        let (obj, s) = self.trace(pose, rays.origin, d);
        if obj == Obj::Sky {
            return Sample {
                obj,
                x: [0.0; 3],
                albedo: [0.0; 3],
                normal: [0.0; 3],
                shadow: 0.0,
            };
        }
        let x = add(rays.origin, scale(d, s));
        let (albedo, normal) = self.surface(obj, x, pose);
        let shadow = self.shadow(obj, x, pose);
        Sample {
            obj,
            x,
            albedo,
            normal,
            shadow,
        }
    }

    fn key_color(s: &Sample) -> [u8; 3] {
        if s.obj == Obj::Sky {
            SKY
        } else {
            Self::shade(s.albedo, s.normal, s.shadow)
        }
    }

    /// Shadow bitfield and `S_min`/`S_max` of a sample following its material point over the
    /// subframes whose poses are `poses` (`poses[0]` is the key frame's).
    fn shadow_field(&self, s: &Sample, poses: &[Pose]) -> (u32, [u8; 3], [u8; 3]) {
        if s.obj == Obj::Sky {
            return (0, [0; 3], [0; 3]);
        }
        let quantise = |f: f64| (f * 3.0).round().clamp(0.0, 3.0) as u32;
        let mut bits = 0u32;
        let l0 = quantise(s.shadow);
        let (mut lmin, mut lmax) = (l0, l0);
        for (j, pj) in poses.iter().enumerate() {
            let level = if j == 0 {
                l0
            } else {
                let xj = self.carry_between(s.obj, s.x, &poses[0], pj);
                quantise(self.shadow(s.obj, xj, pj))
            };
            bits |= level << (2 * j);
            lmin = lmin.min(level);
            lmax = lmax.max(level);
        }
        if lmin == lmax {
            return (0, [0; 3], [0; 3]);
        }
        // The extremes keep the key frame's albedo and normal: only the shadow is re-applied, as
        // the client's eqs. 9–11 only interpolate the shadow.
        let at = |l: u32| Self::shade(s.albedo, s.normal, l as f64 / 3.0);
        let smin = if lmin == l0 { [0; 3] } else { at(lmin) };
        let smax = if lmax == l0 { [0; 3] } else { at(lmax) };
        (bits, smin, smax)
    }

    /// Server buffers of `camera` at `time` (seconds); `interval` = Δ = 1/f_s; `subframes` =
    /// S = f_d/f_s.
    ///
    /// The motion is expressed in this camera's NDC with the camera held fixed (DESIGN.md), so the
    /// same rig camera one server frame earlier or later is not needed. A camera whose matrices
    /// cannot be inverted sees only sky.
    ///
    /// # Panics
    /// When `subframes` is not in `1..=16` (2 bits each in a `u32`).
    pub fn render_server(
        &self,
        camera: &Camera,
        time: f64,
        interval: f64,
        subframes: usize,
    ) -> CameraBuffers {
        assert!(
            (1..=16).contains(&subframes),
            "subframes must be in 1..=16, got {subframes}"
        );
        let (w, h) = (camera.width, camera.height);
        // None when the camera's matrices cannot be inverted: then everything is sky.
        let rays = Rays::new(camera).ok();
        let pose = self.pose(time);
        // Poses are the same for every pixel: computed once, not per pixel and subframe.
        let step = interval / subframes as f64;
        let poses_fwd: Vec<Pose> = (0..subframes)
            .map(|j| self.pose(time + step * j as f64))
            .collect();
        let poses_bwd: Vec<Pose> = (0..subframes)
            .map(|j| self.pose(time - step * j as f64))
            .collect();
        let (pose_next, pose_prev) = (self.pose(time + interval), self.pose(time - interval));
        let blocks: Vec<CameraBuffers> = (0..h.div_ceil(BLOCK_ROWS))
            .into_par_iter()
            .map(|b| {
                let rows = BLOCK_ROWS.min(h - b * BLOCK_ROWS);
                let mut blk = CameraBuffers::zeroed(w, rows);
                for r in 0..rows {
                    for i in 0..w {
                        let k = r * w + i;
                        let Some(rays) = rays.as_ref() else {
                            blk.color[3 * k..3 * k + 3].copy_from_slice(&SKY);
                            continue;
                        };
                        let s = self.sample(rays, &pose, i, b * BLOCK_ROWS + r);
                        blk.color[3 * k..3 * k + 3].copy_from_slice(&Self::key_color(&s));
                        if s.obj == Obj::Sky {
                            continue; // Z = 0, zero motion, no dynamic shadow.
                        }
                        let p = rays.project(s.x);
                        blk.depth[k] = p[2] as f32;
                        if self.dynamic && s.obj.moves() {
                            let pf =
                                rays.project(self.carry_between(s.obj, s.x, &pose, &pose_next));
                            let pb =
                                rays.project(self.carry_between(s.obj, s.x, &pose, &pose_prev));
                            for c in 0..3 {
                                blk.motion_fwd[3 * k + c] = (pf[c] - p[c]) as f32;
                                blk.motion_bwd[3 * k + c] = (pb[c] - p[c]) as f32;
                            }
                        }
                        if !self.dynamic {
                            continue; // Nothing moves, so no shadow changes: all zero.
                        }
                        let (bf, minf, maxf) = self.shadow_field(&s, &poses_fwd);
                        let (bb, minb, maxb) = self.shadow_field(&s, &poses_bwd);
                        blk.shadow_fwd.bits[k] = bf;
                        blk.shadow_bwd.bits[k] = bb;
                        blk.shadow_fwd.s_min[3 * k..3 * k + 3].copy_from_slice(&minf);
                        blk.shadow_fwd.s_max[3 * k..3 * k + 3].copy_from_slice(&maxf);
                        blk.shadow_bwd.s_min[3 * k..3 * k + 3].copy_from_slice(&minb);
                        blk.shadow_bwd.s_max[3 * k..3 * k + 3].copy_from_slice(&maxb);
                    }
                }
                blk
            })
            .collect();
        CameraBuffers::from_row_blocks(w, h, blocks)
    }

    /// Ground-truth colour (`H·W·3` RGB8) at the client `camera` and `time`: the same shading as
    /// the server colour, so at a server camera and time it equals that colour exactly.
    pub fn render_ground_truth(&self, camera: &Camera, time: f64) -> Vec<u8> {
        let (w, h) = (camera.width, camera.height);
        // None when the camera's matrices cannot be inverted: then everything is sky.
        let rays = Rays::new(camera).ok();
        let pose = self.pose(time);
        let mut out = vec![0u8; 3 * w * h];
        if w == 0 {
            return out;
        }
        out.par_chunks_mut(3 * w * BLOCK_ROWS)
            .enumerate()
            .for_each(|(b, chunk)| {
                for (k, px) in chunk.chunks_exact_mut(3).enumerate() {
                    let (i, j) = (k % w, b * BLOCK_ROWS + k / w);
                    let c = match rays.as_ref() {
                        Some(rays) => Self::key_color(&self.sample(rays, &pose, i, j)),
                        None => SKY,
                    };
                    px.copy_from_slice(&c);
                }
            });
        out
    }
}

/// `[[c,0,s],[0,1,0],[−s,0,c]]`: a rotation about +y by `deg` degrees (positive turns −z toward
/// −x, i.e. to the left).
fn yaw(deg: f64) -> Mat4 {
    let (s, c) = deg.to_radians().sin_cos();
    Mat4([
        [c, 0.0, s, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [-s, 0.0, c, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ])
}

fn translate(t: V3) -> Mat4 {
    let mut m = Mat4::IDENTITY;
    for (row, v) in m.0.iter_mut().zip(t) {
        row[3] = v;
    }
    m
}

/// The DESIGN.md rig at a head pose: main camera (60° vertical FOV, `width×height`) looking from
/// `eye` at `target` with +y up, and two auxiliary cameras (80°, half width and height each,
/// rounded down, at least 1), 20 cm left and right of the main camera along its x axis, yawed 10°
/// outward. Returns `(main, [left, right])`; near plane [`NEAR`], far plane [`FAR`].
pub fn rig(eye: [f64; 3], target: [f64; 3], width: usize, height: usize) -> (Camera, [Camera; 2]) {
    let view = Mat4::look_at(eye, target, [0.0, 1.0, 0.0]);
    let aspect = |w: usize, h: usize| w.max(1) as f64 / h.max(1) as f64;
    let main = Camera {
        view,
        proj: Mat4::perspective(60.0, aspect(width, height), NEAR, FAR),
        width,
        height,
    };
    let (aw, ah) = ((width / 2).max(1), (height / 2).max(1));
    let aux_proj = Mat4::perspective(80.0, aspect(aw, ah), NEAR, FAR);
    // Camera-to-world of an auxiliary camera is main · T(±0.2 x) · yaw(±10°) (left turns left);
    // its view matrix is the inverse of that.
    let aux = |side: f64| Camera {
        view: yaw(10.0 * side)
            .mul(&translate([-0.2 * side, 0.0, 0.0]))
            .mul(&view),
        proj: aux_proj,
        width: aw,
        height: ah,
    };
    (main, [aux(-1.0), aux(1.0)])
}

/// A deterministic head path for tests and benchmarks: eye position and look-at target at time
/// `t`. The eye sways sideways by ±0.5 m (at most 0.55 m/s) with a slight bob, near
/// `(0, 0.35, 2.5)`, looking toward the sphere's path at `(0, −0.3, −3)`.
pub fn head_pose(t: f64) -> ([f64; 3], [f64; 3]) {
    let eye = [
        0.5 * (1.1 * t).sin(),
        0.35 + 0.05 * (0.7 * t).sin(),
        2.5 + 0.1 * (0.5 * t).sin(),
    ];
    let target = [0.2 * (0.9 * t).sin(), -0.3, -3.0];
    (eye, target)
}

/// One server frame of the scene: every camera of the [`rig`] at the [`head_pose`] of its time,
/// with its buffers. The fixture the benchmarks, property tests and examples reproject from.
#[derive(Debug, Clone)]
pub struct SyntheticFrame {
    /// Main camera first, then the auxiliary cameras, each with its buffers.
    pub cams: Vec<(Camera, CameraBuffers)>,
}

impl SyntheticFrame {
    /// Renders the frame at time `t` (main camera `width × height`), motion over `interval`
    /// seconds and `subframes` shadow subframes.
    pub fn render(
        scene: &SyntheticScene,
        t: f64,
        width: usize,
        height: usize,
        interval: f64,
        subframes: usize,
    ) -> SyntheticFrame {
        let (eye, target) = head_pose(t);
        let (main, aux) = rig(eye, target, width, height);
        let cams = [main, aux[0], aux[1]]
            .into_iter()
            .map(|c| (c, scene.render_server(&c, t, interval, subframes)))
            .collect();
        SyntheticFrame { cams }
    }

    /// The frame as the older (`forward = true`: forward motion and shadows) or the newer image
    /// of a pair (backward ones).
    pub fn view(&self, forward: bool) -> FrameView<'_> {
        FrameView {
            main: self.cams[0].1.view(self.cams[0].0, forward),
            aux: self.cams[1..]
                .iter()
                .map(|(camera, b)| b.view(*camera, forward))
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests;
