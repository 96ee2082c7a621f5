//! Bindings of `reproj_core::synthetic`, the analytic test scene.

use numpy::PyArray3;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use reproj_core::memory::{pixels, server_buffers_bytes, synthetic_truth_bytes};
use reproj_core::synthetic::{self, SyntheticScene};

use crate::api::{camera_items, put_buffers, rgb};
use crate::convert;
use crate::errors::invalid;
use crate::guarded;
use crate::memory::reserve;

/// Every server buffer of one camera of the synthetic scene at `time`, as a dict of arrays:
/// `color`, `depth`, `motion_fwd`, `motion_bwd`, `shadow_fwd_bits`, `shadow_fwd_min`,
/// `shadow_fwd_max`, `shadow_bwd_bits`, `shadow_bwd_min`, `shadow_bwd_max`. `camera` is a
/// `(view, proj, width, height)` tuple, as `reproject` takes its client.
#[pyfunction]
#[pyo3(signature = (dynamic, camera, time, interval, subframes))]
pub fn synthetic_render_server<'py>(
    py: Python<'py>,
    dynamic: bool,
    camera: &Bound<'py, PyAny>,
    time: f64,
    interval: f64,
    subframes: i64,
) -> PyResult<Bound<'py, PyDict>> {
    guarded("synthetic_render_server", || {
        let camera = convert::client(camera, "camera")?;
        let time = convert::finite(time, "time")?;
        if !(interval.is_finite() && interval > 0.0) {
            return Err(invalid(format!(
                "interval: expected a finite value > 0, got {interval}"
            )));
        }
        let s = convert::subframes(subframes)?;
        reserve(server_buffers_bytes(pixels(&camera)), || {
            let (w, h) = (camera.width, camera.height);
            format!("synthetic_render_server: a {w}x{h} camera")
        })?;
        let scene = SyntheticScene::new(dynamic);
        let r = py.detach(|| scene.render_server(&camera, time, interval, s));
        let d = PyDict::new(py);
        put_buffers(py, r, &d)?;
        Ok(d)
    })
}

/// Ground-truth RGB8 image of the synthetic scene at a client `camera` (a `(view, proj, width,
/// height)` tuple) and `time`.
#[pyfunction]
#[pyo3(signature = (dynamic, camera, time))]
pub fn synthetic_ground_truth<'py>(
    py: Python<'py>,
    dynamic: bool,
    camera: &Bound<'py, PyAny>,
    time: f64,
) -> PyResult<Bound<'py, PyArray3<u8>>> {
    guarded("synthetic_ground_truth", || {
        let camera = convert::client(camera, "camera")?;
        let time = convert::finite(time, "time")?;
        reserve(synthetic_truth_bytes(pixels(&camera)), || {
            let (w, h) = (camera.width, camera.height);
            format!("synthetic_ground_truth: a {w}x{h} image")
        })?;
        let scene = SyntheticScene::new(dynamic);
        let img = py.detach(|| scene.render_ground_truth(&camera, time));
        rgb(py, img, camera.height, camera.width)
    })
}

/// The DESIGN.md camera rig at a head pose: `[main, aux_left, aux_right]`, each
/// `(view, proj, width, height)`.
#[pyfunction]
#[pyo3(signature = (eye, target, width, height))]
pub fn synthetic_rig<'py>(
    py: Python<'py>,
    eye: (f64, f64, f64),
    target: (f64, f64, f64),
    width: i64,
    height: i64,
) -> PyResult<Bound<'py, PyList>> {
    guarded("synthetic_rig", || {
        let width = convert::side(width, "width")?;
        let height = convert::side(height, "height")?;
        let (eye, target) = ([eye.0, eye.1, eye.2], [target.0, target.1, target.2]);
        if !eye.iter().chain(&target).all(|v| v.is_finite()) || eye == target {
            return Err(invalid(format!(
                "eye {eye:?} and target {target:?} must be finite and distinct"
            )));
        }
        let (main, aux) = synthetic::rig(eye, target, width, height);
        let cams = [main, aux[0], aux[1]]
            .iter()
            .map(|c| PyTuple::new(py, camera_items(py, c)?))
            .collect::<PyResult<Vec<_>>>()?;
        PyList::new(py, cams)
    })
}

/// The deterministic head path of the synthetic scene: `(eye, target)` at time `t`.
#[pyfunction]
#[pyo3(signature = (t))]
#[allow(clippy::type_complexity)]
pub fn synthetic_head_pose(t: f64) -> PyResult<((f64, f64, f64), (f64, f64, f64))> {
    guarded("synthetic_head_pose", || {
        let t = convert::finite(t, "t")?;
        let (e, g) = synthetic::head_pose(t);
        Ok(((e[0], e[1], e[2]), (g[0], g[1], g[2])))
    })
}
