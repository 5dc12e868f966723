// 1-pixel points with subgroup operations (64-bit path; the host appends
// rasterize.wgsl and project.wgsl and uses this entry where the adapter has
// wgpu::Features::SUBGROUP). Invocations read points as `main` does, strided by
// the workgroup size, so a subgroup's loads coalesce; in Morton order a
// subgroup's consecutive points mostly land on one pixel, and then the
// subgroup reduces them and one invocation writes: one depth test and at most
// one atomicMin for 32 points instead of 32 (Schütz et al. 2021 dedup
// consecutive points per thread; this does it across a subgroup, keeping the
// loads coalesced). Where the subgroup's points fall on several pixels,
// SEGMENTED (set by the host) picks a segmented min over runs of equal pixels,
// or else each invocation writes its own point.
// The result is what `main` leaves: the minimum of `depth << 32 | rgb` per pixel.

const SEGMENTED: bool = false; // replaced by the host

@compute @workgroup_size(256)
fn main_subgroup(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
    @builtin(subgroup_invocation_id) lane: u32,
    @builtin(subgroup_size) lanes: u32,
) {
    let none = 0xffffffffu;
    let base = (wg.y * nwg.x + wg.x) * (256u * POINTS_PER_THREAD) + li;
    if (params.point_size != 1u) {
        for (var k = 0u; k < POINTS_PER_THREAD; k++) {
            let i = base + k * 256u;
            if (i >= params.count) {
                return;
            }
            draw(i);
        }
        return;
    }
    // No early return: every invocation of the subgroup takes part in each
    // subgroup operation.
    for (var k = 0u; k < POINTS_PER_THREAD; k++) {
        let i = base + k * 256u;
        var idx = none;
        var depth = none;
        if (i < params.count) {
            let p = project(i);
            if (p.w != 0.0) {
                idx = pixel_of(p.xy);
                depth = bitcast<u32>(p.z);
            }
        }
        let first = subgroupBroadcastFirst(idx);
        if (subgroupAll(idx == first)) {
            if (first == none) {
                continue;
            }
            let dmin = subgroupMin(depth);
            // PRETEST
            // Colour only from the nearest points: the 64-bit minimum breaks
            // depth ties by colour.
            var c = none;
            if (depth == dmin) {
                c = cs[i] & 0xffffffu;
            }
            let cmin = subgroupMin(c);
            if (lane == 0u) {
                write_min(first, (u64(dmin) << 32u) | u64(cmin));
            }
            continue;
        }
        if (!SEGMENTED) {
            if (idx != none) {
                write_min(idx, (u64(depth) << 32u) | u64(cs[i] & 0xffffffu));
            }
            continue;
        }
        // Segmented minimum: after the step of width s, each invocation holds
        // the minimum over the invocations [lane, lane + 2s) of its own pixel
        // that it reached through neighbours of that pixel; the first of each
        // run of equal pixels then holds its run's minimum.
        var c = none;
        if (idx != none) {
            c = cs[i] & 0xffffffu;
        }
        for (var s = 1u; s < lanes; s = s << 1u) {
            let oi = subgroupShuffleDown(idx, s);
            let od = subgroupShuffleDown(depth, s);
            let oc = subgroupShuffleDown(c, s);
            if (lane + s < lanes && oi == idx && (od < depth || (od == depth && oc < c))) {
                depth = od;
                c = oc;
            }
        }
        let prev = subgroupShuffleUp(idx, 1u);
        if (idx != none && (lane == 0u || prev != idx)) {
            write_min(idx, (u64(depth) << 32u) | u64(c));
        }
    }
}

