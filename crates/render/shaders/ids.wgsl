// The id pass (run only when the host keeps ids, after rasterize and before
// resolve): each point covers the same pixels as in `draw` of rasterize*.wgsl,
// and where the framebuffer holds exactly the value this point would have
// written, it records its id there. Ids are `0xffffffff - (id_base + i)` under
// `atomicMax` into a buffer cleared to 0 (no point), so the smallest id wins,
// as the CPU rasterizer's `winners` breaks ties. The framebuffer is read as
// plain words, so no 64-bit atomics are needed here. The host appends
// ids_match64.wgsl or ids_match32.wgsl (`matches`, per framebuffer), then project.wgsl.

// Params and the point bindings (group 0): project.wgsl, appended by the host.
@group(1) @binding(0) var<storage, read_write> ids: array<atomic<u32>>;

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let i = (wg.y * nwg.x + wg.x) * 256u + li;
    if (i >= params.count) {
        return;
    }
    let p = project(i);
    if (p.w == 0.0) {
        return;
    }
    let tag = 0xffffffffu - (params.id_base + i);
    if (params.point_size == 1u) {
        let idx = pixel_of(p.xy);
        if (idx != 0xffffffffu && matches(idx, i, p.z)) {
            atomicMax(&ids[idx], tag);
        }
        return;
    }
    let w = i32(params.width);
    let h = i32(params.height);
    let fx = p.x - params.off;
    let fy = p.y - params.off;
    if (!(fx > -4.0 && fy > -4.0 && fx < params.hw * 2.0 + 4.0 && fy < params.hh * 2.0 + 4.0)) {
        return;
    }
    let x0 = i32(floor(fx));
    let y0 = i32(floor(fy));
    let s = i32(params.point_size);
    for (var py = max(y0, 0); py < min(y0 + s, h); py++) {
        for (var px = max(x0, 0); px < min(x0 + s, w); px++) {
            let idx = u32(py) * params.width + u32(px);
            if (matches(idx, i, p.z)) {
                atomicMax(&ids[idx], tag);
            }
        }
    }
}
