//! Borrowed views of what the client holds of one server frame, and of the client's request.

use crate::camera::Camera;
use crate::error::{ReprojError, Result};

/// The dynamic-shadow buffers of one source image (seeds/000 §3.3): for every pixel a bitfield
/// with 2 bits per subframe (subframe `j` in bits `2j, 2j+1`, subframe 0 the key frame itself) and
/// the colours `S_min`/`S_max` at the minimum/maximum level. Bitfield 0 means "no dynamic shadow".
#[derive(Debug, Clone, Copy)]
pub struct ShadowView<'a> {
    /// `H·W` bitfields.
    pub bits: &'a [u32],
    /// `H·W·3` RGB8 colour at the minimum level (0 where that level is the key frame's).
    pub s_min: &'a [u8],
    /// `H·W·3` RGB8 colour at the maximum level (0 where that level is the key frame's).
    pub s_max: &'a [u8],
}

/// One camera of one server frame, with the directional buffers for the role it plays in a pair:
/// for the older frame `F_t` the forward motion `O_{t→t+1}` and forward shadows; for the newer
/// frame `F_{t+1}` the backward motion `O_{t+1→t}` and backward shadows.
#[derive(Debug, Clone, Copy)]
pub struct CameraView<'a> {
    /// The server camera `C` at this frame's time.
    pub camera: Camera,
    /// `H·W·3` RGB8 colour `I`.
    pub color: &'a [u8],
    /// `H·W` reversed depth `Z`. NaN or infinite marks a pixel invalid.
    pub depth: &'a [f32],
    /// `H·W·3` object motion in this camera's NDC (DESIGN.md). `None` means static (all zero).
    pub motion: Option<&'a [f32]>,
    /// Dynamic-shadow buffers of this direction; `None` disables shadow application for it.
    pub shadow: Option<ShadowView<'a>>,
}

/// The cameras of one server frame: the main camera and the auxiliary cameras, in rig order.
#[derive(Debug, Clone)]
pub struct FrameView<'a> {
    /// The main camera.
    pub main: CameraView<'a>,
    /// The auxiliary cameras (empty when the frame has none).
    pub aux: Vec<CameraView<'a>>,
}

/// [`ReprojError::BufferSize`] when a buffer holds `actual` elements instead of `expected`:
/// `what` names it and `detail` gives the expected shape. Both are built only for the error
/// (this runs for every buffer of every camera of every frame).
pub(crate) fn check_len(
    actual: usize,
    expected: usize,
    what: impl FnOnce() -> String,
    detail: impl FnOnce() -> String,
) -> Result<()> {
    if actual != expected {
        return Err(ReprojError::BufferSize {
            what: what(),
            expected,
            actual,
            detail: detail(),
        });
    }
    Ok(())
}

impl CameraView<'_> {
    /// Checks the camera's size, then every buffer against it.
    ///
    /// # Errors
    /// [`ReprojError::BadSize`] when a side of the camera is zero or above
    /// [`crate::MAX_SIDE`] ([`Camera::check_size`]); [`ReprojError::BufferSize`] naming the first
    /// buffer whose length is wrong.
    pub fn validate(&self, what: &str) -> Result<()> {
        if !self.camera.size_ok() {
            // The label is built only for the error: this runs for every camera of every frame.
            self.camera.check_size(&format!("{what} camera"))?;
        }
        let (w, h) = (self.camera.width, self.camera.height);
        let n = w * h;
        check_len(
            self.color.len(),
            n * 3,
            || format!("{what}.color"),
            || format!("{h}x{w}x3"),
        )?;
        check_len(
            self.depth.len(),
            n,
            || format!("{what}.depth"),
            || format!("{h}x{w}"),
        )?;
        if let Some(m) = self.motion {
            check_len(
                m.len(),
                n * 3,
                || format!("{what}.motion"),
                || format!("{h}x{w}x3"),
            )?;
        }
        if let Some(s) = &self.shadow {
            check_len(
                s.bits.len(),
                n,
                || format!("{what}.shadow.bits"),
                || format!("{h}x{w}"),
            )?;
            check_len(
                s.s_min.len(),
                n * 3,
                || format!("{what}.shadow.s_min"),
                || format!("{h}x{w}x3"),
            )?;
            check_len(
                s.s_max.len(),
                n * 3,
                || format!("{what}.shadow.s_max"),
                || format!("{h}x{w}x3"),
            )?;
        }
        Ok(())
    }

    /// The motion of pixel `idx`, zero when the frame carries none.
    #[inline(always)]
    pub fn motion_at(&self, idx: usize) -> [f32; 3] {
        match self.motion {
            Some(m) => [m[3 * idx], m[3 * idx + 1], m[3 * idx + 2]],
            None => [0.0; 3],
        }
    }

    /// What state derived from this view's geometry and kept across calls (`ours`' pair state,
    /// `backward_bidir`'s full flows) depends on: the view-projection matrix, the size, and the
    /// depth and motion buffers' addresses and lengths. The buffers are compared by address, not
    /// content: a caller that rewrites them in place with another frame resets that state.
    pub(crate) fn geometry_key(&self) -> GeometryKey {
        let (mp, ml) = self
            .motion
            .map_or((0, 0), |m| (m.as_ptr() as usize, m.len()));
        let (dp, dl) = (self.depth.as_ptr() as usize, self.depth.len());
        let (w, h) = (self.camera.width, self.camera.height);
        GeometryKey(self.camera.view_proj().0, [w, h, dp, dl, mp, ml])
    }
}

/// [`CameraView::geometry_key`].
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct GeometryKey([[f64; 4]; 4], [usize; 6]);

/// The dynamic-shadow buffers of one direction, owned (DESIGN.md "Dynamic shadows"); borrowed as a
/// [`ShadowView`].
#[derive(Debug, Clone, PartialEq)]
pub struct ShadowBuffers {
    /// `H·W` bitfields: 2 bits per subframe, subframe `j` in bits `2j, 2j+1`; 0 where the level is
    /// the same at every subframe.
    pub bits: Vec<u32>,
    /// `H·W·3` RGB8 colour at the minimum level; 0 where that level is subframe 0's or bits = 0.
    pub s_min: Vec<u8>,
    /// `H·W·3` RGB8 colour at the maximum level; 0 where that level is subframe 0's or bits = 0.
    pub s_max: Vec<u8>,
}

impl ShadowBuffers {
    /// `n` pixels of zeros ("no dynamic shadow").
    pub fn zeroed(n: usize) -> Self {
        ShadowBuffers {
            bits: vec![0; n],
            s_min: vec![0; 3 * n],
            s_max: vec![0; 3 * n],
        }
    }

    fn with_capacity(n: usize) -> Self {
        ShadowBuffers {
            bits: Vec::with_capacity(n),
            s_min: Vec::with_capacity(3 * n),
            s_max: Vec::with_capacity(3 * n),
        }
    }

    fn extend(&mut self, other: &ShadowBuffers) {
        self.bits.extend_from_slice(&other.bits);
        self.s_min.extend_from_slice(&other.s_min);
        self.s_max.extend_from_slice(&other.s_max);
    }

    /// Borrows the buffers.
    pub fn view(&self) -> ShadowView<'_> {
        ShadowView {
            bits: &self.bits,
            s_min: &self.s_min,
            s_max: &self.s_max,
        }
    }
}

/// Every server buffer of one camera at one time, owned, with both directions: what a renderer
/// produces. [`CameraBuffers::view`] borrows it as the older or the newer image of a pair.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraBuffers {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// `H·W·3` RGB8 colour (continuous soft shadow).
    pub color: Vec<u8>,
    /// `H·W` reversed depth; 0 for the sky.
    pub depth: Vec<f32>,
    /// `H·W·3` object motion `P(X_{t+Δ}) − P(X_t)` in this camera's NDC, camera held fixed.
    pub motion_fwd: Vec<f32>,
    /// `H·W·3` object motion `P(X_{t−Δ}) − P(X_t)` in this camera's NDC, camera held fixed.
    pub motion_bwd: Vec<f32>,
    /// Shadow buffers toward `t + Δ`: subframe `j` at `t + jΔ/S`.
    pub shadow_fwd: ShadowBuffers,
    /// Shadow buffers toward `t − Δ`: subframe `j` at `t − jΔ/S`.
    pub shadow_bwd: ShadowBuffers,
}

impl CameraBuffers {
    /// `width × height` pixels of zeros: black, sky depth, no motion, no dynamic shadow.
    pub fn zeroed(width: usize, height: usize) -> Self {
        let n = width * height;
        CameraBuffers {
            width,
            height,
            color: vec![0; 3 * n],
            depth: vec![0.0; n],
            motion_fwd: vec![0.0; 3 * n],
            motion_bwd: vec![0.0; 3 * n],
            shadow_fwd: ShadowBuffers::zeroed(n),
            shadow_bwd: ShadowBuffers::zeroed(n),
        }
    }

    /// The `width × height` image whose rows are those of `blocks`, in order (each block
    /// `width` wide; a renderer's row blocks, rendered in parallel).
    pub fn from_row_blocks(
        width: usize,
        height: usize,
        blocks: impl IntoIterator<Item = CameraBuffers>,
    ) -> Self {
        let n = width * height;
        let mut out = CameraBuffers {
            width,
            height,
            color: Vec::with_capacity(3 * n),
            depth: Vec::with_capacity(n),
            motion_fwd: Vec::with_capacity(3 * n),
            motion_bwd: Vec::with_capacity(3 * n),
            shadow_fwd: ShadowBuffers::with_capacity(n),
            shadow_bwd: ShadowBuffers::with_capacity(n),
        };
        for b in blocks {
            debug_assert_eq!(b.width, width, "row block of another width");
            out.color.extend_from_slice(&b.color);
            out.depth.extend_from_slice(&b.depth);
            out.motion_fwd.extend_from_slice(&b.motion_fwd);
            out.motion_bwd.extend_from_slice(&b.motion_bwd);
            out.shadow_fwd.extend(&b.shadow_fwd);
            out.shadow_bwd.extend(&b.shadow_bwd);
        }
        out
    }

    /// The buffers seen from `camera` (the camera they were rendered at) as the older image of a
    /// pair (`forward = true`: forward motion and shadows) or the newer one (backward ones).
    pub fn view(&self, camera: Camera, forward: bool) -> CameraView<'_> {
        let (motion, shadow) = if forward {
            (&self.motion_fwd, &self.shadow_fwd)
        } else {
            (&self.motion_bwd, &self.shadow_bwd)
        };
        CameraView {
            camera,
            color: &self.color,
            depth: &self.depth,
            motion: Some(motion),
            shadow: Some(shadow.view()),
        }
    }
}

/// The most auxiliary cameras a frame may have (their diagnostic codes fit below
/// [`crate::Diagnostics::BLENDED`]).
pub const MAX_AUX: usize = 62;

impl FrameView<'_> {
    /// Checks every camera's size and buffers ([`CameraView::validate`]).
    ///
    /// # Errors
    /// The first [`ReprojError::BadSize`] or [`ReprojError::BufferSize`] found;
    /// [`ReprojError::CameraMismatch`] for more than [`MAX_AUX`] auxiliary cameras.
    pub fn validate(&self, what: &str) -> Result<()> {
        if self.aux.len() > MAX_AUX {
            // Each auxiliary camera of each frame has its own diagnostic code below the BLENDED
            // flag (`Diagnostics::AUX_BASE + 2i + 1 < 0x80`).
            return Err(ReprojError::CameraMismatch(format!(
                "{what}: {} auxiliary cameras; at most {MAX_AUX} are supported",
                self.aux.len()
            )));
        }
        self.main.validate(&format!("{what}.main"))?;
        for (i, a) in self.aux.iter().enumerate() {
            a.validate(&format!("{what}.aux[{i}]"))?;
        }
        Ok(())
    }

    /// Checks the frames of a server-frame pair: each frame's buffers ([`FrameView::validate`],
    /// as "newer" and "older"), and that both have the same number of auxiliary cameras.
    ///
    /// # Errors
    /// The first [`ReprojError::BadSize`] or [`ReprojError::BufferSize`] found, or
    /// [`ReprojError::CameraMismatch`].
    pub fn validate_pair(older: Option<&FrameView>, newer: &FrameView) -> Result<()> {
        newer.validate("newer")?;
        if let Some(o) = older {
            o.validate("older")?;
            if o.aux.len() != newer.aux.len() {
                return Err(ReprojError::CameraMismatch(format!(
                    "older frame has {} auxiliary cameras, newer has {}",
                    o.aux.len(),
                    newer.aux.len()
                )));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Mat4;

    fn camera(w: usize, h: usize) -> Camera {
        Camera::new(
            Mat4::look_at([0.0; 3], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]),
            Mat4::perspective(60.0, w as f64 / h as f64, 0.1, 100.0),
            w,
            h,
            "test",
        )
        .unwrap()
    }

    /// Each buffer of a camera must hold its size's elements: the first one that does not is
    /// named, with the element counts and the shape expected.
    #[test]
    fn validate_names_the_first_buffer_of_the_wrong_length() {
        let (w, h) = (4, 3);
        let b = CameraBuffers::zeroed(w, h);
        let good = b.view(camera(w, h), true);
        good.validate("newer").unwrap();
        let short_color = &b.color[1..];
        let short_depth = &b.depth[1..];
        let long_motion = [0.0f32; 4 * 3 * 3 + 3];
        let short_bits = &b.shadow_fwd.bits[1..];
        let cases: [(CameraView, &str, usize, usize); 4] = [
            (
                CameraView {
                    color: short_color,
                    ..good
                },
                "newer.color",
                36,
                35,
            ),
            (
                CameraView {
                    depth: short_depth,
                    ..good
                },
                "newer.depth",
                12,
                11,
            ),
            (
                CameraView {
                    motion: Some(&long_motion),
                    ..good
                },
                "newer.motion",
                36,
                39,
            ),
            (
                CameraView {
                    shadow: Some(ShadowView {
                        bits: short_bits,
                        ..good.shadow.unwrap()
                    }),
                    ..good
                },
                "newer.shadow.bits",
                12,
                11,
            ),
        ];
        for (view, name, want, got) in cases {
            match view.validate("newer") {
                Err(ReprojError::BufferSize {
                    what,
                    expected,
                    actual,
                    ..
                }) => assert_eq!((what.as_str(), expected, actual), (name, want, got)),
                other => panic!("{name}: {other:?}"),
            }
        }
    }

    #[test]
    fn validate_pair_needs_the_same_auxiliary_cameras() {
        let b = CameraBuffers::zeroed(4, 3);
        let view = b.view(camera(4, 3), true);
        let with = |aux: usize| FrameView {
            main: view,
            aux: vec![view; aux],
        };
        FrameView::validate_pair(Some(&with(2)), &with(2)).unwrap();
        FrameView::validate_pair(None, &with(1)).unwrap();
        match FrameView::validate_pair(Some(&with(1)), &with(2)) {
            Err(ReprojError::CameraMismatch(m)) => {
                assert_eq!(m, "older frame has 1 auxiliary cameras, newer has 2")
            }
            other => panic!("{other:?}"),
        }
    }
}
