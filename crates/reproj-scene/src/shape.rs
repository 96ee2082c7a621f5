//! Shapes in object space: analytic primitives and triangle meshes with their own BVH.
//!
//! Every intersection is computed in `f64`. A mesh's BVH (obvhs, `f32`) only culls: its boxes are
//! padded so that `f32` rounding can never cull a triangle the `f64` test would hit.

use std::f64::consts::PI;
use std::sync::Arc;

use crate::math::{add, cross, dot, normalize, scale, sub, V3};
use crate::mesh::LocalHit;
pub use crate::mesh::{Bounds, Mesh, Vertex};

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
    Gltf(Arc<crate::gltf_model::GltfShape>),
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
    // Inlined into the shadow rays' candidate loop, for the reason `intersect_t` is.
    #[inline(always)]
    pub(crate) fn occludes(&self, o: V3, d: V3) -> bool {
        match self {
            Shape::Mesh(m) => m.occludes(o, d),
            Shape::Gltf(g) => g.rest().occludes(o, d),
            // The analytic shapes decide with the distance alone: the same arithmetic as
            // `intersect`, without its normal and texture coordinates (an `atan2` and an `asin`
            // per sphere hit), so the answer is exactly `intersect(..).is_some()`.
            Shape::Sphere { radius } => {
                sphere_t(o, d, [0.0; 3], *radius, 0.0, f64::INFINITY).is_some()
            }
            Shape::Cuboid { min, max } => cuboid_t(o, d, *min, *max, 0.0, f64::INFINITY).is_some(),
            Shape::Capsule { a, b, radius } => {
                capsule_t(o, d, *a, *b, *radius, 0.0, f64::INFINITY).is_some()
            }
            Shape::Quad { half } => quad_t(o, d, *half, 0.0, f64::INFINITY).is_some(),
        }
    }

    /// Nearest intersection of `o + t·d`, `t ∈ (tmin, tmax)`, in object space (the renderer
    /// calls the two halves itself, so that only the closest hit is finished).
    #[cfg(test)]
    pub(crate) fn intersect(&self, o: V3, d: V3, tmin: f64, tmax: f64) -> Option<LocalHit> {
        self.intersect_t(o, d, tmin, tmax)
            .map(|p| self.finish(o, d, p))
    }

    /// The tests' `Shape::intersect` up to its ray parameter: what finding `t` produced, without
    /// the normal and texture coordinates of an analytic shape (an `atan2` and an `asin` on a
    /// sphere), which a closest-hit search needs only for its winner ([`Shape::finish`]).
    // Inlined into the primary rays' candidate loop: most calls are a box or the ground quad,
    // cheaper than the call with its spills and the `Partial` passed through memory.
    #[inline(always)]
    pub(crate) fn intersect_t(&self, o: V3, d: V3, tmin: f64, tmax: f64) -> Option<Partial> {
        let p = match self {
            Shape::Sphere { radius } => {
                sphere_t(o, d, [0.0; 3], *radius, tmin, tmax).map(Partial::Sphere)
            }
            Shape::Cuboid { min, max } => {
                cuboid_t(o, d, *min, *max, tmin, tmax).map(|(t, k)| Partial::Cuboid(t, k))
            }
            Shape::Capsule { a, b, radius } => capsule_t(o, d, *a, *b, *radius, tmin, tmax)
                .map(|(t, radial, face, axis)| Partial::Capsule(t, radial, face, axis)),
            Shape::Quad { half } => {
                quad_t(o, d, *half, tmin, tmax).map(|(t, x, z)| Partial::Quad(t, x, z))
            }
            Shape::Mesh(m) => m.intersect(o, d, tmin, tmax).map(Partial::Done),
            Shape::Gltf(g) => g.rest().intersect(o, d, tmin, tmax).map(Partial::Done),
        };
        p.filter(|p| p.t() > tmin && p.t() < tmax)
    }

    /// The full hit from [`Shape::intersect_t`]'s answer for the same `o` and `d`.
    // Inlined into `Snapshot::finish_hit`, the renderer's one caller (left to itself, the
    // compiler's choice changes with unrelated edits of the crate).
    #[inline(always)]
    pub(crate) fn finish(&self, o: V3, d: V3, p: Partial) -> LocalHit {
        match (self, p) {
            (_, Partial::Done(h)) => h,
            (Shape::Cuboid { min, max }, Partial::Cuboid(t, k)) => {
                cuboid_hit(o, d, *min, *max, t, k)
            }
            (Shape::Capsule { a, .. }, Partial::Capsule(t, radial, face, axis)) => {
                capsule_hit(o, d, *a, t, radial, face, axis)
            }
            (_, Partial::Quad(t, x, z)) => LocalHit {
                t,
                normal: [0.0, 1.0, 0.0],
                uv: [x, z],
                face: 0,
            },
            // A sphere (the only shape left that answers with `t` alone) centred at the origin.
            (_, p) => sphere_hit(o, d, [0.0; 3], p.t()),
        }
    }
}

/// What [`Shape::intersect_t`] found: the ray parameter and whatever of the hit came with it.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Partial {
    Sphere(f64),
    /// `t` and the axis of the face.
    Cuboid(f64, usize),
    /// `t`, the unnormalised radial direction, the face and the unit axis.
    Capsule(f64, V3, u32, V3),
    /// `t` and the hit's `x` and `z`.
    Quad(f64, f64, f64),
    /// A mesh's complete hit.
    Done(LocalHit),
}

impl Partial {
    /// The ray parameter.
    pub(crate) fn t(&self) -> f64 {
        match *self {
            Partial::Sphere(t)
            | Partial::Cuboid(t, _)
            | Partial::Capsule(t, ..)
            | Partial::Quad(t, ..) => t,
            Partial::Done(h) => h.t,
        }
    }
}

/// Where `o + t·d`, `t ∈ (tmin, tmax)`, meets the rectangle `y = 0` of half extents `half`:
/// `(t, x, z)`.
#[inline]
fn quad_t(o: V3, d: V3, half: [f64; 2], tmin: f64, tmax: f64) -> Option<(f64, f64, f64)> {
    if d[1] == 0.0 {
        return None;
    }
    let t = -o[1] / d[1];
    let x = o[0] + t * d[0];
    let z = o[2] + t * d[2];
    (t > tmin && t < tmax && x.abs() <= half[0] && z.abs() <= half[1]).then_some((t, x, z))
}

/// The ray parameter where `o + t·d`, `t ∈ (tmin, tmax)`, first meets the sphere `(c, r)`.
#[inline]
fn sphere_t(o: V3, d: V3, c: V3, r: f64, tmin: f64, tmax: f64) -> Option<f64> {
    // The front surface first; the back one only when the front lies before tmin.
    sphere_roots(o, d, c, r)?
        .into_iter()
        .find(|&t| t > tmin && t < tmax)
}

/// Both ray parameters where the ray `o + t·d` meets the sphere of centre `c` and radius `r`,
/// the front one first; `None` when it misses.
fn sphere_roots(o: V3, d: V3, c: V3, r: f64) -> Option<[f64; 2]> {
    let oc = sub(o, c);
    let a = dot(d, d);
    let b = dot(d, oc);
    let disc = b * b - a * (dot(oc, oc) - r * r);
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    Some([(-b - sq) / a, (-b + sq) / a])
}

fn sphere_hit(o: V3, d: V3, c: V3, t: f64) -> LocalHit {
    let n = normalize(sub(add(o, scale(d, t)), c));
    let lon = n[2].atan2(n[0]) / (2.0 * PI) + 0.5;
    let lat = n[1].clamp(-1.0, 1.0).asin() / PI + 0.5;
    LocalHit {
        t,
        normal: n,
        uv: [lon, lat],
        face: 0,
    }
}

fn cuboid_hit(o: V3, d: V3, min: V3, max: V3, t: f64, k: usize) -> LocalHit {
    let p = add(o, scale(d, t));
    let mid = 0.5 * (min[k] + max[k]);
    let mut n = [0.0; 3];
    n[k] = if p[k] >= mid { 1.0 } else { -1.0 };
    let face = 2 * k as u32 + u32::from(n[k] > 0.0);
    LocalHit {
        t,
        normal: n,
        uv: [p[(k + 1) % 3], p[(k + 2) % 3]],
        face,
    }
}

/// Where `o + t·d`, `t ∈ (tmin, tmax)`, first meets the box `[min, max]`: `(t, axis of the
/// face)`.
#[inline]
fn cuboid_t(o: V3, d: V3, min: V3, max: V3, tmin: f64, tmax: f64) -> Option<(f64, usize)> {
    // The entry and exit distances so far and the axes they came from.
    let mut st = (f64::NEG_INFINITY, f64::INFINITY, 0usize, 0usize);
    // One slab, `false` where the ray runs parallel to it outside. Called for the three axes in
    // turn rather than in a loop: the compiler left the loop rolled, with its state on the stack
    // (the same operations in the same order, so the same answer).
    let slab = |k: usize, (t0, t1, a0, a1): &mut (f64, f64, usize, usize)| {
        if d[k] == 0.0 {
            return !(o[k] < min[k] || o[k] > max[k]);
        }
        let (mut a, mut b) = ((min[k] - o[k]) / d[k], (max[k] - o[k]) / d[k]);
        if a > b {
            std::mem::swap(&mut a, &mut b);
        }
        if a > *t0 {
            *t0 = a;
            *a0 = k;
        }
        if b < *t1 {
            *t1 = b;
            *a1 = k;
        }
        true
    };
    // A slab only raises the entry distance and lowers the exit, so a ray that has left the box
    // after two slabs (most misses) misses it whatever the third says.
    if !(slab(0, &mut st) && slab(1, &mut st)) || st.0 > st.1 || !slab(2, &mut st) {
        return None;
    }
    let (t0, t1, a0, a1) = st;
    if t0 > t1 {
        return None;
    }
    let (t, k) = if t0 > tmin { (t0, a0) } else { (t1, a1) };
    (t > tmin && t < tmax).then_some((t, k))
}

fn capsule_hit(o: V3, d: V3, a: V3, t: f64, radial: V3, face: u32, axis: V3) -> LocalHit {
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
    LocalHit {
        t,
        normal: n,
        uv: [ang, dot(sub(p, a), axis)],
        face,
    }
}

/// Where `o + t·d`, `t ∈ (tmin, tmax)`, first meets the capsule: `(t, the unnormalised radial
/// direction, face, unit axis)`.
#[inline]
fn capsule_t(
    o: V3,
    d: V3,
    a: V3,
    b: V3,
    r: f64,
    tmin: f64,
    tmax: f64,
) -> Option<(f64, V3, u32, V3)> {
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
        let Some(roots) = sphere_roots(o, d, c, r) else {
            continue;
        };
        // Only the cap's outer half belongs to the capsule. Both roots in order: a ray from
        // inside the capsule (or from a `tmin` past its front) meets the cap sphere first on its
        // inner half, inside the body, and leaves through the outer half at the second root.
        for t in roots.into_iter().filter(|&t| t > tmin && t < lim) {
            let p = add(o, scale(d, t));
            let s = dot(sub(p, a), axis);
            if (face == 1 && s <= 0.0) || (face == 2 && s >= len) {
                // The cap sphere's unit normal at the hit, scaled back to the radius.
                let n = normalize(sub(p, c));
                best = Some((t, scale(n, r), face));
                break;
            }
        }
    }
    best.map(|(t, radial, face)| (t, radial, face, axis))
}

#[cfg(test)]
mod tests {
    use super::*;

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

    /// Every ray of `rays` as `(origin, direction, tmin)`: what `intersect` finds from `tmin`
    /// on, as `(t, normal, uv, face)`, with `occludes` (from `t > 0`) agreeing where `tmin` is 0.
    #[allow(clippy::type_complexity)]
    fn hits(shape: &Shape, rays: &[(V3, V3, f64)]) -> Vec<Option<(f64, V3, [f64; 2], u32)>> {
        rays.iter()
            .map(|&(o, d, tmin)| {
                let h = shape.intersect(o, d, tmin, 100.0);
                if tmin == 0.0 {
                    assert_eq!(shape.occludes(o, d), h.is_some(), "{shape:?} {o:?} {d:?}");
                }
                h.map(|h| (h.t, h.normal, h.uv, h.face))
            })
            .collect()
    }

    /// The analytic shapes against rays worked by hand (dyadic values, so every answer is
    /// exact): the near surface from outside and the far one from inside, each face's own
    /// normal, number and texture coordinates, edges and tangents inclusive, a ray parallel to a
    /// face on its plane, and bounds that touch the surface on every side.
    #[test]
    fn analytic_shapes_answer_rays_worked_by_hand() {
        let sphere = Shape::Sphere { radius: 2.0 };
        assert_eq!(
            sphere.bounds(),
            Bounds {
                min: [-2.0; 3],
                max: [2.0; 3]
            }
        );
        let got = hits(
            &sphere,
            &[
                // From above, the direction not unit: t in its units.
                ([0.0, 5.0, 0.0], [0.0, -2.0, 0.0], 0.0),
                // From inside: the far side, with the outward normal.
                ([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 0.0),
                // From outside past the front (tmin beyond it): the back.
                ([0.0, 0.0, 5.0], [0.0, 0.0, -1.0], 4.0),
                // Tangent at (2, 0, 0), and just past it.
                ([2.0, 0.0, 5.0], [0.0, 0.0, -1.0], 0.0),
                ([2.0 + 1e-9, 0.0, 5.0], [0.0, 0.0, -1.0], 0.0),
                // Pointing away.
                ([0.0, 0.0, 5.0], [0.0, 0.0, 1.0], 0.0),
            ],
        );
        assert_eq!(
            got,
            [
                Some((1.5, [0.0, 1.0, 0.0], [0.5, 1.0], 0)),
                Some((2.0, [0.0, 0.0, -1.0], [0.25, 0.5], 0)),
                Some((7.0, [0.0, 0.0, -1.0], [0.25, 0.5], 0)),
                Some((5.0, [1.0, 0.0, 0.0], [0.5, 0.5], 0)),
                None,
                None,
            ]
        );

        let cube = Shape::Cuboid {
            min: [-1.0, -1.0, -1.0],
            max: [1.0, 2.0, 1.0],
        };
        assert_eq!(
            cube.bounds(),
            Bounds {
                min: [-1.0; 3],
                max: [1.0, 2.0, 1.0]
            }
        );
        let got = hits(
            &cube,
            &[
                ([0.25, 5.0, 0.5], [0.0, -2.0, 0.0], 0.0),
                ([0.25, -5.0, 0.5], [0.0, 1.0, 0.0], 0.0),
                ([-4.0, 0.5, 0.25], [1.0, 0.0, 0.0], 0.0),
                ([0.0, 0.5, 0.25], [1.0, 0.0, 0.0], 0.0),
                ([0.0, 0.5, 5.0], [0.0, 0.0, -1.0], 0.0),
                // Inside: the exit.
                ([0.0, 0.5, 0.0], [0.0, 0.0, 1.0], 0.0),
                // Parallel to the face x = 1, on its plane (the slab is closed), and just off it.
                ([1.0, 5.0, 0.5], [0.0, -1.0, 0.0], 0.0),
                ([1.0 + 1e-9, 5.0, 0.5], [0.0, -1.0, 0.0], 0.0),
                // Through an edge.
                ([1.0, 5.0, 1.0], [0.0, -1.0, 0.0], 0.0),
            ],
        );
        assert_eq!(
            got,
            [
                Some((1.5, [0.0, 1.0, 0.0], [0.5, 0.25], 3)),
                Some((4.0, [0.0, -1.0, 0.0], [0.5, 0.25], 2)),
                Some((3.0, [-1.0, 0.0, 0.0], [0.5, 0.25], 0)),
                Some((1.0, [1.0, 0.0, 0.0], [0.5, 0.25], 1)),
                Some((4.0, [0.0, 0.0, 1.0], [0.0, 0.5], 5)),
                Some((1.0, [0.0, 0.0, 1.0], [0.0, 0.5], 5)),
                Some((3.0, [0.0, 1.0, 0.0], [0.5, 1.0], 3)),
                None,
                Some((3.0, [0.0, 1.0, 0.0], [1.0, 1.0], 3)),
            ]
        );

        let quad = Shape::Quad { half: [2.0, 1.0] };
        assert_eq!(
            quad.bounds(),
            Bounds {
                min: [-2.0, 0.0, -1.0],
                max: [2.0, 0.0, 1.0]
            }
        );
        let got = hits(
            &quad,
            &[
                ([1.5, 3.0, 0.5], [0.0, -1.0, 0.0], 0.0),
                // From below: seen from both sides (the normal stays +y).
                ([-1.5, -3.0, -0.5], [0.0, 1.0, 0.0], 0.0),
                // Its edges and corner inclusive, each axis with its own half extent.
                ([2.0, 3.0, 0.0], [0.0, -1.0, 0.0], 0.0),
                ([0.0, 3.0, -1.0], [0.0, -1.0, 0.0], 0.0),
                ([-2.0, 3.0, 1.0], [0.0, -1.0, 0.0], 0.0),
                ([0.0, 3.0, 1.5], [0.0, -1.0, 0.0], 0.0),
                ([2.0 + 1e-9, 3.0, 0.0], [0.0, -1.0, 0.0], 0.0),
                // Parallel to it.
                ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 0.0),
            ],
        );
        assert_eq!(
            got,
            [
                Some((3.0, [0.0, 1.0, 0.0], [1.5, 0.5], 0)),
                Some((3.0, [0.0, 1.0, 0.0], [-1.5, -0.5], 0)),
                Some((3.0, [0.0, 1.0, 0.0], [2.0, 0.0], 0)),
                Some((3.0, [0.0, 1.0, 0.0], [0.0, -1.0], 0)),
                Some((3.0, [0.0, 1.0, 0.0], [-2.0, 1.0], 0)),
                None,
                None,
                None,
            ]
        );

        // The segment from a = (0, 0.25, 0) to b = (0, −0.25, 0) (axis −y), radius 0.125.
        let cap = Shape::Capsule {
            a: [0.0, 0.25, 0.0],
            b: [0.0, -0.25, 0.0],
            radius: 0.125,
        };
        assert_eq!(
            cap.bounds(),
            Bounds {
                min: [-0.125, -0.375, -0.125],
                max: [0.125, 0.375, 0.125]
            }
        );
        let got = hits(
            &cap,
            &[
                // The body from the side (at its end b too: the body's range is closed), the
                // caps along the axis from either end.
                ([1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], 0.0),
                ([1.0, -0.25, 0.0], [-1.0, 0.0, 0.0], 0.0),
                ([0.0, 1.0, 0.0], [0.0, -1.0, 0.0], 0.0),
                ([0.0, -1.0, 0.0], [0.0, 1.0, 0.0], 0.0),
                // Beside it.
                ([0.25, 0.0, 1.0], [0.0, 0.0, -1.0], 0.0),
            ],
        );
        assert_eq!(
            got.iter()
                .map(|h| h.map(|h| (h.0, h.1, h.3)))
                .collect::<Vec<_>>(),
            [
                Some((0.875, [1.0, 0.0, 0.0], 0)),
                Some((0.875, [1.0, 0.0, 0.0], 0)),
                Some((0.625, [0.0, 1.0, 0.0], 1)),
                Some((0.625, [0.0, -1.0, 0.0], 2)),
                None,
            ]
        );
        // The body's second texture coordinate is the distance along the axis from `a`.
        assert_eq!(got[0].map(|h| h.2[1]), Some(0.25));
        assert_eq!(got[1].map(|h| h.2[1]), Some(0.5));
        // From inside (or from a `tmin` past the front): the ray meets a cap sphere first on
        // its inner half, inside the body, and leaves the capsule through the cap's outer half
        // (these found nothing when only the cap sphere's first root was tried).
        let got = hits(
            &cap,
            &[
                ([0.0, 0.25, 0.0], [0.0, -1.0, 0.0], 0.0),
                ([0.0, 0.0, 0.0], [0.0, 1.0, 0.0], 0.0),
                ([0.0, 1.0, 0.0], [0.0, -1.0, 0.0], 1.0),
            ],
        );
        assert_eq!(
            got.iter()
                .map(|h| h.map(|h| (h.0, h.1, h.3)))
                .collect::<Vec<_>>(),
            [
                Some((0.625, [0.0, -1.0, 0.0], 2)),
                Some((0.375, [0.0, 1.0, 0.0], 1)),
                Some((1.375, [0.0, -1.0, 0.0], 2)),
            ]
        );
    }
}
