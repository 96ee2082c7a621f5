//! The stream decoder's dequantisation kernels (`reproj_core::dequant`): depth and motion from
//! the geometry picture's 12-bit codes, shadow colours from their Y′CbCr picture. Called by
//! `splitrender.codec.coder` with views of the decoded planes; each checks that the tile lies in
//! its plane and that the masks have the camera's size before the kernel runs. And the
//! encoder's half-size buffers (`reproj_core::quant`).

use numpy::{
    Element, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyReadwriteArrayDyn,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use reproj_core::dequant::{self, CodeTile, YCbCrPlanes};
use reproj_core::quant;

use crate::convert::{array, array_mut, finite, side, slice, slice_mut, Dim};
use crate::errors::invalid;
use crate::guarded;
use crate::memory::reserve;

/// A position inside a plane (`0..=MAX_SIDE`).
fn position(v: i64, what: &str) -> PyResult<usize> {
    usize::try_from(v)
        .ok()
        .filter(|&p| p <= reproj_core::MAX_SIDE)
        .ok_or_else(|| {
            invalid(format!(
                "{what}: expected 0..={}, got {v}",
                reproj_core::MAX_SIDE
            ))
        })
}

/// A 2-D C-contiguous plane and its row length.
fn plane<'py, T: numpy::Element>(
    obj: &Bound<'py, PyAny>,
    what: &str,
) -> PyResult<(PyReadonlyArrayDyn<'py, T>, usize)> {
    let a = array::<T>(obj, what, &[Dim::Any("rows"), Dim::Any("stride")])?;
    let stride = a.shape()[1];
    Ok((a, stride))
}

fn mask<'py>(
    obj: Option<&Bound<'py, PyAny>>,
    what: &str,
    w: usize,
    h: usize,
) -> PyResult<Option<PyReadonlyArrayDyn<'py, bool>>> {
    obj.filter(|m| !m.is_none())
        .map(|m| array::<bool>(m, what, &[Dim::Is(h), Dim::Is(w)]))
        .transpose()
}

/// Where a kernel writes: `out` when given (the caller's array, reused across frames so that
/// its pages are not faulted in again for every frame), else a new numpy array (reserved
/// first, for `call`). Every value is written by the kernel either way.
fn output<'py, T: Element>(
    py: Python<'py>,
    out: Option<&Bound<'py, PyAny>>,
    shape: &[usize],
    call: &str,
) -> PyResult<(Bound<'py, PyArrayDyn<T>>, PyReadwriteArrayDyn<'py, T>)> {
    if let Some(o) = out.filter(|o| !o.is_none()) {
        let dims: Vec<Dim> = shape.iter().map(|&n| Dim::Is(n)).collect();
        let rw = array_mut::<T>(o, "out", &dims)?;
        return Ok((o.cast::<PyArrayDyn<T>>()?.clone(), rw));
    }
    let bytes = shape.iter().product::<usize>() * std::mem::size_of::<T>();
    reserve(bytes as u64, || {
        format!("{call}: an output array of shape {shape:?}")
    })?;
    let arr = PyArrayDyn::<T>::zeros(py, shape, false);
    let rw = arr
        .try_readwrite()
        .map_err(|e| invalid(format!("out: cannot borrow the array for writing: {e}")))?;
    Ok((arr, rw))
}

fn tile<'a>(
    codes: &'a [u16],
    stride: usize,
    x: i64,
    y: i64,
    w: usize,
    h: usize,
    what: &str,
) -> PyResult<CodeTile<'a>> {
    let t = CodeTile {
        plane: codes,
        stride,
        x: position(x, what)?,
        y: position(y, what)?,
    };
    if !t.fits(w, h) {
        return Err(invalid(format!(
            "{what}: a {w}x{h} tile at ({x}, {y}) does not fit a plane of {} rows of {stride}",
            codes.len() / stride.max(1)
        )));
    }
    Ok(t)
}

/// Depth `float32[h, w]` from the full-resolution tile at `(x, y)` of `codes` (`uint16[rows,
/// stride]`): `f32(code) · scale + offset`, NaN where `invalid_mask`; written into `out`
/// (`float32[h, w]`) when given, which is returned.
#[pyfunction]
#[pyo3(signature = (codes, x, y, w, h, scale, offset, invalid_mask=None, out=None))]
#[allow(clippy::too_many_arguments)]
pub fn dequantise_depth<'py>(
    py: Python<'py>,
    codes: &Bound<'py, PyAny>,
    x: i64,
    y: i64,
    w: i64,
    h: i64,
    scale: f64,
    offset: f64,
    invalid_mask: Option<&Bound<'py, PyAny>>,
    out: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    guarded("dequantise_depth", || {
        let (w, h) = (side(w, "w")?, side(h, "h")?);
        let (scale, offset) = (
            finite(scale, "scale")? as f32,
            finite(offset, "offset")? as f32,
        );
        let (codes, stride) = plane::<u16>(codes, "codes")?;
        let codes = slice(&codes, "codes")?;
        let t = tile(codes, stride, x, y, w, h, "depth tile")?;
        let inv = mask(invalid_mask, "invalid_mask", w, h)?;
        let inv = inv.as_ref().map(|m| slice(m, "invalid_mask")).transpose()?;
        let (arr, mut rw) = output::<f32>(py, out, &[h, w], "dequantise_depth")?;
        let dst = slice_mut(&mut rw, "out")?;
        py.detach(|| dequant::depth_from_codes(t, w, h, scale, offset, inv, dst));
        Ok(arr)
    })
}

/// Motion `float32[h, w, 3]` from three half-resolution channel tiles of `codes` at `tiles`
/// (`[(x, y)] * 3`): `f32(code) · scale[c] + offset[c]` copied to the 2×2 pixels it covers,
/// `+0.0` where `static_mask`, NaN where `invalid_mask`; written into `out` (`float32[h, w,
/// 3]`) when given, which is returned.
#[pyfunction]
#[pyo3(signature = (codes, tiles, w, h, scale, offset, static_mask=None, invalid_mask=None, out=None))]
#[allow(clippy::too_many_arguments)]
pub fn dequantise_motion<'py>(
    py: Python<'py>,
    codes: &Bound<'py, PyAny>,
    tiles: [(i64, i64); 3],
    w: i64,
    h: i64,
    scale: [f64; 3],
    offset: [f64; 3],
    static_mask: Option<&Bound<'py, PyAny>>,
    invalid_mask: Option<&Bound<'py, PyAny>>,
    out: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    guarded("dequantise_motion", || {
        let (w, h) = (side(w, "w")?, side(h, "h")?);
        let (codes, stride) = plane::<u16>(codes, "codes")?;
        let codes = slice(&codes, "codes")?;
        let (hw, hh) = (w.div_ceil(2), h.div_ceil(2));
        let mut ch = [CodeTile {
            plane: codes,
            stride,
            x: 0,
            y: 0,
        }; 3];
        let (mut s, mut o) = ([0f32; 3], [0f32; 3]);
        for c in 0..3 {
            let (x, y) = tiles[c];
            ch[c] = tile(codes, stride, x, y, hw, hh, &format!("motion tile {c}"))?;
            s[c] = finite(scale[c], "scale")? as f32;
            o[c] = finite(offset[c], "offset")? as f32;
        }
        let st = mask(static_mask, "static_mask", w, h)?;
        let st = st.as_ref().map(|m| slice(m, "static_mask")).transpose()?;
        let inv = mask(invalid_mask, "invalid_mask", w, h)?;
        let inv = inv.as_ref().map(|m| slice(m, "invalid_mask")).transpose()?;
        let (arr, mut rw) = output::<f32>(py, out, &[h, w, 3], "dequantise_motion")?;
        let dst = slice_mut(&mut rw, "out")?;
        py.detach(|| dequant::motion_from_half_codes(ch, w, h, s, o, st, inv, dst));
        Ok(arr)
    })
}

/// A shadow colour `uint8[h, w, 3]` from the tile at `(x, y)` of its full-range BT.709 Y′CbCr
/// planes (`luma` `uint8[rows, stride]`, `cb`/`cr` at full or half resolution), converted where
/// `bits` (`uint32[h, w]`) is non-zero and 0 elsewhere; written into `out` (`uint8[h, w, 3]`)
/// when given, which is returned. `half`: the tile holds one sample per 2×2 pixels
/// (`⌈w/2⌉ × ⌈h/2⌉`, stream format 4).
#[pyfunction]
#[pyo3(signature = (luma, cb, cr, x, y, bits, out=None, half=false))]
#[allow(clippy::too_many_arguments)]
pub fn shadow_colour<'py>(
    py: Python<'py>,
    luma: &Bound<'py, PyAny>,
    cb: &Bound<'py, PyAny>,
    cr: &Bound<'py, PyAny>,
    x: i64,
    y: i64,
    bits: &Bound<'py, PyAny>,
    out: Option<&Bound<'py, PyAny>>,
    half: bool,
) -> PyResult<Bound<'py, PyArrayDyn<u8>>> {
    guarded("shadow_colour", || {
        let bits = array::<u32>(bits, "bits", &[Dim::Any("h"), Dim::Any("w")])?;
        let (h, w) = (bits.shape()[0], bits.shape()[1]);
        let (l, ls) = plane::<u8>(luma, "luma")?;
        let (b, bs) = plane::<u8>(cb, "cb")?;
        let (r, rs) = plane::<u8>(cr, "cr")?;
        if rs != bs || r.shape()[0] != b.shape()[0] {
            return Err(invalid(format!(
                "cr: expected the shape of cb {:?}, got {:?}",
                b.shape(),
                r.shape()
            )));
        }
        // 4:2:0 chroma has half the luma's rows; 4:4:4 as many.
        let sub = if b.shape()[0] == l.shape()[0] { 1 } else { 2 };
        let planes = YCbCrPlanes {
            y: slice(&l, "luma")?,
            cb: slice(&b, "cb")?,
            cr: slice(&r, "cr")?,
            stride: [ls, bs],
            sub,
        };
        let (x, y) = (position(x, "x")?, position(y, "y")?);
        let step = if half { 2 } else { 1 };
        let (tw, th) = (w.div_ceil(step), h.div_ceil(step));
        if !planes.fits(x, y, tw, th) {
            return Err(invalid(format!(
                "shadow tile: {tw}x{th} at ({x}, {y}) does not fit luma {:?} with chroma {:?}",
                l.shape(),
                b.shape()
            )));
        }
        let bits = slice(&bits, "bits")?;
        let (arr, mut rw) = output::<u8>(py, out, &[h, w, 3], "shadow_colour")?;
        let dst = slice_mut(&mut rw, "out")?;
        py.detach(|| dequant::shadow_colour_from_ycbcr(planes, x, y, w, h, step, bits, dst));
        Ok(arr)
    })
}

/// Per 2×2 block of `a` (`float32[h, w, c]`; an odd side padded), the mean over the pixels
/// where `weight` (`bool[h, w]`) is set, 0 where none is (summed in float64, rounded once),
/// and whether any is: `(float32[⌈h/2⌉, ⌈w/2⌉, c], bool[⌈h/2⌉, ⌈w/2⌉])`. The encoder's
/// half-size motion and shadow colours (`reproj_core::quant::block_mean`).
#[pyfunction]
#[allow(clippy::type_complexity)]
pub fn block_mean<'py>(
    py: Python<'py>,
    a: &Bound<'py, PyAny>,
    weight: &Bound<'py, PyAny>,
) -> PyResult<(Bound<'py, PyArrayDyn<f32>>, Bound<'py, PyArrayDyn<bool>>)> {
    guarded("block_mean", || {
        let a = array::<f32>(a, "a", &[Dim::Any("h"), Dim::Any("w"), Dim::Any("c")])?;
        let (h, w, c) = (a.shape()[0], a.shape()[1], a.shape()[2]);
        let weight = array::<bool>(weight, "weight", &[Dim::Is(h), Dim::Is(w)])?;
        let (hh, hw) = (h.div_ceil(2), w.div_ceil(2));
        let (mean, mut mean_rw) = output::<f32>(py, None, &[hh, hw, c], "block_mean")?;
        let (any, mut any_rw) = output::<bool>(py, None, &[hh, hw], "block_mean")?;
        let (src, on) = (slice(&a, "a")?, slice(&weight, "weight")?);
        let (dst, set) = (
            slice_mut(&mut mean_rw, "mean")?,
            slice_mut(&mut any_rw, "any")?,
        );
        py.detach(|| quant::block_mean(src, w, h, c, on, dst, set));
        Ok((mean, any))
    })
}
