// Tonemap pass: the linear HDR target → the display (an sRGB target encodes on store).
// c' = 1 − exp(−c): linear near black, saturating smoothly instead of clipping.

@group(0) @binding(0) var t_hdr: texture_2d<f32>;

@vertex
fn vs_tonemap(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // One triangle covering the viewport: (−1,−1), (3,−1), (−1,3).
    let xy = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u)) * 2.0 - vec2<f32>(1.0);
    return vec4<f32>(xy, 0.0, 1.0);
}

@fragment
fn fs_tonemap(@builtin(position) frag: vec4<f32>) -> @location(0) vec4<f32> {
    let c = textureLoad(t_hdr, vec2<i32>(frag.xy), 0).rgb;
    return vec4<f32>(vec3<f32>(1.0) - exp(-max(c, vec3<f32>(0.0))), 1.0);
}
