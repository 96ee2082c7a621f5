//! Tests of the renderer: determinism, motion and shadow buffers against independent
//! computations, input checks and the colour filter.

use super::*;
use crate::rig::rig;
use crate::scene::{Scene, Variant};
use crate::scenes::builtin;
use crate::shape::Shape;

const DT: f64 = 0.1;
const S: usize = 4;

/// The main camera of server frame `k` at `w×h`.
fn camera(scene: &Scene, k: usize, w: usize, h: usize) -> Camera {
    rig(
        &scene.path.server_pose(k, 10.0),
        w,
        h,
        scene.near,
        scene.far,
    )
    .main
}

/// `(object, face)` seen at each pixel (`None` for the sky).
fn ids(scene: &Scene, cam: &Camera, t: f64) -> Vec<Option<(usize, u32)>> {
    let rays = camera_rays(cam, "test").unwrap();
    let snap = scene.at(t);
    let mut out = Vec::new();
    for j in 0..cam.height {
        for i in 0..cam.width {
            let s = sample(&snap, &rays, i, j, false);
            // A smooth mesh counts as one surface: its triangles are smaller than a pixel
            // here, and bilinear interpolation across them errs only to second order.
            out.push(s.obj.map(|o| {
                let mesh = matches!(scene.objects[o].shape, crate::shape::Shape::Mesh(_));
                (o, if mesh { 0 } else { s.face })
            }));
        }
    }
    out
}

fn f32_bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn rendering_is_deterministic_and_independent_of_the_thread_count() {
    let scene = builtin("courtyard", Variant::Dynamic).unwrap();
    let cam = camera(&scene, 12, 61, 35);
    let t = 1.2;
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            (
                render_server(&scene, &cam, t, DT, S, 3).unwrap().buffers,
                render_ground_truth(&scene, &cam, t, 3).unwrap(),
            )
        })
    };
    let (a, ga) = run(1);
    let (b, gb) = run(4);
    let (c, gc) = run(4);
    for (x, gx) in [(&b, &gb), (&c, &gc)] {
        assert_eq!(&ga, gx);
        assert_eq!(a.color, x.color);
        assert_eq!(f32_bits(&a.depth), f32_bits(&x.depth));
        assert_eq!(f32_bits(&a.motion_fwd), f32_bits(&x.motion_fwd));
        assert_eq!(f32_bits(&a.motion_bwd), f32_bits(&x.motion_bwd));
        assert_eq!(a.shadow_fwd, x.shadow_fwd);
        assert_eq!(a.shadow_bwd, x.shadow_bwd);
    }
    // The ground truth at a server camera and time is the server colour, byte for byte.
    assert_eq!(ga, a.color);
}

#[test]
fn static_variants_have_no_motion_and_no_dynamic_shadow() {
    for name in crate::scenes::SCENE_NAMES {
        let scene = builtin(name, Variant::Static).unwrap();
        let cam = camera(&scene, 7, 48, 27);
        let r = render_server(&scene, &cam, 0.7, DT, S, 2).unwrap().buffers;
        assert!(r.motion_fwd.iter().chain(&r.motion_bwd).all(|&m| m == 0.0));
        for sb in [&r.shadow_fwd, &r.shadow_bwd] {
            assert!(sb.bits.iter().all(|&b| b == 0), "{name}");
            assert!(sb.s_min.iter().chain(&sb.s_max).all(|&c| c == 0), "{name}");
        }
        assert!(r.depth.iter().any(|&z| z > 0.0), "{name} sees nothing");
    }
}

/// Bilinear sample of `depth` at NDC `(x, y)` and the four pixels it reads, or `None` when the
/// footprint leaves the image.
fn bilinear(depth: &[f32], w: usize, h: usize, x: f64, y: f64) -> Option<(f64, [usize; 4])> {
    let fx = (x + 1.0) * 0.5 * w as f64 - 0.5;
    let fy = (1.0 - y) * 0.5 * h as f64 - 0.5;
    let (i0, j0) = (fx.floor(), fy.floor());
    if !(i0 >= 0.0 && j0 >= 0.0 && i0 + 1.0 < w as f64 && j0 + 1.0 < h as f64) {
        return None;
    }
    let (i0, j0) = (i0 as usize, j0 as usize);
    let (ax, ay) = (fx - i0 as f64, fy - j0 as f64);
    let k = [
        j0 * w + i0,
        j0 * w + i0 + 1,
        (j0 + 1) * w + i0,
        (j0 + 1) * w + i0 + 1,
    ];
    let z = |n: usize| f64::from(depth[k[n]]);
    let top = z(0) + (z(1) - z(0)) * ax;
    let bot = z(2) + (z(3) - z(2)) * ax;
    Some((top + (bot - top) * ay, k))
}

/// Moving every visible point of one frame by its motion lands it on the other frame's surface
/// (camera held fixed). The other frame is sampled bilinearly at the exact landing point, not
/// at the nearest pixel centre (which sees a neighbouring material point whose depth differs
/// by the depth gradient); footprints that straddle another object or face (silhouettes,
/// creases, occlusion at the other time) are skipped.
fn check_motion_consistency(name: &str, k: usize) {
    let scene = builtin(name, Variant::Dynamic).unwrap();
    let (w, h) = (96, 54);
    let cam = camera(&scene, k, w, h);
    let t = k as f64 * DT;
    let a = render_server(&scene, &cam, t, DT, 1, 1).unwrap().buffers;
    let b = render_server(&scene, &cam, t + DT, DT, 1, 1)
        .unwrap()
        .buffers;
    let (ia, ib) = (ids(&scene, &cam, t), ids(&scene, &cam, t + DT));
    for (src, dst, ids_src, ids_dst, motion) in [
        (&a, &b, &ia, &ib, &a.motion_fwd),
        (&b, &a, &ib, &ia, &b.motion_bwd),
    ] {
        let (mut comparable, mut good, mut moving, mut moving_good) = (0usize, 0, 0, 0);
        for j in 0..h {
            for i in 0..w {
                let p = j * w + i;
                let Some(id) = ids_src[p] else { continue };
                let o = &motion[3 * p..3 * p + 3];
                if !scene.moves(id.0) {
                    assert_eq!(o, &[0.0; 3], "{name}: still object moves at {i},{j}");
                }
                let x = (2 * i + 1) as f64 / w as f64 - 1.0 + f64::from(o[0]);
                let y = 1.0 - (2 * j + 1) as f64 / h as f64 + f64::from(o[1]);
                let z = f64::from(src.depth[p]) + f64::from(o[2]);
                let Some((zi, quad)) = bilinear(&dst.depth, w, h, x, y) else {
                    continue;
                };
                if quad.iter().any(|&q| ids_dst[q] != Some(id)) {
                    continue;
                }
                comparable += 1;
                let ok = (zi - z).abs() <= 1e-4;
                good += usize::from(ok);
                // Thin curved meshes (a 9 cm tube two pixels wide) are beyond what a bilinear
                // footprint resolves; `motion_unprojects_to_the_moved_material_point` covers them.
                let mesh = matches!(scene.objects[id.0].shape, crate::shape::Shape::Mesh(_));
                if scene.moves(id.0) && !mesh {
                    moving += 1;
                    moving_good += usize::from(ok);
                }
            }
        }
        assert!(
            moving >= 10,
            "{name}: only {moving} moving comparable pixels"
        );
        // The still pixels pass trivially, so the moving ones are held to a bar of their own.
        assert!(
            moving_good as f64 >= 0.9 * moving as f64,
            "{name}: {moving_good} of {moving} moving pixels within 1e-4"
        );
        assert!(
            good as f64 >= 0.99 * comparable as f64,
            "{name}: {good} of {comparable} within 1e-4"
        );
    }
}

/// `P⁻¹(p̄ + O[p])` is the material point seen at `p` moved by its object's transforms,
/// written out independently of the renderer's `carry`.
#[test]
fn motion_unprojects_to_the_moved_material_point() {
    for (name, k) in [("lab", 12), ("courtyard", 10), ("colonnade", 5)] {
        check_unprojected_motion(name, k);
    }
}

fn check_unprojected_motion(name: &str, k: usize) {
    let scene = builtin(name, Variant::Dynamic).unwrap();
    let (w, h) = (96, 54);
    let cam = camera(&scene, k, w, h);
    let t = k as f64 * DT;
    let r = render_server(&scene, &cam, t, DT, 1, 1).unwrap().buffers;
    let inv_vp = cam.view_proj().inverse().unwrap();
    let unproject = |x: f64, y: f64, z: f64| {
        let q = inv_vp.mul_vec([x, y, z, 1.0]);
        [q[0] / q[3], q[1] / q[3], q[2] / q[3]]
    };
    let ids_t = ids(&scene, &cam, t);
    let w0 = scene.transforms(t);
    let (mut checked, mut moving) = (0, 0);
    for (motion, dt) in [(&r.motion_fwd, DT), (&r.motion_bwd, -DT)] {
        let w1 = scene.transforms(t + dt);
        for p in 0..w * h {
            // Every object, still ones too (where the expected point is the point itself): an
            // object wrongly taken as still (a child of a moving parent) shows here.
            let Some((obj, _)) = ids_t[p] else { continue };
            moving += usize::from(scene.moves(obj));
            let (i, j) = (p % w, p / w);
            let x = (2 * i + 1) as f64 / w as f64 - 1.0;
            let y = 1.0 - (2 * j + 1) as f64 / h as f64;
            let z = f64::from(r.depth[p]);
            let x0 = unproject(x, y, z);
            let expect = w1[obj].point(w0[obj].inverse().point(x0));
            let o = &motion[3 * p..3 * p + 3];
            let moved = unproject(
                x + f64::from(o[0]),
                y + f64::from(o[1]),
                z + f64::from(o[2]),
            );
            let err = (0..3)
                .map(|k| (moved[k] - expect[k]).abs())
                .fold(0.0, f64::max);
            // Measured at most 1.7e-7 m (f32 depth and motion; courtyard), over moves of up to
            // 0.22 m: a motion off by 0.1 % is 2.3e-4 m off in the lab.
            assert!(
                err < 4e-7,
                "{name} pixel {i},{j}: {moved:?} vs {expect:?} ({err:e})"
            );
            checked += 1;
        }
    }
    assert!(checked > 1000 && moving > 100, "{name}: {checked} {moving}");
}

#[test]
fn motion_moves_points_onto_the_next_and_previous_frames_surfaces() {
    check_motion_consistency("courtyard", 10);
    check_motion_consistency("lab", 12);
    check_motion_consistency("colonnade", 5);
}

/// On still objects the bitfield's subframe `j` is exactly the quantised shadow observed when
/// the scene is rendered directly at `t ± jΔ/S` from the same camera; subframe 0 (and every
/// subframe, where the bits are 0) is the key frame's.
#[test]
fn shadow_bits_match_directly_rendered_subframes() {
    let scene = builtin("lab", Variant::Dynamic).unwrap();
    let (w, h) = (64, 36);
    let cam = camera(&scene, 20, w, h);
    let t = 2.0;
    let r = render_server(&scene, &cam, t, DT, S, 1).unwrap().buffers;
    let key = ids(&scene, &cam, t);
    let q = |f: f32| (f64::from(f) * 3.0).round() as u32;
    let mut changing = 0;
    for (sb, sign) in [(&r.shadow_fwd, 1.0), (&r.shadow_bwd, -1.0)] {
        for j in 0..S {
            let tj = t + sign * DT / S as f64 * j as f64;
            let direct = render_shadow_fraction(&scene, &cam, tj).unwrap();
            let at_j = ids(&scene, &cam, tj);
            for p in 0..w * h {
                let Some(id) = key[p] else { continue };
                if scene.moves(id.0) || at_j[p] != key[p] {
                    continue;
                }
                let bits = sb.bits[p];
                let level = if bits == 0 {
                    let key_f = render_shadow_fraction_at(&scene, &cam, t, p);
                    q(key_f)
                } else {
                    (bits >> (2 * j)) & 3
                };
                assert_eq!(level, q(direct[p]), "pixel {p}, subframe {j}, sign {sign}");
                changing += usize::from(bits != 0 && j == 1);
            }
        }
    }
    assert!(
        changing > 10,
        "only {changing} still pixels with a changing shadow"
    );
}

fn render_shadow_fraction_at(scene: &Scene, cam: &Camera, t: f64, p: usize) -> f32 {
    let rays = camera_rays(cam, "test").unwrap();
    let snap = scene.at(t);
    sample(&snap, &rays, p % cam.width, p / cam.width, true).shadow as f32
}

#[test]
fn shadow_colours_follow_the_levels_and_the_sky_is_far_and_still() {
    let scene = builtin("courtyard", Variant::Dynamic).unwrap();
    let cam = camera(&scene, 10, 80, 45);
    let r = render_server(&scene, &cam, 1.0, DT, S, 3).unwrap().buffers;
    let (mut with_bits, mut brighter, mut darker) = (0, 0, 0);
    for sb in [&r.shadow_fwd, &r.shadow_bwd] {
        for p in 0..80 * 45 {
            let bits = sb.bits[p];
            let (smin, smax) = (&sb.s_min[3 * p..3 * p + 3], &sb.s_max[3 * p..3 * p + 3]);
            if bits == 0 {
                assert!(smin == [0; 3] && smax == [0; 3]);
                continue;
            }
            with_bits += 1;
            assert_eq!(bits >> (2 * S), 0);
            let levels: Vec<u32> = (0..S).map(|j| (bits >> (2 * j)) & 3).collect();
            let (lo, hi) = (*levels.iter().min().unwrap(), *levels.iter().max().unwrap());
            assert!(lo < hi);
            assert_eq!(smin == [0; 3], lo == levels[0]);
            assert_eq!(smax == [0; 3], hi == levels[0]);
            // `S_min` is the colour under less shadow than the key frame's (lit at least as
            // brightly in every channel), `S_max` under more.
            let key = &r.color[3 * p..3 * p + 3];
            let sum = |c: &[u8]| c.iter().map(|&v| u32::from(v)).sum::<u32>();
            if lo < levels[0] {
                assert!((0..3).all(|k| smin[k] >= key[k]), "{smin:?} vs {key:?}");
                brighter += usize::from(sum(smin) > sum(key));
            }
            if hi > levels[0] {
                assert!((0..3).all(|k| smax[k] <= key[k]), "{smax:?} vs {key:?}");
                darker += usize::from(sum(smax) < sum(key));
            }
        }
    }
    assert!(with_bits > 10, "{with_bits}");
    assert!(brighter > 10 && darker > 10, "{brighter} {darker}");
    let mut sky = 0;
    // Point-sampled, so that a sky pixel is sky in all of its colour (supersampled, a thin
    // pole between two pixel centres would tint it).
    let r = render_server(&scene, &cam, 1.0, DT, S, 1).unwrap().buffers;
    // Point-sampled, `S_min` and `S_max` are the key frame's surface shaded at the least and
    // most shadow of the levels (level / 3), nothing else changed.
    let (rays, snap) = (camera_rays(&cam, "test").unwrap(), scene.at(1.0));
    let mut compared = 0;
    for sb in [&r.shadow_fwd, &r.shadow_bwd] {
        for p in (0..80 * 45).filter(|&p| sb.bits[p] != 0) {
            let s = sample(&snap, &rays, p % 80, p / 80, true);
            let m = &scene.objects[s.obj.unwrap()].material;
            let at = |l: u32| {
                let c = snap.shade(m, s.albedo, s.normal, s.dir, f64::from(l) / 3.0);
                c.map(rgb8)
            };
            let levels = (0..S).map(|j| (sb.bits[p] >> (2 * j)) & 3);
            let (lo, hi) = (levels.clone().min().unwrap(), levels.max().unwrap());
            let l0 = sb.bits[p] & 3;
            if lo < l0 {
                assert_eq!(sb.s_min[3 * p..3 * p + 3], at(lo), "pixel {p}");
                compared += 1;
            }
            if hi > l0 {
                assert_eq!(sb.s_max[3 * p..3 * p + 3], at(hi), "pixel {p}");
                compared += 1;
            }
        }
    }
    assert!(compared > 10, "{compared}");
    for p in 0..80 * 45 {
        if r.depth[p] == 0.0 {
            sky += 1;
            assert_eq!(&r.color[3 * p..3 * p + 3], &scene.sky);
            assert_eq!(&r.motion_fwd[3 * p..3 * p + 3], &[0.0; 3]);
            assert_eq!(r.shadow_fwd.bits[p], 0);
        } else {
            assert!(r.depth[p] > 0.0 && r.depth[p] <= 1.0);
        }
    }
    assert!(sky > 0);
}

#[test]
fn bad_inputs_are_errors() {
    let scene = builtin("lab", Variant::Static).unwrap();
    let cam = camera(&scene, 0, 8, 8);
    for subframes in [0, 17] {
        assert!(matches!(
            render_server(&scene, &cam, 0.0, DT, subframes, 1),
            Err(SceneError::BadSubframes { subframes: s }) if s == subframes
        ));
    }
    // The limits themselves are allowed: 1 and 16 subframes, 1 and MAX_SAMPLES samples.
    for (subframes, n) in [(1, MAX_SAMPLES), (16, 1)] {
        assert!(render_server(&scene, &cam, 0.0, DT, subframes, n).is_ok());
        assert!(render_ground_truth(&scene, &cam, 0.0, n).is_ok());
    }
    for n in [0, MAX_SAMPLES + 1] {
        assert!(matches!(
            render_server(&scene, &cam, 0.0, DT, 4, n),
            Err(SceneError::BadSamples { samples, .. }) if samples == n
        ));
        assert!(matches!(
            render_ground_truth(&scene, &cam, 0.0, n),
            Err(SceneError::BadSamples { .. })
        ));
    }
    let mut bad = cam;
    bad.view = Mat4([[0.0; 4]; 4]);
    assert!(matches!(
        render_ground_truth(&scene, &bad, 0.0, 1),
        Err(SceneError::BadCamera { .. })
    ));
}

/// Supersampling filters colour only: for every sample count the ground truth at the server
/// camera and time is the server colour byte for byte, and depth, motion and the shadow
/// bitfields are bit-identical to the point-sampled render (they stay at the pixel centre).
#[test]
fn sample_count_keeps_the_identity_and_leaves_geometry_alone() {
    for (name, k) in [("courtyard", 10), ("lab", 20), ("colonnade", 5)] {
        let scene = builtin(name, Variant::Dynamic).unwrap();
        let cam = camera(&scene, k, 48, 27);
        let t = k as f64 * DT;
        let renders: Vec<reproj_core::CameraBuffers> = [1, 2, 3]
            .iter()
            .map(|&n| {
                let r = render_server(&scene, &cam, t, DT, S, n).unwrap().buffers;
                assert_eq!(
                    render_ground_truth(&scene, &cam, t, n).unwrap(),
                    r.color,
                    "{name}, {n}×{n}: the ground truth at the server camera is not the colour"
                );
                r
            })
            .collect();
        let point = &renders[0];
        for (r, n) in renders[1..].iter().zip(2..) {
            assert_ne!(r.color, point.color, "{name}: {n}×{n} filters nothing");
            assert_eq!(f32_bits(&r.depth), f32_bits(&point.depth), "{name} {n}");
            assert_eq!(
                f32_bits(&r.motion_fwd),
                f32_bits(&point.motion_fwd),
                "{name} {n}"
            );
            assert_eq!(
                f32_bits(&r.motion_bwd),
                f32_bits(&point.motion_bwd),
                "{name} {n}"
            );
            for (a, b) in [
                (&r.shadow_fwd, &point.shadow_fwd),
                (&r.shadow_bwd, &point.shadow_bwd),
            ] {
                assert_eq!(a.bits, b.bits, "{name} {n}");
                // S_min/S_max are colours (filtered), but present exactly where the bits are.
                for p in 0..a.bits.len() {
                    let (mn, mx) = (&a.s_min[3 * p..3 * p + 3], &a.s_max[3 * p..3 * p + 3]);
                    let (pmn, pmx) = (&b.s_min[3 * p..3 * p + 3], &b.s_max[3 * p..3 * p + 3]);
                    assert_eq!(mn == [0; 3], pmn == [0; 3], "{name} {n} pixel {p}");
                    assert_eq!(mx == [0; 3], pmx == [0; 3], "{name} {n} pixel {p}");
                }
            }
        }
    }
}

/// Where a pixel's whole footprint lies on one flat, one-colour surface, the supersampled
/// colour is the point-sampled one: the filter blurs texture, it does not shift or darken
/// colour. Every material is made one colour (`uv_scale` 0 puts every point at uv (0, 0),
/// inside a grout line) and matte, the scene static; the pixels compared are those whose
/// `n×n` sub-sample rays all hit the same face of the same box or quad.
#[test]
fn supersampled_flat_colour_equals_the_point_sample() {
    let mut scene = builtin("courtyard", Variant::Static).unwrap();
    for o in &mut scene.objects {
        o.material = Material::matte(
            crate::material::Pattern::Tiles,
            [0.2, 0.3, 0.4],
            [0.55, 0.45, 0.35],
            0.0,
            0,
        );
    }
    let (w, h, t) = (64, 36, 0.4);
    let cam = camera(&scene, 4, w, h);
    let rays = camera_rays(&cam, "test").unwrap();
    let snap = scene.at(t);
    let point = render_ground_truth(&scene, &cam, t, 1).unwrap();
    let mut flat = 0;
    for n in [2, 3, 4] {
        let fine = render_ground_truth(&scene, &cam, t, n).unwrap();
        for j in 0..h {
            for i in 0..w {
                let c = sample(&snap, &rays, i, j, false);
                let Some(o) = c.obj else { continue };
                let planar = matches!(
                    scene.objects[o].shape,
                    Shape::Cuboid { .. } | Shape::Quad { .. }
                );
                let one_face = (0..n * n).all(|q| {
                    let s = sample_ray(
                        &snap,
                        &rays,
                        rays.sub_ray(i, j, q % n, q / n, n),
                        Needs::COLOUR,
                        None,
                    );
                    s.obj == c.obj && s.face == c.face
                });
                if !planar || !one_face {
                    continue;
                }
                flat += 1;
                let p = 3 * (j * w + i);
                assert_eq!(fine[p..p + 3], point[p..p + 3], "{n}×{n} at pixel {i},{j}");
            }
        }
    }
    assert!(flat > 1000, "only {flat} flat pixels compared");
}

/// FNV-1a (64-bit) of a byte stream: a fixed, dependency-free digest for the pinned renders.
fn fnv1a(bytes: impl IntoIterator<Item = u8>) -> u64 {
    bytes.into_iter().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Every byte of a camera's server buffers, floats by their bits.
fn buffer_bytes(b: &reproj_core::CameraBuffers) -> Vec<u8> {
    let floats = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let mut out = b.color.clone();
    out.extend(floats(&b.depth));
    out.extend(floats(&b.motion_fwd));
    out.extend(floats(&b.motion_bwd));
    for sb in [&b.shadow_fwd, &b.shadow_bwd] {
        out.extend(sb.bits.iter().flat_map(|x| x.to_le_bytes()));
        out.extend(&sb.s_min);
        out.extend(&sb.s_max);
    }
    out
}

/// The renderer's output pinned byte for byte: one server frame (main and both auxiliary
/// cameras, every buffer, 3×3 colour sub-samples) and one ground-truth frame (3×3, and 2×2 at
/// the same camera) of every built-in scene, static and dynamic, at 48×27. Speed-ups of the
/// renderer (traversal, intersection, BVH) must leave these digests unchanged; a deliberate
/// change of the images updates them together with the recording format's renderer version.
#[test]
fn renders_are_pinned_byte_for_byte() {
    const SCALE: f64 = 0.01875; // 48×27 main camera, 24×13 auxiliary ones.
    let pinned: [(&str, Variant, u64, u64); 6] = [
        (
            "courtyard",
            Variant::Static,
            0xaa6b74688cac063f,
            0x8fa14b17f3a5eab2,
        ),
        (
            "courtyard",
            Variant::Dynamic,
            0x58ff4f686f814948,
            0x74396a18356b07ad,
        ),
        (
            "colonnade",
            Variant::Static,
            0xe9cb07e030d24047,
            0xa7a8fd8a53672bb7,
        ),
        (
            "colonnade",
            Variant::Dynamic,
            0xc107c20a08c050da,
            0xcb2d36690f229f24,
        ),
        (
            "lab",
            Variant::Static,
            0x0850591b8f6821bc,
            0xaa06ff8591403244,
        ),
        (
            "lab",
            Variant::Dynamic,
            0x6d82b12bbc8c95e3,
            0x35c2fa34ed32cf20,
        ),
    ];
    let mut got = Vec::new();
    for &(name, variant, _, _) in &pinned {
        let scene = builtin(name, variant).unwrap();
        let frame = crate::render_server_frame(&scene, 12, SCALE, 10.0, S).unwrap();
        let server = fnv1a(
            std::iter::once(&frame.main)
                .chain(&frame.aux)
                .flat_map(|c| buffer_bytes(&c.buffers)),
        );
        let n = 150; // t = 1.25 s at 120 Hz, between server frames.
        let mut truth = crate::render_client_frame(&scene, n, SCALE, 120.0, false).unwrap();
        let (w, h) = crate::main_size(SCALE).unwrap();
        let pose = scene.path.client_pose(n as f64 / 120.0);
        let cam = crate::rig::mono(&pose, w, h, scene.near, scene.far);
        truth.push(render_ground_truth(&scene, &cam, n as f64 / 120.0, 2).unwrap());
        got.push((name, variant, server, fnv1a(truth.concat())));
    }
    let expect: Vec<_> = pinned.to_vec();
    assert_eq!(got, expect, "renders differ from the pinned digests");
}

/// The colour filter's rounding without the library is the library's, for special values,
/// every half-integer and its neighbours, and random values of every magnitude.
#[test]
fn rgb8_rounds_as_the_library_does() {
    let lib = |x: f64| x.round().clamp(0.0, 255.0) as u8;
    let mut xs = vec![
        0.0,
        -0.0,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::MIN_POSITIVE,
        f64::MAX,
        0.49999999999999994,
    ];
    for k in -4..600 {
        let h = k as f64 * 0.5;
        xs.extend([
            h,
            f64::from_bits(h.to_bits() + 1),
            f64::from_bits(h.to_bits().wrapping_sub(1)),
        ]);
    }
    let mut state = 0x2545_f491_4f6c_dd1du64;
    for _ in 0..200_000 {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        xs.push(f64::from_bits(state));
        xs.push((state >> 11) as f64 / (1u64 << 53) as f64 * 300.0 - 20.0);
    }
    for x in xs {
        assert_eq!(rgb8(x), lib(x), "{x:e} ({:#x})", x.to_bits());
    }
}
