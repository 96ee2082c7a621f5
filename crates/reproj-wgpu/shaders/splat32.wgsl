// Pass 1 with 32-bit atomics only, for adapters without 64-bit atomic min/max: the same maximum of
// (bits(z), !idx) as `splat64.wgsl`, exactly, in two dispatches over the same points.
//
// Each cell is two words, laid out as the 64-bit key in memory (word 2k = !idx, word 2k+1 =
// bits(z)), so the resolve pass is the same for both. `depth_pass` keeps the largest bits(z) per
// cell (positive floats order like their bits); after it has finished, `index_pass` recomputes
// every point (deterministically, the same code on the same inputs) and, where its depth equals the
// cell's, keeps the largest !idx, i.e. the smallest source index among the nearest points.

@group(0) @binding(4) var<storage, read_write> splat: array<atomic<u32>>;

@compute @workgroup_size(16, 16, 1)
fn depth_pass(@builtin(global_invocation_id) gid: vec3<u32>) {
    let p = splat_point(gid, true);
    if p.cell >= 0 {
        atomicMax(&splat[2u * u32(p.cell) + 1u], bitcast<u32>(p.key_z));
    }
}

@compute @workgroup_size(16, 16, 1)
fn index_pass(@builtin(global_invocation_id) gid: vec3<u32>) {
    let p = splat_point(gid, false);
    if p.cell >= 0 && atomicLoad(&splat[2u * u32(p.cell) + 1u]) == bitcast<u32>(p.key_z) {
        atomicMax(&splat[2u * u32(p.cell)], ~p.idx);
    }
}
