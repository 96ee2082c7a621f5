//! Tests of glTF loading and placement: a small generated model (a textured quad on a linear
//! translation, a strip skinned to two joints) and, where /work/shared/assets holds them, Fox,
//! CesiumMan and FlightHelmet.

use std::f64::consts::PI;
use std::path::PathBuf;
use std::sync::Arc;

use reproj_core::Camera;

use super::*;
use crate::anim::Anim;
use crate::math::{add, sub, Rigid, V3};
use crate::render::{camera_rays, render_ground_truth, render_server, sample, Rays};
use crate::rig::{mono, CameraPath, HeadPose};
use crate::scene::{Light, Scene, Variant};

const DT: f64 = 0.1;

pub(super) fn base64(data: &[u8]) -> String {
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
pub(super) fn test_dir() -> PathBuf {
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

pub(super) fn empty_scene() -> Scene {
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
    let rays = camera_rays(&cam, "t").unwrap();
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
    let rays = camera_rays(&cam, "t").unwrap();
    let t = 1.0;
    let r = render_server(&scene, &cam, t, DT, 4, 1).unwrap().buffers;
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
    let rays = camera_rays(&cam, "t").unwrap();
    let t = 1.0;
    let r = render_server(&scene, &cam, t, DT, 4, 1).unwrap().buffers;
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
    // A header claiming 16000x16000 pixels (3 GB decoded): refused naming the size, before the
    // decoder's "Memory limit exceeded".
    let huge = write_model("hugetex", "huge.jpg", false);
    let mut jpeg = Vec::new();
    image::RgbImage::new(8, 8)
        .write_to(
            &mut std::io::Cursor::new(&mut jpeg),
            image::ImageFormat::Jpeg,
        )
        .unwrap();
    let sof = jpeg.windows(2).position(|w| w == [0xFF, 0xC0]).unwrap();
    jpeg[sof + 5..sof + 9].copy_from_slice(&[0x3E, 0x80, 0x3E, 0x80]); // height, width 16000
    std::fs::write(huge.parent().unwrap().join("huge.jpg"), jpeg).unwrap();
    check(
        &huge,
        "texture file \"huge.jpg\" is 16000x16000 pixels (3072000000 bytes decoded)",
    );
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
    let moving = f
        .main
        .buffers
        .motion_fwd
        .iter()
        .filter(|m| m.abs() > 1e-5)
        .count();
    let seen = f.main.buffers.depth.iter().filter(|&&z| z > 0.0).count();
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

/// The SHA-256 of the file at `p`, read here (not by the loader).
fn file_sha256(p: &Path) -> String {
    use sha2::Digest;
    let bytes = std::fs::read(p).unwrap();
    sha2::Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// `write_model`'s document as JSON and the bytes of its (data: URI) buffer.
fn model_json_and_bin(model: &Path) -> (gltf::json::Value, Vec<u8>) {
    let json: gltf::json::Value =
        gltf::json::deserialize::from_str(&std::fs::read_to_string(model).unwrap()).unwrap();
    let uri = json["buffers"][0]["uri"].as_str().unwrap();
    let bin = source::base64_decode(uri.split_once(";base64,").unwrap().1).unwrap();
    (json, bin)
}

#[test]
fn recorded_file_digests_are_the_sha256_of_the_files() {
    // The hex form itself, against the standard's value for "abc".
    assert_eq!(
        source::sha256_hex(b"abc"),
        "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
    );
    let model = write_model("digest", "tex.png", false);
    let dir = model.parent().unwrap().to_path_buf();
    let (json, bin) = model_json_and_bin(&model);
    let tex = dir.join("tex.png");
    let png = std::fs::read(&tex).unwrap();
    let data_png = format!("data:image/png;base64,{}", base64(&png));

    // A .gltf with an external .bin (percent-encoded, named by two buffers), its texture, an
    // image no material uses (read for its digest only), a data: image and buffer (not
    // listed), and an unused image whose file is missing (left out: the model still loads).
    let mut doc = json.clone();
    let n = bin.len();
    doc["buffers"] = serde_json_value(&format!(
        r#"[{{"byteLength":{n},"uri":"model%20data.bin"}},
            {{"byteLength":{n},"uri":"model%20data.bin"}},
            {{"byteLength":1,"uri":"data:application/octet-stream;base64,AA=="}}]"#
    ));
    doc["images"] = serde_json_value(&format!(
        r#"[{{"uri":"tex.png"}},{{"uri":"sub/unused.png"}},{{"uri":"{data_png}"}},
            {{"uri":"gone.png"}}]"#
    ));
    std::fs::write(dir.join("model data.bin"), &bin).unwrap();
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    std::fs::write(dir.join("sub/unused.png"), b"not decoded").unwrap();
    let ext = dir.join("external.gltf");
    std::fs::write(&ext, gltf::json::serialize::to_vec(&doc).unwrap()).unwrap();
    let files = GltfModel::load(&ext).unwrap().files;
    let bin_sha = file_sha256(&dir.join("model data.bin"));
    assert_eq!(files.sha256, file_sha256(&ext));
    assert_eq!(
        files.resources,
        [
            bin_sha.clone(),
            bin_sha,
            file_sha256(&tex),
            file_sha256(&dir.join("sub/unused.png"))
        ]
    );

    // A .glb: its BIN chunk is the model file's; its texture is an external file.
    let mut doc = json.clone();
    doc["buffers"] = serde_json_value(&format!(r#"[{{"byteLength":{n}}}]"#));
    let glb = super::hostile::glb_bytes(&doc, &bin);
    let glb_path = dir.join("model.glb");
    std::fs::write(&glb_path, &glb).unwrap();
    let files = GltfModel::load(&glb_path).unwrap().files;
    assert_eq!(files.sha256, file_sha256(&glb_path));
    assert_eq!(files.resources, [file_sha256(&tex)]);

    // Only data: URIs: the model file alone.
    let mut doc = json;
    doc["images"] = serde_json_value(&format!(r#"[{{"uri":"{data_png}"}}]"#));
    let inline = dir.join("inline.gltf");
    std::fs::write(&inline, gltf::json::serialize::to_vec(&doc).unwrap()).unwrap();
    let files = GltfModel::load(&inline).unwrap().files;
    assert_eq!(files.sha256, file_sha256(&inline));
    assert!(files.resources.is_empty(), "{:?}", files.resources);
}

fn serde_json_value(s: &str) -> gltf::json::Value {
    gltf::json::deserialize::from_str(s).unwrap()
}
