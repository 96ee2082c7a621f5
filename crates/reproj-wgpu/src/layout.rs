//! Host mirrors of the WGSL uniform structs in `shaders/shared/bindings.wgsl` (same field order;
//! `#[repr(C)]` with explicit padding so that the byte layout is WGSL's uniform layout).

use bytemuck::{Pod, Zeroable};
use reproj_core::NdcTransfer;

/// Source slots: two frames × (main + up to three auxiliary cameras).
pub const MAX_SLOTS: usize = 8;

/// `Transfer`: reproj-core's [`NdcTransfer`], rows of the matrix and the world-w row.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct TransferU {
    /// `P_to · P_from⁻¹`, row-major.
    pub m: [[f32; 4]; 4],
    /// Row 3 of `P_from⁻¹`.
    pub w_row: [f32; 4],
}

impl From<&NdcTransfer> for TransferU {
    fn from(t: &NdcTransfer) -> Self {
        let m = &t.m.0;
        TransferU {
            m: [
                [m[0], m[1], m[2], m[3]],
                [m[4], m[5], m[6], m[7]],
                [m[8], m[9], m[10], m[11]],
                [m[12], m[13], m[14], m[15]],
            ],
            w_row: t.w_row,
        }
    }
}

/// `Source`: what stays fixed while a pair is loaded.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct SourceU {
    pub to_other: TransferU,
    pub from_other: TransferU,
    pub to_main_same: TransferU,
    pub to_main_other: TransferU,
    pub offset: u32,
    pub width: u32,
    pub height: u32,
    pub present: u32,
    pub cell_offset: u32,
    pub _pad: [u32; 3],
}

/// `FrameSource`: per client frame and slot.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct FrameSourceU {
    pub to_client: TransferU,
    pub w: f32,
    pub _pad: [f32; 3],
}

/// `Frame`: per client frame.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct FrameU {
    pub client_w: u32,
    pub client_h: u32,
    pub alpha: f32,
    pub mode: u32,
    pub bidirectional: u32,
    pub n_aux: u32,
    pub iterations: u32,
    pub window: u32,
    pub subframes: u32,
    pub shadows: u32,
    pub blend: u32,
    pub vis_other: u32,
    pub eps_e: f32,
    pub eps_e_aux: f32,
    pub eps_z: f32,
    pub eps_z_aux: f32,
    pub eps_o: f32,
    pub _pad: [f32; 3],
    pub sources: [FrameSourceU; MAX_SLOTS],
}

/// `Texel`: one source pixel of the concatenated per-pixel buffer.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct TexelU {
    pub color: u32,
    pub depth: f32,
    pub motion: [f32; 3],
    pub bits: u32,
    pub s_min: u32,
    pub s_max: u32,
}

/// Bytes per auxiliary cell (`AuxCell`: 8 words).
pub const AUX_CELL_BYTES: u64 = 32;
/// Bytes per flow entry (`vec4<f32>`).
pub const FLOW_BYTES: u64 = 16;
/// Bytes per splat cell (one 64-bit key, or two 32-bit words).
pub const SPLAT_BYTES: u64 = 8;
/// Bytes per output pixel (packed RGB8).
pub const OUT_BYTES: u64 = 4;
/// Bytes per diagnostics entry (`vec2<u32>`).
pub const DIAG_BYTES: u64 = 8;

/// RGB8 packed as `R | G << 8 | B << 16`, as the shaders read and write it.
#[inline]
pub fn pack_rgb(c: &[u8]) -> u32 {
    u32::from(c[0]) | (u32::from(c[1]) << 8) | (u32::from(c[2]) << 16)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The byte size naga computes for every shared WGSL struct equals its Rust mirror's.
    #[test]
    fn sizes_match_the_wgsl_structs() {
        let src = crate::shaders::SHARED[0].1;
        let module = naga::front::wgsl::parse_str(src).expect("bindings.wgsl parses");
        let size = |name: &str| {
            let (_, ty) = module
                .types
                .iter()
                .find(|(_, t)| t.name.as_deref() == Some(name))
                .unwrap_or_else(|| panic!("no WGSL struct {name}"));
            ty.inner.size(module.to_ctx()) as usize
        };
        use std::mem::size_of;
        assert_eq!(size("Transfer"), size_of::<TransferU>());
        assert_eq!(size("Source"), size_of::<SourceU>());
        assert_eq!(size("FrameSource"), size_of::<FrameSourceU>());
        assert_eq!(size("Frame"), size_of::<FrameU>());
        assert_eq!(size("Texel"), size_of::<TexelU>());
        assert_eq!(size("AuxCell") as u64, AUX_CELL_BYTES);
        // The uniform layout rule: array elements of a uniform are 16-byte multiples.
        assert_eq!(size_of::<SourceU>() % 16, 0);
        assert_eq!(size_of::<FrameSourceU>() % 16, 0);
    }

    /// Every member of every shared WGSL struct with a Rust mirror sits at the byte offset of the
    /// mirror's field (sizes alone let two fields of one type trade places: the shaders then read
    /// `eps_z_aux` as `eps_z`, or the window as the iteration count).
    #[test]
    fn offsets_match_the_wgsl_structs() {
        use std::mem::offset_of;
        let src = crate::shaders::SHARED[0].1;
        let module = naga::front::wgsl::parse_str(src).expect("bindings.wgsl parses");
        // (WGSL struct, [(WGSL member, offset of the Rust field that mirrors it)]).
        let tables: [(&str, Vec<(&str, usize)>); 5] = [
            (
                "Transfer",
                vec![
                    ("m", offset_of!(TransferU, m)),
                    ("w_row", offset_of!(TransferU, w_row)),
                ],
            ),
            (
                "Source",
                vec![
                    ("to_other", offset_of!(SourceU, to_other)),
                    ("from_other", offset_of!(SourceU, from_other)),
                    ("to_main_same", offset_of!(SourceU, to_main_same)),
                    ("to_main_other", offset_of!(SourceU, to_main_other)),
                    ("offset", offset_of!(SourceU, offset)),
                    ("width", offset_of!(SourceU, width)),
                    ("height", offset_of!(SourceU, height)),
                    ("present", offset_of!(SourceU, present)),
                    ("cell_offset", offset_of!(SourceU, cell_offset)),
                    ("_pad0", offset_of!(SourceU, _pad)),
                    ("_pad1", offset_of!(SourceU, _pad) + 4),
                    ("_pad2", offset_of!(SourceU, _pad) + 8),
                ],
            ),
            (
                "FrameSource",
                vec![
                    ("to_client", offset_of!(FrameSourceU, to_client)),
                    ("w", offset_of!(FrameSourceU, w)),
                    ("_pad0", offset_of!(FrameSourceU, _pad)),
                    ("_pad1", offset_of!(FrameSourceU, _pad) + 4),
                    ("_pad2", offset_of!(FrameSourceU, _pad) + 8),
                ],
            ),
            (
                "Frame",
                vec![
                    ("client_w", offset_of!(FrameU, client_w)),
                    ("client_h", offset_of!(FrameU, client_h)),
                    ("alpha", offset_of!(FrameU, alpha)),
                    ("mode", offset_of!(FrameU, mode)),
                    ("bidirectional", offset_of!(FrameU, bidirectional)),
                    ("n_aux", offset_of!(FrameU, n_aux)),
                    ("iterations", offset_of!(FrameU, iterations)),
                    ("window", offset_of!(FrameU, window)),
                    ("subframes", offset_of!(FrameU, subframes)),
                    ("shadows", offset_of!(FrameU, shadows)),
                    ("blend", offset_of!(FrameU, blend)),
                    ("vis_other", offset_of!(FrameU, vis_other)),
                    ("eps_e", offset_of!(FrameU, eps_e)),
                    ("eps_e_aux", offset_of!(FrameU, eps_e_aux)),
                    ("eps_z", offset_of!(FrameU, eps_z)),
                    ("eps_z_aux", offset_of!(FrameU, eps_z_aux)),
                    ("eps_o", offset_of!(FrameU, eps_o)),
                    ("_pad0", offset_of!(FrameU, _pad)),
                    ("_pad1", offset_of!(FrameU, _pad) + 4),
                    ("_pad2", offset_of!(FrameU, _pad) + 8),
                    ("sources", offset_of!(FrameU, sources)),
                ],
            ),
            (
                "Texel",
                vec![
                    ("color", offset_of!(TexelU, color)),
                    ("depth", offset_of!(TexelU, depth)),
                    ("mx", offset_of!(TexelU, motion)),
                    ("my", offset_of!(TexelU, motion) + 4),
                    ("mz", offset_of!(TexelU, motion) + 8),
                    ("bits", offset_of!(TexelU, bits)),
                    ("s_min", offset_of!(TexelU, s_min)),
                    ("s_max", offset_of!(TexelU, s_max)),
                ],
            ),
        ];
        for (name, table) in tables {
            let (_, ty) = module
                .types
                .iter()
                .find(|(_, t)| t.name.as_deref() == Some(name))
                .unwrap_or_else(|| panic!("no WGSL struct {name}"));
            let naga::TypeInner::Struct { members, .. } = &ty.inner else {
                panic!("{name} is not a struct");
            };
            let wgsl: Vec<(&str, usize)> = members
                .iter()
                .map(|m| (m.name.as_deref().unwrap_or("?"), m.offset as usize))
                .collect();
            assert_eq!(
                wgsl, table,
                "{name}: WGSL members and offsets against the Rust mirror"
            );
        }
    }

    #[test]
    fn pack_rgb_is_little_endian_rgb() {
        assert_eq!(pack_rgb(&[1, 2, 3]).to_le_bytes(), [1, 2, 3, 0]);
    }
}
