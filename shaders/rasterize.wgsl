// Point rasterization with 64-bit atomics (Schütz et al. 2021): one invocation per
// point, transform by the batch MVP, clip, project, and `atomicMin` the packed
// `depth_bits << 32 | rgb` into the framebuffer (nearest wins, ties to the smaller
// colour). Must match `Projector::splat` in src/render/cpu.rs.
// Needs wgpu::Features::SHADER_INT64 | SHADER_INT64_ATOMIC_MIN_MAX. Where
// SHADER_INT64_ATOMIC_ALL_OPS exists, the host replaces the EARLY_OUT marker with
// a plain atomicLoad depth test that skips most atomicMin calls on dense input.
// Each invocation handles POINTS_PER_THREAD points (strided by the workgroup size).

struct Params {
    mvp: mat4x4<f32>,
    width: u32,
    height: u32,
    point_size: u32,
    count: u32,
    hw: f32,
    hh: f32,
    off: f32,
    log2_near: f32,  // 32-bit path: depth16 = (log2(w) - log2_near) * depth_scale
    depth_scale: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> xs: array<f32>;
@group(0) @binding(2) var<storage, read> ys: array<f32>;
@group(0) @binding(3) var<storage, read> zs: array<f32>;
@group(0) @binding(4) var<storage, read> cs: array<u32>;
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
        let idx = pixel_of(i);
        if (idx == none) {
            continue;
        }
        let v = (u64(bitcast<u32>(clip_w(i))) << 32u) | u64(cs[i] & 0xffffffu);
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

fn clip_w(i: u32) -> f32 {
    let m = params.mvp;
    return m[0].w * xs[i] + m[1].w * ys[i] + m[2].w * zs[i] + m[3].w;
}

// The pixel a 1-pixel point lands on, or 0xffffffff when it is clipped; the same
// tests as `draw`.
fn pixel_of(i: u32) -> u32 {
    let x = xs[i];
    let y = ys[i];
    let z = zs[i];
    let m = params.mvp;
    let cw = m[0].w * x + m[1].w * y + m[2].w * z + m[3].w;
    let cz = m[0].z * x + m[1].z * y + m[2].z * z + m[3].z;
    if (!(cw > 0.0 && cz >= 0.0 && cz <= cw)) {
        return 0xffffffffu;
    }
    let cx = m[0].x * x + m[1].x * y + m[2].x * z + m[3].x;
    let cy = m[0].y * x + m[1].y * y + m[2].y * z + m[3].y;
    let sx = cx / cw * params.hw + params.hw;
    let sy = params.hh - cy / cw * params.hh;
    if (sx >= 0.0 && sy >= 0.0 && sx < params.hw * 2.0 && sy < params.hh * 2.0) {
        let ix = min(i32(sx), i32(params.width) - 1);
        let iy = min(i32(sy), i32(params.height) - 1);
        return u32(iy) * params.width + u32(ix);
    }
    return 0xffffffffu;
}

fn draw(i: u32) {
    let x = xs[i];
    let y = ys[i];
    let z = zs[i];
    let m = params.mvp;
    let cw = m[0].w * x + m[1].w * y + m[2].w * z + m[3].w;
    let cz = m[0].z * x + m[1].z * y + m[2].z * z + m[3].z;
    if (!(cw > 0.0 && cz >= 0.0 && cz <= cw)) {
        return;
    }
    let cx = m[0].x * x + m[1].x * y + m[2].x * z + m[3].x;
    let cy = m[0].y * x + m[1].y * y + m[2].y * z + m[3].y;
    let sx = cx / cw * params.hw + params.hw;
    let sy = params.hh - cy / cw * params.hh;
    let v = (u64(bitcast<u32>(cw)) << 32u) | u64(cs[i] & 0xffffffu);
    let w = i32(params.width);
    let h = i32(params.height);
    if (params.point_size == 1u) {
        if (sx >= 0.0 && sy >= 0.0 && sx < params.hw * 2.0 && sy < params.hh * 2.0) {
            let ix = min(i32(sx), w - 1);
            let iy = min(i32(sy), h - 1);
            write_min(u32(iy) * params.width + u32(ix), v);
        }
        return;
    }
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
