// Dynamic-shadow application, seeds/000 §3.3 eqs. 9–11, line for line after reproj-core
// `shadow.rs` (see its module docs for the subframe times and where we differ from the reference:
// equal levels give the key colour instead of 0/0; colours stay in f32 until the final rounding).

// The quantised level L_j of subframe j.
fn level(bits: u32, j: u32) -> u32 {
    return (bits >> (2u * j)) & 3u;
}

// C(j), the colour of subframe j (eq. 10 and the lerp inside eq. 11).
fn subframe_color(base: vec3<f32>, bits: u32, s_min: u32, s_max: u32, j: u32, s: u32) -> vec3<f32> {
    if j == 0u || j >= s || bits == 0u {
        return base;
    }
    let l0 = level(bits, 0u);
    var lmin = l0;
    var lmax = l0;
    for (var i = 1u; i < s; i++) {
        let l = level(bits, i);
        lmin = min(lmin, l);
        lmax = max(lmax, l);
    }
    if lmax == lmin {
        // All levels equal: nothing changes over the interval (the reference's 0/0).
        return base;
    }
    let tau = f32(level(bits, j) - lmin) / f32(lmax - lmin);
    let a = select(rgb_of(s_min), base, lmin == l0);
    let b = select(rgb_of(s_max), base, lmax == l0);
    return vec3<f32>(a.x + tau * (b.x - a.x), a.y + tau * (b.y - a.y), a.z + tau * (b.z - a.z));
}

// c_S, the colour of a source pixel at α with its dynamic shadow applied (eqs. 9–11).
fn shadow_color(base_rgb: u32, bits: u32, s_min: u32, s_max: u32, alpha: f32, s: u32, role: u32) -> vec3<f32> {
    let basef = rgb_of(base_rgb);
    if bits == 0u {
        return basef;
    }
    let beta = f32(s) * alpha;
    let lo = floor(beta);
    let hi = ceil(beta);
    // lo ≥ S: extrapolation; hi ≤ 0: α = 0, the key frame time of the older image.
    if !(lo < f32(s) && hi > 0.0) {
        return basef;
    }
    let lo_i = u32(lo);
    let hi_i = u32(hi);
    let lambda = beta - lo;
    var j_lo = lo_i;
    var j_hi = hi_i;
    if role == ROLE_NEWER {
        j_lo = s - lo_i;
        j_hi = s - hi_i;
    }
    if j_lo == j_hi || j_hi >= s {
        return subframe_color(basef, bits, s_min, s_max, j_lo, s);
    } else if j_lo >= s {
        return subframe_color(basef, bits, s_min, s_max, j_hi, s);
    }
    let a = subframe_color(basef, bits, s_min, s_max, j_lo, s);
    let b = subframe_color(basef, bits, s_min, s_max, j_hi, s);
    return vec3<f32>(a.x + lambda * (b.x - a.x), a.y + lambda * (b.y - a.y), a.z + lambda * (b.z - a.z));
}

// `round_rgb`: a colour in [0, 255] floats to RGB8 (half up after clamping), packed R | G << 8 |
// B << 16.
fn round_rgb(c: vec3<f32>) -> u32 {
    let r = u32(clamp(c.x, 0.0, 255.0) + 0.5);
    let g = u32(clamp(c.y, 0.0, 255.0) + 0.5);
    let b = u32(clamp(c.z, 0.0, 255.0) + 0.5);
    return r | (g << 8u) | (b << 16u);
}
