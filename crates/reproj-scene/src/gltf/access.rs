//! Bounds-checked decoding of accessors, and the decode budget.
//!
//! The `gltf` crate's readers trust the file: a `byteStride` smaller than the element panics in
//! a slice index, and a sparse accessor of any `count` without a buffer view is expanded into
//! memory. Here every accessor is checked against the JSON and against the bytes actually
//! present before anything is allocated: the buffer view lies inside its buffer, the stride holds
//! an element, the last element ends inside the view, sparse indices and values lie inside
//! their views, and the decoded size fits the [`Budget`]. Float components must be finite.

use std::path::Path;
use std::sync::Arc;

use gltf::json;
use gltf::json::accessor::{ComponentType, Type};
use gltf::json::validation::Checked;

use super::err;
use crate::error::{Result, SceneError};

/// How many bytes of decoded data the file may produce: `FACTOR` per input byte (an `f32`
/// becomes an `f64`, a `u8` weight an `f64`, and several primitives may share one accessor) plus
/// a fixed allowance for accessors that cost nothing in the file (no buffer view: all zeros).
#[derive(Debug)]
pub(crate) struct Budget {
    left: usize,
    total: usize,
    /// The fixed allowance in `total` (the rest is proportional to the input).
    base: usize,
}

/// Decoded bytes allowed per byte of input (file, buffers and textures read).
pub(crate) const BUDGET_FACTOR: usize = 64;
/// Decoded bytes allowed on top of `BUDGET_FACTOR` × input.
pub(crate) const BUDGET_BASE: usize = 64 << 20;

impl Budget {
    /// A budget of `BUDGET_FACTOR × input + base` bytes.
    pub(crate) fn new(input: usize, base: usize) -> Budget {
        let total = input.saturating_mul(BUDGET_FACTOR).saturating_add(base);
        Budget {
            left: total,
            total,
            base,
        }
    }

    /// Takes `bytes` from the budget, or says what would have exceeded it.
    pub(crate) fn take(&mut self, path: &Path, what: &str, bytes: usize) -> Result<()> {
        if bytes > self.left {
            return Err(err(
                path,
                format!(
                    "{what}: decoding it needs {bytes} bytes, more than the {} left of the \
                     {}-byte budget this file's size allows ({BUDGET_FACTOR} bytes per input \
                     byte + what is left of a fixed allowance the models of a scene share)",
                    self.left, self.total
                ),
            ));
        }
        self.left -= bytes;
        Ok(())
    }

    /// Adds the allowance of `input` more bytes read (a texture file).
    pub(crate) fn grow(&mut self, input: usize) {
        let more = input.saturating_mul(BUDGET_FACTOR);
        self.left = self.left.saturating_add(more);
        self.total = self.total.saturating_add(more);
    }

    /// Bytes still available.
    pub(crate) fn left(&self) -> usize {
        self.left
    }

    /// How much of the fixed allowance was taken: what was taken beyond the part proportional
    /// to the input.
    pub(crate) fn fixed_used(&self) -> usize {
        (self.total - self.left).saturating_sub(self.total - self.base)
    }
}

/// Bytes read from the file or a URI, shared where several buffers name the same file.
pub(super) type Bytes = Arc<Vec<u8>>;

/// The document, its buffers and the budget left: what decoding an accessor needs.
pub(super) struct Data<'a> {
    pub(super) path: &'a Path,
    pub(super) root: &'a json::Root,
    pub(super) buffers: Vec<Bytes>,
    pub(super) budget: Budget,
}

/// What a caller accepts for one accessor: its type and, per component type, whether it must
/// be normalized (`Some(true)`), must not be (`Some(false)`); types not listed are refused.
pub(super) struct Expect {
    pub(super) ty: Type,
    pub(super) components: &'static [(ComponentType, bool)],
}

impl Expect {
    pub(super) const fn floats(ty: Type) -> Expect {
        Expect {
            ty,
            components: &[(ComponentType::F32, false)],
        }
    }
}

fn components(ty: Type) -> usize {
    match ty {
        Type::Scalar => 1,
        Type::Vec2 => 2,
        Type::Vec3 => 3,
        Type::Vec4 | Type::Mat2 => 4,
        Type::Mat3 => 9,
        Type::Mat4 => 16,
    }
}

fn type_name(ty: Type) -> &'static str {
    match ty {
        Type::Scalar => "SCALAR",
        Type::Vec2 => "VEC2",
        Type::Vec3 => "VEC3",
        Type::Vec4 => "VEC4",
        Type::Mat2 => "MAT2",
        Type::Mat3 => "MAT3",
        Type::Mat4 => "MAT4",
    }
}

fn component_name(c: ComponentType) -> &'static str {
    match c {
        ComponentType::I8 => "BYTE",
        ComponentType::U8 => "UNSIGNED_BYTE",
        ComponentType::I16 => "SHORT",
        ComponentType::U16 => "UNSIGNED_SHORT",
        ComponentType::U32 => "UNSIGNED_INT",
        ComponentType::F32 => "FLOAT",
    }
}

fn component_size(c: ComponentType) -> usize {
    match c {
        ComponentType::I8 | ComponentType::U8 => 1,
        ComponentType::I16 | ComponentType::U16 => 2,
        ComponentType::U32 | ComponentType::F32 => 4,
    }
}

/// One component at the start of `b` (which holds at least its size), normalized as glTF says
/// (signed types clamp −max to −1).
fn component(c: ComponentType, normalized: bool, b: &[u8]) -> f64 {
    let (v, max) = match c {
        ComponentType::I8 => (f64::from(b[0] as i8), 127.0),
        ComponentType::U8 => (f64::from(b[0]), 255.0),
        ComponentType::I16 => (f64::from(i16::from_le_bytes([b[0], b[1]])), 32767.0),
        ComponentType::U16 => (f64::from(u16::from_le_bytes([b[0], b[1]])), 65535.0),
        ComponentType::U32 => (f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])), 1.0),
        ComponentType::F32 => return f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
    };
    if normalized {
        (v / max).max(-1.0)
    } else {
        v
    }
}

/// The bytes of buffer view `view`, checked against its buffer's declared length and the bytes
/// actually present.
pub(super) fn view_bytes<'b>(
    path: &Path,
    root: &json::Root,
    buffers: &'b [Bytes],
    view: usize,
    what: &str,
) -> Result<&'b [u8]> {
    let v = root
        .buffer_views
        .get(view)
        .ok_or_else(|| err(path, format!("{what}: buffer view {view} does not exist")))?;
    let b = v.buffer.value();
    let data = buffers
        .get(b)
        .ok_or_else(|| err(path, format!("{what}: buffer {b} does not exist")))?;
    let declared = root.buffers.get(b).map_or(0, |x| x.byte_length.0);
    let start = v.byte_offset.map_or(0, |o| o.0);
    let end = start.checked_add(v.byte_length.0);
    match end {
        Some(end) if end <= declared && end <= data.len() as u64 => {
            Ok(&data[start as usize..end as usize])
        }
        _ => Err(err(
            path,
            format!(
                "{what}: buffer view {view} spans bytes {start}..{start}+{} of buffer {b}, which \
                 declares {declared} bytes and holds {}",
                v.byte_length.0,
                data.len()
            ),
        )),
    }
}

/// Decodes accessor `index` into `count` elements of `N` components each, as `f64`, after
/// checking its type against `expect`, every byte range against the data present, and the
/// decoded size against `budget`. `what` names the use (e.g. `POSITION`) in messages, which
/// read "accessor 3 (POSITION): …".
///
/// # Errors
/// [`SceneError::Gltf`] naming the accessor, what is wrong and what was expected.
pub(super) fn read<const N: usize>(
    data: &mut Data<'_>,
    index: usize,
    what: &str,
    expect: &Expect,
) -> Result<Vec<[f64; N]>> {
    let (path, root, buffers) = (data.path, data.root, &data.buffers[..]);
    let budget = &mut data.budget;
    let name = format!("accessor {index} ({what})");
    let here = |problem: String| err(path, format!("{name}: {problem}"));
    let a = root
        .accessors
        .get(index)
        .ok_or_else(|| err(path, format!("{name} does not exist")))?;
    // Document validation refuses unknown enums; unwrap them without trusting that.
    let (Checked::Valid(&ty), Checked::Valid(ct)) = (a.type_.as_ref(), a.component_type.as_ref())
    else {
        return Err(here("unknown type or componentType".into()));
    };
    let ct = ct.0;
    debug_assert_eq!(components(expect.ty), N);
    if ty != expect.ty {
        return Err(here(format!(
            "type {}, expected {}",
            type_name(ty),
            type_name(expect.ty)
        )));
    }
    match expect.components.iter().find(|(c, _)| *c == ct) {
        None => {
            let ok: Vec<String> = expect
                .components
                .iter()
                .map(|(c, n)| {
                    format!(
                        "{}{}",
                        component_name(*c),
                        if *n { " (normalized)" } else { "" }
                    )
                })
                .collect();
            return Err(here(format!(
                "componentType {}, expected {}",
                component_name(ct),
                ok.join(" or ")
            )));
        }
        Some((_, normalized)) if a.normalized != *normalized && ct != ComponentType::F32 => {
            return Err(here(format!(
                "normalized is {}, expected {normalized} for {}",
                a.normalized,
                component_name(ct)
            )));
        }
        Some(_) => {}
    }
    let normalized = a.normalized && ct != ComponentType::F32;
    let csize = component_size(ct);
    let esize = csize * N;
    let count = a.count.0;
    // The decoded vector is charged before it exists (twice: callers convert it once more).
    let bytes = count
        .checked_mul((N * 8 * 2) as u64)
        .and_then(|b| usize::try_from(b).ok())
        .unwrap_or(usize::MAX);
    budget.take(path, &format!("{name} with count {count}"), bytes)?;
    let count = count as usize;

    let mut out: Vec<[f64; N]> = match a.buffer_view {
        None => vec![[0.0; N]; count],
        Some(view) => {
            let data = view_bytes(path, root, buffers, view.value(), &name)?;
            let stride = match root.buffer_views[view.value()].byte_stride {
                Some(s) if s.0 != 0 => s.0,
                _ => esize,
            };
            if stride < esize {
                return Err(here(format!(
                    "byteStride {stride} is smaller than the element size {esize}"
                )));
            }
            let offset = a.byte_offset.map_or(0, |o| o.0);
            // The last element must end inside the view: offset + stride·(count−1) + size.
            let end = (count as u64).checked_sub(1).map_or(Some(offset), |last| {
                last.checked_mul(stride as u64)
                    .and_then(|x| x.checked_add(offset))
                    .and_then(|x| x.checked_add(esize as u64))
            });
            match end {
                Some(end) if end <= data.len() as u64 => {}
                _ => {
                    return Err(here(format!(
                        "{count} elements of {esize} bytes at byteOffset {offset} with stride \
                         {stride} do not fit in buffer view {} ({} bytes)",
                        view.value(),
                        data.len()
                    )))
                }
            }
            let offset = offset as usize;
            (0..count)
                .map(|i| {
                    let e = &data[offset + i * stride..][..esize];
                    std::array::from_fn(|k| component(ct, normalized, &e[k * csize..]))
                })
                .collect()
        }
    };

    if let Some(s) = &a.sparse {
        let n = s.count.0;
        if n == 0 || n > count as u64 {
            return Err(here(format!(
                "sparse count {n}, expected 1..={count} (the accessor's count)"
            )));
        }
        let n = n as usize;
        let it = match s.indices.component_type.as_ref() {
            Checked::Valid(c)
                if matches!(
                    c.0,
                    ComponentType::U8 | ComponentType::U16 | ComponentType::U32
                ) =>
            {
                c.0
            }
            _ => {
                return Err(here(
                    "sparse indices componentType, expected UNSIGNED_BYTE, UNSIGNED_SHORT or \
                     UNSIGNED_INT"
                        .into(),
                ))
            }
        };
        let isize_ = component_size(it);
        let sparse_bytes = |view: usize, part: &str| {
            view_bytes(path, root, buffers, view, &format!("{name} sparse {part}"))
        };
        let idx = sparse_bytes(s.indices.buffer_view.value(), "indices")?;
        let vals = sparse_bytes(s.values.buffer_view.value(), "values")?;
        let fits = |data: &[u8], offset: u64, size: usize| {
            (n as u64)
                .checked_mul(size as u64)
                .and_then(|x| x.checked_add(offset))
                .is_some_and(|end| end <= data.len() as u64)
        };
        if !fits(idx, s.indices.byte_offset.0, isize_) {
            return Err(here(format!(
                "{n} sparse indices of {isize_} bytes at byteOffset {} do not fit in their buffer view ({} bytes)",
                s.indices.byte_offset.0,
                idx.len()
            )));
        }
        if !fits(vals, s.values.byte_offset.0, esize) {
            return Err(here(format!(
                "{n} sparse values of {esize} bytes at byteOffset {} do not fit in their buffer view ({} bytes)",
                s.values.byte_offset.0,
                vals.len()
            )));
        }
        let (io, vo) = (
            s.indices.byte_offset.0 as usize,
            s.values.byte_offset.0 as usize,
        );
        let mut prev: Option<usize> = None;
        for j in 0..n {
            let i = component(it, false, &idx[io + j * isize_..]) as usize;
            if i >= count || prev.is_some_and(|p| i <= p) {
                return Err(here(format!(
                    "sparse index {i} at position {j}, expected strictly increasing indices below {count}"
                )));
            }
            prev = Some(i);
            let e = &vals[vo + j * esize..][..esize];
            out[i] = std::array::from_fn(|k| component(ct, normalized, &e[k * csize..]));
        }
    }

    if ct == ComponentType::F32 {
        if let Some((i, e)) = out
            .iter()
            .enumerate()
            .find(|(_, e)| !e.iter().all(|x| x.is_finite()))
        {
            return Err(here(format!(
                "element {i} is {e:?}, expected finite numbers"
            )));
        }
    }
    Ok(out)
}

/// [`read`] for vertex indices: `SCALAR` of `UNSIGNED_BYTE`, `UNSIGNED_SHORT` or `UNSIGNED_INT`.
pub(super) fn read_indices(data: &mut Data<'_>, index: usize, what: &str) -> Result<Vec<u32>> {
    const EXPECT: Expect = Expect {
        ty: Type::Scalar,
        components: &[
            (ComponentType::U8, false),
            (ComponentType::U16, false),
            (ComponentType::U32, false),
        ],
    };
    let v: Vec<[f64; 1]> = read(data, index, what, &EXPECT)?;
    // Every value came from an unsigned integer of at most 32 bits, so the cast is exact.
    Ok(v.into_iter().map(|[x]| x as u32).collect())
}

/// The error for a value outside `±bound` or not finite, naming where it is.
pub(super) fn bounded(path: &Path, what: &str, values: &[f64], bound: f64) -> Result<()> {
    match values.iter().find(|x| !(x.abs() <= bound)) {
        None => Ok(()),
        Some(x) => Err(SceneError::Gltf {
            path: path.display().to_string(),
            problem: format!("{what}: value {x:e} is not finite or beyond ±{bound:e}; expected finite numbers within that bound"),
        }),
    }
}
