//! Bindings of `reproj-scene`, the reference server renderer: the built-in scenes, their server
//! frames (every buffer of the three rig cameras) and ground-truth client frames.
//!
//! Building a scene (meshes, their BVHs) is not free, so a [`Scene`] object holds one and every
//! render is a method on it. Poses cross the boundary as `float64[4, 4]` camera-to-world rigid
//! matrices (the camera looks along its −z), so that Python can drive the rig with any client
//! motion (recorded head traces) while the rig itself stays in Rust.

use numpy::PyArray2;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use reproj_core::memory::{pixels, server_buffers_bytes};
use reproj_core::{Camera, Mat4};
use reproj_scene::{self as rs, HeadPose, Rigid, SceneError, ServerBuffers, Variant};

use crate::api::{camera_items, mat, put_buffers, rgb};
use crate::convert;
use crate::errors::invalid;
use crate::guarded;
use crate::memory::reserve;

/// Maps a renderer error onto the hierarchy. Every variant is listed (no wildcard) so that a new
/// variant has to be mapped deliberately. Arguments and scene files (glTF, bad or unsupported)
/// are caller input, so every variant is an `InvalidInputError`; the message names the file.
fn map_scene_error(e: SceneError) -> PyErr {
    let msg = e.to_string();
    match e {
        SceneError::UnknownScene { .. }
        | SceneError::UnknownVariant { .. }
        | SceneError::BadSubframes { .. }
        | SceneError::BadSamples { .. }
        | SceneError::BadScale { .. }
        | SceneError::BadTime { .. }
        | SceneError::BadCamera { .. }
        | SceneError::BadHierarchy { .. }
        | SceneError::BadPath { .. }
        | SceneError::Changed { .. }
        | SceneError::Gltf { .. }
        | SceneError::GltfUnsupported { .. } => invalid(msg),
    }
}

fn rate(v: f64, what: &str) -> PyResult<f64> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(invalid(format!(
            "{what}: expected a finite float > 0, got {v}"
        )))
    }
}

/// Frame indices stay below 2^31 so that `index / rate` is exact enough and never overflows.
fn index(v: i64, what: &str) -> PyResult<usize> {
    match usize::try_from(v) {
        Ok(i) if v < (1 << 31) => Ok(i),
        _ => Err(invalid(format!(
            "{what}: expected an int in [0, 2^31), got {v}"
        ))),
    }
}

/// Colour sub-samples per pixel side for a `width×height` camera: `v`, checked, or the renderer's
/// default for that size when `None`.
fn samples(v: Option<i64>, width: usize, height: usize) -> PyResult<usize> {
    match v {
        None => Ok(rs::default_samples(width, height)),
        Some(n) => match usize::try_from(n) {
            Ok(s) if (1..=rs::MAX_SAMPLES).contains(&s) => Ok(s),
            _ => Err(invalid(format!(
                "samples: expected 1..={} per pixel side or None, got {n}",
                rs::MAX_SAMPLES
            ))),
        },
    }
}

/// A camera-to-world matrix as a 4×4 array.
fn pose_matrix<'py>(py: Python<'py>, p: &HeadPose) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let r = &p.0;
    let m = Mat4([
        [r.rot[0][0], r.rot[0][1], r.rot[0][2], r.trans[0]],
        [r.rot[1][0], r.rot[1][1], r.rot[1][2], r.trans[1]],
        [r.rot[2][0], r.rot[2][1], r.rot[2][2], r.trans[2]],
        [0.0, 0.0, 0.0, 1.0],
    ]);
    mat(py, &m)
}

/// A camera-to-world pose from a 4×4 matrix: finite, last row `[0, 0, 0, 1]`, and an orthonormal
/// right-handed rotation (to 1e-6), since the rig moves cameras in the pose's own frame.
fn head_pose(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<HeadPose> {
    let m = convert::matrix(obj, what)?;
    let bad = |why: &str| {
        invalid(format!(
            "{what}: expected a rigid camera-to-world matrix, {why}"
        ))
    };
    if !m.0.iter().flatten().all(|v| v.is_finite()) {
        return Err(bad("got non-finite values"));
    }
    if m.0[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(bad(&format!(
            "last row must be [0, 0, 0, 1], got {:?}",
            m.0[3]
        )));
    }
    let rot = [
        [m.0[0][0], m.0[0][1], m.0[0][2]],
        [m.0[1][0], m.0[1][1], m.0[1][2]],
        [m.0[2][0], m.0[2][1], m.0[2][2]],
    ];
    for a in 0..3 {
        for b in 0..3 {
            let d: f64 = (0..3).map(|k| rot[k][a] * rot[k][b]).sum();
            let want = if a == b { 1.0 } else { 0.0 };
            if (d - want).abs() > 1e-6 {
                return Err(bad("its 3×3 rotation is not orthonormal"));
            }
        }
    }
    let det = rot[0][0] * (rot[1][1] * rot[2][2] - rot[1][2] * rot[2][1])
        - rot[0][1] * (rot[1][0] * rot[2][2] - rot[1][2] * rot[2][0])
        + rot[0][2] * (rot[1][0] * rot[2][1] - rot[1][1] * rot[2][0]);
    if det < 0.0 {
        return Err(bad("its rotation is a reflection (determinant −1)"));
    }
    Ok(HeadPose(Rigid {
        rot,
        trans: [m.0[0][3], m.0[1][3], m.0[2][3]],
    }))
}

/// One camera's buffers as the dict documented on [`Scene::render_server_frame`].
fn buffers_dict(py: Python<'_>, b: ServerBuffers) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("view", mat(py, &b.view)?)?;
    d.set_item("proj", mat(py, &b.proj)?)?;
    put_buffers(py, b.buffers, &d)?;
    Ok(d)
}

/// The names of the built-in scenes.
#[pyfunction]
pub fn scene_names() -> Vec<&'static str> {
    rs::SCENE_NAMES.to_vec()
}

/// The renderer's default colour sub-samples per pixel side for a `width×height` camera (3 up to
/// 640×360 pixels, 2 above).
#[pyfunction]
pub fn default_samples(width: usize, height: usize) -> usize {
    rs::default_samples(width, height)
}

/// One glTF placement: `(path, position, yaw_deg, scale, animation, time_offset, speed)`.
type ModelSpec = (String, [f64; 3], f64, f64, Option<usize>, f64, f64);

/// A built-in scene of the reference renderer, built once (meshes and their BVHs) and rendered
/// by its methods with the GIL released.
#[pyclass(module = "splitrender._native", frozen)]
#[derive(Debug)]
pub struct Scene {
    inner: rs::Scene,
    /// What each placed model was loaded from, in the order placed.
    files: Vec<rs::gltf::ModelFiles>,
}

impl Scene {
    /// `pose` read as a camera-to-world matrix, or `fallback` when `None`.
    fn pose_or(&self, pose: Option<&Bound<'_, PyAny>>, fallback: HeadPose) -> PyResult<HeadPose> {
        match pose {
            Some(p) => head_pose(p, "pose"),
            None => Ok(fallback),
        }
    }
}

#[pymethods]
impl Scene {
    /// Builds the built-in scene `name` (`scene_names()`) in `variant` (`"static"` or
    /// `"dynamic"`).
    ///
    /// `models` places glTF 2.0 models into it, each as `(path, position, yaw_deg, scale,
    /// animation, time_offset, speed)`: the model is scaled, turned by `yaw_deg` about +y and
    /// moved to `position`; `animation` is the index of the glTF animation to play (`None`: rest
    /// pose), starting at `time_offset` seconds of model time and running at `speed`.
    #[new]
    #[pyo3(signature = (name, variant = "dynamic", models = None))]
    fn new(
        py: Python<'_>,
        name: &str,
        variant: &str,
        models: Option<Vec<ModelSpec>>,
    ) -> PyResult<Scene> {
        guarded("Scene", || {
            let variant = Variant::parse(variant).map_err(map_scene_error)?;
            let models = models.unwrap_or_default();
            for (i, m) in models.iter().enumerate() {
                let what = format!("models[{i}]");
                for v in [m.1[0], m.1[1], m.1[2], m.2, m.5, m.6] {
                    convert::finite(v, &what)?;
                }
                if !(m.3 > 0.0 && m.3.is_finite()) {
                    return Err(invalid(format!(
                        "{what}: scale must be a finite value > 0, got {}",
                        m.3
                    )));
                }
                if !(m.6 > 0.0) {
                    return Err(invalid(format!("{what}: speed must be > 0, got {}", m.6)));
                }
            }
            let (inner, files) = py
                .detach(|| {
                    let mut scene = rs::builtin(name, variant)?;
                    let mut files = Vec::with_capacity(models.len());
                    // One fixed decode allowance for all the models (GltfModel::load_sharing).
                    let mut allowance = rs::GLTF_ALLOWANCE;
                    for (path, position, yaw_deg, scale, animation, time_offset, speed) in &models {
                        let place = Rigid::translation(*position)
                            .then(&Rigid::rotation([0.0, 1.0, 0.0], yaw_deg.to_radians()));
                        let placement = rs::Placement {
                            place,
                            scale: *scale,
                            animation: *animation,
                            time_offset: *time_offset,
                            speed: *speed,
                        };
                        let model = rs::GltfModel::load_sharing(path, &mut allowance)?;
                        files.push(model.files.clone());
                        rs::place_model(&mut scene, &std::sync::Arc::new(model), placement)?;
                    }
                    Ok((scene, files))
                })
                .map_err(map_scene_error)?;
            Ok(Scene { inner, files })
        })
    }

    /// Scene name.
    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }

    /// `"static"` or `"dynamic"`.
    #[getter]
    fn variant(&self) -> &'static str {
        self.inner.variant.name()
    }

    /// What each placed model was loaded from, in the order placed: `(sha256, resources)`, the
    /// SHA-256 (64 lower-case hex digits) of the model file's bytes and of each file its glTF
    /// document references by a relative URI (`buffers`, then `images`, in the document's
    /// order), of the bytes read when this scene was built (`reproj_scene::gltf::ModelFiles`).
    #[getter]
    fn model_files(&self) -> Vec<(String, Vec<String>)> {
        self.files
            .iter()
            .map(|f| (f.sha256.clone(), f.resources.clone()))
            .collect()
    }

    /// Length of the animation and the head-box path (seconds).
    #[getter]
    fn duration(&self) -> f64 {
        self.inner.duration
    }

    /// Near plane of every camera (metres).
    #[getter]
    fn near(&self) -> f64 {
        self.inner.near
    }

    /// Far plane of every camera (metres).
    #[getter]
    fn far(&self) -> f64 {
        self.inner.far
    }

    /// Main camera size `(width, height)` at `scale`: `round(2560·scale) × round(1440·scale)`.
    fn main_size(&self, scale: f64) -> PyResult<(usize, usize)> {
        guarded("Scene.main_size", || {
            rs::main_size(scale).map_err(map_scene_error)
        })
    }

    /// The rig's camera sizes at `scale`, `[main, left, right]` as `(width, height)`: the main
    /// camera of `main_size` and the auxiliary cameras of half its sides, rounded down, at
    /// least 1.
    fn camera_sizes(&self, scale: f64) -> PyResult<[(usize, usize); 3]> {
        guarded("Scene.camera_sizes", || {
            rs::camera_sizes(scale).map_err(map_scene_error)
        })
    }

    /// The head box's camera-to-world pose at `t` (no anchor deviation).
    fn head_box<'py>(&self, py: Python<'py>, t: f64) -> PyResult<Bound<'py, PyArray2<f64>>> {
        guarded("Scene.head_box", || {
            let t = convert::finite(t, "t")?;
            pose_matrix(py, &self.inner.path.head_box(t))
        })
    }

    /// The client's actual (anchor) camera-to-world pose at `t`.
    fn client_pose<'py>(&self, py: Python<'py>, t: f64) -> PyResult<Bound<'py, PyArray2<f64>>> {
        guarded("Scene.client_pose", || {
            let t = convert::finite(t, "t")?;
            pose_matrix(py, &self.inner.path.client_pose(t))
        })
    }

    /// The predicted camera-to-world pose the server renders frame `k` at (rate `fs`): the head
    /// box at `k / fs` with the anchor's deviation of 100 ms earlier.
    fn server_pose<'py>(
        &self,
        py: Python<'py>,
        k: i64,
        fs: f64,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        guarded("Scene.server_pose", || {
            let k = index(k, "k")?;
            let fs = rate(fs, "fs")?;
            pose_matrix(py, &self.inner.path.server_pose(k, fs))
        })
    }

    /// Every buffer of server frame `k` (time `k / fs`) at `scale`, with `subframes` shadow
    /// subframes, rendered at `pose` (camera-to-world 4×4) or, when `None`, at the scene's own
    /// predicted pose. Colour (and `S_min`/`S_max`) is the mean of `samples × samples`
    /// sub-samples per pixel, `None` = the renderer's default for each camera's size (3 up to
    /// 640×360, 2 above); geometry is sampled at the pixel centre. Returns `{"index", "time",
    /// "pose", "main", "aux": [left, right]}`, each camera a dict with `view`, `proj`, `width`,
    /// `height`, `color`, `depth`, `motion_fwd`, `motion_bwd`, `shadow_{fwd,bwd}_{bits,min,max}`.
    #[pyo3(signature = (k, scale, fs = 10.0, subframes = 4, pose = None, samples = None))]
    #[allow(clippy::too_many_arguments)]
    fn render_server_frame<'py>(
        &self,
        py: Python<'py>,
        k: i64,
        scale: f64,
        fs: f64,
        subframes: i64,
        pose: Option<&Bound<'py, PyAny>>,
        samples: Option<i64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        guarded("Scene.render_server_frame", || {
            let k = index(k, "k")?;
            let fs = rate(fs, "fs")?;
            let s = convert::subframes(subframes)?;
            let (w, h) = rs::main_size(scale).map_err(map_scene_error)?;
            let scene = &self.inner;
            let pose = self.pose_or(pose, scene.path.server_pose(k, fs))?;
            let t = k as f64 / fs;
            let rig = rs::rig(&pose, w, h, scene.near, scene.far);
            let n_main = self::samples(samples, rig.main.width, rig.main.height)?;
            let n_aux = self::samples(samples, rig.aux[0].width, rig.aux[0].height)?;
            let aux_bytes = server_buffers_bytes(pixels(&rig.aux[0]));
            reserve(
                server_buffers_bytes(pixels(&rig.main)) + 2 * aux_bytes,
                || {
                    format!(
                    "Scene.render_server_frame: a {w}x{h} server frame and two {}x{} auxiliary \
                     cameras (scale {scale})",
                    rig.aux[0].width, rig.aux[0].height
                )
                },
            )?;
            let (main, aux) = py
                .detach(|| -> rs::Result<_> {
                    let one = |c: &Camera, n| rs::render_server(scene, c, t, 1.0 / fs, s, n);
                    Ok((
                        one(&rig.main, n_main)?,
                        [one(&rig.aux[0], n_aux)?, one(&rig.aux[1], n_aux)?],
                    ))
                })
                .map_err(map_scene_error)?;
            let d = PyDict::new(py);
            d.set_item("index", k)?;
            d.set_item("time", t)?;
            d.set_item("pose", pose_matrix(py, &pose)?)?;
            d.set_item("main", buffers_dict(py, main)?)?;
            let [a0, a1] = aux;
            let aux = PyList::new(py, [buffers_dict(py, a0)?, buffers_dict(py, a1)?])?;
            d.set_item("aux", aux)?;
            Ok(d)
        })
    }

    /// Ground truth of client frame `n` (time `n / fc`) at the main camera's size for `scale`:
    /// one `(view, proj, width, height, color)` per eye (`[left, right]` when `stereo`, IPD 7 cm),
    /// at `pose` (camera-to-world 4×4) or, when `None`, at the client's actual pose; colour from
    /// `samples × samples` sub-samples per pixel as [`Scene::render_server_frame`]'s main camera.
    #[pyo3(signature = (n, scale, fc = 120.0, stereo = false, pose = None, samples = None))]
    #[allow(clippy::too_many_arguments)]
    fn render_client_frame<'py>(
        &self,
        py: Python<'py>,
        n: i64,
        scale: f64,
        fc: f64,
        stereo: bool,
        pose: Option<&Bound<'py, PyAny>>,
        samples: Option<i64>,
    ) -> PyResult<Bound<'py, PyList>> {
        guarded("Scene.render_client_frame", || {
            let n = index(n, "n")?;
            let fc = rate(fc, "fc")?;
            let (w, h) = rs::main_size(scale).map_err(map_scene_error)?;
            let ns = self::samples(samples, w, h)?;
            let scene = &self.inner;
            let t = n as f64 / fc;
            let pose = self.pose_or(pose, scene.path.client_pose(t))?;
            let cams = if stereo {
                rs::stereo(&pose, w, h, scene.near, scene.far).to_vec()
            } else {
                vec![rs::mono(&pose, w, h, scene.near, scene.far)]
            };
            reserve(cams.iter().map(rs::truth_bytes).sum(), || {
                format!(
                    "Scene.render_client_frame: {} {w}x{h} image(s) (scale {scale})",
                    cams.len()
                )
            })?;
            let images = py
                .detach(|| {
                    cams.iter()
                        .map(|c| rs::render_ground_truth(scene, c, t, ns))
                        .collect::<rs::Result<Vec<_>>>()
                })
                .map_err(map_scene_error)?;
            let eyes = cams
                .iter()
                .zip(images)
                .map(|(c, img)| {
                    let mut items = camera_items(py, c)?;
                    items.push(rgb(py, img, c.height, c.width)?.into_any());
                    PyTuple::new(py, items)
                })
                .collect::<PyResult<Vec<_>>>()?;
            PyList::new(py, eyes)
        })
    }

    /// Ground-truth RGB8 image at any client camera and time `t`, colour from `samples ×
    /// samples` sub-samples per pixel (`None`: the default for the camera's size).
    #[pyo3(signature = (view, proj, width, height, t, samples = None))]
    #[allow(clippy::too_many_arguments)]
    fn render_ground_truth<'py>(
        &self,
        py: Python<'py>,
        view: &Bound<'py, PyAny>,
        proj: &Bound<'py, PyAny>,
        width: i64,
        height: i64,
        t: f64,
        samples: Option<i64>,
    ) -> PyResult<Bound<'py, numpy::PyArray3<u8>>> {
        guarded("Scene.render_ground_truth", || {
            let camera = convert::camera(view, proj, width, height, "camera")?;
            let t = convert::finite(t, "t")?;
            let n = self::samples(samples, camera.width, camera.height)?;
            let scene = &self.inner;
            reserve(rs::truth_bytes(&camera), || {
                let (w, h) = (camera.width, camera.height);
                format!("Scene.render_ground_truth: a {w}x{h} image")
            })?;
            let img = py
                .detach(|| rs::render_ground_truth(scene, &camera, t, n))
                .map_err(map_scene_error)?;
            rgb(py, img, camera.height, camera.width)
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "Scene({:?}, {:?})",
            self.inner.name,
            self.inner.variant.name()
        )
    }
}
