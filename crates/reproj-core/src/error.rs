//! Errors of the reprojection core.

use thiserror::Error;

/// Everything that can go wrong in a reprojection call.
///
/// Every variant is an input problem the caller can fix; the kernels themselves do not fail once
/// the inputs are validated. The Python bindings map every variant to a `ValueError` subclass.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ReprojError {
    /// A buffer has the wrong number of elements for its camera.
    #[error("{what}: expected {expected} elements ({detail}), got {actual}")]
    BufferSize {
        /// Which buffer.
        what: String,
        /// Expected element count.
        expected: usize,
        /// Actual element count.
        actual: usize,
        /// Human-readable shape description, e.g. `"720x1280x3"`.
        detail: String,
    },
    /// Camera sizes that must agree do not.
    #[error("{0}")]
    CameraMismatch(String),
    /// A view-projection matrix is singular or not finite.
    #[error("{what}: matrix is not invertible or not finite")]
    SingularMatrix {
        /// Which camera.
        what: String,
    },
    /// A camera with a zero or absurd size.
    #[error("{what}: invalid image size {width}x{height} (each side must be in 1..={max})")]
    BadSize {
        /// Which camera.
        what: String,
        /// Width in pixels.
        width: usize,
        /// Height in pixels.
        height: usize,
        /// Largest side supported.
        max: usize,
    },
    /// α outside what the method supports.
    #[error("alpha = {alpha} is outside the supported range {range} for method '{method}'")]
    AlphaRange {
        /// The α given.
        alpha: f32,
        /// The method.
        method: String,
        /// The supported range in words.
        range: String,
    },
    /// A method needs a frame that was not given.
    #[error("{0}")]
    MissingFrame(String),
    /// An option with a value outside its domain.
    #[error("option {name} = {value}: {expected}")]
    BadOption {
        /// The option name.
        name: String,
        /// The value given, formatted.
        value: String,
        /// What is allowed.
        expected: String,
    },
    /// A method name that does not exist.
    #[error("unknown method '{0}'; expected one of: ours, ours_extrapolate, forward_splat, timewarp, backward_bidir")]
    UnknownMethod(String),
}

/// Result alias of the core.
pub type Result<T> = std::result::Result<T, ReprojError>;
