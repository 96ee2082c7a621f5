//! The crate's error type.

/// Everything that can go wrong when building or rendering a scene.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SceneError {
    /// A built-in scene name that does not exist.
    #[error("unknown scene {name:?}; valid scenes: {valid}")]
    UnknownScene {
        /// The name asked for.
        name: String,
        /// The valid names, comma-separated.
        valid: String,
    },
    /// A variant other than `static` or `dynamic`.
    #[error("unknown scene variant {name:?}; valid variants: static, dynamic")]
    UnknownVariant {
        /// The name asked for.
        name: String,
    },
    /// The number of shadow subframes must fit 2 bits each into a `u32`.
    #[error("subframes must be in 1..=16, got {subframes}")]
    BadSubframes {
        /// The number asked for.
        subframes: usize,
    },
    /// A colour sample count per pixel side outside `1..=MAX_SAMPLES`.
    #[error("samples must be in 1..={max} per pixel side, got {samples}")]
    BadSamples {
        /// The number asked for.
        samples: usize,
        /// Largest accepted ([`crate::render::MAX_SAMPLES`]).
        max: usize,
    },
    /// A render scale that gives an empty or oversized image.
    #[error(
        "scale {scale:?} gives a {}×{} main camera (each side must be in 2..={max})",
        side(*.width),
        side(*.height)
    )]
    BadScale {
        /// The scale asked for.
        scale: f64,
        /// Resulting width (rounded; beyond any `usize` for an absurd scale, NaN for NaN).
        width: f64,
        /// Resulting height.
        height: f64,
        /// Largest side accepted.
        max: usize,
    },
    /// A time, interval or frame rate that is not finite (or not positive, for a rate), or a
    /// time at which an object of the scene is not at a finite position.
    #[error("{what} = {value:?}: {expected}")]
    BadTime {
        /// Which argument.
        what: String,
        /// The value given.
        value: f64,
        /// What is accepted.
        expected: String,
    },
    /// A camera with a zero or oversized side, or matrices that cannot be inverted.
    #[error("camera {what}: {why}")]
    BadCamera {
        /// Which camera.
        what: String,
        /// What is wrong with it.
        why: String,
    },
    /// An object whose parent index does not come before it.
    #[error("object {index} ({name}) has parent {parent}, which is not an earlier object")]
    BadHierarchy {
        /// The object's index.
        index: usize,
        /// The object's name.
        name: String,
        /// Its parent index.
        parent: usize,
    },
    /// A camera path without keys, with a key that is not finite, or with key times that
    /// decrease.
    #[error("camera path: {why}")]
    BadPath {
        /// What is wrong with it.
        why: String,
    },
    /// A scene whose objects were changed in place (added, removed, re-parented, animated)
    /// since [`crate::Scene::new`] or [`crate::Scene::refresh`] derived which of them move.
    #[error(
        "the scene's objects changed since Scene::new or Scene::refresh derived which move \
         ({derived} derived, {now} now): call Scene::refresh after changing them"
    )]
    Changed {
        /// Objects when it was derived.
        derived: usize,
        /// Objects now.
        now: usize,
    },
    /// A glTF file that cannot be read or is malformed (bad JSON, a missing buffer or texture
    /// file, an out-of-range index, inconsistent data).
    #[error("glTF {path}: {problem}")]
    Gltf {
        /// The file.
        path: String,
        /// What is wrong with it.
        problem: String,
    },
    /// A glTF file using a feature the renderer does not implement.
    #[error("glTF {path}: unsupported: {what}")]
    GltfUnsupported {
        /// The file.
        path: String,
        /// The feature.
        what: String,
    },
}

/// `Result` with [`SceneError`].
pub type Result<T, E = SceneError> = std::result::Result<T, E>;

/// A side of [`SceneError::BadScale`] in words: a whole number as such, one too large to write
/// out (1e300) with an exponent.
fn side(v: f64) -> String {
    if v.is_finite() && v.abs() < 1e15 {
        format!("{v}")
    } else {
        format!("{v:.3e}")
    }
}
