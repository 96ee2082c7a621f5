//! # reproj-core
//!
//! The CPU kernels of splitrender: client-side image-based spatio-temporal reprojection for split
//! rendering, after Steiner et al. 2025 ("Image-Based Spatio-Temporal Interpolation for Split
//! Rendering", seeds/000), with the comparison methods of its evaluation.
//!
//! Conventions (coordinates, reversed depth, motion, shadow bits, timing) are those of
//! shared/DESIGN.md and are documented in [`camera`]. The crate knows nothing of Python; the
//! bindings live in `reproj-py`.
//!
//! Entry point: [`reproject()`], which writes one client frame into a caller-owned buffer holding the
//! previous client frame (pixels without a match keep that colour, seeds/000 §3.5 rule 3).

#![warn(missing_docs)]

pub mod backward_bidir;
pub mod camera;
pub mod dequant;
pub mod error;
pub mod frame;
pub mod memory;
pub mod method;
pub mod ours;
pub mod params;
pub mod pool;
pub mod request;
pub mod shadow;
mod simd;
pub mod ssim;
pub mod synthetic;
pub mod timewarp;

pub use backward_bidir::BidirHistory;
pub use camera::{Camera, Mat4, NdcTransfer, Projector, Rays, M4, MAX_SIDE};
pub use error::{ReprojError, Result};
pub use frame::{CameraBuffers, CameraView, FrameView, ShadowBuffers, ShadowView};
pub use method::{prepare_pair, reproject, Method};
/// The former name of [`ours`] (its public path before issue 12).
pub use ours as reproject;
pub use ours::scene_flow;
pub use params::{Params, TILE};
pub use request::{Diagnostics, Output, Request};
pub use shadow::{apply_shadows, shadow_color, Role};
