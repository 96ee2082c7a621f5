//! Errors of the GPU path.

use reproj_core::ReprojError;
use thiserror::Error;

/// Everything that can go wrong on the GPU path.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum GpuError {
    /// An input problem, with exactly the message the CPU path gives for it.
    #[error(transparent)]
    Input(#[from] ReprojError),
    /// No GPU adapter (or no usable device) could be found.
    #[error("no wgpu adapter: {0}. Install a Vulkan driver; without a GPU, Mesa's software rasteriser lavapipe works (Debian/Ubuntu: apt-get install mesa-vulkan-drivers)")]
    NoAdapter(String),
    /// The environment asks for something that cannot work (`WGPU_BACKEND` naming no backend).
    #[error("{0}")]
    Config(String),
    /// The method or configuration has no GPU kernel.
    #[error("{0}")]
    Unsupported(String),
    /// The device reported an error (out of memory, a limit exceeded).
    #[error("wgpu device error: {0}")]
    Device(String),
    /// The device was lost (a driver reset, a removed GPU, `wgpu::Device::destroy`): nothing
    /// made on it works again. A new device (a new [`crate::GpuContext`]) may.
    #[error("the GPU device was lost ({0}); make a new reprojector (on a new device) or use the CPU path")]
    Lost(String),
    /// Frames or a client image larger than this device's buffers can hold (its limits),
    /// found before anything was asked of it: the caller's to change.
    #[error("{0}")]
    TooLarge(String),
    /// A call out of order (rendering before any frames were loaded): the caller's to fix.
    #[error("{0}")]
    Order(String),
    /// An inconsistent state inside the reprojector (a buffer it made is missing): a bug.
    #[error("{0}")]
    State(String),
}

/// Result alias of the GPU path.
pub type Result<T> = std::result::Result<T, GpuError>;
