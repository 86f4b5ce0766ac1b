// Lighting pass: every pixel of the G-buffer lit by the light groups through their shadow maps,
// one window of c_window lights per draw, the draws adding up (src/render/shading.rs). Linear
// radiance × exposure goes to an Rgba16Float target.
//
// L_out = Σ_k E_k · f(l_k, v) · max(0, n·l_k) · V_k                      (DESIGN.md, "A light")
// f(l, v) = ρ/π + k_s · (s + 8)/(8π) · (n·h)^s,  h = normalize(l + v)     (src/render/scene.rs)
// No ambient term: the lights carry all of the map's energy.

const PI: f32 = 3.14159265358979;
// Lights per lighting draw; mirrors WINDOW in src/render/shading.rs. fs_light calls shade_light
// once per slot with a constant index, so every load of the window is uniform across the pixels
// (lavapipe loads dynamically indexed uniforms one SIMD lane at a time, which cost more than the
// shading itself).
const c_window: u32 = 16u;
// Shadow lookups beyond this many taps are not offered (1 = one bilinear 2×2 PCF tap).
const c_max_pcf_taps: u32 = 4u;

struct Globals {
    camera_pos: vec4<f32>,
    // x: exposure; y: glossy-refinement threshold t (the lobe's fraction of its peak below which a
    // light gets diffuse only); z: normal offset of shadow lookups (world units); w: one shadow texel
    // in texture coordinates.
    params: vec4<f32>,
    // x: unused; y: 1 = glossy refinement; z: PCF taps (1 or 4; 0 = no shadows); w: unused.
    flags: vec4<u32>,
};

struct Light {
    // xyz: unit vector toward the light. w: 0 = a light; 1 = a light, the last of its group in this
    // window (apply the group's shadow to the group's sum); 2 = an empty slot.
    dir: vec4<f32>,
    // rgb: radiance × sr. w: the group's shadow-map layer, or −1 for none (lit).
    irradiance: vec4<f32>,
    // The group's world → shadow clip matrix, first three rows (orthographic: the fourth is 0 0 0 1).
    shadow: array<vec4<f32>, 3>,
    // The group's cone of directions: a normal n can receive light from it only if
    // n·xyz > w = −sin β (ALGORITHMS.md §6); w = −2 when culling is off.
    cone: vec4<f32>,
};

struct Window {
    // The cone of every light in the window, as Light::cone: pixels outside it skip the draw.
    cone: vec4<f32>,
    lights: array<Light, c_window>,
};

@group(0) @binding(0) var<uniform> u_globals: Globals;
@group(0) @binding(1) var t_shadow: texture_depth_2d_array;
@group(0) @binding(2) var s_shadow: sampler_comparison;
@group(0) @binding(3) var t_position: texture_2d<f32>;
@group(0) @binding(4) var t_normal: texture_2d<f32>;
@group(0) @binding(5) var t_material: texture_2d<f32>;
// One window of lights per draw (a dynamic offset).
@group(1) @binding(0) var<uniform> u_window: Window;

@vertex
fn vs_light(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // One triangle covering the viewport: (−1,−1), (3,−1), (−1,3).
    let xy = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u)) * 2.0 - vec2<f32>(1.0);
    return vec4<f32>(xy, 0.0, 1.0);
}

// What the pixel's shading needs, computed once.
struct Pixel {
    world: vec3<f32>,
    n: vec3<f32>,
    v: vec3<f32>,
    r: vec3<f32>,
    diffuse: vec3<f32>,
    ks: f32,
    s: f32,
    lobe_norm: f32,
    cos_cone: f32,
};

// The running sums of a pixel.
struct Acc {
    // Unshadowed radiance of the current group so far.
    group: vec3<f32>,
    // Shadowed radiance of the finished groups.
    radiance: vec3<f32>,
};

// Fraction of a group's shadow map that sees the pixel lit (PCF).
fn visibility(light: Light, px: Pixel) -> f32 {
    let layer = i32(light.irradiance.w);
    if layer < 0 || u_globals.flags.z == 0u {
        return 1.0;
    }
    // Offset along the normal so a surface does not shadow itself (shadow acne).
    let p = vec4<f32>(px.world + px.n * u_globals.params.z, 1.0);
    let clip = vec3<f32>(dot(light.shadow[0], p), dot(light.shadow[1], p), dot(light.shadow[2], p));
    // Compensate for the Y-flip difference between NDC and texture coordinates.
    let uv = clip.xy * vec2<f32>(0.5, -0.5) + vec2<f32>(0.5);
    if any(uv < vec2<f32>(0.0)) || any(uv > vec2<f32>(1.0)) {
        return 1.0; // outside the casters' footprint: nothing can block this light here
    }
    // Beyond the far plane counts as "at the far plane": behind every caster, in front of the clear.
    let depth = clamp(clip.z, 0.0, 1.0);
    if u_globals.flags.z <= 1u {
        return textureSampleCompareLevel(t_shadow, s_shadow, uv, layer, depth);
    }
    // Four bilinear taps half a texel apart: a 3 × 3 tent over the texels.
    let h = 0.5 * u_globals.params.w;
    var sum = 0.0;
    for (var i = 0u; i < c_max_pcf_taps; i++) {
        let o = vec2<f32>(select(-h, h, (i & 1u) != 0u), select(-h, h, (i & 2u) != 0u));
        sum += textureSampleCompareLevel(t_shadow, s_shadow, uv + o, layer, depth);
    }
    return sum / f32(c_max_pcf_taps);
}

// Adds light `j` of the window. `j` is a constant at every call site.
fn shade_light(j: u32, px: Pixel, acc: ptr<function, Acc>) {
    let light = u_window.lights[j];
    if light.dir.w > 1.5 {
        return; // an empty slot
    }
    // Culling by normal: skip the group's lights where the pixel faces away from all of them.
    if dot(px.n, light.cone.xyz) > light.cone.w {
        let l = light.dir.xyz;
        let ndl = max(dot(px.n, l), 0.0);
        var f = px.diffuse;
        // Glossy refinement: the lobe only for lights near the reflected view direction.
        if px.ks > 0.0 && (u_globals.flags.y == 0u || dot(l, px.r) > px.cos_cone) {
            let h = normalize(l + px.v);
            f += vec3<f32>(px.lobe_norm * pow(max(dot(px.n, h), 0.0), px.s));
        }
        (*acc).group += light.irradiance.rgb * f * ndl;
    }
    if light.dir.w > 0.5 {
        // The group's last light here: one shadow lookup for all of it, and only where it adds light.
        if any((*acc).group > vec3<f32>(0.0)) {
            (*acc).radiance += (*acc).group * visibility(light, px);
        }
        (*acc).group = vec3<f32>(0.0);
    }
}

@fragment
fn fs_light(@builtin(position) frag: vec4<f32>) -> @location(0) vec4<f32> {
    let texel = vec2<i32>(frag.xy);
    let g_normal = textureLoad(t_normal, texel, 0);
    let n = g_normal.xyz;
    // Background (nothing drawn), or a normal that no light of this window can reach.
    if dot(n, n) == 0.0 || dot(n, u_window.cone.xyz) <= u_window.cone.w {
        discard;
    }
    let g_position = textureLoad(t_position, texel, 0);
    let g_material = textureLoad(t_material, texel, 0);
    var px: Pixel;
    px.world = g_position.xyz;
    px.n = n;
    px.v = normalize(u_globals.camera_pos.xyz - px.world);
    px.r = reflect(-px.v, n);
    px.diffuse = g_material.rgb / PI;
    px.ks = g_normal.w;
    px.s = max(g_material.a * 255.0, 1.0);
    px.lobe_norm = px.ks * (px.s + 8.0) / (8.0 * PI);
    // The lobe (n·h)^s falls below t of its peak for n·h < t^(1/s), i.e. for lights farther than
    // 2·acos(t^(1/s)) from the reflected view direction: cos 2x = 2 cos² x − 1.
    px.cos_cone = 2.0 * pow(u_globals.params.y, 2.0 / px.s) - 1.0;

    var acc: Acc;
    acc.group = vec3<f32>(0.0);
    acc.radiance = vec3<f32>(0.0);
    // c_window calls, each with a constant index.
    shade_light(0u, px, &acc);
    shade_light(1u, px, &acc);
    shade_light(2u, px, &acc);
    shade_light(3u, px, &acc);
    shade_light(4u, px, &acc);
    shade_light(5u, px, &acc);
    shade_light(6u, px, &acc);
    shade_light(7u, px, &acc);
    shade_light(8u, px, &acc);
    shade_light(9u, px, &acc);
    shade_light(10u, px, &acc);
    shade_light(11u, px, &acc);
    shade_light(12u, px, &acc);
    shade_light(13u, px, &acc);
    shade_light(14u, px, &acc);
    shade_light(15u, px, &acc);
    // Windows add up in the target (additive blending).
    return vec4<f32>(acc.radiance * u_globals.params.x, 1.0);
}
