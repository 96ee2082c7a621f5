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

    #[test]
    fn pack_rgb_is_little_endian_rgb() {
        assert_eq!(pack_rgb(&[1, 2, 3]).to_le_bytes(), [1, 2, 3, 0]);
    }
}
