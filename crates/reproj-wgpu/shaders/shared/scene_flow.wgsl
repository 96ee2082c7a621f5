// Pass 1, scene flow and splat target of one source pixel, line for line after reproj-core
// `ours/pass1.rs` (`scene_flow_and_splat`) and `ours/pair.rs` (`visible_in`). Used by both
// splat variants (`splat64.wgsl`, `splat32.wgsl`), which differ only in how the key reaches the
// grid.

@group(0) @binding(3) var<storage, read_write> flow: array<vec4<f32>>;

// What pass 1 computes for one source pixel.
struct SplatPoint {
    // M_cam = P_{t+α}(X(w)) − p̄ (xyz), w = 1 visible in main / 0 not; (0, 0, 0, -1) for an invalid
    // pixel (NaN on the CPU).
    flow: vec4<f32>,
    // Global index of the grid cell hit, or -1 when the point is not splatted.
    cell: i32,
    // Client reversed depth of the key, clamped to [+0, 1].
    key_z: f32,
    // Source-local pixel index j·W + i (the key's tie-break).
    idx: u32,
}

// The source slot of dispatch layer z: all slots when bidirectional, the newer ones otherwise.
fn slot_of_layer(z: u32) -> u32 {
    return select(2u * z + 1u, z, frame.bidirectional != 0u);
}

// `visible_in`: whether the point with clip coordinates h in the main camera of slot `main` is
// inside its frustum (strictly inside ±0.999) and not behind its depth buffer by more than eps_z.
fn visible_in(main: u32, h: vec4<f32>, eps_z: f32) -> bool {
    if !(h.w > 0.0) || !all_finite4(h) {
        return false;
    }
    let c = vec3<f32>(h.x / h.w, h.y / h.w, h.z / h.w);
    let lim = 0.999;
    if !(all_finite3(c) && abs(c.x) < lim && abs(c.y) < lim && c.z > 0.0 && c.z < 1.0) {
        return false;
    }
    let mw = sources[main].width;
    let q = pixel_of_ndc(c.x, c.y, mw, sources[main].height);
    if q.x < 0 {
        return false;
    }
    let zm = texels[sources[main].offset + u32(q.y) * mw + u32(q.x)].depth;
    // NaN main depth: the CPU's comparison fails, so the point counts as visible.
    if !is_finite(zm) {
        return true;
    }
    // Occluded when main saw something nearer (larger reversed depth) at that pixel.
    return !(2.0 * (zm - c.z) > eps_z);
}

// `scene_flow_and_splat` for pixel (i, j) of slot `slot`: eqs. 1, 12, 13 and the splat target.
fn scene_flow_point(slot: u32, i: u32, j: u32) -> SplatPoint {
    let src = sources[slot];
    let sw = src.width;
    let sh = src.height;
    let idx = j * sw + i;
    var out = SplatPoint(vec4<f32>(0.0, 0.0, 0.0, -1.0), -1, 0.0, idx);
    let t = texels[src.offset + idx];
    let z = t.depth;
    let o = vec3<f32>(t.mx, t.my, t.mz);
    // Invalid depth or motion never reaches the output (DESIGN.md).
    if !(is_finite(z) && z >= 0.0 && z <= 1.0 && all_finite3(o)) {
        return out;
    }
    let xy = ndc_of_pixel(i, j, sw, sh);
    let x = xy.x;
    let y = xy.y;
    let c = vec3<f32>(x, y, z);
    let c2 = vec3<f32>(x + o.x, y + o.y, z + o.z);
    let moved = o.x != 0.0 || o.y != 0.0 || o.z != 0.0;
    let fs = frame.sources[slot];
    let w = fs.w;
    // P_{t+α}(X + w·(X' − X)) = P X + w·(P X' − P X): the world-space blend of eq. 1 done on clip
    // coordinates, each already divided by its world w.
    let a = transfer_clip(fs.to_client, c);
    var h = a;
    if moved {
        let b = transfer_clip(fs.to_client, c2);
        h = vec4<f32>(a.x + w * (b.x - a.x), a.y + w * (b.y - a.y), a.z + w * (b.z - a.z), a.w + w * (b.w - a.w));
    }
    if !(h.w > 0.0) || !all_finite4(h) {
        return out; // behind the client camera (or degenerate)
    }
    let iw = 1.0 / h.w;
    let cc = vec3<f32>(h.x * iw, h.y * iw, h.z * iw);
    var v = true;
    if slot >= 2u {
        // Auxiliary source: the main camera at the source's time (slot of the same role), and at
        // the other time when bidirectional.
        let role = slot & 1u;
        let eps_z = frame.eps_z_aux;
        v = visible_in(role, transfer_clip(src.to_main_same, c), eps_z)
            || (frame.vis_other != 0u && visible_in(1u - role, transfer_clip(src.to_main_other, c2), eps_z));
    }
    out.flow = vec4<f32>(cc.x - x, cc.y - y, cc.z - z, select(0.0, 1.0, v));
    // In front of the client (w > 0, checked above) and not nearer than its near plane (with a
    // margin for the f32 round trip of points on it). Points at or beyond the far plane are kept,
    // their key depth clamped to exactly +0.
    if cc.z <= 1.0 + 1e-5 {
        let q = pixel_of_ndc(cc.x, cc.y, sw, sh);
        if q.x >= 0 {
            out.cell = i32(src.offset + u32(q.y) * sw + u32(q.x));
            out.key_z = select(0.0, min(cc.z, 1.0), cc.z > 0.0);
        }
    }
    return out;
}

// The point of splat-pass invocation `gid`, its scene flow stored when `store_flow`; cell -1
// (nothing to splat, nothing stored) for an invocation outside its source image.
fn splat_point(gid: vec3<u32>, store_flow: bool) -> SplatPoint {
    let slot = slot_of_layer(gid.z);
    if gid.x >= sources[slot].width || gid.y >= sources[slot].height {
        return SplatPoint(vec4<f32>(0.0), -1, 0.0, 0u);
    }
    let p = scene_flow_point(slot, gid.x, gid.y);
    if store_flow {
        flow[sources[slot].offset + p.idx] = p.flow;
    }
    return p;
}
