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
//! [`Object`]: crate::Object
//! [`Shape::Gltf`]: crate::Shape::Gltf
//! [`Anim::Keyframes`]: crate::Anim::Keyframes
//!
//! Colours: the base-colour factor times the base-colour texture (bilinear, repeat wrap), both
//! taken as the renderer's linear `[0,1]` albedo like every procedural material (the renderer does
//! no sRGB conversion anywhere). Morph targets are not applied (their weight channels are
//! ignored); the `CUBICSPLINE` interpolation, non-triangle primitives, texture coordinate sets
//! other than 0 and any extension in `extensionsRequired` are refused with
//! [`SceneError::GltfUnsupported`].
//!
//! The file is untrusted (issue 15). Only regular files are read, each at most
//! `MAX_FILE_BYTES` (1 GiB); the GLB container is split here with every length checked
//! against the bytes present; the `gltf` crate only parses and validates the JSON, after the
//! indices its validation would use unchecked are checked. Accessors are decoded by `access.rs`,
//! never by the crate's readers: buffer views inside their buffers, strides that hold an element,
//! sparse indices and values inside their views, and every decoded size charged to a budget
//! proportional to the input *before* it is allocated; textures decode under the same budget.
//! Positions, node transforms, inverse bind matrices and animation values must be finite and
//! within `MAX_COORD` (1e15), quaternions non-zero, matrices affine and invertible, and
//! a placed model must stay within that bound at every time of its animation, so that nothing
//! absurd reaches the BVH. Each refusal is a [`SceneError::Gltf`] naming the file, the element
//! (accessor, node, animation channel…), what was found and what was expected.
//!
//! This file holds the error helpers and the public names; `load.rs` walks the document into a
//! [`GltfModel`] (defined, with [`GltfShape`] and [`NodeTrack`], in the crate's `gltf_model`
//! module, below the shapes and animations that use them), `source.rs` reads the file, its GLB
//! chunks and its buffers, `access.rs` decodes accessors, `read.rs` decodes one image and one
//! primitive, `place.rs` puts a model into a scene, `tests.rs` and `hostile.rs` hold the unit
//! tests.
//!
//! The loader also records what it read: the SHA-256 of the model file and of each file the
//! document references by a relative URI ([`ModelFiles`], on [`GltfModel::files`]), hashed
//! from the bytes it decoded, so that a scene's identity (the Python `Scene.digest`) is of
//! what renders, not of what the files hold when it is asked.

mod access;
#[cfg(test)]
mod hostile;
mod load;
mod place;
mod read;
mod source;
#[cfg(test)]
mod tests;

use std::path::Path;

use crate::error::SceneError;
pub use crate::gltf_model::{GltfModel, GltfShape, ModelFiles, NodeTrack, Texture};
pub use load::GLTF_ALLOWANCE;
pub use place::{load_gltf_scene, place_gltf, place_model, Placement};

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
