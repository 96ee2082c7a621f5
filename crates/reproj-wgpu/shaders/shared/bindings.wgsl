// Shared types and the bind group of every reprojection pass (group 0, declared explicitly on the
// host by `bind_group_layout_entries` in `src/reprojector.rs`; the Rust mirrors of the uniform
// structs are in `src/layout.rs`).
//
// Source slots: slot 2c is camera c of the older frame F_t, slot 2c+1 camera c of the newer frame
// F_{t+1}; camera 0 is the main camera, camera 1 + i auxiliary camera i. A unidirectional frame
// uses the odd (newer) slots only, so reproj-core's `sources[cam]` is slot 2·cam + 1 there and its
// `sources[2·cam]`, `sources[2·cam + 1]` are the same slots when bidirectional.

const MAX_SLOTS: u32 = 8u;
const ROLE_OLDER: u32 = 0u;
const ROLE_NEWER: u32 = 1u;
const MODE_OURS: u32 = 0u;
const MODE_FORWARD_SPLAT: u32 = 1u;
// Stands in for reproj-core's `f32::INFINITY` (no infinity literal in WGSL); only compared.
const NO_ERROR: f32 = 3.0e38;

// reproj-core `NdcTransfer`: P_to · P_from⁻¹ (rows) and row 3 of P_from⁻¹ (the world point's w).
struct Transfer {
    m: array<vec4<f32>, 4>,
    w_row: vec4<f32>,
}

// What never changes while a pair is loaded, per source slot.
struct Source {
    // This camera's NDC → the same camera at the other time (eqs. 2, 3), and back.
    to_other: Transfer,
    from_other: Transfer,
    // This camera's NDC → the main camera at the same time / at the other time ("visible in main").
    to_main_same: Transfer,
    to_main_other: Transfer,
    // First texel of this source in the concatenated per-pixel buffers.
    offset: u32,
    width: u32,
    height: u32,
    present: u32,
    // First cell of this camera's auxiliary grid (newer auxiliary slots only).
    cell_offset: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// Per client frame and source slot: P_{t+α} · P_src⁻¹ and the fraction w of the object motion
// (α for the older frame, 1 − α for the newer one; negative when extrapolating).
struct FrameSource {
    to_client: Transfer,
    w: f32,
    _pad0: f32,
    _pad1: f32,
    _pad2: f32,
}

// Per client frame: the request and reproj-core's `Resolve` context.
struct Frame {
    client_w: u32,
    client_h: u32,
    alpha: f32,
    mode: u32,
    bidirectional: u32,
    n_aux: u32,
    iterations: u32,
    window: u32,
    subframes: u32,
    // mode == ours && params.use_shadows
    shadows: u32,
    // bidirectional && mode == ours && params.blend
    blend: u32,
    // bidirectional: "visible in main" also tests the main camera at the other time
    vis_other: u32,
    eps_e: f32,
    eps_e_aux: f32,
    eps_z: f32,
    eps_z_aux: f32,
    eps_o: f32,
    _pad0: f32,
    _pad1: f32,
    _pad2: f32,
    sources: array<FrameSource, MAX_SLOTS>,
}

// One source pixel: colour (RGB8 in the low bytes), reversed depth Z, object motion O (eq. 1,
// the direction of the source's role), shadow bitfield Φ and S_min / S_max (RGB8). A frame without
// motion carries zeros and one without shadows Φ = 0, which reproj-core treats identically.
struct Texel {
    color: u32,
    depth: f32,
    mx: f32,
    my: f32,
    mz: f32,
    bits: u32,
    s_min: u32,
    s_max: u32,
}

// reproj-core `AuxCell`: the auxiliary match of one grid cell with its colour after Algorithm 2.
struct AuxCell {
    valid: u32,
    code: u32,
    z: f32,
    e: f32,
    vis: u32,
    r: f32,
    g: f32,
    b: f32,
}

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<uniform> sources: array<Source, MAX_SLOTS>;
@group(0) @binding(2) var<storage, read> texels: array<Texel>;
