// Fallback point rasterization for adapters without 64-bit atomics: the packed
// value is `depth16 << 16 | bgr565` with a 32-bit `atomicMin`. The 16-bit depth
// is log2 of the view depth scaled over [near, far] (uniform relative precision,
// about 0.02% of the distance for far/near = 1e5), so only points that close
// may resolve either way.
// Same transform, splat rules and dispatch shape as rasterize.wgsl.

// Params and the point bindings (group 0): project.wgsl, appended by the host.
@group(1) @binding(0) var<storage, read_write> fb: array<atomic<u32>>;

const POINTS_PER_THREAD: u32 = 1u; // replaced by the host

fn write_min(idx: u32, v: u32) {
    if (atomicLoad(&fb[idx]) <= v) {
        return;
    }
    atomicMin(&fb[idx], v);
}

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let base = (wg.y * nwg.x + wg.x) * (256u * POINTS_PER_THREAD) + li;
    for (var k = 0u; k < POINTS_PER_THREAD; k++) {
        let i = base + k * 256u;
        if (i >= params.count) {
            return;
        }
        draw(i);
    }
}

fn draw(i: u32) {
    let p = project(i);
    if (p.w == 0.0) {
        return;
    }
    let cw = p.z;
    let c = cs[i];
    // Blue in the high bits, red in the low ones: ties then break like the
    // 64-bit path, which compares b << 16 | g << 8 | r.
    let bgr565 = (((c >> 19u) & 0x1fu) << 11u) | (((c >> 10u) & 0x3fu) << 5u) | ((c >> 3u) & 0x1fu);
    let d16 = u32(clamp((log2(cw) - params.log2_near) * params.depth_scale, 0.0, 65534.0));
    let v = (d16 << 16u) | bgr565;
    if (params.point_size == 1u) {
        let idx = pixel_of(p.xy);
        if (idx != 0xffffffffu) {
            write_min(idx, v);
        }
        return;
    }
    let w = i32(params.width);
    let h = i32(params.height);
    let sx = p.x;
    let sy = p.y;
    let fx = sx - params.off;
    let fy = sy - params.off;
    if (!(fx > -4.0 && fy > -4.0 && fx < params.hw * 2.0 + 4.0 && fy < params.hh * 2.0 + 4.0)) {
        return;
    }
    let x0 = i32(floor(fx));
    let y0 = i32(floor(fy));
    let s = i32(params.point_size);
    for (var py = max(y0, 0); py < min(y0 + s, h); py++) {
        for (var px = max(x0, 0); px < min(x0 + s, w); px++) {
            write_min(u32(py) * params.width + u32(px), v);
        }
    }
}
