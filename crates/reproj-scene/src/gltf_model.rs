//! A glTF model as the renderer holds it once [`crate::gltf`] has decoded it: nodes with their
//! rest transforms, triangle primitives, base-colour materials and textures, skins and animation
//! channels; the node hierarchy's world matrices at any model time; and what one mesh node placed
//! in a scene becomes: its geometry ([`GltfShape`], posed by linear blend skinning when it
//! deforms) and, for a rigid node, its keyframed motion ([`NodeTrack`]). The kinds (static, rigid,
//! deforming) are described in [`crate::gltf`].

use std::path::PathBuf;
use std::sync::Arc;

use glam::{DMat3, DMat4, DQuat, DVec3};

use crate::math::{Rigid, V3};
use crate::mesh::{Bounds, Mesh, Vertex};

/// A decoded texture: linear `[0,1]` RGB, row 0 at `v = 0` (glTF's image convention).
#[derive(Debug, Clone)]
pub struct Texture {
    pub(crate) width: usize,
    pub(crate) height: usize,
    pub(crate) rgb: Vec<[f32; 3]>,
}

impl Texture {
    /// Bilinear sample at `uv` with repeat wrapping (glTF's default sampler).
    pub fn sample(&self, uv: [f64; 2]) -> V3 {
        let (w, h) = (self.width as f64, self.height as f64);
        let x = uv[0] * w - 0.5;
        let y = uv[1] * h - 0.5;
        if !(x.is_finite() && y.is_finite()) {
            return [0.0; 3];
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let at = |i: f64, j: f64| {
            let i = (i as i64).rem_euclid(self.width as i64) as usize;
            let j = (j as i64).rem_euclid(self.height as i64) as usize;
            self.rgb[j * self.width + i].map(f64::from)
        };
        let (a, b, c, d) = (
            at(x0, y0),
            at(x0 + 1.0, y0),
            at(x0, y0 + 1.0),
            at(x0 + 1.0, y0 + 1.0),
        );
        std::array::from_fn(|k| {
            let top = a[k] + (b[k] - a[k]) * fx;
            let bot = c[k] + (d[k] - c[k]) * fx;
            top + (bot - top) * fy
        })
    }
}

/// A glTF material reduced to what the renderer shades: base colour factor and texture.
#[derive(Debug, Clone)]
pub(crate) struct GltfMaterial {
    pub(crate) factor: V3,
    pub(crate) texture: Option<Arc<Texture>>,
}

/// A node's rest transform.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Trs {
    pub(crate) t: DVec3,
    pub(crate) r: DQuat,
    pub(crate) s: DVec3,
}

#[derive(Debug, Clone)]
pub(crate) enum Local {
    Matrix(DMat4),
    Trs(Trs),
}

#[derive(Debug, Clone)]
pub(crate) struct Node {
    pub(crate) local: Local,
    pub(crate) parent: Option<usize>,
    pub(crate) mesh: Option<usize>,
    pub(crate) skin: Option<usize>,
}

/// One triangle primitive, validated.
#[derive(Debug, Clone)]
pub(crate) struct Prim {
    pub(crate) positions: Vec<DVec3>,
    pub(crate) normals: Option<Vec<DVec3>>,
    pub(crate) uvs: Option<Vec<[f64; 2]>>,
    pub(crate) joints: Option<Vec<[u16; 4]>>,
    pub(crate) weights: Option<Vec<[f64; 4]>>,
    pub(crate) triangles: Vec<[u32; 3]>,
    pub(crate) material: Option<usize>,
}

#[derive(Debug, Clone)]
pub(crate) struct Skin {
    pub(crate) joints: Vec<usize>,
    pub(crate) inverse_bind: Vec<DMat4>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Property {
    Translation,
    Rotation,
    Scale,
}

#[derive(Debug, Clone)]
pub(crate) struct Channel {
    pub(crate) node: usize,
    pub(crate) property: Property,
    pub(crate) step: bool,
    pub(crate) times: Vec<f64>,
    pub(crate) values: Vec<[f64; 4]>,
}

impl Channel {
    /// The channel's value at model time `tau` (clamped at the ends; slerp for rotations).
    fn value(&self, tau: f64) -> [f64; 4] {
        let n = self.times.len();
        let i = self.times.partition_point(|&k| k <= tau);
        if i == 0 {
            return self.values[0];
        }
        if i >= n || self.step {
            return self.values[i - 1];
        }
        let (t0, t1) = (self.times[i - 1], self.times[i]);
        let s = if t1 > t0 { (tau - t0) / (t1 - t0) } else { 0.0 };
        let (a, b) = (self.values[i - 1], self.values[i]);
        match self.property {
            Property::Rotation => {
                let qa = DQuat::from_array(a).normalize();
                let qb = DQuat::from_array(b).normalize();
                qa.slerp(qb, s).to_array()
            }
            _ => std::array::from_fn(|k| a[k] + (b[k] - a[k]) * s),
        }
    }
}

/// One animation: its channels and time range.
#[derive(Debug, Clone)]
pub(crate) struct Animation {
    pub(crate) name: String,
    pub(crate) channels: Vec<Channel>,
    pub(crate) start: f64,
    pub(crate) end: f64,
}

/// The files a [`GltfModel`] was loaded from, as SHA-256 digests (64 lower-case hex digits)
/// of the bytes the loader read and decoded when it was built: what the model renders, not
/// what the files hold later (each file is read once; these are not a second read).
///
/// The model file is hashed whole (a GLB with its BIN chunk). `resources` lists each file its
/// glTF document references by a relative URI: every `buffers` entry, then every `images`
/// entry, in the document's order, one digest per entry (an entry naming the same file as
/// another repeats its digest). `data:` URIs, a GLB's BIN chunk and images in buffer views are
/// bytes of the model file (or of a buffer) and not listed. An image that no material uses as
/// its base colour is not decoded, but its file is still read (once) and hashed, so that the
/// list does not depend on which images the renderer uses.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ModelFiles {
    /// SHA-256 (hex) of the model file (`.gltf` or `.glb`).
    pub sha256: String,
    /// SHA-256 (hex) of each file referenced by a relative URI: buffers, then images.
    pub resources: Vec<String>,
}

/// A loaded glTF model (the default scene, or the first one).
#[derive(Debug)]
pub struct GltfModel {
    /// The file it came from.
    pub path: PathBuf,
    /// The SHA-256 of the bytes of the model file and of each external file it references, as
    /// the loader read them ([`ModelFiles`]).
    pub files: ModelFiles,
    pub(crate) nodes: Vec<Node>,
    /// Nodes of the scene, parents before children.
    pub(crate) order: Vec<usize>,
    pub(crate) meshes: Vec<Vec<Prim>>,
    pub(crate) materials: Vec<GltfMaterial>,
    pub(crate) skins: Vec<Skin>,
    pub(crate) animations: Vec<Animation>,
}

impl GltfModel {
    /// Names of the animations, in file order.
    pub fn animation_names(&self) -> Vec<String> {
        self.animations.iter().map(|a| a.name.clone()).collect()
    }

    /// `(start, end)` of animation `a` in model time (seconds).
    pub fn animation_range(&self, a: usize) -> Option<(f64, f64)> {
        self.animations.get(a).map(|a| (a.start, a.end))
    }

    /// Number of triangles over all mesh nodes of the scene.
    pub fn triangle_count(&self) -> usize {
        self.order
            .iter()
            .filter_map(|&n| self.nodes[n].mesh)
            .map(|m| {
                self.meshes[m]
                    .iter()
                    .map(|p| p.triangles.len())
                    .sum::<usize>()
            })
            .sum()
    }

    /// World matrix of every node at model time `tau` under animation `anim`.
    pub(crate) fn world(&self, anim: Option<usize>, tau: f64) -> Vec<DMat4> {
        let mut trs: Vec<Local> = self.nodes.iter().map(|n| n.local.clone()).collect();
        if let Some(a) = anim.and_then(|a| self.animations.get(a)) {
            for ch in &a.channels {
                let v = ch.value(tau);
                if let Local::Trs(x) = &mut trs[ch.node] {
                    match ch.property {
                        Property::Translation => x.t = DVec3::new(v[0], v[1], v[2]),
                        Property::Scale => x.s = DVec3::new(v[0], v[1], v[2]),
                        Property::Rotation => x.r = DQuat::from_array(v).normalize(),
                    }
                }
            }
        }
        let mut world = vec![DMat4::IDENTITY; self.nodes.len()];
        for &n in &self.order {
            let local = match &trs[n] {
                Local::Matrix(m) => *m,
                Local::Trs(x) => DMat4::from_scale_rotation_translation(x.s, x.r, x.t),
            };
            world[n] = match self.nodes[n].parent {
                Some(p) => world[p] * local,
                None => local,
            };
        }
        world
    }

    /// Bounds of the scene at rest (model space, no animation).
    pub fn bounds(&self) -> Bounds {
        let world = self.world(None, 0.0);
        let mut pts = Vec::new();
        for &n in &self.order {
            if let Some(m) = self.nodes[n].mesh {
                for p in &self.meshes[m] {
                    pts.extend(p.positions.iter().map(|&v| {
                        let w = world[n].transform_point3(v);
                        [w.x, w.y, w.z]
                    }));
                }
            }
        }
        Bounds::around(pts)
    }
}

/// Maps scene time to model time: `τ = offset + speed·t`, looped over the animation's range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Clock {
    pub(crate) offset: f64,
    pub(crate) speed: f64,
    pub(crate) start: f64,
    pub(crate) end: f64,
}

impl Clock {
    pub(crate) fn tau(&self, t: f64) -> f64 {
        let tau = self.offset + self.speed * t;
        let len = self.end - self.start;
        if len > 0.0 {
            self.start + (tau - self.start).rem_euclid(len)
        } else {
            self.start
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Kind {
    Static,
    Rigid,
    Deforming,
}

/// One mesh node of a glTF model placed in a scene and what drives it: the animation, the clock
/// from scene to model time and the placement scale. Its geometry ([`GltfShape`]) and, for the
/// rigid kind, its motion ([`NodeTrack`]) share it.
#[derive(Debug, Clone)]
pub(crate) struct PlacedNode {
    pub(crate) model: Arc<GltfModel>,
    pub(crate) node: usize,
    pub(crate) animation: Option<usize>,
    pub(crate) clock: Clock,
    pub(crate) scale: f64,
}

impl PlacedNode {
    /// The node itself.
    fn get(&self) -> &Node {
        &self.model.nodes[self.node]
    }

    /// The world matrix of every node of the model at scene time `t`.
    fn world(&self, t: f64) -> Vec<DMat4> {
        self.model.world(self.animation, self.clock.tau(t))
    }
}

/// The same node of the same loaded model (compared by identity), driven the same way.
impl PartialEq for PlacedNode {
    fn eq(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.model, &other.model)
            && self.node == other.node
            && self.animation == other.animation
            && self.clock == other.clock
            && self.scale == other.scale
    }
}

/// The geometry of one glTF mesh node placed in a scene (see the module docs for the kinds).
pub struct GltfShape {
    pub(crate) placed: PlacedNode,
    pub(crate) kind: Kind,
    /// Rigid kind: the linear part of the node's world matrix at the reference time, baked into
    /// the geometry.
    pub(crate) reference: DMat3,
    /// The geometry at the reference time (scene time 0), in object space.
    pub(crate) rest: Arc<Mesh>,
    /// Material index per triangle (`usize::MAX`: the glTF default material).
    pub(crate) tri_material: Vec<usize>,
}

impl std::fmt::Debug for GltfShape {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GltfShape")
            .field("path", &self.placed.model.path)
            .field("node", &self.placed.node)
            .field("kind", &self.kind)
            .field("rest", &self.rest)
            .finish()
    }
}

impl GltfShape {
    /// The mesh at scene time 0 (what a static snapshot uses).
    pub fn rest(&self) -> &Arc<Mesh> {
        &self.rest
    }

    /// Whether the mesh itself changes with time (skinned or non-rigidly animated).
    pub fn deforms(&self) -> bool {
        self.kind == Kind::Deforming
    }

    /// Whether this is a skinned mesh.
    pub fn skinned(&self) -> bool {
        self.placed.get().skin.is_some()
    }

    /// Albedo of triangle `tri` at `uv`: base colour factor times the base-colour texture.
    pub fn albedo(&self, tri: u32, uv: [f64; 2]) -> V3 {
        let m = self
            .tri_material
            .get(tri as usize)
            .and_then(|&m| self.placed.model.materials.get(m));
        match m {
            Some(m) => match &m.texture {
                Some(tex) => {
                    let c = tex.sample(uv);
                    std::array::from_fn(|k| (c[k] * m.factor[k]).clamp(0.0, 1.0))
                }
                None => m.factor.map(|c| c.clamp(0.0, 1.0)),
            },
            None => [0.8; 3],
        }
    }

    /// The object-space vertices under `world`, the world matrix of every node of the model
    /// (`PlacedNode::world`) at the time they are wanted: computed once by a caller that poses
    /// many nodes at one time, it costs each node its own vertices only (each computing it
    /// made placing a model of n mesh nodes O(n²)).
    fn vertices(&self, world: &[DMat4]) -> Vec<Vertex> {
        let node = self.placed.get();
        let prims = &self.placed.model.meshes[node.mesh.expect("mesh node")];
        let s = self.placed.scale;
        let mut out = Vec::with_capacity(prims.iter().map(|p| p.positions.len()).sum());
        let joints: Option<Vec<DMat4>> = node.skin.map(|k| {
            let skin = &self.placed.model.skins[k];
            skin.joints
                .iter()
                .zip(&skin.inverse_bind)
                .map(|(&j, ib)| world[j] * *ib)
                .collect()
        });
        for p in prims {
            for (v, &pos) in p.positions.iter().enumerate() {
                // The matrix taking this vertex to object space (before the placement scale).
                let m = match (&joints, &p.joints, &p.weights) {
                    (Some(js), Some(jv), Some(wv)) => {
                        let (j, w) = (jv[v], wv[v]);
                        let sum: f64 = w.iter().sum();
                        let norm = if sum > 0.0 { 1.0 / sum } else { 0.0 };
                        let mut acc = DMat4::ZERO;
                        for k in 0..4 {
                            if w[k] != 0.0 {
                                acc += js[j[k] as usize] * (w[k] * norm);
                            }
                        }
                        if sum > 0.0 {
                            acc
                        } else {
                            world[self.placed.node]
                        }
                    }
                    _ => match self.kind {
                        Kind::Rigid => DMat4::from_mat3(self.reference),
                        _ => world[self.placed.node],
                    },
                };
                let q = m.transform_point3(pos) * s;
                let n = p
                    .normals
                    .as_ref()
                    .map(|ns| {
                        let lin = DMat3::from_mat4(m);
                        let it = if lin.determinant().abs() > 1e-300 {
                            lin.inverse().transpose()
                        } else {
                            lin
                        };
                        it * ns[v]
                    })
                    .unwrap_or(DVec3::ZERO);
                out.push(Vertex {
                    position: [q.x, q.y, q.z],
                    normal: [n.x, n.y, n.z],
                    uv: p.uvs.as_ref().map_or([0.0; 2], |u| u[v]),
                });
            }
        }
        out
    }

    fn triangles(&self) -> Vec<[u32; 3]> {
        let node = self.placed.get();
        let mut out = Vec::new();
        let mut base = 0u32;
        for p in &self.placed.model.meshes[node.mesh.expect("mesh node")] {
            out.extend(p.triangles.iter().map(|t| t.map(|i| i + base)));
            base += p.positions.len() as u32;
        }
        out
    }

    /// The mesh posed at scene time `t` with its BVH built (deforming kind only).
    pub(crate) fn posed(&self, t: f64) -> Mesh {
        self.posed_in(&self.placed.world(t))
    }

    /// [`GltfShape::posed`] under the world matrices of every node at the time wanted.
    pub(crate) fn posed_in(&self, world: &[DMat4]) -> Mesh {
        Mesh::new(self.vertices(world), self.triangles())
    }
}

/// The rigid motion of a rigid-kind glTF node: its world matrix at model time `τ(t)` relative to
/// the reference, with the placement scale applied to the translation.
#[derive(Debug)]
pub struct NodeTrack {
    pub(crate) placed: PlacedNode,
    pub(crate) inv_reference: DMat3,
}

/// `inv_reference` follows from the placed node, so it is not compared.
impl PartialEq for NodeTrack {
    fn eq(&self, other: &Self) -> bool {
        self.placed == other.placed
    }
}

impl NodeTrack {
    /// The transform at scene time `t`.
    pub fn at(&self, t: f64) -> Rigid {
        let w = self.placed.world(t)[self.placed.node];
        let r = DMat3::from_mat4(w) * self.inv_reference;
        let tr = w.w_axis.truncate() * self.placed.scale;
        Rigid {
            // DMat3 is column-major; Rigid is row-major.
            rot: std::array::from_fn(|i| std::array::from_fn(|j| r.col(j)[i])),
            trans: [tr.x, tr.y, tr.z],
        }
    }
}
