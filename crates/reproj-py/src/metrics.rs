//! The evaluation's SSIM kernel (`reproj_core::ssim`), called by `splitrender.evaluation.metrics`
//! with both images already as `float64` in `[0, 1]`.

use numpy::{PyArray3, PyUntypedArrayMethods};
use pyo3::prelude::*;

use crate::api::shaped;
use crate::convert::{array, slice, Dim};
use crate::errors::{invalid, map_reproj_error};
use crate::guarded;
use crate::memory::reserve;

/// SSIM of `x` against `y` (`float64[H, W, C]`, C-contiguous, the same shape): the mean of the
/// per-pixel, per-channel map, and the map itself when `want_map`.
#[pyfunction]
#[pyo3(signature = (x, y, want_map=false))]
pub fn ssim<'py>(
    py: Python<'py>,
    x: &Bound<'py, PyAny>,
    y: &Bound<'py, PyAny>,
    want_map: bool,
) -> PyResult<(f64, Option<Bound<'py, PyArray3<f64>>>)> {
    guarded("ssim", || {
        let dims = [Dim::Any("height"), Dim::Any("width"), Dim::Any("channels")];
        let xa = array::<f64>(x, "x", &dims)?;
        let ya = array::<f64>(y, "y", &dims)?;
        let shape = xa.shape().to_vec();
        if ya.shape() != shape.as_slice() {
            return Err(invalid(format!(
                "x and y: expected the same shape, got {:?} and {:?}",
                shape,
                ya.shape()
            )));
        }
        let (xs, ys) = (slice(&xa, "x")?, slice(&ya, "y")?);
        let (h, w, c) = (shape[0], shape[1], shape[2]);
        let run = |map: Option<&mut [f64]>| {
            py.detach(|| reproj_core::ssim::ssim(xs, ys, h, w, c, map))
                .map_err(map_reproj_error)
        };
        if want_map {
            reserve(8 * xs.len() as u64, || {
                format!("ssim: a map of shape ({h}, {w}, {c})")
            })?;
            let mut map = vec![0.0f64; xs.len()];
            let mean = run(Some(&mut map))?;
            Ok((mean, Some(shaped(py, map, (h, w, c))?)))
        } else {
            Ok((run(None)?, None))
        }
    })
}
