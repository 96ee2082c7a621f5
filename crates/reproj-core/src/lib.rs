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
//!
//! ```
//! use reproj_core::synthetic::{head_pose, rig, SyntheticFrame, SyntheticScene};
//! use reproj_core::{reproject, Method, Output, Params, Request};
//!
//! // Two server frames 0.1 s apart (main camera 32×18 and two auxiliary cameras each), with
//! // 4 dynamic-shadow subframes: the older one with its forward motion, the newer with its
//! // backward motion.
//! let scene = SyntheticScene::new(true);
//! let (w, h) = (32, 18);
//! let f0 = SyntheticFrame::render(&scene, 0.0, w, h, 0.1, 4);
//! let f1 = SyntheticFrame::render(&scene, 0.1, w, h, 0.1, 4);
//! // The client's camera half way between them (α = 0.5).
//! let (eye, target) = head_pose(0.05);
//! let request = Request { client: rig(eye, target, w, h).0, alpha: 0.5 };
//! // The previous client frame; pixels without a match keep it.
//! let mut image = vec![0u8; w * h * 3];
//! reproject(
//!     Method::Ours,
//!     Some(&f0.view(true)),
//!     &f1.view(false),
//!     &request,
//!     &Params::default(),
//!     Output::new(&mut image),
//!     None,
//! )?;
//! # Ok::<(), reproj_core::ReprojError>(())
//! ```

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
pub mod quant;
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
