// Point rasterization with 64-bit atomics (Schütz et al. 2021): one invocation per
// point, transform by the batch MVP, clip, project, and `atomicMin` the packed
// `depth_bits << 32 | rgb` into the framebuffer (nearest wins, ties to the smaller
// colour). Must match `Projector::splat` in src/render/cpu.rs.
// Needs wgpu::Features::SHADER_INT64 | SHADER_INT64_ATOMIC_MIN_MAX. Where
// SHADER_INT64_ATOMIC_ALL_OPS exists, the host replaces the EARLY_OUT marker with
// a plain atomicLoad depth test that skips most atomicMin calls on dense input.
// Each invocation handles POINTS_PER_THREAD points (strided by the workgroup size).

// Params and the point bindings (group 0): project.wgsl, appended by the host.
@group(1) @binding(0) var<storage, read_write> fb: array<atomic<u64>>;

const POINTS_PER_THREAD: u32 = 1u; // replaced by the host

fn write_min(idx: u32, v: u64) {
    // EARLY_OUT
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

// The same points, but each invocation takes POINTS_PER_THREAD consecutive ones
// and, for 1-pixel points, merges runs that land on one pixel (frequent in Morton
// order, where neighbours in the buffer are neighbours in space) into a single
// atomicMin. Same result: the minimum of a run is what its atomics would leave.
@compute @workgroup_size(256)
fn main_merge(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let first = ((wg.y * nwg.x + wg.x) * 256u + li) * POINTS_PER_THREAD;
    if (params.point_size != 1u) {
        for (var k = 0u; k < POINTS_PER_THREAD; k++) {
            let i = first + k;
            if (i >= params.count) {
                return;
            }
            draw(i);
        }
        return;
    }
    let none = 0xffffffffu;
    var cur_idx = none;
    var cur_v = (u64(none) << 32u) | u64(none);
    for (var k = 0u; k < POINTS_PER_THREAD; k++) {
        let i = first + k;
        if (i >= params.count) {
            break;
        }
        let p = project(i);
        if (p.w == 0.0) {
            continue;
        }
        let idx = pixel_of(p.xy);
        if (idx == none) {
            continue;
        }
        let v = (u64(bitcast<u32>(p.z)) << 32u) | u64(cs[i] & 0xffffffu);
        if (idx == cur_idx) {
            cur_v = min(cur_v, v);
        } else {
            if (cur_idx != none) {
                write_min(cur_idx, cur_v);
            }
            cur_idx = idx;
            cur_v = v;
        }
    }
    if (cur_idx != none) {
        write_min(cur_idx, cur_v);
    }
}

fn draw(i: u32) {
    let p = project(i);
    if (p.w == 0.0) {
        return;
    }
    let v = (u64(bitcast<u32>(p.z)) << 32u) | u64(cs[i] & 0xffffffu);
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
