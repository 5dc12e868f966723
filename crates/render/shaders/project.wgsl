// Shared by rasterize.wgsl, rasterize_u32.wgsl and ids.wgsl (the host appends it to each):
// the per-dispatch parameters and point columns (group 0), the transform and clip
// test of point `i`, and the pixel a 1-pixel point hits.
// Must match `RasterParams` and `Projector` in src/render/gpu.rs and cpu.rs.

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
    id_base: u32,    // the id pass: frame-wide id of this chunk's first point
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> xs: array<f32>;
@group(0) @binding(2) var<storage, read> ys: array<f32>;
@group(0) @binding(3) var<storage, read> zs: array<f32>;
@group(0) @binding(4) var<storage, read> cs: array<u32>;

// Screen position (x, y) and clip w of point `i`, with w = 1.0 when the point
// is inside the clip volume and 0.0 when it is not.
fn project(i: u32) -> vec4<f32> {
    let x = xs[i];
    let y = ys[i];
    let z = zs[i];
    let m = params.mvp;
    let cw = m[0].w * x + m[1].w * y + m[2].w * z + m[3].w;
    let cz = m[0].z * x + m[1].z * y + m[2].z * z + m[3].z;
    if (!(cw > 0.0 && cz >= 0.0 && cz <= cw)) {
        return vec4<f32>(0.0, 0.0, 0.0, 0.0);
    }
    let cx = m[0].x * x + m[1].x * y + m[2].x * z + m[3].x;
    let cy = m[0].y * x + m[1].y * y + m[2].y * z + m[3].y;
    let sx = cx / cw * params.hw + params.hw;
    let sy = params.hh - cy / cw * params.hh;
    return vec4<f32>(sx, sy, cw, 1.0);
}

// The pixel a 1-pixel point at screen position `p` lands on, or 0xffffffff when
// it is off screen.
fn pixel_of(p: vec2<f32>) -> u32 {
    if (p.x >= 0.0 && p.y >= 0.0 && p.x < params.hw * 2.0 && p.y < params.hh * 2.0) {
        let ix = min(i32(p.x), i32(params.width) - 1);
        let iy = min(i32(p.y), i32(params.height) - 1);
        return u32(iy) * params.width + u32(ix);
    }
    return 0xffffffffu;
}
