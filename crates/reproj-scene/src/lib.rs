//! # reproj-scene
//!
//! The reference server renderer of splitrender: a CPU ray caster (rayon over blocks of 16 rows)
//! of animated scenes that writes every buffer the server streams and every frame the evaluation
//! needs, exactly consistent with each other (shared/DESIGN.md conventions throughout):
//!
//! - per server frame and camera (main + two auxiliary, [`rig()`]): colour, reversed depth,
//!   object motion forward and backward in the camera's NDC (exactly zero on still objects),
//!   dynamic-shadow bitfields and `S_min`/`S_max` colours forward and backward, and the view and
//!   projection matrices ([`render_server`], [`render_server_frame`]);
//! - colour (server, `S_min`/`S_max`, ground truth) box-filtered over `n×n` sub-samples per
//!   pixel ([`default_samples`]; see [`render`]), geometry at the pixel centre;
//! - ground truth at the client's actual pose, mono or stereo ([`render_ground_truth`],
//!   [`render_client_frame`]);
//! - the built-in scenes `courtyard`, `colonnade` and `lab`, each static or dynamic, with their
//!   head-box paths and the deterministic prediction error of DESIGN.md ([`builtin`],
//!   [`CameraPath`]);
//! - glTF 2.0 models ([`gltf`]): meshes, node hierarchy, base-colour textures, node animation and
//!   linear blend skinning, loaded on their own ([`load_gltf_scene`]) or placed into a built-in
//!   scene ([`place_gltf`]); skinned material points are (triangle, barycentrics), so non-rigid
//!   motion is exact too.
//!
//! The scene model is two-level: every object has a shape in object space (analytic sphere,
//! box, capsule, quad, or a triangle mesh with its own BVH built once) and a rigid world
//! transform that is a function of time through a parent-child hierarchy ([`Anim`]: linear,
//! accelerating, oscillating, spinning, rolling, circling, swinging joints). Rays are moved into
//! object space per instance, so rigid animation never rebuilds a mesh BVH; the top-level BVH over
//! the instances' world boxes is rebuilt per instant (a few dozen boxes). Material points are
//! tracked as (object, object-space point), which is what makes motion and shadow subframes exact.
//!
//! ## BVH crate: obvhs 0.4 (over bvh 0.13)
//!
//! Both were compared for this renderer's needs (rigid instances, a per-instant top-level
//! rebuild, closest-hit primary rays and any-hit shadow rays with `f64` intersection code):
//!
//! | | obvhs 0.4 | bvh 0.13 |
//! |---|---|---|
//! | traversal API | closure per primitive returning `t`; the crate culls nodes beyond the current closest `t` (`ray_traverse`) and stops at the first hit (`ray_traverse_miss`) | iterators of candidate shapes (`traverse_iterator`, `nearest_traverse_iterator`); no closest-hit culling, the caller filters |
//! | primitives | anything with an AABB (`Boundable`): instances, analytic shapes, triangles | anything `BHShape` (must store its node index, i.e. `&mut` shapes at build) |
//! | build | PLOC + reinsertion + leaf collapse, presets from "fastest" (microseconds for the top level) to "slow"; also refit, insertion/removal and a CWBVH (8-wide) for later speed-ups | binned SAH; refit/optimize for moved shapes |
//! | scalar | `f32` (glam) only | generic, `f32` or `f64` (nalgebra) |
//! | dependencies | glam, bytemuck, half, rdst (small) | nalgebra 0.35 with serde, num-traits, wide |
//! | licence / upkeep | MIT OR Apache-2.0 (as this workspace); active, used by tray_racing and bevy experiments | MIT; active |
//!
//! obvhs wins on the traversal API (closest-hit culling for free is what a ray caster wants; with
//! bvh every candidate box along the ray is returned and tested) and on the build presets and
//! licence. Its one drawback, `f32` only, does not touch exactness: the BVH only culls, every
//! intersection is computed in `f64` by this crate, and all boxes are padded outward so `f32`
//! rounding can never cull a primitive the `f64` test would hit (checked against brute force in
//! the tests). Both crates are edition 2024 (rustc ≥ 1.85; bvh declares 1.90), so the workspace
//! declares `rust-version = 1.85`.
//!
//! ## Shading
//!
//! Textured Lambert plus an optional Blinn–Phong highlight under one directional light with an
//! angular radius (soft shadows: the fraction of 32 fixed Vogel-spiral rays over the light's
//! disc that are blocked), plus a sky/ground hemisphere ambient. The light may swing (the `lab`).
//! Procedural textures ([`Pattern`]) carry detail down to centimetres.

#![warn(missing_docs)]

pub mod anim;
pub mod error;
pub mod gltf;
mod gltf_model;
pub mod material;
pub mod math;
mod mesh;
pub mod meshes;
pub mod render;
pub mod rig;
pub mod scene;
pub mod scenes;
pub mod shape;

pub use anim::Anim;
pub use error::{Result, SceneError};
pub use gltf::{load_gltf_scene, place_gltf, place_model, GltfModel, Placement, GLTF_ALLOWANCE};
pub use material::{Material, Pattern};
pub use math::{Rigid, V3};
pub use render::{
    default_samples, render_ground_truth, render_server, render_shadow_fraction, truth_bytes,
    ServerBuffers, ShadowBuffers, MAX_SAMPLES,
};
pub use rig::{
    aux_size, camera_sizes, main_size, mono, rig, stereo, CameraPath, HeadPose, Rig,
    PREDICTION_DELAY,
};
pub use scene::{Light, Object, Scene, Variant};
pub use scenes::{builtin, SCENE_NAMES};
pub use shape::{Mesh, Shape, Vertex};

/// Server frame rate f_s (DESIGN.md default).
pub const F_S: f64 = 10.0;
/// Client frame rate f_c.
pub const F_C: f64 = 120.0;
/// Dynamic-shadow rate f_d.
pub const F_D: f64 = 40.0;

/// Every buffer of one server frame: the three cameras of the rig at the predicted pose.
#[derive(Debug, Clone, PartialEq)]
pub struct ServerFrame {
    /// Frame index `k`.
    pub index: usize,
    /// Time `k / f_s` (seconds).
    pub time: f64,
    /// The (predicted) pose rendered.
    pub pose: HeadPose,
    /// Main camera.
    pub main: ServerBuffers,
    /// Left and right auxiliary cameras.
    pub aux: [ServerBuffers; 2],
}

impl ServerFrame {
    /// The frame as the older image of a pair (`forward = true`: forward motion and shadows) or
    /// the newer one (backward ones).
    pub fn view(&self, forward: bool) -> reproj_core::FrameView<'_> {
        reproj_core::FrameView {
            main: self.main.camera_view(forward),
            aux: self.aux.iter().map(|a| a.camera_view(forward)).collect(),
        }
    }
}

/// Renders server frame `k` of `scene` at `scale` (main camera `round(2560·scale) ×
/// round(1440·scale)`), server rate `fs` and `subframes` shadow subframes per server interval,
/// each camera's colour with [`default_samples`] for its size.
///
/// # Errors
/// [`SceneError::BadScale`] for a scale that gives an empty or oversized image,
/// [`SceneError::BadTime`] for a rate `fs` that is not finite and positive (or a time `k / fs`
/// at which the scene is not finite), [`SceneError::BadSubframes`] for `subframes ∉ 1..=16`,
/// and the errors of [`Scene::check`].
pub fn render_server_frame(
    scene: &Scene,
    k: usize,
    scale: f64,
    fs: f64,
    subframes: usize,
) -> Result<ServerFrame> {
    let (w, h) = main_size(scale)?;
    let fs = render::check_rate("fs", fs)?;
    scene.check()?; // before its path gives the pose
    let pose = scene.path.server_pose(k, fs);
    let r = rig(&pose, w, h, scene.near, scene.far);
    let t = k as f64 / fs;
    let one = |c: &reproj_core::Camera| {
        render_server(
            scene,
            c,
            t,
            1.0 / fs,
            subframes,
            default_samples(c.width, c.height),
        )
    };
    Ok(ServerFrame {
        index: k,
        time: t,
        pose,
        main: one(&r.main)?,
        aux: [one(&r.aux[0])?, one(&r.aux[1])?],
    })
}

/// Ground truth of client frame `n` (time `n / fc`) at the client's actual pose: one RGB8 image
/// (mono) or two, `[left, right]` (stereo, IPD 7 cm), at the main camera's size for `scale`, with
/// [`default_samples`] (so it matches [`render_server_frame`]'s main colour at a server pose).
///
/// # Errors
/// [`SceneError::BadScale`] as [`render_server_frame`]; [`SceneError::BadTime`] for a rate `fc`
/// that is not finite and positive (or a time `n / fc` at which the scene is not finite), and
/// the errors of [`Scene::check`].
pub fn render_client_frame(
    scene: &Scene,
    n: usize,
    scale: f64,
    fc: f64,
    stereo_eyes: bool,
) -> Result<Vec<Vec<u8>>> {
    let (w, h) = main_size(scale)?;
    let fc = render::check_rate("fc", fc)?;
    let t = n as f64 / fc;
    scene.check()?; // before its path gives the pose
    let pose = scene.path.client_pose(t);
    let cams = if stereo_eyes {
        stereo(&pose, w, h, scene.near, scene.far).to_vec()
    } else {
        vec![mono(&pose, w, h, scene.near, scene.far)]
    };
    cams.iter()
        .map(|c| render_ground_truth(scene, c, t, default_samples(w, h)))
        .collect()
}
