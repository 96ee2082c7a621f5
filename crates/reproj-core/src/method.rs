//! Method selection by name and the single entry point [`reproject`], which checks the inputs and
//! dispatches to the methods' modules (it only dispatches: what the methods share lives below them,
//! in [`crate::request`]).

use std::fmt;
use std::str::FromStr;

use crate::backward_bidir::{self, BidirHistory};
use crate::camera::Camera;
use crate::error::{ReprojError, Result};
use crate::frame::FrameView;
use crate::params::Params;
use crate::request::Output;
use crate::{ours, timewarp};

// The public paths these had when they were defined here.
pub use crate::request::{Diagnostics, Request, MAX_ALPHA};

/// The reprojection methods of shared/DESIGN.md "Methods".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Method {
    /// seeds/000: splat-initialised bidirectional FPI at the client pose, Algorithms 1–2 with the
    /// motion-cancel check, auxiliary cameras, shadow application; extrapolates when `α ≥ 1`.
    Ours,
    /// `Ours` from the newest frame alone (unidirectional extrapolation, `α ≥ 1`).
    OursExtrapolate,
    /// Depth-aware point splatting and a 3×3 nearest search, no FPI (seeds/000 §4.2); from the
    /// newest frame unless [`Params::splat_bidirectional`].
    ForwardSplat,
    /// Planar reprojection of the current frame at its average depth.
    Timewarp,
    /// seeds/001: image-space bidirectional reprojection interpolating between the two server NDC
    /// spaces (ignores the client pose).
    BackwardBidir,
}

impl Method {
    /// Every method, in the order of the paper's tables.
    pub const ALL: [Method; 5] = [
        Method::Ours,
        Method::OursExtrapolate,
        Method::ForwardSplat,
        Method::Timewarp,
        Method::BackwardBidir,
    ];

    /// The method's name as used everywhere (CLI, Python, results files).
    pub fn name(&self) -> &'static str {
        match self {
            Method::Ours => "ours",
            Method::OursExtrapolate => "ours_extrapolate",
            Method::ForwardSplat => "forward_splat",
            Method::Timewarp => "timewarp",
            Method::BackwardBidir => "backward_bidir",
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = ReprojError;
    fn from_str(s: &str) -> Result<Method> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| ReprojError::UnknownMethod(s.to_string()))
    }
}

/// Synthesises one client frame with `method` into `out`.
///
/// `out.image` (`H·W·3` RGB8 at the client camera's size) holds the previous client frame on
/// entry; pixels without a match keep it; `out.diag`, when given, receives the per-pixel
/// [`Diagnostics`]. `older` is `F_t` (with its forward motion and shadows), `newer`
/// is `F_{t+1}` (with its backward motion and shadows). Unidirectional methods (ours_extrapolate,
/// forward_splat, timewarp) use `newer` alone when `α ≥ 1` or `older` is `None`; timewarp uses
/// `older` when `α < 1`.
///
/// `history` is the client's state for the current server-frame pair: `backward_bidir` reads and
/// updates its previous B-frame (seeds/001 latest-frame initialisation), and `ours`,
/// `ours_extrapolate` and `forward_splat` keep the work that does not depend on the client pose
/// there ([`crate::ours::PairCache`]), so that it is done once per pair instead of once per
/// client frame. The caller resets it when the frame pair changes; `None` gives the same output.
///
/// # Errors
/// Any [`ReprojError`] about the inputs; nothing is written to `out` then.
pub fn reproject(
    method: Method,
    older: Option<&FrameView>,
    newer: &FrameView,
    request: &Request,
    params: &Params,
    out: Output,
    history: Option<&mut BidirHistory>,
) -> Result<()> {
    let (cw, ch) = (request.client.width, request.client.height);
    let check = || out.check(cw, ch);
    match route(method, older, newer, request, params, check)? {
        Route::Splat(mode, older_used) => ours::run(
            mode,
            older_used,
            newer,
            request,
            params,
            out,
            history.map(BidirHistory::pair_cache),
        ),
        Route::Timewarp(frame) => timewarp::run(frame, request, params, out),
        Route::BackwardBidir(older) => {
            backward_bidir::run(older, newer, request, params, out, history)
        }
    }
}

/// Computes into `history` the pair-level state that the next [`reproject`] call with the same
/// method, frames and parameters would otherwise compute on its own ([`crate::ours::PairCache`]:
/// Algorithm 2's correspondences and the auxiliary cameras' visibility in main), and nothing of
/// a client frame. A client calls it when the pair's newer frame arrives, off the display path,
/// so that the first client frame of the pair costs what the others do.
///
/// The pair state depends on whether the frames are interpolated or extrapolated, not on the
/// client pose or on `α` otherwise: with `older` given, this prepares interpolation (every
/// `α < 1`) for the methods that interpolate (`ours`, `forward_splat` with
/// [`Params::splat_bidirectional`]); without it, and for `ours_extrapolate` and unidirectional
/// `forward_splat`, extrapolation from `newer` (`α ≥ 1`). `client` is checked as [`reproject`]
/// checks it; the state does not depend on it. Methods without pair state (`timewarp`,
/// `backward_bidir`) check their inputs and do nothing.
///
/// Work already in `history` for the same pair is kept (the call then does nothing);
/// [`BidirHistory::pair_builds`] counts the computations.
///
/// # Errors
/// Any [`ReprojError`] [`reproject`] gives for these inputs at that `α`; `history` is unchanged
/// then.
pub fn prepare_pair(
    method: Method,
    older: Option<&FrameView>,
    newer: &FrameView,
    client: &Camera,
    params: &Params,
    history: &mut BidirHistory,
) -> Result<()> {
    let interpolates = older.is_some()
        && (method == Method::Ours
            || (method == Method::ForwardSplat && params.splat_bidirectional));
    let request = Request {
        client: *client,
        alpha: if interpolates { 0.0 } else { 1.0 },
    };
    match route(method, older, newer, &request, params, || Ok(()))? {
        Route::Splat(mode, older_used) => {
            ours::prepare(mode, older_used, newer, params, history.pair_cache())
        }
        Route::Timewarp(_) | Route::BackwardBidir(_) => Ok(()),
    }
}

/// Where [`reproject`] sends a call, once its inputs are checked.
enum Route<'f, 'a> {
    /// The splat-based kernel ([`ours::run`]) in this mode, with the older frame when it takes
    /// part.
    Splat(ours::Mode, Option<&'f FrameView<'a>>),
    /// Timewarp from this frame.
    Timewarp(&'f FrameView<'a>),
    /// `backward_bidir` with this older frame (and the newer one).
    BackwardBidir(&'f FrameView<'a>),
}

/// Checks what every method shares (parameters, client camera, `output`: the caller's output
/// buffers, then `α`'s range and the frame pair) and what each method needs of `older` and `α`;
/// shared by [`reproject`] and [`prepare_pair`], so that both accept exactly the same calls.
fn route<'f, 'a>(
    method: Method,
    older: Option<&'f FrameView<'a>>,
    newer: &'f FrameView<'a>,
    request: &Request,
    params: &Params,
    output: impl FnOnce() -> Result<()>,
) -> Result<Route<'f, 'a>> {
    params.validate()?;
    request.client.projector("client camera")?;
    output()?;
    let alpha = request.alpha;
    let range_err = |range: &str| ReprojError::AlphaRange {
        alpha,
        method: method.name().into(),
        range: range.into(),
    };
    if !(alpha.is_finite() && (0.0..=MAX_ALPHA).contains(&alpha)) {
        return Err(range_err("[0, 3]"));
    }
    FrameView::validate_pair(older, newer)?;
    // The splat-based methods share one kernel; they differ in its mode and whether the older
    // frame takes part. Interpolating (`α < 1`) needs the older frame; the unidirectional
    // variants only extrapolate.
    let interpolating = |missing: &str| match older {
        None if alpha < 1.0 => Err(ReprojError::MissingFrame(missing.into())),
        _ => Ok(older),
    };
    let extrapolating = |range: &str| {
        if alpha < 1.0 {
            Err(range_err(range))
        } else {
            Ok(None)
        }
    };
    Ok(match method {
        Method::Ours => Route::Splat(
            ours::Mode::Ours,
            interpolating("method 'ours' interpolates for alpha < 1 and needs the older frame; pass it, or use alpha >= 1 to extrapolate from the newer frame")?,
        ),
        Method::OursExtrapolate => Route::Splat(
            ours::Mode::Ours,
            extrapolating("[1, 3] (extrapolation from the newest frame, given as `newer`)")?,
        ),
        Method::ForwardSplat if params.splat_bidirectional => Route::Splat(
            ours::Mode::ForwardSplat,
            interpolating("bidirectional forward_splat with alpha < 1 needs the older frame")?,
        ),
        Method::ForwardSplat => Route::Splat(
            ours::Mode::ForwardSplat,
            extrapolating(
                "[1, 3] (unidirectional splatting from the newest frame, given as `newer`)",
            )?,
        ),
        Method::Timewarp => Route::Timewarp(match older {
            Some(o) if alpha < 1.0 => o,
            _ => newer,
        }),
        Method::BackwardBidir => {
            let older = older.ok_or_else(|| {
                ReprojError::MissingFrame("method 'backward_bidir' needs both frames".into())
            })?;
            // α > 1 is refused by the kernel itself (backward_bidir::reproject), which is
            // also called directly.
            Route::BackwardBidir(older)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for m in Method::ALL {
            assert_eq!(m.name().parse::<Method>().unwrap(), m);
            assert_eq!(m.to_string(), m.name());
        }
        // The names of DESIGN.md "Methods", in the order of the paper's tables.
        let names = Method::ALL.map(|m| m.name());
        assert_eq!(
            names,
            [
                "ours",
                "ours_extrapolate",
                "forward_splat",
                "timewarp",
                "backward_bidir"
            ]
        );
        assert!(matches!(
            "nope".parse::<Method>(),
            Err(ReprojError::UnknownMethod(_))
        ));
    }

    /// Which frames each method takes, and the errors when `α` or a frame does not fit it:
    /// timewarp warps the older frame before `α = 1` and the newer one from there (or when the
    /// older is missing); interpolation needs the older frame; the extrapolating methods refuse
    /// `α < 1`, backward_bidir `α > 1`, every method `α` outside `[0, 3]` or NaN.
    #[test]
    fn calls_are_routed_by_alpha_and_the_frames_given() {
        use crate::camera::Mat4;
        use crate::frame::CameraBuffers;
        let (w, h) = (8, 6);
        let cam = Camera::new(
            Mat4::look_at([0.0; 3], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]),
            Mat4::perspective(60.0, w as f64 / h as f64, 0.1, 100.0),
            w,
            h,
            "test",
        )
        .unwrap();
        // Two flat frames of one colour each at 5 m.
        let frame = |rgb: u8| {
            let mut b = CameraBuffers::zeroed(w, h);
            b.color.fill(rgb);
            b.depth.fill(0.1 * 95.0 / (5.0 * 99.9));
            b
        };
        let (ob, nb) = (frame(40), frame(90));
        let (older, newer) = (
            FrameView {
                main: ob.view(cam, true),
                aux: vec![],
            },
            FrameView {
                main: nb.view(cam, false),
                aux: vec![],
            },
        );
        let call = |m: Method, older: Option<&FrameView>, alpha: f32| {
            let mut out = vec![0u8; w * h * 3];
            let request = Request { client: cam, alpha };
            let p = Params::default();
            reproject(m, older, &newer, &request, &p, Output::new(&mut out), None).map(|()| out)
        };
        let tw = Method::Timewarp;
        assert!(call(tw, Some(&older), 0.5)
            .unwrap()
            .iter()
            .all(|&v| v == 40));
        assert!(call(tw, Some(&older), 1.0)
            .unwrap()
            .iter()
            .all(|&v| v == 90));
        assert!(call(tw, None, 0.5).unwrap().iter().all(|&v| v == 90));
        let missing = |r: Result<Vec<u8>>| matches!(r, Err(ReprojError::MissingFrame(_)));
        let range = |r: Result<Vec<u8>>| matches!(r, Err(ReprojError::AlphaRange { .. }));
        assert!(missing(call(Method::Ours, None, 0.5)));
        assert!(call(Method::Ours, None, 1.0).is_ok());
        assert!(missing(call(Method::BackwardBidir, None, 0.5)));
        assert!(range(call(Method::BackwardBidir, Some(&older), 1.5)));
        assert!(range(call(Method::OursExtrapolate, Some(&older), 0.5)));
        assert!(range(call(Method::ForwardSplat, Some(&older), 0.5)));
        for m in Method::ALL {
            for alpha in [-0.1, 3.5, f32::NAN] {
                assert!(range(call(m, Some(&older), alpha)), "{m} at {alpha}");
            }
        }
    }

    #[test]
    fn more_auxiliary_cameras_than_diagnostic_codes_is_an_error() {
        use crate::frame::MAX_AUX;
        use crate::synthetic::{head_pose, rig, SyntheticFrame, SyntheticScene};
        let scene = SyntheticScene::new(false);
        let (w, h) = (32, 18);
        let f0 = SyntheticFrame::render(&scene, 0.0, w, h, 0.1, 4);
        let f1 = SyntheticFrame::render(&scene, 0.1, w, h, 0.1, 4);
        let (mut older, mut newer) = (f0.view(true), f1.view(false));
        let (e, t) = head_pose(0.05);
        let req = Request {
            client: rig(e, t, w, h).0,
            alpha: 0.5,
        };
        let mut out = vec![0u8; w * h * 3];
        let p = Params::default();
        let mut call = |older: &FrameView, newer: &FrameView| {
            reproject(
                Method::Ours,
                Some(older),
                newer,
                &req,
                &p,
                Output::new(&mut out),
                None,
            )
        };
        // At the limit: accepted.
        for v in [&mut older, &mut newer] {
            let a = v.aux[0];
            v.aux = vec![a; MAX_AUX];
        }
        call(&older, &newer).expect("MAX_AUX auxiliary cameras are supported");
        // One more: the error names the count and the limit.
        for v in [&mut older, &mut newer] {
            v.aux.push(v.aux[0]);
        }
        let err = call(&older, &newer).expect_err("too many auxiliary cameras");
        assert!(
            matches!(&err, ReprojError::CameraMismatch(m) if m.contains("63 auxiliary cameras") && m.contains("at most 62")),
            "{err}"
        );
    }
}
