// Camera maths, line for line after reproj-core `camera.rs` (DESIGN.md conventions: NDC x left →
// right, y bottom → top, pixel centre of column i, row j at ((2i+1)/W − 1, 1 − (2j+1)/H); reversed
// depth; row-major matrices acting on column vectors).
//
// Sums are written in the CPU's order. A GPU compiler may still contract a·b + c into one fused
// multiply-add, so results can differ from the CPU in the last bit; the parity tests bound what
// that changes in the output.

// Whether `x` is neither NaN nor infinite, from its bits: WGSL has no isnan, and a compiler may
// assume that float comparisons never see NaN, so every validity test of the CPU path that relies
// on NaN failing a comparison is an explicit bit test here.
fn is_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) < 0x7f800000u;
}

fn all_finite3(v: vec3<f32>) -> bool {
    return is_finite(v.x) && is_finite(v.y) && is_finite(v.z);
}

fn all_finite4(v: vec4<f32>) -> bool {
    return is_finite(v.x) && is_finite(v.y) && is_finite(v.z) && is_finite(v.w);
}

// `M4::apply`: M · (x, y, z, 1)ᵀ, the full homogeneous result.
fn m4_apply(m: array<vec4<f32>, 4>, p: vec3<f32>) -> vec4<f32> {
    return vec4<f32>(
        m[0].x * p.x + m[0].y * p.y + m[0].z * p.z + m[0].w,
        m[1].x * p.x + m[1].y * p.y + m[1].z * p.z + m[1].w,
        m[2].x * p.x + m[2].y * p.y + m[2].z * p.z + m[2].w,
        m[3].x * p.x + m[3].y * p.y + m[3].z * p.z + m[3].w,
    );
}

// `NdcTransfer::clip`: clip coordinates in the target camera of the world point P_from⁻¹(c̄),
// divided by that point's homogeneous w.
fn transfer_clip(t: Transfer, c: vec3<f32>) -> vec4<f32> {
    let h = m4_apply(t.m, c);
    let r = t.w_row;
    let iw = 1.0 / (r.x * c.x + r.y * c.y + r.z * c.z + r.w);
    return vec4<f32>(h.x * iw, h.y * iw, h.z * iw, h.w * iw);
}

// `ndc_of_pixel`: NDC of the centre of pixel (i, j) in a w × h image.
fn ndc_of_pixel(i: u32, j: u32, w: u32, h: u32) -> vec2<f32> {
    return vec2<f32>(
        f32(2u * i + 1u) / f32(w) - 1.0,
        1.0 - f32(2u * j + 1u) / f32(h),
    );
}

// `pixel_of_ndc`: the pixel of a w × h image containing NDC (x, y), i = ⌊(x+1)·W/2⌋,
// j = ⌊(1−y)·H/2⌋; (-1, -1) outside the image or for NaN (the CPU's `None`).
fn pixel_of_ndc(x: f32, y: f32, w: u32, h: u32) -> vec2<i32> {
    let wf = f32(w);
    let hf = f32(h);
    let fx = (x + 1.0) * 0.5 * wf;
    let fy = (1.0 - y) * 0.5 * hf;
    if is_finite(fx) && is_finite(fy) && fx >= 0.0 && fy >= 0.0 && fx < wf && fy < hf {
        return vec2<i32>(i32(min(u32(fx), w - 1u)), i32(min(u32(fy), h - 1u)));
    }
    return vec2<i32>(-1, -1);
}

fn rgb_of(c: u32) -> vec3<f32> {
    return vec3<f32>(f32(c & 0xffu), f32((c >> 8u) & 0xffu), f32((c >> 16u) & 0xffu));
}
