//! # reproj-wgpu
//!
//! The GPU twin of `reproj-core`: the client reprojection of splitrender (Steiner et al. 2025,
//! seeds/000 §3.5) for `ours`, `ours_extrapolate` and `forward_splat` as WGSL compute shaders run
//! by wgpu, with the same semantics and error messages as the CPU path.
//!
//! - `shaders/shared/*.wgsl`: bindings and types, camera maths (`camera.rs`), shadows
//!   (`shadow.rs`, eqs. 9–11), the scene flow of pass 1 (eqs. 1, 12, 13); `shaders/splat64.wgsl` and
//!   `shaders/splat32.wgsl`: the splat with a 64-bit atomic maximum, or with 32-bit atomics in two
//!   dispatches where the adapter lacks `SHADER_INT64_ATOMIC_MIN_MAX`; `shaders/resolve.wgsl`:
//!   window search, fixed-point iteration (eq. 5), Algorithms 1 and 2, auxiliary merge. Each
//!   function names the reproj-core function it mirrors, so the two read side by side.
//! - [`GpuContext`]: device creation, apart from the kernels ([`Reprojector::with_device`] takes a
//!   caller's device).
//! - [`Reprojector`]: loads a pair of server frames onto the device once
//!   ([`Reprojector::load`]), then renders client frames from a pose and `α`
//!   ([`Reprojector::render`]), downloading the image or leaving it on the device. A real-time
//!   client uploads the next pair on its receiving thread ([`Uploader::upload`]) and makes it
//!   current between two display frames ([`Reprojector::install`]).
//!
//! ```no_run
//! # fn main() -> Result<(), reproj_wgpu::GpuError> {
//! # let (older, newer, request): (reproj_core::FrameView, reproj_core::FrameView, reproj_core::Request) = todo!();
//! use reproj_wgpu::{ContextOptions, GpuContext, Previous, Reprojector, ReprojectorOptions};
//! let ctx = GpuContext::new(&ContextOptions::default())?;
//! let mut gpu = Reprojector::new(&ctx, &ReprojectorOptions::default())?;
//! gpu.load(Some(&older), &newer)?;
//! let mut image = vec![0u8; request.client.width * request.client.height * 3];
//! gpu.render(0, reproj_core::Method::Ours, &request, &Default::default(), Previous::Keep,
//!            Some(&mut image), None)?;
//! # Ok(()) }
//! ```
//!
//! On a machine without a desktop session (a server, a CI runner, a cluster node), Mesa's Vulkan
//! device-selection layer, which the loader runs in every process that makes an instance, asks
//! the Wayland library for the desktop's GPU, and that library writes "error: XDG_RUNTIME_DIR is
//! invalid or not set in the environment." to stderr. There is no desktop GPU to find there:
//! set `NODEVICE_SELECT=1` (the layer's own switch) in the environment before the process
//! starts, as the Python package does for itself (`splitrender.gpu`) and `scripts/test.sh` for
//! these tests. A library cannot safely set it for its caller: other threads may read the
//! environment at the same time.

#![warn(missing_docs)]

pub mod context;
pub mod error;
mod layout;
pub mod reprojector;
pub mod shaders;

pub use context::{ContextOptions, DeviceLoss, GpuContext};
pub use error::{GpuError, Result};
pub use reprojector::{
    Atomics, Previous, Reprojector, ReprojectorOptions, UploadedPair, Uploader, MAX_CAMERAS,
    MAX_OUTPUTS,
};
