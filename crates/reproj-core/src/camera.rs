//! Cameras and the conventions of shared/DESIGN.md.
//!
//! - NDC `x ∈ [−1,1]` left→right, `y ∈ [−1,1]` bottom→top; the pixel centre of column `i`, row `j`
//!   is `x = (2i+1)/W − 1`, `y = 1 − (2j+1)/H` (row 0 at the top).
//! - Reversed depth `Z ∈ [0,1]`: 1 at the near plane, 0 at the (finite) far plane.
//! - Matrices are row-major 4×4 acting on column vectors: `clip = P · [x, y, z, 1]ᵀ`.
//!
//! Matrices arrive in `f64` (the API's precision), are combined and inverted in `f64`, and only
//! then rounded to `f32` for the kernels, so that the inverse is as exact as the data allows.

use crate::error::{ReprojError, Result};

/// Largest image side the kernels accept. Splat keys store a linear pixel index in 32 bits, and
/// anything larger than this is certainly a corrupted header rather than a real camera.
pub const MAX_SIDE: usize = 16384;

/// A row-major 4×4 matrix in `f64`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mat4(pub [[f64; 4]; 4]);

impl Mat4 {
    /// The identity.
    pub const IDENTITY: Mat4 = Mat4([
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]);

    /// Builds a matrix from 16 row-major values.
    pub fn from_row_major(v: &[f64; 16]) -> Mat4 {
        let mut m = [[0.0; 4]; 4];
        for r in 0..4 {
            for c in 0..4 {
                m[r][c] = v[r * 4 + c];
            }
        }
        Mat4(m)
    }

    /// `self · other`.
    pub fn mul(&self, other: &Mat4) -> Mat4 {
        let mut m = [[0.0; 4]; 4];
        for (r, row) in m.iter_mut().enumerate() {
            for (c, out) in row.iter_mut().enumerate() {
                *out = (0..4).map(|k| self.0[r][k] * other.0[k][c]).sum();
            }
        }
        Mat4(m)
    }

    /// `self · v` for a column vector.
    pub fn mul_vec(&self, v: [f64; 4]) -> [f64; 4] {
        let mut o = [0.0; 4];
        for (r, out) in o.iter_mut().enumerate() {
            *out = (0..4).map(|k| self.0[r][k] * v[k]).sum();
        }
        o
    }

    /// The inverse by Gauss–Jordan elimination with partial pivoting, or `None` if the matrix is
    /// singular (pivot below `1e-12` relative to the largest entry) or holds non-finite values.
    pub fn inverse(&self) -> Option<Mat4> {
        let scale = self.0.iter().flatten().fold(0.0f64, |a, &b| a.max(b.abs()));
        if !scale.is_finite() || scale == 0.0 {
            return None;
        }
        let mut a = self.0;
        let mut inv = Mat4::IDENTITY.0;
        for col in 0..4 {
            let pivot = (col..4)
                .max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))
                .unwrap_or(col);
            if a[pivot][col].abs() <= 1e-12 * scale {
                return None;
            }
            a.swap(col, pivot);
            inv.swap(col, pivot);
            let d = a[col][col];
            for k in 0..4 {
                a[col][k] /= d;
                inv[col][k] /= d;
            }
            for r in 0..4 {
                if r != col {
                    let f = a[r][col];
                    if f != 0.0 {
                        for k in 0..4 {
                            a[r][k] -= f * a[col][k];
                            inv[r][k] -= f * inv[col][k];
                        }
                    }
                }
            }
        }
        let out = Mat4(inv);
        out.0.iter().flatten().all(|v| v.is_finite()).then_some(out)
    }

    /// A reversed-depth perspective projection with a finite far plane (DESIGN.md): vertical field
    /// of view `fov_y_deg`, `aspect = W/H`; view-space depth `d = −z` maps to
    /// `Z = n(f − d) / (d(f − n))`, 1 at the near plane and 0 at the far plane.
    pub fn perspective(fov_y_deg: f64, aspect: f64, near: f64, far: f64) -> Mat4 {
        let fy = 1.0 / (fov_y_deg.to_radians() * 0.5).tan();
        let a = near / (far - near);
        let b = near * far / (far - near);
        Mat4([
            [fy / aspect, 0.0, 0.0, 0.0],
            [0.0, fy, 0.0, 0.0],
            [0.0, 0.0, a, b],
            [0.0, 0.0, -1.0, 0.0],
        ])
    }

    /// World→camera matrix of a camera at `eye` looking at `target` (the camera looks along its −z,
    /// +y up as close to `up` as possible).
    pub fn look_at(eye: [f64; 3], target: [f64; 3], up: [f64; 3]) -> Mat4 {
        let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let norm = |a: [f64; 3]| {
            let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            [a[0] / l, a[1] / l, a[2] / l]
        };
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let f = norm(sub(target, eye));
        let x = norm(cross(f, up));
        let y = cross(x, f);
        let z = [-f[0], -f[1], -f[2]];
        Mat4([
            [x[0], x[1], x[2], -dot(x, eye)],
            [y[0], y[1], y[2], -dot(y, eye)],
            [z[0], z[1], z[2], -dot(z, eye)],
            [0.0, 0.0, 0.0, 1.0],
        ])
    }

    /// The matrix rounded to `f32`, row-major.
    pub fn to_f32(&self) -> M4 {
        let mut m = [0.0f32; 16];
        for r in 0..4 {
            for c in 0..4 {
                m[r * 4 + c] = self.0[r][c] as f32;
            }
        }
        M4(m)
    }
}

/// A row-major 4×4 matrix in `f32`, as the kernels use it (and as the WGSL twin will).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct M4(pub [f32; 16]);

impl M4 {
    /// `self · (x, y, z, 1)ᵀ`, the full homogeneous result.
    #[inline(always)]
    pub fn apply(&self, p: [f32; 3]) -> [f32; 4] {
        let m = &self.0;
        [
            m[0] * p[0] + m[1] * p[1] + m[2] * p[2] + m[3],
            m[4] * p[0] + m[5] * p[1] + m[6] * p[2] + m[7],
            m[8] * p[0] + m[9] * p[1] + m[10] * p[2] + m[11],
            m[12] * p[0] + m[13] * p[1] + m[14] * p[2] + m[15],
        ]
    }

    /// `self · (x, y, z, 1)ᵀ` followed by the perspective division. The result is NaN-free only
    /// when `w ≠ 0`; callers that need to reject points behind the camera use [`M4::apply`].
    #[inline(always)]
    pub fn project(&self, p: [f32; 3]) -> [f32; 3] {
        let h = self.apply(p);
        let iw = 1.0 / h[3];
        [h[0] * iw, h[1] * iw, h[2] * iw]
    }
}

/// A pinhole camera: world→camera `view`, camera→clip `proj` (reversed depth), and image size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// World → camera (the camera looks along its −z).
    pub view: Mat4,
    /// Camera → clip, reversed depth in `[0,1]`.
    pub proj: Mat4,
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
}

impl Camera {
    /// Creates a camera, checking the size.
    ///
    /// # Errors
    /// [`ReprojError::BadSize`] when a side is zero or above [`MAX_SIDE`].
    pub fn new(view: Mat4, proj: Mat4, width: usize, height: usize, what: &str) -> Result<Camera> {
        let camera = Camera {
            view,
            proj,
            width,
            height,
        };
        camera.check_size(what)?;
        Ok(camera)
    }

    /// Checks the size: each side in `1..=`[`MAX_SIDE`]. The fields are public, so a camera
    /// built without [`Camera::new`] may hold any size; every entry point that takes one
    /// ([`crate::reproject()`], [`Camera::projector`], [`crate::CameraView::validate`]) checks
    /// it with this before using it.
    ///
    /// # Errors
    /// [`ReprojError::BadSize`] when a side is zero or above [`MAX_SIDE`].
    pub fn check_size(&self, what: &str) -> Result<()> {
        let (width, height) = (self.width, self.height);
        if !self.size_ok() {
            return Err(ReprojError::BadSize {
                what: what.to_string(),
                width,
                height,
                max: MAX_SIDE,
            });
        }
        Ok(())
    }

    /// Whether each side is in `1..=`[`MAX_SIDE`] ([`Camera::check_size`] without the error,
    /// for callers that build the error's label only when it is needed).
    pub(crate) fn size_ok(&self) -> bool {
        (1..=MAX_SIDE).contains(&self.width) && (1..=MAX_SIDE).contains(&self.height)
    }

    /// `P = proj · view` in `f64`.
    pub fn view_proj(&self) -> Mat4 {
        self.proj.mul(&self.view)
    }

    /// The kernel-side form of this camera: `P` and `P⁻¹` in `f32`.
    ///
    /// # Errors
    /// [`ReprojError::BadSize`] when a side is zero or above [`MAX_SIDE`] (checked first,
    /// [`Camera::check_size`]); [`ReprojError::SingularMatrix`] when `P` cannot be inverted.
    pub fn projector(&self, what: &str) -> Result<Projector> {
        self.check_size(what)?;
        let vp = self.view_proj();
        let inv = vp.inverse().ok_or_else(|| ReprojError::SingularMatrix {
            what: what.to_string(),
        })?;
        Ok(Projector {
            vp: vp.to_f32(),
            inv_vp: inv.to_f32(),
            width: self.width,
            height: self.height,
        })
    }
}

/// A camera's rays, for ray casting a scene from it (the analytic scene of [`crate::synthetic`]
/// and reproj-scene's renderer): its centre and `P⁻¹` for the pixel directions, in `f64`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rays {
    vp: Mat4,
    inv_vp: Mat4,
    /// The camera's centre (world).
    pub origin: [f64; 3],
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
}

impl Rays {
    /// The rays of `camera`.
    ///
    /// # Errors
    /// The matrix that cannot be inverted, in words: `"singular view-projection"` (checked first)
    /// or `"singular view"`.
    pub fn new(camera: &Camera) -> std::result::Result<Rays, &'static str> {
        let vp = camera.view_proj();
        let inv_vp = vp.inverse().ok_or("singular view-projection")?;
        let iv = camera.view.inverse().ok_or("singular view")?;
        let o = iv.mul_vec([0.0, 0.0, 0.0, 1.0]);
        Ok(Rays {
            vp,
            inv_vp,
            origin: [o[0] / o[3], o[1] / o[3], o[2] / o[3]],
            width: camera.width,
            height: camera.height,
        })
    }

    /// The ray through the centre of pixel `(i, j)`, scaled so that the parameter `s = 1` is the
    /// near plane (so "in front of the near plane" is `s ≥ 1`).
    #[inline]
    pub fn ray(&self, i: usize, j: usize) -> [f64; 3] {
        self.sub_ray(i, j, 0, 0, 1)
    }

    /// The ray through sub-sample `(a, b)` of the `n×n` ordered grid of pixel `(i, j)`, at
    /// `(i + (a + ½)/n, j + (b + ½)/n)` pixels. Numerator and denominator are integers, so the
    /// middle sub-sample of an odd grid is the pixel-centre ray bit for bit.
    #[inline]
    pub fn sub_ray(&self, i: usize, j: usize, a: usize, b: usize, n: usize) -> [f64; 3] {
        self.sub_ray_at(self.sub_ray_column(i, a, n), self.sub_ray_row(j, b, n))
    }

    /// What [`Rays::sub_ray`] takes from the grid column `n·i + a` alone: the products of `P⁻¹`'s
    /// first column with its `x`. A renderer that casts many rays per column (every row's) computes
    /// them once ([`Rays::sub_ray_at`]).
    #[inline]
    pub fn sub_ray_column(&self, i: usize, a: usize, n: usize) -> [f64; 4] {
        let x = (2 * n * i + 2 * a + 1) as f64 / (n * self.width) as f64 - 1.0;
        self.inv_vp.0.map(|r| r[0] * x)
    }

    /// What [`Rays::sub_ray`] takes from the grid row `n·j + b` alone (as
    /// [`Rays::sub_ray_column`], with `P⁻¹`'s second column and the row's `y`).
    #[inline]
    pub fn sub_ray_row(&self, j: usize, b: usize, n: usize) -> [f64; 4] {
        let y = 1.0 - (2 * n * j + 2 * b + 1) as f64 / (n * self.height) as f64;
        self.inv_vp.0.map(|r| r[1] * y)
    }

    /// The sub-sample ray of a grid column and row ([`Rays::sub_ray_column`],
    /// [`Rays::sub_ray_row`]): `P⁻¹·(x, y, 1, 1)` summed term by term in [`Mat4::mul_vec`]'s order,
    /// so the ray is that of `mul_vec` bit for bit.
    #[inline]
    pub fn sub_ray_at(&self, column: [f64; 4], row: [f64; 4]) -> [f64; 3] {
        let m = &self.inv_vp.0;
        let h: [f64; 4] = std::array::from_fn(|r| {
            [column[r], row[r], m[r][2] * 1.0, m[r][3] * 1.0]
                .iter()
                .sum()
        });
        let o = self.origin;
        [h[0] / h[3] - o[0], h[1] / h[3] - o[1], h[2] / h[3] - o[2]]
    }

    /// `P(X)` with the perspective division.
    #[inline]
    pub fn project(&self, x: [f64; 3]) -> [f64; 3] {
        let h = self.vp.mul_vec([x[0], x[1], x[2], 1.0]);
        [h[0] / h[3], h[1] / h[3], h[2] / h[3]]
    }
}

/// A camera ready for the kernels: `P` and `P⁻¹` in `f32` plus its pixel grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projector {
    /// `P = proj · view`.
    pub vp: M4,
    /// `P⁻¹`.
    pub inv_vp: M4,
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
}

impl Projector {
    /// NDC of the centre of pixel `(i, j)`: `x = (2i+1)/W − 1`, `y = 1 − (2j+1)/H`.
    #[inline(always)]
    pub fn ndc_of_pixel(&self, i: usize, j: usize) -> [f32; 2] {
        ndc_of_pixel(i, j, self.width, self.height)
    }

    /// The pixel containing NDC point `(x, y)`, or `None` outside the image (or for NaN).
    #[inline(always)]
    pub fn pixel_of_ndc(&self, x: f32, y: f32) -> Option<(usize, usize)> {
        pixel_of_ndc(x, y, self.width, self.height)
    }

    /// World point of NDC `(x, y, Z)`: `P⁻¹(p̄)` with the perspective division.
    #[inline(always)]
    pub fn unproject(&self, ndc: [f32; 3]) -> [f32; 3] {
        self.inv_vp.project(ndc)
    }
}

/// The map from one camera's NDC to another camera's clip space, `P_to · P_from⁻¹`, composed in
/// `f64` and rounded once to `f32`, with the homogeneous `w` of the world point (row 3 of
/// `P_from⁻¹`) kept apart.
///
/// `P_to(P_from⁻¹(c̄))` needs two matrix products and a division in between; the composite needs one
/// product. The world `w` still matters twice: its sign tells whether the point is in front of
/// `P_to` (`clip.w / w_world > 0`), and blending two world points (object motion applied linearly in
/// world space) must weight their clip coordinates by `1 / w_world` each.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NdcTransfer {
    /// `P_to · P_from⁻¹`.
    pub m: M4,
    /// Row 3 of `P_from⁻¹`: the world point's homogeneous `w`.
    pub w_row: [f32; 4],
}

impl NdcTransfer {
    /// The transfer from camera `from` (whose `P⁻¹` is `from_inv`) to the camera with `P = to_vp`.
    pub fn new(from_inv: &Mat4, to_vp: &Mat4) -> NdcTransfer {
        let m = to_vp.mul(from_inv).to_f32();
        let r = from_inv.0[3];
        NdcTransfer {
            m,
            w_row: [r[0] as f32, r[1] as f32, r[2] as f32, r[3] as f32],
        }
    }

    /// Clip coordinates in the target camera of the world point `P_from⁻¹(c̄)`, divided by that
    /// point's homogeneous `w`, i.e. `P_to · X` for the dehomogenised world point `X`.
    #[inline(always)]
    pub fn clip(&self, c: [f32; 3]) -> [f32; 4] {
        let h = self.m.apply(c);
        let r = &self.w_row;
        let iw = 1.0 / (r[0] * c[0] + r[1] * c[1] + r[2] * c[2] + r[3]);
        [h[0] * iw, h[1] * iw, h[2] * iw, h[3] * iw]
    }
}

/// NDC of the centre of pixel `(i, j)` in a `w × h` image.
#[inline(always)]
pub fn ndc_of_pixel(i: usize, j: usize, w: usize, h: usize) -> [f32; 2] {
    // Through i32: sides are at most MAX_SIDE, and x86-64 converts i32 ⇄ f32 in one instruction
    // but u64 ⇄ f32 only in a branchy sequence; this runs several times per pixel.
    [
        (2 * i as i32 + 1) as f32 / w as i32 as f32 - 1.0,
        1.0 - (2 * j as i32 + 1) as f32 / h as i32 as f32,
    ]
}

/// `odd / side` for an odd `odd = 2i + 1 < 2·side` and `side ≤ MAX_SIDE` (both integers as
/// floats), the quotient of [`ndc_of_pixel`], from `recip = 1/side` without a division: the
/// product `q = odd · recip`, then Markstein's correction `q + (odd − q·side) · recip`, whose
/// residual one fused multiply-add computes exactly. With `recip` the correctly rounded
/// reciprocal and `q` within an ulp of the quotient, the corrected value is the correctly rounded
/// quotient, i.e. the division's bytes; checked for every pixel of every side up to
/// [`MAX_SIDE`] (`centre_quotient_is_the_division_at_every_pixel_of_every_side`).
///
/// Why: the search's last stage computes the NDC of the pixel each target ended on, two
/// divisions per target beside the square root of the reprojection error, all on the divider.
/// Without the divisions the 1280×720 frame on two threads took 0.979–0.983 of the time, paired
/// in one process (on one thread no difference; docs/performance.md). Only for builds with FMA
/// instructions: elsewhere `mul_add` is a library call.
#[inline(always)]
pub(crate) fn centre_quotient(odd: f32, side: f32, recip: f32) -> f32 {
    let q = odd * recip;
    (-q).mul_add(side, odd).mul_add(recip, q)
}

/// The NDC of every pixel centre of a `W × H` image, by column (x) and by row (y): the same values
/// as [`ndc_of_pixel`] (which is separable), looked up instead of divided for each search.
#[derive(Debug, Clone, Default)]
pub(crate) struct NdcTable {
    pub(crate) x: Vec<f32>,
    pub(crate) y: Vec<f32>,
}

impl NdcTable {
    pub(crate) fn new(w: usize, h: usize) -> NdcTable {
        NdcTable {
            x: (0..w).map(|i| ndc_of_pixel(i, 0, w, h)[0]).collect(),
            y: (0..h).map(|j| ndc_of_pixel(0, j, w, h)[1]).collect(),
        }
    }

    /// The NDC of the centre of pixel `(i, j)`.
    #[inline(always)]
    pub(crate) fn at(&self, i: usize, j: usize) -> [f32; 2] {
        [self.x[i], self.y[j]]
    }
}

/// The pixel of a `w × h` image that contains NDC `(x, y)`: `i = ⌊(x+1)·W/2⌋`,
/// `j = ⌊(1−y)·H/2⌋`; `None` outside the image or for NaN.
#[inline(always)]
pub fn pixel_of_ndc(x: f32, y: f32, w: usize, h: usize) -> Option<(usize, usize)> {
    let (wf, hf) = (w as i32 as f32, h as i32 as f32);
    let fx = (x + 1.0) * 0.5 * wf;
    let fy = (1.0 - y) * 0.5 * hf;
    // NaN fails every comparison, so it is rejected here too. For the non-negative values that
    // pass, truncation is the floor: no libm `floorf` call in the innermost loops, and i32 (not
    // usize) conversions, which are single instructions.
    if fx >= 0.0 && fy >= 0.0 && fx < wf && fy < hf {
        // SAFETY: `0 ≤ fx < wf ≤ 2³¹` (and the same for `fy`), so both are finite and truncate
        // into i32's range; this skips the NaN and overflow handling of a saturating `as` cast.
        // The truncation is at most `w − 1` because `fx < wf` and `wf` is an integer.
        let (ix, iy) = unsafe { (fx.to_int_unchecked::<i32>(), fy.to_int_unchecked::<i32>()) };
        Some((ix as usize, iy as usize))
    } else {
        None
    }
}

/// [`pixel_of_ndc`] without branches, for row loops that must vectorise: whether a `w × h` image
/// (`wf`, `hf`: its sides as floats) has a pixel containing NDC `(x, y)` (`false` outside it and
/// for NaN), and that pixel's row-major index `⌊fy⌋·w + ⌊fx⌋` (0 when there is none, for the
/// caller to discard).
///
/// A saturating `f32 as i32` costs a compare and a blend per lane for NaN and overflow; selecting
/// an in-range value first lets the truncation be the single conversion instruction.
#[inline(always)]
pub(crate) fn pixel_index_of_ndc(x: f32, y: f32, wf: f32, hf: f32, w: u32) -> (bool, u32) {
    let fx = (x + 1.0) * 0.5 * wf;
    let fy = (1.0 - y) * 0.5 * hf;
    // `&`, not `&&`: short-circuit branches keep a row loop from vectorising.
    let inside = (fx >= 0.0) & (fy >= 0.0) & (fx < wf) & (fy < hf);
    let (fx, fy) = if inside { (fx, fy) } else { (0.0, 0.0) };
    // SAFETY: both are in `[0, 2¹⁶)` here (sides are at most 16384), so finite and in i32 range;
    // the truncation is the floor of these non-negative values.
    let (qi, qj) = unsafe { (fx.to_int_unchecked::<i32>(), fy.to_int_unchecked::<i32>()) };
    (inside, qj as u32 * w + qi as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_quotient_is_the_division_at_every_pixel_of_every_side() {
        // Exhaustive: 134 M pixel columns, about 1.5 s in a debug build.
        for side in 1..=MAX_SIDE as i32 {
            let (sf, recip) = (side as f32, 1.0 / side as f32);
            for i in 0..side {
                let odd = (2 * i + 1) as f32;
                let q = centre_quotient(odd, sf, recip);
                assert_eq!(q.to_bits(), (odd / sf).to_bits(), "pixel {i} of {side}");
            }
        }
    }

    #[test]
    fn inverse_of_product_is_identity() {
        let a = Mat4([
            [2.0, 0.5, 0.0, 1.0],
            [0.0, 1.5, 0.3, -2.0],
            [0.1, 0.0, 1.0, 0.5],
            [0.0, 0.0, -1.0, 0.0],
        ]);
        let i = a.mul(&a.inverse().unwrap());
        for r in 0..4 {
            for c in 0..4 {
                let e = if r == c { 1.0 } else { 0.0 };
                assert!((i.0[r][c] - e).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn singular_matrix_has_no_inverse() {
        let mut a = Mat4::IDENTITY;
        a.0[2] = [0.0; 4];
        assert!(a.inverse().is_none());
        a.0[2][2] = f64::NAN;
        assert!(a.inverse().is_none());
    }

    #[test]
    fn perspective_is_reversed_depth() {
        let p = Mat4::perspective(60.0, 16.0 / 9.0, 0.1, 100.0);
        let z_at = |d: f64| {
            let c = p.mul_vec([0.0, 0.0, -d, 1.0]);
            c[2] / c[3]
        };
        assert!((z_at(0.1) - 1.0).abs() < 1e-12);
        assert!(z_at(100.0).abs() < 1e-12);
        assert!(z_at(1.0) > z_at(2.0));
    }

    /// A point on the edge of the vertical field of view projects to `y = ±1`, one on the edge
    /// of the horizontal one (`tan(h/2) = aspect · tan(v/2)`) to `x = ±1`, whatever its depth.
    #[test]
    fn perspective_maps_the_field_of_view_to_the_image_edges() {
        let (fov, aspect) = (50.0f64, 1.6);
        let p = Mat4::perspective(fov, aspect, 0.1, 100.0);
        let t = (fov.to_radians() / 2.0).tan();
        for d in [0.5, 3.0, 40.0] {
            let ndc = |x: f64, y: f64| {
                let c = p.mul_vec([x, y, -d, 1.0]);
                [c[0] / c[3], c[1] / c[3]]
            };
            let [x, y] = ndc(0.0, d * t);
            assert!(
                x.abs() < 1e-12 && (y - 1.0).abs() < 1e-12,
                "top at {d}: {y}"
            );
            let [x, y] = ndc(-d * t * aspect, 0.0);
            assert!(
                (x + 1.0).abs() < 1e-12 && y.abs() < 1e-12,
                "left at {d}: {x}"
            );
        }
    }

    /// The camera's x axis points right of the view direction and its y axis up (toward `up`):
    /// a world point right of and above the target lands at positive camera x and y, and the
    /// rotation is orthonormal.
    #[test]
    fn look_at_is_right_handed_with_up_on_top() {
        // Looking from the origin along −z: the view matrix is the identity.
        let v = Mat4::look_at([0.0; 3], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]);
        for r in 0..4 {
            for c in 0..4 {
                let e = if r == c { 1.0 } else { 0.0 };
                assert!((v.0[r][c] - e).abs() < 1e-15, "{v:?}");
            }
        }
        // Looking along +x from (1, 2, 3): right is +z, up is +y.
        let v = Mat4::look_at([1.0, 2.0, 3.0], [5.0, 2.0, 3.0], [0.0, 1.0, 0.0]);
        let p = v.mul_vec([5.0, 2.5, 3.5, 1.0]);
        assert!(
            (p[0] - 0.5).abs() < 1e-12 && (p[1] - 0.5).abs() < 1e-12,
            "{p:?}"
        );
        assert!((p[2] + 4.0).abs() < 1e-12);
        for a in 0..3 {
            for b in 0..3 {
                let d: f64 = (0..3).map(|k| v.0[a][k] * v.0[b][k]).sum();
                assert!((d - if a == b { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn look_at_puts_target_on_the_axis() {
        let v = Mat4::look_at([1.0, 2.0, 3.0], [4.0, 2.0, -1.0], [0.0, 1.0, 0.0]);
        let t = v.mul_vec([4.0, 2.0, -1.0, 1.0]);
        assert!(t[0].abs() < 1e-12 && t[1].abs() < 1e-12);
        assert!((t[2] + 5.0).abs() < 1e-12);
    }

    /// The ray from a grid column's and row's shares is the one `mul_vec` gives for the grid
    /// point, bit for bit (the renderers rely on it: tables of shares leave their images alone),
    /// odd widths included (a column at `x = 0` exactly).
    #[test]
    fn sub_ray_from_shares_is_mul_vecs_ray() {
        for (w, h, eye) in [(7, 5, [0.3, 1.7, 4.0]), (64, 36, [-12.5, 3.25, -0.75])] {
            let view = Mat4::look_at(eye, [0.5, 0.2, -3.0], [0.0, 1.0, 0.0]);
            let camera = Camera::new(view, Mat4::perspective(55.0, 1.6, 0.1, 80.0), w, h, "t");
            let rays = Rays::new(&camera.unwrap()).unwrap();
            for n in 1..=3 {
                for (j, b, i, a) in
                    (0..h * n).flat_map(|r| (0..w * n).map(move |c| (r / n, r % n, c / n, c % n)))
                {
                    let x = (2 * n * i + 2 * a + 1) as f64 / (n * w) as f64 - 1.0;
                    let y = 1.0 - (2 * n * j + 2 * b + 1) as f64 / (n * h) as f64;
                    let p = rays.inv_vp.mul_vec([x, y, 1.0, 1.0]);
                    let o = rays.origin;
                    let want = [0, 1, 2].map(|k| (p[k] / p[3] - o[k]).to_bits());
                    let got =
                        rays.sub_ray_at(rays.sub_ray_column(i, a, n), rays.sub_ray_row(j, b, n));
                    assert_eq!(
                        got.map(f64::to_bits),
                        want,
                        "{w}x{h} n={n} ({i},{j}) ({a},{b})"
                    );
                    assert_eq!(rays.sub_ray(i, j, a, b, n).map(f64::to_bits), want);
                }
            }
        }
    }

    #[test]
    fn pixel_ndc_round_trip() {
        for (w, h) in [(1, 1), (7, 5), (640, 360)] {
            for j in 0..h {
                for i in 0..w {
                    let [x, y] = ndc_of_pixel(i, j, w, h);
                    assert_eq!(pixel_of_ndc(x, y, w, h), Some((i, j)));
                }
            }
        }
        // The centres of DESIGN.md: x = (2i+1)/W − 1, y = 1 − (2j+1)/H (row 0 at the top).
        assert_eq!(ndc_of_pixel(0, 0, 4, 2), [-0.75, 0.5]);
        assert_eq!(ndc_of_pixel(3, 1, 4, 2), [0.75, -0.5]);
        assert_eq!(pixel_of_ndc(0.3, -0.9, 4, 2), Some((2, 1)));
        assert_eq!(pixel_of_ndc(-0.3, 0.9, 4, 2), Some((1, 0)));
        assert_eq!(pixel_of_ndc(f32::NAN, 0.0, 4, 4), None);
        assert_eq!(pixel_of_ndc(1.0, 0.0, 4, 4), None);
        assert_eq!(pixel_of_ndc(-1.0, 1.0, 4, 4), Some((0, 0)));
    }
}
