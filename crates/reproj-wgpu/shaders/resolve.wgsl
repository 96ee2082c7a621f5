// Pass 2, per output pixel (and per auxiliary grid cell): window search, fixed-point iteration,
// Algorithm 1, auxiliary merge and Algorithm 2, after reproj-core `ours/` (search.rs,
// select.rs, auxiliary.rs: `Resolve::search`, `best_match`, `color_of`, `second_chance`,
// `correspondence`, `resolve_aux_grid`, `resolve_pixel`). Two steps are arranged differently on
// the CPU, with the same results: the CPU does the window search for all cells at once as a
// separable minimum filter (`window_min`), where a GPU invocation scans its 3×3 window directly,
// and it evaluates Algorithm 2's full scene flows (eqs. 2, 3) for every pixel in pass 1
// (`full_flow_row`), where the GPU evaluates them for the chosen match only (`correspondence`
// below).

// M_cam per source pixel (pass 1): xyz flow, w = 1 / 0 visible in main, -1 invalid.
@group(0) @binding(3) var<storage, read_write> flow: array<vec4<f32>>;
// Splat cells: x = !idx, y = bits(z); (0, 0) is empty (see splat64.wgsl).
@group(0) @binding(4) var<storage, read_write> splat: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read_write> aux_cells: array<AuxCell>;
// The client image, R | G << 8 | B << 16 per pixel; unmatched pixels keep what is there.
@group(0) @binding(6) var<storage, read_write> out_rgb: array<u32>;
// Diagnostics per output pixel: (source code, bits of the error; NaN where none).
@group(0) @binding(7) var<storage, read_write> out_diag: array<vec2<u32>>;

const NAN_BITS: u32 = 0x7fc00000u;
const CODE_MAIN_OLDER: u32 = 1u;
const CODE_MAIN_NEWER: u32 = 2u;
const CODE_AUX_BASE: u32 = 3u;
const CODE_BLENDED: u32 = 0x80u;

// The outcome of the search in one source image for one output pixel.
struct Match {
    valid: bool,
    // Source pixel index (source-local).
    p: u32,
    // Reprojection error (eq. 7), aspect-scaled NDC.
    e: f32,
    // Client reversed depth (eq. 8).
    z: f32,
    vis: bool,
}

// A per-camera decision of Algorithm 1.
struct Choice {
    valid: bool,
    slot: u32,
    m: Match,
    visible_in_main: bool,
}

struct Shaded {
    rgb: vec3<f32>,
    blended: bool,
}

fn no_match() -> Match {
    return Match(false, 0u, NO_ERROR, 0.0, false);
}

// Whether splat key k is nearer (or as near with a smaller source index) than `best`.
fn key_wins(k: vec2<u32>, best: vec2<u32>) -> bool {
    return k.y > best.y || (k.y == best.y && k.x > best.x);
}

// `Resolve::search`: the window search and fixed-point iteration in source `slot` for the output
// pixel at NDC t.
fn search(slot: u32, t: vec2<f32>) -> Match {
    let sw = sources[slot].width;
    let sh = sources[slot].height;
    let off = sources[slot].offset;
    let c = pixel_of_ndc(t.x, t.y, sw, sh);
    if c.x < 0 {
        return no_match();
    }
    let ci = u32(c.x);
    let cj = u32(c.y);
    let wr = frame.window;
    let i0 = select(ci - wr, 0u, ci < wr);
    let i1 = min(ci + wr, sw - 1u);
    let j0 = select(cj - wr, 0u, cj < wr);
    let j1 = min(cj + wr, sh - 1u);
    var best = vec2<u32>(0u, 0u);
    for (var qj = j0; qj <= j1; qj++) {
        for (var qi = i0; qi <= i1; qi++) {
            let k = splat[off + qj * sw + qi];
            if key_wins(k, best) {
                best = k;
            }
        }
    }
    if best.x == 0u {
        return no_match();
    }
    var p = ~best.x;
    var pi = p % sw;
    var pj = p / sw;
    // Fixed-point iteration p ← pix(T − M_cam[p]) (eq. 5 with the flows of eqs. 12/13), stopping
    // once p maps to itself (every further iteration would too).
    var m = flow[off + p];
    for (var it = 0u; it < frame.iterations; it++) {
        if m.w < 0.0 {
            break; // NaN flow on the CPU: pixel_of_ndc fails
        }
        let n = pixel_of_ndc(t.x - m.x, t.y - m.y, sw, sh);
        if n.x < 0 || (u32(n.x) == pi && u32(n.y) == pj) {
            break;
        }
        pi = u32(n.x);
        pj = u32(n.y);
        p = pj * sw + pi;
        m = flow[off + p];
    }
    if m.w < 0.0 {
        return no_match();
    }
    let pxy = ndc_of_pixel(pi, pj, sw, sh);
    let short = f32(min(sw, sh));
    let ex = (pxy.x + m.x - t.x) * (f32(sw) / short);
    let ey = (pxy.y + m.y - t.y) * (f32(sh) / short);
    let e = sqrt(ex * ex + ey * ey);
    let z = texels[off + p].depth + m.z;
    if !(is_finite(e) && is_finite(z)) {
        return no_match();
    }
    return Match(true, p, e, z, m.w > 0.0);
}

// `Resolve::best_match`: Algorithm 1 for camera `cam`.
fn best_match(cam: u32, t: vec2<f32>, eps_e: f32, eps_z: f32) -> Choice {
    var none = Choice(false, 0u, no_match(), false);
    if frame.bidirectional != 0u {
        let fi = 2u * cam;
        let bi = 2u * cam + 1u;
        let f = search(fi, t);
        let b = search(bi, t);
        let ef = select(NO_ERROR, f.e, f.valid);
        let eb = select(NO_ERROR, b.e, b.valid);
        let f_ok = f.valid && ef < eps_e;
        let b_ok = b.valid && eb < eps_e;
        if !f_ok && !b_ok {
            return none;
        }
        let both = f_ok && b_ok;
        let zf = select(0.0, f.z, f.valid);
        let zb = select(0.0, b.z, b.valid);
        let sim = both && 2.0 * abs(zf - zb) < eps_z;
        // Both correspond but differ in depth: the nearer (larger reversed depth) occludes.
        // Otherwise the smaller error (the only corresponding one if just one does).
        let older = (both && !sim && zf > zb) || ((!both || sim) && ef < eb);
        if older {
            if !f.valid {
                return none;
            }
            return Choice(true, fi, f, f.vis || (sim && b.valid && b.vis));
        }
        if !b.valid {
            return none;
        }
        return Choice(true, bi, b, b.vis || (sim && f.valid && f.vis));
    }
    let slot = 2u * cam + 1u;
    let m = search(slot, t);
    if !(m.valid && m.e < eps_e) {
        return none;
    }
    return Choice(true, slot, m, m.vis);
}

// `Resolve::color_of`: colour of pixel p of `slot` with its dynamic shadow applied at α.
fn color_of(slot: u32, p: u32) -> vec3<f32> {
    let t = texels[sources[slot].offset + p];
    if frame.shadows != 0u {
        return shadow_color(t.color, t.bits, t.s_min, t.s_max, frame.alpha, frame.subframes, slot & 1u);
    }
    return rgb_of(t.color);
}

struct FullFlow {
    valid: bool,
    f: vec3<f32>,
}

// The full scene flow (eqs. 2, 3) of pixel (i, j) of `slot` through transfer `to`.
fn full_flow(slot: u32, to: Transfer, i: u32, j: u32) -> FullFlow {
    let w = sources[slot].width;
    let t = texels[sources[slot].offset + j * w + i];
    let z = t.depth;
    let xy = ndc_of_pixel(i, j, w, sources[slot].height);
    let h = transfer_clip(to, vec3<f32>(xy.x + t.mx, xy.y + t.my, z + t.mz));
    if !(h.w > 0.0) || !is_finite(h.w) {
        return FullFlow(false, vec3<f32>(0.0));
    }
    let iw = 1.0 / h.w;
    let f = vec3<f32>(h.x * iw - xy.x, h.y * iw - xy.y, h.z * iw - z);
    return FullFlow(all_finite3(f), f);
}

struct Correspondence {
    valid: bool,
    // Pixel index in the other slot.
    q: u32,
    // M_full_s(p) + M_full_o(q).
    sum: vec3<f32>,
    zq: f32,
    pz: f32,
}

// `correspondence`: pixel p of `slot` moved by its full scene flow into the same camera at the
// other time, and the full flow back from the pixel q it lands on.
fn correspondence(slot: u32, p: u32) -> Correspondence {
    var none = Correspondence(false, 0u, vec3<f32>(0.0), 0.0, 0.0);
    let other = slot ^ 1u;
    let w = sources[slot].width;
    let pi = p % w;
    let pj = p / w;
    let ms = full_flow(slot, sources[slot].to_other, pi, pj);
    if !ms.valid {
        return none;
    }
    let xy = ndc_of_pixel(pi, pj, w, sources[slot].height);
    let pz = texels[sources[slot].offset + p].depth + ms.f.z;
    let ow = sources[other].width;
    let qq = pixel_of_ndc(xy.x + ms.f.x, xy.y + ms.f.y, ow, sources[other].height);
    if qq.x < 0 {
        return none;
    }
    let q = u32(qq.y) * ow + u32(qq.x);
    let zq = texels[sources[other].offset + q].depth;
    if !is_finite(zq) {
        return none;
    }
    let mo = full_flow(other, sources[slot].from_other, u32(qq.x), u32(qq.y));
    if !mo.valid {
        return none;
    }
    return Correspondence(true, q, ms.f + mo.f, zq, pz);
}

// `Resolve::second_chance`: Algorithm 2, the colour of the chosen match blended with its
// correspondence in the other frame when the motions cancel and the depths agree.
fn second_chance(c: Choice, eps_z: f32) -> Shaded {
    let base = color_of(c.slot, c.m.p);
    if frame.blend == 0u {
        return Shaded(base, false);
    }
    let k = correspondence(c.slot, c.m.p);
    if !k.valid {
        return Shaded(base, false);
    }
    // ‖M_full_s(p) + M_full_o(q)‖ < ε_O, z in [−1,1]-NDC units (2·ΔZ).
    let n2 = k.sum.x * k.sum.x + k.sum.y * k.sum.y + 4.0 * k.sum.z * k.sum.z;
    let eps_o = frame.eps_o;
    if !(n2 < eps_o * eps_o && 2.0 * abs(k.zq - k.pz) < eps_z) {
        return Shaded(base, false);
    }
    let oc = color_of(c.slot ^ 1u, k.q);
    // ω: the weight of the chosen side's own colour.
    let omega = select(frame.alpha, 1.0 - frame.alpha, (c.slot & 1u) == ROLE_OLDER);
    return Shaded(vec3<f32>(
        omega * base.x + (1.0 - omega) * oc.x,
        omega * base.y + (1.0 - omega) * oc.y,
        omega * base.z + (1.0 - omega) * oc.z,
    ), true);
}

// `Resolve::code_of`: the diagnostic code of a choice.
fn code_of(slot: u32, blended: bool) -> u32 {
    let cam = slot / 2u;
    let role = slot & 1u;
    var code = CODE_AUX_BASE + 2u * (cam - 1u) + role;
    if cam == 0u {
        code = select(CODE_MAIN_NEWER, CODE_MAIN_OLDER, role == ROLE_OLDER);
    }
    return select(code, code | CODE_BLENDED, blended);
}

// `Resolve::resolve_aux_grid`: Algorithms 1 and 2 for auxiliary camera gid.z + 1, once per cell of
// its grid (the newer frame's camera resolution), aiming at the cell centre.
@compute @workgroup_size(16, 16, 1)
fn aux_grid(@builtin(global_invocation_id) gid: vec3<u32>) {
    let cam = gid.z + 1u;
    let gslot = 2u * cam + 1u;
    let w = sources[gslot].width;
    let h = sources[gslot].height;
    if gid.x >= w || gid.y >= h {
        return;
    }
    let t = ndc_of_pixel(gid.x, gid.y, w, h);
    let cell = sources[gslot].cell_offset + gid.y * w + gid.x;
    let choice = best_match(cam, t, frame.eps_e_aux, frame.eps_z_aux);
    if !choice.valid {
        aux_cells[cell] = AuxCell(0u, 0u, 0.0, 0.0, 0u, 0.0, 0.0, 0.0);
        return;
    }
    let s = second_chance(choice, frame.eps_z_aux);
    aux_cells[cell] = AuxCell(
        1u,
        code_of(choice.slot, s.blended),
        choice.m.z,
        choice.m.e,
        select(0u, 1u, choice.visible_in_main),
        s.rgb.x,
        s.rgb.y,
        s.rgb.z,
    );
}

// `Resolve::resolve_pixel`: the whole per-pixel decision for output pixel gid.xy.
@compute @workgroup_size(16, 16, 1)
fn resolve(@builtin(global_invocation_id) gid: vec3<u32>) {
    let cw = frame.client_w;
    if gid.x >= cw || gid.y >= frame.client_h {
        return;
    }
    let o = gid.y * cw + gid.x;
    let t = ndc_of_pixel(gid.x, gid.y, cw, frame.client_h);
    let main = best_match(0u, t, frame.eps_e, frame.eps_z);
    // Best auxiliary match (§3.5): the nearer if depths differ, else the smaller error.
    var aux = AuxCell(0u, 0u, 0.0, 0.0, 0u, 0.0, 0.0, 0.0);
    for (var a = 0u; a < frame.n_aux; a++) {
        let gslot = 2u * (a + 1u) + 1u;
        let gw = sources[gslot].width;
        let q = pixel_of_ndc(t.x, t.y, gw, sources[gslot].height);
        if q.x < 0 {
            continue;
        }
        let c = aux_cells[sources[gslot].cell_offset + u32(q.y) * gw + u32(q.x)];
        if c.valid == 0u {
            continue;
        }
        if aux.valid == 0u {
            aux = c;
        } else {
            let sim = 2.0 * abs(c.z - aux.z) < frame.eps_z_aux;
            if (!sim && c.z > aux.z) || (sim && c.e < aux.e) {
                aux = c;
            }
        }
    }
    // Merge with main (§3.5 rules 1–3): main wins unless it found nothing, or the auxiliary point
    // is nearer, at a different depth, and not visible in the main camera.
    var use_aux = false;
    if aux.valid != 0u {
        if main.valid {
            let sim = 2.0 * abs(aux.z - main.m.z) < frame.eps_z_aux;
            use_aux = aux.vis == 0u && !sim && aux.z > main.m.z;
        } else {
            use_aux = true;
        }
    }
    if use_aux {
        out_rgb[o] = round_rgb(vec3<f32>(aux.r, aux.g, aux.b));
        out_diag[o] = vec2<u32>(aux.code, bitcast<u32>(aux.e));
        return;
    }
    if !main.valid {
        out_diag[o] = vec2<u32>(0u, NAN_BITS);
        return;
    }
    let s = second_chance(main, frame.eps_z);
    out_rgb[o] = round_rgb(s.rgb);
    out_diag[o] = vec2<u32>(code_of(main.slot, s.blended), bitcast<u32>(main.m.e));
}
