// Resolves the packed framebuffer to RGBA8 (one u32 per pixel,
// r | g << 8 | b << 16 | a << 24) plus, when asked, linear view depth (+inf for
// background) for eye-dome lighting on the CPU, and resets each pixel to empty
// for the next frame (the clear entry points are only needed for a fresh or
// possibly dirty framebuffer). The 64-bit framebuffer is read as vec2<u32>
// (x = colour, y = depth bits) so this module needs no int64 support.

struct Params {
    pixels: u32,
    background: u32, // packed like the colour column, alpha 255
    near: f32,
    far: f32,
    _unused: u32,
    write_depth: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read_write> fb64: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read_write> fb32: array<u32>;
@group(0) @binding(3) var<storage, read_write> out_rgba: array<u32>;
@group(0) @binding(4) var<storage, read_write> out_depth: array<f32>;

// Each invocation handles PIXELS_PER_THREAD pixels, strided by the workgroup
// size: lavapipe pays a noticeable cost per workgroup, so fewer, longer
// workgroups are several times faster there. Must match the host constant.
const PIXELS_PER_THREAD: u32 = 16u;

fn first_pixel(wg: vec3<u32>, nwg: vec3<u32>, li: u32) -> u32 {
    return (wg.y * nwg.x + wg.x) * (256u * PIXELS_PER_THREAD) + li;
}

@compute @workgroup_size(256)
fn clear64(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let base = first_pixel(wg, nwg, li);
    for (var k = 0u; k < PIXELS_PER_THREAD; k++) {
        let i = base + k * 256u;
        if (i >= params.pixels) {
            return;
        }
        clear64_pixel(i);
    }
}

fn clear64_pixel(i: u32) {
    fb64[i] = vec2<u32>(0xffffffffu, 0xffffffffu);
}

@compute @workgroup_size(256)
fn clear32(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let base = first_pixel(wg, nwg, li);
    for (var k = 0u; k < PIXELS_PER_THREAD; k++) {
        let i = base + k * 256u;
        if (i >= params.pixels) {
            return;
        }
        clear32_pixel(i);
    }
}

fn clear32_pixel(i: u32) {
    fb32[i] = 0xffffffffu;
}

@compute @workgroup_size(256)
fn resolve64(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let base = first_pixel(wg, nwg, li);
    for (var k = 0u; k < PIXELS_PER_THREAD; k++) {
        let i = base + k * 256u;
        if (i >= params.pixels) {
            return;
        }
        resolve64_pixel(i);
    }
}

fn resolve64_pixel(i: u32) {
    let v = fb64[i];
    fb64[i] = vec2<u32>(0xffffffffu, 0xffffffffu);
    if (v.x == 0xffffffffu && v.y == 0xffffffffu) {
        out_rgba[i] = params.background;
        if (params.write_depth != 0u) {
            out_depth[i] = bitcast<f32>(0x7f800000u);
        }
    } else {
        out_rgba[i] = (v.x & 0xffffffu) | 0xff000000u;
        if (params.write_depth != 0u) {
            out_depth[i] = bitcast<f32>(v.y);
        }
    }
}

@compute @workgroup_size(256)
fn resolve32(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let base = first_pixel(wg, nwg, li);
    for (var k = 0u; k < PIXELS_PER_THREAD; k++) {
        let i = base + k * 256u;
        if (i >= params.pixels) {
            return;
        }
        resolve32_pixel(i);
    }
}

fn resolve32_pixel(i: u32) {
    let v = fb32[i];
    fb32[i] = 0xffffffffu;
    if (v == 0xffffffffu) {
        out_rgba[i] = params.background;
        if (params.write_depth != 0u) {
            out_depth[i] = bitcast<f32>(0x7f800000u);
        }
    } else {
        let c = v & 0xffffu;
        let b = (c >> 11u) & 0x1fu;
        let g = (c >> 5u) & 0x3fu;
        let r = c & 0x1fu;
        let r8 = (r << 3u) | (r >> 2u);
        let g8 = (g << 2u) | (g >> 4u);
        let b8 = (b << 3u) | (b >> 2u);
        out_rgba[i] = r8 | (g8 << 8u) | (b8 << 16u) | 0xff000000u;
        if (params.write_depth != 0u) {
            let z = f32(v >> 16u) / 65535.0;
            out_depth[i] = params.far * params.near / (params.far - z * (params.far - params.near));
        }
    }
}
