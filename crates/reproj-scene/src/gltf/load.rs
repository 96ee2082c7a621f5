//! Loading a `.gltf` or `.glb` file into a [`GltfModel`]: buffers, base-colour materials and
//! textures, meshes, the node hierarchy, skins and animation channels, each validated.

use std::path::Path;
use std::sync::Arc;

use glam::{DMat4, DQuat, DVec3};

use super::read::{decode_image, read_primitive};
use super::{err, unsupported};
use crate::error::Result;
use crate::gltf_model::{
    Animation, Channel, GltfMaterial, GltfModel, Local, Node, Property, Skin, Texture, Trs,
};

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
