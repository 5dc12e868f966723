// The 32-bit framebuffer: `log-depth16 << 16 | bgr565`, packed as in
// rasterize_u32.wgsl's `draw`.
@group(1) @binding(1) var<storage, read> fb: array<u32>;

fn matches(idx: u32, i: u32, cw: f32) -> bool {
    let c = cs[i];
    let bgr565 = (((c >> 19u) & 0x1fu) << 11u) | (((c >> 10u) & 0x3fu) << 5u) | ((c >> 3u) & 0x1fu);
    let d16 = u32(clamp((log2(cw) - params.log2_near) * params.depth_scale, 0.0, 65534.0));
    return fb[idx] == ((d16 << 16u) | bgr565);
}
