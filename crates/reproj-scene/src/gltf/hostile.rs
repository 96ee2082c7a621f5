//! Hostile glTF input (issue 15): one test per reported example, and proptest cases on mutated
//! files (JSON fields, GLB bytes, truncation) with the property "`Ok` or a typed error, never a
//! panic, and at most a bounded allocation proportional to the input".
//!
//! Allocation is measured by a counting global allocator of this test binary: per thread (the
//! test harness runs tests on parallel threads), the peak of live bytes while the measured
//! closure runs.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::PathBuf;
use std::sync::Arc;

use gltf::json::Value;
use proptest::prelude::*;

use super::load::decode;
use super::tests::empty_scene;
use super::*;
use crate::error::SceneError;
use crate::math::Rigid;

struct Counting;

thread_local! {
    static TRACKING: Cell<bool> = const { Cell::new(false) };
    static LIVE: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
}

fn note(delta: isize) {
    // `try_with`: allocations also happen while thread-locals are torn down.
    let _ = TRACKING.try_with(|t| {
        if t.get() {
            let _ = LIVE.try_with(|l| {
                let v = l.get() + delta;
                l.set(v);
                let _ = PEAK.try_with(|p| p.set(p.get().max(v)));
            });
        }
    });
}

// SAFETY: every method forwards to `System` with the caller's arguments unchanged; the counting
// only reads and writes this thread's `Cell`s, which neither allocate nor unwind.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size() as isize);
        // SAFETY: the caller's contract for `alloc` is passed on unchanged.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size() as isize);
        // SAFETY: as `alloc`.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        note(-(layout.size() as isize));
        // SAFETY: `ptr` was allocated by `System` with `layout` (every allocation goes there).
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size as isize - layout.size() as isize);
        // SAFETY: as `dealloc`, and `new_size` comes from the caller's contract.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static COUNTING: Counting = Counting;

/// Runs `f` and returns its result with the peak of bytes it held allocated on this thread.
fn peak_bytes<T>(f: impl FnOnce() -> T) -> (T, usize) {
    LIVE.with(|l| l.set(0));
    PEAK.with(|p| p.set(0));
    TRACKING.with(|t| t.set(true));
    let out = f();
    TRACKING.with(|t| t.set(false));
    (out, PEAK.with(|p| p.get()).max(0) as usize)
}

/// The decode budget's fixed part in these tests (1 MiB instead of 64), so that the allocation
/// bound below is tight enough to catch an allocation driven by a count field.
const TEST_BUDGET_BASE: usize = 1 << 20;

/// Peak bytes allowed to decode an `n`-byte file: the budget (64 per input byte plus the fixed
/// part) plus room for the JSON document's own structures and transient copies.
fn allocation_bound(n: usize) -> usize {
    256 * n + 4 * TEST_BUDGET_BASE
}

/// A small valid model: a triangle (node 0, TRS, translated by an animation), the same
/// triangle skinned to a two-joint chain whose tip rotates (node 1, positions through a sparse
/// accessor without a buffer view), all data in one buffer.
struct Model {
    json: Value,
    bin: Vec<u8>,
}

fn f32s(bin: &mut Vec<u8>, v: &[f32]) -> (usize, usize) {
    let o = bin.len();
    v.iter()
        .for_each(|x| bin.extend_from_slice(&x.to_le_bytes()));
    (o, bin.len() - o)
}

fn bytes(bin: &mut Vec<u8>, v: &[u8]) -> (usize, usize) {
    let o = bin.len();
    bin.extend_from_slice(v);
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    (o, v.len())
}

fn base_model() -> Model {
    let mut bin = Vec::new();
    let h = std::f32::consts::FRAC_1_SQRT_2;
    #[rustfmt::skip]
    let ibm: Vec<f32> = [
        [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 1.0],
    ]
    .concat();
    let views = [
        f32s(&mut bin, &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]),
        bytes(&mut bin, &[0, 0, 1, 0, 2, 0]),
        f32s(&mut bin, &[0.0, 1.0]),
        f32s(&mut bin, &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]),
        f32s(&mut bin, &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, h, h]),
        bytes(&mut bin, &[0, 1, 0, 0, 0, 1, 0, 0, 1, 0, 0, 0]),
        f32s(
            &mut bin,
            &[0.5, 0.5, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        ),
        f32s(&mut bin, &ibm),
        bytes(&mut bin, &[1]),
        f32s(&mut bin, &[2.0, 0.0, 0.0]),
    ];
    let views: Vec<Value> = views
        .iter()
        .map(|&(o, l)| {
            serde_json_value(&format!(
                r#"{{"buffer":0,"byteOffset":{o},"byteLength":{l}}}"#
            ))
        })
        .collect();
    let acc = |view: usize, ct: u32, count: usize, ty: &str| {
        serde_json_value(&format!(
            r#"{{"bufferView":{view},"componentType":{ct},"count":{count},"type":"{ty}"}}"#
        ))
    };
    let mut json = serde_json_value(
        r#"{
  "asset": {"version": "2.0"},
  "scene": 0,
  "scenes": [{"nodes": [0, 1, 2]}],
  "nodes": [
    {"mesh": 0, "translation": [0, 0, 0], "rotation": [0, 0, 0, 1], "scale": [1, 1, 1]},
    {"mesh": 1, "skin": 0},
    {"children": [3]},
    {"translation": [1, 0, 0]}
  ],
  "meshes": [
    {"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]},
    {"primitives": [{"attributes": {"POSITION": 8, "JOINTS_0": 5, "WEIGHTS_0": 6}, "indices": 1}]}
  ],
  "skins": [{"joints": [2, 3], "inverseBindMatrices": 7}],
  "animations": [{"channels": [
      {"sampler": 0, "target": {"node": 0, "path": "translation"}},
      {"sampler": 1, "target": {"node": 3, "path": "rotation"}}],
    "samplers": [{"input": 2, "output": 3}, {"input": 2, "output": 4}]}],
  "buffers": [{"byteLength": 0}]
}"#,
    );
    let mut position = acc(0, 5126, 3, "VEC3");
    position["min"] = serde_json_value("[0, 0, 0]");
    position["max"] = serde_json_value("[1, 1, 0]");
    let mut accessors = vec![
        position,
        acc(1, 5123, 3, "SCALAR"),
        acc(2, 5126, 2, "SCALAR"),
        acc(3, 5126, 2, "VEC3"),
        acc(4, 5126, 2, "VEC4"),
        acc(5, 5121, 3, "VEC4"),
        acc(6, 5126, 3, "VEC4"),
        acc(7, 5126, 2, "MAT4"),
    ];
    accessors.push(serde_json_value(
        r#"{"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[2,0,0],"sparse":{"count":1,
            "indices":{"bufferView":8,"componentType":5121},"values":{"bufferView":9}}}"#,
    ));
    json["accessors"] = Value::Array(accessors);
    json["bufferViews"] = Value::Array(views);
    json["buffers"][0]["byteLength"] = Value::from(bin.len());
    Model { json, bin }
}

fn serde_json_value(s: &str) -> Value {
    gltf::json::deserialize::from_str(s).unwrap()
}

/// A GLB file: header, `json` as its JSON chunk (space-padded), `bin` as its BIN chunk
/// (zero-padded).
pub(super) fn glb_bytes(json: &Value, bin: &[u8]) -> Vec<u8> {
    let mut json = gltf::json::serialize::to_vec(json).unwrap();
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    let mut bin = bin.to_vec();
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

impl Model {
    /// The GLB file of the model ([`glb_bytes`]).
    fn glb(&self) -> Vec<u8> {
        glb_bytes(&self.json, &self.bin)
    }

    /// Sets the value at JSON pointer `ptr`, adding the last key when it is missing.
    fn set(&mut self, ptr: &str, v: Value) {
        let (parent, key) = ptr.rsplit_once('/').unwrap();
        match self.json.pointer_mut(parent) {
            Some(Value::Object(o)) => {
                o.insert(key.to_string(), v);
            }
            Some(Value::Array(a)) => {
                if let Some(slot) = key.parse::<usize>().ok().and_then(|i| a.get_mut(i)) {
                    *slot = v;
                }
            }
            _ => {}
        }
    }
}

fn path() -> PathBuf {
    PathBuf::from("hostile.glb")
}

fn load(bytes: &[u8]) -> Result<GltfModel, SceneError> {
    decode(&path(), bytes, TEST_BUDGET_BASE)
}

fn load_err(m: &Model) -> String {
    match load(&m.glb()) {
        Ok(_) => panic!("expected an error"),
        Err(e) => {
            assert!(matches!(e, SceneError::Gltf { .. }), "{e:?}");
            e.to_string()
        }
    }
}

fn place_err(m: &Model, placement: Placement) -> String {
    let model = Arc::new(load(&m.glb()).unwrap());
    let mut scene = empty_scene();
    let e = place_model(&mut scene, &model, placement).unwrap_err();
    assert!(
        scene.objects.is_empty(),
        "the scene was changed before the error"
    );
    e.to_string()
}

fn assert_names(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "{msg:?} does not contain {p:?}");
    }
    assert!(
        msg.contains("hostile.glb"),
        "{msg:?} does not name the file"
    );
}

#[test]
fn base_model_loads_and_places() {
    let m = base_model();
    let model = Arc::new(load(&m.glb()).unwrap());
    assert_eq!(model.triangle_count(), 2);
    let mut scene = empty_scene();
    assert_eq!(
        place_model(&mut scene, &model, Placement::default()).unwrap(),
        vec![0, 1]
    );
}

#[test]
fn allocation_counter_sees_an_allocation() {
    // The property below relies on the counter; a 10 MB vector must show.
    let ((), peak) = peak_bytes(|| drop(std::hint::black_box(vec![1u8; 10 << 20])));
    assert!(peak >= 10 << 20, "peak {peak}");
}

#[test]
fn byte_stride_smaller_than_the_element() {
    let mut m = base_model();
    m.set("/bufferViews/0/byteStride", 4.into());
    assert_names(
        &load_err(&m),
        &["accessor 0 (POSITION): byteStride 4 is smaller than the element size 12"],
    );
}

#[test]
fn stride_that_runs_past_the_view() {
    let mut m = base_model();
    m.set("/bufferViews/0/byteStride", 16.into());
    assert_names(
        &load_err(&m),
        &[
            "accessor 0 (POSITION): 3 elements of 12 bytes",
            "stride 16 do not fit in buffer view 0 (36 bytes)",
        ],
    );
}

/// Appends `bytes` to the model's buffer as a new buffer view and returns its index.
fn add_view(m: &mut Model, data: &[u8]) -> usize {
    let (o, l) = bytes(&mut m.bin, data);
    let views = m.json["bufferViews"].as_array_mut().unwrap();
    views.push(serde_json_value(&format!(
        r#"{{"buffer":0,"byteOffset":{o},"byteLength":{l}}}"#
    )));
    let index = views.len() - 1;
    m.json["buffers"][0]["byteLength"] = Value::from(m.bin.len());
    index
}

/// The positions mesh `mesh` decoded to.
fn positions(model: &GltfModel, mesh: usize) -> Vec<[f64; 3]> {
    model.meshes[mesh][0]
        .positions
        .iter()
        .map(|p| [p.x, p.y, p.z])
        .collect()
}

#[test]
fn strided_accessor_that_ends_at_its_view_end_loads() {
    // Positions 16 bytes apart with nothing after the last one: 2·16 + 12 = 44 bytes, what
    // the last element needs (not 3·16 = 48).
    let mut m = base_model();
    let want = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let mut data = Vec::new();
    for (k, p) in want.iter().enumerate() {
        data.extend(p.iter().flat_map(|&c| (c as f32).to_le_bytes()));
        if k < 2 {
            data.extend([0xFF; 4]); // another attribute's bytes, interleaved
        }
    }
    assert_eq!(data.len(), 44);
    let view = add_view(&mut m, &data);
    m.set(&format!("/bufferViews/{view}/byteStride"), 16.into());
    m.set("/accessors/0/bufferView", view.into());
    let model = load(&m.glb()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(positions(&model, 0), want);
    // One byte less and the last element does not fit.
    m.set(&format!("/bufferViews/{view}/byteLength"), 43.into());
    assert_names(
        &load_err(&m),
        &[
            "accessor 0 (POSITION): 3 elements of 12 bytes at byteOffset 0 with stride 16 do \
           not fit in buffer view 10 (43 bytes)",
        ],
    );
}

#[test]
fn sparse_counts_and_indices_at_their_limits() {
    // Accessor 8 (3 positions, all zero without a buffer view) with `n` sparse values at
    // `indices`: every element replaced is allowed, as is the last index (count − 1).
    let with = |indices: &[u8]| {
        let mut m = base_model();
        let iv = add_view(&mut m, indices);
        let values: Vec<u8> = (0..indices.len())
            .flat_map(|k| [k as f32 + 1.0, 0.5, 0.0])
            .flat_map(f32::to_le_bytes)
            .collect();
        let vv = add_view(&mut m, &values);
        m.set("/accessors/8/sparse/count", indices.len().into());
        m.set("/accessors/8/sparse/indices/bufferView", iv.into());
        m.set("/accessors/8/sparse/values/bufferView", vv.into());
        m.set("/accessors/8/max", serde_json_value("[3, 0.5, 0]"));
        m
    };
    let model = load(&with(&[0, 1, 2]).glb()).unwrap_or_else(|e| panic!("{e}"));
    let want = [[1.0, 0.5, 0.0], [2.0, 0.5, 0.0], [3.0, 0.5, 0.0]];
    assert_eq!(positions(&model, 1), want);
    let model = load(&with(&[2]).glb()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        positions(&model, 1),
        [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.5, 0.0]]
    );
    assert_names(
        &load_err(&with(&[0, 1, 2, 3])),
        &["accessor 8 (POSITION): sparse count 4, expected 1..=3 (the accessor's count)"],
    );
    for (indices, bad, at) in [
        (&[0u8, 1, 3][..], 3, 2),
        (&[0, 2, 2][..], 2, 2),
        (&[1, 0][..], 0, 1),
    ] {
        assert_names(
            &load_err(&with(indices)),
            &[&format!(
                "accessor 8 (POSITION): sparse index {bad} at position {at}, expected strictly \
                 increasing indices below 3"
            )],
        );
    }
}

#[test]
fn base_colour_texture_on_a_second_uv_set() {
    // Not implemented: refused (before its image is read) rather than drawn with the first
    // set's coordinates.
    let mut m = base_model();
    let texture =
        r#"[{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0, "texCoord": 1}}}]"#;
    m.set("/materials", serde_json_value(texture));
    m.set("/textures", serde_json_value(r#"[{"source": 0}]"#));
    m.set("/images", serde_json_value(r#"[{"uri": "missing.png"}]"#));
    let e = load(&m.glb()).unwrap_err();
    assert!(matches!(e, SceneError::GltfUnsupported { .. }), "{e:?}");
    assert_names(&e.to_string(), &["material 0 uses TEXCOORD_1"]);
}

#[test]
fn one_value_set_is_refused_naming_the_problem() {
    // (JSON pointer, value, what the error must say) on the base model, one case at a time.
    let n = base_model().bin.len();
    let cases = [
        // Accessor 8's one sparse index (1 byte) and value (12 bytes) past their views' end.
        (
            "/accessors/8/sparse/indices/byteOffset",
            "1".to_string(),
            "accessor 8 (POSITION): 1 sparse indices of 1 bytes at byteOffset 1 do not fit in \
             their buffer view (1 bytes)"
                .to_string(),
        ),
        (
            "/accessors/8/sparse/values/byteOffset",
            "4".to_string(),
            "accessor 8 (POSITION): 1 sparse values of 12 bytes at byteOffset 4 do not fit in \
             their buffer view (12 bytes)"
                .to_string(),
        ),
        (
            "/buffers/0/byteLength",
            (n + 4).to_string(),
            format!("buffer 0 holds {n} bytes, the file declares {}", n + 4),
        ),
        (
            "/accessors/1/count",
            "2".to_string(),
            "2 indices is not a multiple of 3".to_string(),
        ),
        // A node that is its own child; a cycle through two nodes gives each one parent, and
        // the walk from the scene's roots finds it.
        (
            "/nodes/2/children",
            "[2]".to_string(),
            "node 2 has more than one parent".to_string(),
        ),
        (
            "/nodes/3/children",
            "[2]".to_string(),
            "node 2 is reached twice (a cycle?)".to_string(),
        ),
        (
            "/accessors/7/count",
            "1".to_string(),
            "skin 0: 1 inverse bind matrices for 2 joints".to_string(),
        ),
        // Sampler 0: 2 key times (accessor 2), its 2 translations (accessor 3) cut to 1.
        (
            "/accessors/3/count",
            "1".to_string(),
            "animation 0 channel 0: 2 key times for 1 values".to_string(),
        ),
        // Channel 1 turns node 3, here given by a matrix (glTF forbids animating one).
        (
            "/nodes/3",
            r#"{"matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 1, 0, 0, 1]}"#.to_string(),
            "animation 0 channel 1 targets node 3, which has a matrix".to_string(),
        ),
        // 1e39 is beyond f32: the factor is read as infinity.
        (
            "/materials",
            r#"[{"pbrMetallicRoughness": {"baseColorFactor": [1, 1e39, 1, 1]}}]"#.to_string(),
            "material 0: baseColorFactor [1.0, inf, 1.0, 1.0], expected finite numbers".to_string(),
        ),
    ];
    for (ptr, value, message) in cases {
        let mut m = base_model();
        m.set(ptr, serde_json_value(&value));
        assert_names(&load_err(&m), &[&message]);
    }
}

#[test]
fn node_with_two_parents() {
    // Node 3, child of node 2 (in the scene), also a child of node 4 (not in the scene, so the
    // walk from the scene's roots would not meet it twice).
    let mut m = base_model();
    m.json["nodes"]
        .as_array_mut()
        .unwrap()
        .push(serde_json_value(r#"{"children": [3]}"#));
    assert_names(&load_err(&m), &["node 3 has more than one parent"]);
}

#[test]
fn animation_key_times_must_increase() {
    let mut m = base_model();
    let times: Vec<u8> = [1.0f32, 0.0]
        .into_iter()
        .flat_map(f32::to_le_bytes)
        .collect();
    let view = add_view(&mut m, &times);
    m.set("/accessors/2/bufferView", view.into());
    assert_names(
        &load_err(&m),
        &["animation 0 channel 0: key times not increasing"],
    );
}

#[test]
fn placement_scale_speed_and_time_offset_must_be_finite() {
    let m = base_model();
    for scale in [0.0, -1.0, f64::INFINITY, f64::NAN] {
        let msg = place_err(
            &m,
            Placement {
                scale,
                ..Placement::default()
            },
        );
        assert_names(
            &msg,
            &[&format!(
                "placement scale {scale}: expected a finite number > 0"
            )],
        );
    }
    for (time_offset, speed) in [(f64::NAN, 1.0), (0.0, f64::INFINITY)] {
        let msg = place_err(
            &m,
            Placement {
                time_offset,
                speed,
                ..Placement::default()
            },
        );
        assert_names(
            &msg,
            &[&format!(
                "placement time offset {time_offset} and speed {speed}: expected finite numbers"
            )],
        );
    }
}

#[test]
fn animation_channel_targeting_a_missing_node() {
    let mut m = base_model();
    m.set("/animations/0/channels/1/target/node", 99.into());
    assert_names(
        &load_err(&m),
        &["animation 0 channel 1 targets node 99, which does not exist (4 nodes)"],
    );
}

#[test]
fn unknown_animation_target_path() {
    let mut m = base_model();
    m.set("/animations/0/channels/0/target/path", "colour".into());
    assert_names(
        &load_err(&m),
        &["animation 0 channel 0: unknown target path"],
    );
}

#[test]
fn huge_placement_scale_is_refused_before_the_bvh() {
    let m = base_model();
    let msg = place_err(
        &m,
        Placement {
            scale: 1e40,
            ..Placement::default()
        },
    );
    assert_names(&msg, &["placed with scale 1e40", "expected at most 1e15 m"]);
    // A placement far from the origin likewise.
    let msg = place_err(
        &m,
        Placement {
            place: Rigid::translation([1e300, 0.0, 0.0]),
            ..Placement::default()
        },
    );
    assert_names(&msg, &["placement translation", "expected at most 1e15 m"]);
}

#[test]
fn huge_node_scale_is_refused() {
    // 1e40 is beyond f32: it reads as infinity.
    let mut m = base_model();
    m.set("/nodes/0/scale/0", 1e40.into());
    assert_names(
        &load_err(&m),
        &["node 0 scale: value inf is not finite or beyond ±1e15"],
    );
    // Finite and large per node, but a chain of them multiplies.
    let mut m = base_model();
    m.set("/nodes/2/scale", serde_json_value("[1e10, 1e10, 1e10]"));
    m.set("/nodes/3/scale", serde_json_value("[1e10, 1e10, 1e10]"));
    let msg = place_err(&m, Placement::default());
    assert_names(
        &msg,
        &["node 1: placed with scale 1", "expected at most 1e15 m"],
    );
}

#[test]
fn sparse_accessor_with_a_huge_count_is_refused_before_allocating() {
    let mut m = base_model();
    m.set("/accessors/8/count", 500_000_000.into());
    let glb = m.glb();
    let (result, peak) = peak_bytes(|| load(&glb));
    let msg = result.unwrap_err().to_string();
    assert_names(
        &msg,
        &["accessor 8 (POSITION) with count 500000000: decoding it needs 24000000000 bytes"],
    );
    assert!(peak <= allocation_bound(glb.len()), "peak {peak} bytes");
}

#[test]
fn glb_header_length_beyond_the_file() {
    let mut glb = base_model().glb();
    glb[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
    let n = glb.len();
    let (result, peak) = peak_bytes(|| load(&glb));
    assert_names(
        &result.unwrap_err().to_string(),
        &[&format!("GLB header length 4294967295, expected 20..={n}")],
    );
    assert!(peak <= allocation_bound(n), "peak {peak} bytes");
    // A chunk length beyond the file.
    let mut glb = base_model().glb();
    glb[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
    assert_names(
        &load(&glb).unwrap_err().to_string(),
        &["GLB chunk 0 at byte 12 declares 4294967295 bytes"],
    );
}

#[test]
fn non_finite_positions() {
    for (bad, shown) in [(f32::NAN, "NaN"), (f32::INFINITY, "inf")] {
        let mut m = base_model();
        m.bin[12..16].copy_from_slice(&bad.to_le_bytes());
        assert_names(
            &load_err(&m),
            &[&format!(
                "accessor 0 (POSITION): element 1 is [{shown}, 0.0, 0.0], expected finite numbers"
            )],
        );
    }
    // Finite but absurd.
    let mut m = base_model();
    m.bin[12..16].copy_from_slice(&1e30f32.to_le_bytes());
    assert_names(
        &load_err(&m),
        &["accessor 0 (POSITION): value 1", "beyond ±1e15"],
    );
}

#[test]
fn position_typed_vec2() {
    let mut m = base_model();
    m.set("/accessors/0/type", "VEC2".into());
    assert_names(
        &load_err(&m),
        &["accessor 0 (POSITION): type VEC2, expected VEC3"],
    );
}

#[test]
fn zero_quaternion() {
    let mut m = base_model();
    m.set("/nodes/0/rotation", serde_json_value("[0, 0, 0, 0]"));
    assert_names(
        &load_err(&m),
        &["node 0: rotation [0.0, 0.0, 0.0, 0.0] has length 0, expected a unit quaternion"],
    );
    // In an animation's output too.
    let mut m = base_model();
    m.bin[76..92].copy_from_slice(&[0; 16]);
    assert_names(
        &load_err(&m),
        &["animation 0 channel 1 output key 0: rotation"],
    );
}

#[test]
fn bad_matrices() {
    let mut m = base_model();
    m.set(
        "/nodes/2/matrix",
        serde_json_value("[1e39, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]"),
    );
    assert_names(&load_err(&m), &["node 2 matrix: value inf is not finite"]);
    let mut m = base_model();
    m.set(
        "/nodes/2/matrix",
        serde_json_value("[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1]"),
    );
    assert_names(
        &load_err(&m),
        &["node 2: matrix is not invertible (determinant 0e0)"],
    );
    let mut m = base_model();
    m.set(
        "/nodes/2/matrix",
        serde_json_value("[1, 0, 0, 5, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]"),
    );
    assert_names(
        &load_err(&m),
        &["node 2: matrix's last row is [5.0, 0.0, 0.0, 1.0]"],
    );
}

#[test]
fn model_without_meshes() {
    let mut m = base_model();
    m.set("/scenes/0/nodes", serde_json_value("[2]"));
    let msg = place_err(&m, Placement::default());
    assert_names(
        &msg,
        &["no mesh node with triangles, expected at least one"],
    );
}

#[test]
fn scene_of_a_model_without_geometry() {
    // load_gltf_scene sizes its camera path by the model's bounds: none to size by is refused
    // before the placement (which would name the mesh nodes instead).
    let mut m = base_model();
    m.set("/scenes/0/nodes", serde_json_value("[2]"));
    let p = super::tests::test_dir().join(format!("reproj-gltf-{}-empty.glb", std::process::id()));
    std::fs::write(&p, m.glb()).unwrap();
    let e = load_gltf_scene(&p).expect_err("expected an error");
    std::fs::remove_file(&p).unwrap();
    let msg = e.to_string();
    assert!(
        msg.contains("the scene has no geometry") && msg.contains("empty.glb"),
        "{msg}"
    );
}

/// The base model with `extra` more nodes (4, 5, ...), each an instance of mesh 0, in no scene.
fn with_mesh_nodes(extra: usize) -> Model {
    let mut m = base_model();
    let nodes = m.json["nodes"].as_array_mut().unwrap();
    nodes.extend((0..extra).map(|_| serde_json_value(r#"{"mesh": 0}"#)));
    m
}

#[test]
fn placement_work_is_bounded() {
    // 5000 mesh nodes under the animated node 0 (and the skinned node 1): each would evaluate the whole hierarchy at
    // every key time; a file of a few hundred kilobytes asks for that.
    let extra = 5000;
    let mut m = with_mesh_nodes(extra);
    m.json["nodes"][0]["children"] = Value::from((4..4 + extra).collect::<Vec<usize>>());
    let msg = place_err(&m, Placement::default());
    assert_names(
        &msg,
        &["5002 animated mesh nodes", "expected at most 200000000"],
    );
}

#[test]
fn placed_objects_are_bounded() {
    // 4095 still mesh nodes beside nodes 0 and 1, in the rest pose (no hierarchy work to
    // bound): each would be an object posed at every instant the renderer takes.
    let extra = 4095;
    let mut m = with_mesh_nodes(extra);
    m.json["scenes"][0]["nodes"] = Value::from((0..4 + extra).collect::<Vec<usize>>());
    m.json["scenes"][0]["nodes"]
        .as_array_mut()
        .unwrap()
        .remove(3); // node 3: node 2's child
    let rest = Placement {
        animation: None,
        ..Placement::default()
    };
    let msg = place_err(&m, rest);
    assert_names(
        &msg,
        &["4097 mesh nodes to place beside the scene's 0 objects, expected at most 4096"],
    );
    // One fewer fits.
    m.json["scenes"][0]["nodes"].as_array_mut().unwrap().pop();
    let model = Arc::new(load(&m.glb()).unwrap());
    let placed = place_model(&mut empty_scene(), &model, rest).unwrap();
    assert_eq!(placed.len(), 4096);
}

#[test]
fn negative_skin_weights() {
    let mut m = base_model();
    let at = 124; // WEIGHTS_0 view (bytes 120..168): vertex 0, weight 1
    m.bin[at..at + 4].copy_from_slice(&(-0.5f32).to_le_bytes());
    assert_names(
        &load_err(&m),
        &["WEIGHTS_0 of vertex 0", "expected non-negative weights"],
    );
}

#[test]
fn non_regular_files_are_refused() {
    // /dev/zero reports a size of 0 and never ends; a directory cannot be read as a file.
    for p in ["/dev/zero", env!("CARGO_MANIFEST_DIR")] {
        let e = GltfModel::load(p).unwrap_err().to_string();
        assert!(e.contains("is not a regular file"), "{e}");
    }
}

#[test]
fn uris_with_a_scheme_are_refused() {
    for uri in ["http://example.com/x.bin", "file:x.bin", "C:x.bin"] {
        let mut m = base_model();
        m.set("/buffers/0/uri", uri.into());
        assert_names(
            &load_err(&m),
            &[&format!(
                "URI {uri:?}: expected a relative path or a data: URI"
            )],
        );
    }
}

#[test]
fn read_file_takes_at_most_its_cap() {
    let p = super::tests::test_dir().join(format!("reproj-gltf-{}-cap.bin", std::process::id()));
    std::fs::write(&p, [7u8; 10]).unwrap();
    let model = PathBuf::from("m.gltf");
    let whole = super::source::read_file(&model, &p, "buffer 0", 10);
    let over = super::source::read_file(&model, &p, "buffer 0", 9);
    std::fs::remove_file(&p).unwrap();
    assert_eq!(whole.unwrap(), vec![7u8; 10]);
    let e = over.unwrap_err().to_string();
    assert!(
        e.contains("m.gltf") && e.contains("cap.bin is larger than the limit of 9 bytes"),
        "{e}"
    );
}

#[test]
fn glb_of_another_version() {
    let mut glb = base_model().glb();
    glb[4..8].copy_from_slice(&1u32.to_le_bytes());
    assert_names(
        &load(&glb).unwrap_err().to_string(),
        &["GLB version 1, expected 2"],
    );
}

#[test]
fn json_document_that_is_not_an_object() {
    for text in [&b"[1, 2]"[..], b" 3", b"null"] {
        assert_names(
            &load(text).unwrap_err().to_string(),
            &["malformed glTF: expected a JSON object"],
        );
    }
}

#[test]
fn absolute_uris_are_refused() {
    // `base.join` of an absolute URI, plain or percent-encoded, discarded the model's folder and
    // read any file on the machine: this one, which lies outside the folder, loaded.
    let dir = super::tests::test_dir().join(format!("reproj-gltf-{}-uris", std::process::id()));
    let models = dir.join("models");
    std::fs::create_dir_all(&models).unwrap();
    let m = base_model();
    let shared = dir.join("shared.bin");
    std::fs::write(&shared, &m.bin).unwrap();
    let write = |uri: &str| {
        let mut json = m.json.clone();
        json["buffers"][0]["uri"] = Value::from(uri);
        let p = models.join("model.gltf");
        std::fs::write(&p, gltf::json::serialize::to_vec(&json).unwrap()).unwrap();
        p
    };
    // Real assets share files through "..": a relative path still reads outside the folder.
    for uri in [
        "../shared.bin",
        "..%2Fshared.bin",
        "../models/../shared.bin",
    ] {
        GltfModel::load(write(uri)).unwrap_or_else(|e| panic!("{uri}: {e}"));
    }
    let absolute = std::fs::canonicalize(&shared).unwrap();
    let plain = absolute.to_str().unwrap().to_string();
    let encoded = plain.replace('/', "%2F");
    assert!(
        plain.starts_with('/') && encoded.starts_with("%2F"),
        "{plain}"
    );
    // Windows roots, drives and UNC names are refused on every host, where they would be
    // absolute (written with %5C and %3A: a raw ':' is refused as a scheme).
    let windows = [
        "%5Cshared.bin",
        "C%3Ashared.bin",
        "c%3A%5Cx.bin",
        "%5C%5Cserver%5Cshare%5Cx.bin",
        "//server/share/x.bin",
    ];
    for uri in [plain.as_str(), encoded.as_str()]
        .into_iter()
        .chain(windows)
    {
        let p = write(uri);
        let e = GltfModel::load(&p).unwrap_err();
        assert!(matches!(e, SceneError::Gltf { .. }), "{uri}: {e:?}");
        let msg = e.to_string();
        for part in [
            p.display().to_string(),
            format!("URI {uri:?}"),
            "is an absolute path, expected a relative path or a data: URI".to_string(),
        ] {
            assert!(msg.contains(&part), "{msg:?} does not contain {part:?}");
        }
    }
    let e = GltfModel::load(write(&encoded)).unwrap_err().to_string();
    assert!(e.contains(&format!("(decoded {plain:?})")), "{e}");
}

#[test]
fn required_extensions_are_unsupported_not_malformed() {
    // The document's validation refused an extension the `gltf` crate does not know first, as
    // "malformed glTF: invalid glTF: extensionsRequired[0] = ...: Unsupported extension".
    for ext in [
        "KHR_draco_mesh_compression",
        "EXT_meshopt_compression",
        "FOO_bar",
    ] {
        let mut m = base_model();
        m.set("/extensionsRequired", Value::from(vec![ext]));
        m.set("/extensionsUsed", Value::from(vec![ext]));
        let e = load(&m.glb()).unwrap_err();
        assert!(matches!(e, SceneError::GltfUnsupported { .. }), "{e:?}");
        let msg = e.to_string();
        assert_names(
            &msg,
            &[&format!(
                "required extension {ext} (the renderer implements none)"
            )],
        );
        assert!(!msg.contains("malformed"), "{msg}");
    }
}

#[test]
fn models_of_a_scene_share_the_fixed_allowance() {
    // Each load had its own 64 MiB on top of 64 bytes per input byte: a scene description
    // placing one 738-byte file 10 times held 0.9 GB, 4,000 times would have held hundreds.
    let mut m = base_model();
    // Mesh 0's positions: 99,999 of them, all but one zero (no buffer view, one sparse value).
    let mut big = m.json["accessors"][8].clone();
    big["count"] = 99_999.into();
    m.json["accessors"].as_array_mut().unwrap().push(big);
    m.set("/meshes/0/primitives/0/attributes/POSITION", 9.into());
    let dir = super::tests::test_dir().join(format!("reproj-gltf-{}-share", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("sparse.glb");
    std::fs::write(&p, m.glb()).unwrap();
    let mut allowance = GLTF_ALLOWANCE;
    GltfModel::load_sharing(&p, &mut allowance).unwrap();
    let used = GLTF_ALLOWANCE - allowance;
    assert!(used > 99_999 * 3 * 8, "used {used}");
    // Exactly what it takes, then nothing left for a second one.
    let mut allowance = used;
    GltfModel::load_sharing(&p, &mut allowance).unwrap();
    assert_eq!(allowance, 0);
    let e = GltfModel::load_sharing(&p, &mut allowance).unwrap_err();
    assert!(matches!(e, SceneError::Gltf { .. }), "{e:?}");
    let msg = e.to_string();
    assert!(
        msg.contains("sparse.glb") && msg.contains("a fixed allowance the models of a scene share"),
        "{msg}"
    );
    GltfModel::load(&p).unwrap(); // alone, as before
}

/// JSON fields the mutations rewrite: every count, offset, stride, length, type and index kind
/// the loader reads.
const FIELDS: &[&str] = &[
    "/accessors/0/count",
    "/accessors/1/count",
    "/accessors/2/count",
    "/accessors/4/count",
    "/accessors/7/count",
    "/accessors/8/count",
    "/accessors/0/byteOffset",
    "/accessors/1/byteOffset",
    "/accessors/5/byteOffset",
    "/accessors/0/componentType",
    "/accessors/1/componentType",
    "/accessors/4/componentType",
    "/accessors/6/componentType",
    "/accessors/0/type",
    "/accessors/7/type",
    "/accessors/0/bufferView",
    "/accessors/3/bufferView",
    "/accessors/4/normalized",
    "/accessors/8/sparse/count",
    "/accessors/8/sparse/indices/byteOffset",
    "/accessors/8/sparse/indices/componentType",
    "/accessors/8/sparse/values/byteOffset",
    "/accessors/8/sparse/values/bufferView",
    "/bufferViews/0/byteStride",
    "/bufferViews/5/byteStride",
    "/bufferViews/0/byteOffset",
    "/bufferViews/0/byteLength",
    "/bufferViews/7/byteLength",
    "/bufferViews/9/byteOffset",
    "/buffers/0/byteLength",
    "/buffers/0/uri",
    "/nodes/0/translation/0",
    "/nodes/0/rotation/3",
    "/nodes/0/scale/1",
    "/nodes/2/matrix",
    "/nodes/3/translation/2",
    "/nodes/2/children/0",
    "/nodes/3/children",
    "/nodes/1/skin",
    "/skins/0/joints/1",
    "/skins/0/inverseBindMatrices",
    "/meshes/0/primitives/0/indices",
    "/meshes/0/primitives/0/mode",
    "/meshes/1/primitives/0/attributes/POSITION",
    "/animations/0/channels/0/target/node",
    "/animations/0/channels/1/target/path",
    "/animations/0/channels/0/sampler",
    "/animations/0/samplers/0/input",
    "/animations/0/samplers/1/output",
    "/animations/0/samplers/0/interpolation",
    "/scene",
    "/scenes/0/nodes/0",
];

/// Values the mutations write: boundaries of the integer widths, counts that would demand
/// gigabytes, magnitudes beyond `f32`, wrong kinds.
fn value(k: usize) -> Value {
    let list = [
        "0",
        "1",
        "2",
        "3",
        "4",
        "5",
        "11",
        "12",
        "13",
        "16",
        "255",
        "256",
        "65535",
        "65536",
        "2147483648",
        "4294967295",
        "500000000",
        "1099511627776",
        "-1",
        "0.5",
        "1e40",
        "-1e20",
        "1e-40",
        "null",
        "true",
        "\"VEC2\"",
        "\"MAT4\"",
        "\"STEP\"",
        "\"CUBICSPLINE\"",
        "\"scale\"",
        "\"x.bin\"",
        "\"data:,abc\"",
        "\"%FF\"",
        "[]",
        "[0]",
        "[1e39,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]",
        "[0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,1]",
        "5120",
        "5121",
        "5122",
        "5123",
        "5125",
        "5126",
    ];
    serde_json_value(list[k % list.len()])
}

#[derive(Debug, Clone)]
enum ByteEdit {
    /// XOR a byte at a position (modulo the length).
    Flip(usize, u8),
    /// Overwrite the aligned `u32` at a position with one of the interesting values.
    Word(usize, u32),
    /// Keep only a prefix of this length (modulo the length).
    Truncate(usize),
}

fn byte_edit() -> impl Strategy<Value = ByteEdit> {
    let words = prop::sample::select(vec![
        0,
        1,
        3,
        4,
        12,
        20,
        255,
        65535,
        1 << 31,
        u32::MAX,
        500_000_000,
    ]);
    prop_oneof![
        (any::<usize>(), 1..=255u8).prop_map(|(p, x)| ByteEdit::Flip(p, x)),
        (any::<usize>(), words).prop_map(|(p, w)| ByteEdit::Word(p, w)),
        any::<usize>().prop_map(ByteEdit::Truncate),
    ]
}

/// 256 cases from a fixed seed by default (reproducible in CI); with `PROPTEST_CASES` set, that
/// many cases drawn afresh each run (or from `PROPTEST_RNG_SEED`): the longer profile.
fn config() -> ProptestConfig {
    let from_env = ProptestConfig::default();
    if std::env::var_os("PROPTEST_CASES").is_some() {
        return from_env;
    }
    ProptestConfig {
        cases: 256,
        rng_seed: proptest::test_runner::RngSeed::Fixed(15),
        ..from_env
    }
}

/// Decodes `bytes` under the allocation counter and, when it loads, places it into a scene
/// (which builds the BVH): any panic fails the case, and so does a peak allocation beyond the
/// bound or an error that is not one of the glTF variants.
fn check(bytes: &[u8]) -> Result<(), TestCaseError> {
    let (result, peak) = peak_bytes(|| load(bytes));
    prop_assert!(
        peak <= allocation_bound(bytes.len()),
        "{peak} bytes allocated for a {}-byte input (bound {})",
        bytes.len(),
        allocation_bound(bytes.len())
    );
    match result {
        Ok(model) => {
            let mut scene = empty_scene();
            if let Err(e) = place_model(&mut scene, &Arc::new(model), Placement::default()) {
                prop_assert!(
                    matches!(
                        e,
                        SceneError::Gltf { .. } | SceneError::GltfUnsupported { .. }
                    ),
                    "{e:?}"
                );
            }
        }
        Err(e) => {
            prop_assert!(
                matches!(
                    e,
                    SceneError::Gltf { .. } | SceneError::GltfUnsupported { .. }
                ),
                "{e:?}"
            );
            prop_assert!(!e.to_string().contains("panicked"), "{e}");
        }
    }
    Ok(())
}

fn apply(glb: &mut Vec<u8>, edits: &[ByteEdit]) {
    for e in edits {
        if glb.is_empty() {
            return;
        }
        match *e {
            ByteEdit::Flip(p, x) => {
                let n = glb.len();
                glb[p % n] ^= x;
            }
            ByteEdit::Word(p, w) => {
                let at = (p % glb.len()) & !3;
                if at + 4 <= glb.len() {
                    glb[at..at + 4].copy_from_slice(&w.to_le_bytes());
                }
            }
            ByteEdit::Truncate(p) => {
                let n = glb.len();
                glb.truncate(p % (n + 1));
            }
        }
    }
}

proptest! {
    #![proptest_config(config())]

    /// JSON fields rewritten (then written as GLB, sometimes with byte edits on top).
    #[test]
    fn mutated_fields_never_panic_or_overallocate(
        fields in prop::collection::vec((0..FIELDS.len(), 0..64usize), 1..4),
        edits in prop::collection::vec(byte_edit(), 0..2),
        as_gltf in any::<bool>(),
    ) {
        let mut m = base_model();
        for &(f, v) in &fields {
            m.set(FIELDS[f], value(v));
        }
        let mut bytes = if as_gltf {
            // The same document as a .gltf file: the buffer as a data URI.
            let mut json = m.json.clone();
            json["buffers"][0]["uri"] = Value::from(format!(
                "data:application/octet-stream;base64,{}",
                super::tests::base64(&m.bin)
            ));
            gltf::json::serialize::to_vec(&json).unwrap()
        } else {
            m.glb()
        };
        apply(&mut bytes, &edits);
        check(&bytes)?;
    }

    /// Raw byte edits of the GLB file: bit flips, length and count words, truncation.
    #[test]
    fn mutated_bytes_never_panic_or_overallocate(
        edits in prop::collection::vec(byte_edit(), 1..5),
    ) {
        let mut glb = base_model().glb();
        apply(&mut glb, &edits);
        check(&glb)?;
    }
}
