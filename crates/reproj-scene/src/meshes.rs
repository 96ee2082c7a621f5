//! Procedural triangle meshes (no external files): parametric surfaces on a `(u, v)` grid.

use std::f64::consts::PI;
use std::sync::Arc;

use crate::math::{add, cross, dot, normalize, scale, sub, V3};
use crate::mesh::{Mesh, Vertex};
use crate::shape::Shape;

/// A closed-or-open parametric surface: `f(u, v) → position` on an `nu × nv` grid of quads over
/// `[0,1]²`, normals by central differences (so they are smooth across the wrap), UV scaled by
/// `uv_scale`. `wrap_u`/`wrap_v` share the seam vertices' neighbours for the normals.
fn parametric(
    nu: usize,
    nv: usize,
    uv_scale: [f64; 2],
    f: impl Fn(f64, f64) -> V3,
    flip: bool,
) -> Shape {
    let h = 1e-5;
    let mut vertices = Vec::with_capacity((nu + 1) * (nv + 1));
    for j in 0..=nv {
        for i in 0..=nu {
            let (u, v) = (i as f64 / nu as f64, j as f64 / nv as f64);
            let p = f(u, v);
            let du = sub(f(u + h, v), f(u - h, v));
            let dv = sub(f(u, v + h), f(u, v - h));
            let mut n = cross(du, dv);
            if dot(n, n) < 1e-40 {
                // A pole: fall back to the direction away from the centre of the ring.
                n = p;
            }
            let n = normalize(if flip { scale(n, -1.0) } else { n });
            vertices.push(Vertex {
                position: p,
                normal: n,
                uv: [u * uv_scale[0], v * uv_scale[1]],
            });
        }
    }
    let mut triangles = Vec::with_capacity(2 * nu * nv);
    let idx = |i: usize, j: usize| (j * (nu + 1) + i) as u32;
    for j in 0..nv {
        for i in 0..nu {
            let (a, b, c, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    Shape::Mesh(Arc::new(Mesh::new(vertices, triangles)))
}

/// A torus about the y axis: ring radius `r_major`, tube radius `r_minor`.
pub fn torus(r_major: f64, r_minor: f64, n_major: usize, n_minor: usize) -> Shape {
    parametric(
        n_major,
        n_minor,
        [8.0, 2.0],
        |u, v| {
            let (a, b) = (2.0 * PI * u, 2.0 * PI * v);
            let r = r_major + r_minor * b.cos();
            [r * a.cos(), r_minor * b.sin(), -r * a.sin()]
        },
        false,
    )
}

/// A surface of revolution about +y: `profile(s) → (radius, height)` for `s ∈ [0,1]`, bottom to
/// top (a column, a vase).
pub fn lathe(profile: impl Fn(f64) -> (f64, f64), n_around: usize, n_along: usize) -> Shape {
    parametric(
        n_around,
        n_along,
        [4.0, 4.0],
        |u, v| {
            let (r, y) = profile(v.clamp(0.0, 1.0));
            let a = 2.0 * PI * u;
            [r * a.cos(), y, -r * a.sin()]
        },
        false,
    )
}

/// A `(p, q)` torus knot as a tube of radius `tube`: a complex, self-shadowing object.
pub fn torus_knot(
    p: f64,
    q: f64,
    radius: f64,
    tube: f64,
    n_along: usize,
    n_around: usize,
) -> Shape {
    let centre = move |s: f64| -> V3 {
        let a = 2.0 * PI * s;
        let r = radius * (0.6 + 0.4 * (q * a).cos());
        [
            r * (p * a).cos(),
            radius * 0.4 * (q * a).sin(),
            r * (p * a).sin(),
        ]
    };
    parametric(
        n_along,
        n_around,
        [24.0, 2.0],
        move |u, v| {
            let c = centre(u);
            let tangent = normalize(sub(centre(u + 1e-4), centre(u - 1e-4)));
            // A frame from the second derivative direction (the knot never has a straight run).
            let acc = sub(
                add(centre(u + 1e-3), centre(u - 1e-3)),
                scale(centre(u), 2.0),
            );
            let nrm = normalize(sub(acc, scale(tangent, dot(acc, tangent))));
            let bin = cross(tangent, nrm);
            let b = 2.0 * PI * v;
            add(
                c,
                add(scale(nrm, tube * b.cos()), scale(bin, tube * b.sin())),
            )
        },
        true,
    )
}

/// A gear-like wheel about the y axis: `teeth` rounded teeth on a disc of `radius` and
/// `thickness`, as a closed lathe-free extrusion (its rim is a radius function of the angle).
pub fn gear(radius: f64, thickness: f64, teeth: usize, n_around: usize) -> Shape {
    let r_of = move |a: f64| radius * (1.0 + 0.12 * (teeth as f64 * a).sin().clamp(-0.6, 0.6));
    parametric(
        n_around,
        8,
        [6.0, 1.0],
        move |u, v| {
            let a = 2.0 * PI * u;
            // v walks: bottom centre → bottom rim → top rim → top centre.
            let (r, y) = if v < 0.25 {
                (r_of(a) * v / 0.25, -thickness / 2.0)
            } else if v < 0.75 {
                (r_of(a), thickness * ((v - 0.25) / 0.5 - 0.5))
            } else {
                (r_of(a) * (1.0 - v) / 0.25, thickness / 2.0)
            };
            [r * a.cos(), y, -r * a.sin()]
        },
        false,
    )
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
}
