//! Reading one image into a [`Texture`] and one triangle primitive's accessors into a [`Prim`],
//! validated against the file (pixel formats, image sizes within the budget, attribute types and
//! lengths, finite and bounded positions, non-negative weights, vertex indices).

use glam::DVec3;

use image::ImageFormat;

use super::access::{self, read, Bytes, Data, Expect};
use super::source::Sources;
use super::{err, unsupported};
use crate::error::{Result, SceneError};
use crate::gltf_model::{Prim, Texture};

/// Largest texture side decoded (pixels).
const MAX_TEXTURE_SIDE: u32 = 16384;

pub(super) fn decode_image(
    data: &mut Data<'_>,
    sources: &mut Sources<'_>,
    image: &gltf::Image<'_>,
) -> Result<Texture> {
    let path = data.path;
    let (what, bytes, mime): (String, Bytes, Option<String>) = match image.source() {
        gltf::image::Source::Uri { uri, mime_type } => {
            let what = if uri.starts_with("data:") {
                format!("embedded image {}", image.index())
            } else {
                format!("texture file {uri:?}")
            };
            let bytes = sources.read(uri, &what)?;
            (what, bytes, mime_type.map(str::to_string))
        }
        gltf::image::Source::View { view, mime_type } => {
            let what = format!("embedded image {}", image.index());
            let b = access::view_bytes(path, data.root, &data.buffers, view.index(), &what)?;
            (what, Bytes::new(b.to_vec()), Some(mime_type.to_string()))
        }
    };
    let format = match mime.as_deref() {
        Some("image/png") => Some(ImageFormat::Png),
        Some("image/jpeg") => Some(ImageFormat::Jpeg),
        _ => image::guess_format(&bytes).ok(),
    }
    .filter(|f| matches!(f, ImageFormat::Png | ImageFormat::Jpeg))
    .ok_or_else(|| unsupported(path, format!("{what} is neither PNG nor JPEG")))?;
    // The decoder sizes its buffer from the image header; the limits keep a header that claims
    // a huge image from allocating more than the model's budget allows.
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_TEXTURE_SIDE);
    limits.max_image_height = Some(MAX_TEXTURE_SIDE);
    limits.max_alloc = Some(data.budget.left() as u64);
    // The header first, to name a size the budget cannot hold (the decoder's refusal read only
    // "Memory limit exceeded").
    let (hw, hh) = image::ImageReader::with_format(std::io::Cursor::new(&bytes[..]), format)
        .into_dimensions()
        .map_err(|e| err(path, format!("cannot decode {what}: {e}")))?;
    let need = (hw as usize)
        .saturating_mul(hh as usize)
        .saturating_mul(std::mem::size_of::<[f32; 3]>());
    if hw.max(hh) > MAX_TEXTURE_SIDE || need > data.budget.left() {
        return Err(err(
            path,
            format!(
                "{what} is {hw}x{hh} pixels ({need} bytes decoded), expected at most \
                 {MAX_TEXTURE_SIDE} on a side and within the {} bytes left of the decode budget",
                data.budget.left()
            ),
        ));
    }
    let mut reader = image::ImageReader::with_format(std::io::Cursor::new(&bytes[..]), format);
    reader.limits(limits);
    let decoded = reader
        .decode()
        .map_err(|e| err(path, format!("cannot decode {what}: {e}")))?;
    let (w, h) = (decoded.width() as usize, decoded.height() as usize);
    if w == 0 || h == 0 {
        return Err(err(path, format!("{what} is empty")));
    }
    data.budget
        .take(path, &what, w * h * std::mem::size_of::<[f32; 3]>())?;
    use image::DynamicImage as D;
    let rgb: Vec<[f32; 3]> = match decoded {
        D::ImageLuma8(_) | D::ImageLumaA8(_) | D::ImageRgb8(_) | D::ImageRgba8(_) => decoded
            .to_rgb8()
            .pixels()
            .map(|p| p.0.map(|c| f32::from(c) / 255.0))
            .collect(),
        other => {
            return Err(unsupported(
                path,
                format!("{what} has pixel format {:?}", other.color()),
            ))
        }
    };
    Ok(Texture {
        width: w,
        height: h,
        rgb,
    })
}

/// Largest coordinate of a vertex, a translation or a scale accepted in a model (metres or a
/// factor): beyond it, squares of coordinates leave the `f32` range of the BVH's boxes, and no
/// real model comes near it.
pub(crate) const MAX_COORD: f64 = 1e15;

fn vec3s(v: Vec<[f64; 3]>) -> Vec<DVec3> {
    v.into_iter().map(DVec3::from_array).collect()
}

/// The optional per-vertex attribute `semantic` of primitive `p`: `None` when the primitive has
/// none; an error (through `here`, which names the primitive) when it has other than one entry
/// for each of the `n` vertices.
fn per_vertex<const N: usize>(
    data: &mut Data<'_>,
    p: &gltf::Primitive<'_>,
    semantic: gltf::Semantic,
    expect: &Expect,
    n: usize,
    here: &dyn Fn(String) -> SceneError,
) -> Result<Option<Vec<[f64; N]>>> {
    let Some(a) = p.get(&semantic) else {
        return Ok(None);
    };
    let what = semantic.to_string(); // "TEXCOORD_0", as the file names it
    let v = read::<N>(data, a.index(), &what, expect)?;
    if v.len() != n {
        return Err(here(format!(
            "{what} has {} entries for {n} vertices",
            v.len()
        )));
    }
    Ok(Some(v))
}

pub(super) fn read_primitive(
    data: &mut Data<'_>,
    mesh: usize,
    k: usize,
    p: &gltf::Primitive<'_>,
) -> Result<Prim> {
    use gltf::json::accessor::{ComponentType as C, Type};
    use gltf::Semantic as S;
    let path = data.path;
    let here = |problem: String| err(path, format!("mesh {mesh} primitive {k}: {problem}"));
    if p.mode() != gltf::mesh::Mode::Triangles {
        return Err(unsupported(
            path,
            format!(
                "mesh {mesh} primitive {k} has mode {:?} (only TRIANGLES)",
                p.mode()
            ),
        ));
    }
    let Some(pos) = p.get(&gltf::Semantic::Positions).map(|a| a.index()) else {
        return Err(here("no POSITION attribute".into()));
    };
    let positions = read::<3>(data, pos, "POSITION", &Expect::floats(Type::Vec3))?;
    access::bounded(
        path,
        &format!("accessor {pos} (POSITION)"),
        positions.as_flattened(),
        MAX_COORD,
    )?;
    let positions = vec3s(positions);
    let n = positions.len();
    const UNORM: &[(C, bool)] = &[(C::F32, false), (C::U8, true), (C::U16, true)];
    const VEC3: Expect = Expect::floats(Type::Vec3);
    const UV: Expect = Expect {
        ty: Type::Vec2,
        components: UNORM,
    };
    const JOINTS: Expect = Expect {
        ty: Type::Vec4,
        components: &[(C::U8, false), (C::U16, false)],
    };
    const WEIGHTS: Expect = Expect {
        ty: Type::Vec4,
        components: UNORM,
    };
    let normals = per_vertex::<3>(data, p, S::Normals, &VEC3, n, &here)?;
    let uvs = per_vertex::<2>(data, p, S::TexCoords(0), &UV, n, &here)?;
    let joints = per_vertex::<4>(data, p, S::Joints(0), &JOINTS, n, &here)?;
    let weights = per_vertex::<4>(data, p, S::Weights(0), &WEIGHTS, n, &here)?;
    // Skinning divides by the sum of the weights: a negative one could make it tiny.
    if let Some(v) = &weights {
        if let Some(i) = v
            .iter()
            .position(|w| w.iter().any(|&x| !(0.0..=1e6).contains(&x)))
        {
            return Err(here(format!(
                "WEIGHTS_0 of vertex {i} is {:?}, expected non-negative weights",
                v[i]
            )));
        }
    }
    let flat: Vec<u32> = match p.indices() {
        Some(a) => access::read_indices(data, a.index(), "indices")?,
        None => {
            data.budget.take(
                path,
                &format!("mesh {mesh} primitive {k} implicit indices"),
                4 * n,
            )?;
            (0..n as u32).collect()
        }
    };
    if flat.len() % 3 != 0 {
        return Err(here(format!(
            "{} indices is not a multiple of 3",
            flat.len()
        )));
    }
    if let Some((i, &bad)) = flat.iter().enumerate().find(|(_, &x)| x as usize >= n) {
        return Err(here(format!(
            "vertex index {bad} at position {i} is out of range ({n} vertices)"
        )));
    }
    Ok(Prim {
        positions,
        normals: normals.map(vec3s),
        uvs,
        // Unsigned 8- or 16-bit integers, so the casts are exact.
        joints: joints.map(|v| v.into_iter().map(|j| j.map(|x| x as u16)).collect()),
        weights,
        triangles: flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
        material: p.material().index(),
    })
}
