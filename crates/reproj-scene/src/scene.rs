//! The scene model: objects (shape, material, place in a parent-child hierarchy, animation), the
//! main light, and the scene at one instant (world transforms plus a top-level BVH).

use std::f64::consts::PI;
use std::time::Duration;

use obvhs::aabb::Aabb;
use obvhs::bvh2::builder::build_bvh2;
use obvhs::bvh2::Bvh2;
use obvhs::ray::RayHit;
use obvhs::{Boundable, BvhBuildParams};

use crate::anim::Anim;
use crate::error::{Result, SceneError};
use crate::material::Material;
use crate::math::{add, cross, dot, length, lerp, mul, normalize, scale, sub, Rigid, V3};
use crate::mesh::{f32_ray, Bounds, LocalHit};
use crate::rig::CameraPath;
use crate::shape::{Partial, Shape};

/// Shadow rays per shading point over the light's disc. 32 keeps the penumbra smooth (33
/// levels) while a fixed spiral keeps it deterministic.
pub const SHADOW_SAMPLES: usize = 32;

// One bit per shadow ray in the masks of `Snapshot::blocked_rays`.
const _: () = assert!(SHADOW_SAMPLES > 0 && SHADOW_SAMPLES <= 32);

/// Corners of the polygon around the light's disc whose rays decide a convex occluder's umbra
/// ([`Snapshot::occluded_rays`]).
///
/// For a convex solid `K` and a ray origin `o`, the directions `l + w` (`w ⊥ l`) whose rays
/// meet `K` form a convex set of `w`: the cone over `K − o` is convex, and so is its section
/// by a plane. The disc samples' `w` lie within the radius `R₀` of the largest; the polygon's
/// corners are those of a regular hexagon around the radius `R₀·(1 + 10⁻³)`. When the rays
/// toward all six are blocked, so is every ray toward the polygon, and every sample lies inside
/// it by at least `10⁻³·R₀` (`2·10⁻⁵` radians in the courtyard), far beyond where rounding could
/// turn its own test (`Shape::occludes`, errors near `10⁻¹⁵` of the coordinates) the other
/// way. Only the box and the sphere are used so: their tests are one slab or one quadratic,
/// without seams between pieces.
const UMBRA_SIDES: usize = 6;

/// Every shadow ray of a shading point, as a mask of [`Snapshot::blocked_rays`].
pub(crate) const ALL_RAYS: u32 = u32::MAX >> (32 - SHADOW_SAMPLES);

/// The shadow fraction of a mask of hidden shadow rays.
pub(crate) fn shadow_fraction(hidden: u32) -> f64 {
    hidden.count_ones() as f64 / SHADOW_SAMPLES as f64
}

/// Which occluders [`Snapshot::blocked_rays`] traces against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Occluders<'c> {
    All,
    /// Objects that do not move (the same at every instant).
    Still,
    /// These moving objects (a superset of those that can shadow the point, see
    /// [`Snapshot::movers_near`]).
    Moving(&'c [usize]),
}

/// One object: a shape with a material, placed in its parent's frame and animated.
#[derive(Debug, Clone)]
pub struct Object {
    /// Name (for errors and debugging).
    pub name: String,
    /// Geometry in object space.
    pub shape: Shape,
    /// Surface material.
    pub material: Material,
    /// Index of the parent object (it must come earlier), or `None` for the world.
    pub parent: Option<usize>,
    /// Rest placement in the parent's frame, applied after the animation.
    pub place: Rigid,
    /// Elementary motions, `local(t) = place ∘ anims[0](t) ∘ anims[1](t) ∘ …`; empty = still.
    pub anims: Vec<Anim>,
    /// Whether it blocks the main light.
    pub casts_shadow: bool,
}

impl Object {
    /// A still, shadow-casting object placed at `place` in the world.
    pub fn new(name: &str, shape: Shape, material: Material, place: Rigid) -> Object {
        Object {
            name: name.to_string(),
            shape,
            material,
            parent: None,
            place,
            anims: Vec::new(),
            casts_shadow: true,
        }
    }

    /// The same object with motions appended.
    pub fn animated(mut self, anims: impl IntoIterator<Item = Anim>) -> Object {
        self.anims.extend(anims);
        self
    }

    /// The same object attached to `parent`.
    pub fn child_of(mut self, parent: usize) -> Object {
        self.parent = Some(parent);
        self
    }
}

/// The main directional light, with an angular radius for soft shadows, plus a sky/ground
/// hemisphere ambient term.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Light {
    /// Elevation above the horizon (radians).
    pub elevation: f64,
    /// Azimuth at `t = 0` (radians; 0 = from +z, π/2 = from +x).
    pub azimuth: f64,
    /// Azimuth swing amplitude (radians) in the dynamic variant: `azimuth + swing·sin(rate·t)`.
    pub swing: f64,
    /// Swing rate (rad/s).
    pub swing_rate: f64,
    /// Elevation swing amplitude (radians), with the same rate (cosine phase).
    pub elevation_swing: f64,
    /// Angular radius of the light's disc (radians); sets the width of the penumbrae.
    pub angular_radius: f64,
    /// Light colour times intensity.
    pub color: V3,
    /// Ambient from above.
    pub ambient_sky: V3,
    /// Ambient from below.
    pub ambient_ground: V3,
}

impl Light {
    /// Unit vector toward the light at (effective) time `t`.
    pub fn direction(&self, t: f64) -> V3 {
        let az = self.azimuth + self.swing * (self.swing_rate * t).sin();
        let el = self.elevation + self.elevation_swing * (self.swing_rate * t).cos();
        [el.cos() * az.sin(), el.sin(), el.cos() * az.cos()]
    }

    /// The fixed Vogel-spiral sample directions over the light's disc around `l`.
    fn samples(&self, l: V3) -> [V3; SHADOW_SAMPLES] {
        let e1 = normalize(if l[1].abs() < 0.99 {
            cross(l, [0.0, 1.0, 0.0])
        } else {
            cross(l, [1.0, 0.0, 0.0])
        });
        let e2 = cross(e1, l);
        let golden = PI * (3.0 - 5f64.sqrt());
        std::array::from_fn(|k| {
            let r = self.angular_radius.tan() * ((k as f64 + 0.5) / SHADOW_SAMPLES as f64).sqrt();
            let (s, c) = (k as f64 * golden).sin_cos();
            normalize(add(l, add(scale(e1, r * c), scale(e2, r * s))))
        })
    }
}

/// Still or animated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Variant {
    /// Every object and the light stay at their `t = 0` pose (the camera still moves).
    Static,
    /// Objects and light animate.
    Dynamic,
}

impl Variant {
    /// `"static"` or `"dynamic"`.
    pub fn name(self) -> &'static str {
        match self {
            Variant::Static => "static",
            Variant::Dynamic => "dynamic",
        }
    }

    /// Parses `"static"` or `"dynamic"`.
    ///
    /// # Errors
    /// [`SceneError::UnknownVariant`] for anything else.
    pub fn parse(name: &str) -> Result<Variant> {
        match name {
            "static" => Ok(Variant::Static),
            "dynamic" => Ok(Variant::Dynamic),
            _ => Err(SceneError::UnknownVariant {
                name: name.to_string(),
            }),
        }
    }
}

/// A renderable, animated scene with its camera path.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Scene name.
    pub name: String,
    /// Static or dynamic.
    pub variant: Variant,
    /// Objects, parents before children.
    pub objects: Vec<Object>,
    /// The main light.
    pub light: Light,
    /// Colour of every pixel where nothing is hit (at `Z = 0`).
    pub sky: [u8; 3],
    /// Length of the animation (seconds).
    pub duration: f64,
    /// Near plane of every camera (metres).
    pub near: f64,
    /// Far plane of every camera (metres); geometry beyond it is not drawn.
    pub far: f64,
    /// The head-box path and the anchor's deviation from it.
    pub path: CameraPath,
    moves: Vec<bool>,
}

impl Scene {
    /// Assembles a scene, checking the hierarchy and the camera path.
    ///
    /// # Errors
    /// [`SceneError::BadHierarchy`] when a parent does not come before its child;
    /// [`SceneError::BadPath`] as [`CameraPath::check`].
    pub fn new(
        name: &str,
        variant: Variant,
        objects: Vec<Object>,
        light: Light,
        sky: [u8; 3],
        duration: f64,
        (near, far): (f64, f64),
        path: CameraPath,
    ) -> Result<Scene> {
        let moves = compute_moves(&objects, variant)?;
        path.check()?;
        Ok(Scene {
            name: name.to_string(),
            variant,
            objects,
            light,
            sky,
            duration,
            near,
            far,
            path,
            moves,
        })
    }

    /// Re-derives which objects move after `objects` was changed in place (e.g. by
    /// [`crate::gltf::place_gltf`], or motions appended to an object).
    ///
    /// # Errors
    /// [`SceneError::BadHierarchy`] and [`SceneError::BadPath`] as [`Scene::new`].
    pub fn refresh(&mut self) -> Result<()> {
        self.moves = compute_moves(&self.objects, self.variant)?;
        self.path.check()
    }

    /// Checks what rendering relies on, as every render function does first: the camera path
    /// ([`CameraPath::check`]), and that which objects move was derived from the objects as
    /// they are (the fields are public; a change needs [`Scene::refresh`]).
    ///
    /// # Errors
    /// [`SceneError::BadPath`], [`SceneError::BadHierarchy`], or [`SceneError::Changed`] when
    /// the objects changed since [`Scene::new`] or [`Scene::refresh`].
    pub fn check(&self) -> Result<()> {
        self.path.check()?;
        if compute_moves(&self.objects, self.variant)? != self.moves {
            return Err(SceneError::Changed {
                derived: self.moves.len(),
                now: self.objects.len(),
            });
        }
        Ok(())
    }

    /// Whether object `i` moves (never in the static variant). Points on objects that do not
    /// move have exactly zero motion.
    ///
    /// # Panics
    /// When `i` is not an object's index.
    pub fn moves(&self, i: usize) -> bool {
        self.moves[i]
    }

    /// The time the animation is evaluated at: `t`, or 0 in the static variant.
    fn anim_time(&self, t: f64) -> f64 {
        match self.variant {
            Variant::Static => 0.0,
            Variant::Dynamic => t,
        }
    }

    /// World transform of every object at time `t`.
    ///
    /// # Panics
    /// When an object's parent is not an earlier object ([`Scene::new`], [`Scene::refresh`]
    /// and [`Scene::check`] refuse such a scene).
    pub fn transforms(&self, t: f64) -> Vec<Rigid> {
        let te = self.anim_time(t);
        let mut world: Vec<Rigid> = Vec::with_capacity(self.objects.len());
        for o in &self.objects {
            let mut local = o.place;
            for a in &o.anims {
                local = local.then(&a.at(te));
            }
            let w = match o.parent {
                Some(p) => world[p].then(&local),
                None => local,
            };
            world.push(w);
        }
        world
    }

    /// The scene frozen at time `t`.
    pub(crate) fn at(&self, t: f64) -> Snapshot<'_> {
        Snapshot::new(self, t)
    }
}

/// Which objects move: animated, deforming, or children of moving ones (never in the static
/// variant); checks that parents come first.
fn compute_moves(objects: &[Object], variant: Variant) -> Result<Vec<bool>> {
    let mut moves = Vec::with_capacity(objects.len());
    for (index, o) in objects.iter().enumerate() {
        let parent_moves = match o.parent {
            Some(p) if p < index => moves[p],
            Some(parent) => {
                return Err(SceneError::BadHierarchy {
                    index,
                    name: o.name.clone(),
                    parent,
                })
            }
            None => false,
        };
        moves.push(
            variant == Variant::Dynamic
                && (parent_moves || !o.anims.is_empty() || o.shape.deforms()),
        );
    }
    Ok(moves)
}

struct Instance(Aabb);

impl Boundable for Instance {
    fn aabb(&self) -> Aabb {
        self.0
    }
}

/// The nearest surface along a ray.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hit {
    /// Object index.
    pub obj: usize,
    /// Ray parameter.
    pub t: f64,
    /// The object-space intersection.
    pub local: LocalHit,
}

/// A scene at one instant: world transforms, their inverses, bounding spheres, the top-level
/// BVH over the instances (rebuilt per instant: a few dozen boxes, microseconds) and the light.
pub(crate) struct Snapshot<'a> {
    /// Unique to this snapshot (for [`NEAR_CASTERS`]).
    id: u64,
    pub scene: &'a Scene,
    pub world: Vec<Rigid>,
    pub inv: Vec<Rigid>,
    spheres: Vec<(V3, f64)>,
    bvh: Option<Bvh2>,
    /// Deforming shapes posed at this instant (meshes with their BVH, built once per snapshot);
    /// `None` where the object's own shape applies.
    posed: Vec<Option<Shape>>,
    pub light: V3,
    samples: [V3; SHADOW_SAMPLES],
    /// A bound on `dot(n, l)` above which no disc sample lies below the tangent plane of a
    /// point with unit normal `n` ([`Snapshot::below_tangent_plane`]).
    all_above: f64,
    /// `(sin, cos)` of the light's angular radius.
    light_sin_cos: (f64, f64),
    /// Per object: the light direction in object space and the object-space bounds, what the
    /// shadow rays' culling needs of every object on every evaluation.
    light_obj: Vec<(V3, Bounds)>,
    /// The shadow-casting objects arranged across the light, so each shadow evaluation visits
    /// only those its cone can reach.
    cull: ShadowCull,
    /// The shadow-casting objects that move.
    moving_casters: Vec<usize>,
    /// Per object: the shadow rays' directions (`samples`) in its object space.
    samples_obj: Vec<[V3; SHADOW_SAMPLES]>,
    /// Per object: the least and the greatest `y` of `samples_obj` (a quad's normal axis).
    samples_y: Vec<(f64, f64)>,
    /// A bound on `|ŝ − l|` over the unit disc samples `ŝ` ([`crate::mesh::Mesh::occluded_rays`]).
    spread: f64,
    /// Per object: the directions toward the corners of the polygon around the disc
    /// ([`UMBRA_SIDES`]) in its object space.
    umbra_obj: Vec<[V3; UMBRA_SIDES]>,
}

/// A conservative pre-selection for the shadow cull, built once per instant.
///
/// With `a` the light's angular radius (plus a little, to cover the exact test's tolerance),
/// `s = sin a`, and an object's bounding sphere `(c, r)` at distance `dist` from the point `x`,
/// the exact sphere test in [`Snapshot::shadow`] keeps only objects whose centre lies within
/// `r + s·dist` of the line `x + t·l`; with `q` that lateral distance and `h` the distance along
/// `l`, `dist ≤ |h| + q` gives `q ≤ (r + s·|h|) / (1 − s)`. Objects are sorted by one coordinate
/// across the light, in a few windows by size (ordinary objects, then houses and walls up to four
/// times as wide), so a query reads only the part of each window that bound allows for the
/// window's largest radius and the depth range; the few giant objects (the ground) are always
/// tested. Both the windows and the per-object bound keep a 1 % margin plus an absolute one
/// against rounding, so they never reject an object that the exact tests would keep: the
/// candidate set is unchanged (its order is not, which decides only which occluder of a ray is
/// found first, not whether one is).
struct ShadowCull {
    /// Unit vectors across the light.
    e1: V3,
    e2: V3,
    /// `sin a` and `1.01 / (1 − s)`; `None` for a light so wide that the bound is useless.
    s: Option<(f64, f64)>,
    /// Per object: centre's coordinates `(u, v, w)` along `e1`, `e2`, `l`.
    proj: Vec<V3>,
    /// Shadow casters by size, each window as `(u, index)` sorted by `u`, with its largest
    /// radius.
    windows: Vec<(Vec<(f64, usize)>, f64)>,
    /// Shadow casters always tested (giant, or every caster when the light is too wide).
    big: Vec<usize>,
    /// The range of `w` over all casters, and the scale of the coordinates (for the absolute
    /// margin).
    w_range: (f64, f64),
    size: f64,
    /// How far a shading point may lie from the point of a query with the radii grown by as
    /// much ([`Snapshot::near_casters`]); 0 where queries are not shared.
    reach: f64,
    /// `(sin, cos)` of the light's angular radius plus [`NEAR_ANGLE`], for the exact test that
    /// filters a shared query's list ([`Snapshot::may_shadow_near`]); `None` for a light so wide
    /// (as `s`) that the list is not filtered.
    near_sin_cos: Option<(f64, f64)>,
}

/// The angle (radians) by which [`Snapshot::may_shadow_near`] widens the light's disc: it covers
/// the slack and the rounding of the exact test ([`Snapshot::sphere_may_shadow`]) at the point
/// itself, see there.
const NEAR_ANGLE: f64 = 1e-3;

/// Per thread: the shadow casters that [`ShadowCull`] keeps for every point within the cull's
/// `reach` of `x`, at the instant of the snapshot numbered `snap` ([`Snapshot::near_casters`]).
struct NearCasters {
    snap: u64,
    x: V3,
    list: Vec<usize>,
}

thread_local! {
    /// Neighbouring pixels' shading points mostly lie within the cull's reach of each other, so
    /// one query serves a run of them.
    static NEAR_CASTERS: std::cell::RefCell<NearCasters> = const {
        std::cell::RefCell::new(NearCasters {
            snap: u64::MAX,
            x: [0.0; 3],
            list: Vec::new(),
        })
    };
}

/// Numbers the snapshots, so that [`NEAR_CASTERS`] is never read for another instant or scene.
static NEXT_SNAPSHOT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

impl ShadowCull {
    fn new(objects: &[Object], spheres: &[(V3, f64)], l: V3, angular_radius: f64) -> ShadowCull {
        let e1 = normalize(if l[0].abs() < 0.9 {
            cross(l, [1.0, 0.0, 0.0])
        } else {
            cross(l, [0.0, 1.0, 0.0])
        });
        let e2 = normalize(cross(l, e1));
        let a = angular_radius + 1e-4;
        let s = (a < 0.5).then(|| (a.sin(), 1.01 / (1.0 - a.sin())));
        let proj: Vec<V3> = spheres
            .iter()
            .map(|&(c, _)| [dot(c, e1), dot(c, e2), dot(c, l)])
            .collect();
        let casters: Vec<usize> = (0..objects.len())
            .filter(|&i| objects[i].casts_shadow)
            .collect();
        let (mut u_lo, mut u_hi) = (f64::INFINITY, f64::NEG_INFINITY);
        let (mut w_lo, mut w_hi) = (f64::INFINITY, f64::NEG_INFINITY);
        let mut size = 1.0f64;
        for &i in &casters {
            let (c, r) = spheres[i];
            u_lo = u_lo.min(proj[i][0]);
            u_hi = u_hi.max(proj[i][0]);
            w_lo = w_lo.min(proj[i][2]);
            w_hi = w_hi.max(proj[i][2]);
            size = size.max(c.iter().fold(r, |m, x| m.max(x.abs() + r)));
        }
        // An object wider than a sixteenth of the casters' spread would widen every window of
        // the ordinary ones; up to four times that, it goes to a second window; beyond, it is
        // tested always.
        let limits = [1.0, 4.0].map(|f| f * (u_hi - u_lo) / 16.0);
        let mut windows = limits.map(|_| (Vec::new(), 0.0f64));
        let mut big = Vec::new();
        for &i in &casters {
            let r = spheres[i].1;
            let window = limits.iter().position(|&limit| r <= limit);
            match window {
                Some(w) if s.is_some() && proj[i].iter().all(|x| x.is_finite()) => {
                    windows[w].0.push((proj[i][0], i));
                    windows[w].1 = windows[w].1.max(r);
                }
                _ => big.push(i),
            }
        }
        for (sorted, _) in &mut windows {
            sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
        // Half the ordinary casters' size limit: most runs of neighbouring pixels' points share
        // one query, and the grown radii and box add few casters to it. With the list filtered
        // by the exact tests (`may_shadow_near`), of the reaches tried (a quarter to all of the
        // limit) half gave the fewest instructions in the courtyard's ground truth; before the
        // filter, the whole limit did (of a quarter to four times it).
        let reach = limits[0] * 0.5;
        let reach = if reach.is_finite() && reach > 0.0 {
            reach
        } else {
            0.0
        };
        ShadowCull {
            e1,
            e2,
            s,
            proj,
            windows: windows.into(),
            big,
            w_range: (w_lo, w_hi),
            size,
            reach,
            near_sin_cos: (angular_radius < 0.5).then(|| (angular_radius + NEAR_ANGLE).sin_cos()),
        }
    }

    /// Calls `visit` on every shadow caster whose bounding sphere, its radius grown by `grow`,
    /// the exact test could keep for a shadow evaluation at `x` (`ext` the largest coordinate of
    /// `x`, at least 1); `spheres` are the objects' world bounding spheres.
    fn visit(
        &self,
        x: V3,
        (l, ext, grow): (V3, f64, f64),
        spheres: &[(V3, f64)],
        mut visit: impl FnMut(usize),
    ) {
        let Some((s, k)) = self.s else {
            self.big.iter().for_each(|&i| visit(i));
            return;
        };
        let p = [dot(x, self.e1), dot(x, self.e2), dot(x, l)];
        if !p.iter().all(|c| c.is_finite()) {
            self.big
                .iter()
                .chain(self.windows.iter().flat_map(|w| w.0.iter().map(|e| &e.1)))
                .for_each(|&i| visit(i));
            return;
        }
        let eps = 1e-6 * (self.size + ext);
        let may = |i: usize| may_shadow(&self.proj[i], spheres[i].1 + grow, &p, (s, k), eps);
        for &i in &self.big {
            if may(i) {
                visit(i);
            }
        }
        let depth = (self.w_range.1 - p[2]).max(p[2] - self.w_range.0).max(0.0);
        for (sorted, r_max) in &self.windows {
            let half = (r_max + grow + s * depth) * k + eps;
            let start = sorted.partition_point(|e| e.0 < p[0] - half);
            for &(u, i) in &sorted[start..] {
                if u > p[0] + half {
                    break;
                }
                if may(i) {
                    visit(i);
                }
            }
        }
    }
}

/// The directions toward the corners of the polygon of [`UMBRA_SIDES`] around the disc samples
/// `samples` of the light `l`.
fn umbra_corners(samples: &[V3; SHADOW_SAMPLES], l: V3) -> [V3; UMBRA_SIDES] {
    // Each sample's point on the plane at unit distance along `l` (its ray's direction scaled to
    // `l + w`), and the largest `|w|`.
    let r0 = samples.iter().fold(0.0f64, |m, s| {
        m.max(length(sub(scale(*s, 1.0 / dot(*s, l)), l)))
    });
    let e1 = normalize(if l[0].abs() < 0.9 {
        cross(l, [1.0, 0.0, 0.0])
    } else {
        cross(l, [0.0, 1.0, 0.0])
    });
    let e2 = normalize(cross(l, e1));
    // A regular polygon's corners lie at `1 / cos(π / sides)` of its inner radius.
    let corner = r0 * (1.0 + 1e-3) / (PI / UMBRA_SIDES as f64).cos();
    std::array::from_fn(|j| {
        let (s, c) = (2.0 * PI * j as f64 / UMBRA_SIDES as f64).sin_cos();
        add(l, add(scale(e1, corner * c), scale(e2, corner * s)))
    })
}

/// The pre-selection of [`ShadowCull`] for one sphere: whether a sphere of radius `r` whose
/// centre has the coordinates `q` across and along the light may shadow the point with the
/// coordinates `p`, with `(s, k)` and `eps` as there.
#[inline]
fn may_shadow(q: &V3, r: f64, p: &V3, (s, k): (f64, f64), eps: f64) -> bool {
    let (du, dv) = (q[0] - p[0], q[1] - p[1]);
    let bound = (r + s * (q[2] - p[2]).abs()) * k + eps;
    // Rejects only on a definite answer (a NaN keeps the object, as the exact test would have to
    // decide).
    (du * du + dv * dv).partial_cmp(&(bound * bound)) != Some(std::cmp::Ordering::Greater)
}

/// The moving shadow casters over several instants with one light, each with a sphere that
/// holds its bounding spheres at all of them ([`Snapshot::swept_casters`]).
pub(crate) struct SweptCasters {
    /// Per moving caster: its index, the coordinates of the sphere's centre across and along the
    /// light (as in [`ShadowCull`]) and the sphere's radius.
    casters: Vec<(usize, V3, f64)>,
}

impl<'a> Snapshot<'a> {
    fn new(scene: &'a Scene, t: f64) -> Snapshot<'a> {
        let world = scene.transforms(t);
        let inv: Vec<Rigid> = world.iter().map(Rigid::inverse).collect();
        let te = scene.anim_time(t);
        let posed: Vec<Option<Shape>> = scene
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| match &o.shape {
                Shape::Gltf(g) if scene.moves(i) && g.deforms() => {
                    Some(Shape::Mesh(std::sync::Arc::new(g.posed(te))))
                }
                _ => None,
            })
            .collect();
        let mut spheres = Vec::with_capacity(world.len());
        let mut boxes = Vec::with_capacity(world.len());
        for (i, w) in world.iter().enumerate() {
            let b = posed[i]
                .as_ref()
                .unwrap_or(&scene.objects[i].shape)
                .bounds();
            let (c, r) = b.sphere();
            spheres.push((w.point(c), r));
            boxes.push(Instance(
                Bounds::around(b.corners().map(|p| w.point(p))).padded_f32(),
            ));
        }
        let bvh = (!boxes.is_empty()).then(|| {
            build_bvh2(
                &boxes,
                BvhBuildParams::fastest_build(),
                &mut Duration::default(),
            )
        });
        let light = scene.light.direction(scene.anim_time(t));
        let light_obj = (0..world.len())
            .map(|i| {
                let b = posed[i]
                    .as_ref()
                    .unwrap_or(&scene.objects[i].shape)
                    .bounds();
                (inv[i].vector(light), b)
            })
            .collect();
        let cull = ShadowCull::new(&scene.objects, &spheres, light, scene.light.angular_radius);
        let moving_casters = (0..world.len())
            .filter(|&i| scene.objects[i].casts_shadow && scene.moves(i))
            .collect();
        let samples = scene.light.samples(light);
        // The sine of the widest angle between the light and a disc sample (each sample's
        // component across `l`, over its length), plus a margin far above their rounding.
        let all_above = samples.iter().fold(0.0f64, |m, s| {
            let across = sub(*s, scale(light, dot(*s, light)));
            m.max(length(across) / length(*s))
        }) + 1e-6;
        let samples_obj: Vec<[V3; SHADOW_SAMPLES]> =
            inv.iter().map(|m| samples.map(|s| m.vector(s))).collect();
        let samples_y = samples_obj
            .iter()
            .map(|dirs| {
                dirs.iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), d| {
                        (lo.min(d[1]), hi.max(d[1]))
                    })
            })
            .collect();
        let spread = samples
            .iter()
            .fold(0.0f64, |m, s| m.max(length(sub(normalize(*s), light))))
            * (1.0 + 1e-6);
        let umbra = umbra_corners(&samples, light);
        let umbra_obj = inv.iter().map(|m| umbra.map(|s| m.vector(s))).collect();
        Snapshot {
            id: NEXT_SNAPSHOT.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
            spread,
            umbra_obj,
            cull,
            moving_casters,
            samples_obj,
            samples_y,
            all_above,
            light_sin_cos: scene.light.angular_radius.sin_cos(),
            light_obj,
            scene,
            world,
            inv,
            spheres,
            bvh,
            posed,
            light,
            samples,
        }
    }

    /// Object `i`'s world bounding sphere at this instant.
    pub(crate) fn sphere(&self, i: usize) -> (V3, f64) {
        self.spheres[i]
    }

    /// Object `i`'s shape at this instant.
    pub fn shape(&self, i: usize) -> &Shape {
        self.posed[i]
            .as_ref()
            .unwrap_or(&self.scene.objects[i].shape)
    }

    /// Whether the ray `x + t·l` (`l` the light), `t ≥ 0`, passes within `grow` (per axis) of object `i`'s
    /// object-space box.
    fn cone_may_hit(&self, i: usize, x: V3, grow: f64) -> bool {
        let (d, b) = &self.light_obj[i];
        let o = self.inv[i].point(x);
        crate::mesh::grown_slabs(b.min, b.max, grow, o, *d).is_some_and(|(t0, t1)| t0 <= t1)
    }

    /// The nearest surface along `o + t·d` with `t ∈ (tmin, tmax)`.
    pub fn trace(&self, o: V3, d: V3, tmin: f64, tmax: f64) -> Option<Hit> {
        let bvh = self.bvh.as_ref()?;
        let ray = f32_ray(o, d, f32::INFINITY);
        // The winner's object and what its `t` came with, in its object space: the normal and
        // texture coordinates are computed once, for the winner only, from the same values.
        let mut best: Option<(usize, V3, V3, Partial)> = None;
        let mut limit = tmax;
        let mut rh = RayHit::none();
        bvh.ray_traverse(ray, &mut rh, |_, id| {
            let obj = bvh.primitive_indices[id] as usize;
            let inv = &self.inv[obj];
            let (lo, ld) = (inv.point(o), inv.vector(d));
            match self.shape(obj).intersect_t(lo, ld, tmin, limit) {
                Some(p) => {
                    limit = p.t();
                    best = Some((obj, lo, ld, p));
                    // Culling bound only: a little above the f64 distance, so the f32 box tests
                    // never drop a closer instance.
                    (limit * (1.0 + 1e-6)) as f32 + 1e-6
                }
                None => f32::INFINITY,
            }
        });
        Some(self.finish_hit(best?))
    }

    /// The hit of a closest-hit search's winner: its object, the ray in its object space and
    /// what its distance came with (the normal and texture coordinates, for the winner only).
    #[inline]
    pub(crate) fn finish_hit(&self, (obj, lo, ld, p): (usize, V3, V3, Partial)) -> Hit {
        let local = self.shape(obj).finish(lo, ld, p);
        Hit {
            obj,
            t: local.t,
            local,
        }
    }

    /// The distance from `x` to object `i`'s bounding-sphere centre, or `None` where the
    /// sphere's angular disc seen from `x` and the light's disc do not overlap (the object
    /// cannot shadow `x`).
    #[inline]
    fn sphere_may_shadow(&self, i: usize, x: V3) -> Option<f64> {
        let (c, r) = self.spheres[i];
        let v = sub(c, x);
        let dist = length(v);
        self.discs_may_overlap(v, dist, r, self.light_sin_cos, 1e-9)
            .then_some(dist)
    }

    /// Whether a sphere of radius `r` whose centre lies at `v` from a point (`dist = |v|`) may
    /// overlap the light's disc seen from there: its angular disc (radius `b = asin(r / dist)`
    /// around `v`) and the light's (`sin_cos` of its angular radius `a`, around the light
    /// direction) meet when the angle `γ` between their centres is at most `a + b`, tested as
    /// `cos γ ≥ cos(a + b) − slack`; true where the point is inside the sphere (or a value is
    /// NaN). The exact test ([`Snapshot::sphere_may_shadow`]) and the shared lists' filter
    /// ([`Snapshot::may_shadow_near`], with its margins) are this one test.
    #[inline(always)]
    fn discs_may_overlap(
        &self,
        v: V3,
        dist: f64,
        r: f64,
        (sin_a, cos_a): (f64, f64),
        slack: f64,
    ) -> bool {
        if dist > r {
            let cos_gamma = dot(v, self.light) / dist;
            let sin_b = r / dist;
            let cos_b = (1.0 - sin_b * sin_b).max(0.0).sqrt();
            if cos_gamma < cos_a * cos_b - sin_a * sin_b - slack {
                return false;
            }
        }
        true
    }

    /// Whether object `i` may pass [`Snapshot::sphere_may_shadow`] and then the box test of
    /// [`Snapshot::blocked_rays`] ([`Snapshot::cone_may_hit`]) at some point `x` with
    /// `|x − x₀| ≤ reach` (as [`Snapshot::near_casters`] checks it): false only where they surely
    /// fail at every such `x`. First the same sphere test at `x₀` with the sphere's radius grown
    /// to `R = (r + reach)(1 + 10⁻⁹)`, the light's disc widened by [`NEAR_ANGLE`] (`δ`) and a
    /// slack of `10⁻⁶` instead of `10⁻⁹`; then the same box test at `x₀` with the box grown
    /// more (below).
    ///
    /// Why it keeps what the test at `x` keeps (`u` the unit roundoff, about `10⁻¹⁶`; `|x − x₀|`
    /// is at most `reach(1 + 4u)`, as its square was compared):
    /// - Kept at `x` with the computed distance `≤ r`: truly `|c − x| ≤ r(1 + 4u)`, so
    ///   `|c − x₀| ≤ (r + reach)(1 + 4u)`, computed at most `(r + reach)(1 + 8u) < R`: kept.
    /// - Kept at `x` otherwise, `x` truly outside the sphere (else as above): with `γ` the angle
    ///   between `l` and `c − x`, `b = asin(r / |c − x|)` and `a` the light's angular radius, the
    ///   test passed `cos γ ≥ cos(a + b) − 10⁻⁹`, up to its rounding (`cos b = √(1 − sin² b)`
    ///   can be off by `√(4u) < 3.2·10⁻⁸`): truly `cos γ ≥ cos(a + b) − η` with `η < 4·10⁻⁸`.
    ///   As `cos θ − cos(θ + δ) ≥ 2 sin²(δ/2) = 5·10⁻⁷ > η` for `0 ≤ θ ≤ π − δ` (here
    ///   `θ = a + b < 0.5 + π/2`), `γ ≤ a + δ + b`: the caps of radius `a + δ` around `l` and `b`
    ///   around `c − x` overlap, and a direction `ŝ` in both leaves `x` into the sphere
    ///   (`t ≥ 0`). The parallel ray from `x₀` passes within `|x − x₀|` of that point, so it
    ///   meets the sphere `(c, r + reach(1 + 4u))`, inside `(c, R)`: either `x₀` lies within
    ///   that sphere (computed distance `< R`, kept) or `γ₀ ≤ a + δ + b₀` holds exactly at `x₀`
    ///   with `b₀ = asin(R / |c − x₀|)`, which the computed test, off by under `4·10⁻⁸`, passes
    ///   with its slack of `10⁻⁶`.
    ///
    /// The box test at `x` asks whether the ray `o + t·d` (`o` the object-space `x`, `d` the
    /// light there, `t ≥ 0`) comes within `g = (|c − x| + r)·sin a / cos a` (per axis) of the
    /// object's box. The transform is rigid, so `o₀` (the object-space `x₀`) is within
    /// `|x − x₀| ≤ reach(1 + 4u)` of `o` on each axis, and `o₀ + t·d` within `g + reach(1 + 4u)`
    /// of the box wherever `o + t·d` is within `g`; and `|c − x| ≤ |c − x₀| + reach(1 + 4u)`. So
    /// the grown box here, `((|c − x₀| + reach + r)·sin a / cos a + reach)(1 + 10⁻⁶)` plus
    /// `10⁻⁶` of the coordinates' size, holds that ray with a margin far above the rounding of
    /// both slab tests (a slab's bound `(lo − o)/d` is rounded twice and `lo` once, a few `u` of
    /// the coordinates in space) and of the two transforms. A ray parallel to a slab and outside
    /// it at `x₀` (no interval) is outside by the margin at `x` as well.
    ///
    /// A NaN anywhere keeps the object.
    #[inline]
    fn may_shadow_near(&self, i: usize, x0: V3, reach: f64) -> bool {
        let Some((sin_a, cos_a)) = self.cull.near_sin_cos else {
            return true;
        };
        let (c, r0) = self.spheres[i];
        let r = (r0 + reach) * (1.0 + 1e-9);
        let v = sub(c, x0);
        let dist = length(v);
        if !self.discs_may_overlap(v, dist, r, (sin_a, cos_a), 1e-6) {
            return false;
        }
        // The box test, as said above (`sin a`, `cos a` of the light's own radius, as at `x`).
        let (sa, ca) = self.light_sin_cos;
        let (d, b) = &self.light_obj[i];
        let o = self.inv[i].point(x0);
        let size = [o, b.min, b.max]
            .iter()
            .flatten()
            .fold(dist, |m, v| m.max(v.abs()))
            + r
            + reach;
        let grow = ((dist + reach + r0) * sa / ca + reach) * (1.0 + 1e-6) + 1e-6 * size;
        crate::mesh::grown_slabs(b.min, b.max, grow, o, *d).is_some_and(|(t0, t1)| !(t0 > t1))
    }

    /// Fraction of the light's disc hidden from the point `x` with unit normal `n` (facing the
    /// side it is seen from) on object `obj`: 0 lit … 1 fully shadowed.
    ///
    /// Directions of the disc below the surface's tangent plane count as hidden (the surface
    /// itself blocks them), so the shadow is continuous across the terminator. A convex object
    /// is skipped as an occluder of itself: it cannot block the directions above its own tangent
    /// plane, and skipping it rules out shadow acne.
    pub fn shadow(&self, obj: usize, x: V3, n: V3) -> f64 {
        shadow_fraction(self.blocked_rays(obj, x, n, Occluders::All, None))
    }

    /// Whether the shadow rays of a still point are the same rays at `self` and at `other`
    /// (the same light direction, hence the same disc samples), so that the still objects'
    /// part of [`Snapshot::blocked_rays`] found at one holds at the other: a still object has
    /// the same transform at every instant.
    pub(crate) fn same_light(&self, other: &Snapshot<'_>) -> bool {
        self.light.map(f64::to_bits) == other.light.map(f64::to_bits)
    }

    /// The moving shadow casters over this instant and `others` (all with this light, see
    /// [`Snapshot::same_light`]), each with a sphere around its bounding spheres at every one.
    pub(crate) fn swept_casters(&self, others: &[&Snapshot<'_>]) -> SweptCasters {
        let (e1, e2, l) = (self.cull.e1, self.cull.e2, self.light);
        let casters = self
            .moving_casters
            .iter()
            .map(|&i| {
                let (c, r) = self.spheres[i];
                let r = others.iter().fold(r, |m, o| {
                    let (cj, rj) = o.spheres[i];
                    m.max(length(sub(cj, c)) + rj)
                });
                (i, [dot(c, e1), dot(c, e2), dot(c, l)], r)
            })
            .collect();
        SweptCasters { casters }
    }

    /// Into `out` (cleared first): the casters of `swept` that may shadow the point `x` at any of
    /// its instants, a superset of those that [`Snapshot::blocked_rays`] would keep at each.
    ///
    /// The sphere `(C, R)` holds the sphere `(c, r)` of every instant, with `δ = |c − C|`,
    /// `r + δ ≤ R`; [`ShadowCull`]'s bound for `(c, r)` is then at most the bound for `(C, R)`
    /// less `δ` (the factor `1 / (1 − s)` exceeds 1), and `c`'s distance from the light's line
    /// through `x` is at least `C`'s less `δ`, so a caster the bound rejects for `(C, R)` is
    /// rejected for every `(c, r)`, and the exact tests reject it too.
    pub(crate) fn movers_near(&self, swept: &SweptCasters, x: V3, out: &mut Vec<usize>) {
        out.clear();
        let p = [
            dot(x, self.cull.e1),
            dot(x, self.cull.e2),
            dot(x, self.light),
        ];
        let Some(sk) = self.cull.s.filter(|_| p.iter().all(|c| c.is_finite())) else {
            out.extend(swept.casters.iter().map(|c| c.0));
            return;
        };
        let ext = x.iter().fold(1.0f64, |a, c| a.max(c.abs()));
        let eps = 1e-6 * (self.cull.size + ext);
        out.extend(
            swept
                .casters
                .iter()
                .filter(|(_, q, r)| may_shadow(q, *r, &p, sk, eps))
                .map(|c| c.0),
        );
    }

    /// The shadow rays of [`Snapshot::shadow`] that are hidden, one bit per disc sample (bit
    /// `k` for sample `k`): those below the tangent plane and those that an occluder among
    /// `which` blocks. Rays already in `known` are not traced again (and are in the result).
    ///
    /// A ray is hidden when any occluder blocks it, so the mask over all occluders is the union
    /// of the masks over the still and the moving ones, and the order of the tests does not
    /// change it. Which objects are candidates does not depend on the other objects (the cull
    /// keeps every object the exact per-object tests keep, see [`ShadowCull`]), so a still
    /// point's still candidates, and what they block, are the same at every instant with the
    /// same light.
    pub(crate) fn blocked_rays(
        &self,
        obj: usize,
        x: V3,
        n: V3,
        which: Occluders<'_>,
        known: Option<u32>,
    ) -> u32 {
        let l = self.light;
        let (sin_a, cos_a) = self.light_sin_cos;
        if dot(n, l) < -sin_a {
            return ALL_RAYS;
        }
        // `known` holds the rays below the tangent plane already, when it is given.
        let mut hidden = known.unwrap_or_else(|| self.below_tangent_plane(n));
        if hidden == ALL_RAYS {
            return hidden;
        }
        // Offset along the normal against acne on meshes, relative to the coordinates' size.
        let ext = x.iter().fold(1.0f64, |a, c| a.max(c.abs()));
        let origin = add(x, scale(n, 1e-5 * ext));
        // Candidates with the shadow ray's origin in their object space (the same for all 32
        // rays, so it is transformed once per candidate instead of once per ray). Four in place
        // (the array is zeroed at every evaluation, and the courtyard averages under one
        // candidate per evaluation), more in `overflow`.
        let mut candidates = [(0usize, [0.0f64; 3]); 4];
        let mut nc = 0;
        let mut overflow: Vec<(usize, V3)> = Vec::new();
        let mut consider = |i: usize| {
            if i == obj && self.scene.objects[i].shape.is_convex() {
                return;
            }
            let Some(dist) = self.sphere_may_shadow(i, x) else {
                return;
            };
            let r = self.spheres[i].1;
            // The sphere is loose around long objects (walls, beams): test the light's cone
            // against the object-space box too, grown by the cone's radius at the far side of the
            // box, which contains every shadow ray's path through the box.
            if !self.cone_may_hit(i, x, (dist + r) * sin_a / cos_a) {
                return;
            }
            let c = (i, self.inv[i].point(origin));
            if nc < candidates.len() {
                candidates[nc] = c;
                nc += 1;
            } else {
                overflow.push(c);
            }
        };
        match which {
            // A short list: the exact tests alone, without the cull's window.
            Occluders::Moving(list) => list.iter().for_each(|&i| consider(i)),
            Occluders::All | Occluders::Still => {
                let still = which == Occluders::Still;
                self.near_casters(x, ext, |i| {
                    if !(still && self.scene.moves(i)) {
                        consider(i);
                    }
                })
            }
        }
        if nc == 0 && overflow.is_empty() {
            return hidden;
        }
        // Candidate by candidate: a ray is hidden when any candidate blocks it, so the order
        // changes only the work (a candidate tests the rays that the ones before it left).
        for &(i, o) in candidates[..nc].iter().chain(&overflow) {
            let todo = ALL_RAYS & !hidden;
            if todo == 0 {
                break;
            }
            hidden |= self.occluded_rays(i, o, todo);
        }
        hidden
    }

    /// Calls `visit` on every shadow caster that [`ShadowCull::visit`] keeps at `x` (`ext` as
    /// there), and on a few more, in the order of that visit: the casters kept for the grown
    /// radii at a point within the cull's `reach` of `x`, the last such query of this thread,
    /// and among them those that [`Snapshot::may_shadow_near`] keeps there.
    ///
    /// A ray `x + t·ŝ` (`t ≥ 0`) that meets a sphere `(c, r)` runs parallel to `x₀ + t·ŝ`, at
    /// `|x − x₀|` from it, which meets `(c, r + |x − x₀|)`. So a sphere that the exact test
    /// keeps at `x` is, grown by `reach ≥ |x − x₀|`, kept by the exact test at `x₀`, and hence by
    /// the cull's bound there (grown alike, with the absolute margin of the larger coordinates
    /// `ext + reach`): the list holds every caster the cull would keep at `x`. The extra ones
    /// are rejected by the exact tests that follow (`blocked_rays`), and the windows and the
    /// always-tested casters come in the same fixed order, so the candidates are those of a
    /// query at `x`, in the same order. The filter keeps every caster that the exact sphere
    /// test keeps at any such `x` (see [`Snapshot::may_shadow_near`]), so it changes neither.
    fn near_casters(&self, x: V3, ext: f64, mut visit: impl FnMut(usize)) {
        let (l, reach) = (self.light, self.cull.reach);
        if reach == 0.0 || !x.iter().all(|c| c.is_finite()) {
            return self.cull.visit(x, (l, ext, 0.0), &self.spheres, visit);
        }
        NEAR_CASTERS.with(|near| {
            let mut near = near.borrow_mut();
            let v = sub(x, near.x);
            if near.snap != self.id || !(dot(v, v) <= reach * reach) {
                let list = &mut near.list;
                list.clear();
                self.cull
                    .visit(x, (l, ext + reach, reach), &self.spheres, |i| {
                        if self.may_shadow_near(i, x, reach) {
                            list.push(i);
                        }
                    });
                near.snap = self.id;
                near.x = x;
            }
            near.list.iter().for_each(|&i| visit(i));
        });
    }

    /// The rays among `todo` (a mask as in [`Snapshot::blocked_rays`]) that object `i` blocks,
    /// the shadow rays' origin being `o` in its object space: exactly those for which
    /// [`Shape::occludes`] is true ([`Snapshot::occluded_each`]), found with fewer tests.
    fn occluded_rays(&self, i: usize, o: V3, todo: u32) -> u32 {
        let dirs = &self.samples_obj[i];
        let shape = self.shape(i);
        let mesh = match shape {
            Shape::Mesh(m) => Some(m.as_ref()),
            Shape::Gltf(g) => Some(g.rest().as_ref()),
            _ => None,
        };
        if let Some(m) = mesh {
            return m.occluded_rays(o, dirs, (self.light_obj[i].0, self.spread), todo);
        }
        // A quad (the plane `y = 0`) blocks a ray only at `t = −o_y / d_y > 0`: an origin on
        // the side every direction leaves toward (or on the plane) has `t ≤ 0` for each (the
        // sign of the quotient is exact; `d_y = 0` is no hit either). In the courtyard, the
        // ground is a candidate of the points near it on the houses and walls.
        if matches!(shape, Shape::Quad { .. }) {
            let (lo, hi) = self.samples_y[i];
            if (o[1] >= 0.0 && lo >= 0.0) || (o[1] <= 0.0 && hi <= 0.0) {
                return 0;
            }
        }
        // A convex solid that blocks the rays toward every corner of the polygon around the
        // light's disc blocks every ray of the disc (see `UMBRA_SIDES`).
        if matches!(shape, Shape::Cuboid { .. } | Shape::Sphere { .. })
            && todo.count_ones() as usize > UMBRA_SIDES
            && self.umbra_obj[i].iter().all(|&d| shape.occludes(o, d))
        {
            return todo;
        }
        self.occluded_each(i, o, todo)
    }

    /// [`Snapshot::occluded_rays`] ray by ray.
    fn occluded_each(&self, i: usize, o: V3, todo: u32) -> u32 {
        let shape = self.shape(i);
        crate::mesh::bits(todo)
            .filter(|&k| shape.occludes(o, self.samples_obj[i][k]))
            .fold(0u32, |m, k| m | 1 << k)
    }

    /// The disc samples below the tangent plane of a point with unit normal `n` (`dot(s, n) ≤ 0`),
    /// one bit each as in [`Snapshot::blocked_rays`].
    ///
    /// When the light is higher above the plane than the disc is wide, none is, and the 32 dot
    /// products are skipped: with `θ` the angle between `n` and `l` and `φ` the widest angle of
    /// a sample from `l` (`sin φ ≤ all_above − 10⁻⁶`), `cos θ > sin φ` gives `θ + φ < 90°`, so
    /// every `dot(s, n)` is positive by about `10⁻⁶`, far beyond the rounding of the sum (about
    /// `10⁻¹⁵` for unit vectors): the loop would have found no bit either.
    fn below_tangent_plane(&self, n: V3) -> u32 {
        if dot(n, self.light) > self.all_above * length(n) {
            return 0;
        }
        self.below_each(n)
    }

    /// [`Snapshot::below_tangent_plane`] sample by sample.
    fn below_each(&self, n: V3) -> u32 {
        let mut below = 0u32;
        for (k, s) in self.samples.iter().enumerate() {
            if dot(*s, n) <= 0.0 {
                below |= 1 << k;
            }
        }
        below
    }

    /// Shaded colour of albedo `albedo` with unit normal `n` under shadow fraction `f`, seen
    /// along the primary ray's direction `dir` (from the eye toward the point, any length), on
    /// the RGB8 scale (`[0, 255]`, clamped as a display would) but not yet rounded, so that
    /// sub-samples can be averaged before the one rounding.
    // Inlined into the colour filter's caller (`key_color`), as `trace_eye` is, for the same
    // reason.
    #[inline]
    pub fn shade(&self, m: &Material, albedo: V3, n: V3, dir: V3, f: f64) -> V3 {
        self.shade_lit(m, albedo, n, dir, self.light_at(n, f))
    }

    /// What [`Snapshot::shade`] computes of the light alone, for unit normal `n` under shadow
    /// fraction `f`: the same for every sample with the same `n` and `f` (the sub-samples on
    /// one plane of a pixel), so that it can be computed once for them.
    #[inline]
    pub(crate) fn light_at(&self, n: V3, f: f64) -> LightAt {
        let light = &self.scene.light;
        let lit = 1.0 - f;
        let nl = dot(n, self.light).max(0.0);
        let amb = lerp(light.ambient_ground, light.ambient_sky, 0.5 + 0.5 * n[1]);
        LightAt {
            lit,
            nl,
            diffuse: add(amb, scale(light.color, lit * nl)),
        }
    }

    /// [`Snapshot::shade`] with its light terms `e` (from [`Snapshot::light_at`] for `n` and
    /// the shadow fraction): Lambert (ambient by the normal's height plus the direct light
    /// `lit·max(n·l, 0)`) and a Blinn–Phong highlight.
    #[inline]
    pub(crate) fn shade_lit(&self, m: &Material, albedo: V3, n: V3, dir: V3, e: LightAt) -> V3 {
        let l = self.light;
        let mut c = mul(albedo, e.diffuse);
        if m.specular > 0.0 && e.nl > 0.0 {
            // The unit view direction (toward the eye) only here: most materials are matte, and
            // a square root and a division per sample go unread there.
            let view = normalize(scale(dir, -1.0));
            let h = normalize(add(l, view));
            let s = m.specular * e.lit * dot(n, h).max(0.0).powf(m.shininess);
            c = add(c, scale(self.scene.light.color, s));
        }
        c.map(|v| (v * 255.0).clamp(0.0, 255.0))
    }
}

/// The light terms of [`Snapshot::shade`] at one normal and shadow fraction
/// ([`Snapshot::light_at`]).
#[derive(Clone, Copy)]
pub(crate) struct LightAt {
    /// `1 − f`, the unshadowed part of the light's disc.
    lit: f64,
    /// `max(n·l, 0)`.
    nl: f64,
    /// The ambient term plus the direct light, `lit·nl` times the light's colour.
    diffuse: V3,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{builtin, Variant, SCENE_NAMES};

    /// Skipping the per-sample test for normals well toward the light finds what the test finds
    /// (no sample below the plane), for normals all around the light and crowded near the
    /// threshold, where some samples are below.
    #[test]
    fn tangent_plane_shortcut_finds_what_each_sample_finds() {
        let (mut skipped, mut some_below) = (0, 0);
        for name in SCENE_NAMES {
            let scene = builtin(name, Variant::Dynamic).unwrap();
            for t in [0.0, 1.3, 2.7] {
                let snap = Snapshot::new(&scene, t);
                let l = snap.light;
                let e1 = normalize(cross(l, [0.3, 1.0, 0.2]));
                let e2 = cross(l, e1);
                // Angles from the light: a coarse sweep plus a fine one around 90° − φ.
                let edge = (snap.all_above - 1e-6).asin();
                let angles = (0..=90)
                    .map(|k| k as f64 * PI / 90.0)
                    .chain((-200..=200).map(|k| PI / 2.0 - edge + k as f64 * 1e-5));
                for theta in angles {
                    for k in 0..24 {
                        let (s, c) = (k as f64 * PI / 12.0).sin_cos();
                        let across = add(scale(e1, c), scale(e2, s));
                        let n = normalize(add(scale(l, theta.cos()), scale(across, theta.sin())));
                        let each = snap.below_each(n);
                        assert_eq!(snap.below_tangent_plane(n), each, "{name} t={t} n={n:?}");
                        skipped += usize::from(dot(n, l) > snap.all_above);
                        some_below += usize::from(each != 0 && each != ALL_RAYS);
                    }
                }
            }
        }
        assert!(skipped > 0 && some_below > 0, "{skipped} {some_below}");
    }

    /// The shortcuts of `occluded_rays` (one BVH walk for all rays of a mesh, the umbra of a box
    /// or sphere from the polygon's corners) find exactly the rays that the per-ray tests find,
    /// at origins whose rays pass through and around every caster (its inside, its silhouette and
    /// the umbra's edge), and every kind of answer occurs: umbra, penumbra, and none.
    #[test]
    fn occluded_rays_finds_what_each_ray_finds() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut umbra, mut partial, mut none, mut mesh_partial) = (0, 0, 0, 0);
        for name in SCENE_NAMES {
            let scene = builtin(name, Variant::Dynamic).unwrap();
            for t in [0.0, 1.3] {
                let snap = Snapshot::new(&scene, t);
                for i in 0..scene.objects.len() {
                    let b = snap.light_obj[i].1;
                    let is_mesh = !scene.objects[i].shape.is_convex();
                    for _ in 0..150 {
                        // A point in or near the object's box (object space), then back toward
                        // the light's opposite side by a random distance: its shadow rays pass
                        // near that point.
                        let p: V3 = std::array::from_fn(|k| {
                            let w = b.max[k] - b.min[k];
                            b.min[k] - 0.1 * w + 1.2 * w * uniform()
                        });
                        let back = 0.02 + 10.0 * uniform() * uniform();
                        let o = sub(p, scale(snap.light_obj[i].0, back));
                        let todo = if uniform() < 0.3 {
                            (uniform() * f64::from(u32::MAX)) as u32 & ALL_RAYS
                        } else {
                            ALL_RAYS
                        };
                        let each = snap.occluded_each(i, o, todo);
                        assert_eq!(
                            snap.occluded_rays(i, o, todo),
                            each,
                            "{name} t={t} object {i} o={o:?} todo={todo:#x}"
                        );
                        if todo == ALL_RAYS {
                            match each {
                                ALL_RAYS => umbra += 1,
                                0 => none += 1,
                                _ => {
                                    partial += 1;
                                    mesh_partial += usize::from(is_mesh);
                                }
                            }
                        }
                    }
                }
            }
        }
        assert!(
            umbra > 100 && partial > 100 && none > 100 && mesh_partial > 10,
            "umbra {umbra}, partial {partial}, none {none}, mesh partial {mesh_partial}"
        );
    }

    /// The umbra shortcut at the edge of a box's umbra: origins stepped across it in small steps,
    /// so that the six corners go from all blocked to some not, with samples on both sides.
    #[test]
    fn umbra_shortcut_agrees_across_the_umbra_edge() {
        let scene = builtin("courtyard", Variant::Dynamic).unwrap();
        let snap = Snapshot::new(&scene, 0.0);
        let houses: Vec<usize> = (0..scene.objects.len())
            .filter(|&i| scene.objects[i].name == "house")
            .collect();
        let (mut full, mut taken) = (0, 0);
        for &i in &houses {
            let (l, b) = snap.light_obj[i];
            // Across the box's middle at half its height, 3 m back from it along the light.
            let mid: V3 = std::array::from_fn(|k| 0.5 * (b.min[k] + b.max[k]));
            let across = normalize(cross(l, [0.0, 1.0, 0.0]));
            let half = (0..3).fold(0.0f64, |m, k| m.max(b.max[k] - b.min[k]));
            for step in -4000..=4000 {
                let o = sub(
                    add(mid, scale(across, step as f64 * half / 3000.0)),
                    scale(l, 3.0),
                );
                let each = snap.occluded_each(i, o, ALL_RAYS);
                assert_eq!(
                    snap.occluded_rays(i, o, ALL_RAYS),
                    each,
                    "house {i} step {step}"
                );
                full += usize::from(each == ALL_RAYS);
                taken += usize::from(
                    snap.umbra_obj[i]
                        .iter()
                        .all(|&d| snap.shape(i).occludes(o, d)),
                );
            }
        }
        // Some umbra points are decided by the corners, and near the edge some are not.
        assert!(taken > 0 && taken < full, "taken {taken}, full {full}");
    }

    /// The shadow cull's pre-selection never drops an object that the exact bounding-sphere test
    /// keeps (so the candidate set, and the image, is unchanged), and it does drop some.
    #[test]
    fn shadow_cull_keeps_every_object_the_sphere_test_keeps() {
        let (mut visited, mut kept, mut total) = (0usize, 0usize, 0usize);
        for name in SCENE_NAMES {
            let scene = builtin(name, Variant::Dynamic).unwrap();
            for t in [0.0, 1.3, 2.7] {
                let snap = Snapshot::new(&scene, t);
                let casters: Vec<usize> = (0..scene.objects.len())
                    .filter(|&i| scene.objects[i].casts_shadow)
                    .collect();
                let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
                for &i in &casters {
                    let c = snap.spheres[i].0;
                    for k in 0..3 {
                        lo[k] = lo[k].min(c[k] - 1.0);
                        hi[k] = hi[k].max(c[k] + 1.0);
                    }
                }
                for step in 0..729 {
                    let f = [step % 9, step / 9 % 9, step / 81].map(|s| s as f64 / 8.0);
                    let x = [0, 1, 2].map(|k| lo[k] + f[k] * (hi[k] - lo[k]));
                    let ext = x.iter().fold(1.0f64, |a, c| a.max(c.abs()));
                    let mut seen = vec![false; scene.objects.len()];
                    snap.cull
                        .visit(x, (snap.light, ext, 0.0), &snap.spheres, |i| seen[i] = true);
                    for &i in &casters {
                        total += 1;
                        visited += usize::from(seen[i]);
                        if snap.sphere_may_shadow(i, x).is_some() {
                            kept += 1;
                            assert!(seen[i], "{name} t={t} x={x:?}: object {i} dropped");
                        }
                    }
                }
            }
        }
        assert!(
            kept > 0 && visited < total,
            "kept {kept}, visited {visited} of {total}"
        );
    }

    /// A shared shadow-cull query keeps, for a point up to the cull's reach away, every caster
    /// that the exact tests of `blocked_rays` keep there, at the edge of those tests (the sphere
    /// test alone, and with the box test): each caster seen from points just inside its reach
    /// across the light, with the query made a little less than the reach farther out (so a
    /// growth of the radii cut below the reach fails) or as far in another direction across or
    /// along the light, and from points on its sphere, with the query as far out from the
    /// centre: the edges that the filter of the shared list (`may_shadow_near`) must keep.
    #[test]
    fn near_casters_keep_every_object_the_exact_tests_keep_within_reach() {
        let ext = |x: V3| x.iter().fold(1.0f64, |a, c| a.max(c.abs()));
        // Whether a query made at `x0` (not served by the last one, which may lie within reach
        // of it) serves `x` and lists caster `i` there.
        let listed = |snap: &Snapshot<'_>, i: usize, x0: V3, x: V3| {
            NEAR_CASTERS.with(|near| near.borrow_mut().snap = u64::MAX);
            snap.near_casters(x0, ext(x0), |_| {});
            let mut seen = false;
            snap.near_casters(x, ext(x), |j| seen |= j == i);
            NEAR_CASTERS.with(|near| assert_eq!(near.borrow().x, x0));
            seen
        };
        let mut edges = 0usize;
        for name in SCENE_NAMES {
            let scene = builtin(name, Variant::Dynamic).unwrap();
            for t in [0.0, 1.3] {
                let snap = Snapshot::new(&scene, t);
                let reach = snap.cull.reach;
                assert!(reach > 0.0, "{name}: no reach");
                // A query serves points within its reach and no farther.
                let x0 = snap.spheres[0].0;
                for (f, served) in [(0.999, true), (1.001, false), (1.5, false), (3.0, false)] {
                    let x = add(x0, scale(normalize([0.3, -0.5, 0.8]), f * reach));
                    NEAR_CASTERS.with(|near| near.borrow_mut().snap = u64::MAX);
                    snap.near_casters(x0, ext(x0), |_| {});
                    snap.near_casters(x, ext(x), |_| {});
                    let from = NEAR_CASTERS.with(|near| near.borrow().x);
                    assert_eq!(from == x0, served, "{name} t={t}: {f} reaches");
                }
                let (l, e1, e2) = (snap.light, snap.cull.e1, snap.cull.e2);
                let (sin_a, cos_a) = snap.light_sin_cos;
                for i in (0..scene.objects.len()).filter(|&i| scene.objects[i].casts_shadow) {
                    let (c, r) = snap.spheres[i];
                    // `blocked_rays`' exact tests at `x`: the sphere's, and (`both`) the box's.
                    let keeps = |x: V3, both: bool| {
                        snap.sphere_may_shadow(i, x).is_some_and(|dist| {
                            !both || snap.cone_may_hit(i, x, (dist + r) * sin_a / cos_a)
                        })
                    };
                    for (depth, both) in [0.5, 3.0, 12.0, 40.0]
                        .into_iter()
                        .flat_map(|depth| [(depth, false), (depth, true)])
                    {
                        for e in [e1, e2, scale(e1, -1.0), scale(e2, -1.0)] {
                            let at = |u: f64| add(sub(c, scale(l, r + depth)), scale(e, u));
                            // The largest offset across the light that the exact tests keep.
                            let (mut lo, mut hi) = (0.0, 4.0 * (r + depth));
                            assert!(keeps(at(lo), both));
                            assert!(!keeps(at(hi), both));
                            for _ in 0..60 {
                                let mid = 0.5 * (lo + hi);
                                if keeps(at(mid), both) {
                                    lo = mid;
                                } else {
                                    hi = mid;
                                }
                            }
                            let x = at(lo);
                            // At the sphere test's edge the box test may fail (the list need
                            // not hold the caster there).
                            if !keeps(x, true) {
                                continue;
                            }
                            let far = at(lo + reach * (1.0 - 1e-9));
                            let step = |w: V3| add(x, scale(w, reach * (1.0 - 1e-9)));
                            let sides =
                                [e1, e2, l, scale(e1, -1.0), scale(e2, -1.0), scale(l, -1.0)];
                            for x0 in std::iter::once(far).chain(sides.map(step)) {
                                let seen = listed(&snap, i, x0, x);
                                assert!(seen, "{name} t={t} object {i} depth {depth}: dropped");
                                edges += 1;
                            }
                        }
                    }
                    // Points on the sphere (kept by its distance, or by the cone where that is
                    // rounded above `r`), the query a reach farther out from the centre.
                    for w in [e1, e2, l, scale(e1, -1.0), scale(e2, -1.0), scale(l, -1.0)] {
                        let (x, x0) = (
                            add(c, scale(w, r)),
                            add(c, scale(w, r + reach * (1.0 - 1e-9))),
                        );
                        if !keeps(x, true) {
                            continue;
                        }
                        let seen = listed(&snap, i, x0, x);
                        assert!(seen, "{name} t={t} object {i} on its sphere: dropped");
                        edges += 1;
                    }
                }
            }
        }
        assert!(edges > 0);
    }

    /// Checks that quad `i` of `snap` blocks the same shadow rays through its shortcut as ray by
    /// ray, from origins on both sides of its plane, on it (either zero) and just off it, over
    /// and beyond the quad; `what` names the case. Counts the origins the shortcut decided, those
    /// with any ray blocked and those with some but not all blocked.
    fn check_quad_shortcut(snap: &Snapshot, i: usize, what: &str) -> [usize; 3] {
        let Shape::Quad { half } = *snap.shape(i) else {
            panic!("{what}: object {i} is no quad");
        };
        let (lo, hi) = snap.samples_y[i];
        let mut counts = [0; 3];
        for y in [-2.0, -1e-300, -0.0, 0.0, 1e-300, 2.0] {
            for (fx, fz) in [(0.0, 0.0), (0.5, -0.3), (0.99, 0.99), (1.5, 0.2)] {
                let o = [fx * half[0], y, fz * half[1]];
                let each = snap.occluded_each(i, o, ALL_RAYS);
                assert_eq!(
                    snap.occluded_rays(i, o, ALL_RAYS),
                    each,
                    "{what} object {i} o={o:?}"
                );
                counts[0] += usize::from((y >= 0.0 && lo >= 0.0) || (y <= 0.0 && hi <= 0.0));
                counts[1] += usize::from(each != 0);
                counts[2] += usize::from(each != 0 && each != ALL_RAYS);
            }
        }
        counts
    }

    /// The quad shortcut finds what each ray finds, for origins on both sides of the plane, on
    /// it (either zero) and just off it, over and beyond the quad, under every built-in light.
    #[test]
    fn quad_shortcut_finds_what_each_ray_finds() {
        let (mut shortcut, mut blocked) = (0, 0);
        for name in SCENE_NAMES {
            let scene = builtin(name, Variant::Dynamic).unwrap();
            for t in [0.0, 1.3, 2.7] {
                let snap = Snapshot::new(&scene, t);
                for i in 0..scene.objects.len() {
                    if !matches!(snap.shape(i), Shape::Quad { .. }) {
                        continue;
                    }
                    let [decided, any, _] = check_quad_shortcut(&snap, i, &format!("{name} t={t}"));
                    shortcut += decided;
                    blocked += any;
                }
            }
        }
        assert!(
            shortcut > 0 && blocked > 0,
            "shortcut {shortcut}, blocked {blocked}"
        );
    }

    /// The quad shortcut for quads turned every way against the light: the shadow rays all
    /// leaving the plane's +y side, all its −y side, and straddling it (the normal within the
    /// light's angular radius of a right angle to it), for origins on both sides, on it and
    /// just off it, over and beyond the quad.
    #[test]
    fn quad_shortcut_finds_what_each_ray_finds_for_quads_turned_against_the_light() {
        let (mut straddle, mut shortcut, mut blocked) = (0, 0, 0);
        for name in SCENE_NAMES {
            let mut scene = builtin(name, Variant::Static).unwrap();
            let Some(q) = (0..scene.objects.len())
                .find(|&i| matches!(scene.objects[i].shape, Shape::Quad { .. }))
            else {
                continue;
            };
            let l = Snapshot::new(&scene, 0.0).light;
            let a = scene.light.angular_radius;
            let across = normalize(cross(l, [0.0, 1.0, 0.0]));
            let side = cross(across, l);
            let place = scene.objects[q].place;
            // Far from the light's plane either way, and across it in steps of an eighth of the
            // light's radius (the lowest sample just below or above the plane at some).
            let across_light = (-12..=12).map(|k| f64::from(k) * a / 8.0);
            for phi in [-1.0, -0.3, 0.3, 1.0, 2.0].into_iter().chain(across_light) {
                // The quad's normal at `phi` from the plane at a right angle to the light.
                let n = add(scale(side, phi.cos()), scale(l, phi.sin()));
                let turn =
                    Rigid::rotation(cross([0.0, 1.0, 0.0], n), dot(n, [0.0, 1.0, 0.0]).acos());
                scene.objects[q].place = Rigid::translation(place.trans).then(&turn);
                let snap = Snapshot::new(&scene, 0.0);
                let (lo, hi) = snap.samples_y[q];
                straddle += usize::from(lo < 0.0 && hi > 0.0);
                let [decided, _, partly] =
                    check_quad_shortcut(&snap, q, &format!("{name} phi={phi}"));
                shortcut += decided;
                blocked += partly;
            }
        }
        assert!(
            straddle > 0 && shortcut > 0 && blocked > 0,
            "straddle {straddle}, shortcut {shortcut}, partly blocked {blocked}"
        );
    }

    /// `blocked_rays` (the cull, the exact sphere and box tests, the shortcuts) hides exactly the
    /// shadow rays that tracing every ray against every shadow caster hides (the point's own
    /// convex object skipped, the rays below the tangent plane hidden), at the surfaces that
    /// primary rays of each scene's camera meet, in sun, penumbra and shadow.
    #[test]
    fn blocked_rays_finds_what_every_caster_finds() {
        let (mut lit, mut partial, mut dark) = (0, 0, 0);
        for name in SCENE_NAMES {
            let scene = builtin(name, Variant::Dynamic).unwrap();
            let t = 1.3;
            let snap = Snapshot::new(&scene, t);
            let cam = crate::rig::rig(
                &scene.path.server_pose(13, 10.0),
                64,
                36,
                scene.near,
                scene.far,
            )
            .main;
            let rays = crate::render::camera_rays(&cam, "test").unwrap();
            for j in 0..cam.height {
                for i in 0..cam.width {
                    let d = rays.ray(i, j);
                    let Some(hit) = snap.trace(rays.origin, d, 1.0, scene.far / scene.near) else {
                        continue;
                    };
                    let x = add(rays.origin, scale(d, hit.t));
                    let mut n = normalize(snap.world[hit.obj].vector(hit.local.normal));
                    if dot(n, d) > 0.0 {
                        n = scale(n, -1.0);
                    }
                    let got = snap.blocked_rays(hit.obj, x, n, Occluders::All, None);
                    // Every caster, every ray, from the offset origin that `blocked_rays`
                    // documents.
                    let ext = x.iter().fold(1.0f64, |a, c| a.max(c.abs()));
                    let origin = add(x, scale(n, 1e-5 * ext));
                    let mut want = 0u32;
                    for (k, s) in snap.samples.iter().enumerate() {
                        let below = dot(*s, n) <= 0.0;
                        let hidden = below
                            || (0..scene.objects.len()).any(|c| {
                                scene.objects[c].casts_shadow
                                    && !(c == hit.obj && scene.objects[c].shape.is_convex())
                                    && snap
                                        .shape(c)
                                        .occludes(snap.inv[c].point(origin), snap.inv[c].vector(*s))
                            });
                        want |= u32::from(hidden) << k;
                    }
                    assert_eq!(got, want, "{name} pixel ({i}, {j}) object {}", hit.obj);
                    match want {
                        0 => lit += 1,
                        ALL_RAYS => dark += 1,
                        _ => partial += 1,
                    }
                }
            }
        }
        assert!(
            lit > 0 && partial > 0 && dark > 0,
            "lit {lit}, penumbra {partial}, shadow {dark}"
        );
    }
}
