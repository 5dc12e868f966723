// Resolves the packed framebuffer to RGBA8 (one u32 per pixel,
// r | g << 8 | b << 16 | a << 24) plus, when asked, linear view depth (+inf for
// background) for eye-dome lighting on the CPU, and resets each pixel to empty
// for the next frame (the clear entry points are only needed for a fresh or
// possibly dirty framebuffer).
//
// Each invocation handles a quad of 4 consecutive pixels with vec4 loads and
// stores (the host pads the framebuffer to a multiple of 4 pixels): software
// Vulkan (lavapipe) turns per-lane scalar accesses into slow scatters, and
// real GPUs do not mind. The 64-bit framebuffer is read as vec4<u32> holding
// two pixels (colour, depth bits, colour, depth bits), so this module needs no
// int64 support.

struct Params {
    quads: u32,
    background: u32, // packed like the colour column, alpha 255
    log2_near: f32,   // 32-bit path: depth = exp2(log2_near + depth16 / depth_scale)
    depth_scale: f32,
    _unused: u32,
    write_depth: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read_write> fb64: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read_write> fb32: array<vec4<u32>>;
@group(0) @binding(3) var<storage, read_write> out_rgba: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read_write> out_depth: array<vec4<f32>>;

const EMPTY: vec4<u32> = vec4<u32>(0xffffffffu, 0xffffffffu, 0xffffffffu, 0xffffffffu);
const INF: u32 = 0x7f800000u;

fn quad_index(wg: vec3<u32>, nwg: vec3<u32>, li: u32) -> u32 {
    return (wg.y * nwg.x + wg.x) * 256u + li;
}

@compute @workgroup_size(256)
fn clear64(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let q = quad_index(wg, nwg, li);
    if (q < params.quads) {
        fb64[2u * q] = EMPTY;
        fb64[2u * q + 1u] = EMPTY;
    }
}

@compute @workgroup_size(256)
fn clear32(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let q = quad_index(wg, nwg, li);
    if (q < params.quads) {
        fb32[q] = EMPTY;
    }
}

@compute @workgroup_size(256)
fn resolve64(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let q = quad_index(wg, nwg, li);
    if (q >= params.quads) {
        return;
    }
    let a = fb64[2u * q];
    let b = fb64[2u * q + 1u];
    fb64[2u * q] = EMPTY;
    fb64[2u * q + 1u] = EMPTY;
    let colors = vec4<u32>(a.x, a.z, b.x, b.z);
    let depths = vec4<u32>(a.y, a.w, b.y, b.w);
    let empty = (colors == EMPTY) & (depths == EMPTY);
    let rgba = (colors & vec4<u32>(0xffffffu)) | vec4<u32>(0xff000000u);
    out_rgba[q] = select(rgba, vec4<u32>(params.background), empty);
    if (params.write_depth != 0u) {
        out_depth[q] = bitcast<vec4<f32>>(select(depths, vec4<u32>(INF), empty));
    }
}

@compute @workgroup_size(256)
fn resolve32(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let q = quad_index(wg, nwg, li);
    if (q >= params.quads) {
        return;
    }
    let v = fb32[q];
    fb32[q] = EMPTY;
    let empty = v == EMPTY;
    // depth16 << 16 | bgr565
    let c = v & vec4<u32>(0xffffu);
    let b = (c >> vec4<u32>(11u)) & vec4<u32>(0x1fu);
    let g = (c >> vec4<u32>(5u)) & vec4<u32>(0x3fu);
    let r = c & vec4<u32>(0x1fu);
    let r8 = (r << vec4<u32>(3u)) | (r >> vec4<u32>(2u));
    let g8 = (g << vec4<u32>(2u)) | (g >> vec4<u32>(4u));
    let b8 = (b << vec4<u32>(3u)) | (b >> vec4<u32>(2u));
    let rgba = r8 | (g8 << vec4<u32>(8u)) | (b8 << vec4<u32>(16u)) | vec4<u32>(0xff000000u);
    out_rgba[q] = select(rgba, vec4<u32>(params.background), empty);
    if (params.write_depth != 0u) {
        let d = exp2(params.log2_near + vec4<f32>(v >> vec4<u32>(16u)) / params.depth_scale);
        out_depth[q] = select(d, bitcast<vec4<f32>>(vec4<u32>(INF)), empty);
    }
}
