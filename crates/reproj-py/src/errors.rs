//! The Python exception hierarchy and the mapping of core errors onto it.
//!
//! ```text
//! Exception
//! └── SplitRenderError
//!     ├── InvalidInputError (also a ValueError)
//!     ├── OutOfMemoryError  (also a MemoryError)
//!     └── StreamError
//! ```
//!
//! `create_exception!` takes a single base class, but `InvalidInputError` must be both a
//! `SplitRenderError` and a `ValueError` so that callers can catch either (and
//! `OutOfMemoryError` a `MemoryError`). Each is therefore created once, natively, by calling
//! `type(name, (SplitRenderError, builtin), namespace)` — exactly what a Python `class`
//! statement does — and kept in a [`PyOnceLock`]. All the classes report `__module__ ==
//! "splitrender.errors"`, where the Python package re-exports them.

use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};
use reproj_core::ReprojError;

pyo3::create_exception!(
    splitrender.errors,
    SplitRenderError,
    PyException,
    "Base class of every error raised by splitrender."
);
pyo3::create_exception!(
    splitrender.errors,
    StreamError,
    SplitRenderError,
    "A malformed, truncated or out-of-order stream packet."
);

static INVALID_INPUT: PyOnceLock<Py<PyType>> = PyOnceLock::new();

const INVALID_INPUT_DOC: &str = "Invalid arguments: a wrong dtype, shape, size, matrix, option or \
method. Subclass of both SplitRenderError and ValueError.";

static OUT_OF_MEMORY: PyOnceLock<Py<PyType>> = PyOnceLock::new();

const OUT_OF_MEMORY_DOC: &str = "A call whose sizes are legal but need more memory than this \
machine could allocate, raised before the call allocates anything: the message names the call, \
its sizes and the bytes it needs. Subclass of both SplitRenderError and MemoryError.";

/// The class `name(SplitRenderError, B)` with `doc`, created on first use and kept in `cell`.
fn with_builtin_base<'py, B: pyo3::PyTypeInfo>(
    py: Python<'py>,
    cell: &'static PyOnceLock<Py<PyType>>,
    name: &str,
    doc: &str,
) -> PyResult<&'py Bound<'py, PyType>> {
    let ty = cell.get_or_try_init(py, || -> PyResult<Py<PyType>> {
        let bases = PyTuple::new(py, [py.get_type::<SplitRenderError>(), py.get_type::<B>()])?;
        let ns = PyDict::new(py);
        ns.set_item("__module__", "splitrender.errors")?;
        ns.set_item("__doc__", doc)?;
        let ty = py
            .get_type::<PyType>()
            .call1((name, bases, ns))?
            .cast_into::<PyType>()?;
        Ok(ty.unbind())
    })?;
    Ok(ty.bind(py))
}

/// The `InvalidInputError` class, created on first use.
pub fn invalid_input_type(py: Python<'_>) -> PyResult<&Bound<'_, PyType>> {
    with_builtin_base::<pyo3::exceptions::PyValueError>(
        py,
        &INVALID_INPUT,
        "InvalidInputError",
        INVALID_INPUT_DOC,
    )
}

/// The `OutOfMemoryError` class, created on first use.
pub fn out_of_memory_type(py: Python<'_>) -> PyResult<&Bound<'_, PyType>> {
    with_builtin_base::<pyo3::exceptions::PyMemoryError>(
        py,
        &OUT_OF_MEMORY,
        "OutOfMemoryError",
        OUT_OF_MEMORY_DOC,
    )
}

/// An `InvalidInputError` with `msg`.
pub fn invalid(msg: impl Into<String>) -> PyErr {
    let msg = msg.into();
    Python::attach(|py| match invalid_input_type(py) {
        Ok(ty) => PyErr::from_type(ty.clone(), msg),
        // Cannot happen short of memory exhaustion; still an error of the hierarchy.
        Err(_) => SplitRenderError::new_err(msg),
    })
}

/// An `OutOfMemoryError` with `msg`.
pub fn out_of_memory(msg: impl Into<String>) -> PyErr {
    let msg = msg.into();
    Python::attach(|py| match out_of_memory_type(py) {
        Ok(ty) => PyErr::from_type(ty.clone(), msg),
        Err(_) => SplitRenderError::new_err(msg),
    })
}

/// Maps a core error onto the hierarchy. Every variant is listed (no wildcard) so that a new
/// variant has to be mapped deliberately. All current variants are caller mistakes.
pub fn map_reproj_error(e: ReprojError) -> PyErr {
    let msg = e.to_string();
    match e {
        ReprojError::BufferSize { .. }
        | ReprojError::CameraMismatch(_)
        | ReprojError::SingularMatrix { .. }
        | ReprojError::BadSize { .. }
        | ReprojError::AlphaRange { .. }
        | ReprojError::MissingFrame(_)
        | ReprojError::BadOption { .. }
        | ReprojError::UnknownMethod(_) => invalid(msg),
    }
}
