//! `timewarp`: planar reprojection at the average depth. (Being written.)

use crate::error::Result;
use crate::frame::FrameView;
use crate::method::{Diagnostics, Request};
use crate::params::Params;

/// Runs `timewarp` from `frame`.
///
/// # Errors
/// Input errors only.
pub fn run(
    _frame: &FrameView,
    _request: &Request,
    _params: &Params,
    _out: &mut [u8],
    _diag: Option<&mut Diagnostics>,
) -> Result<()> {
    Ok(())
}
