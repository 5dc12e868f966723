// The 64-bit framebuffer read as (low, high) words: colour, then depth bits.
@group(1) @binding(1) var<storage, read> fb: array<vec2<u32>>;

fn matches(idx: u32, i: u32, cw: f32) -> bool {
    let v = fb[idx];
    return v.y == bitcast<u32>(cw) && v.x == (cs[i] & 0xffffffu);
}
