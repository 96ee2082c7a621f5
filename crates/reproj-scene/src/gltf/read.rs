//! Reading one image into a [`Texture`] and one triangle primitive's accessors into a [`Prim`],
//! validated against the file (pixel formats, attribute lengths, vertex indices).

use std::path::Path;

use glam::DVec3;

use super::{err, unsupported};
use crate::error::Result;
use crate::gltf_model::{Prim, Texture};

pub(super) fn decode_image(
    path: &Path,
    base: &Path,
    image: &gltf::Image<'_>,
    buffers: &[gltf::buffer::Data],
) -> Result<Texture> {
    let what = match image.source() {
        gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") => {
            format!("texture file {uri:?}")
        }
        _ => format!("embedded image {}", image.index()),
    };
    let data = gltf::image::Data::from_source(image.source(), Some(base), buffers)
        .map_err(|e| err(path, format!("cannot load {what}: {e}")))?;
    use gltf::image::Format;
    let ch = match data.format {
        Format::R8 => 1,
        Format::R8G8 => 2,
        Format::R8G8B8 => 3,
        Format::R8G8B8A8 => 4,
        f => return Err(unsupported(path, format!("{what} has pixel format {f:?}"))),
    };
    let (w, h) = (data.width as usize, data.height as usize);
    if w == 0 || h == 0 || data.pixels.len() < w * h * ch {
        return Err(err(path, format!("{what} is empty or truncated")));
    }
    let rgb = data
        .pixels
        .chunks_exact(ch)
        .take(w * h)
        .map(|p| {
            let c = |k: usize| f32::from(p[if ch < 3 { 0 } else { k }]) / 255.0;
            [c(0), c(1), c(2)]
        })
        .collect();
    Ok(Texture {
        width: w,
        height: h,
        rgb,
    })
}

pub(super) fn read_primitive(
    path: &Path,
    mesh: usize,
    k: usize,
    p: &gltf::Primitive<'_>,
    buffers: &[gltf::buffer::Data],
) -> Result<Prim> {
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
    let reader = p.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
    let positions: Vec<DVec3> = reader
        .read_positions()
        .ok_or_else(|| here("missing or unreadable POSITION".into()))?
        .map(|v| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64))
        .collect();
    let n = positions.len();
    let same = |what: &str, len: usize| {
        if len == n {
            Ok(())
        } else {
            Err(here(format!("{what} has {len} entries for {n} vertices")))
        }
    };
    let normals = match reader.read_normals() {
        Some(it) => {
            let v: Vec<DVec3> = it
                .map(|v| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64))
                .collect();
            same("NORMAL", v.len())?;
            Some(v)
        }
        None => None,
    };
    let uvs = match reader.read_tex_coords(0) {
        Some(it) => {
            let v: Vec<[f64; 2]> = it.into_f32().map(|v| [v[0] as f64, v[1] as f64]).collect();
            same("TEXCOORD_0", v.len())?;
            Some(v)
        }
        None => None,
    };
    let joints = match reader.read_joints(0) {
        Some(it) => {
            let v: Vec<[u16; 4]> = it.into_u16().collect();
            same("JOINTS_0", v.len())?;
            Some(v)
        }
        None => None,
    };
    let weights = match reader.read_weights(0) {
        Some(it) => {
            let v: Vec<[f64; 4]> = it.into_f32().map(|w| w.map(f64::from)).collect();
            same("WEIGHTS_0", v.len())?;
            Some(v)
        }
        None => None,
    };
    let flat: Vec<u32> = match p.indices() {
        Some(_) => reader
            .read_indices()
            .ok_or_else(|| here("unreadable indices".into()))?
            .into_u32()
            .collect(),
        None => (0..n as u32).collect(),
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
        normals,
        uvs,
        joints,
        weights,
        triangles: flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
        material: p.material().index(),
    })
}
