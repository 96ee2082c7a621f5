//! glTF 2.0 models: loading (meshes, node hierarchy, base-colour textures, node animation,
//! skins), placement into a scene, and the time-dependent geometry of skinned meshes.
//!
//! Every mesh node of the model's scene becomes one [`Object`] whose shape is a
//! [`Shape::Gltf`]. Three kinds, chosen per node at placement:
//!
//! - **static**: nothing on the node's chain is animated; the geometry is baked into the scene's
//!   object space once (node world matrix and placement scale applied).
//! - **rigid**: unskinned and animated, with a world matrix `A(τ)` whose linear part stays a
//!   rotation of its reference value (`A(τ)·A(τ₀)⁻¹` orthonormal at every key time). The
//!   geometry is baked at `τ₀` and the motion maps onto the existing per-object
//!   transform-of-time machinery ([`Anim::Keyframes`]), so the mesh BVH is built once and motion
//!   is the exact rigid motion, as for the built-in objects.
//! - **deforming**: skinned (linear blend skinning), or animated non-rigidly (animated scale,
//!   shear through a scaled parent). The scene's snapshot at time `t` poses the vertices at `t`
//!   and builds that mesh's BVH (once per snapshot, i.e. per time value of a frame render). A
//!   material point is (object, triangle, barycentrics): at another time it is the same triangle
//!   and barycentrics on the mesh posed then, which makes non-rigid motion and shadow tracking
//!   exact.
//!
//! Colours: the base-colour factor times the base-colour texture (bilinear, repeat wrap), both
//! taken as the renderer's linear `[0,1]` albedo like every procedural material (the renderer does
//! no sRGB conversion anywhere). Morph targets are not applied (their weight channels are
//! ignored); the `CUBICSPLINE` interpolation, non-triangle primitives and texture coordinate sets
//! other than 0 are refused with [`SceneError::GltfUnsupported`].
//!
//! The file is untrusted: every accessor is checked against its buffer by the `gltf` crate's
//! reader, vertex indices, joint indices and attribute lengths are validated before use, and a
//! panic inside the decoder is turned into an error naming the file.

use std::f64::consts::PI;
use std::path::Path;
use std::sync::Arc;

use glam::{DMat3, DMat4, DQuat, DVec3};

use crate::anim::Anim;
use crate::error::{Result, SceneError};
use crate::gltf_model::{
    Animation, Channel, Clock, GltfMaterial, Kind, Local, Node, Prim, Property, Skin, Trs,
};
pub use crate::gltf_model::{GltfModel, GltfShape, NodeTrack, Texture};
use crate::material::{Material, Pattern};
use crate::math::{add, scale, Rigid};
use crate::mesh::Mesh;
use crate::rig::CameraPath;
use crate::scene::{Light, Object, Scene, Variant};
use crate::shape::Shape;

fn err(path: &Path, problem: impl Into<String>) -> SceneError {
    SceneError::Gltf {
        path: path.display().to_string(),
        problem: problem.into(),
    }
}

fn unsupported(path: &Path, what: impl Into<String>) -> SceneError {
    SceneError::GltfUnsupported {
        path: path.display().to_string(),
        what: what.into(),
    }
}

impl GltfModel {
    /// Loads and validates a `.gltf` (with its buffers and textures) or `.glb` file.
    ///
    /// # Errors
    /// [`SceneError::Gltf`] for an unreadable or malformed file, a missing buffer or texture file
    /// or an out-of-range index; [`SceneError::GltfUnsupported`] for features the renderer does
    /// not implement. Both name the file.
    pub fn load(path: impl AsRef<Path>) -> Result<GltfModel> {
        let path = path.as_ref();
        // The decoders index untrusted data; a panic there must become an error, not an abort
        // of the caller.
        std::panic::catch_unwind(|| load_inner(path))
            .unwrap_or_else(|_| Err(err(path, "the glTF decoder panicked on malformed data")))
    }
}

fn load_inner(path: &Path) -> Result<GltfModel> {
    let gltf::Gltf { document, blob } = gltf::Gltf::open(path).map_err(|e| match e {
        gltf::Error::Io(e) => err(path, format!("cannot read the file: {e}")),
        e => err(path, format!("malformed glTF: {e}")),
    })?;
    let base = path.parent().unwrap_or(Path::new("."));
    if let Some(ext) = document.extensions_required().next() {
        return Err(unsupported(path, format!("required extension {ext}")));
    }
    let buffers = gltf::import_buffers(&document, Some(base), blob).map_err(|e| {
        let uris: Vec<String> = document
            .buffers()
            .filter_map(|b| match b.source() {
                gltf::buffer::Source::Uri(u) if !u.starts_with("data:") => Some(u.to_string()),
                _ => None,
            })
            .collect();
        err(
            path,
            format!("cannot load a buffer (external: {uris:?}): {e}"),
        )
    })?;
    for b in document.buffers() {
        if buffers[b.index()].len() < b.length() {
            return Err(err(
                path,
                format!(
                    "buffer {} holds {} bytes, the file declares {}",
                    b.index(),
                    buffers[b.index()].len(),
                    b.length()
                ),
            ));
        }
    }

    // Textures: only the base-colour ones are decoded (FlightHelmet's normal and ORM maps would
    // cost seconds for nothing).
    let mut decoded: Vec<Option<Arc<Texture>>> = vec![None; document.images().len()];
    let mut materials = Vec::new();
    for m in document.materials() {
        let pbr = m.pbr_metallic_roughness();
        let f = pbr.base_color_factor();
        let texture = match pbr.base_color_texture() {
            Some(info) => {
                if info.tex_coord() != 0 {
                    return Err(unsupported(
                        path,
                        format!(
                            "material {} uses TEXCOORD_{}",
                            m.index().unwrap_or(0),
                            info.tex_coord()
                        ),
                    ));
                }
                let image = info.texture().source();
                let i = image.index();
                if decoded[i].is_none() {
                    decoded[i] = Some(Arc::new(decode_image(path, base, &image, &buffers)?));
                }
                decoded[i].clone()
            }
            None => None,
        };
        materials.push(GltfMaterial {
            factor: [f[0] as f64, f[1] as f64, f[2] as f64],
            texture,
        });
    }

    let mut meshes = Vec::new();
    for mesh in document.meshes() {
        let mut prims = Vec::new();
        for (k, p) in mesh.primitives().enumerate() {
            prims.push(read_primitive(path, mesh.index(), k, &p, &buffers)?);
        }
        meshes.push(prims);
    }

    let mut nodes: Vec<Node> = document
        .nodes()
        .map(|n| Node {
            local: match n.transform() {
                gltf::scene::Transform::Matrix { matrix } => {
                    Local::Matrix(DMat4::from_cols_array_2d(&matrix.map(|c| c.map(f64::from))))
                }
                gltf::scene::Transform::Decomposed {
                    translation,
                    rotation,
                    scale,
                } => Local::Trs(Trs {
                    t: DVec3::from_array(translation.map(f64::from)),
                    r: DQuat::from_array(rotation.map(f64::from)).normalize(),
                    s: DVec3::from_array(scale.map(f64::from)),
                }),
            },
            parent: None,
            mesh: n.mesh().map(|m| m.index()),
            skin: n.skin().map(|s| s.index()),
        })
        .collect();
    for n in document.nodes() {
        for c in n.children() {
            if nodes[c.index()].parent.is_some() || c.index() == n.index() {
                return Err(err(
                    path,
                    format!("node {} has more than one parent", c.index()),
                ));
            }
            nodes[c.index()].parent = Some(n.index());
        }
    }
    let scene = document
        .default_scene()
        .or_else(|| document.scenes().next())
        .ok_or_else(|| err(path, "no scene"))?;
    let mut order = Vec::new();
    let mut stack: Vec<usize> = scene.nodes().map(|n| n.index()).collect();
    stack.reverse();
    let mut seen = vec![false; nodes.len()];
    while let Some(n) = stack.pop() {
        if std::mem::replace(&mut seen[n], true) {
            return Err(err(path, format!("node {n} is reached twice (a cycle?)")));
        }
        order.push(n);
        let node = document.nodes().nth(n).expect("index from the document");
        stack.extend(node.children().map(|c| c.index()));
    }

    let mut skins = Vec::new();
    for s in document.skins() {
        let joints: Vec<usize> = s.joints().map(|j| j.index()).collect();
        let reader = s.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let inverse_bind: Vec<DMat4> = match s.inverse_bind_matrices() {
            Some(_) => reader
                .read_inverse_bind_matrices()
                .ok_or_else(|| {
                    err(
                        path,
                        format!("skin {}: unreadable inverseBindMatrices", s.index()),
                    )
                })?
                .map(|m| DMat4::from_cols_array_2d(&m.map(|c| c.map(f64::from))))
                .collect(),
            None => vec![DMat4::IDENTITY; joints.len()],
        };
        if inverse_bind.len() < joints.len() {
            return Err(err(
                path,
                format!(
                    "skin {}: {} inverse bind matrices for {} joints",
                    s.index(),
                    inverse_bind.len(),
                    joints.len()
                ),
            ));
        }
        skins.push(Skin {
            joints,
            inverse_bind,
        });
    }
    for &n in &order {
        if let (Some(m), Some(s)) = (nodes[n].mesh, nodes[n].skin) {
            let nj = skins[s].joints.len();
            for (k, p) in meshes[m].iter().enumerate() {
                let (Some(j), Some(_)) = (&p.joints, &p.weights) else {
                    return Err(err(
                        path,
                        format!("mesh {m} primitive {k} is skinned without JOINTS_0/WEIGHTS_0"),
                    ));
                };
                if let Some(bad) = j.iter().flatten().find(|&&x| x as usize >= nj) {
                    return Err(err(
                        path,
                        format!("mesh {m} primitive {k}: joint index {bad} out of range (skin {s} has {nj} joints)"),
                    ));
                }
            }
        }
    }

    let mut animations = Vec::new();
    for a in document.animations() {
        let mut channels = Vec::new();
        for ch in a.channels() {
            let target = ch.target();
            let property = match target.property() {
                gltf::animation::Property::Translation => Property::Translation,
                gltf::animation::Property::Rotation => Property::Rotation,
                gltf::animation::Property::Scale => Property::Scale,
                // Morph targets are not applied, so their weights have nothing to drive.
                gltf::animation::Property::MorphTargetWeights => continue,
            };
            let step = match ch.sampler().interpolation() {
                gltf::animation::Interpolation::Linear => false,
                gltf::animation::Interpolation::Step => true,
                gltf::animation::Interpolation::CubicSpline => {
                    return Err(unsupported(
                        path,
                        format!("animation {} uses CUBICSPLINE interpolation", a.index()),
                    ))
                }
            };
            let reader = ch.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let bad = || {
                err(
                    path,
                    format!(
                        "animation {} channel {}: unreadable sampler data",
                        a.index(),
                        ch.index()
                    ),
                )
            };
            let times: Vec<f64> = reader
                .read_inputs()
                .ok_or_else(bad)?
                .map(f64::from)
                .collect();
            let values: Vec<[f64; 4]> = match reader.read_outputs().ok_or_else(bad)? {
                gltf::animation::util::ReadOutputs::Translations(it)
                | gltf::animation::util::ReadOutputs::Scales(it) => it
                    .map(|v| [v[0] as f64, v[1] as f64, v[2] as f64, 0.0])
                    .collect(),
                gltf::animation::util::ReadOutputs::Rotations(r) => {
                    r.into_f32().map(|q| q.map(f64::from)).collect()
                }
                gltf::animation::util::ReadOutputs::MorphTargetWeights(_) => continue,
            };
            if times.is_empty() || values.len() != times.len() {
                return Err(err(
                    path,
                    format!(
                        "animation {} channel {}: {} key times for {} values",
                        a.index(),
                        ch.index(),
                        times.len(),
                        values.len()
                    ),
                ));
            }
            if times.windows(2).any(|w| !(w[1] >= w[0])) || !times.iter().all(|t| t.is_finite()) {
                return Err(err(
                    path,
                    format!(
                        "animation {} channel {}: key times not increasing",
                        a.index(),
                        ch.index()
                    ),
                ));
            }
            if matches!(nodes[target.node().index()].local, Local::Matrix(_)) {
                return Err(err(
                    path,
                    format!(
                        "animation {} targets node {}, which has a matrix",
                        a.index(),
                        target.node().index()
                    ),
                ));
            }
            channels.push(Channel {
                node: target.node().index(),
                property,
                step,
                times,
                values,
            });
        }
        let start = channels
            .iter()
            .map(|c| c.times[0])
            .fold(f64::INFINITY, f64::min);
        let end = channels
            .iter()
            .map(|c| c.times[c.times.len() - 1])
            .fold(f64::NEG_INFINITY, f64::max);
        animations.push(Animation {
            name: a.name().unwrap_or("").to_string(),
            channels,
            start: if start.is_finite() { start } else { 0.0 },
            end: if end.is_finite() { end } else { 0.0 },
        });
    }

    Ok(GltfModel {
        path: path.to_path_buf(),
        nodes,
        order,
        meshes,
        materials,
        skins,
        animations,
    })
}

fn decode_image(
    path: &Path,
    base: &Path,
    image: &gltf::Image<'_>,
    buffers: &[gltf::buffer::Data],
) -> Result<Texture> {
    let what = match image.source() {
        gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") => {
            format!("texture file {uri:?}")
        }
        _ => format!("embedded image {}", image.index()),
    };
    let data = gltf::image::Data::from_source(image.source(), Some(base), buffers)
        .map_err(|e| err(path, format!("cannot load {what}: {e}")))?;
    use gltf::image::Format;
    let ch = match data.format {
        Format::R8 => 1,
        Format::R8G8 => 2,
        Format::R8G8B8 => 3,
        Format::R8G8B8A8 => 4,
        f => return Err(unsupported(path, format!("{what} has pixel format {f:?}"))),
    };
    let (w, h) = (data.width as usize, data.height as usize);
    if w == 0 || h == 0 || data.pixels.len() < w * h * ch {
        return Err(err(path, format!("{what} is empty or truncated")));
    }
    let rgb = data
        .pixels
        .chunks_exact(ch)
        .take(w * h)
        .map(|p| {
            let c = |k: usize| f32::from(p[if ch < 3 { 0 } else { k }]) / 255.0;
            [c(0), c(1), c(2)]
        })
        .collect();
    Ok(Texture {
        width: w,
        height: h,
        rgb,
    })
}

fn read_primitive(
    path: &Path,
    mesh: usize,
    k: usize,
    p: &gltf::Primitive<'_>,
    buffers: &[gltf::buffer::Data],
) -> Result<Prim> {
    let here = |problem: String| err(path, format!("mesh {mesh} primitive {k}: {problem}"));
    if p.mode() != gltf::mesh::Mode::Triangles {
        return Err(unsupported(
            path,
            format!(
                "mesh {mesh} primitive {k} has mode {:?} (only TRIANGLES)",
                p.mode()
            ),
        ));
    }
    let reader = p.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
    let positions: Vec<DVec3> = reader
        .read_positions()
        .ok_or_else(|| here("missing or unreadable POSITION".into()))?
        .map(|v| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64))
        .collect();
    let n = positions.len();
    let same = |what: &str, len: usize| {
        if len == n {
            Ok(())
        } else {
            Err(here(format!("{what} has {len} entries for {n} vertices")))
        }
    };
    let normals = match reader.read_normals() {
        Some(it) => {
            let v: Vec<DVec3> = it
                .map(|v| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64))
                .collect();
            same("NORMAL", v.len())?;
            Some(v)
        }
        None => None,
    };
    let uvs = match reader.read_tex_coords(0) {
        Some(it) => {
            let v: Vec<[f64; 2]> = it.into_f32().map(|v| [v[0] as f64, v[1] as f64]).collect();
            same("TEXCOORD_0", v.len())?;
            Some(v)
        }
        None => None,
    };
    let joints = match reader.read_joints(0) {
        Some(it) => {
            let v: Vec<[u16; 4]> = it.into_u16().collect();
            same("JOINTS_0", v.len())?;
            Some(v)
        }
        None => None,
    };
    let weights = match reader.read_weights(0) {
        Some(it) => {
            let v: Vec<[f64; 4]> = it.into_f32().map(|w| w.map(f64::from)).collect();
            same("WEIGHTS_0", v.len())?;
            Some(v)
        }
        None => None,
    };
    let flat: Vec<u32> = match p.indices() {
        Some(_) => reader
            .read_indices()
            .ok_or_else(|| here("unreadable indices".into()))?
            .into_u32()
            .collect(),
        None => (0..n as u32).collect(),
    };
    if flat.len() % 3 != 0 {
        return Err(here(format!(
            "{} indices is not a multiple of 3",
            flat.len()
        )));
    }
    if let Some((i, &bad)) = flat.iter().enumerate().find(|(_, &x)| x as usize >= n) {
        return Err(here(format!(
            "vertex index {bad} at position {i} is out of range ({n} vertices)"
        )));
    }
    Ok(Prim {
        positions,
        normals,
        uvs,
        joints,
        weights,
        triangles: flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
        material: p.material().index(),
    })
}

/// Where and how a glTF model is put into a scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    /// Rigid placement of the model's space in the world.
    pub place: Rigid,
    /// Uniform scale applied to the model first (glTF is in metres, but many models are not).
    pub scale: f64,
    /// Which animation plays (`None`: the rest pose).
    pub animation: Option<usize>,
    /// Model time at scene time 0 (seconds).
    pub time_offset: f64,
    /// Model seconds per scene second.
    pub speed: f64,
}

impl Default for Placement {
    fn default() -> Self {
        Placement {
            place: Rigid::IDENTITY,
            scale: 1.0,
            animation: Some(0),
            time_offset: 0.0,
            speed: 1.0,
        }
    }
}

/// Loads `path` and adds its mesh nodes to `scene` as objects (see the module docs); returns
/// their indices. Extra motions can be appended to the returned objects' `anims` (e.g. an
/// [`Anim::Circle`] to make a walking model go round) before [`Scene::refresh`].
///
/// # Errors
/// As [`GltfModel::load`]; [`SceneError::Gltf`] for an animation index out of range or a
/// non-positive scale.
pub fn place_gltf(
    scene: &mut Scene,
    path: impl AsRef<Path>,
    placement: Placement,
) -> Result<Vec<usize>> {
    let model = Arc::new(GltfModel::load(path.as_ref())?);
    place_model(scene, &model, placement)
}

/// [`place_gltf`] for an already loaded model (several instances share its data).
///
/// # Errors
/// As [`place_gltf`].
pub fn place_model(
    scene: &mut Scene,
    model: &Arc<GltfModel>,
    placement: Placement,
) -> Result<Vec<usize>> {
    let path = &model.path;
    if !(placement.scale > 0.0 && placement.scale.is_finite()) {
        return Err(err(
            path,
            format!("placement scale {} must be positive", placement.scale),
        ));
    }
    let animation = match placement.animation {
        Some(a) if a >= model.animations.len() => {
            if model.animations.is_empty() {
                None
            } else {
                return Err(err(
                    path,
                    format!(
                        "animation {a} out of range ({} animations)",
                        model.animations.len()
                    ),
                ));
            }
        }
        a => a,
    };
    let (start, end) = animation.map_or((0.0, 0.0), |a| {
        (model.animations[a].start, model.animations[a].end)
    });
    let clock = Clock {
        offset: placement.time_offset + start,
        speed: placement.speed,
        start,
        end,
    };
    let mut added = Vec::new();
    let stem = path
        .file_stem()
        .map_or("gltf".into(), |s| s.to_string_lossy().to_string());
    for &n in &model.order {
        let node = &model.nodes[n];
        let Some(m) = node.mesh else { continue };
        if model.meshes[m].iter().all(|p| p.triangles.is_empty()) {
            continue;
        }
        let animated = model.animated(animation, n);
        let tau0 = clock.tau(0.0);
        let reference = DMat3::from_mat4(model.world(animation, tau0)[n]);
        let kind = if let Some(skin) = node.skin {
            // Skinned: deforms when any joint moves; a rest skin is still posed once.
            let moving = model.skins[skin]
                .joints
                .iter()
                .any(|&j| model.animated(animation, j));
            if moving {
                Kind::Deforming
            } else {
                Kind::Static
            }
        } else if !animated {
            Kind::Static
        } else if rigid_over_keys(model, animation, n, reference) {
            Kind::Rigid
        } else {
            Kind::Deforming
        };
        let mut shape = GltfShape {
            model: model.clone(),
            node: n,
            animation,
            clock,
            scale: placement.scale,
            kind,
            reference,
            rest: Arc::new(Mesh::new(Vec::new(), Vec::new())),
            tri_material: Vec::new(),
        };
        shape.tri_material = model.meshes[m]
            .iter()
            .flat_map(|p| std::iter::repeat_n(p.material.unwrap_or(usize::MAX), p.triangles.len()))
            .collect();
        shape.rest = Arc::new(shape.posed(0.0));
        let mut anims = Vec::new();
        if kind == Kind::Rigid {
            let inv = reference.inverse();
            anims.push(Anim::Keyframes(Arc::new(NodeTrack {
                model: model.clone(),
                node: n,
                animation,
                clock,
                scale: placement.scale,
                inv_reference: inv,
            })));
        }
        let name = format!("{stem}/node{n}");
        let mut o = Object::new(
            &name,
            Shape::Gltf(Arc::new(shape)),
            Material::matte(Pattern::Checker, [0.8; 3], [0.8; 3], 1.0, 0),
            placement.place,
        )
        .animated(anims);
        // Rigid and static kinds bake the translation of the node at the reference time into the
        // track or the geometry respectively; nothing else to do here.
        o.casts_shadow = true;
        added.push(scene.objects.len());
        scene.objects.push(o);
    }
    scene.refresh()?;
    Ok(added)
}

/// Whether node `n`'s world linear part stays `R(τ)·reference` with `R` a rotation at every key
/// time of the animation and halfway between.
fn rigid_over_keys(
    model: &GltfModel,
    animation: Option<usize>,
    n: usize,
    reference: DMat3,
) -> bool {
    if reference.determinant().abs() < 1e-12 {
        return false;
    }
    let inv = reference.inverse();
    let Some(a) = animation.and_then(|a| model.animations.get(a)) else {
        return true;
    };
    let mut times: Vec<f64> = a
        .channels
        .iter()
        .flat_map(|c| c.times.iter().copied())
        .collect();
    times.sort_by(f64::total_cmp);
    times.dedup();
    let mids: Vec<f64> = times.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
    times.extend(mids);
    times.iter().all(|&tau| {
        let r = DMat3::from_mat4(model.world(animation, tau)[n]) * inv;
        let e = r.transpose() * r - DMat3::IDENTITY;
        e.to_cols_array().iter().all(|x| x.abs() < 1e-9) && r.determinant() > 0.0
    })
}
/// A scene holding only the model at `path` (its first animation playing from its start, scaled
/// to about 1.7 m tall when it is far from human size) on a light ground, under the
/// courtyard's kind of light, with a camera path circling slowly around the model's bounds.
///
/// # Errors
/// As [`place_gltf`].
pub fn load_gltf_scene(path: impl AsRef<Path>) -> Result<Scene> {
    let path = path.as_ref();
    let model = Arc::new(GltfModel::load(path)?);
    let b = model.bounds();
    let size = (0..3).map(|k| b.max[k] - b.min[k]).fold(0.0, f64::max);
    if !(size > 0.0 && size.is_finite()) {
        return Err(err(path, "the scene has no geometry"));
    }
    let s = if !(0.2..=20.0).contains(&size) {
        1.7 / size
    } else {
        1.0
    };
    let centre = scale(add(b.min, b.max), 0.5 * s);
    // Stand the model on the ground at y = 0, centred on the origin.
    let place = Rigid::translation([-centre[0], -b.min[1] * s, -centre[2]]);
    let duration = model
        .animations
        .first()
        .map_or(4.0, |a| (a.end - a.start).clamp(1.0, 20.0));
    let radius = 0.5 * size * s;
    let light = Light {
        elevation: 0.8,
        azimuth: 0.6,
        swing: 0.0,
        swing_rate: 0.0,
        elevation_swing: 0.0,
        angular_radius: 0.02,
        color: [1.0, 0.96, 0.9],
        ambient_sky: [0.32, 0.36, 0.42],
        ambient_ground: [0.2, 0.18, 0.16],
    };
    let look = [0.0, (b.max[1] - b.min[1]) * s * 0.5, 0.0];
    let dist = 2.4 * radius.max(0.3);
    let keys = (0..=8)
        .map(|k| {
            let a = 0.25 + 0.5 * PI * k as f64 / 8.0;
            let time = duration * k as f64 / 8.0;
            (
                time,
                [dist * a.sin(), look[1] + 0.4 * dist, dist * a.cos()],
                look,
            )
        })
        .collect();
    let path_cam = CameraPath {
        keys,
        translation_amplitude: 0.02 * dist,
        rotation_amplitude: 0.01,
        seed: 3,
    };
    let ground = Object::new(
        "ground",
        Shape::Quad {
            half: [20.0 * radius.max(0.3), 20.0 * radius.max(0.3)],
        },
        Material::matte(
            Pattern::Tiles,
            [0.7, 0.7, 0.68],
            [0.45, 0.45, 0.43],
            4.0,
            11,
        ),
        Rigid::IDENTITY,
    );
    let mut scene = Scene::new(
        &path.display().to_string(),
        Variant::Dynamic,
        vec![ground],
        light,
        [150, 185, 230],
        duration,
        (0.05 * dist.min(1.0), 100.0 * dist),
        path_cam,
    )?;
    place_model(
        &mut scene,
        &model,
        Placement {
            place,
            scale: s,
            ..Placement::default()
        },
    )?;
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{sub, V3};
    use crate::render::{render_ground_truth, render_server, sample, Rays};
    use crate::rig::{mono, HeadPose};
    use reproj_core::Camera;
    use std::path::PathBuf;

    const DT: f64 = 0.1;

    fn base64(data: &[u8]) -> String {
        const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut out = String::new();
        for c in data.chunks(3) {
            let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
            let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
            for k in 0..4 {
                if k <= c.len() {
                    out.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
                } else {
                    out.push('=');
                }
            }
        }
        out
    }

    /// Buffer builder: appends little-endian data aligned to 4 and returns (offset, length).
    #[derive(Default)]
    struct Buf(Vec<u8>);
    impl Buf {
        fn f32s(&mut self, v: &[f32]) -> (usize, usize) {
            let o = self.0.len();
            v.iter()
                .for_each(|x| self.0.extend_from_slice(&x.to_le_bytes()));
            (o, self.0.len() - o)
        }
        fn u16s(&mut self, v: &[u16]) -> (usize, usize) {
            let o = self.0.len();
            v.iter()
                .for_each(|x| self.0.extend_from_slice(&x.to_le_bytes()));
            while self.0.len() % 4 != 0 {
                self.0.push(0);
            }
            (o, 2 * v.len())
        }
    }

    /// Strip vertex `i` (0..18): column `i / 2` at x = 0.25·column, row y = 0 or 0.2.
    fn strip_rest(i: usize) -> [f32; 3] {
        [(i / 2) as f32 * 0.25, (i % 2) as f32 * 0.2, 0.0]
    }

    /// Where the tests write their models: under the workspace's `target/`, so that repeated
    /// runs do not litter the system's temporary directory and `cargo clean` removes them.
    fn test_dir() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/test-tmp")
    }

    /// Writes the test model into a fresh directory: a textured quad (2×2 texture: red, green /
    /// blue, white) translated at 1 m/s along x by a LINEAR channel, and a strip skinned to two
    /// joints, the second rotating about z by 22.5°/s around the strip's middle, (1, 0, 0).
    /// `bad_index` puts an out-of-range vertex index into the quad; `texture` names its image.
    fn write_model(name: &str, texture: &str, bad_index: bool) -> PathBuf {
        let dir = test_dir().join(format!("reproj-gltf-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let img = image::RgbImage::from_fn(2, 2, |x, y| {
            image::Rgb(match (x, y) {
                (0, 0) => [255, 0, 0],
                (1, 0) => [0, 255, 0],
                (0, 1) => [0, 0, 255],
                _ => [255, 255, 255],
            })
        });
        img.save(dir.join("tex.png")).unwrap();
        let mut b = Buf::default();
        let qp = b.f32s(&[
            -0.5, -0.5, 0.0, 0.5, -0.5, 0.0, 0.5, 0.5, 0.0, -0.5, 0.5, 0.0,
        ]);
        let qn = b.f32s(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0]);
        let qt = b.f32s(&[0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]);
        let qi = b.u16s(&[0, 1, 2, 0, 2, if bad_index { 99 } else { 3 }]);
        let sp: Vec<f32> = (0..18).flat_map(strip_rest).collect();
        let sp = b.f32s(&sp);
        let sn = b.f32s(&[0.0, 0.0, 1.0].repeat(18));
        let joints: Vec<u16> = (0..18).flat_map(|_| [0u16, 1, 0, 0]).collect();
        let sj = b.u16s(&joints);
        let weights: Vec<f32> = (0..18)
            .flat_map(|i| {
                let x = strip_rest(i)[0];
                let w1 = if x < 1.0 {
                    0.0
                } else if x == 1.0 {
                    0.5
                } else {
                    1.0
                };
                [1.0 - w1, w1, 0.0, 0.0]
            })
            .collect();
        let sw = b.f32s(&weights);
        let si: Vec<u16> = (0..8u16)
            .flat_map(|c| [2 * c, 2 * c + 2, 2 * c + 3, 2 * c, 2 * c + 3, 2 * c + 1])
            .collect();
        let si = b.u16s(&si);
        #[rustfmt::skip]
        let ibm = b.f32s(&[
            1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
            1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 1.0,
        ]);
        let times = b.f32s(&[0.0, 4.0]);
        let trans = b.f32s(&[0.0, 1.0, 0.0, 4.0, 1.0, 0.0]);
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let rots = b.f32s(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, h, h]);
        let views = [qp, qn, qt, qi, sp, sn, sj, sw, si, ibm, times, trans, rots];
        let views_json: Vec<String> = views
            .iter()
            .map(|(o, l)| format!(r#"{{"buffer":0,"byteOffset":{o},"byteLength":{l}}}"#))
            .collect();
        let acc = |v: usize, ct: u32, n: usize, ty: &str, extra: &str| {
            format!(r#"{{"bufferView":{v},"componentType":{ct},"count":{n},"type":"{ty}"{extra}}}"#)
        };
        let accessors = [
            acc(
                0,
                5126,
                4,
                "VEC3",
                r#","min":[-0.5,-0.5,0],"max":[0.5,0.5,0]"#,
            ),
            acc(1, 5126, 4, "VEC3", ""),
            acc(2, 5126, 4, "VEC2", ""),
            acc(3, 5123, 6, "SCALAR", ""),
            acc(4, 5126, 18, "VEC3", r#","min":[0,0,0],"max":[2,0.2,0]"#),
            acc(5, 5126, 18, "VEC3", ""),
            acc(6, 5123, 18, "VEC4", ""),
            acc(7, 5126, 18, "VEC4", ""),
            acc(8, 5123, 48, "SCALAR", ""),
            acc(9, 5126, 2, "MAT4", ""),
            acc(10, 5126, 2, "SCALAR", r#","min":[0],"max":[4]"#),
            acc(11, 5126, 2, "VEC3", ""),
            acc(12, 5126, 2, "VEC4", ""),
        ];
        let json = format!(
            r#"{{
  "asset": {{"version": "2.0"}},
  "scene": 0,
  "scenes": [{{"nodes": [0, 1, 2]}}],
  "nodes": [
    {{"name": "quad", "mesh": 0, "translation": [0, 1, 0]}},
    {{"name": "strip", "mesh": 1, "skin": 0}},
    {{"name": "root", "translation": [0, 0, 0], "children": [3]}},
    {{"name": "tip", "translation": [1, 0, 0]}}
  ],
  "meshes": [
    {{"primitives": [{{"attributes": {{"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}}, "indices": 3, "material": 0}}]}},
    {{"primitives": [{{"attributes": {{"POSITION": 4, "NORMAL": 5, "JOINTS_0": 6, "WEIGHTS_0": 7}}, "indices": 8}}]}}
  ],
  "skins": [{{"joints": [2, 3], "inverseBindMatrices": 9}}],
  "materials": [{{"pbrMetallicRoughness": {{"baseColorTexture": {{"index": 0}}}}}}],
  "textures": [{{"source": 0}}],
  "images": [{{"uri": "{texture}"}}],
  "animations": [{{"channels": [
      {{"sampler": 0, "target": {{"node": 0, "path": "translation"}}}},
      {{"sampler": 1, "target": {{"node": 3, "path": "rotation"}}}}],
    "samplers": [
      {{"input": 10, "output": 11, "interpolation": "LINEAR"}},
      {{"input": 10, "output": 12, "interpolation": "LINEAR"}}]}}],
  "accessors": [{}],
  "bufferViews": [{}],
  "buffers": [{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{}"}}]
}}"#,
            accessors.join(","),
            views_json.join(","),
            b.0.len(),
            base64(&b.0)
        );
        let path = dir.join("model.gltf");
        std::fs::write(&path, json).unwrap();
        path
    }

    fn empty_scene() -> Scene {
        let eye = [0.0, 0.0, 4.0];
        Scene::new(
            "test",
            Variant::Dynamic,
            Vec::new(),
            Light {
                elevation: 0.9,
                azimuth: 0.3,
                swing: 0.0,
                swing_rate: 0.0,
                elevation_swing: 0.0,
                angular_radius: 0.02,
                color: [0.8; 3],
                ambient_sky: [0.2; 3],
                ambient_ground: [0.2; 3],
            },
            [0, 0, 0],
            4.0,
            (0.1, 100.0),
            CameraPath {
                keys: vec![(0.0, eye, [0.0; 3])],
                translation_amplitude: 0.0,
                rotation_amplitude: 0.0,
                seed: 0,
            },
        )
        .unwrap()
    }

    fn test_scene(name: &str) -> Scene {
        let mut scene = empty_scene();
        let ids = place_gltf(
            &mut scene,
            write_model(name, "tex.png", false),
            Placement::default(),
        )
        .unwrap();
        assert_eq!(ids, vec![0, 1]);
        scene
    }

    fn camera() -> Camera {
        mono(
            &HeadPose::look_at([0.0, 0.0, 4.0], [0.0; 3]),
            96,
            72,
            0.1,
            100.0,
        )
    }

    fn pixel_of(rays: &Rays, x: V3) -> (usize, usize) {
        let p = rays.project(x);
        let i = ((p[0] + 1.0) * rays.width as f64 / 2.0 - 0.5).round() as usize;
        let j = ((1.0 - p[1]) * rays.height as f64 / 2.0 - 0.5).round() as usize;
        (i, j)
    }

    #[test]
    fn texture_shows_where_expected() {
        let scene = test_scene("texture");
        let cam = camera();
        let rays = Rays::new(&cam, "t").unwrap();
        let snap = scene.at(0.0);
        let image = render_ground_truth(&scene, &cam, 0.0, 1).unwrap();
        // Quad centre at (0, 1, 0); uv (0.25, 0.25) is the top-left texel (red), and so on.
        for (x, want) in [
            ([-0.25, 1.25, 0.0], 0),
            ([0.25, 1.25, 0.0], 1),
            ([-0.25, 0.75, 0.0], 2),
        ] {
            let (i, j) = pixel_of(&rays, x);
            let s = sample(&snap, &rays, i, j, false);
            assert_eq!(s.obj, Some(0));
            assert!(s.albedo[want] > 0.7, "{x:?}: {:?}", s.albedo);
            assert!(
                (0..3).filter(|&k| k != want).all(|k| s.albedo[k] < 0.3),
                "{x:?}: {:?}",
                s.albedo
            );
            let px = &image[3 * (j * cam.width + i)..][..3];
            assert!(
                (0..3).filter(|&k| k != want).all(|k| px[k] < px[want]),
                "{px:?}"
            );
        }
        let (i, j) = pixel_of(&rays, [0.25, 0.75, 0.0]);
        assert!(sample(&snap, &rays, i, j, false)
            .albedo
            .iter()
            .all(|&c| c > 0.7));
    }

    #[test]
    fn rigid_node_animation_gives_the_analytic_motion() {
        let scene = test_scene("rigid");
        assert!(matches!(scene.objects[0].anims[..], [Anim::Keyframes(_)]));
        assert!(!scene.objects[0].shape.deforms() && scene.objects[1].shape.deforms());
        let cam = camera();
        let rays = Rays::new(&cam, "t").unwrap();
        let t = 1.0;
        let r = render_server(&scene, &cam, t, DT, 4, 1).unwrap();
        let snap = scene.at(t);
        let mut n = 0;
        for j in 0..cam.height {
            for i in 0..cam.width {
                let s = sample(&snap, &rays, i, j, false);
                if s.obj != Some(0) {
                    continue;
                }
                let k = j * cam.width + i;
                // 1 m/s along x.
                let p0 = rays.project(s.x);
                let pf = rays.project(add(s.x, [DT, 0.0, 0.0]));
                let pb = rays.project(add(s.x, [-DT, 0.0, 0.0]));
                for c in 0..3 {
                    assert!((r.motion_fwd[3 * k + c] as f64 - (pf[c] - p0[c])).abs() < 1e-6);
                    assert!((r.motion_bwd[3 * k + c] as f64 - (pb[c] - p0[c])).abs() < 1e-6);
                }
                n += 1;
            }
        }
        assert!(n > 100, "{n} quad pixels");
    }

    #[test]
    fn skinned_motion_lands_on_the_skinned_material_point() {
        let scene = test_scene("skin");
        let cam = camera();
        let rays = Rays::new(&cam, "t").unwrap();
        let t = 1.0;
        let r = render_server(&scene, &cam, t, DT, 4, 1).unwrap();
        let inv_vp = cam.view_proj().inverse().unwrap();
        let theta = |t: f64| 0.5 * PI * t / 4.0;
        let pivot = [1.0, 0.0, 0.0];
        let rot = |a: f64, p: V3| {
            let (s, c) = a.sin_cos();
            let d = sub(p, pivot);
            add(pivot, [c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]])
        };
        let (mut rigid_part, mut blended) = (0, 0);
        for j in 0..cam.height {
            for i in 0..cam.width {
                let k = j * cam.width + i;
                let snap = scene.at(t);
                let s = sample(&snap, &rays, i, j, false);
                if s.obj != Some(1) {
                    continue;
                }
                // The pixel plus its motion, un-projected (depth and motion as stored, f32).
                let x = (2 * i + 1) as f64 / cam.width as f64 - 1.0;
                let y = 1.0 - (2 * j + 1) as f64 / cam.height as f64;
                let m = &r.motion_fwd[3 * k..3 * k + 3];
                let h = inv_vp.mul_vec([
                    x + m[0] as f64,
                    y + m[1] as f64,
                    r.depth[k] as f64 + m[2] as f64,
                    1.0,
                ]);
                let got = [h[0] / h[3], h[1] / h[3], h[2] / h[3]];
                // The rest position of the material point (model space) by undoing joint 2.
                let rest = rot(-theta(t), s.x);
                if rest[0] > 1.26 {
                    // Only on joint 2: the analytic rotation about the pivot.
                    let want = rot(theta(t + DT), rest);
                    let e = crate::math::length(sub(got, want));
                    assert!(e < 2e-4, "pixel {i},{j}: {got:?} vs {want:?} ({e})");
                    rigid_part += 1;
                } else if rest[0] > 0.8 && rest[0] < 1.24 {
                    // Blended: the point moves, less than a point on joint 2 would.
                    let full = rot(theta(t + DT), rest);
                    let moved = crate::math::length(sub(got, s.x));
                    let most = crate::math::length(sub(full, s.x));
                    assert!(moved < most + 1e-4, "{rest:?}: {moved} {most}");
                    blended += usize::from(moved > 1e-4);
                } else if rest[0] < 0.74 {
                    // Only on the still joint 1: exactly no motion.
                    assert!(m.iter().all(|&c| c == 0.0), "{m:?}");
                }
            }
        }
        assert!(rigid_part > 20 && blended > 2, "{rigid_part} {blended}");
    }

    #[test]
    fn bad_files_give_errors_naming_file_and_problem() {
        let dir = test_dir().join(format!("reproj-gltf-{}-bad", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let check = |path: &Path, needle: &str| {
            let e = GltfModel::load(path).unwrap_err().to_string();
            assert!(e.contains(&path.display().to_string()), "{e}");
            assert!(e.contains(needle), "{e}");
        };
        let junk = dir.join("junk.gltf");
        std::fs::write(&junk, "{ this is not json").unwrap();
        check(&junk, "malformed");
        check(&dir.join("absent.gltf"), "cannot read");
        check(&write_model("notex", "missing.png", false), "missing.png");
        check(&write_model("badidx", "tex.png", true), "vertex index 99");
        let lines = write_model("lines", "tex.png", false);
        let json = std::fs::read_to_string(&lines).unwrap().replacen(
            r#""indices": 3,"#,
            r#""indices": 3, "mode": 1,"#,
            1,
        );
        std::fs::write(&lines, json).unwrap();
        check(&lines, "unsupported");
        let cubic = write_model("cubic", "tex.png", false);
        let json = std::fs::read_to_string(&cubic)
            .unwrap()
            .replacen("LINEAR", "CUBICSPLINE", 1);
        std::fs::write(&cubic, json).unwrap();
        check(&cubic, "CUBICSPLINE");
    }

    fn asset(rel: &str) -> Option<PathBuf> {
        let p = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/assets")
            .join(rel);
        if p.exists() {
            Some(p)
        } else {
            eprintln!("skipping: {} is absent", p.display());
            None
        }
    }

    /// Renders server frame 3 of a loaded model's scene and checks the model moves.
    fn renders_with_motion(scene: &Scene) {
        let f = crate::render_server_frame(scene, 3, 0.03, 10.0, 2).unwrap();
        let moving = f.main.motion_fwd.iter().filter(|m| m.abs() > 1e-5).count();
        let seen = f.main.depth.iter().filter(|&&z| z > 0.0).count();
        assert!(
            seen > 0 && moving > 10,
            "{}: {moving} moving pixels",
            scene.name
        );
    }

    #[test]
    fn fox_and_cesium_man_load_and_move() {
        for rel in ["Fox/Fox.glb", "CesiumMan/CesiumMan.gltf"] {
            let Some(path) = asset(rel) else { continue };
            let scene = load_gltf_scene(&path).unwrap();
            assert!(
                scene.objects.iter().any(|o| o.shape.deforms()),
                "{rel} is not skinned"
            );
            renders_with_motion(&scene);
        }
    }

    #[test]
    fn fox_runs_in_the_courtyard() {
        let Some(path) = asset("Fox/Fox.glb") else {
            return;
        };
        let model = Arc::new(GltfModel::load(&path).unwrap());
        assert_eq!(model.animation_names().len(), 3);
        let b = model.bounds();
        let s = 0.6 / (b.max[1] - b.min[1]);
        let mut scene = crate::builtin("courtyard", Variant::Dynamic).unwrap();
        let n = scene.objects.len();
        let ids = place_model(
            &mut scene,
            &model,
            Placement {
                place: Rigid::translation([0.0, 0.0, 0.0]),
                scale: s,
                animation: Some(2),
                ..Placement::default()
            },
        )
        .unwrap();
        assert!(ids.iter().all(|&i| i >= n && scene.moves(i)));
        crate::render_server_frame(&scene, 2, 0.02, 10.0, 2).unwrap();
    }

    #[test]
    fn flight_helmet_loads() {
        let Some(path) = asset("FlightHelmet/FlightHelmet.gltf") else {
            return;
        };
        let model = GltfModel::load(&path).unwrap();
        assert!(
            model.triangle_count() > 90_000,
            "{}",
            model.triangle_count()
        );
        let scene = load_gltf_scene(&path).unwrap();
        crate::render_client_frame(&scene, 0, 0.02, 120.0, false).unwrap();
    }
}
