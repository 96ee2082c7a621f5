//! Putting a loaded model into a scene: [`Placement`], [`place_gltf`] and [`place_model`] (which
//! choose each mesh node's kind, see [`crate::gltf`]), and a scene of the model's own,
//! [`load_gltf_scene`].

use std::f64::consts::PI;
use std::path::Path;
use std::sync::Arc;

use glam::{DMat3, DMat4, DVec3};

use super::err;
use super::read::MAX_COORD;
use crate::anim::Anim;
use crate::error::Result;
use crate::gltf_model::{
    Clock, GltfModel, GltfShape, Kind, Local, NodeTrack, PlacedNode, Property,
};
use crate::material::{Material, Pattern};
use crate::math::{add, length, scale, Rigid};
use crate::mesh::Mesh;
use crate::rig::CameraPath;
use crate::scene::{Light, Object, Scene, Variant};
use crate::shape::Shape;

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
/// As [`GltfModel::load`]; [`SceneError::Gltf`] for an animation index out of range, a
/// non-positive scale, non-finite timing, a placement or geometry reaching beyond
/// `MAX_COORD` (1e15 m) from the origin at any time of the animation, a model without triangles,
/// more hierarchy work than `MAX_HIERARCHY_WORK`, or more mesh nodes than the scene has room
/// for (`MAX_OBJECTS` objects in all).
///
/// [`SceneError::Gltf`]: crate::SceneError::Gltf
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
            format!(
                "placement scale {}: expected a finite number > 0",
                placement.scale
            ),
        ));
    }
    if !(placement.time_offset.is_finite() && placement.speed.is_finite()) {
        return Err(err(
            path,
            format!(
                "placement time offset {} and speed {}: expected finite numbers",
                placement.time_offset, placement.speed
            ),
        ));
    }
    let p = &placement.place;
    let shift = length(p.trans);
    if !(shift <= MAX_COORD && p.rot.iter().flatten().all(|x| x.is_finite())) {
        return Err(err(
            path,
            format!(
                "placement translation {:?} is {shift:e} m from the origin or its rotation is not \
                 finite, expected at most {MAX_COORD:e} m and a finite rotation",
                p.trans
            ),
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
    // Refused before any object is added, so that an error leaves the scene as it was.
    let reach = world_reach(model, animation);
    let moving = moving_nodes(model, animation);
    let skin_moving: Vec<bool> = model
        .skins
        .iter()
        .map(|s| s.joints.iter().any(|&j| moving[j]))
        .collect();
    let mut mesh_nodes = 0usize;
    let mut animated_meshes = 0usize;
    for &n in &model.order {
        let Some(m) = model.nodes[n].mesh else {
            continue;
        };
        if model.meshes[m].iter().all(|p| p.triangles.is_empty()) {
            continue;
        }
        mesh_nodes += 1;
        let skin_moves = model.nodes[n].skin.is_some_and(|s| skin_moving[s]);
        animated_meshes += usize::from(moving[n] || skin_moves);
        let extent = placement.scale * geometry_reach(model, n, &reach) + shift;
        if !(extent <= MAX_COORD) {
            return Err(err(
                path,
                format!(
                    "node {n}: placed with scale {:e}, its geometry can reach {extent:e} m from the \
                     origin (node transforms and animation included), expected at most \
                     {MAX_COORD:e} m",
                    placement.scale
                ),
            ));
        }
    }
    if mesh_nodes == 0 {
        return Err(err(
            path,
            "the model's scene has no mesh node with triangles, expected at least one",
        ));
    }
    // Each moving mesh node evaluates the whole hierarchy at every key time (the rigidity test
    // below) and at every snapshot (posing): bound that work, or a small file of many nodes and
    // keys would keep the renderer busy for hours.
    let keys = animation
        .and_then(|a| model.animations.get(a))
        .map_or(0, |a| {
            a.channels.iter().map(|c| c.times.len()).sum::<usize>()
        });
    let per_pass = model.nodes.len() + keys;
    let work = animated_meshes
        .saturating_mul(2 * keys + 1)
        .saturating_mul(per_pass);
    if work > MAX_HIERARCHY_WORK {
        return Err(err(
            path,
            format!(
                "{animated_meshes} animated mesh nodes, {keys} key values and {} nodes need {work} \
                 node evaluations to place, expected at most {MAX_HIERARCHY_WORK}",
                model.nodes.len()
            ),
        ));
    }
    // Each mesh node becomes an object of the scene, and every instant the renderer takes
    // (sub-frames, samples: hundreds for one frame) places all of them: a 300 kB file of
    // 16,000 instances of one triangle took 14 s to render 0.01 s of a recording, and one of
    // 200,000 ran past 200 s.
    if scene.objects.len() + mesh_nodes > MAX_OBJECTS {
        return Err(err(
            path,
            format!(
                "{mesh_nodes} mesh nodes to place beside the scene's {} objects, expected at most \
                 {MAX_OBJECTS} objects in all (each is posed at every instant rendered)",
                scene.objects.len()
            ),
        ));
    }
    let tau0 = clock.tau(0.0);
    let world0 = model.world(animation, tau0);
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
        let animated = moving[n];
        let reference = DMat3::from_mat4(world0[n]);
        let kind = if let Some(skin) = node.skin {
            // Skinned: deforms when any joint moves; a rest skin is still posed once.
            if skin_moving[skin] {
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
        let placed = PlacedNode {
            model: model.clone(),
            node: n,
            animation,
            clock,
            scale: placement.scale,
        };
        let mut shape = GltfShape {
            placed: placed.clone(),
            kind,
            reference,
            rest: Arc::new(Mesh::new(Vec::new(), Vec::new())),
            tri_material: Vec::new(),
        };
        shape.tri_material = model.meshes[m]
            .iter()
            .flat_map(|p| std::iter::repeat_n(p.material.unwrap_or(usize::MAX), p.triangles.len()))
            .collect();
        // The rest pose from the world matrices at time 0, computed once for every node.
        shape.rest = Arc::new(shape.posed_in(&world0));
        let mut anims = Vec::new();
        if kind == Kind::Rigid {
            let inv = reference.inverse();
            anims.push(Anim::Keyframes(Arc::new(NodeTrack {
                placed,
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

/// Most objects a scene may hold once a model's mesh nodes are placed (one object each): the
/// built-in scenes have a few dozen; 4,000 instances of a triangle render a frame in about a
/// second here, and the cost of every instant grows with the count.
const MAX_OBJECTS: usize = 4096;

/// Largest number of node evaluations [`place_model`] accepts for one model (moving mesh nodes ×
/// key times × nodes): a few seconds of work.
const MAX_HIERARCHY_WORK: usize = 200_000_000;

/// Whether animation `animation` moves each node, through itself or an ancestor (one pass,
/// parents before children).
fn moving_nodes(model: &GltfModel, animation: Option<usize>) -> Vec<bool> {
    let mut moving = vec![false; model.nodes.len()];
    if let Some(a) = animation.and_then(|a| model.animations.get(a)) {
        for ch in &a.channels {
            moving[ch.node] = true;
        }
    }
    for &n in &model.order {
        if let Some(p) = model.nodes[n].parent {
            moving[n] |= moving[p];
        }
    }
    moving
}

/// For every node, bounds `(l, t)` over all times of `animation` on its world matrix: the norm of
/// the linear part is at most `l` and the translation at most `t` long. Each local transform's
/// bounds take the largest scale and translation over the rest value and the key values of the
/// channels driving it (interpolation stays within them; rotations keep lengths), and chain
/// down the hierarchy. Non-finite results read as beyond any bound.
fn world_reach(model: &GltfModel, animation: Option<usize>) -> Vec<(f64, f64)> {
    let channels = animation
        .and_then(|a| model.animations.get(a))
        .map_or(&[][..], |a| &a.channels[..]);
    let mut local: Vec<(f64, f64)> = model
        .nodes
        .iter()
        .map(|node| match &node.local {
            Local::Matrix(m) => (frobenius(m), m.w_axis.truncate().length()),
            Local::Trs(x) => (x.s.abs().max_element(), x.t.length()),
        })
        .collect();
    for ch in channels {
        let l = &mut local[ch.node];
        for v in &ch.values {
            let v3 = DVec3::new(v[0], v[1], v[2]);
            match ch.property {
                Property::Scale => l.0 = l.0.max(v3.abs().max_element()),
                Property::Translation => l.1 = l.1.max(v3.length()),
                Property::Rotation => {}
            }
        }
    }
    let mut world = vec![(1.0, 0.0); model.nodes.len()];
    for &n in &model.order {
        let (pl, pt) = model.nodes[n].parent.map_or((1.0, 0.0), |p| world[p]);
        world[n] = (pl * local[n].0, pl * local[n].1 + pt);
    }
    world
}

/// The Frobenius norm of an affine matrix's linear part: a bound on how much it stretches.
fn frobenius(m: &DMat4) -> f64 {
    let lin = DMat3::from_mat4(*m).to_cols_array();
    lin.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// A bound on the distance from the model's origin of mesh node `n`'s vertices at any time,
/// skinned or not, from [`world_reach`]'s bounds (skinning weights are non-negative and
/// normalised, so a skinned vertex stays within the farthest joint's reach).
fn geometry_reach(model: &GltfModel, n: usize, reach: &[(f64, f64)]) -> f64 {
    let node = &model.nodes[n];
    let r = node.mesh.map_or(0.0, |m| {
        model.meshes[m]
            .iter()
            .flat_map(|p| p.positions.iter().map(|v| v.length()))
            .fold(0.0, f64::max)
    });
    let own = reach[n].0 * r + reach[n].1;
    let own = if own.is_nan() { f64::INFINITY } else { own };
    let Some(skin) = node.skin.and_then(|s| model.skins.get(s)) else {
        return own;
    };
    skin.joints
        .iter()
        .zip(&skin.inverse_bind)
        .map(|(&j, ib)| {
            let (l, t) = reach[j];
            l * (frobenius(ib) * r + ib.w_axis.truncate().length()) + t
        })
        .fold(
            own,
            |a, b| if b.is_nan() { f64::INFINITY } else { a.max(b) },
        )
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
