// Pass 1 with one 64-bit atomic maximum per point (wgpu SHADER_INT64_ATOMIC_MIN_MAX).
//
// reproj-core keeps the minimum of `(!bits(z) << 32) | idx` in cells reset to u64::MAX. Here the
// key is its bitwise complement, `(bits(z) << 32) | !idx`, kept by a maximum in cells cleared to
// 0 (a buffer clear, no pass): the order is exactly reversed, so the same point wins — the nearest
// (largest reversed depth), ties to the smaller source index. No real key is 0 (!idx ≠ 0), so 0
// still means "empty". The resolve pass reads a cell as vec2<u32>(low = !idx, high = bits(z)).

@group(0) @binding(4) var<storage, read_write> splat: array<atomic<u64>>;

@compute @workgroup_size(16, 16, 1)
fn splat_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let p = splat_point(gid, true);
    if p.cell >= 0 {
        let key = (u64(bitcast<u32>(p.key_z)) << 32u) | u64(~p.idx);
        atomicMax(&splat[u32(p.cell)], key);
    }
}
