//! `WgpuReprojector` and `wgpu_adapter`: the bindings of reproj-wgpu (the GPU path).
//!
//! Thin as the rest: inputs are checked by the same conversions as `reproject` (`convert.rs`),
//! every device call runs with the GIL released, and every [`GpuError`] maps onto the exception
//! hierarchy: input problems and methods without a GPU kernel are `InvalidInputError`, a missing
//! adapter (or a `WGPU_BACKEND` that names none) is `GpuUnavailableError` (with how to get one),
//! a lost device `GpuDeviceLostError`, other device failures `SplitRenderError`.
//!
//! One device per process ([`context`]), created on first use and shared by every reprojector:
//! creating a device costs far more than a client frame (pipelines compile per reprojector).
//! A lost device is replaced by the next reprojector made: the ones on it keep failing.

use std::sync::{Arc, Mutex};

use pyo3::prelude::*;
use pyo3::types::PyTuple;
use reproj_core::{Diagnostics, Method, Request};
use reproj_wgpu::{
    ContextOptions, GpuContext, GpuError, Previous, Reprojector, ReprojectorOptions, UploadedPair,
    Uploader, MAX_OUTPUTS,
};

use crate::api::{kernel_alpha, rgb, shaped};
use crate::convert::{self, array, slice, Dim, FrameArrays};
use crate::errors::{invalid, map_reproj_error, SplitRenderError};
use crate::guarded;
use crate::memory::reserve;

pyo3::create_exception!(
    splitrender.errors,
    GpuUnavailableError,
    SplitRenderError,
    "The wgpu backend was asked for, but no GPU adapter (or device) is available; the message \
says how to install one (Mesa's lavapipe needs no GPU)."
);

pyo3::create_exception!(
    splitrender.errors,
    GpuDeviceLostError,
    SplitRenderError,
    "The GPU device was lost (a driver reset, a removed GPU): the reprojector that raised it \
never works again; a new one is made on a new device, or the CPU path takes over."
);

/// Maps a GPU-path error onto the hierarchy; every variant explicitly.
fn map_gpu_error(e: GpuError) -> PyErr {
    match e {
        GpuError::Input(e) => map_reproj_error(e),
        GpuError::Unsupported(msg) | GpuError::Order(msg) | GpuError::TooLarge(msg) => invalid(msg),
        GpuError::NoAdapter(_) | GpuError::Config(_) => GpuUnavailableError::new_err(e.to_string()),
        GpuError::Lost(_) => GpuDeviceLostError::new_err(e.to_string()),
        GpuError::Device(_) | GpuError::State(_) => SplitRenderError::new_err(e.to_string()),
    }
}

/// The process-wide device, created on first use; the outcome, failure included, is kept until
/// the device is lost, when the next call makes a new one.
fn context(py: Python<'_>) -> PyResult<Arc<GpuContext>> {
    static CONTEXT: Mutex<Option<Result<Arc<GpuContext>, GpuError>>> = Mutex::new(None);
    let ctx = py.detach(|| {
        // A poisoned lock holds a whole value (it is replaced, never changed in place).
        let mut slot = CONTEXT.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(Ok(ctx)) = slot.as_ref() {
            if ctx.loss.reason().is_some() {
                *slot = None;
            }
        }
        slot.get_or_insert_with(|| GpuContext::new(&ContextOptions::default()).map(Arc::new))
            .clone()
    });
    ctx.map_err(map_gpu_error)
}

/// The wgpu adapter in words (e.g. `llvmpipe (...) (Vulkan, Cpu, Mesa ...)`); raises
/// `GpuUnavailableError` when there is none.
#[pyfunction]
pub fn wgpu_adapter(py: Python<'_>) -> PyResult<String> {
    guarded("wgpu_adapter", || Ok(context(py)?.describe()))
}

/// Destroys the process-wide device, as a driver reset or a removed GPU loses it; exists so that
/// the tests can see what a lost device does to the GPU path and its callers. Returns once wgpu
/// counts it lost (a destroyed device is lost when its queue is empty), as a loss the driver
/// reports is.
#[pyfunction]
pub fn _wgpu_lose_device_for_test(py: Python<'_>) -> PyResult<()> {
    guarded("_wgpu_lose_device_for_test", || {
        let ctx = context(py)?;
        py.detach(|| {
            ctx.device.destroy();
            let _ = ctx.loss.check_drained(&ctx.device);
        });
        Ok(())
    })
}

/// The client reprojection on the GPU with the server frames kept on the device: `upload` a pair
/// once and `install` it, then `render` client frames from a pose and `alpha`.
#[pyclass(module = "splitrender._native")]
#[derive(Debug)]
pub struct WgpuReprojector {
    inner: Mutex<Reprojector>,
    /// Uploads without the lock, so that a receiving thread's upload never waits for (or holds
    /// up) the display thread's frame.
    uploader: Uploader,
    adapter: String,
}

/// A pair of server frames on the device (`WgpuReprojector.upload`), made current with
/// `WgpuReprojector.install`; freed when the last reference goes.
#[pyclass(module = "splitrender._native", frozen)]
#[derive(Debug)]
pub struct WgpuPair {
    inner: Arc<UploadedPair>,
}

#[pymethods]
impl WgpuPair {
    /// Whether the pair holds the older frame (can interpolate).
    #[getter]
    fn has_older(&self) -> bool {
        self.inner.has_older()
    }

    /// Bytes of device memory the pair holds.
    #[getter]
    fn device_bytes(&self) -> u64 {
        self.inner.device_bytes()
    }

    fn __repr__(&self) -> String {
        format!(
            "WgpuPair(has_older={}, device_bytes={})",
            self.inner.has_older(),
            self.inner.device_bytes()
        )
    }
}

#[pymethods]
impl WgpuReprojector {
    #[new]
    #[pyo3(signature = (force_32bit_atomics=false))]
    fn new(py: Python<'_>, force_32bit_atomics: bool) -> PyResult<Self> {
        guarded("WgpuReprojector", || {
            let ctx = context(py)?;
            let options = ReprojectorOptions {
                force_32bit_atomics,
            };
            let inner = py
                .detach(|| Reprojector::new(&ctx, &options))
                .map_err(map_gpu_error)?;
            Ok(WgpuReprojector {
                uploader: inner.uploader(),
                inner: Mutex::new(inner),
                adapter: ctx.describe(),
            })
        })
    }

    /// The adapter in words.
    #[getter]
    fn adapter(&self) -> String {
        self.adapter.clone()
    }

    /// Why its device was lost (`None` while it is not): it never renders again.
    #[getter]
    fn lost(&self) -> PyResult<Option<String>> {
        guarded("WgpuReprojector.lost", || {
            Ok(self.lock()?.lost().map(str::to_owned))
        })
    }

    /// `"int64"` (one 64-bit atomic max per splat) or `"int32"` (two 32-bit passes).
    #[getter]
    fn atomics(&self) -> PyResult<&'static str> {
        guarded("WgpuReprojector.atomics", || {
            Ok(self.lock()?.atomics().name())
        })
    }

    /// Uploads a pair, `older` (forward buffers; None to extrapolate only) and `newer` (backward
    /// buffers), without making it current (any thread, without waiting for a frame being
    /// rendered); `install` makes it current.
    #[pyo3(signature = (older, newer))]
    fn upload<'py>(
        &self,
        py: Python<'py>,
        older: Option<&Bound<'py, PyAny>>,
        newer: &Bound<'py, PyAny>,
    ) -> PyResult<WgpuPair> {
        guarded("WgpuReprojector.upload", || {
            let older = match older.filter(|o| !o.is_none()) {
                Some(o) => Some(FrameArrays::extract(o, "older")?),
                None => None,
            };
            let newer = FrameArrays::extract(newer, "newer")?;
            let older_view = older.as_ref().map(FrameArrays::view).transpose()?;
            let newer_view = newer.view()?;
            let pair = py
                .detach(|| self.uploader.upload(older_view.as_ref(), &newer_view))
                .map_err(map_gpu_error)?;
            Ok(WgpuPair {
                inner: Arc::new(pair),
            })
        })
    }

    /// Makes an uploaded pair current (no copy); returns the pair that was current.
    fn install(&self, py: Python<'_>, pair: &Bound<'_, WgpuPair>) -> PyResult<Option<WgpuPair>> {
        guarded("WgpuReprojector.install", || {
            let pair = pair.get().inner.clone();
            let previous = py
                .detach(|| self.lock_detached()?.install(pair))
                .map_err(map_gpu_error)?;
            Ok(previous.map(|inner| WgpuPair { inner }))
        })
    }

    /// One client frame into output slot `slot`; see `splitrender.gpu.GpuReprojector.render`.
    #[pyo3(signature = (method, client, alpha, options=None, previous=None, keep=false, slot=0, diagnostics=false, download=true))]
    #[allow(clippy::too_many_arguments)]
    fn render<'py>(
        &self,
        py: Python<'py>,
        method: &str,
        client: &Bound<'py, PyAny>,
        alpha: f64,
        options: Option<&Bound<'py, PyAny>>,
        previous: Option<&Bound<'py, PyAny>>,
        keep: bool,
        slot: i64,
        diagnostics: bool,
        download: bool,
    ) -> PyResult<Option<Bound<'py, PyAny>>> {
        guarded("WgpuReprojector.render", || {
            let method: Method = method.parse().map_err(map_reproj_error)?;
            let params = convert::params(options)?;
            let client = convert::client(client, "client")?;
            let slot = match usize::try_from(slot) {
                Ok(s) if s < MAX_OUTPUTS => s,
                _ => {
                    return Err(invalid(format!(
                        "slot: expected an int in [0, {}], got {slot}",
                        MAX_OUTPUTS - 1
                    )))
                }
            };
            let (cw, ch) = (client.width, client.height);
            let n = cw * ch;
            let prev = match previous.filter(|p| !p.is_none()) {
                Some(p) => {
                    if keep {
                        return Err(invalid("previous: pass either an image or keep=True"));
                    }
                    let dims = [Dim::Is(ch), Dim::Is(cw), Dim::Is(3)];
                    Some(array::<u8>(p, "previous", &dims)?)
                }
                None => None,
            };
            let prev_slice = prev.as_ref().map(|p| slice(p, "previous")).transpose()?;
            let previous = match (prev_slice, keep) {
                (Some(p), _) => Previous::Image(p),
                (None, true) => Previous::Keep,
                (None, false) => Previous::Black,
            };
            let request = Request {
                client,
                alpha: kernel_alpha(alpha, Some(method))?,
            };
            // The image and diagnostics returned (3 and 1 + 4 bytes a pixel) and as much again
            // for the copies read back from the device. (Device memory is wgpu's to refuse.)
            let host = 3 * download as u64 + 5 * diagnostics as u64;
            reserve(2 * host * n as u64, || {
                format!("WgpuReprojector.render: a {cw}x{ch} client")
            })?;
            let mut out = download.then(|| vec![0u8; n * 3]);
            let mut diag = diagnostics.then(|| Diagnostics::new(n));
            py.detach(|| {
                self.lock_detached()?.render(
                    slot,
                    method,
                    &request,
                    &params,
                    previous,
                    out.as_deref_mut(),
                    diag.as_mut(),
                )
            })
            .map_err(map_gpu_error)?;
            let image = match out {
                Some(o) => rgb(py, o, ch, cw)?.into_any(),
                None => return Ok(None),
            };
            match diag {
                None => Ok(Some(image)),
                Some(d) => {
                    let source = shaped(py, d.source, (ch, cw))?.into_any();
                    let error = shaped(py, d.error, (ch, cw))?.into_any();
                    Ok(Some(PyTuple::new(py, [image, source, error])?.into_any()))
                }
            }
        })
    }

    /// Frees the pair and the output slots on the device.
    fn unload(&self) -> PyResult<()> {
        guarded("WgpuReprojector.unload", || {
            self.lock()?.unload();
            Ok(())
        })
    }

    fn __repr__(&self) -> String {
        format!("WgpuReprojector(adapter={:?})", self.adapter)
    }
}

impl WgpuReprojector {
    fn lock(&self) -> PyResult<std::sync::MutexGuard<'_, Reprojector>> {
        self.inner.lock().map_err(|_| {
            SplitRenderError::new_err("WgpuReprojector: poisoned by an earlier internal error")
        })
    }

    /// The lock taken without the GIL (a second thread waits for the first one's frame).
    fn lock_detached(&self) -> Result<std::sync::MutexGuard<'_, Reprojector>, GpuError> {
        self.inner.lock().map_err(|_| {
            GpuError::State("WgpuReprojector: poisoned by an earlier internal error".into())
        })
    }
}
