// Shading pass: diffuse + normalized Blinn-Phong under many directional lights, one shadow map per
// light group (src/render/shading.rs). Linear radiance × exposure goes to an Rgba32Float target.
//
// L_out = Σ_k E_k · f(l_k, v) · max(0, n·l_k) · V_k                      (DESIGN.md, "A light")
// f(l, v) = ρ/π + k_s · (s + 8)/(8π) · (n·h)^s,  h = normalize(l + v)     (src/render/scene.rs)
// No ambient term: the lights carry all of the map's energy.

const PI: f32 = 3.14159265358979;
// Shadow lookups beyond this many taps are not offered (1 = one bilinear 2×2 PCF tap).
const c_max_pcf_taps: u32 = 4u;

struct Globals {
    view_proj: mat4x4<f32>,
    camera_pos: vec4<f32>,
    // x: exposure; y: glossy-refinement threshold t (the lobe's fraction of its peak below which a
    // light gets diffuse only); z: normal offset of shadow lookups (world units); w: one shadow texel
    // in texture coordinates.
    params: vec4<f32>,
    // x: 1 = cull lights by normal bin; y: 1 = glossy refinement; z: PCF taps (1 or 4);
    // w: side B of the B × B octahedral grid of normal bins.
    flags: vec4<u32>,
};

struct Light {
    // xyz: unit vector toward the light.
    to_light: vec4<f32>,
    // rgb: radiance × sr.
    irradiance: vec4<f32>,
};

struct Group {
    // World → shadow clip of the map this group's lights share.
    view_proj: mat4x4<f32>,
    // Layer in t_shadow, or 0xffffffff for no shadow map (lit).
    layer: u32,
    // Members are s_lights[first .. first + count].
    first: u32,
    count: u32,
    pad: u32,
};

@group(0) @binding(0) var<uniform> u_globals: Globals;
@group(0) @binding(1) var<storage, read> s_lights: array<Light>;
@group(0) @binding(2) var<storage, read> s_groups: array<Group>;
// Per normal bin: (offset, count) into s_bin_groups. Entry B·B lists every group (culling off).
@group(0) @binding(3) var<storage, read> s_bins: array<vec2<u32>>;
@group(0) @binding(4) var<storage, read> s_bin_groups: array<u32>;
@group(0) @binding(5) var t_shadow: texture_depth_2d_array;
@group(0) @binding(6) var s_shadow: sampler_comparison;

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

// Octahedral map of a unit vector to [0,1]² with +Y at the centre; must match
// `octahedral_encode` in src/render/shading.rs, which builds the bins' cones.
fn octahedral_encode(n: vec3<f32>) -> vec2<f32> {
    var p = n.xz / (abs(n.x) + abs(n.y) + abs(n.z));
    if n.y < 0.0 {
        let s = select(vec2<f32>(-1.0), vec2<f32>(1.0), p >= vec2<f32>(0.0));
        p = (vec2<f32>(1.0) - abs(p.yx)) * s;
    }
    return p * 0.5 + vec2<f32>(0.5);
}

// Fraction of the group's shadow map that sees `world` lit (PCF).
fn visibility(g: Group, world: vec3<f32>, n: vec3<f32>) -> f32 {
    if g.layer == 0xffffffffu {
        return 1.0;
    }
    // Offset along the normal so a surface does not shadow itself (shadow acne).
    let p = world + n * u_globals.params.z;
    let clip = g.view_proj * vec4<f32>(p, 1.0);
    // Compensate for the Y-flip difference between NDC and texture coordinates.
    let uv = clip.xy * vec2<f32>(0.5, -0.5) + vec2<f32>(0.5);
    if any(uv < vec2<f32>(0.0)) || any(uv > vec2<f32>(1.0)) {
        return 1.0; // outside the casters' footprint: nothing can block this light here
    }
    // Beyond the far plane counts as "at the far plane": behind every caster, in front of the clear.
    let depth = clamp(clip.z, 0.0, 1.0);
    if u_globals.flags.z <= 1u {
        return textureSampleCompareLevel(t_shadow, s_shadow, uv, g.layer, depth);
    }
    // Four bilinear taps half a texel apart: a 3 × 3 tent over the texels.
    let h = 0.5 * u_globals.params.w;
    var sum = 0.0;
    for (var i = 0u; i < c_max_pcf_taps; i++) {
        let o = vec2<f32>(select(-h, h, (i & 1u) != 0u), select(-h, h, (i & 2u) != 0u));
        sum += textureSampleCompareLevel(t_shadow, s_shadow, uv + o, g.layer, depth);
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

    var bin = u_globals.flags.w * u_globals.flags.w; // the list of every group
    if u_globals.flags.x != 0u {
        let b = u_globals.flags.w;
        let cell = min(vec2<u32>(octahedral_encode(n) * f32(b)), vec2<u32>(b - 1u));
        bin = cell.y * b + cell.x;
    }
    let list = s_bins[bin];

    var radiance = vec3<f32>(0.0);
    for (var i = 0u; i < list.y; i++) {
        let g = s_groups[s_bin_groups[list.x + i]];
        var sum = vec3<f32>(0.0);
        for (var k = g.first; k < g.first + g.count; k++) {
            let light = s_lights[k];
            let l = light.to_light.xyz;
            let ndl = dot(n, l);
            if ndl <= 0.0 {
                continue;
            }
            var f = diffuse;
            if ks > 0.0 && (!refine || dot(l, r) > cos_cone) {
                let h = normalize(l + v);
                f += vec3<f32>(lobe_norm * pow(max(dot(n, h), 0.0), s));
            }
            sum += light.irradiance.rgb * f * ndl;
        }
        // Only lights that reach the surface pay for a shadow lookup.
        if any(sum > vec3<f32>(0.0)) {
            radiance += sum * visibility(g, in.world, n);
        }
    }
    return vec4<f32>(radiance * u_globals.params.x, 1.0);
}
