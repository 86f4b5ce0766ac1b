// Shading pass: diffuse + normalized Blinn-Phong under many directional lights, one shadow map per
// light group (src/render/shading.rs). Linear radiance × exposure goes to an Rgba32Float target.
//
// L_out = Σ_k E_k · f(l_k, v) · max(0, n·l_k) · V_k                      (DESIGN.md, "A light")
// f(l, v) = ρ/π + k_s · (s + 8)/(8π) · (n·h)^s,  h = normalize(l + v)     (src/render/scene.rs)
// No ambient term: the lights carry all of the map's energy.

const PI: f32 = 3.14159265358979;
// Mirror MAX_LIGHTS and MAX_LIST / 4 in src/render/shading.rs.
const c_max_lights: u32 = 1024u;
const c_max_list_vec4: u32 = 4096u;
// Shadow lookups beyond this many taps are not offered (1 = one bilinear 2×2 PCF tap).
const c_max_pcf_taps: u32 = 4u;

struct Globals {
    view_proj: mat4x4<f32>,
    camera_pos: vec4<f32>,
    // x: exposure; y: glossy-refinement threshold t (the lobe's fraction of its peak below which a
    // light gets diffuse only); z: normal offset of shadow lookups (world units); w: one shadow texel
    // in texture coordinates.
    params: vec4<f32>,
    // x: 1 = lights culled per draw; y: 1 = glossy refinement; z: PCF taps (1 or 4; 0 = no shadows);
    // w: number of groups.
    flags: vec4<u32>,
};

struct Light {
    // xyz: unit vector toward the light.
    to_light: vec4<f32>,
    // rgb: radiance × sr.
    irradiance: vec4<f32>,
};

struct Group {
    // World → shadow clip of the map this group's lights share: its first three rows (the map is
    // orthographic, so the fourth row is 0 0 0 1).
    rows: array<vec4<f32>, 3>,
    // x: layer in t_shadow, or 0xffffffff for no shadow map (lit); members are
    // u_lights.items[y .. y + z].
    info: vec4<u32>,
};

// Uniform buffers rather than storage: see the note on `ShadingPass::lights` in shading.rs.
struct Lights { items: array<Light, c_max_lights> };
struct Groups { items: array<Group, c_max_lights> };
// Group indices, four to a vec4 (uniform arrays have a 16-byte stride).
struct Lists { items: array<vec4<u32>, c_max_list_vec4> };

@group(0) @binding(0) var<uniform> u_globals: Globals;
@group(0) @binding(1) var<uniform> u_lights: Lights;
@group(0) @binding(2) var<uniform> u_groups: Groups;
// The draws' lists of group indices (see u_draw).
@group(0) @binding(3) var<uniform> u_lists: Lists;
@group(0) @binding(4) var t_shadow: texture_depth_2d_array;
@group(0) @binding(5) var s_shadow: sampler_comparison;

struct DrawParams {
    // (offset, count) into u_lists of the groups that can reach this draw's normal cone.
    list: vec2<u32>,
    pad: vec2<u32>,
};
// Set per draw (a dynamic offset), so every pixel of a draw loops over the same list: on a SIMD
// rasterizer the loop and its loads stay uniform.
@group(1) @binding(0) var<uniform> u_draw: DrawParams;

struct VertexInput {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) albedo: vec3<f32>,
    @location(3) gloss: vec2<f32>,
};

struct VertexOutput {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) albedo: vec3<f32>,
    @location(3) gloss: vec2<f32>,
};

@vertex
fn vs_main(in: VertexInput) -> VertexOutput {
    var out: VertexOutput;
    out.clip = u_globals.view_proj * vec4<f32>(in.position, 1.0);
    out.world = in.position;
    out.normal = in.normal;
    out.albedo = in.albedo;
    out.gloss = in.gloss;
    return out;
}

// Fraction of the group's shadow map that sees `world` lit (PCF).
fn visibility(gi: u32, world: vec3<f32>, n: vec3<f32>) -> f32 {
    let layer = u_groups.items[gi].info.x;
    if layer == 0xffffffffu || u_globals.flags.z == 0u {
        return 1.0;
    }
    // Offset along the normal so a surface does not shadow itself (shadow acne).
    let p = world + n * u_globals.params.z;
    let rows = u_groups.items[gi].rows;
    let p1 = vec4<f32>(p, 1.0);
    let clip = vec3<f32>(dot(rows[0], p1), dot(rows[1], p1), dot(rows[2], p1));
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

@fragment
fn fs_main(in: VertexOutput) -> @location(0) vec4<f32> {
    let n = normalize(in.normal);
    let v = normalize(u_globals.camera_pos.xyz - in.world);
    let r = reflect(-v, n);
    let diffuse = in.albedo / PI;
    let ks = in.gloss.x;
    let s = in.gloss.y;
    let lobe_norm = ks * (s + 8.0) / (8.0 * PI);
    // The lobe (n·h)^s falls below t of its peak for n·h < t^(1/s), i.e. for lights farther than
    // 2·acos(t^(1/s)) from the reflected view direction: cos 2x = 2 cos² x − 1.
    let cos_cone = 2.0 * pow(u_globals.params.y, 2.0 / s) - 1.0;
    let refine = u_globals.flags.y != 0u;

    // Culling on: this draw's list. Off: every group, in order.
    let culled = u_globals.flags.x != 0u;
    let list = select(vec2<u32>(0u, u_globals.flags.w), u_draw.list, culled);
    var radiance = vec3<f32>(0.0);
    for (var i = 0u; i < list.y; i++) {
        var gi = i;
        if culled {
            let e = list.x + i;
            gi = u_lists.items[e >> 2u][e & 3u];
        }
        let info = u_groups.items[gi].info;
        let first = info.y;
        let end = first + info.z;
        var sum = vec3<f32>(0.0);
        // No early `continue` for lights behind the surface: a divergent continue would make the
        // loop, and every load in it, divergent across the SIMD lanes; max(0, n·l) costs less.
        for (var k = first; k < end; k++) {
            let l = u_lights.items[k].to_light.xyz;
            let ndl = max(dot(n, l), 0.0);
            var f = diffuse;
            if ks > 0.0 && (!refine || dot(l, r) > cos_cone) {
                let h = normalize(l + v);
                f += vec3<f32>(lobe_norm * pow(max(dot(n, h), 0.0), s));
            }
            sum += u_lights.items[k].irradiance.rgb * f * ndl;
        }
        // Only lights that reach the surface pay for a shadow lookup.
        if any(sum > vec3<f32>(0.0)) {
            radiance += sum * visibility(gi, in.world, n);
        }
    }
    return vec4<f32>(radiance * u_globals.params.x, 1.0);
}
