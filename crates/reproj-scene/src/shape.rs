//! Shapes in object space: analytic primitives and triangle meshes with their own BVH.
//!
//! Every intersection is computed in `f64`. A mesh's BVH (obvhs, `f32`) only culls: its boxes are
//! padded so that `f32` rounding can never cull a triangle the `f64` test would hit.

use std::f64::consts::PI;
use std::fmt;
use std::sync::Arc;
use std::time::Duration;

use glam::Vec3A;
use obvhs::aabb::Aabb;
use obvhs::bvh2::builder::build_bvh2;
use obvhs::bvh2::Bvh2;
use obvhs::ray::{Ray, RayHit};
use obvhs::{Boundable, BvhBuildParams};

use crate::math::{add, cross, dot, length, normalize, scale, sub, V3};

/// Where a ray meets a shape, in object space.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LocalHit {
    /// Ray parameter (the ray direction is not normalised; rigid transforms keep it).
    pub t: f64,
    /// Unit outward normal in object space.
    pub normal: V3,
    /// Texture coordinates.
    pub uv: [f64; 2],
    /// Which face or triangle (tests use it to find silhouettes).
    pub face: u32,
}

/// An axis-aligned box `[min, max]` in `f64`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    /// Minimum corner.
    pub min: V3,
    /// Maximum corner.
    pub max: V3,
}

impl Bounds {
    /// The box around `points`.
    pub fn around(points: impl IntoIterator<Item = V3>) -> Bounds {
        let mut b = Bounds {
            min: [f64::INFINITY; 3],
            max: [f64::NEG_INFINITY; 3],
        };
        for p in points {
            for (k, &c) in p.iter().enumerate() {
                b.min[k] = b.min[k].min(c);
                b.max[k] = b.max[k].max(c);
            }
        }
        b
    }

    /// The eight corners.
    pub fn corners(&self) -> [V3; 8] {
        std::array::from_fn(|i| {
            [
                if i & 1 == 0 { self.min[0] } else { self.max[0] },
                if i & 2 == 0 { self.min[1] } else { self.max[1] },
                if i & 4 == 0 { self.min[2] } else { self.max[2] },
            ]
        })
    }

    /// The `f32` box for the BVH, padded outward so `f32` rounding (of the box and of the
    /// `f32` ray–box test) cannot cull what the `f64` intersection would hit.
    pub(crate) fn padded_f32(&self) -> Aabb {
        let ext = (0..3)
            .map(|k| self.min[k].abs().max(self.max[k].abs()))
            .fold(1.0, f64::max);
        let pad = 1e-4 * ext;
        Aabb::new(
            Vec3A::new(
                (self.min[0] - pad) as f32,
                (self.min[1] - pad) as f32,
                (self.min[2] - pad) as f32,
            ),
            Vec3A::new(
                (self.max[0] + pad) as f32,
                (self.max[1] + pad) as f32,
                (self.max[2] + pad) as f32,
            ),
        )
    }

    /// Centre and radius of a sphere that contains the box.
    pub(crate) fn sphere(&self) -> (V3, f64) {
        let c = scale(add(self.min, self.max), 0.5);
        (c, length(sub(self.max, c)))
    }
}

/// A vertex of a triangle mesh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vertex {
    /// Object-space position.
    pub position: V3,
    /// Object-space normal (need not be unit; interpolated and normalised when shading).
    pub normal: V3,
    /// Texture coordinates.
    pub uv: [f64; 2],
}

struct Tri(Aabb);

impl Boundable for Tri {
    fn aabb(&self) -> Aabb {
        self.0
    }
}

/// A triangle mesh with per-vertex normals and UVs and its own BVH in object space. Built once;
/// rigid animation moves the ray, never the mesh, so it is never rebuilt.
pub struct Mesh {
    /// Vertices.
    pub vertices: Vec<Vertex>,
    /// Counter-clockwise (seen from outside) index triples.
    pub triangles: Vec<[u32; 3]>,
    bounds: Bounds,
    bvh: Bvh2,
}

impl fmt::Debug for Mesh {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Mesh")
            .field("vertices", &self.vertices.len())
            .field("triangles", &self.triangles.len())
            .field("bvh_nodes", &self.bvh.nodes.len())
            .finish()
    }
}

impl Mesh {
    /// Builds the mesh and its BVH. Indices out of range are dropped with their triangle.
    pub fn new(vertices: Vec<Vertex>, triangles: Vec<[u32; 3]>) -> Mesh {
        let n = vertices.len() as u32;
        let triangles: Vec<[u32; 3]> = triangles
            .into_iter()
            .filter(|t| t.iter().all(|&i| i < n))
            .collect();
        let prims: Vec<Tri> = triangles
            .iter()
            .map(|t| Tri(Bounds::around(t.map(|i| vertices[i as usize].position)).padded_f32()))
            .collect();
        // medium_build: the meshes are built once per scene, so traversal speed matters more.
        let bvh = build_bvh2(
            &prims,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );
        let bounds = Bounds::around(vertices.iter().map(|v| v.position));
        Mesh {
            vertices,
            triangles,
            bounds,
            bvh,
        }
    }

    /// Object-space bounds.
    pub fn bounds(&self) -> Bounds {
        self.bounds
    }

    pub(crate) fn intersect(&self, o: V3, d: V3, tmin: f64, tmax: f64) -> Option<LocalHit> {
        if self.triangles.is_empty() {
            return None;
        }
        let ray = Ray::new(
            Vec3A::new(o[0] as f32, o[1] as f32, o[2] as f32),
            Vec3A::new(d[0] as f32, d[1] as f32, d[2] as f32),
            0.0,
            f32_above(tmax),
        );
        let mut best: Option<(f64, u32, f64, f64)> = None;
        let mut limit = tmax;
        let mut hit = RayHit::none();
        self.bvh.ray_traverse(ray, &mut hit, |_, id| {
            let tri = self.bvh.primitive_indices[id];
            match self.triangle_hit(tri, o, d, tmin, limit) {
                Some((t, u, v)) => {
                    limit = t;
                    best = Some((t, tri, u, v));
                    f32_above(t)
                }
                None => f32::INFINITY,
            }
        });
        let (t, tri, u, v) = best?;
        let [a, b, c] = self.triangles[tri as usize].map(|i| &self.vertices[i as usize]);
        let w = 1.0 - u - v;
        let mut n = add(
            add(scale(a.normal, w), scale(b.normal, u)),
            scale(c.normal, v),
        );
        if dot(n, n) < 1e-30 {
            n = cross(sub(b.position, a.position), sub(c.position, a.position));
        }
        Some(LocalHit {
            t,
            normal: normalize(n),
            uv: [
                a.uv[0] * w + b.uv[0] * u + c.uv[0] * v,
                a.uv[1] * w + b.uv[1] * u + c.uv[1] * v,
            ],
            face: tri,
        })
    }

    /// Whether anything blocks `o + t·d` for `t > 0` (any hit, stops at the first).
    pub(crate) fn occludes(&self, o: V3, d: V3) -> bool {
        if self.triangles.is_empty() {
            return false;
        }
        let ray = Ray::new(
            Vec3A::new(o[0] as f32, o[1] as f32, o[2] as f32),
            Vec3A::new(d[0] as f32, d[1] as f32, d[2] as f32),
            0.0,
            f32::INFINITY,
        );
        !self.bvh.ray_traverse_miss(ray, |_, id| {
            let tri = self.bvh.primitive_indices[id];
            if self.triangle_hit(tri, o, d, 0.0, f64::INFINITY).is_some() {
                0.0
            } else {
                f32::INFINITY
            }
        })
    }

    /// Möller–Trumbore in `f64`: `(t, u, v)` for `t ∈ (tmin, tmax)`. Both sides count (the meshes
    /// are closed, and open ones are meant to be seen from both sides).
    fn triangle_hit(
        &self,
        tri: u32,
        o: V3,
        d: V3,
        tmin: f64,
        tmax: f64,
    ) -> Option<(f64, f64, f64)> {
        let [a, b, c] = self.triangles[tri as usize].map(|i| self.vertices[i as usize].position);
        let e1 = sub(b, a);
        let e2 = sub(c, a);
        let p = cross(d, e2);
        let det = dot(e1, p);
        if det.abs() < 1e-300 {
            return None;
        }
        let inv = 1.0 / det;
        let s = sub(o, a);
        let u = dot(s, p) * inv;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = cross(s, e1);
        let v = dot(d, q) * inv;
        if v < 0.0 || u + v > 1.0 {
            return None;
        }
        let t = dot(e2, q) * inv;
        (t > tmin && t < tmax).then_some((t, u, v))
    }
}

/// The smallest `f32` strictly above `t` (for `f32` culling bounds that never cut below an `f64`
/// distance); infinity stays infinity.
fn f32_above(t: f64) -> f32 {
    let f = t as f32;
    if !f.is_finite() {
        return f32::INFINITY;
    }
    let g = if f64::from(f) > t {
        f
    } else {
        f32::from_bits(if f >= 0.0 {
            f.to_bits() + 1
        } else {
            f.to_bits() - 1
        })
    };
    g * (1.0 + 4.0 * f32::EPSILON)
}

/// A shape in object space.
#[derive(Debug, Clone)]
pub enum Shape {
    /// A sphere of `radius` centred at the origin; UV = (longitude, latitude) in `[0,1]²`.
    Sphere {
        /// Radius (metres).
        radius: f64,
    },
    /// An axis-aligned box `[min, max]`; UV = the two in-face coordinates (metres).
    Cuboid {
        /// Minimum corner.
        min: V3,
        /// Maximum corner.
        max: V3,
    },
    /// A capsule: the segment `a–b` swept by a sphere of `radius`; UV = (angle around the axis in
    /// `[0,1]`, metres along it).
    Capsule {
        /// One end of the axis.
        a: V3,
        /// The other end.
        b: V3,
        /// Radius.
        radius: f64,
    },
    /// The rectangle `y = 0`, `|x| ≤ half[0]`, `|z| ≤ half[1]`, visible from both sides;
    /// UV = `(x, z)` in metres.
    Quad {
        /// Half extents along x and z.
        half: [f64; 2],
    },
    /// A triangle mesh (shared between instances).
    Mesh(Arc<Mesh>),
    /// A mesh node of a glTF model: textured, possibly skinned (its geometry may change with
    /// time; a scene snapshot poses it, see [`crate::gltf`]).
    Gltf(Arc<crate::gltf::GltfShape>),
}

impl Shape {
    /// Object-space bounds.
    pub fn bounds(&self) -> Bounds {
        match self {
            Shape::Sphere { radius } => Bounds {
                min: [-radius; 3],
                max: [*radius; 3],
            },
            Shape::Cuboid { min, max } => Bounds {
                min: *min,
                max: *max,
            },
            Shape::Capsule { a, b, radius } => {
                let r = *radius;
                Bounds {
                    min: std::array::from_fn(|k| a[k].min(b[k]) - r),
                    max: std::array::from_fn(|k| a[k].max(b[k]) + r),
                }
            }
            Shape::Quad { half } => Bounds {
                min: [-half[0], 0.0, -half[1]],
                max: [half[0], 0.0, half[1]],
            },
            Shape::Mesh(m) => m.bounds(),
            Shape::Gltf(g) => g.rest().bounds(),
        }
    }

    /// Whether the shape is convex, so it can never shadow itself where it faces the light (its
    /// shadow rays then skip it, which also rules out self-shadowing acne).
    pub fn is_convex(&self) -> bool {
        !matches!(self, Shape::Mesh(_) | Shape::Gltf(_))
    }

    /// Whether the geometry itself changes with time (a skinned or non-rigidly animated glTF
    /// node), so snapshots must pose it.
    pub fn deforms(&self) -> bool {
        matches!(self, Shape::Gltf(g) if g.deforms())
    }

    /// The albedo the shape carries itself (glTF textures), for triangle or face `face` at `uv`;
    /// `None` where the object's [`crate::Material`] applies.
    pub(crate) fn own_albedo(&self, face: u32, uv: [f64; 2]) -> Option<V3> {
        match self {
            Shape::Gltf(g) => Some(g.albedo(face, uv)),
            _ => None,
        }
    }

    /// Whether the shape blocks `o + t·d` for any `t > 0` (shadow rays).
    pub(crate) fn occludes(&self, o: V3, d: V3) -> bool {
        match self {
            Shape::Mesh(m) => m.occludes(o, d),
            Shape::Gltf(g) => g.rest().occludes(o, d),
            _ => self.intersect(o, d, 0.0, f64::INFINITY).is_some(),
        }
    }

    /// Nearest intersection of `o + t·d`, `t ∈ (tmin, tmax)`, in object space.
    pub(crate) fn intersect(&self, o: V3, d: V3, tmin: f64, tmax: f64) -> Option<LocalHit> {
        let hit = match self {
            Shape::Sphere { radius } => sphere_hit(o, d, [0.0; 3], *radius, tmin, tmax),
            Shape::Cuboid { min, max } => cuboid_hit(o, d, *min, *max, tmin, tmax),
            Shape::Capsule { a, b, radius } => capsule_hit(o, d, *a, *b, *radius, tmin, tmax),
            Shape::Quad { half } => {
                if d[1] == 0.0 {
                    return None;
                }
                let t = -o[1] / d[1];
                let x = o[0] + t * d[0];
                let z = o[2] + t * d[2];
                (t > tmin && t < tmax && x.abs() <= half[0] && z.abs() <= half[1]).then_some(
                    LocalHit {
                        t,
                        normal: [0.0, 1.0, 0.0],
                        uv: [x, z],
                        face: 0,
                    },
                )
            }
            Shape::Mesh(m) => m.intersect(o, d, tmin, tmax),
            Shape::Gltf(g) => g.rest().intersect(o, d, tmin, tmax),
        };
        hit.filter(|h| h.t > tmin && h.t < tmax)
    }
}

fn sphere_hit(o: V3, d: V3, c: V3, r: f64, tmin: f64, tmax: f64) -> Option<LocalHit> {
    let oc = sub(o, c);
    let a = dot(d, d);
    let b = dot(d, oc);
    let disc = b * b - a * (dot(oc, oc) - r * r);
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    // The front surface first; the back one only when the front lies before tmin.
    let t = [(-b - sq) / a, (-b + sq) / a]
        .into_iter()
        .find(|&t| t > tmin && t < tmax)?;
    let n = normalize(sub(add(o, scale(d, t)), c));
    let lon = n[2].atan2(n[0]) / (2.0 * PI) + 0.5;
    let lat = n[1].clamp(-1.0, 1.0).asin() / PI + 0.5;
    Some(LocalHit {
        t,
        normal: n,
        uv: [lon, lat],
        face: 0,
    })
}

fn cuboid_hit(o: V3, d: V3, min: V3, max: V3, tmin: f64, tmax: f64) -> Option<LocalHit> {
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    let (mut a0, mut a1) = (0usize, 0usize);
    for k in 0..3 {
        if d[k] == 0.0 {
            if o[k] < min[k] || o[k] > max[k] {
                return None;
            }
            continue;
        }
        let (mut a, mut b) = ((min[k] - o[k]) / d[k], (max[k] - o[k]) / d[k]);
        if a > b {
            std::mem::swap(&mut a, &mut b);
        }
        if a > t0 {
            t0 = a;
            a0 = k;
        }
        if b < t1 {
            t1 = b;
            a1 = k;
        }
    }
    if t0 > t1 {
        return None;
    }
    let (t, k) = if t0 > tmin { (t0, a0) } else { (t1, a1) };
    if !(t > tmin && t < tmax) {
        return None;
    }
    let p = add(o, scale(d, t));
    let mid = 0.5 * (min[k] + max[k]);
    let mut n = [0.0; 3];
    n[k] = if p[k] >= mid { 1.0 } else { -1.0 };
    let face = 2 * k as u32 + u32::from(n[k] > 0.0);
    Some(LocalHit {
        t,
        normal: n,
        uv: [p[(k + 1) % 3], p[(k + 2) % 3]],
        face,
    })
}

fn capsule_hit(o: V3, d: V3, a: V3, b: V3, r: f64, tmin: f64, tmax: f64) -> Option<LocalHit> {
    let ba = sub(b, a);
    let len2 = dot(ba, ba);
    let len = len2.sqrt();
    let axis = scale(ba, 1.0 / len);
    let mut best: Option<(f64, V3, u32)> = None;
    // Cylinder body: |(p − a) − ((p − a)·axis) axis| = r with 0 ≤ (p − a)·axis ≤ len.
    let oa = sub(o, a);
    let dp = sub(d, scale(axis, dot(d, axis)));
    let op = sub(oa, scale(axis, dot(oa, axis)));
    let qa = dot(dp, dp);
    if qa > 0.0 {
        let qb = dot(dp, op);
        let qc = dot(op, op) - r * r;
        let disc = qb * qb - qa * qc;
        if disc >= 0.0 {
            let sq = disc.sqrt();
            for t in [(-qb - sq) / qa, (-qb + sq) / qa] {
                if t > tmin && t < tmax {
                    let h = dot(add(oa, scale(d, t)), axis);
                    if (0.0..=len).contains(&h) {
                        let p = add(oa, scale(d, t));
                        best = Some((t, sub(p, scale(axis, h)), 0));
                        break;
                    }
                }
            }
        }
    }
    for (c, face) in [(a, 1), (b, 2)] {
        let lim = best.map_or(tmax, |b| b.0);
        if let Some(h) = sphere_hit(o, d, c, r, tmin, lim) {
            // Only the cap's outer half belongs to the capsule.
            let p = add(o, scale(d, h.t));
            let s = dot(sub(p, a), axis);
            if (face == 1 && s <= 0.0) || (face == 2 && s >= len) {
                best = Some((h.t, scale(h.normal, r), face));
            }
        }
    }
    let (t, radial, face) = best?;
    let n = normalize(radial);
    let p = add(o, scale(d, t));
    // UV: angle around the axis (against a fixed perpendicular) and distance along it.
    let e1 = normalize(if axis[0].abs() < 0.9 {
        cross(axis, [1.0, 0.0, 0.0])
    } else {
        cross(axis, [0.0, 1.0, 0.0])
    });
    let e2 = cross(axis, e1);
    let ang = dot(n, e2).atan2(dot(n, e1)) / (2.0 * PI) + 0.5;
    Some(LocalHit {
        t,
        normal: n,
        uv: [ang, dot(sub(p, a), axis)],
        face,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::meshes;

    #[test]
    fn mesh_bvh_matches_brute_force() {
        let m = meshes::torus(0.6, 0.2, 24, 12);
        let Shape::Mesh(mesh) = &m else {
            unreachable!()
        };
        let mut hits = 0;
        for k in 0..400 {
            let a = k as f64 * 0.37;
            let o = [2.0 * a.cos(), 0.3 * (1.3 * a).sin(), 2.0 * a.sin()];
            let target = [0.5 * (0.7 * a).sin(), 0.1 * (2.1 * a).cos(), 0.4 * a.cos()];
            let d = sub(target, o);
            let fast = mesh.intersect(o, d, 0.0, f64::INFINITY).map(|h| h.t);
            let brute = (0..mesh.triangles.len() as u32)
                .filter_map(|tri| mesh.triangle_hit(tri, o, d, 0.0, f64::INFINITY))
                .map(|h| h.0)
                .fold(None, |acc: Option<f64>, t| {
                    Some(acc.map_or(t, |a| a.min(t)))
                });
            assert_eq!(fast, brute, "ray {k}");
            hits += usize::from(fast.is_some());
        }
        assert!(hits > 100, "{hits}");
    }

    #[test]
    fn capsule_and_cuboid_hits_are_on_the_surface() {
        let cap = Shape::Capsule {
            a: [0.0, 0.0, 0.0],
            b: [0.0, -0.5, 0.0],
            radius: 0.1,
        };
        let h = cap
            .intersect([1.0, -0.2, 0.0], [-1.0, 0.0, 0.0], 0.0, 10.0)
            .unwrap();
        assert!((h.t - 0.9).abs() < 1e-12 && (h.normal[0] - 1.0).abs() < 1e-12);
        let h = cap
            .intersect([0.0, 1.0, 0.0], [0.0, -1.0, 0.0], 0.0, 10.0)
            .unwrap();
        assert!((h.t - 0.9).abs() < 1e-12 && (h.normal[1] - 1.0).abs() < 1e-12);
        let cube = Shape::Cuboid {
            min: [-1.0; 3],
            max: [1.0, 2.0, 1.0],
        };
        let h = cube
            .intersect([0.2, 5.0, 0.1], [0.0, -2.0, 0.0], 0.0, 10.0)
            .unwrap();
        assert!((h.t - 1.5).abs() < 1e-12 && h.normal == [0.0, 1.0, 0.0]);
    }

    #[test]
    fn f32_above_is_above() {
        for t in [0.0, 1e-9, 0.1, 1.0, 3.7, 1e6] {
            assert!(f64::from(f32_above(t)) > t);
        }
        assert_eq!(f32_above(f64::INFINITY), f32::INFINITY);
    }
}
