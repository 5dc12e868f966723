// Clears the packed framebuffer and resolves it to RGBA8 (one u32 per pixel,
// r | g << 8 | b << 16 | a << 24) plus linear view depth (+inf for background)
// for eye-dome lighting on the CPU. The 64-bit framebuffer is read as
// vec2<u32> (x = colour, y = depth bits) so this module needs no int64 support.

struct Params {
    pixels: u32,
    background: u32, // packed like the colour column, alpha 255
    near: f32,
    far: f32,
    row_stride: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read_write> fb64: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read_write> fb32: array<u32>;
@group(0) @binding(3) var<storage, read_write> out_rgba: array<u32>;
@group(0) @binding(4) var<storage, read_write> out_depth: array<f32>;

fn pixel_index(gid: vec3<u32>) -> u32 {
    return gid.y * params.row_stride + gid.x;
}

@compute @workgroup_size(256)
fn clear64(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel_index(gid);
    if (i < params.pixels) {
        fb64[i] = vec2<u32>(0xffffffffu, 0xffffffffu);
    }
}

@compute @workgroup_size(256)
fn clear32(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel_index(gid);
    if (i < params.pixels) {
        fb32[i] = 0xffffffffu;
    }
}

@compute @workgroup_size(256)
fn resolve64(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel_index(gid);
    if (i >= params.pixels) {
        return;
    }
    let v = fb64[i];
    if (v.x == 0xffffffffu && v.y == 0xffffffffu) {
        out_rgba[i] = params.background;
        out_depth[i] = bitcast<f32>(0x7f800000u);
    } else {
        out_rgba[i] = (v.x & 0xffffffu) | 0xff000000u;
        out_depth[i] = bitcast<f32>(v.y);
    }
}

@compute @workgroup_size(256)
fn resolve32(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel_index(gid);
    if (i >= params.pixels) {
        return;
    }
    let v = fb32[i];
    if (v == 0xffffffffu) {
        out_rgba[i] = params.background;
        out_depth[i] = bitcast<f32>(0x7f800000u);
    } else {
        let c = v & 0xffffu;
        let b = (c >> 11u) & 0x1fu;
        let g = (c >> 5u) & 0x3fu;
        let r = c & 0x1fu;
        let r8 = (r << 3u) | (r >> 2u);
        let g8 = (g << 2u) | (g >> 4u);
        let b8 = (b << 3u) | (b >> 2u);
        out_rgba[i] = r8 | (g8 << 8u) | (b8 << 16u) | 0xff000000u;
        let z = f32(v >> 16u) / 65535.0;
        out_depth[i] = params.far * params.near / (params.far - z * (params.far - params.near));
    }
}
