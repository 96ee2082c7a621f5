//! Checked conversions from Python objects to the core's types.
//!
//! Every check names the buffer and says what was expected and what came, e.g.
//! `newer.aux[1].depth: expected float32 array of shape (360, 640), got float64 (360, 640)`.
//! Arrays are borrowed read-only and never copied; only C-contiguous, aligned arrays of the exact
//! dtype are accepted (no silent casts), so what the kernel reads is what the caller passed.

use numpy::npyffi::flags::NPY_ARRAY_ALIGNED;
use numpy::{
    Element, PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn,
    PyReadwriteArrayDyn, PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use reproj_core::{Camera, CameraView, FrameView, Mat4, Params, ShadowView, MAX_SIDE};

use crate::errors::{invalid, map_reproj_error};

/// One expected array dimension.
#[derive(Debug, Clone, Copy)]
pub enum Dim {
    /// Exactly this many.
    Is(usize),
    /// Any size (named in messages).
    Any(&'static str),
}

fn fmt_shape(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

fn fmt_dims(dims: &[Dim]) -> String {
    let parts: Vec<String> = dims
        .iter()
        .map(|d| match d {
            Dim::Is(n) => n.to_string(),
            Dim::Any(name) => (*name).to_string(),
        })
        .collect();
    match parts.as_slice() {
        [one] => format!("({one},)"),
        _ => format!("({})", parts.join(", ")),
    }
}

/// The Python type name of `obj`, for messages.
pub fn type_name(obj: &Bound<'_, PyAny>) -> String {
    obj.get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "object".into())
}

/// What `obj` is, for messages: `float64 (360, 640)` for arrays, the type name otherwise.
pub fn describe(obj: &Bound<'_, PyAny>) -> String {
    match obj.cast::<PyUntypedArray>() {
        Ok(a) => format!("{} {}", a.dtype(), fmt_shape(a.shape())),
        Err(_) if obj.is_none() => "None".into(),
        Err(_) => type_name(obj),
    }
}

/// Borrows `obj` as a C-contiguous, aligned array of `T` with the given dimensions.
///
/// # Errors
/// `InvalidInputError` naming `what`, the expected dtype and shape, and what came.
pub fn array<'py, T: Element>(
    obj: &Bound<'py, PyAny>,
    what: &str,
    dims: &[Dim],
) -> PyResult<PyReadonlyArrayDyn<'py, T>> {
    checked_array::<T>(obj, what, dims)?
        .try_readonly()
        .map_err(|e| invalid(format!("{what}: cannot borrow the array: {e}")))
}

/// Borrows `obj` for writing, with the checks of [`array()`]; also refused: a read-only array
/// and one that overlaps an array borrowed elsewhere in the same call (an input).
///
/// # Errors
/// `InvalidInputError` naming `what`.
pub fn array_mut<'py, T: Element>(
    obj: &Bound<'py, PyAny>,
    what: &str,
    dims: &[Dim],
) -> PyResult<PyReadwriteArrayDyn<'py, T>> {
    checked_array::<T>(obj, what, dims)?
        .try_readwrite()
        .map_err(|e| invalid(format!("{what}: cannot borrow the array for writing: {e}")))
}

fn checked_array<'a, 'py, T: Element>(
    obj: &'a Bound<'py, PyAny>,
    what: &str,
    dims: &[Dim],
) -> PyResult<&'a Bound<'py, PyArrayDyn<T>>> {
    let py = obj.py();
    let want = numpy::dtype::<T>(py);
    let mismatch = || {
        invalid(format!(
            "{what}: expected {want} array of shape {}, got {}",
            fmt_dims(dims),
            describe(obj)
        ))
    };
    let arr = obj.cast::<PyUntypedArray>().map_err(|_| mismatch())?;
    let shape_ok = arr.ndim() == dims.len()
        && dims.iter().zip(arr.shape()).all(|(d, &s)| match d {
            Dim::Is(n) => *n == s,
            Dim::Any(_) => true,
        });
    if !shape_ok || !arr.dtype().is_equiv_to(&want) {
        return Err(mismatch());
    }
    if !arr.is_c_contiguous() {
        return Err(invalid(format!(
            "{what}: expected a C-contiguous array, got a non-contiguous {} view with strides {:?} \
             (pass numpy.ascontiguousarray(...))",
            describe(obj),
            arr.strides()
        )));
    }
    // SAFETY: `as_array_ptr` points to the live array object that `arr` keeps alive; reading its
    // `flags` field is a plain read of initialised memory while we hold the GIL.
    let flags = unsafe { (*arr.as_array_ptr()).flags };
    if flags & NPY_ARRAY_ALIGNED == 0 {
        return Err(invalid(format!(
            "{what}: expected an aligned array, got an unaligned {} buffer (pass numpy.array(..., copy=True))",
            describe(obj)
        )));
    }
    obj.cast::<PyArrayDyn<T>>().map_err(|_| mismatch())
}

/// The contiguous data of an array checked by [`array()`].
pub fn slice<'a, T: Element>(a: &'a PyReadonlyArrayDyn<'_, T>, what: &str) -> PyResult<&'a [T]> {
    a.as_slice()
        .map_err(|_| invalid(format!("{what}: expected a C-contiguous array")))
}

/// The contiguous data of an array borrowed by [`array_mut`].
pub fn slice_mut<'a, T: Element>(
    a: &'a mut PyReadwriteArrayDyn<'_, T>,
    what: &str,
) -> PyResult<&'a mut [T]> {
    a.as_slice_mut()
        .map_err(|_| invalid(format!("{what}: expected a C-contiguous array")))
}

/// A 4×4 `float64` matrix (any strides).
///
/// # Errors
/// `InvalidInputError` for anything else.
pub fn matrix(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Mat4> {
    let py = obj.py();
    let want = numpy::dtype::<f64>(py);
    let mismatch = || {
        invalid(format!(
            "{what}: expected float64 array of shape (4, 4), got {}",
            describe(obj)
        ))
    };
    let arr = obj.cast::<PyUntypedArray>().map_err(|_| mismatch())?;
    if arr.shape() != [4, 4] || !arr.dtype().is_equiv_to(&want) {
        return Err(mismatch());
    }
    let typed = obj.cast::<PyArrayDyn<f64>>().map_err(|_| mismatch())?;
    let ro = typed
        .try_readonly()
        .map_err(|e| invalid(format!("{what}: cannot borrow the array: {e}")))?;
    let view = ro.as_array();
    let mut m = [[0.0; 4]; 4];
    for (r, row) in m.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = view[[r, c]];
        }
    }
    Ok(Mat4(m))
}

/// The items of a tuple or list of exactly `n` entries.
///
/// # Errors
/// `InvalidInputError` naming `what` and the expected layout `layout`.
pub fn items<'py>(
    obj: &Bound<'py, PyAny>,
    what: &str,
    n: usize,
    layout: &str,
) -> PyResult<Vec<Bound<'py, PyAny>>> {
    let v = sequence(obj, what, layout)?;
    if v.len() != n {
        return Err(invalid(format!(
            "{what}: expected a tuple {layout}, got a sequence of {} items",
            v.len()
        )));
    }
    Ok(v)
}

/// The items of a tuple or list of any length.
///
/// # Errors
/// `InvalidInputError` when `obj` is neither.
pub fn sequence<'py>(
    obj: &Bound<'py, PyAny>,
    what: &str,
    layout: &str,
) -> PyResult<Vec<Bound<'py, PyAny>>> {
    if let Ok(t) = obj.cast::<PyTuple>() {
        Ok(t.iter().collect())
    } else if let Ok(l) = obj.cast::<PyList>() {
        Ok(l.iter().collect())
    } else {
        Err(invalid(format!(
            "{what}: expected a tuple {layout}, got {}",
            describe(obj)
        )))
    }
}

/// A Python float (or anything with `__float__`).
pub fn float(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<f64> {
    obj.extract::<f64>()
        .map_err(|_| invalid(format!("{what}: expected a float, got {}", describe(obj))))
}

/// `x` as the kernels take it (f32), refused where narrowing would change what it means: a
/// finite value beyond f32's range (it became inf), or, with `nonzero`, a value other than 0
/// that f32 cannot tell from 0. Checked on the caller's f64, so that the message names the
/// value given (narrowed first, `eps_e = 1e300` was refused as `eps_e = inf`).
pub fn narrow(x: f64, what: &str, nonzero: bool) -> PyResult<f32> {
    let v = x as f32;
    if (x.is_finite() && !v.is_finite()) || (nonzero && x != 0.0 && v == 0.0) {
        let tiny = if nonzero {
            "; at least 1.4e-45 where not 0"
        } else {
            ""
        };
        return Err(invalid(format!(
            "{what} = {x:?}: expected a value within float32's range (at most 3.4e38{tiny})"
        )));
    }
    Ok(v)
}

/// A Python int (or anything with `__index__`).
pub fn int(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<i64> {
    if obj.is_instance_of::<pyo3::types::PyBool>() {
        return Err(invalid(format!("{what}: expected an int, got bool")));
    }
    obj.extract::<i64>()
        .map_err(|_| invalid(format!("{what}: expected an int, got {}", describe(obj))))
}

/// An image side in `1..=MAX_SIDE`, checked before anything is allocated for it.
pub fn side(value: i64, what: &str) -> PyResult<usize> {
    match usize::try_from(value) {
        Ok(v) if (1..=MAX_SIDE).contains(&v) => Ok(v),
        _ => Err(invalid(format!(
            "{what}: expected an image side in 1..={MAX_SIDE}, got {value}"
        ))),
    }
}

/// A camera from `(view, proj)` matrices and a size given as Python ints.
pub fn camera(
    view: &Bound<'_, PyAny>,
    proj: &Bound<'_, PyAny>,
    width: i64,
    height: i64,
    what: &str,
) -> PyResult<Camera> {
    let view = matrix(view, &format!("{what}.view"))?;
    let proj = matrix(proj, &format!("{what}.proj"))?;
    let width = side(width, &format!("{what}.width"))?;
    let height = side(height, &format!("{what}.height"))?;
    Camera::new(view, proj, width, height, what).map_err(map_reproj_error)
}

/// The client camera from a `(view, proj, width, height)` tuple.
pub fn client(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Camera> {
    let it = items(obj, what, 4, "(view, proj, width, height)")?;
    let width = int(&it[2], &format!("{what}.width"))?;
    let height = int(&it[3], &format!("{what}.height"))?;
    camera(&it[0], &it[1], width, height, what)
}

/// Borrowed arrays of one server camera.
pub struct CamArrays<'py> {
    camera: Camera,
    color: PyReadonlyArrayDyn<'py, u8>,
    depth: PyReadonlyArrayDyn<'py, f32>,
    motion: Option<PyReadonlyArrayDyn<'py, f32>>,
    shadow: Option<[ShadowArray<'py>; 3]>,
    what: String,
}

/// A shadow bitfield or colour buffer.
pub enum ShadowArray<'py> {
    /// `bits`.
    Bits(PyReadonlyArrayDyn<'py, u32>),
    /// `s_min` or `s_max`.
    Color(PyReadonlyArrayDyn<'py, u8>),
}

/// The `(H, W)` a source image's buffers suggest, for messages: the depth's shape when it is 2-D,
/// else the first two sides of the colour when that is 3-D.
fn suggested_size(depth: &Bound<'_, PyAny>, color: Option<&Bound<'_, PyAny>>) -> [Dim; 2] {
    let shape_of = |o: &Bound<'_, PyAny>, ndim: usize| {
        o.cast::<PyUntypedArray>()
            .ok()
            .filter(|a| a.ndim() == ndim)
            .map(|a| [Dim::Is(a.shape()[0]), Dim::Is(a.shape()[1])])
    };
    shape_of(depth, 2)
        .or_else(|| color.and_then(|c| shape_of(c, 3)))
        .unwrap_or([Dim::Any("H"), Dim::Any("W")])
}

/// The depth and size of a source image: depth is `(H, W)`, and its shape sets the camera size.
/// `color`, when given, only improves the message for a depth that is not 2-D.
pub fn depth_and_size<'py>(
    obj: &Bound<'py, PyAny>,
    what: &str,
    color: Option<&Bound<'py, PyAny>>,
) -> PyResult<(PyReadonlyArrayDyn<'py, f32>, usize, usize)> {
    let depth = array::<f32>(obj, what, &suggested_size(obj, color))?;
    let (h, w) = (depth.shape()[0], depth.shape()[1]);
    if !(1..=MAX_SIDE).contains(&h) || !(1..=MAX_SIDE).contains(&w) {
        return Err(invalid(format!(
            "{what}: expected each side in 1..={MAX_SIDE}, got shape ({h}, {w})"
        )));
    }
    Ok((depth, w, h))
}

/// Shadow buffers `(bits u32[H,W], s_min u8[H,W,3], s_max u8[H,W,3])`.
pub fn shadow<'py>(
    obj: &Bound<'py, PyAny>,
    what: &str,
    w: usize,
    h: usize,
) -> PyResult<[ShadowArray<'py>; 3]> {
    let s = items(obj, what, 3, "(bits, s_min, s_max)")?;
    let hw = [Dim::Is(h), Dim::Is(w)];
    let hw3 = [Dim::Is(h), Dim::Is(w), Dim::Is(3)];
    Ok([
        ShadowArray::Bits(array::<u32>(&s[0], &format!("{what}.bits"), &hw)?),
        ShadowArray::Color(array::<u8>(&s[1], &format!("{what}.s_min"), &hw3)?),
        ShadowArray::Color(array::<u8>(&s[2], &format!("{what}.s_max"), &hw3)?),
    ])
}

impl<'py> CamArrays<'py> {
    /// `(view, proj, color, depth, motion | None, shadow | None)`.
    pub fn extract(obj: &Bound<'py, PyAny>, what: &str) -> PyResult<Self> {
        let it = items(obj, what, 6, "(view, proj, color, depth, motion, shadow)")?;
        let view = matrix(&it[0], &format!("{what}.view"))?;
        let proj = matrix(&it[1], &format!("{what}.proj"))?;
        let (depth, w, h) = depth_and_size(&it[3], &format!("{what}.depth"), Some(&it[2]))?;
        let camera = Camera::new(view, proj, w, h, what).map_err(map_reproj_error)?;
        let hw3 = [Dim::Is(h), Dim::Is(w), Dim::Is(3)];
        let color = array::<u8>(&it[2], &format!("{what}.color"), &hw3)?;
        let motion = if it[4].is_none() {
            None
        } else {
            Some(array::<f32>(&it[4], &format!("{what}.motion"), &hw3)?)
        };
        let shadow = if it[5].is_none() {
            None
        } else {
            Some(shadow(&it[5], &format!("{what}.shadow"), w, h)?)
        };
        Ok(CamArrays {
            camera,
            color,
            depth,
            motion,
            shadow,
            what: what.to_string(),
        })
    }

    /// Strong references to every array borrowed, appended to `out` (see
    /// `BidirHistory::arrays`).
    fn keep(&self, out: &mut Vec<Py<PyAny>>) {
        out.push(self.color.as_any().clone().unbind());
        out.push(self.depth.as_any().clone().unbind());
        out.extend(self.motion.iter().map(|m| m.as_any().clone().unbind()));
        for a in self.shadow.iter().flatten() {
            out.push(match a {
                ShadowArray::Bits(b) => b.as_any().clone().unbind(),
                ShadowArray::Color(c) => c.as_any().clone().unbind(),
            });
        }
    }

    /// The borrowed view the kernels take.
    pub fn view(&self) -> PyResult<CameraView<'_>> {
        let what = &self.what;
        let shadow = match &self.shadow {
            Some([ShadowArray::Bits(b), ShadowArray::Color(lo), ShadowArray::Color(hi)]) => {
                Some(ShadowView {
                    bits: slice(b, &format!("{what}.shadow.bits"))?,
                    s_min: slice(lo, &format!("{what}.shadow.s_min"))?,
                    s_max: slice(hi, &format!("{what}.shadow.s_max"))?,
                })
            }
            Some(_) => return Err(invalid(format!("{what}.shadow: malformed buffers"))),
            None => None,
        };
        Ok(CameraView {
            camera: self.camera,
            color: slice(&self.color, &format!("{what}.color"))?,
            depth: slice(&self.depth, &format!("{what}.depth"))?,
            motion: match &self.motion {
                Some(m) => Some(slice(m, &format!("{what}.motion"))?),
                None => None,
            },
            shadow,
        })
    }
}

/// Borrowed arrays of one server frame: `(main, aux)`.
pub struct FrameArrays<'py> {
    main: CamArrays<'py>,
    aux: Vec<CamArrays<'py>>,
}

impl<'py> FrameArrays<'py> {
    /// `(main: Cam, aux: list[Cam])`.
    pub fn extract(obj: &Bound<'py, PyAny>, what: &str) -> PyResult<Self> {
        let it = items(obj, what, 2, "(main, aux)")?;
        let main = CamArrays::extract(&it[0], &format!("{what}.main"))?;
        let aux = sequence(&it[1], &format!("{what}.aux"), "or list of cameras")?
            .iter()
            .enumerate()
            .map(|(i, a)| CamArrays::extract(a, &format!("{what}.aux[{i}]")))
            .collect::<PyResult<Vec<_>>>()?;
        Ok(FrameArrays { main, aux })
    }

    /// Strong references to every array of the frame, appended to `out`.
    pub fn keep(&self, out: &mut Vec<Py<PyAny>>) {
        self.main.keep(out);
        self.aux.iter().for_each(|a| a.keep(out));
    }

    /// The borrowed view the kernels take.
    pub fn view(&self) -> PyResult<FrameView<'_>> {
        Ok(FrameView {
            main: self.main.view()?,
            aux: self
                .aux
                .iter()
                .map(CamArrays::view)
                .collect::<PyResult<Vec<_>>>()?,
        })
    }
}

/// The option names `reproject` accepts, in [`Params`] order.
pub const OPTION_NAMES: [&str; 12] = [
    "eps_e",
    "eps_z",
    "eps_o",
    "aux_threshold_scale",
    "window",
    "fpi_iterations",
    "bidir_iterations",
    "shadow_subframes",
    "use_shadows",
    "use_aux",
    "blend",
    "splat_bidirectional",
];

fn opt_count(v: &Bound<'_, PyAny>, name: &str) -> PyResult<usize> {
    let what = format!("option {name}");
    let n = int(v, &what)?;
    usize::try_from(n).map_err(|_| invalid(format!("{what} = {n}: expected an int >= 0")))
}

fn opt_bool(v: &Bound<'_, PyAny>, name: &str) -> PyResult<bool> {
    v.extract::<bool>().map_err(|_| {
        invalid(format!(
            "option {name}: expected a bool, got {}",
            describe(v)
        ))
    })
}

/// [`Params`] from an options dict (`None` for the defaults); the domains are checked here too.
///
/// # Errors
/// `InvalidInputError` for a non-dict, an unknown key (listing the valid ones), a wrong type, or a
/// value outside its domain.
pub fn params(options: Option<&Bound<'_, PyAny>>) -> PyResult<Params> {
    let mut p = Params::default();
    let Some(options) = options.filter(|o| !o.is_none()) else {
        return Ok(p);
    };
    let dict = options.cast::<PyDict>().map_err(|_| {
        invalid(format!(
            "options: expected a dict, got {}",
            describe(options)
        ))
    })?;
    for (k, v) in dict.iter() {
        let key: String = k
            .extract()
            .map_err(|_| invalid(format!("options: keys must be str, got {}", describe(&k))))?;
        let what = format!("option {key}");
        let f = |v: &Bound<'_, PyAny>| narrow(float(v, &what)?, &what, true);
        match key.as_str() {
            "eps_e" => p.eps_e = f(&v)?,
            "eps_z" => p.eps_z = f(&v)?,
            "eps_o" => p.eps_o = f(&v)?,
            "aux_threshold_scale" => p.aux_threshold_scale = f(&v)?,
            "window" => p.window = opt_count(&v, &key)?,
            "fpi_iterations" => p.fpi_iterations = opt_count(&v, &key)?,
            "bidir_iterations" => p.bidir_iterations = opt_count(&v, &key)?,
            "shadow_subframes" => p.shadow_subframes = opt_count(&v, &key)?,
            "use_shadows" => p.use_shadows = opt_bool(&v, &key)?,
            "use_aux" => p.use_aux = opt_bool(&v, &key)?,
            "blend" => p.blend = opt_bool(&v, &key)?,
            "splat_bidirectional" => p.splat_bidirectional = opt_bool(&v, &key)?,
            _ => {
                return Err(invalid(format!(
                    "unknown option '{key}'; valid options: {}",
                    OPTION_NAMES.join(", ")
                )))
            }
        }
    }
    p.validate().map_err(map_reproj_error)?;
    Ok(p)
}

/// Fails to compile when [`Params`] gains a field, so that [`OPTION_NAMES`] and [`params`] are
/// kept in step with the core.
#[allow(dead_code)]
fn option_names_cover_params(p: Params) {
    let Params {
        eps_e: _,
        eps_z: _,
        eps_o: _,
        aux_threshold_scale: _,
        window: _,
        fpi_iterations: _,
        bidir_iterations: _,
        shadow_subframes: _,
        use_shadows: _,
        use_aux: _,
        blend: _,
        splat_bidirectional: _,
    } = p;
}

/// `v`, when finite.
pub(crate) fn finite(v: f64, what: &str) -> PyResult<f64> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(invalid(format!("{what}: expected a finite float, got {v}")))
    }
}

/// Shadow subframes per server interval, `1..=16` (2 bits each in a `u32`).
pub(crate) fn subframes(v: i64) -> PyResult<usize> {
    match usize::try_from(v) {
        Ok(s) if (1..=16).contains(&s) => Ok(s),
        _ => Err(invalid(format!("subframes: expected 1..=16, got {v}"))),
    }
}
