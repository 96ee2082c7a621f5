//! `splitrender._native`: the PyO3 bindings of reproj-core, and the only crate that knows Python.
//!
//! Every function here is thin: it checks its inputs (dtype, shape, contiguity and sizes, naming
//! the offending buffer), allocates the output, runs the kernel with the GIL released
//! (`py.detach`), and maps the core's errors onto the exception hierarchy of `errors`. Every body
//! runs inside `guarded`, so a Rust panic surfaces as `SplitRenderError("internal error in …")`
//! instead of pyo3's `PanicException` (a `BaseException` that ordinary `except` clauses miss).

use std::panic::{catch_unwind, AssertUnwindSafe};

use pyo3::prelude::*;

mod api;
mod codec;
mod convert;
mod errors;
mod gpu;
mod memory;
mod metrics;
mod scene;
mod synth;

use errors::{invalid_input_type, out_of_memory_type, SplitRenderError, StreamError};

/// Runs `f`, turning a panic into `SplitRenderError("internal error in <name>: … (please report)")`.
///
/// A panic inside `py.detach` unwinds through pyo3's guard, which re-attaches the thread first,
/// and rayon re-raises worker panics on the calling thread, so one catch here covers both.
pub(crate) fn guarded<T>(name: &str, f: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(result) => result,
        Err(payload) => {
            let msg = if let Some(s) = payload.downcast_ref::<&str>() {
                (*s).to_string()
            } else if let Some(s) = payload.downcast_ref::<String>() {
                s.clone()
            } else {
                "unknown panic payload".to_string()
            };
            Err(SplitRenderError::new_err(format!(
                "internal error in {name}: {msg} (please report)"
            )))
        }
    }
}

/// Panics inside [`guarded`]; exists so that the tests can prove panics never reach Python as
/// `PanicException`.
#[pyfunction]
fn _panic_for_test() -> PyResult<()> {
    guarded("_panic_for_test", || -> PyResult<()> {
        panic!("deliberate panic for the test suite")
    })
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add(
        "METHODS",
        reproj_core::Method::ALL.map(|m| m.name()).to_vec(),
    )?;
    m.add("SplitRenderError", py.get_type::<SplitRenderError>())?;
    m.add("InvalidInputError", invalid_input_type(py)?)?;
    m.add("OutOfMemoryError", out_of_memory_type(py)?)?;
    m.add("StreamError", py.get_type::<StreamError>())?;
    m.add(
        "GpuUnavailableError",
        py.get_type::<gpu::GpuUnavailableError>(),
    )?;
    m.add(
        "GpuDeviceLostError",
        py.get_type::<gpu::GpuDeviceLostError>(),
    )?;
    m.add_class::<gpu::WgpuReprojector>()?;
    m.add_class::<gpu::WgpuPair>()?;
    m.add_function(wrap_pyfunction!(gpu::wgpu_adapter, m)?)?;
    m.add_class::<api::BidirHistory>()?;
    m.add_function(wrap_pyfunction!(api::reproject, m)?)?;
    m.add_function(wrap_pyfunction!(api::scene_flow, m)?)?;
    m.add_function(wrap_pyfunction!(api::apply_shadows, m)?)?;
    m.add_function(wrap_pyfunction!(api::perspective, m)?)?;
    m.add_function(wrap_pyfunction!(api::look_at, m)?)?;
    m.add_function(wrap_pyfunction!(api::singular_camera, m)?)?;
    m.add_function(wrap_pyfunction!(api::render_thread_ids, m)?)?;
    m.add_function(wrap_pyfunction!(api::simd_tier, m)?)?;
    m.add_function(wrap_pyfunction!(codec::dequantise_depth, m)?)?;
    m.add_function(wrap_pyfunction!(codec::dequantise_motion, m)?)?;
    m.add_function(wrap_pyfunction!(codec::shadow_colour, m)?)?;
    m.add_function(wrap_pyfunction!(codec::block_mean, m)?)?;
    m.add_function(wrap_pyfunction!(metrics::ssim, m)?)?;
    m.add_function(wrap_pyfunction!(synth::synthetic_render_server, m)?)?;
    m.add_function(wrap_pyfunction!(synth::synthetic_ground_truth, m)?)?;
    m.add_function(wrap_pyfunction!(synth::synthetic_rig, m)?)?;
    m.add_function(wrap_pyfunction!(synth::synthetic_head_pose, m)?)?;
    m.add_class::<scene::Scene>()?;
    m.add_function(wrap_pyfunction!(scene::scene_names, m)?)?;
    m.add_function(wrap_pyfunction!(scene::default_samples, m)?)?;
    m.add("MAX_SAMPLES", reproj_scene::MAX_SAMPLES)?;
    m.add("MAX_PREPARE_THREADS", api::MAX_PREPARE_THREADS)?;
    m.add("GPU_OUTPUT_SLOTS", reproj_wgpu::MAX_OUTPUTS)?;
    m.add_function(wrap_pyfunction!(_panic_for_test, m)?)?;
    m.add_function(wrap_pyfunction!(gpu::_wgpu_lose_device_for_test, m)?)?;
    Ok(())
}
