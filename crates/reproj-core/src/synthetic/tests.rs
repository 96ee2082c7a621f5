//! Unit tests of the synthetic scene.

use super::*;

const S: usize = 4;
const DT: f64 = 0.1;

fn max_abs_diff(a: V3, b: V3) -> f64 {
    (0..3).map(|c| (a[c] - b[c]).abs()).fold(0.0, f64::max)
}

fn cams(t: f64, w: usize, h: usize) -> (Camera, [Camera; 2]) {
    let (eye, target) = head_pose(t);
    rig(eye, target, w, h)
}

/// The object seen at each pixel (for tests that look at one kind of surface).
fn objects(scene: &SyntheticScene, cam: &Camera, t: f64) -> Vec<Obj> {
    let rays = Rays::new(cam).unwrap();
    let pose = scene.pose(t);
    let mut out = Vec::new();
    for j in 0..cam.height {
        for i in 0..cam.width {
            out.push(scene.sample(&rays, &pose, i, j).obj);
        }
    }
    out
}

#[test]
fn static_scene_has_no_motion_and_no_dynamic_shadow() {
    let scene = SyntheticScene::new(false);
    let (main, aux) = cams(0.3, 96, 54);
    for cam in [main, aux[0], aux[1]] {
        let r = scene.render_server(&cam, 0.3, DT, S);
        assert!(r.motion_fwd.iter().chain(&r.motion_bwd).all(|&m| m == 0.0));
        for sb in [&r.shadow_fwd, &r.shadow_bwd] {
            assert!(sb.bits.iter().all(|&b| b == 0));
            assert!(sb.s_min.iter().chain(&sb.s_max).all(|&c| c == 0));
        }
    }
}

#[test]
fn static_geometry_has_exactly_zero_motion_in_the_dynamic_scene() {
    let scene = SyntheticScene::new(true);
    let (main, _) = cams(0.2, 96, 54);
    let r = scene.render_server(&main, 0.2, DT, S);
    let objs = objects(&scene, &main, 0.2);
    let mut moving = 0;
    for (k, o) in objs.iter().enumerate() {
        let m = &r.motion_fwd[3 * k..3 * k + 3];
        if o.moves() {
            moving += 1;
            assert!(m.iter().any(|&v| v != 0.0));
        } else {
            assert_eq!(m, &[0.0; 3]);
            assert_eq!(&r.motion_bwd[3 * k..3 * k + 3], &[0.0; 3]);
        }
    }
    assert!(moving > 100);
}

/// `P⁻¹(p̄ + O[p])` is the material point seen at `p`, moved by the scene to `t ± Δ`.
#[test]
fn motion_unprojects_to_the_moved_point() {
    let scene = SyntheticScene::new(true);
    let t = 0.2;
    let (main, _) = cams(t, 128, 72);
    let r = scene.render_server(&main, t, DT, S);
    let proj = main.projector("main").unwrap();
    let rays = Rays::new(&main).unwrap();
    let pose = scene.pose(t);
    let mut checked = [0usize; 2];
    for j in 0..main.height {
        for i in 0..main.width {
            let s = scene.sample(&rays, &pose, i, j);
            if !s.obj.moves() {
                continue;
            }
            let k = j * main.width + i;
            let [x, y] = proj.ndc_of_pixel(i, j);
            let z = r.depth[k];
            let x0 = proj.unproject([x, y, z]).map(f64::from);
            assert!(max_abs_diff(x0, s.x) < 1e-3, "depth at {i},{j}");
            for (m, dt) in [(&r.motion_fwd, DT), (&r.motion_bwd, -DT)] {
                let o = &m[3 * k..3 * k + 3];
                let moved = proj
                    .unproject([x + o[0], y + o[1], z + o[2]])
                    .map(f64::from);
                // The analytic motion, written out independently of `carry`.
                let expect = match s.obj {
                    Obj::Sphere => {
                        let c0 = [2.0 * (0.75 * t).sin(), 0.6, -3.0];
                        let c1 = [2.0 * (0.75 * (t + dt)).sin(), 0.6, -3.0];
                        let body = rotate(sub(s.x, c0), spin_axis(), -SPHERE_SPIN * t);
                        add(c1, rotate(body, spin_axis(), SPHERE_SPIN * (t + dt)))
                    }
                    _ => {
                        let dy = 0.35 * ((3.0 * (t + dt)).sin() - (3.0 * t).sin());
                        add(s.x, [0.0, dy, 0.0])
                    }
                };
                assert!(max_abs_diff(expect, scene.carry(s.obj, s.x, t, t + dt)) < 1e-9);
                let err = max_abs_diff(moved, expect);
                assert!(err < 1e-3, "pixel {i},{j}: {moved:?} vs {expect:?}");
            }
            checked[usize::from(s.obj == Obj::Cube)] += 1;
        }
    }
    assert!(checked[0] > 50 && checked[1] > 10, "{checked:?}");
}

#[test]
fn ground_truth_at_a_server_camera_equals_the_server_colour() {
    let scene = SyntheticScene::new(true);
    let (main, aux) = cams(0.45, 80, 45);
    for cam in [main, aux[0], aux[1]] {
        let r = scene.render_server(&cam, 0.45, DT, S);
        assert_eq!(scene.render_ground_truth(&cam, 0.45), r.color);
    }
}

#[test]
fn sweeping_shadow_sets_bits_on_the_wall() {
    let scene = SyntheticScene::new(true);
    let t = 0.0;
    let (main, _) = cams(t, 160, 90);
    let r = scene.render_server(&main, t, DT, S);
    let objs = objects(&scene, &main, t);
    let rays = Rays::new(&main).unwrap();
    let pose = scene.pose(t);
    for (sb, sign) in [(&r.shadow_fwd, 1.0), (&r.shadow_bwd, -1.0)] {
        let (mut on_wall, mut smin_stored) = (0, 0);
        for (k, o) in objs.iter().enumerate() {
            let bits = sb.bits[k];
            let (smin, smax) = (&sb.s_min[3 * k..3 * k + 3], &sb.s_max[3 * k..3 * k + 3]);
            if bits == 0 {
                assert!(smin == [0; 3] && smax == [0; 3]);
                continue;
            }
            if *o == Obj::Wall {
                on_wall += 1;
            }
            let levels: Vec<u32> = (0..S).map(|j| (bits >> (2 * j)) & 3).collect();
            let (lmin, lmax) = (*levels.iter().min().unwrap(), *levels.iter().max().unwrap());
            assert!(lmin < lmax);
            assert_eq!(bits >> (2 * S), 0);
            // Subframe 0 is the key frame's (continuous) shadow, quantised.
            let s = scene.sample(&rays, &pose, k % main.width, k / main.width);
            assert_eq!(levels[0], (s.shadow * 3.0).round() as u32);
            // And subframe j follows the point to t ± jΔ/S.
            let tj = t + sign * DT / S as f64 * 3.0;
            let xj = scene.carry(s.obj, s.x, t, tj);
            let f = scene.shadow(s.obj, xj, &scene.pose(tj));
            assert_eq!(levels[3], (f * 3.0).round() as u32);
            assert_eq!(smin == [0; 3], lmin == levels[0]);
            assert_eq!(smax == [0; 3], lmax == levels[0]);
            // A stored extreme is the key sample shaded at that level.
            let at = |l: u32| SyntheticScene::shade(s.albedo, s.normal, f64::from(l) / 3.0);
            if lmax != levels[0] {
                assert_eq!(smax, at(lmax));
            }
            if lmin != levels[0] {
                assert_eq!(smin, at(lmin));
                smin_stored += 1;
            }
        }
        assert!(
            on_wall > 5 && smin_stored > 5,
            "only {on_wall} wall pixels with dynamic shadow, {smin_stored} with S_min"
        );
    }
}

#[test]
fn sky_is_at_the_far_plane_and_still() {
    let scene = SyntheticScene::new(true);
    let (_, aux) = cams(0.0, 96, 54);
    let r = scene.render_server(&aux[0], 0.0, DT, S);
    let mut sky = 0;
    for k in 0..r.depth.len() {
        if r.depth[k] == 0.0 {
            sky += 1;
            assert_eq!(&r.color[3 * k..3 * k + 3], &SKY);
            assert_eq!(&r.motion_fwd[3 * k..3 * k + 3], &[0.0; 3]);
            assert_eq!(r.shadow_fwd.bits[k], 0);
        } else {
            assert!(r.depth[k] > 0.0 && r.depth[k] <= 1.0);
        }
    }
    assert!(sky > 0);
}

#[test]
fn rendering_is_independent_of_the_thread_count() {
    let scene = SyntheticScene::new(true);
    let (main, _) = cams(0.7, 70, 37);
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let r = scene.render_server(&main, 0.7, DT, S);
            (r, scene.render_ground_truth(&main, 0.7))
        })
    };
    let (a, ga) = run(1);
    let (b, gb) = run(3);
    assert_eq!(a.color, b.color);
    assert_eq!(ga, gb);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.depth), bits(&b.depth));
    assert_eq!(bits(&a.motion_fwd), bits(&b.motion_fwd));
    assert_eq!(bits(&a.motion_bwd), bits(&b.motion_bwd));
    for (x, y) in [
        (&a.shadow_fwd, &b.shadow_fwd),
        (&a.shadow_bwd, &b.shadow_bwd),
    ] {
        assert_eq!(x.bits, y.bits);
        assert_eq!(x.s_min, y.s_min);
        assert_eq!(x.s_max, y.s_max);
    }
}

#[test]
fn rig_matches_the_design() {
    let (main, [left, right]) = rig([0.3, 0.2, 2.0], [0.3, 0.2, -4.0], 1280, 720);
    assert_eq!((main.width, main.height), (1280, 720));
    assert_eq!(
        (left.width, left.height, right.width, right.height),
        (640, 360, 640, 360)
    );
    let centre = |c: &Camera| {
        let iv = c.view.inverse().unwrap();
        let o = iv.mul_vec([0.0, 0.0, 0.0, 1.0]);
        let f = iv.mul_vec([0.0, 0.0, -1.0, 0.0]);
        ([o[0], o[1], o[2]], [f[0], f[1], f[2]])
    };
    let (lo, lf) = centre(&left);
    let (ro, rf) = centre(&right);
    // The main camera looks along −z, so its x axis is world +x.
    assert!((lo[0] - 0.1).abs() < 1e-12 && (ro[0] - 0.5).abs() < 1e-12);
    let (s, c) = 10f64.to_radians().sin_cos();
    assert!(
        (lf[0] + s).abs() < 1e-12 && (lf[2] + c).abs() < 1e-12,
        "left looks left"
    );
    assert!(
        (rf[0] - s).abs() < 1e-12 && (rf[2] + c).abs() < 1e-12,
        "right looks right"
    );
    // Vertical field of view: 60° main, 80° auxiliary.
    assert!((main.proj.0[1][1] - 1.0 / 30f64.to_radians().tan()).abs() < 1e-12);
    assert!((left.proj.0[1][1] - 1.0 / 40f64.to_radians().tan()).abs() < 1e-12);
}

#[test]
fn disc_overlap_limits() {
    let a = 0.05;
    assert_eq!(disc_overlap(a, 0.1, 0.2), 0.0);
    assert!((disc_overlap(a, 0.1, 0.0) - PI * a * a).abs() < 1e-15);
    // Continuous at both ends of the partial range.
    let inner = disc_overlap(a, 0.1, 0.05 + 1e-9);
    assert!((inner - PI * a * a).abs() < 1e-6);
    assert!(disc_overlap(a, 0.1, 0.15 - 1e-9) < 1e-6);
}
