//! Triangle meshes in object space with their own BVH, the `f64` boxes that bound every shape,
//! and the carrying of a material point from one pose of a mesh to another (deforming glTF
//! meshes).
//!
//! Every intersection is computed in `f64`. A mesh's BVH (obvhs, `f32`) only culls: its boxes are
//! padded so that `f32` rounding can never cull a triangle the `f64` test would hit.

use std::collections::{HashMap, HashSet};
use std::fmt;
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
    /// The BVH over the triangles' boxes, one primitive per distinct box ([`Mesh::new`]).
    bvh: Bvh2,
    /// Per BVH primitive, its triangles: `prim_tris[prim_start[p]..prim_start[p + 1]]`, in
    /// increasing order.
    prim_start: Vec<u32>,
    prim_tris: Vec<u32>,
    /// Per triangle, the padded box its BVH leaf was built from ([`Mesh::occluded_rays`]).
    tri_boxes: Vec<Aabb>,
    /// Per triangle, its first corner `a` and the edges `b − a` and `c − a` that
    /// [`Mesh::triangle_hit`] starts from: the same values, formed once rather than at every
    /// test (and read from one place rather than through three vertex indices).
    tri_edges: Vec<[V3; 3]>,
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
    ///
    /// The BVH's primitives are the triangles' distinct padded boxes, each standing for every
    /// triangle with that box, numbered in the order of their first triangle (a mesh whose boxes
    /// all differ gets one primitive per triangle, in triangle order): the BVH build (PLOC) is
    /// quadratic in the number of coincident boxes (every merge distance ties: 20,000 took
    /// 10 s), and a glTF file of under a kilobyte whose sparse index accessor repeats one
    /// triangle 333,333 times was still loading after 300 s. Left out of it: triangles with
    /// `b` or `c` at `a` (the ray–triangle test's determinant is then exactly zero, or NaN, so
    /// no ray can hit them) and exact copies of an earlier triangle (which can never be the
    /// answer: the earlier one is tested first and gives the same distance); they keep their
    /// indices in [`Mesh::triangles`].
    pub fn new(vertices: Vec<Vertex>, triangles: Vec<[u32; 3]>) -> Mesh {
        let n = vertices.len() as u32;
        let triangles: Vec<[u32; 3]> = triangles
            .into_iter()
            .filter(|t| t.iter().all(|&i| i < n))
            .collect();
        let tri_edges: Vec<[V3; 3]> = triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| vertices[i as usize].position);
                [a, sub(b, a), sub(c, a)]
            })
            .collect();
        let tri_boxes: Vec<Aabb> = triangles
            .iter()
            .map(|t| Bounds::around(t.map(|i| vertices[i as usize].position)).padded_f32())
            .collect();
        let (prims, prim_start, prim_tris) = group_boxes(&tri_boxes, &tri_edges);
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
            prim_start,
            prim_tris,
            tri_boxes,
            tri_edges,
        }
    }

    /// The triangles of BVH primitive `prim` (an index into the BVH's primitive list).
    #[inline]
    fn prim_triangles(&self, prim: u32) -> &[u32] {
        let p = prim as usize;
        &self.prim_tris[self.prim_start[p] as usize..self.prim_start[p + 1] as usize]
    }

    /// Object-space bounds.
    pub fn bounds(&self) -> Bounds {
        self.bounds
    }

    pub(crate) fn intersect(&self, o: V3, d: V3, tmin: f64, tmax: f64) -> Option<LocalHit> {
        if self.prim_tris.is_empty() {
            return None;
        }
        let ray = f32_ray(o, d, f32_above(tmax));
        let mut best: Option<(f64, u32, f64, f64)> = None;
        let mut limit = tmax;
        let mut hit = RayHit::none();
        self.bvh.ray_traverse(ray, &mut hit, |_, id| {
            let mut found = f32::INFINITY;
            for &tri in self.prim_triangles(self.bvh.primitive_indices[id]) {
                if let Some((t, u, v)) = self.triangle_hit(tri, o, d, tmin, limit) {
                    limit = t;
                    best = Some((t, tri, u, v));
                    found = f32_above(t);
                }
            }
            found
        });
        let (t, tri, u, v) = best?;
        let [a, b, c] = self.triangles[tri as usize].map(|i| &self.vertices[i as usize]);
        let w = 1.0 - u - v;
        Some(LocalHit {
            t,
            normal: smooth_normal([a, b, c], w, u, v),
            uv: [
                a.uv[0] * w + b.uv[0] * u + c.uv[0] * v,
                a.uv[1] * w + b.uv[1] * u + c.uv[1] * v,
            ],
            face: tri,
        })
    }

    /// Whether anything blocks `o + t·d` for `t > 0` (any hit, stops at the first).
    pub(crate) fn occludes(&self, o: V3, d: V3) -> bool {
        if self.prim_tris.is_empty() {
            return false;
        }
        let ray = f32_ray(o, d, f32::INFINITY);
        !self.bvh.ray_traverse_miss(ray, |_, id| {
            let prim = self.bvh.primitive_indices[id];
            let hits = |&tri: &u32| self.triangle_hit(tri, o, d, 0.0, f64::INFINITY).is_some();
            if self.prim_triangles(prim).iter().any(hits) {
                0.0
            } else {
                f32::INFINITY
            }
        })
    }

    /// Which of the rays `o + t·dirs[k]`, `t > 0`, `k` in `todo`, the mesh blocks, as a mask: the
    /// rays that [`Mesh::occludes`] finds blocked, found with one walk of the BVH for all of
    /// them instead of one per ray.
    ///
    /// `cone = (axis, spread)`: every `dirs[k]` over its length lies within `spread` of the unit
    /// `axis` (a chord: `|d̂ − axis| ≤ spread`). A point `p = o + u·d̂` of a box lies within
    /// `u·spread ≤ D·spread` of the axis point `o + u·axis`, `D` the distance from `o` to the
    /// box's farthest corner, so the axis ray meets the box grown by that much: a node it does
    /// not meet holds no triangle any of the rays can hit. The growth keeps a relative margin and
    /// an absolute one of `10⁻⁵` of the coordinates' size, far above the `f32` rounding of a
    /// per-ray walk, so the triangles listed include every one that such a walk would test and
    /// the `f64` test would hit (the per-ray walk's padded boxes never cull one either): each
    /// ray's answer, whether some triangle's `f64` test hits it, is the same. Where more
    /// triangles than fit in place are reachable, the rays are walked one by one.
    ///
    /// `N` is the scene's shadow-ray count (`scene::SHADOW_SAMPLES`), a parameter here so that
    /// meshes stay below the scene that owns them; the masks hold one bit per ray.
    pub(crate) fn occluded_rays<const N: usize>(
        &self,
        o: V3,
        dirs: &[V3; N],
        (axis, spread): (V3, f64),
        todo: u32,
    ) -> u32 {
        const { assert!(N <= 32, "one bit per ray in a u32 mask") };
        let each = |todo: u32| {
            bits(todo)
                .filter(|&k| self.occludes(o, dirs[k]))
                .fold(0u32, |m, k| m | 1 << k)
        };
        if self.prim_tris.is_empty() || todo == 0 {
            return 0;
        }
        if !(o.iter().chain(&axis).all(|c| c.is_finite()) && spread.is_finite()) {
            return each(todo);
        }
        let mut tris = [0u32; 64];
        let mut nt = 0;
        let mut stack = [0u32; 64];
        let mut sp = 1;
        let meets = |b: &Aabb| {
            let lo = [b.min.x, b.min.y, b.min.z].map(f64::from);
            let hi = [b.max.x, b.max.y, b.max.z].map(f64::from);
            cone_meets(lo, hi, o, axis, spread)
        };
        while sp > 0 {
            sp -= 1;
            let node = &self.bvh.nodes[stack[sp] as usize];
            if !meets(node.aabb()) {
                continue;
            }
            let first = node.first_index as usize;
            if node.is_leaf() {
                // A leaf's triangles one by one, each with its own padded box (a leaf of one
                // triangle would have had that box).
                let prims = &self.bvh.primitive_indices[first..first + node.prim_count as usize];
                for &tri in prims.iter().flat_map(|&p| self.prim_triangles(p)) {
                    if meets(&self.tri_boxes[tri as usize]) {
                        if nt == tris.len() {
                            return each(todo);
                        }
                        tris[nt] = tri;
                        nt += 1;
                    }
                }
            } else {
                if sp + 2 > stack.len() {
                    return each(todo);
                }
                stack[sp] = first as u32;
                stack[sp + 1] = first as u32 + 1;
                sp += 2;
            }
        }
        let tris = &tris[..nt];
        let mut hidden = 0u32;
        // Neighbouring rays mostly meet the same triangle: the last one that blocked is tried
        // first.
        let mut last: Option<u32> = None;
        for k in bits(todo) {
            let hits = |&tri: &u32| {
                self.triangle_hit(tri, o, dirs[k], 0.0, f64::INFINITY)
                    .is_some()
            };
            let hit = if last.as_ref().is_some_and(hits) {
                last
            } else {
                tris.iter().find(|t| hits(t)).copied()
            };
            if hit.is_some() {
                last = hit;
                hidden |= 1 << k;
            }
        }
        hidden
    }

    /// Möller–Trumbore in `f64`: `(t, u, v)` for `t ∈ (tmin, tmax)`. Both sides count (the meshes
    /// are closed, and open ones are meant to be seen from both sides).
    pub(crate) fn triangle_hit(
        &self,
        tri: u32,
        o: V3,
        d: V3,
        tmin: f64,
        tmax: f64,
    ) -> Option<(f64, f64, f64)> {
        let [a, e1, e2] = self.tri_edges[tri as usize];
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

/// The BVH primitives of [`Mesh::new`]: the distinct boxes among `boxes` of the triangles that
/// can be hit, in the order of their first triangle, and per primitive its triangles,
/// increasing, as `(boxes, start, triangles)` with primitive `p`'s at
/// `triangles[start[p]..start[p + 1]]`.
///
/// Left out: a triangle with an edge from its first corner zero (`edges[t] = [a, b − a, c − a]`;
/// its determinant is zero, no ray hits it), and a triangle whose `edges` are bit for bit an
/// earlier one's. [`Mesh::triangle_hit`] reads nothing else, so such a copy gives the same `t`
/// as the earlier triangle, which is in the same primitive and tested first: the nearest-hit
/// search keeps the first of equal distances and the occlusion tests need one hit, so the copy
/// changes no answer. (A sparse glTF accessor repeats one index triple at no cost in bytes.)
fn group_boxes(boxes: &[Aabb], edges: &[[V3; 3]]) -> (Vec<Tri>, Vec<u32>, Vec<u32>) {
    let key = |b: &Aabb| [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z].map(f32::to_bits);
    let mut first: HashMap<[u32; 6], u32> = HashMap::with_capacity(boxes.len());
    let mut seen: HashSet<[u64; 9]> = HashSet::with_capacity(boxes.len());
    // Per hittable triangle, its primitive.
    let mut prim_of: Vec<(u32, u32)> = Vec::with_capacity(boxes.len());
    let mut prims = Vec::new();
    for (t, (b, e)) in boxes.iter().zip(edges).enumerate() {
        let bits: [u64; 9] = std::array::from_fn(|i| e[i / 3][i % 3].to_bits());
        if e[1] == [0.0; 3] || e[2] == [0.0; 3] || !seen.insert(bits) {
            continue;
        }
        let next = prims.len() as u32;
        let p = *first.entry(key(b)).or_insert(next);
        if p == next {
            prims.push(Tri(*b));
        }
        prim_of.push((p, t as u32));
    }
    // A stable sort by primitive keeps each primitive's triangles in increasing order.
    prim_of.sort_by_key(|&(p, _)| p);
    let mut start = vec![0u32; prims.len() + 1];
    for &(p, _) in &prim_of {
        start[p as usize + 1] += 1;
    }
    for p in 0..prims.len() {
        start[p + 1] += start[p];
    }
    (prims, start, prim_of.into_iter().map(|(_, t)| t).collect())
}

/// The set bits of `m`, lowest first.
pub(crate) fn bits(mut m: u32) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (m != 0).then(|| {
            let k = m.trailing_zeros() as usize;
            m &= m - 1;
            k
        })
    })
}

/// Whether a ray `o + t·d`, `t > 0`, with `|d̂ − axis| ≤ spread` may pass through the box `[lo,
/// hi]` ([`Mesh::occluded_rays`] has the argument).
#[inline]
fn cone_meets(lo: V3, hi: V3, o: V3, axis: V3, spread: f64) -> bool {
    let mut far2 = 0.0;
    let mut size = o.iter().fold(1.0f64, |m, c| m.max(c.abs()));
    for k in 0..3 {
        let (a, b) = (lo[k] - o[k], hi[k] - o[k]);
        far2 += (a * a).max(b * b);
        size = size.max(lo[k].abs()).max(hi[k].abs());
    }
    let far = far2.sqrt();
    let grow = far * spread * 1.001 + 1e-5 * (size + far);
    // A NaN (no finite answer) keeps the box.
    grown_slabs(lo, hi, grow, o, axis).is_some_and(|(t0, t1)| !(t0 > t1))
}

/// The interval `(t0, t1)`, `t0 ≥ 0`, of the ray `o + t·d` inside the box `[lo, hi]` grown by
/// `grow` on every side, by its three slabs (empty where `t0 > t1`), or `None` where the ray
/// runs parallel to a slab outside it. Shared by the shadow cull's cone test
/// ([`crate::scene`]) and [`cone_meets`], which read a NaN each their own way.
#[inline]
pub(crate) fn grown_slabs(lo: V3, hi: V3, grow: f64, o: V3, d: V3) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for k in 0..3 {
        let (lo, hi) = (lo[k] - grow, hi[k] + grow);
        if d[k] == 0.0 {
            if o[k] < lo || o[k] > hi {
                return None;
            }
            continue;
        }
        let (mut a, mut b) = ((lo - o[k]) / d[k], (hi - o[k]) / d[k]);
        if a > b {
            std::mem::swap(&mut a, &mut b);
        }
        t0 = t0.max(a);
        t1 = t1.min(b);
    }
    Some((t0, t1))
}

/// The `f32` ray `o + t·d`, `t ∈ [0, tmax]`, of a BVH traversal (the BVH only culls; every hit
/// is computed in `f64`).
pub(crate) fn f32_ray(o: V3, d: V3, tmax: f32) -> Ray {
    Ray::new(
        Vec3A::new(o[0] as f32, o[1] as f32, o[2] as f32),
        Vec3A::new(d[0] as f32, d[1] as f32, d[2] as f32),
        0.0,
        tmax,
    )
}

/// The unit normal at barycentric weights `(w, u, v)` of the triangle `a, b, c`: the vertex
/// normals interpolated, or the face normal where they cancel.
fn smooth_normal([a, b, c]: [&Vertex; 3], w: f64, u: f64, v: f64) -> V3 {
    let mut n = add(
        add(scale(a.normal, w), scale(b.normal, u)),
        scale(c.normal, v),
    );
    if dot(n, n) < 1e-30 {
        n = cross(sub(b.position, a.position), sub(c.position, a.position));
    }
    normalize(n)
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
/// Where the material point at `local` (object space, on triangle `tri` of `from`) is on `to`:
/// the same triangle and barycentrics, with the interpolated normal oriented like `n_from`.
pub(crate) fn carry_on_mesh(from: &Mesh, to: &Mesh, tri: u32, local: V3, n_from: V3) -> (V3, V3) {
    let Some(t) = from.triangles.get(tri as usize) else {
        return (local, n_from);
    };
    let [a, b, c] = t.map(|i| from.vertices[i as usize].position);
    let (u, v) = barycentric(a, b, c, local);
    let w = 1.0 - u - v;
    let at = |m: &Mesh| {
        let [a, b, c] = t.map(|i| m.vertices[i as usize]);
        let p = add(
            add(scale(a.position, w), scale(b.position, u)),
            scale(c.position, v),
        );
        (p, smooth_normal([&a, &b, &c], w, u, v))
    };
    let (_, nk) = at(from);
    let (p, n) = at(to);
    let flip = if dot(nk, n_from) < 0.0 { -1.0 } else { 1.0 };
    // The offset of the point from the plane of the triangle (rounding only) is carried along.
    let (pk, _) = at(from);
    (add(p, sub(local, pk)), scale(n, flip))
}

/// Barycentrics `(u, v)` of `p` (on the triangle's plane) for `b` and `c`.
fn barycentric(a: V3, b: V3, c: V3, p: V3) -> (f64, f64) {
    let (e1, e2, d) = (sub(b, a), sub(c, a), sub(p, a));
    let (d11, d12, d22) = (dot(e1, e1), dot(e1, e2), dot(e2, e2));
    let (p1, p2) = (dot(d, e1), dot(d, e2));
    let den = d11 * d22 - d12 * d12;
    if den.abs() < 1e-300 {
        return (0.0, 0.0);
    }
    ((d22 * p1 - d12 * p2) / den, (d11 * p2 - d12 * p1) / den)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f32_above_is_above() {
        for t in [0.0, 1e-9, 0.1, 1.0, 3.7, 1e6] {
            assert!(f64::from(f32_above(t)) > t);
        }
        assert_eq!(f32_above(f64::INFINITY), f32::INFINITY);
    }

    fn vertex(position: V3, normal: V3, uv: [f64; 2]) -> Vertex {
        Vertex {
            position,
            normal,
            uv,
        }
    }

    /// A small mesh: an 8 × 8 grid of unit quads (two triangles each, the halves of a quad
    /// sharing their box) in the plane z = 0, each quad's corners at its own vertices, with
    /// normals and UVs that tell the vertices apart.
    fn grid() -> (Vec<Vertex>, Vec<[u32; 3]>) {
        let (mut vs, mut ts) = (Vec::new(), Vec::new());
        for i in 0..8 {
            for j in 0..8 {
                let base = vs.len() as u32;
                for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
                    let p = [f64::from(i) + dx, f64::from(j) + dy, 0.0];
                    vs.push(vertex(p, [0.1 * dx, 0.1 * dy, 1.0], [dx, dy]));
                }
                ts.push([base, base + 1, base + 2]);
                ts.push([base, base + 2, base + 3]);
            }
        }
        (vs, ts)
    }

    /// Möller–Trumbore's edges are exact and closed: on the triangle (0,0,0), (1,0,0), (0,1,0) a
    /// ray straight down through (x, y, 1) has u = x, v = y and t = 1 with no rounding, so points
    /// on the edges and corners (u = 0, v = 0, u + v = 1) hit and points 2⁻⁴⁰ beyond an edge
    /// miss: in the triangle test, the BVH walk, the shadow ray and the bundled shadow rays alike
    /// (their culling boxes must hold the corners).
    #[test]
    fn triangle_edges_are_closed_and_exact() {
        let n = [0.0, 0.0, 1.0];
        let mesh = Mesh::new(
            vec![
                vertex([0.0; 3], n, [0.0, 0.0]),
                vertex([1.0, 0.0, 0.0], n, [1.0, 0.0]),
                vertex([0.0, 1.0, 0.0], n, [0.0, 1.0]),
            ],
            vec![[0, 1, 2]],
        );
        let e = 2f64.powi(-40);
        let down = [0.0, 0.0, -1.0];
        let cases = [
            (0.25, 0.25, true),
            (0.5, 0.5, true),
            (0.0, 0.5, true),
            (0.5, 0.0, true),
            (0.0, 0.0, true),
            (1.0, 0.0, true),
            (0.0, 1.0, true),
            (0.5, 0.5 + e, false),
            (0.5 + e, 0.5, false),
            (1.0 + e, 0.0, false),
            (-e, 0.5, false),
            (0.5, -e, false),
            (-e, -e, false),
        ];
        for (x, y, hit) in cases {
            let o = [x, y, 1.0];
            let at = format!("({x}, {y})");
            let want = hit.then_some((1.0, x, y));
            assert_eq!(mesh.triangle_hit(0, o, down, 0.0, 10.0), want, "{at}");
            let h = mesh.intersect(o, down, 0.0, 10.0);
            let want = hit.then_some((1.0, [x, y], 0));
            assert_eq!(h.map(|h| (h.t, h.uv, h.face)), want, "{at}");
            assert_eq!(mesh.occludes(o, down), hit, "{at}");
            let bundled = mesh.occluded_rays(o, &[down], (down, 0.0), 1);
            assert_eq!(bundled, u32::from(hit), "{at}");
        }
    }

    #[test]
    fn coincident_triangles_share_one_bvh_primitive() {
        // One triangle 20,000 times and one corner 20,000 times (a few hundred bytes of sparse
        // glTF accessor): the BVH build is quadratic in coincident boxes, so they must not
        // each be a primitive of their own (2N − 1 nodes before).
        let vs = vec![
            vertex([0.0; 3], [0.0, 0.0, 1.0], [0.0; 2]),
            vertex([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0]),
            vertex([0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0]),
        ];
        let mut ts = vec![[0, 1, 2]; 20_000];
        ts.extend(vec![[0, 0, 0]; 20_000]);
        let mesh = Mesh::new(vs, ts);
        assert_eq!(
            mesh.triangles.len(),
            40_000,
            "every triangle is kept for its index"
        );
        assert_eq!(mesh.bvh.nodes.len(), 1);
        assert_eq!(
            (mesh.prim_start.as_slice(), mesh.prim_tris.as_slice()),
            (&[0, 1][..], &[0][..])
        );
        let hit = mesh.intersect([0.2, 0.2, 1.0], [0.0, 0.0, -1.0], 0.0, 10.0);
        assert_eq!(hit.map(|h| (h.t, h.face)), Some((1.0, 0)));
        // Only degenerate triangles: nothing to hit, and no walk of an empty BVH.
        let flat = Mesh::new(
            vec![vertex([0.0; 3], [0.0; 3], [0.0; 2]); 3],
            vec![[0, 1, 2]; 9],
        );
        assert!(flat.prim_tris.is_empty());
        assert!(flat
            .intersect([0.0, 0.0, 1.0], [0.0, 0.0, -1.0], 0.0, 10.0)
            .is_none());
        assert!(!flat.occludes([0.0, 0.0, 1.0], [0.0, 0.0, -1.0]));
    }

    #[test]
    fn copies_and_degenerate_triangles_change_no_answer() {
        // The grid, then every triangle again over vertices of its own at the same positions
        // (other normals and UVs, so a copy that won a hit would show), and degenerate ones:
        // every ray must get the grid's own answer, the earlier triangle's.
        let (vs, ts) = grid();
        let plain = Mesh::new(vs.clone(), ts.clone());
        let (mut vs2, mut ts2) = (vs.clone(), ts.clone());
        for t in &ts {
            let base = vs2.len() as u32;
            for &i in t {
                let v = vs[i as usize];
                vs2.push(vertex(v.position, [0.5, -0.5, 1.0], [9.0, 9.0]));
            }
            ts2.push([base, base + 1, base + 2]);
            ts2.push([t[0], t[0], t[1]]);
        }
        let copied = Mesh::new(vs2, ts2);
        assert_eq!(
            copied.prim_tris, plain.prim_tris,
            "no copy or degenerate one is tested"
        );
        let mut checked = 0;
        for k in 0..400 {
            let (x, y) = (
                f64::from(k % 20) * 0.41 - 0.3,
                f64::from(k / 20) * 0.41 - 0.3,
            );
            let o = [x, y, 2.0];
            for d in [[0.0, 0.0, -1.0], [0.13, -0.07, -1.0], [-0.5, 0.5, -0.25]] {
                let (a, b) = (
                    plain.intersect(o, d, 0.0, 1e9),
                    copied.intersect(o, d, 0.0, 1e9),
                );
                let key = |h: Option<LocalHit>| h.map(|h| (h.t, h.face, h.normal, h.uv));
                assert_eq!(key(a), key(b), "ray {o:?} {d:?}");
                assert_eq!(plain.occludes(o, d), copied.occludes(o, d));
                checked += usize::from(a.is_some());
            }
        }
        assert!(
            checked > 300,
            "the rays must meet the grid ({checked} hits)"
        );
    }
}
