//! Primary rays without the scene BVH: per screen tile, the objects whose boxes the tile's rays
//! can reach, nearest first ([`EyeTiles`], [`Snapshot::trace_eye`]).
//!
//! Every primary ray of a camera leaves its centre, so an object's place relative to the rays is
//! known once per camera: the objects a tile's pyramid of rays can meet (their bounding sphere
//! within the tile's cone, their box not beyond one of its side planes) are listed once per tile,
//! sorted by how near the tile's rays can meet their boxes, and a ray tests them in that order
//! until the next box lies beyond its nearest hit so far. That finds the same nearest distance as
//! the BVH; which object wins a tie (two objects at exactly the same distance) depends on the order
//! they are tested in, so a ray that meets one falls back to [`Snapshot::trace`], whose order
//! decides, and the answer is the BVH's in every case.

use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

use rayon::prelude::*;
use reproj_core::Camera;

use super::Rays;
use crate::math::{dot, length, normalize, sub, Rigid, V3};
use crate::scene::{Hit, Snapshot};
use crate::shape::{Partial, Shape};

/// The base-2 logarithm of the pixels per tile side, by the image width: the wider tiles of
/// wide images hold more pixels per list built and list a few more objects per ray. Counted over
/// the courtyard's ground truth: at 128×72, 8 pixels gave fewer instructions than 4 or 16; at
/// 640×360 and 1280×720, 16 fewer than 8 or 32. (A shift: a pixel's tile is looked up five times
/// per pixel, and a division by a size known only at run time costs more.)
fn tile_shift(width: usize) -> u32 {
    if width >= 512 {
        4
    } else {
        3
    }
}

/// The most list entries a camera's tiles may hold together: an eighth a pixel on average (8 a
/// tile of 8×8 pixels, 32 of 16×16; the built-in scenes need at most 0.033 at 640×360 and up),
/// and at least 4,096 (64 KiB) for small images. A scene of hundreds of objects overlapping on
/// screen would list more, and the lists' memory grows with pixels × objects (4,096 objects at
/// 1280×720 would be 0.9 GB): beyond the cap [`EyeTiles::new`] gives up and the BVH serves every
/// ray, with the same answers. With it the lists take at most 4 bytes a pixel (twice the 16
/// bytes of an eighth of an entry, while the rows are joined), which the renderers' memory
/// bounds count ([`super::truth_bytes`], [`reproj_core::memory::server_buffers_bytes`]).
fn max_entries(pixels: usize) -> usize {
    (pixels / 8).max(1 << 12)
}

/// A tile's side planes: each through the camera centre and two adjacent corner rays (indices
/// into the corners `(x0, y0)`, `(x1, y0)`, `(x0, y1)`, `(x1, y1)`).
const SIDES: [(usize, usize); 4] = [(0, 1), (1, 3), (3, 2), (2, 0)];

/// An entry of a tile's list: a bound below the distance from the camera centre of every point
/// of the object's box that a ray of the tile can reach (the box's distance, or farther along
/// the tile's rays, see [`EyeTiles::new`]), less a margin, and the object.
type Entry = (f64, usize);

/// Per screen tile of one camera at one instant, the objects its rays may meet.
pub(crate) struct EyeTiles<'s> {
    /// `log2` of the pixels per tile side ([`tile_shift`]).
    shift: u32,
    /// Tiles per row.
    cols: usize,
    /// Every tile's list (row-major, one after another; tile `k`'s is `starts[k]..starts[k +
    /// 1]`), nearest first.
    lists: Vec<Entry>,
    starts: Vec<usize>,
    /// Per object, what a ray needs of it, in one place: the search reads nothing else.
    targets: Vec<Target<'s>>,
    /// [`super::far_s`] of the snapshot.
    far: f64,
}

/// One tile's list and the objects' records: what [`Snapshot::trace_eye`] reads, looked up once
/// per pixel for its centre and colour sub-sample rays (they all pass through the same tile).
#[derive(Clone, Copy)]
pub(crate) struct EyeTile<'t, 's> {
    list: &'t [Entry],
    targets: &'t [Target<'s>],
    /// [`super::far_s`] of the snapshot (a division once per frame instead of once per ray).
    pub far: f64,
}

/// What a primary ray needs of one object ([`Snapshot::trace_eye`]).
struct Target<'s> {
    /// The camera centre in the object's space.
    origin: V3,
    /// World → object (the snapshot's `inv`, copied).
    inv: Rigid,
    /// The object's shape at this instant.
    shape: &'s Shape,
    /// Whether `inv`'s rotation is exactly the identity (ones and zeros): it then maps a
    /// direction without a zero component to itself bit for bit ([`Snapshot::trace_eye`]).
    unrotated: bool,
}

impl Target<'_> {
    /// The primary ray's direction `d` in the object's space; `plain`: no component of `d` is
    /// zero ([`Snapshot::trace_eye`]).
    #[inline]
    fn direction(&self, d: V3, plain: bool) -> V3 {
        if plain && self.unrotated {
            d
        } else {
            self.inv.vector(d)
        }
    }
}

impl<'s> EyeTiles<'s> {
    /// The tiles of `camera` (whose rays are `rays`) at the instant `snap`; `None` where the
    /// camera's geometry is not finite or the lists would hold more than [`max_entries`] (the
    /// BVH then serves every ray).
    pub(crate) fn new(
        snap: &'s Snapshot<'_>,
        camera: &Camera,
        rays: &Rays,
    ) -> Option<EyeTiles<'s>> {
        let inv_vp = camera.view_proj().inverse()?;
        let o = rays.origin;
        let (w, h) = (rays.width, rays.height);
        // The unit direction through the point `(px, py)` in pixels (edges at integers).
        let dir = |px: usize, py: usize| {
            let x = 2.0 * px as f64 / w as f64 - 1.0;
            let y = 1.0 - 2.0 * py as f64 / h as f64;
            let q = inv_vp.mul_vec([x, y, 1.0, 1.0]);
            normalize(sub([q[0] / q[3], q[1] / q[3], q[2] / q[3]], o))
        };
        let shift = tile_shift(w);
        let tile = 1 << shift;
        let (cols, rows) = (w.div_ceil(tile), h.div_ceil(tile));
        let n = snap.world.len();
        // Per object: its sphere's centre relative to the camera centre, its distance, radius,
        // and the angle its sphere subtends (the same for every tile).
        let spheres: Vec<(V3, f64, f64, f64)> = (0..n)
            .map(|i| {
                let (c, r) = snap.sphere(i);
                let v = sub(c, o);
                let dist = length(v);
                (v, dist, r, (r / dist).min(1.0).asin())
            })
            .collect();
        let size = spheres.iter().fold(
            o.iter().fold(1.0f64, |m, c| m.max(c.abs())),
            |m, &(_, d, r, _)| m.max(d + r),
        );
        let eps = 1e-9 * size;
        // The entries listed so far over every row: a row stops once they exceed the cap. The
        // outcome does not depend on the threads (the total exceeds the cap or not), and what
        // is held beyond the cap before a row notices is at most one tile's list a thread.
        let cap = max_entries(w * h);
        let listed = AtomicUsize::new(0);
        // Per object: the corners of its object-space box in the world, relative to the camera
        // centre, with their distances from it (the box holds every hit, as for the sphere).
        let boxes: Vec<[(V3, f64); 8]> = (0..n)
            .map(|i| {
                let corners = snap.shape(i).bounds().corners();
                corners.map(|c| {
                    let q = sub(snap.world[i].point(c), o);
                    (q, length(q))
                })
            })
            .collect();
        // Per object: the distance from the camera centre to its box (at least that to its
        // sphere, as the sphere holds the box), which no hit is nearer than, and the centre's
        // distance from each of the box's slabs in its space (0 inside the slab).
        let box_dist: Vec<(f64, V3)> = (0..n)
            .map(|i| {
                let b = snap.shape(i).bounds();
                let p = snap.inv[i].point(o);
                let gaps: V3 =
                    std::array::from_fn(|k| (p[k] - p[k].max(b.min[k]).min(b.max[k])).abs());
                (length(gaps), gaps)
            })
            .collect();
        // One row of tiles: every tile's list one after another, and where each ends.
        let tile_row = |ty: usize| -> Option<(Vec<Entry>, Vec<usize>)> {
            let (mut lists, mut ends) = (Vec::new(), Vec::with_capacity(cols));
            for tx in 0..cols {
                let (x0, x1) = (tx * tile, ((tx + 1) * tile).min(w));
                let (y0, y1) = (ty * tile, ((ty + 1) * tile).min(h));
                let corners = [dir(x0, y0), dir(x1, y0), dir(x0, y1), dir(x1, y1)];
                let axis = normalize(
                    corners
                        .iter()
                        .fold([0.0; 3], |a, c| crate::math::add(a, *c)),
                );
                // Every ray through the tile lies in the cone around `axis` through its corners
                // (the directions within an angle of `axis` meet the image plane in a convex set).
                let cone = corners
                    .iter()
                    .map(|c| dot(*c, axis).clamp(-1.0, 1.0).acos())
                    .fold(0.0f64, f64::max);
                if !cone.is_finite() || !axis.iter().all(|a| a.is_finite()) {
                    return None;
                }
                // The tile's rays fill the pyramid from the camera centre over its four corner
                // rays; its side planes through the centre, each normal pointing out.
                let sides: [V3; 4] = std::array::from_fn(|k| {
                    let (a, b) = (corners[SIDES[k].0], corners[SIDES[k].1]);
                    let p = normalize(crate::math::cross(a, b));
                    if dot(p, axis) > 0.0 {
                        crate::math::scale(p, -1.0)
                    } else {
                        p
                    }
                });
                let (sin_c, cos_c) = (cone + 1e-6).sin_cos();
                let first = lists.len();
                for (i, &(v, dist, r, reach)) in spheres.iter().enumerate() {
                    let (bd, gaps) = box_dist[i];
                    // A sphere that holds the centre (or nearly) is met by any ray.
                    let keep = if !(dist > r * (1.0 + 1e-6) + eps) {
                        true
                    } else {
                        let gamma = (dot(v, axis) / dist).clamp(-1.0, 1.0).acos();
                        // A box with every corner beyond one side plane (by a margin far above
                        // the rounding of the planes and of the rays' directions) lies outside
                        // the pyramid, so no ray of the tile meets it.
                        !(gamma > cone + reach + 1e-6)
                            && !sides.iter().any(|&p| {
                                boxes[i]
                                    .iter()
                                    .all(|&(q, len)| dot(p, q) > 1e-6 * len + eps)
                            })
                    };
                    if keep {
                        // A ray of unit direction `d` (in the object's space) reaches a slab `k`
                        // that the centre lies outside of no nearer than `gaps[k] / |d_k|`. With
                        // `d` within `c' = cone + 10⁻⁶` of the axis `a` and `θ` the angle from
                        // `a` to the axis `k`, `|d_k| ≤ cos(θ − c')` (1 where `θ ≤ c'`), which
                        // is `cos θ cos c' + sin θ sin c'`; the entry's margin covers the
                        // rounding of these few operations.
                        let a = snap.inv[i].vector(axis);
                        let slabs = (0..3).fold(bd, |m, k| {
                            let c = a[k].abs().min(1.0);
                            let top = if c >= cos_c {
                                1.0
                            } else {
                                c * cos_c + (1.0 - c * c).sqrt() * sin_c
                            };
                            m.max(gaps[k] / top)
                        });
                        lists.push(((slabs * (1.0 - 1e-6) - eps).max(0.0), i));
                    }
                }
                lists[first..].sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                ends.push(lists.len());
                let added = lists.len() - first;
                if listed.fetch_add(added, Relaxed) + added > cap {
                    return None;
                }
            }
            // Held exactly while the other rows are built and joined (a vector grows by
            // doubling, so up to twice its entries otherwise).
            lists.shrink_to_fit();
            Some((lists, ends))
        };
        // Rows in parallel (at 1280×720, 14 400 tiles each test every object, a sequential step
        // before the pixels otherwise), concatenated in order: the lists do not depend on the
        // thread count.
        let done: Vec<_> = (0..rows)
            .into_par_iter()
            .map(tile_row)
            .collect::<Option<_>>()?;
        let mut lists = Vec::with_capacity(done.iter().map(|(row, _)| row.len()).sum());
        let mut starts = Vec::with_capacity(cols * rows + 1);
        starts.push(0);
        for (row, ends) in done {
            starts.extend(ends.iter().map(|e| lists.len() + e));
            lists.extend(row);
        }
        let targets = (0..n)
            .map(|i| Target {
                origin: snap.inv[i].point(o),
                inv: snap.inv[i],
                shape: snap.shape(i),
                unrotated: snap.inv[i].rot == Rigid::IDENTITY.rot,
            })
            .collect();
        Some(EyeTiles {
            shift,
            cols,
            lists,
            starts,
            targets,
            far: super::far_s(snap),
        })
    }

    /// The entries of every tile's list together.
    #[cfg(test)]
    fn entries(&self) -> usize {
        self.lists.len()
    }

    /// The tile that pixel `(i, j)` lies in.
    pub(crate) fn tile(&self, (i, j): (usize, usize)) -> EyeTile<'_, 's> {
        let k = (j >> self.shift) * self.cols + (i >> self.shift);
        EyeTile {
            list: &self.lists[self.starts[k]..self.starts[k + 1]],
            targets: &self.targets,
            far: self.far,
        }
    }
}

impl Snapshot<'_> {
    /// [`Snapshot::trace`] of the primary ray `d` through a pixel of `eye` (its centre or a
    /// sub-sample of it) from the camera centre `o`, the same answer (see the module
    /// documentation), with `d` in the hit object's space (the search has it already; the
    /// caller needs it for the normal).
    // Inlined into `sample_ray_into`, its one caller (left to itself, the compiler's choice
    // changes with unrelated edits of the crate).
    #[inline]
    pub(crate) fn trace_eye(
        &self,
        eye: &EyeTile<'_, '_>,
        o: V3,
        d: V3,
        tmin: f64,
        tmax: f64,
    ) -> Option<(Hit, V3)> {
        let dn = length(d);
        // (`tmin ≥ 0` keeps every distance found positive, as `next_up` below needs.)
        if !(dn > 0.0 && dn.is_finite() && tmin >= 0.0) {
            return self.trace_dir(o, d, tmin, tmax);
        }
        // The winner so far: its object and what its distance came with (`d` in its space is
        // formed again for the winner alone: the same expression on the same values, and fewer
        // values to keep at each closer hit).
        let mut best: Option<(usize, Partial)> = None;
        let mut limit = tmax;
        // A shape is tested up to `up`: before the first hit `tmax`, then up to and including
        // the nearest distance so far (a positive finite number), to see ties.
        let mut up = tmax;
        // Every hit on an object is at least its `near` from the centre, so the search stops at
        // the first entry with `near > stop` (`stop` follows `limit`: the same product, computed
        // when `limit` changes rather than at every entry).
        let mut stop = limit * dn * (1.0 + 1e-9);
        // The distance of a hit at exactly the nearest distance so far, from another object.
        let mut tie = f64::NAN;
        // An unrotated object's `inv.vector(d)` is `d` itself when no component of `d` is zero
        // (nor infinite, as `dn` is finite): each component is `1·dₖ` plus two products with
        // zero, which are zeros and leave a nonzero sum unchanged (a zero `dₖ` would not come
        // back: `−0.0 + 0.0` is `+0.0`), so the transform is skipped (four in five of the
        // courtyard's entries tested: the ground, most houses, the well).
        let plain = d.iter().all(|&c| c != 0.0);
        for &(near, obj) in eye.list {
            if near > stop {
                break;
            }
            // (A per-ray test against the object's bounding sphere here, which the lists by the
            // tile's cone alone needed, now skips too few shape tests to pay for itself.)
            let target = &eye.targets[obj];
            let ld = target.direction(d, plain);
            if let Some(p) = target.shape.intersect_t(target.origin, ld, tmin, up) {
                if p.t() < limit {
                    limit = p.t();
                    stop = limit * dn * (1.0 + 1e-9);
                    up = next_up(limit);
                    best = Some((obj, p));
                } else {
                    tie = p.t();
                }
            }
        }
        if tie == limit {
            return self.trace_dir(o, d, tmin, tmax);
        }
        let (obj, p) = best?;
        let target = &eye.targets[obj];
        let (lo, ld) = (target.origin, target.direction(d, plain));
        Some((self.finish_hit((obj, lo, ld, p)), ld))
    }

    /// [`Snapshot::trace`], with `d` in the hit object's space.
    fn trace_dir(&self, o: V3, d: V3, tmin: f64, tmax: f64) -> Option<(Hit, V3)> {
        self.trace(o, d, tmin, tmax)
            .map(|h| (h, self.inv[h.obj].vector(d)))
    }
}

/// The next `f64` above the finite positive `t` (`f64::next_up`, newer than the crate's minimum
/// Rust version).
fn next_up(t: f64) -> f64 {
    f64::from_bits(t.to_bits() + 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::camera_rays;
    use crate::rig::rig;
    use crate::scene::{Scene, Variant};
    use crate::scenes::{builtin, SCENE_NAMES};

    /// An unrotated object's transform gives back every direction without a zero component bit
    /// for bit (what lets `trace_eye` skip it), over random bit patterns (huge, tiny and
    /// subnormal components), in every built-in scene that has such objects.
    #[test]
    fn unrotated_objects_keep_directions_without_zeros() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            let x = f64::from_bits(state);
            if x.is_finite() && x != 0.0 {
                x
            } else {
                -1e-310
            }
        };
        let mut unrotated = 0;
        for name in SCENE_NAMES {
            let scene = builtin(name, Variant::Dynamic).unwrap();
            let snap = scene.at(1.3);
            for inv in snap.inv.iter().filter(|m| m.rot == Rigid::IDENTITY.rot) {
                unrotated += 1;
                for _ in 0..2000 {
                    let d = [next(), next(), next()];
                    assert_eq!(inv.vector(d).map(f64::to_bits), d.map(f64::to_bits));
                }
            }
        }
        assert!(unrotated > 0);
    }

    /// For every pixel-centre ray and 2×2 sub-sample ray of a `w×h` main camera: the object,
    /// distance and face that `trace_eye` finds, and how many of them lie on `objs`.
    fn compare(scene: &Scene, k: usize, (w, h): (usize, usize), objs: &[usize]) -> usize {
        let cam = rig(
            &scene.path.server_pose(k, 10.0),
            w,
            h,
            scene.near,
            scene.far,
        )
        .main;
        let rays = camera_rays(&cam, "test").unwrap();
        let t = k as f64 / 10.0;
        let snap = scene.at(t);
        let eye = EyeTiles::new(&snap, &cam, &rays).unwrap();
        let far = scene.far / scene.near;
        let mut on = 0;
        for j in 0..cam.height {
            for i in 0..cam.width {
                let subs = (0..4).map(|q| rays.sub_ray(i, j, q % 2, q / 2, 2));
                for d in std::iter::once(rays.ray(i, j)).chain(subs) {
                    let a = snap.trace(rays.origin, d, 1.0, far);
                    let b = snap
                        .trace_eye(&eye.tile((i, j)), rays.origin, d, 1.0, far)
                        .map(|(h, _)| h);
                    let key = |h: Option<Hit>| h.map(|h| (h.obj, h.t.to_bits(), h.local.face));
                    assert_eq!(key(a), key(b), "{} pixel ({i}, {j})", scene.name);
                    on += usize::from(a.is_some_and(|h| objs.contains(&h.obj)));
                }
            }
        }
        on
    }

    #[test]
    fn tile_lists_find_the_bvh_hit_for_every_primary_ray() {
        for name in SCENE_NAMES {
            let scene = builtin(name, Variant::Dynamic).unwrap();
            for k in [0, 14] {
                compare(&scene, k, (48, 27), &[]);
            }
        }
    }

    /// Every object that a ray through a tile meets (not only the nearest) is in the tile's list,
    /// no nearer than its entry says: the box planes drop only what no ray of the tile can hit,
    /// and the box's distance bounds every hit's. Rays a sixteenth of a pixel from
    /// each pixel's corners, so the tiles' edges are crossed closely from both sides.
    #[test]
    fn tile_lists_hold_every_object_a_ray_of_the_tile_meets() {
        let scene = builtin("courtyard", Variant::Dynamic).unwrap();
        let mut hits = 0;
        for (k, (w, h)) in [(0, (48, 27)), (14, (48, 27)), (14, (520, 293))] {
            let pose = scene.path.server_pose(k, 10.0);
            let cam = rig(&pose, w, h, scene.near, scene.far).main;
            let rays = camera_rays(&cam, "test").unwrap();
            let snap = scene.at(k as f64 / 10.0);
            let eye = EyeTiles::new(&snap, &cam, &rays).unwrap();
            let far = scene.far / scene.near;
            for j in 0..h {
                for i in 0..w {
                    let tile = eye.tile((i, j));
                    for q in [0, 3, 12, 15] {
                        let d = rays.sub_ray(i, j, q % 4, q / 4, 4);
                        for (obj, target) in eye.targets.iter().enumerate() {
                            let ld = target.inv.vector(d);
                            if let Some(p) = target.shape.intersect_t(target.origin, ld, 1.0, far) {
                                hits += 1;
                                let entry = tile.list.iter().find(|e| e.1 == obj);
                                let what = format!("object {obj}, pixel ({i}, {j}), {w}×{h}");
                                let near = entry.unwrap_or_else(|| panic!("{what} missing")).0;
                                assert!(p.t() * length(d) >= near, "{what} nearer");
                            }
                        }
                    }
                }
            }
        }
        assert!(hits > 100_000, "{hits} hits");
    }

    /// The wider tiles of wide images ([`tile_shift`]) find the same hits.
    #[test]
    fn wide_tiles_find_the_bvh_hit_for_every_primary_ray() {
        assert!(tile_shift(48) < tile_shift(520));
        let scene = builtin("courtyard", Variant::Dynamic).unwrap();
        compare(&scene, 14, (520, 293), &[]);
    }

    /// The built-in scenes' lists stay under half [`max_entries`] from the tests' sizes to
    /// 2560×1440 (so they keep the lists' speed), where courtyard with its houses copied in place
    /// 160 times exceeds it and is left to the BVH (the renders' memory bounds count the lists
    /// at the cap); with 16 copies the lists are kept.
    #[test]
    fn the_lists_stop_at_their_cap_and_the_builtin_scenes_stay_far_below_it() {
        let entries = |scene: &Scene, (w, h): (usize, usize)| {
            let pose = scene.path.server_pose(14, 10.0);
            let cam = rig(&pose, w, h, scene.near, scene.far).main;
            let rays = camera_rays(&cam, "test").unwrap();
            let snap = scene.at(1.4);
            EyeTiles::new(&snap, &cam, &rays).map(|e| e.entries())
        };
        for name in SCENE_NAMES {
            let scene = builtin(name, Variant::Dynamic).unwrap();
            for size @ (w, h) in [(48, 27), (640, 360), (1280, 720), (2560, 1440)] {
                let n = entries(&scene, size).unwrap();
                assert!(
                    2 * n <= max_entries(w * h),
                    "{name} at {w}x{h}: {n} entries"
                );
            }
        }
        // Courtyard with every house copied in place, many times over.
        let crowd = |copies: usize| {
            let mut scene = builtin("courtyard", Variant::Static).unwrap();
            let houses: Vec<usize> = (0..scene.objects.len())
                .filter(|&i| scene.objects[i].name == "house")
                .collect();
            for _ in 0..copies {
                for &i in &houses {
                    scene.objects.push(scene.objects[i].clone());
                }
            }
            scene.refresh().unwrap();
            scene
        };
        let size @ (w, h) = (640, 360);
        let some = entries(&crowd(16), size).expect("16 copies: lists kept");
        assert!(some > 2 * entries(&crowd(0), size).unwrap());
        let dense = crowd(160);
        assert_eq!(
            entries(&dense, size),
            None,
            "160 copies at {w}x{h}: lists kept"
        );
        // ... and renders what the scene of one copy does (the copies tie with the originals,
        // whose colours they share), through the BVH.
        let (w, h) = (256, 144);
        assert_eq!(
            entries(&dense, (w, h)),
            None,
            "160 copies at {w}x{h}: lists kept"
        );
        let pose = dense.path.server_pose(14, 10.0);
        let render = |scene: &Scene| {
            let cam = rig(&pose, w, h, scene.near, scene.far).main;
            crate::render_ground_truth(scene, &cam, 1.4, 1).unwrap()
        };
        assert!(render(&dense) == render(&crowd(0)));
    }

    /// Two copies of a house at the same place meet a ray at exactly the same distance: the
    /// BVH's order decides which is seen, and the tile lists defer to it.
    #[test]
    fn exact_ties_are_decided_as_the_bvh_decides_them() {
        let mut scene = builtin("courtyard", Variant::Static).unwrap();
        let houses: Vec<usize> = (0..scene.objects.len())
            .filter(|&i| scene.objects[i].name == "house")
            .collect();
        let mut doubled = houses.clone();
        for &i in &houses {
            scene.objects.push(scene.objects[i].clone());
            doubled.push(scene.objects.len() - 1);
        }
        scene.refresh().unwrap();
        let seen: usize = [0, 14]
            .iter()
            .map(|&k| compare(&scene, k, (48, 27), &doubled))
            .sum();
        assert!(seen > 0, "no ray met a doubled house");
    }

    /// The tiles of the last column and of the last, partial row (27 pixels in tiles of 8) reach
    /// the image's far edges: a small sphere on the centre ray of a pixel at each corner and in
    /// the middle of each edge (a quarter of a pixel across, 2 m out) is found as the BVH finds
    /// it, so its tile's list holds it.
    #[test]
    fn tile_lists_reach_the_image_edges() {
        let mut scene = builtin("courtyard", Variant::Static).unwrap();
        let (k, (w, h)) = (14, (48, 27));
        let pose = scene.path.server_pose(k, 10.0);
        let cam = rig(&pose, w, h, scene.near, scene.far).main;
        let rays = camera_rays(&cam, "test").unwrap();
        let first = scene.objects.len();
        let (mid_w, mid_h) = (w / 2, h / 2);
        let pixels = [
            (0, 0),
            (w - 1, 0),
            (0, h - 1),
            (w - 1, h - 1),
            (mid_w, 0),
            (mid_w, h - 1),
            (0, mid_h),
            (w - 1, mid_h),
        ];
        for (i, j) in pixels {
            let d = normalize(rays.ray(i, j));
            let beside = normalize(rays.ray(if i == 0 { 1 } else { i - 1 }, j));
            let radius = 0.125 * 2.0 * length(sub(d, beside));
            let centre = crate::math::add(rays.origin, crate::math::scale(d, 2.0));
            let material = scene.objects[0].material;
            scene.objects.push(crate::scene::Object::new(
                "probe",
                Shape::Sphere { radius },
                material,
                Rigid::translation(centre),
            ));
        }
        scene.refresh().unwrap();
        let probes: Vec<usize> = (first..scene.objects.len()).collect();
        // Each probe is met at least by its pixel's centre ray.
        let seen = compare(&scene, k, (w, h), &probes);
        assert!(seen >= probes.len(), "{seen} rays met the probes");
    }
}
