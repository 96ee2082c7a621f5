//! `reproject`, `scene_flow`, `apply_shadows`, the camera helpers and `BidirHistory`.

use numpy::ndarray::{Array, Dimension, ShapeBuilder};
use numpy::{IntoPyArray, PyArray, PyArray2, PyArray3, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyTuple;
use reproj_core::memory::reproject_bytes;
use reproj_core::method::MAX_ALPHA;
use reproj_core::{
    Camera, CameraBuffers, CameraView, Diagnostics, Mat4, Method, Output, Params, ReprojError,
    Request, Role,
};

use crate::convert::{self, array, depth_and_size, slice, Dim, FrameArrays};
use crate::errors::{invalid, map_reproj_error, SplitRenderError};
use crate::guarded;
use crate::memory::reserve;

/// An `H×W×3` RGB8 image from a vector of `H·W·3` bytes (no copy).
pub(crate) fn rgb<'py>(
    py: Python<'py>,
    v: Vec<u8>,
    h: usize,
    w: usize,
) -> PyResult<Bound<'py, PyArray3<u8>>> {
    shaped(py, v, (h, w, 3))
}

/// An array of `shape` from a vector of as many values (no copy).
pub(crate) fn shaped<'py, T: numpy::Element, D: Dimension>(
    py: Python<'py>,
    v: Vec<T>,
    shape: impl ShapeBuilder<Dim = D>,
) -> PyResult<Bound<'py, PyArray<T, D>>> {
    Array::from_shape_vec(shape, v)
        .map(|a| a.into_pyarray(py))
        .map_err(|e| SplitRenderError::new_err(format!("internal error: output shape: {e}")))
}

/// Moves one camera's server buffers into `d` as numpy arrays (no copies): `width`, `height`,
/// `color`, `depth`, `motion_fwd`, `motion_bwd`, `shadow_{fwd,bwd}_{bits,min,max}`; shared by the
/// synthetic scene and the renderer bindings.
pub(crate) fn put_buffers(
    py: Python<'_>,
    b: CameraBuffers,
    d: &Bound<'_, pyo3::types::PyDict>,
) -> PyResult<()> {
    let (h, w) = (b.height, b.width);
    d.set_item("width", w)?;
    d.set_item("height", h)?;
    d.set_item("color", rgb(py, b.color, h, w)?)?;
    d.set_item("depth", shaped(py, b.depth, (h, w))?)?;
    d.set_item("motion_fwd", shaped(py, b.motion_fwd, (h, w, 3))?)?;
    d.set_item("motion_bwd", shaped(py, b.motion_bwd, (h, w, 3))?)?;
    for (dir, sb) in [("fwd", b.shadow_fwd), ("bwd", b.shadow_bwd)] {
        d.set_item(format!("shadow_{dir}_bits"), shaped(py, sb.bits, (h, w))?)?;
        d.set_item(format!("shadow_{dir}_min"), rgb(py, sb.s_min, h, w)?)?;
        d.set_item(format!("shadow_{dir}_max"), rgb(py, sb.s_max, h, w)?)?;
    }
    Ok(())
}

/// A camera as the items `(view, proj, width, height)` of a Python tuple.
pub(crate) fn camera_items<'py>(py: Python<'py>, c: &Camera) -> PyResult<Vec<Bound<'py, PyAny>>> {
    Ok(vec![
        mat(py, &c.view)?.into_any(),
        mat(py, &c.proj)?.into_any(),
        c.width.into_pyobject(py)?.into_any(),
        c.height.into_pyobject(py)?.into_any(),
    ])
}

/// A 4×4 `float64` array.
pub(crate) fn mat<'py>(py: Python<'py>, m: &Mat4) -> PyResult<Bound<'py, PyArray2<f64>>> {
    shaped(py, m.0.iter().flatten().copied().collect(), (4, 4))
}

/// The client's state for one server-frame pair, carried from one client frame to the next:
/// `backward_bidir`'s previous B-frame (seeds/001's latest-frame initialisation) and the work of
/// `ours`, `ours_extrapolate` and `forward_splat` that does not depend on the client pose (done
/// once per pair instead of per frame). Create one per frame pair, or call `reset()` when the pair
/// changes. It holds the arrays of its last call's pair until the next call or `reset()`.
/// (The name predates its use by `ours`.)
#[pyclass(module = "splitrender._native")]
#[derive(Debug, Default)]
pub struct BidirHistory {
    inner: reproj_core::BidirHistory,
    /// The arrays of the pair the last call used, kept alive while `inner` may hold that
    /// pair's state. The core recognises its pair by the buffers' addresses (and the cameras
    /// and sizes); freed, another pair's arrays of the same sizes could be given the same
    /// addresses and be served the old pair's state (measured: 1357 of 1536 pixels wrong with
    /// `ours_extrapolate`). Held, no other array can take their place.
    arrays: Vec<Py<PyAny>>,
}

impl BidirHistory {
    /// After a call with `older` and `newer`: on success, records their arrays as the pair
    /// `inner` now holds state for; on failure, forgets the state, which may be the previous
    /// pair's (whose arrays are no longer held, then) or part of this one's.
    fn hold<T>(
        &mut self,
        result: &Result<T, ReprojError>,
        older: Option<&FrameArrays<'_>>,
        newer: &FrameArrays<'_>,
    ) {
        self.arrays.clear();
        if result.is_ok() {
            older.iter().for_each(|o| o.keep(&mut self.arrays));
            newer.keep(&mut self.arrays);
        } else {
            self.inner.reset();
        }
    }
}

/// The most threads `BidirHistory.prepare` accepts for its pool.
pub(crate) const MAX_PREPARE_THREADS: i64 = 256;

#[pymethods]
impl BidirHistory {
    #[new]
    fn new() -> Self {
        Self::default()
    }

    /// Forgets the carried state (call when the frame pair changes) and lets go of the pair's
    /// arrays. Its own buffers are kept for the next pair.
    fn reset(&mut self) {
        self.inner.reset();
        self.arrays.clear();
    }

    /// Computes the pair-level state of `method` for the frames (`reproj_core::prepare_pair`),
    /// which the next `reproject` calls with them then reuse; see `splitrender.prepare_pair`.
    /// `threads`: run it on a dedicated pool of that many threads (kept for later calls), so that
    /// it neither waits behind nor delays the frames on the global pool; `None` = the global
    /// pool.
    #[pyo3(signature = (method, older, newer, client, options=None, threads=None))]
    fn prepare<'py>(
        slf: &Bound<'py, Self>,
        method: &Bound<'py, PyAny>,
        older: Option<&Bound<'py, PyAny>>,
        newer: &Bound<'py, PyAny>,
        client: &Bound<'py, PyAny>,
        options: Option<&Bound<'py, PyAny>>,
        threads: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<()> {
        guarded("BidirHistory.prepare", || {
            // Taken as objects and checked here: pyo3's own conversion of `&str` and `i64`
            // raised TypeError / OverflowError, outside the package's hierarchy (issue 15).
            let method: String = method.extract().map_err(|_| {
                invalid(format!(
                    "method: expected a method name (str), got {}",
                    convert::describe(method)
                ))
            })?;
            let threads = match threads.filter(|t| !t.is_none()) {
                None => None,
                Some(t) => match convert::int(t, "threads")? {
                    t if (1..=MAX_PREPARE_THREADS).contains(&t) => Some(t as usize),
                    t => {
                        return Err(invalid(format!(
                            "threads: expected None or 1..={MAX_PREPARE_THREADS}, got {t}"
                        )))
                    }
                },
            };
            let args = CallArgs::extract(&method, older, newer, client, options)?;
            let mut hist = history_mut(slf.as_any())?;
            let older_view = args.older.as_ref().map(FrameArrays::view).transpose()?;
            let newer_view = args.newer.view()?;
            reserve(reproject_bytes(&newer_view, &args.client), || {
                let (cw, ch) = (args.client.width, args.client.height);
                let m = args.method;
                format!(
                    "BidirHistory.prepare: {m} to a {cw}x{ch} client from {}",
                    sizes(&newer_view)
                )
            })?;
            let inner = &mut hist.inner;
            let mut work = || {
                reproj_core::prepare_pair(
                    args.method,
                    older_view.as_ref(),
                    &newer_view,
                    &args.client,
                    &args.params,
                    inner,
                )
            };
            // As in `reproject`: the kernel only reads the borrowed arrays.
            let done = slf.py().detach(|| match threads {
                None => Ok(work()),
                Some(n) => reproj_core::pool::install(n, work),
            });
            let result = done.map_err(|e| {
                SplitRenderError::new_err(format!(
                    "BidirHistory.prepare: cannot start a pool of {threads:?} threads: {e}"
                ))
            })?;
            hist.hold(&result, args.older.as_ref(), &args.newer);
            result.map_err(map_reproj_error)
        })
    }

    /// How many times the pair-level state was computed into this history (by `prepare`, or by
    /// a `reproject` call whose pair it did not hold); `reset()` does not clear it.
    #[getter]
    fn pair_builds(&self) -> u64 {
        self.inner.pair_builds()
    }

    fn __repr__(&self) -> &'static str {
        "BidirHistory()"
    }
}

/// `alpha` as the kernels take it (f32), refused while it is still the caller's f64 where it is
/// not finite or outside `[0, MAX_ALPHA]`: narrowed first, 1e308 was reported as `inf` and
/// 3.0000001 passed as 3. (`{:?}` prints large and tiny values with an exponent, not in full.)
/// `method`: the method the message names (`None` for `apply_shadows`, which has none).
pub(crate) fn kernel_alpha(alpha: f64, method: Option<Method>) -> PyResult<f32> {
    if alpha.is_finite() && (0.0..=f64::from(MAX_ALPHA)).contains(&alpha) {
        Ok(alpha as f32)
    } else {
        let method = method.map_or(String::new(), |m| format!(" for method '{}'", m.name()));
        Err(invalid(format!(
            "alpha = {alpha:?} is outside the supported range [0, {MAX_ALPHA}]{method}"
        )))
    }
}

/// `history` as a `BidirHistory` borrowed for writing, or the error `reproject` and
/// `BidirHistory.prepare` give for another object or one in use by another call.
fn history_mut<'py>(h: &Bound<'py, PyAny>) -> PyResult<PyRefMut<'py, BidirHistory>> {
    let h = h.cast::<BidirHistory>().map_err(|_| {
        invalid(format!(
            "history: expected a BidirHistory or None, got {}",
            convert::describe(h)
        ))
    })?;
    h.try_borrow_mut()
        .map_err(|_| invalid("history: this BidirHistory is in use by another call"))
}

/// The arguments `reproject` and `BidirHistory.prepare` share, extracted and checked in this
/// order (so that both name the first bad one alike).
struct CallArgs<'py> {
    method: Method,
    params: Params,
    client: Camera,
    older: Option<FrameArrays<'py>>,
    newer: FrameArrays<'py>,
}

impl<'py> CallArgs<'py> {
    fn extract(
        method: &str,
        older: Option<&Bound<'py, PyAny>>,
        newer: &Bound<'py, PyAny>,
        client: &Bound<'py, PyAny>,
        options: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Self> {
        Ok(CallArgs {
            method: method.parse().map_err(map_reproj_error)?,
            params: convert::params(options)?,
            client: convert::client(client, "client")?,
            older: match older.filter(|o| !o.is_none()) {
                Some(o) => Some(FrameArrays::extract(o, "older")?),
                None => None,
            },
            newer: FrameArrays::extract(newer, "newer")?,
        })
    }
}

/// A frame's camera sizes for messages: `"a WxH main camera"` and its auxiliary cameras'.
fn sizes(frame: &reproj_core::FrameView<'_>) -> String {
    let main = &frame.main.camera;
    let mut s = format!("a {}x{} main camera", main.width, main.height);
    if !frame.aux.is_empty() {
        let aux: Vec<String> = frame
            .aux
            .iter()
            .map(|a| format!("{}x{}", a.camera.width, a.camera.height))
            .collect();
        s += &format!(" and auxiliary cameras of {}", aux.join(", "));
    }
    s
}

/// One client frame by `method`; see `splitrender.reproject_alpha` for the semantics.
#[pyfunction]
#[pyo3(signature = (method, older, newer, client, alpha, options=None, previous=None, diagnostics=false, history=None))]
#[allow(clippy::too_many_arguments)]
pub fn reproject<'py>(
    py: Python<'py>,
    method: &str,
    older: Option<&Bound<'py, PyAny>>,
    newer: &Bound<'py, PyAny>,
    client: &Bound<'py, PyAny>,
    alpha: f64,
    options: Option<&Bound<'py, PyAny>>,
    previous: Option<&Bound<'py, PyAny>>,
    diagnostics: bool,
    history: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    guarded("reproject", || {
        let CallArgs {
            method,
            params,
            client,
            older,
            newer,
        } = CallArgs::extract(method, older, newer, client, options)?;
        let (cw, ch) = (client.width, client.height);
        let n = cw * ch;
        let newer_view = newer.view()?;
        // The output and the diagnostics (3 + 1 + 4 bytes a client pixel) with the kernel's.
        reserve(reproject_bytes(&newer_view, &client) + 8 * n as u64, || {
            format!(
                "reproject: {method} to a {cw}x{ch} client from {}",
                sizes(&newer_view)
            )
        })?;
        let mut out = match previous.filter(|p| !p.is_none()) {
            // Copied, never written in place: the caller's previous frame stays as it was.
            Some(p) => {
                let dims = [Dim::Is(ch), Dim::Is(cw), Dim::Is(3)];
                let prev = array::<u8>(p, "previous", &dims)?;
                slice(&prev, "previous")?.to_vec()
            }
            None => vec![0u8; n * 3],
        };
        let mut hist_ref = history
            .filter(|h| !h.is_none())
            .map(history_mut)
            .transpose()?;
        let hist = hist_ref.as_deref_mut().map(|h| &mut h.inner);
        let mut diag = diagnostics.then(|| Diagnostics::new(n));
        let older_view = older.as_ref().map(FrameArrays::view).transpose()?;
        let request = Request {
            client,
            alpha: kernel_alpha(alpha, Some(method))?,
        };
        // The kernel only reads the borrowed arrays. As everywhere with numpy, Python code in
        // another thread that writes to them meanwhile would race with it; we do not copy to
        // guard against that.
        let result = py.detach(|| {
            reproj_core::reproject(
                method,
                older_view.as_ref(),
                &newer_view,
                &request,
                &params,
                Output {
                    image: &mut out,
                    diag: diag.as_mut(),
                },
                hist,
            )
        });
        if let Some(h) = hist_ref.as_deref_mut() {
            h.hold(&result, older.as_ref(), &newer);
        }
        result.map_err(map_reproj_error)?;
        let image = rgb(py, out, ch, cw)?.into_any();
        match diag {
            None => Ok(image),
            Some(d) => {
                let source = shaped(py, d.source, (ch, cw))?.into_any();
                let error = shaped(py, d.error, (ch, cw))?.into_any();
                Ok(PyTuple::new(py, [image, source, error])?.into_any())
            }
        }
    })
}

/// Scene flow of every pixel of one source image to the `client` camera (a `(view, proj, width,
/// height)` tuple, as [`reproject`] takes it) with a fraction `w` of its object motion
/// (seeds/000 eqs. 1, 12, 13): `f32[H, W, 3]`, NaN where invalid.
#[pyfunction]
#[pyo3(signature = (view, proj, depth, motion, client, w))]
pub fn scene_flow<'py>(
    py: Python<'py>,
    view: &Bound<'py, PyAny>,
    proj: &Bound<'py, PyAny>,
    depth: &Bound<'py, PyAny>,
    motion: Option<&Bound<'py, PyAny>>,
    client: &Bound<'py, PyAny>,
    w: f64,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    guarded("scene_flow", || {
        let (depth, sw, sh) = depth_and_size(depth, "depth", None)?;
        let source = convert::camera(view, proj, sw as i64, sh as i64, "source")?;
        let client = convert::client(client, "client")?;
        let motion = match motion.filter(|m| !m.is_none()) {
            Some(m) => Some(array::<f32>(
                m,
                "motion",
                &[Dim::Is(sh), Dim::Is(sw), Dim::Is(3)],
            )?),
            None => None,
        };
        if !w.is_finite() {
            return Err(invalid(format!("w: expected a finite float, got {w}")));
        }
        let w = convert::narrow(w, "w", false)?;
        // The colour below and the flow returned (3 + 12 bytes a pixel).
        reserve(15 * (sw * sh) as u64, || {
            format!("scene_flow: a {sw}x{sh} source image")
        })?;
        // The flow does not read colour; the view still wants a buffer of the right size.
        let color = vec![0u8; sw * sh * 3];
        let cv = CameraView {
            camera: source,
            color: &color,
            depth: slice(&depth, "depth")?,
            motion: motion.as_ref().map(|m| slice(m, "motion")).transpose()?,
            shadow: None,
        };
        let flow = py
            .detach(|| reproj_core::scene_flow(&cv, &client, w))
            .map_err(map_reproj_error)?;
        shaped(py, flow.into_flattened(), (sh, sw, 3))
    })
}

/// One source image with its dynamic shadows applied at `alpha` (seeds/000 eqs. 9–11).
#[pyfunction]
#[pyo3(signature = (color, bits, s_min, s_max, alpha, subframes, role))]
#[allow(clippy::too_many_arguments)]
pub fn apply_shadows<'py>(
    py: Python<'py>,
    color: &Bound<'py, PyAny>,
    bits: &Bound<'py, PyAny>,
    s_min: &Bound<'py, PyAny>,
    s_max: &Bound<'py, PyAny>,
    alpha: f64,
    subframes: i64,
    role: &str,
) -> PyResult<Bound<'py, PyArray3<u8>>> {
    guarded("apply_shadows", || {
        let color = array::<u8>(color, "color", &[Dim::Any("H"), Dim::Any("W"), Dim::Is(3)])?;
        let (h, w) = (color.shape()[0], color.shape()[1]);
        let hw2 = [Dim::Is(h), Dim::Is(w)];
        let hw3d = [Dim::Is(h), Dim::Is(w), Dim::Is(3)];
        let bits = array::<u32>(bits, "bits", &hw2)?;
        let s_min = array::<u8>(s_min, "s_min", &hw3d)?;
        let s_max = array::<u8>(s_max, "s_max", &hw3d)?;
        let alpha = kernel_alpha(alpha, None)?;
        let s = convert::subframes(subframes)?;
        let role = match role {
            "older" => Role::Older,
            "newer" => Role::Newer,
            other => {
                return Err(invalid(format!(
                    "role: expected 'older' or 'newer', got '{other}'"
                )))
            }
        };
        let (c, b, lo, hi) = (
            slice(&color, "color")?,
            slice(&bits, "bits")?,
            slice(&s_min, "s_min")?,
            slice(&s_max, "s_max")?,
        );
        reserve(c.len() as u64, || format!("apply_shadows: a {w}x{h} image"))?;
        let mut out = vec![0u8; c.len()];
        py.detach(|| reproj_core::apply_shadows(c, b, lo, hi, alpha, s, role, &mut out));
        rgb(py, out, h, w)
    })
}

/// A reversed-depth perspective projection (DESIGN.md conventions), `float64[4, 4]`.
#[pyfunction]
#[pyo3(signature = (fov_y_deg, aspect, near, far))]
pub fn perspective(
    py: Python<'_>,
    fov_y_deg: f64,
    aspect: f64,
    near: f64,
    far: f64,
) -> PyResult<Bound<'_, PyArray2<f64>>> {
    guarded("perspective", || {
        if !(fov_y_deg.is_finite() && fov_y_deg > 0.0 && fov_y_deg < 180.0) {
            return Err(invalid(format!(
                "fov_y_deg: expected a value in (0, 180), got {fov_y_deg}"
            )));
        }
        if !(aspect.is_finite() && aspect > 0.0) {
            return Err(invalid(format!(
                "aspect: expected a finite value > 0, got {aspect}"
            )));
        }
        if !(near.is_finite() && far.is_finite() && near > 0.0 && far > near) {
            return Err(invalid(format!(
                "near, far: expected 0 < near < far (finite), got near = {near}, far = {far}"
            )));
        }
        mat(py, &Mat4::perspective(fov_y_deg, aspect, near, far))
    })
}

/// Which of a camera's matrices the reprojection cannot invert, in words (`"singular
/// view-projection"`, checked first, or `"singular view"`), or `None`: the kernels' own test
/// (`Mat4::inverse` of `proj · view` and of `view`), for readers of files to refuse such a
/// camera where they read it.
#[pyfunction]
#[pyo3(signature = (view, proj))]
pub fn singular_camera(
    view: &Bound<'_, PyAny>,
    proj: &Bound<'_, PyAny>,
) -> PyResult<Option<&'static str>> {
    guarded("singular_camera", || {
        let camera = convert::camera(view, proj, 1, 1, "camera")?;
        Ok(reproj_core::Rays::new(&camera).err())
    })
}

/// The world→camera matrix of a camera at `eye` looking at `target`, `float64[4, 4]`;
/// `up` defaults to `(0, 1, 0)`.
#[pyfunction]
#[pyo3(signature = (eye, target, up=None))]
pub fn look_at(
    py: Python<'_>,
    eye: (f64, f64, f64),
    target: (f64, f64, f64),
    up: Option<(f64, f64, f64)>,
) -> PyResult<Bound<'_, PyArray2<f64>>> {
    guarded("look_at", || {
        let up = up.unwrap_or((0.0, 1.0, 0.0));
        let v = |t: (f64, f64, f64)| [t.0, t.1, t.2];
        let m = Mat4::look_at(v(eye), v(target), v(up));
        if !m.0.iter().flatten().all(|x| x.is_finite()) {
            return Err(invalid(format!(
                "look_at: eye {eye:?}, target {target:?} and up {up:?} must be finite, eye != target, \
                 and up not parallel to the view direction"
            )));
        }
        mat(py, &m)
    })
}

/// The instruction set the CPU kernels' row loops run with in this process: `"avx512"`, `"avx2"`
/// or `"baseline"` (the best the processor has, capped by `REPROJ_SIMD`; every tier gives the
/// same bytes, only the time differs), for a benchmark to say what it timed.
#[pyfunction]
pub fn simd_tier() -> PyResult<&'static str> {
    guarded("simd_tier", || {
        Ok(match reproj_core::ours::simd_tier() {
            reproj_core::ours::Simd::Avx512 => "avx512",
            reproj_core::ours::Simd::Avx2 => "avx2",
            reproj_core::ours::Simd::Baseline => "baseline",
        })
    })
}

/// The operating system's thread ids of the threads `reproject` runs on (rayon's global pool,
/// started if it was not; empty where the platform gives none), for a caller that sets their
/// scheduling policy (`splitrender.client.realtime`).
#[pyfunction]
pub fn render_thread_ids(py: Python<'_>) -> PyResult<Vec<i64>> {
    guarded("render_thread_ids", || {
        Ok(py.detach(reproj_core::pool::global_thread_ids))
    })
}
