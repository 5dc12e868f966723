// Shared by rasterize.wgsl and rasterize_u32.wgsl (the host appends it to each):
// the transform and clip test of point `i`, and the pixel a 1-pixel point hits.
// Must match `Projector` in src/render/cpu.rs.

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
