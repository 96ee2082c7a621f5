//! Loading a `.gltf` or `.glb` file into a [`GltfModel`]: buffers, base-colour materials and
//! textures, meshes, the node hierarchy, skins and animation channels, each validated.

use std::panic::AssertUnwindSafe;
use std::path::Path;
use std::sync::Arc;

use glam::{DMat3, DMat4, DQuat, DVec3};
use gltf::json::accessor::{ComponentType as C, Type};
use gltf::json::validation::Checked;

use super::access::{self, read, Budget, Bytes, Data, Expect, BUDGET_BASE};
use super::read::{decode_image, read_primitive, MAX_COORD};
use super::source::{self, Sources, MAX_FILE_BYTES};
use super::{err, unsupported};
use crate::error::Result;
use crate::gltf_model::{
    Animation, Channel, GltfMaterial, GltfModel, Local, ModelFiles, Node, Property, Skin, Texture,
    Trs,
};

impl GltfModel {
    /// Loads and validates a `.gltf` (with its buffers and textures) or `.glb` file.
    ///
    /// # Errors
    /// [`SceneError::Gltf`] for an unreadable or malformed file, a missing buffer or texture file
    /// or an out-of-range index; [`SceneError::GltfUnsupported`] for features the renderer does
    /// not implement. Both name the file.
    ///
    /// [`SceneError::Gltf`]: crate::SceneError::Gltf
    /// [`SceneError::GltfUnsupported`]: crate::SceneError::GltfUnsupported
    pub fn load(path: impl AsRef<Path>) -> Result<GltfModel> {
        let path = path.as_ref();
        let bytes = source::read_file(path, path, "the model file", MAX_FILE_BYTES)?;
        GltfModel::from_bytes(path, &bytes)
    }

    /// Decodes a `.gltf` or `.glb` file's contents; `path` names it in messages and locates its
    /// external buffers and textures.
    ///
    /// # Errors
    /// As [`GltfModel::load`].
    pub fn from_bytes(path: impl AsRef<Path>, bytes: &[u8]) -> Result<GltfModel> {
        decode(path.as_ref(), bytes, BUDGET_BASE)
    }

    /// [`GltfModel::load`] with the fixed part of the decode budget (64 MiB for one model)
    /// drawn from `allowance`, which the models of one scene share: each model's own part
    /// stays 64 bytes per byte of its input, so that a scene description placing a small file
    /// many times (or many small files) cannot decode 64 MiB for each (a 738-byte model placed
    /// 10 times held 0.9 GB). Starts from [`GLTF_ALLOWANCE`] for a scene.
    ///
    /// # Errors
    /// As [`GltfModel::load`]; the budget's message says the allowance is shared.
    pub fn load_sharing(path: impl AsRef<Path>, allowance: &mut usize) -> Result<GltfModel> {
        let path = path.as_ref();
        let bytes = source::read_file(path, path, "the model file", MAX_FILE_BYTES)?;
        let (model, used) = decode_counted(path, &bytes, *allowance)?;
        *allowance = allowance.saturating_sub(used);
        Ok(model)
    }
}

/// The fixed decode allowance of one scene's glTF models ([`GltfModel::load_sharing`]): bytes.
pub const GLTF_ALLOWANCE: usize = BUDGET_BASE;

/// [`GltfModel::from_bytes`] with `budget_base` decoded bytes allowed on top of the part
/// proportional to the input (the tests use a small one).
pub(crate) fn decode(path: &Path, bytes: &[u8], budget_base: usize) -> Result<GltfModel> {
    decode_counted(path, bytes, budget_base).map(|(model, _)| model)
}

/// [`decode`], and how much of `budget_base` the model took.
fn decode_counted(path: &Path, bytes: &[u8], budget_base: usize) -> Result<(GltfModel, usize)> {
    // Every check above the decoders is meant to leave them nothing to panic on; should one
    // still do so, the caller gets an error rather than an abort.
    std::panic::catch_unwind(AssertUnwindSafe(|| {
        decode_checked(path, bytes, budget_base)
    }))
    .unwrap_or_else(|_| Err(err(path, "the glTF decoder panicked on malformed data")))
}

/// The error for a node or animation value that is not finite or beyond [`MAX_COORD`].
fn check_values(path: &Path, what: &str, values: &[f64]) -> Result<()> {
    access::bounded(path, what, values, MAX_COORD)
}

/// A rotation quaternion, normalised; a zero-length or non-finite one is refused (normalising
/// it gives NaN).
fn rotation(path: &Path, what: &str, q: [f64; 4]) -> Result<DQuat> {
    let q = DQuat::from_array(q);
    let len = q.length();
    if !(len.is_finite() && len > 1e-6) {
        return Err(err(
            path,
            format!(
                "{what}: rotation {:?} has length {len}, expected a unit quaternion",
                q.to_array()
            ),
        ));
    }
    Ok(q / len)
}

/// A node's rest transform, checked: finite and bounded values, a non-zero quaternion, an
/// invertible affine matrix. A zero TRS scale is allowed (the glTF specification lets a node
/// be hidden that way).
fn local(path: &Path, index: usize, n: &gltf::json::Node) -> Result<Local> {
    let what = format!("node {index}");
    if let Some(m) = n.matrix {
        let m = m.map(f64::from);
        check_values(path, &format!("{what} matrix"), &m)?;
        // Column-major: the last row is elements 3, 7, 11, 15.
        let row = [m[3], m[7], m[11], m[15]];
        if row != [0.0, 0.0, 0.0, 1.0] {
            return Err(err(
                path,
                format!("{what}: matrix's last row is {row:?}, expected [0, 0, 0, 1] (an affine transform)"),
            ));
        }
        let m = DMat4::from_cols_array(&m);
        let lin = DMat3::from_mat4(m);
        let size = lin
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, x| a.max(x.abs()));
        let det = lin.determinant();
        // Relative to its size, so that a uniformly tiny model is not refused.
        if !(det.abs() > 1e-12 * size.powi(3)) {
            return Err(err(
                path,
                format!("{what}: matrix is not invertible (determinant {det:e}), expected an invertible affine transform"),
            ));
        }
        return Ok(Local::Matrix(m));
    }
    let t = n.translation.unwrap_or([0.0; 3]).map(f64::from);
    let s = n.scale.unwrap_or([1.0; 3]).map(f64::from);
    let r = n
        .rotation
        .map_or([0.0, 0.0, 0.0, 1.0], |q| q.0)
        .map(f64::from);
    check_values(path, &format!("{what} translation"), &t)?;
    check_values(path, &format!("{what} scale"), &s)?;
    check_values(path, &format!("{what} rotation"), &r)?;
    Ok(Local::Trs(Trs {
        t: DVec3::from_array(t),
        r: rotation(path, &what, r)?,
        s: DVec3::from_array(s),
    }))
}

/// What the model was read from ([`ModelFiles`]): the digest of `bytes` and of each file a
/// `buffers` entry, then an `images` entry, names by a relative URI. Called after decoding:
/// every buffer and every decoded texture's file was read by then, and its digest is of the
/// bytes decoded. An image file no material decodes is read here for its digest only, and
/// left out when it cannot be (missing, not a regular file, over the caps, a URI that is not
/// a relative path): nothing of it renders, and the loader took such a model before.
///
/// [`ModelFiles`]: crate::gltf::ModelFiles
fn model_files(
    bytes: &[u8],
    root: &gltf::json::Root,
    sources: &mut Sources<'_>,
) -> Result<ModelFiles> {
    let mut resources = Vec::new();
    for (i, b) in root.buffers.iter().enumerate() {
        if let Some(uri) = &b.uri {
            resources.extend(sources.sha256(uri, &format!("buffer {i}"))?);
        }
    }
    for (i, image) in root.images.iter().enumerate() {
        if let Some(uri) = &image.uri {
            if let Ok(Some(h)) = sources.sha256(uri, &format!("file of image {i}")) {
                resources.push(h);
            }
        }
    }
    Ok(ModelFiles {
        sha256: source::sha256_hex(bytes),
        resources,
    })
}

fn decode_checked(path: &Path, bytes: &[u8], budget_base: usize) -> Result<(GltfModel, usize)> {
    let (json, blob) = if bytes.starts_with(source::GLB_MAGIC) {
        source::split_glb(path, bytes)?
    } else {
        (bytes, None)
    };
    let document = source::parse_document(path, json)?;
    let root = document.as_json();
    let mut sources = Sources::new(path, bytes.len());
    let mut buffers: Vec<Bytes> = Vec::with_capacity(root.buffers.len());
    for (i, b) in root.buffers.iter().enumerate() {
        let d = match (&b.uri, blob) {
            (Some(uri), _) => sources.read(uri, &format!("buffer {i}"))?,
            // Only the first buffer may be the GLB's BIN chunk.
            (None, Some(bin)) if i == 0 => Bytes::new(bin.to_vec()),
            (None, _) => {
                return Err(err(
                    path,
                    format!("buffer {i} has no uri, expected one (only buffer 0 of a GLB file with a BIN chunk may omit it)"),
                ))
            }
        };
        if (d.len() as u64) < b.byte_length.0 {
            return Err(err(
                path,
                format!(
                    "buffer {i} holds {} bytes, the file declares {}",
                    d.len(),
                    b.byte_length.0
                ),
            ));
        }
        buffers.push(d);
    }
    let mut data = Data {
        path,
        root,
        buffers,
        budget: Budget::new(sources.input as usize, budget_base),
    };

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
                    let before = sources.input;
                    let texture = decode_image(&mut data, &mut sources, &image)?;
                    // A texture file read is input too: it widens the budget it was charged to.
                    data.budget.grow((sources.input - before) as usize);
                    decoded[i] = Some(Arc::new(texture));
                }
                decoded[i].clone()
            }
            None => None,
        };
        if !f.iter().all(|c| c.is_finite()) {
            return Err(err(
                path,
                format!(
                    "material {}: baseColorFactor {f:?}, expected finite numbers",
                    m.index().unwrap_or(0)
                ),
            ));
        }
        materials.push(GltfMaterial {
            factor: [f[0] as f64, f[1] as f64, f[2] as f64],
            texture,
        });
    }

    let mut meshes = Vec::new();
    for mesh in document.meshes() {
        let mut prims = Vec::new();
        for (k, p) in mesh.primitives().enumerate() {
            prims.push(read_primitive(&mut data, mesh.index(), k, &p)?);
        }
        meshes.push(prims);
    }

    let mut nodes = Vec::with_capacity(root.nodes.len());
    for (i, n) in root.nodes.iter().enumerate() {
        nodes.push(Node {
            local: local(path, i, n)?,
            parent: None,
            mesh: n.mesh.map(|m| m.value()),
            skin: n.skin.map(|s| s.value()),
        });
    }
    // Indices from the JSON directly: the document's `children()` and `nodes()` iterators look
    // each index up from the start (quadratic in the number of nodes).
    for (p, n) in root.nodes.iter().enumerate() {
        for c in n.children.iter().flatten().map(|c| c.value()) {
            if nodes[c].parent.is_some() || c == p {
                return Err(err(path, format!("node {c} has more than one parent")));
            }
            nodes[c].parent = Some(p);
        }
    }
    let scene = root
        .scenes
        .get(root.scene.map_or(0, |s| s.value()))
        .ok_or_else(|| err(path, "no scene"))?;
    let mut order = Vec::new();
    let mut stack: Vec<usize> = scene.nodes.iter().map(|n| n.value()).collect();
    stack.reverse();
    let mut seen = vec![false; nodes.len()];
    while let Some(n) = stack.pop() {
        if std::mem::replace(&mut seen[n], true) {
            return Err(err(path, format!("node {n} is reached twice (a cycle?)")));
        }
        order.push(n);
        let children = root.nodes[n].children.iter().flatten();
        stack.extend(children.map(|c| c.value()));
    }

    let mut skins = Vec::new();
    for s in document.skins() {
        let joints: Vec<usize> = s.joints().map(|j| j.index()).collect();
        let inverse_bind: Vec<DMat4> = match s.inverse_bind_matrices() {
            Some(a) => {
                let m = read::<16>(
                    &mut data,
                    a.index(),
                    "inverseBindMatrices",
                    &Expect::floats(Type::Mat4),
                )?;
                check_values(
                    path,
                    &format!("skin {} inverseBindMatrices", s.index()),
                    m.as_flattened(),
                )?;
                m.iter().map(DMat4::from_cols_array).collect()
            }
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
            // The channels' targets are not checked by the document's validation: read them
            // from the JSON and check them here (`target().node()` would panic).
            let target = &root.animations[a.index()].channels[ch.index()].target;
            let here = format!("animation {} channel {}", a.index(), ch.index());
            let node = target.node.value();
            if node >= nodes.len() {
                return Err(err(
                    path,
                    format!(
                        "{here} targets node {node}, which does not exist ({} nodes)",
                        nodes.len()
                    ),
                ));
            }
            use gltf::json::animation::Property as P;
            let property = match target.path {
                Checked::Valid(P::Translation) => Property::Translation,
                Checked::Valid(P::Rotation) => Property::Rotation,
                Checked::Valid(P::Scale) => Property::Scale,
                // Morph targets are not applied, so their weights have nothing to drive.
                Checked::Valid(P::MorphTargetWeights) => continue,
                Checked::Invalid => {
                    return Err(err(
                        path,
                        format!("{here}: unknown target path, expected translation, rotation, scale or weights"),
                    ))
                }
            };
            let sampler = ch.sampler();
            let step = match sampler.interpolation() {
                gltf::animation::Interpolation::Linear => false,
                gltf::animation::Interpolation::Step => true,
                gltf::animation::Interpolation::CubicSpline => {
                    return Err(unsupported(
                        path,
                        format!("animation {} uses CUBICSPLINE interpolation", a.index()),
                    ))
                }
            };
            let input = sampler.input().index();
            let output = sampler.output().index();
            let times: Vec<f64> = read::<1>(
                &mut data,
                input,
                &format!("{here} input"),
                &Expect::floats(Type::Scalar),
            )?
            .into_iter()
            .map(|[t]| t)
            .collect();
            let out_what = format!("{here} output");
            let values: Vec<[f64; 4]> = match property {
                Property::Translation | Property::Scale => {
                    let v = read::<3>(&mut data, output, &out_what, &Expect::floats(Type::Vec3))?;
                    check_values(path, &out_what, v.as_flattened())?;
                    v.into_iter().map(|v| [v[0], v[1], v[2], 0.0]).collect()
                }
                Property::Rotation => {
                    const ROTATION: Expect = Expect {
                        ty: Type::Vec4,
                        components: &[
                            (C::F32, false),
                            (C::I8, true),
                            (C::U8, true),
                            (C::I16, true),
                            (C::U16, true),
                        ],
                    };
                    let v = read::<4>(&mut data, output, &out_what, &ROTATION)?;
                    for (k, q) in v.iter().enumerate() {
                        rotation(path, &format!("{out_what} key {k}"), *q)?;
                    }
                    v
                }
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
            if matches!(nodes[node].local, Local::Matrix(_)) {
                return Err(err(
                    path,
                    format!("{here} targets node {node}, which has a matrix"),
                ));
            }
            channels.push(Channel {
                node,
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

    let files = model_files(bytes, root, &mut sources)?;
    let used = data.budget.fixed_used();
    let model = GltfModel {
        path: path.to_path_buf(),
        files,
        nodes,
        order,
        meshes,
        materials,
        skins,
        animations,
    };
    Ok((model, used))
}
