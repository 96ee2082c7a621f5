//! `backward_bidir`: image-space bidirectional reprojection of seeds/001 (Yang et al. 2011).
//! (Being written.)

use crate::error::Result;
use crate::frame::FrameView;
use crate::method::{Diagnostics, Request};
use crate::params::Params;

/// State carried from one client frame to the next for seeds/001's latest-frame initialisation.
#[derive(Debug, Clone, Default)]
pub struct BidirHistory {}

impl BidirHistory {
    /// An empty history (the first B-frame of a pair).
    pub fn new() -> Self {
        Self::default()
    }
}

/// Runs `backward_bidir`. See the module docs.
///
/// # Errors
/// Input errors only.
pub fn run(
    _older: &FrameView,
    _newer: &FrameView,
    _request: &Request,
    _params: &Params,
    _out: &mut [u8],
    _diag: Option<&mut Diagnostics>,
    _history: Option<&mut BidirHistory>,
) -> Result<()> {
    Ok(())
}
